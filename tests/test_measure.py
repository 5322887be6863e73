"""Measurements on constructed states with known answers: blocks of grains on a
lattice, detached grains, shear velocity fields, known energies, dilated blocks."""

from __future__ import annotations

import numpy as np
import pytest

from cocd import Scene, SceneError, Wall, measure

R = 0.005  # grain radius (m)
D = 2 * R


def block(nx, nz, ny=None, spacing=D, lift=0.0):
    """Centres of an nx x (ny x) nz block on a square lattice, lowest grains on z = 0.

    With ``spacing`` > D the lattice is dilated: centres ``spacing/2 + spacing k``.
    """
    axes = [spacing / 2 + spacing * np.arange(n) for n in (nx, ny, nz) if n is not None]
    grid = np.meshgrid(*axes, indexing="ij")
    x = np.stack([g.ravel() for g in grid], axis=1)
    x[:, -1] += lift
    return x


# -- front -------------------------------------------------------------------
def test_front_of_a_block_is_its_right_face():
    x = block(10, 6)
    assert measure.front_position(x, R) == pytest.approx(10 * D, abs=1e-12)


def test_detached_grain_far_ahead_is_not_the_front():
    x = np.vstack([block(10, 6), [[0.3, R]]])
    assert measure.front_position(x, R) == pytest.approx(10 * D, abs=1e-12)
    main = measure.main_mass(x, R)
    assert main.sum() == 60 and not main[-1]


def test_touching_grain_extends_the_front_and_gap_sets_connection():
    touching = np.vstack([block(10, 6), [[10 * D + R, R]]])
    assert measure.front_position(touching, R) == pytest.approx(11 * D, abs=1e-12)
    # A grain 0.4 D ahead: connected by default (0.5 D), not with gap = 0.1 D.
    near = np.vstack([block(10, 6), [[10 * D + 0.4 * D + R, R]]])
    assert measure.front_position(near, R) == pytest.approx(11.4 * D, abs=1e-12)
    assert measure.front_position(near, R, gap=0.1 * D) == pytest.approx(10 * D, abs=1e-12)


def test_front_of_a_scene_ignores_glued_grains():
    mass = block(4, 3, lift=D)
    glued = np.column_stack([R + D * np.arange(40), np.full(40, R)])
    x = np.vstack([mass, glued])
    fixed = np.r_[np.zeros(len(mass), bool), np.ones(40, bool)]
    scene = Scene(x, R, fixed=fixed)
    assert measure.front_position(scene) == pytest.approx(4 * D, abs=1e-12)
    # Counting the glued layer, the front is the end of the layer.
    assert measure.front_position(scene, mask=np.ones(len(x), bool)) == pytest.approx(
        40 * D, abs=1e-12
    )


def test_front_3d_along_either_horizontal_axis():
    x = block(5, 3, ny=4)
    assert measure.front_position(x, R) == pytest.approx(5 * D, abs=1e-12)
    assert measure.front_position(x, R, axis=1) == pytest.approx(4 * D, abs=1e-12)


def test_surface_front_over_an_erodible_layer():
    # A layer two grains thick over 40 diameters, a heap 10 diameters long and
    # 4 grains thick on its left: the front is the heap's right face.
    layer = block(40, 2)
    heap = block(10, 4, lift=2 * D)
    x = np.vstack([layer, heap])
    bins = np.arange(0.0, 40 * D + 1e-12, D)
    surface = np.full(40, 2 * D)
    front = measure.surface_front(x, R, x_bins=bins, surface=surface)
    assert front == pytest.approx(10 * D, abs=1e-12)
    # The layer alone carries no flow; measured against the floor it is all flow.
    assert np.isnan(measure.surface_front(layer, R, x_bins=bins, surface=surface))
    assert measure.surface_front(layer, R, x_bins=bins) == pytest.approx(40 * D, abs=1e-12)
    # A lone grain rolling on the layer 2 bins ahead is crossed, 5 bins ahead it is not.
    near = np.vstack([x, [[12.5 * D, 2 * D + R]]])
    assert measure.surface_front(near, R, x_bins=bins, surface=surface) == pytest.approx(13 * D)
    far = np.vstack([x, [[15.5 * D, 2 * D + R]]])
    assert measure.surface_front(far, R, x_bins=bins, surface=surface) == pytest.approx(10 * D)
    assert measure.surface_front(
        far, R, x_bins=bins, surface=surface, max_gap_bins=5
    ) == pytest.approx(16 * D)
    # A thicker threshold ignores the one-grain bump, not the heap.
    assert measure.surface_front(near, R, x_bins=bins, surface=surface, threshold=1.5 * D) == (
        pytest.approx(10 * D)
    )
    with pytest.raises(SceneError, match=r"surface must be a number or have shape \(40,\)"):
        measure.surface_front(x, R, x_bins=bins, surface=np.zeros(3))
    with pytest.raises(SceneError, match="threshold must be >= 0"):
        measure.surface_front(x, R, x_bins=bins, threshold=-1.0)


