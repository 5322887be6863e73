"""No missed contacts: the motion-following margin, the end-of-step check and its policy."""

from __future__ import annotations

import warnings

import h5py
import numpy as np
import pytest
from conftest import jittered_lattice

import cocd
from cocd import Scene, Wall, detect_contacts
from cocd.config import ConfigError, parse_config
from cocd.contacts import penetration
from cocd.errors import PenetrationError, PenetrationWarning, ProblemError
from cocd.io.runfile import RunFile
from cocd.runs import run

R = 0.01
DT = 1e-3


def moving_lattice(dim, seed, fast=3):
    """Grains on a jittered lattice with random velocities, a few of them fast, a
    fixed grain and two walls."""
    rng = np.random.default_rng(seed)
    shape = (7, 7) if dim == 2 else (4, 4, 4)
    _, radii, x = jittered_lattice(rng, shape, R, (0.9, 1.1), 2.6, 0.1)
    n = len(radii)
    v = rng.normal(scale=1.0, size=(n, dim))
    v[rng.choice(n, fast, replace=False)] *= 20.0
    fixed = np.zeros(n, dtype=bool)
    fixed[0] = True
    up = np.eye(dim)[-1]
    walls = [Wall(-1.2 * R * up, up), Wall(-1.3 * R * np.eye(dim)[0], np.eye(dim)[0])]
    return Scene(x, radii, velocities=v, fixed=fixed, walls=walls)


def expected_pairs(scene, d_max, v, dt, skin):
    """The potential contacts by an O(n^2) loop over the margin's definition."""
    x, r, fixed = scene.positions, scene.radii, scene.fixed
    v = np.where(fixed[:, None], 0.0, v)
    found = set()
    for i in range(scene.n_grains):
        for j in range(i + 1, scene.n_grains):
            if fixed[i] and fixed[j]:
                continue
            gap = np.linalg.norm(x[i] - x[j]) - r[i] - r[j]
            if gap < d_max + skin * dt * np.linalg.norm(v[i] - v[j]):
                found.add((i, j))
    for k, wall in enumerate(scene.walls):
        for i in np.flatnonzero(~fixed):
            gap = float((x[i] - wall.point) @ wall.normal) - r[i]
            if gap < d_max + skin * dt * max(0.0, -float(v[i] @ wall.normal)):
                found.add((int(i), -1 - k))
    return found


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_margin_follows_the_relative_free_velocities(dim, seed):
    scene = moving_lattice(dim, seed)
    v = scene.velocities
    for skin in (0.0, 1.0, 2.0):
        contacts = detect_contacts(scene, 0.2 * R, velocities=v, dt=DT, skin=skin)
        got = set(zip(contacts.i.tolist(), contacts.j.tolist(), strict=True))
        assert got == expected_pairs(scene, 0.2 * R, v, DT, skin)
    # A uniform motion adds no margin: only relative velocities close gaps.
    still = detect_contacts(scene, 0.2 * R)
    drift = Scene(scene.positions, scene.radii, velocities=np.ones_like(v))
    moving = detect_contacts(drift, 0.2 * R, velocities=np.ones_like(v), dt=DT)
    assert moving.nc == detect_contacts(drift, 0.2 * R).nc
    assert still.nc <= detect_contacts(scene, 0.2 * R, velocities=v, dt=DT).nc


def brute_penetration(scene, contacts, start):
    """Deepest overlap: potential contacts and walls at the end, other pairs along the
    straight path (sampled finely); the number of other pairs that touched."""
    x, r = scene.positions, scene.radii
    keys = set(zip(contacts.i.tolist(), contacts.j.tolist(), strict=True))
    worst, missed = 0.0, 0
    taus = np.linspace(0.0, 1.0, 20001)
    for i in range(scene.n_grains):
        for j in range(i + 1, scene.n_grains):
            if scene.fixed[i] and scene.fixed[j]:
                continue
            if (i, j) in keys:
                gap = np.linalg.norm(x[i] - x[j]) - r[i] - r[j]
            else:
                path = (start[i] - start[j]) + taus[:, None] * (
                    (x[i] - x[j]) - (start[i] - start[j])
                )
                gap = np.linalg.norm(path, axis=1).min() - r[i] - r[j]
                missed += gap < 0.0
            worst = max(worst, -gap / min(r[i], r[j]))
    for k, wall in enumerate(scene.walls):
        for i in np.flatnonzero(scene.free):
            gap = float((x[i] - wall.point) @ wall.normal) - r[i]
            missed += gap < 0.0 and (int(i), -1 - k) not in keys
            worst = max(worst, -gap / r[i])
    return worst, missed


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_penetration_against_a_brute_force_sweep(dim, seed):
    scene = moving_lattice(dim, seed, fast=4)
    contacts = detect_contacts(scene, 0.2 * R)  # no margin: fast grains go through
    start = scene.positions.copy()
    scene.positions[scene.free] += 2 * DT * scene.velocities[scene.free]
    pen = penetration(scene, contacts, start)
    worst, missed = brute_penetration(scene, contacts, start)
    assert pen.depth == pytest.approx(worst, rel=1e-3, abs=1e-9)
    assert pen.missed == missed
    assert pen.missed_i.size == missed
    assert np.all(pen.missed_gap >= 0.2 * R - 1e-12)  # they were beyond d_max


