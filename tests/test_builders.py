"""Scene builders: sizes, overlaps, walls, settled packings, the packing cache, hard cases."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest

import cocd
from cocd.builders import (
    HARD_CASES,
    column_collapse,
    grain_groups,
    static_box,
)
from cocd.errors import SceneError
from cocd.packing import packing_fraction, rain_deposition

RAIN_2D = dict(n_grains=300, packing="rain")
BOX_3D = dict(n_grains=250, diameter=0.01)


@pytest.fixture(scope="session", autouse=True)
def packing_cache(tmp_path_factory):
    """One packing cache for the session, so each rain deposition runs once."""
    old = os.environ.get("COCD_CACHE")
    path = tmp_path_factory.mktemp("cocd-cache")
    os.environ["COCD_CACHE"] = str(path)
    yield path
    if old is None:
        del os.environ["COCD_CACHE"]
    else:
        os.environ["COCD_CACHE"] = old


def ready(scene):
    scene.check_overlaps()
    cocd.Stepper(scene, 1e-3)
    return scene


def column(scene):
    return grain_groups(scene)["column"]


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("packing", ["lattice", "rain"])
def test_column_size_by_count_and_by_diameter(dim, packing):
    n = 120 if dim == 2 else 60
    small = dict(length=0.06, height=0.042) | ({"width": 0.03} if dim == 3 else {})
    by_n = ready(column_collapse(dim, n_grains=n, packing=packing, **small))
    assert by_n.dim == dim and by_n.n_grains == n
    d = 2.0 * by_n.radii.mean()
    by_d = ready(column_collapse(dim, diameter=d, packing=packing, **small))
    assert abs(by_d.n_grains - n) <= 0.02 * n + 1
    assert np.isclose(2.0 * by_d.radii.mean(), d, rtol=0.02)


@pytest.mark.parametrize("dim", [2, 3])
def test_column_walls_and_extent(dim):
    scene = ready(column_collapse(dim, n_grains=200))
    normals = np.array([w.normal for w in scene.walls])
    assert any(np.allclose(n, np.eye(dim)[-1]) for n in normals)  # floor
    assert any(np.allclose(n, np.eye(dim)[0]) for n in normals)  # back wall
    assert not any(np.allclose(n, -np.eye(dim)[0]) for n in normals)  # gate removed
    if dim == 3:
        assert len(scene.walls) == 4
        y = scene.positions[:, 1]
        assert y.min() - scene.radii.max() >= 0.0 and y.max() + scene.radii.max() <= 0.20
    x, r = scene.positions, scene.radii
    assert (x[:, 0] + r).max() <= 0.20 + 1e-12
    assert abs((x[:, -1] + r).max() - 0.14) < 4.0 * r.max()
    assert np.allclose(scene.gravity, np.eye(dim)[-1] * -9.81)


def test_sidewall_friction_is_the_lateral_walls_own():
    """mu_side sets the two channel walls' friction; the floor and back wall keep mu_wall."""
    scene = column_collapse(3, n_grains=100, mu=0.4, mu_wall=0.3, mu_side=0.0)
    lateral = [abs(w.normal[1]) > 0.5 for w in scene.walls]
    assert sum(lateral) == 2
    assert [w.mu for w, side in zip(scene.walls, lateral, strict=True) if side] == [0.0, 0.0]
    assert all(w.mu is None for w, side in zip(scene.walls, lateral, strict=True) if not side)
    assert scene.mu_wall == 0.3


def test_sidewall_friction_does_not_change_a_rain_packing(packing_cache):
    """Rain packings are deposited alike whatever the sidewalls' friction: the channels
    of a comparison hold the same grains at the same places."""
    kw = dict(n_grains=40, width=0.05, length=0.05, height=0.05, packing="rain")
    smooth = column_collapse(3, mu_side=0.0, **kw)
    rough = column_collapse(3, mu_side=0.5, **kw)
    assert np.array_equal(smooth.positions, rough.positions)
    assert sorted(w.mu for w in rough.walls if w.mu is not None) == [0.5, 0.5]
    assert sorted(w.mu for w in smooth.walls if w.mu is not None) == [0.0, 0.0]


def test_slope_tilts_gravity():
    scene = column_collapse(3, n_grains=100, slope_deg=22.0)
    a = np.radians(22.0)
    assert np.allclose(scene.gravity, 9.81 * np.array([np.sin(a), 0.0, -np.cos(a)]))