def test_surface_front_moves_with_the_grains_not_by_whole_bins():
    # The heap shifted by 0.3 of a bin: the front follows by 0.3 of a bin.
    bins = np.arange(0.0, 40 * D + 1e-12, D)
    for shift in (0.0, 0.3 * D, 0.45 * D):
        heap = block(10, 4) + [shift, 0.0]
        assert measure.surface_front(heap, R, x_bins=bins) == pytest.approx(10 * D + shift)


def test_runout_and_relative_runout():
    assert measure.runout(0.2, 0.5) == pytest.approx(0.3)
    assert measure.relative_runout(0.2, 0.5) == pytest.approx(1.5)
    series = measure.relative_runout(0.2, np.array([0.2, 0.3, 0.4]))
    np.testing.assert_allclose(series, [0.0, 0.5, 1.0])


# -- mass profile --------------------------------------------------------------
def test_block_has_a_flat_profile_at_its_height():
    x = np.vstack([block(10, 6), [[0.3, R]]])
    edges = np.linspace(0.0, 0.4, 41)  # one bin per column
    profile = measure.mass_profile(x, R, x_bins=edges)
    np.testing.assert_allclose(profile.height[:10], 6 * D)
    assert np.all(np.isnan(profile.height[10:]))  # the detached grain is not in the mass
    np.testing.assert_array_equal(profile.n_grains[:10], 6)
    np.testing.assert_allclose(profile.solid_volume[:10], 6 * np.pi * R**2)
    everything = measure.mass_profile(x, R, x_bins=edges, connected=False)
    assert everything.height[30] == pytest.approx(D)


def test_step_profile_and_3d_cells():
    # Two columns of 6 layers, then 8 columns of 3 layers.
    x = np.vstack([block(2, 6), block(8, 3) + np.array([2 * D, 0.0])])
    profile = measure.mass_profile(x, R, x_bins=np.linspace(0.0, 10 * D, 11))
    np.testing.assert_allclose(profile.height, [6 * D] * 2 + [3 * D] * 8)

    x3 = block(4, 3, ny=2)
    cells = measure.mass_profile(
        x3, R, x_bins=np.linspace(0, 4 * D, 5), y_bins=np.linspace(0, 4 * D, 5)
    )
    assert cells.height.shape == (4, 4)
    np.testing.assert_allclose(cells.height[:, :2], 3 * D)
    assert np.all(np.isnan(cells.height[:, 2:]))
    np.testing.assert_allclose(cells.mean_height, 3 * D)


# -- volume --------------------------------------------------------------------
def test_volume_of_a_block_is_its_bounding_box():
    x = block(10, 6)
    assert measure.granular_volume(x, R) == pytest.approx(10 * D * 6 * D, rel=1e-12)
    # Bins half a diameter wide leave every other bin empty; the surface bridges them.
    fine = np.linspace(0.0, 10 * D, 21)
    assert measure.granular_volume(x, R, x_bins=fine) == pytest.approx(60 * D**2, rel=1e-12)
    x3 = block(5, 3, ny=4)
    assert measure.granular_volume(x3, R) == pytest.approx(5 * 4 * 3 * D**3, rel=1e-12)
    cells = np.linspace(0, 6 * D, 7)
    assert measure.granular_volume(x3, R, x_bins=cells, y_bins=cells) == pytest.approx(60 * D**3)