def three_in_a_line(v=20.0, gap=0.6 * R):
    """C (fast) touching B (at rest), A at rest a gap beyond B. C's impact throws B
    into A within the step, though B and A have no relative free velocity."""
    return Scene(
        positions=[[0.0, 0.0], [2 * R, 0.0], [4 * R + gap, 0.0]],
        radii=R,
        velocities=[[v, 0.0], [0.0, 0.0], [0.0, 0.0]],
        gravity=(0.0, 0.0),
    )


def test_a_grain_thrown_into_another_is_redone_by_default():
    scene = three_in_a_line()
    record = cocd.Stepper(scene, DT, solver="clarabel").step()
    assert record.redos == 1
    assert record.penetration <= 1e-6 and record.missed_contacts == 0
    # The step taken again is the one every pair being a potential contact gives.
    reference = three_in_a_line()
    cocd.Stepper(reference, DT, solver="clarabel", d_max=10 * R).step()
    np.testing.assert_allclose(scene.velocities, reference.velocities, atol=1e-6)
    np.testing.assert_allclose(scene.positions, reference.positions, atol=1e-9)
    # Momentum is shared: B and C move together, A is pushed.
    assert scene.velocities[2, 0] > 0.0


def test_raise_names_the_step_the_pair_and_the_depth():
    scene = three_in_a_line()
    before = scene.positions.copy()
    stepper = cocd.Stepper(scene, DT, solver="clarabel", on_penetration="raise")
    with pytest.raises(PenetrationError, match=r"step 1 .*grains 1 and 2 overlap by 0\.004 m"):
        stepper.step()
    np.testing.assert_array_equal(scene.positions, before)  # the step is not taken
    assert scene.time == 0.0 and stepper.step_count == 0


def test_warn_and_record_let_the_step_through_and_say_so():
    scene = three_in_a_line()
    with pytest.warns(PenetrationWarning, match="grains 1 and 2 overlap"):
        record = cocd.Stepper(scene, DT, solver="clarabel", on_penetration="warn").step()
    assert record.penetration == pytest.approx(0.4, rel=1e-6)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        stepper = cocd.Stepper(three_in_a_line(), DT, solver="clarabel", on_penetration="record")
        record = stepper.step()
    assert record.missed_contacts == 1 and record.penetration == pytest.approx(0.4, rel=1e-6)
    assert stepper.stats().penetration.iloc[0] == record.penetration


def test_a_fast_grain_does_not_tunnel_through_another_unnoticed():
    """Apart again at the end of the step: only the path shows the pass-through."""

    def scene():
        return Scene([[0.0, 0.0], [5 * R, 0.0]], R, velocities=[[100.0, 0.0], [0.0, 0.0]],
                     gravity=(0.0, 0.0))  # fmt: skip

    # A user's fixed threshold without margin: the pair is not a potential contact.
    stepper = cocd.Stepper(scene(), DT, solver="clarabel", d_max=1e-4, on_penetration="record")
    record = stepper.step()
    assert stepper.scene.positions[0, 0] > stepper.scene.positions[1, 0] + 2 * R  # went through
    assert record.missed_contacts == 1 and record.penetration == pytest.approx(2.0)
    # The default policy takes the step again with the pair as a potential contact.
    stepper = cocd.Stepper(scene(), DT, solver="clarabel", d_max=1e-4)
    record = stepper.step()
    x = stepper.scene.positions[:, 0]
    assert record.redos == 1 and x[1] - x[0] >= 2 * R - 1e-9
    # They meet at the end of the step: the gap of 3 R closes, momentum is kept.
    np.testing.assert_allclose(stepper.scene.velocities[:, 0], [65.0, 35.0], rtol=1e-6)
    # And the default margin sees it coming: no redo.
    assert cocd.Stepper(scene(), DT, solver="clarabel").step().redos == 0