@pytest.mark.parametrize("dim", [2, 3])
def test_rough_bed_is_fixed(dim):
    small = dict(length=0.05, height=0.035) | ({"width": 0.03} if dim == 3 else {})
    scene = ready(column_collapse(dim, n_grains=60, bed="rough", **small))
    bed = grain_groups(scene)["bed"]
    assert bed.stop > 0 and scene.fixed[bed].all() and not scene.fixed[column(scene)].any()
    d = 2.0 * scene.radii[column(scene)].mean()
    assert np.allclose(scene.positions[bed, -1], d / 2.0)
    assert scene.positions[bed, 0].max() > 0.19  # covers the bed (4 x 5 cm)
    assert scene.positions[scene.free, -1].min() > d


@pytest.mark.parametrize("packing", ["lattice", "rain"])
def test_erodible_layer_thickness(packing):
    e = 0.012
    scene = ready(
        column_collapse(
            2, n_grains=80, length=0.05, height=0.035, erodible_thickness=e, packing=packing
        )
    )
    layer = grain_groups(scene)["layer"]
    x, r = scene.positions[layer], scene.radii[layer]
    d = 2.0 * r.mean()
    front = x[:, 0] > 0.05 + 3 * d  # in front of the column
    top = np.percentile(x[front, 1] + r[front], 90)
    assert abs(top - e) < d
    assert x[:, 0].max() > 0.19  # over the whole bed length
    assert not scene.fixed[layer].any()


def test_rain_column_2d_packing_fraction():
    t0 = time.perf_counter()
    scene = ready(column_collapse(2, **RAIN_2D))
    print(f"2D rain, {scene.n_grains} discs: {time.perf_counter() - t0:.2f} s")
    d = 2.0 * scene.radii.mean()
    top = (scene.positions[:, 1] + scene.radii).max()
    phi = packing_fraction(scene, (3 * d, 3 * d), (0.20 - 3 * d, top - 4 * d))
    print(f"2D area fraction {phi:.3f}")
    assert 0.80 <= phi <= 0.87
    assert scene.mu == 0.3 and np.all(scene.velocities == 0.0)


def test_static_box_3d_packing_fraction():
    t0 = time.perf_counter()
    scene = ready(static_box(3, **BOX_3D))
    print(f"3D rain, {scene.n_grains} spheres: {time.perf_counter() - t0:.2f} s")
    assert scene.n_grains == 250 and np.isclose(2 * scene.radii.mean(), 0.01)
    assert len(scene.walls) == 5
    d = 0.01
    box = max(float(w.point.max()) for w in scene.walls)
    top = (scene.positions[:, 2] + scene.radii).max()
    phi = packing_fraction(scene, (2 * d, 2 * d, 2 * d), (box - 2 * d, box - 2 * d, top - 3 * d))
    print(f"3D volume fraction {phi:.3f}")
    assert 0.57 <= phi <= 0.66


def test_static_box_2d():
    scene = ready(static_box(2, n_grains=100, diameter=0.01))
    assert scene.n_grains == 100 and len(scene.walls) == 3
    with pytest.raises(SceneError, match="length is for a 3D box"):
        static_box(2, n_grains=100, diameter=0.01, length=0.3)
    with pytest.raises(SceneError, match="mu_side"):
        static_box(2, n_grains=100, diameter=0.01, mu_side=0.2)


def test_static_box_sidewall_friction(packing_cache):
    """mu_side sets the box's two y walls after deposition, as column_collapse does:
    the grains are where they are without it, the floor and end walls keep mu_wall."""
    kw = dict(n_grains=60, diameter=0.01, width=0.04, length=0.08, mu_wall=0.3)
    plain = static_box(3, **kw)
    rough = static_box(3, mu_side=0.23, **kw)
    assert np.array_equal(plain.positions, rough.positions)
    assert all(w.mu is None for w in plain.walls)
    side = [abs(w.normal[1]) > 0.5 for w in rough.walls]
    assert [w.mu for w, s in zip(rough.walls, side, strict=True) if s] == [0.23, 0.23]
    assert all(w.mu is None for w, s in zip(rough.walls, side, strict=True) if not s)
    with pytest.raises(SceneError, match="mu_side"):
        static_box(3, mu_side=-0.1, **kw)


def test_static_box_3d_long():
    """A box longer than wide: its end walls at x = length, sidewalls at y = width, and
    every grain settled between them."""
    scene = ready(static_box(3, n_grains=120, diameter=0.01, width=0.05, length=0.15))
    def far(axis: int) -> float:
        return max(float(w.point[axis]) for w in scene.walls if abs(w.normal[axis]) == 1.0)

    assert far(0) == pytest.approx(0.15) and far(1) == pytest.approx(0.05)
    x, r = scene.positions, scene.radii
    assert np.all(x[:, 0] - r > -1e-4) and np.all(x[:, 0] + r < 0.15 + 1e-4)
    assert np.all(x[:, 1] - r > -1e-4) and np.all(x[:, 1] + r < 0.05 + 1e-4)
    # Spread along the length, not piled in a square corner.
    assert np.ptp(x[:, 0]) > 0.1