def test_relative_volume_variation_of_dilated_blocks():
    x = block(10, 6)
    v0 = measure.granular_volume(x, R)
    s = 1.1
    # A copy scaled by s (radii too): a_V = s^d - 1.
    assert measure.relative_volume_variation(
        measure.granular_volume(s * x, s * R), v0
    ) == pytest.approx(0.21)
    # The lattice spacing grows by s, the grains do not: length a (nx - 1) + D,
    # height a (nz - 1/2) + R with a = s D.
    a = s * D
    expected = (a * 9 + D) * (a * 5.5 + R) / v0 - 1.0
    dilated = block(10, 6, spacing=a)
    assert measure.relative_volume_variation(
        measure.granular_volume(dilated, R), v0
    ) == pytest.approx(expected)
    assert expected == pytest.approx(0.109 * 0.0655 / 0.006 - 1.0, abs=1e-12)
    x3 = block(5, 3, ny=4)
    v3 = measure.granular_volume(x3, R)
    assert measure.relative_volume_variation(
        measure.granular_volume(s * x3, s * R), v3
    ) == pytest.approx(0.331)
    series = measure.relative_volume_variation([v0, 1.05 * v0], v0)
    np.testing.assert_allclose(series, [0.0, 0.05])


# -- velocity profiles -----------------------------------------------------------
def sheared_column(gamma, z0=0.0):
    """3 x 10 block, u_x = gamma (z - z0) above z0 and 0 below; a fast grain far away."""
    x = block(3, 10)
    u = np.where(x[:, 1] > z0, gamma * (x[:, 1] - z0), 0.0)
    v = np.column_stack([u, np.zeros(len(x))])
    x = np.vstack([x, [[0.5, R]]])
    v = np.vstack([v, [[5.0, 0.0]]])
    return x, v


def test_linear_shear_profile_per_bin():
    gamma = 10.0
    x, v = sheared_column(gamma)
    z_bins = np.linspace(0.0, 12 * D, 13)
    u = measure.velocity_profile(x, v, station_x=1.5 * D, half_width=1.5 * D, z_bins=z_bins)
    np.testing.assert_allclose(u[:10], gamma * (R + D * np.arange(10)))
    assert np.all(np.isnan(u[10:]))
    # Two layers per bin: the mean of the two layers' velocities, gamma (R + D/2 + 2 D k).
    u2 = measure.velocity_profile(x, v, station_x=1.5 * D, half_width=1.5 * D, z_bins=z_bins[::2])
    np.testing.assert_allclose(u2[:5], gamma * (D + 2 * D * np.arange(5)))


def test_static_flowing_interface_at_known_height():
    z0 = 4 * D
    x, v = sheared_column(10.0, z0=z0)
    z_bins = np.linspace(0.0, 10 * D, 11)
    common = {"station_x": 1.5 * D, "half_width": 1.5 * D, "z_bins": z_bins}
    assert measure.static_flowing_interface(x, v, bed_top=6 * D, **common) == pytest.approx(z0)
    # A bed thinner than the static layer: capped at its top.
    assert measure.static_flowing_interface(x, v, bed_top=2.5 * D, **common) == pytest.approx(
        2.5 * D
    )
    # Everything moving: nothing static, h_sf is the base.
    moving = v + np.array([0.5, 0.0])
    assert measure.static_flowing_interface(x, moving, bed_top=6 * D, **common) == 0.0
    # A station with no grain: NaN.
    empty = measure.static_flowing_interface(x, v, bed_top=6 * D, **{**common, "station_x": 1.0})
    assert np.isnan(empty)