def test_a_fast_grain_against_a_wall():
    def scene():
        return Scene([[0.0, 5 * R]], R, velocities=[[0.0, -100.0]], walls=[Wall((0, 0), (0, 1))])

    with pytest.raises(PenetrationError, match="grain 0 penetrates wall 0"):
        cocd.Stepper(scene(), DT, solver="clarabel", d_max=1e-4, on_penetration="raise").step()
    stepper = cocd.Stepper(scene(), DT, solver="clarabel", d_max=1e-4)
    record = stepper.step()
    assert record.redos == 1 and record.penetration <= 1e-6
    assert stepper.scene.positions[0, 1] == pytest.approx(R, abs=1e-9)


def test_an_inaccurate_answer_is_not_blamed_on_the_margin():
    """A potential contact left overlapping: a redo with a wider margin cannot help."""
    scene = Scene([[0.0, 1.5 * R]], R, velocities=[[0.0, -10.0]], walls=[Wall((0, 0), (0, 1))],
                  mu=0.0)  # fmt: skip
    stepper = cocd.Stepper(scene, DT, solver="pgs", tol=0.5, max_iter=1, penetration_tol=0.0,
                           residual_factor=None)  # fmt: skip
    try:
        record = stepper.step()
    except PenetrationError as exc:
        assert "a potential contact" in str(exc) and "tighten tol" in str(exc)
    else:  # one sweep answered exactly: nothing overlaps
        assert record.penetration <= 1e-12


def test_policy_options_are_checked():
    scene = three_in_a_line()
    for kwargs, match in [
        ({"on_penetration": "ignore"}, "on_penetration must be one of"),
        ({"penetration_tol": -1.0}, "penetration_tol"),
        ({"skin": float("nan")}, "skin"),
        ({"d_max": -1.0}, "d_max"),
        ({"max_redos": -1}, "max_redos"),
    ]:
        with pytest.raises(ProblemError, match=match):
            cocd.Stepper(scene, DT, **kwargs)
    with pytest.raises(ConfigError, match=r"run\.on_penetration"):
        parse_config({"builder": "column_2d", "run": {"on_penetration": "ignore"}})


def test_run_file_and_stats_record_the_penetration(tmp_path):
    config = parse_config(
        {"builder": "column_2d", "params": {"n_grains": 40}, "run": {"steps": 4, "frame_every": 2}}
    )
    summary = run(config, tmp_path)
    with RunFile(summary.path) as rf:
        stats = rf.stats()
    for name in ("penetration", "missed_contacts", "redos", "redo_time"):
        assert name in stats.columns
    assert stats.penetration.notna().all() and (stats.penetration <= 1e-2).all()
    # A run file written before these statistics existed reads as "not measured".
    with h5py.File(summary.path, "a") as f:
        for name in ("penetration", "missed_contacts", "redos", "redo_time"):
            del f[f"stats/{name}"]
    with RunFile(summary.path) as rf:
        old = rf.stats()
    assert old.penetration.isna().all() and (old.redos == 0).all()
    config = parse_config(
        {"builder": "column_2d", "params": {"n_grains": 40}, "run": {"steps": 6, "frame_every": 2}}
    )
    run(config, tmp_path, resume=True)
    with RunFile(summary.path) as rf:
        stats = rf.stats()
    assert len(stats) == 6 and stats.penetration.iloc[4:].notna().all()


def test_a_step_taken_again_starts_from_the_failed_attempts_impulses(monkeypatch):
    """The redo warm-starts from the attempt it replaces (its contacts but for the pair
    the wider margin adds), not from the step before (none here)."""
    import cocd.stepper as stepper_module

    seen = []
    real = stepper_module.warm_start

    def spy(previous, keys, contact_dim):
        seen.append((previous, keys.copy()))
        return real(previous, keys, contact_dim)

    monkeypatch.setattr(stepper_module, "warm_start", spy)
    stepper = cocd.Stepper(three_in_a_line(), DT, solver="apgd", tol=1e-10)
    record = stepper.step()
    assert record.redos == 1 and record.penetration <= 1e-6
    (first, first_keys), (again, again_keys) = seen
    assert first is None  # the first step of the run
    assert again is not None and np.array_equal(again[0], first_keys)
    assert again[1].shape == (first_keys.size, 2) and np.abs(again[1]).max() > 0.0
    assert set(first_keys) < set(again_keys)  # the pair that went through is added