def test_cache_hit_skips_stepping_and_corruption_rebuilds(packing_cache, monkeypatch):
    initial = cocd.box_3d(27, diameter=0.01, mu=0.0)
    first = rain_deposition(initial, solver="clarabel")
    assert not first.from_cache and first.steps > 0 and first.settled

    def no_stepping(*args, **kwargs):
        raise AssertionError("a cached packing must not step")

    monkeypatch.setattr(cocd.Stepper, "step", no_stepping)
    second = rain_deposition(initial, solver="clarabel")
    assert second.from_cache and second.steps == 0
    assert second.seconds < first.seconds
    assert np.array_equal(second.scene.positions, first.scene.positions)
    monkeypatch.undo()

    files = list(packing_cache.glob("packing-*.npz"))
    assert files
    for f in files:
        f.write_bytes(b"not an npz file")
    third = rain_deposition(initial, solver="clarabel")
    assert not third.from_cache and third.steps > 0
    assert np.allclose(third.scene.positions, first.scene.positions)


def test_deterministic_for_a_seed():
    a = column_collapse(2, n_grains=100, seed=3)
    b = column_collapse(2, n_grains=100, seed=3)
    c = column_collapse(2, n_grains=100, seed=4)
    assert np.array_equal(a.radii, b.radii) and np.array_equal(a.positions, b.positions)
    assert not np.array_equal(a.radii, c.radii)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        (dict(), "n_grains"),
        (dict(n_grains=10, diameter=0.01), "n_grains"),
        (dict(n_grains=0), "n_grains"),
        (dict(n_grains=10, dim=4), "dim"),
        (dict(n_grains=10, length=-1.0), "length"),
        (dict(n_grains=10, height=0.0), "height"),
        (dict(n_grains=10, width=0.1), "width"),
        (dict(n_grains=10, slope_deg=95.0), "slope_deg"),
        (dict(n_grains=10, polydispersity=1.5), "polydispersity"),
        (dict(n_grains=10, bed="bumpy"), "bed"),
        (dict(n_grains=10, packing="poured"), "packing"),
        (dict(n_grains=10, erodible_thickness=-0.01), "erodible_thickness"),
        (dict(n_grains=10, bed_length=0.1), "bed_length"),
        (dict(n_grains=10, density=0.0), "density"),
        (dict(n_grains=10, mu=-1.0), "mu"),
        (dict(n_grains=10, mu_side=0.2), "mu_side"),
        (dict(n_grains=10, dim=3, mu_side=-0.1), "mu_side"),
        # A side smaller than the grains the column is built of, at their diameter.
        (dict(diameter=0.004, dim=3, length=0.001), "length 0.001 m is less than a grain"),
        (dict(diameter=0.004, height=0.003), "height 0.003 m is less than a grain"),
        (dict(diameter=0.004, dim=3, width=0.002), "width 0.002 m is less than a grain"),
    ],
)
def test_bad_arguments_name_themselves(kwargs, name):
    with pytest.raises(SceneError, match=name):
        column_collapse(**kwargs)


@pytest.mark.parametrize("name", sorted(HARD_CASES))
def test_hard_case_builds_and_steps(name, checked_solutions):
    scene = ready(HARD_CASES[name]())
    record = cocd.Stepper(scene, 1e-3, solver="clarabel").step()
    assert record.status in ("optimal", "inaccurate")
    assert checked_solutions


def test_hard_case_shapes():
    heavy = HARD_CASES["heavy_on_light_1e6"]()
    assert np.isclose(heavy.masses[-1] / heavy.masses[0], 1e6)
    assert HARD_CASES["tall_stack_50"]().n_grains == 50
    wedged = HARD_CASES["wedged_grain"]()
    assert np.allclose([w.gaps(wedged.positions, wedged.radii)[0] for w in wedged.walls], 0.0)
    impact = cocd.builders.fast_impact(1.0, dt=1e-3)
    assert np.isclose(-impact.velocities[-1, -1] * 1e-3, impact.radii[-1])
    big = HARD_CASES["size_ratio_10"]()
    assert np.isclose(big.radii.max() / big.radii.min(), 10.0)
    zero = HARD_CASES["zero_gap"]()
    contacts = cocd.detect_contacts(zero)
    assert contacts.gap.size and np.all(contacts.gap == 0.0)
    jammed = HARD_CASES["jammed_box"]()
    gaps = cocd.detect_contacts(jammed).gap
    nc = int(np.count_nonzero(np.abs(gaps) < 1e-9))  # touching pairs
    assert 2 * nc > 1.5 * 3 * jammed.n_grains  # contact unknowns >> degrees of freedom
    for mu in (0.0, 1.5):
        assert cocd.builders.jammed_box(50, mu=mu).mu == mu