# -- energies ---------------------------------------------------------------------
def test_energies_of_a_known_configuration():
    scene = Scene(
        [[0.0, 0.1], [0.1, 0.2], [0.5, R]],
        R,
        density=2000.0,
        velocities=[[1.0, 0.0], [0.0, 2.0], [0.0, 0.0]],
        angular_velocities=[3.0, 0.0, 0.0],
        fixed=np.array([False, False, True]),
        walls=[Wall([0.0, 0.0], [0.0, 1.0])],
    )
    m = 2000.0 * np.pi * R**2
    ek = 0.5 * m * (1.0 + 4.0) + 0.5 * (0.5 * m * R**2) * 9.0
    assert measure.kinetic_energy(scene) == pytest.approx(ek, rel=1e-12)
    assert measure.potential_energy(scene) == pytest.approx(m * 9.81 * 0.3, rel=1e-12)
    bed = np.array([True, False, True])  # the glued grain is left out
    ratio = measure.bed_energy_ratio(scene, bed)
    assert ratio == pytest.approx((0.5 * m + 0.5 * 0.5 * m * R**2 * 9.0) / (m * 9.81 * 0.1))
    above = measure.bed_energy_ratio(scene, bed, reference_height=0.05)
    assert above == pytest.approx(ratio * 2.0)


# -- invalid input -----------------------------------------------------------------
@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: measure.front_position(np.zeros((3, 4)), R), "shape"),
        (lambda: measure.front_position([[0.0, np.nan]], R), "finite"),
        (lambda: measure.front_position(block(2, 2), [R, R]), "radii must be"),
        (lambda: measure.front_position(block(2, 2), -R), "radii must be > 0"),
        (lambda: measure.front_position(block(2, 2)), "radii are required"),
        (lambda: measure.front_position(block(2, 2), R, axis=1), "axis"),
        (lambda: measure.front_position(block(2, 2), R, gap=-1.0), "gap must be >= 0"),
        (lambda: measure.front_position(block(2, 2), R, mask=np.zeros(4, bool)), "no grain"),
        (lambda: measure.front_position(block(2, 2), R, mask=[1, 0, 1, 1]), "boolean"),
        (lambda: measure.mass_profile(block(2, 2), R, x_bins=[0.0, 0.0]), "strictly increasing"),
        (lambda: measure.mass_profile(block(2, 2), R, x_bins=[0.1], y_bins=None), "at least 2"),
        (
            lambda: measure.mass_profile(block(2, 2), R, x_bins=[0, 1], y_bins=[0, 1]),
            "3D scenes only",
        ),
        (lambda: measure.granular_volume(block(4, 2), R, x_bins=[0.0, D]), "do not cover"),
        (lambda: measure.granular_volume(block(4, 2), R, width=0.1), "3D scenes only"),
        (
            lambda: measure.velocity_profile(block(2, 2), station_x=0, half_width=1, z_bins=[0, 1]),
            "velocities",
        ),
        (
            lambda: measure.velocity_profile(
                block(2, 2), np.zeros((4, 2)), station_x=0, half_width=0, z_bins=[0, 1]
            ),
            "half_width",
        ),
        (
            lambda: measure.static_flowing_interface(
                block(2, 2),
                np.zeros((4, 2)),
                station_x=0,
                half_width=1,
                z_bins=[0, 1],
                bed_top=np.nan,
            ),
            "finite",
        ),
        (lambda: measure.relative_volume_variation(1.0, 0.0), "V0 must be > 0"),
        (lambda: measure.relative_volume_variation(-1.0, 1.0), "V must be >= 0"),
        (lambda: measure.relative_runout(-0.1, 0.2), "L0 must be > 0"),
        (lambda: measure.runout(0.1, np.inf), "finite"),
        (lambda: measure.bed_energy_ratio(Scene(block(2, 2), R), np.ones(3, bool)), "shape"),
        (
            lambda: measure.bed_energy_ratio(
                Scene(block(2, 2), R), np.ones(4, bool), reference_height=1.0
            ),
            "reference_height",
        ),
    ],
)
def test_invalid_input_raises_with_a_message(call, message):
    with pytest.raises(SceneError, match=message):
        call()
