"""Contact detection, contact frames and the contact Jacobian."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import jittered_lattice

from cocd import Scene, SceneError, Wall, assemble, detect_contacts
from cocd.contacts import contact_jacobian, dof_layout, unique_ints
from cocd.problem import generalized_velocity

R0 = 0.01
WALL_MU = 0.7


def lattice_scene(dim, *, seed, mu=0.3, mu_wall=0.2, wall_mu=WALL_MU, moving=False):
    """64 grains on a jittered lattice over a floor, by a tilted wall; 3 bottom grains fixed.

    Neighbour gaps are spread over [0.02, 1.0] R0, so about half fall below the
    default ``d_max`` (0.5 R0). The fixed grains (the largest, at the far end of
    the bottom row) are close to each other and to the floor.
    """
    rng = np.random.default_rng(seed)
    shape = (8, 8) if dim == 2 else (4, 4, 4)
    idx, radii, x = jittered_lattice(rng, shape, R0, (0.8, 1.2), 2.52, 0.05)
    n = len(radii)
    fixed = (idx[:, -1] == 0) & (idx[:, 0] >= shape[0] - 3) & np.all(idx[:, 1:-1] == 0, axis=1)
    radii[fixed] = 1.2 * R0
    up = np.eye(dim)[-1]
    side = np.eye(dim)[0] + 0.1 * up
    walls = [Wall(-1.3 * R0 * up, up), Wall(-1.25 * R0 * np.eye(dim)[0], side, mu=wall_mu)]
    kwargs = {}
    if moving:
        kwargs["velocities"] = rng.normal(size=(n, dim))
        kwargs["angular_velocities"] = rng.normal(size=(n,) if dim == 2 else (n, 3)) / R0
    return Scene(x, radii, fixed=fixed, walls=walls, mu=mu, mu_wall=mu_wall, **kwargs)


def brute_force(scene, d_max):
    """Every potential contact by an O(n^2) loop: {(i, j): (gap, normal, mu)}."""
    x, r, fixed = scene.positions, scene.radii, scene.fixed
    found = {}
    for i in range(scene.n_grains):
        for j in range(i + 1, scene.n_grains):
            if fixed[i] and fixed[j]:
                continue
            delta = x[i] - x[j]
            dist = np.sqrt(np.sum(delta**2))
            if dist - r[i] - r[j] < d_max:
                found[(i, j)] = (dist - r[i] - r[j], delta / dist, scene.mu)
    for k, wall in enumerate(scene.walls):
        for i in np.flatnonzero(~fixed):
            gap = float(np.dot(x[i] - wall.point, wall.normal)) - r[i]
            if gap < d_max:
                found[(int(i), -1 - k)] = (gap, wall.normal, scene.wall_friction(k))
    return found


def as_dict(contacts):
    """{(i, j): index in the contact set}."""
    return {
        (int(i), int(j)): a for a, (i, j) in enumerate(zip(contacts.i, contacts.j, strict=True))
    }


def frames(contacts):
    """Normal then tangents, shape (nc, d, d)."""
    return np.concatenate([contacts.normal[:, None, :], contacts.tangents], axis=1)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("d_max", [None, 0.2 * R0, 0.0])
def test_detection_matches_brute_force(dim, d_max):
    """Exactly the pairs with gap < d_max, with the right gaps, normals, mu and radii."""
    scene = lattice_scene(dim, seed=dim)
    contacts = detect_contacts(scene, d_max)
    expected_d_max = 0.5 * scene.radii.mean() if d_max is None else d_max
    assert contacts.d_max == expected_d_max
    expected = brute_force(scene, expected_d_max)
    got = as_dict(contacts)
    assert set(got) == set(expected)
    assert contacts.nc == len(expected)
    for pair, (gap, normal, mu) in expected.items():
        a = got[pair]
        assert contacts.gap[a] == pytest.approx(gap, abs=1e-15)
        np.testing.assert_allclose(contacts.normal[a], normal, atol=1e-14)
        assert contacts.mu[a] == mu
        assert contacts.radius_i[a] == scene.radii[pair[0]]
        assert contacts.radius_j[a] == (scene.radii[pair[1]] if pair[1] >= 0 else 0.0)
    np.testing.assert_allclose(np.linalg.norm(contacts.normal, axis=1), 1.0, atol=1e-14)
    np.testing.assert_array_equal(contacts.is_wall, contacts.j < 0)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_detection_with_margins_matches_brute_force(dim, seed):
    """With velocities and reaches: exactly the pairs whose gap is below
    ``d_max + reach_i + reach_j + skin dt |v_i - v_j|`` (fixed grains at rest), whatever
    the spread of speeds: a bed of fixed grains under a falling mass, a few fast
    grains, a coherent drift."""
    scene = lattice_scene(dim, seed=seed)
    n, rng = scene.n_grains, np.random.default_rng(10 + seed)
    v = rng.normal(scale=0.3, size=(n, dim)) + np.array([2.0, *[0.0] * (dim - 2), -1.5])
    v[rng.choice(n, 3, replace=False)] *= 20.0  # a few fast grains
    v[scene.fixed] = 0.0
    reach = np.where(rng.random(n) < 0.2, 0.3 * R0, 0.0)
    d_max, dt, skin = 0.1 * R0, 2e-3, 2.0
    contacts = detect_contacts(scene, d_max, velocities=v, dt=dt, skin=skin, reach=reach)
    x, r, fixed = scene.positions, scene.radii, scene.fixed
    expected = set()
    for i in range(n):
        for j in range(i + 1, n):
            if fixed[i] and fixed[j]:
                continue
            gap = np.linalg.norm(x[i] - x[j]) - r[i] - r[j]
            margin = reach[i] + reach[j] + skin * dt * np.linalg.norm(v[i] - v[j])
            if gap < d_max + margin:
                expected.add((i, j))
        for k, wall in enumerate(scene.walls):
            if not fixed[i]:
                gap = float(np.dot(x[i] - wall.point, wall.normal)) - r[i]
                approach = max(0.0, -float(v[i] @ wall.normal))
                if gap < d_max + reach[i] + skin * dt * approach:
                    expected.add((i, -1 - k))
    assert set(as_dict(contacts)) == expected
    assert len(expected) > contacts.nc // 2 > 0


@pytest.mark.parametrize("dim", [2, 3])
def test_detection_covers_every_kind_and_skips_fixed_pairs(dim):
    """Grain-grain, grain-fixed and both walls are found; fixed-fixed and fixed-wall are not."""
    scene = lattice_scene(dim, seed=dim)
    d_max = 0.5 * scene.radii.mean()
    contacts = detect_contacts(scene)
    fixed = scene.fixed
    i, j = contacts.i, contacts.j
    grain = j >= 0
    assert np.any(grain & ~fixed[i] & ~fixed[np.maximum(j, 0)])
    assert np.any(grain & (fixed[i] ^ fixed[np.maximum(j, 0)]))
    assert np.any(j == -1) and np.any(j == -2)
    assert not np.any(grain & fixed[i] & fixed[np.maximum(j, 0)])
    assert not np.any(~grain & fixed[i])
    # The lattice really has close fixed-fixed pairs and fixed grains near the floor.
    x, r = scene.positions, scene.radii
    f = np.flatnonzero(fixed)
    ff_gaps = [np.linalg.norm(x[a] - x[b]) - r[a] - r[b] for a in f for b in f if a < b]
    assert min(ff_gaps) < d_max
    assert np.any(scene.walls[0].gaps(x[f], r[f]) < d_max)


@pytest.mark.parametrize("dim", [2, 3])
def test_keys_are_sorted_unique_and_stable(dim):
    """Keys increase strictly, and a pair keeps its key when the grains move."""
    scene = lattice_scene(dim, seed=10 + dim)
    before = detect_contacts(scene)
    assert np.all(np.diff(before.keys) > 0)

    rng = np.random.default_rng(5)
    tiny = scene.copy()
    tiny.positions += 1e-9 * R0 * rng.normal(size=tiny.positions.shape)
    same = detect_contacts(tiny)
    np.testing.assert_array_equal(same.keys, before.keys)
    np.testing.assert_array_equal(same.i, before.i)
    np.testing.assert_array_equal(same.j, before.j)

    moved = scene.copy()
    moved.positions += 0.05 * R0 * rng.normal(size=moved.positions.shape)
    after = detect_contacts(moved)
    old, new = as_dict(before), as_dict(after)
    assert set(old) != set(new)  # some contacts appeared or vanished
    common = set(old) & set(new)
    assert len(common) > 0.8 * len(old)
    for pair in common:
        assert before.keys[old[pair]] == after.keys[new[pair]]


@pytest.mark.parametrize("dim", [2, 3])
def test_keys_are_injective_over_all_pairs(dim):
    """With every pair detected, grain-grain and grain-wall keys are all distinct."""
    rng = np.random.default_rng(3)
    n = 6
    x = np.arange(n)[:, None] * np.eye(dim)[0] * 3.0 + 10.0 * np.eye(dim)[-1]
    walls = [Wall(np.zeros(dim), np.eye(dim)[-1]), Wall(np.zeros(dim), np.eye(dim)[-1] + 0.1)]
    scene = Scene(x, 1.0, walls=walls)
    everything = detect_contacts(scene, d_max=1e3)
    assert everything.nc == n * (n - 1) // 2 + 2 * n
    assert np.unique(everything.keys).size == everything.nc
    wall_keys = set(everything.keys[everything.is_wall].tolist())
    assert wall_keys.isdisjoint(everything.keys[~everything.is_wall].tolist())
    # A shuffle of positions keeps the key of every (i, j).
    scene.positions = 10.0 * np.eye(dim)[-1] + rng.uniform(0, 20, (n, dim))
    again = detect_contacts(scene, d_max=1e3)
    assert as_dict(again).keys() == as_dict(everything).keys()
    for pair, a in as_dict(again).items():
        assert again.keys[a] == everything.keys[as_dict(everything)[pair]]


def frames_for_normals(normals):
    """Contact frames of one grain facing walls with the given normals."""
    dim = normals.shape[1]
    walls = [Wall(-1.5 * n, n) for n in normals]
    scene = Scene(np.zeros((1, dim)), 1.0, walls=walls)
    contacts = detect_contacts(scene, d_max=1.0)
    assert contacts.nc == len(normals)
    return contacts, frames(contacts)


SPECIAL_3D = [
    (0.0, 0.0, -1.0),
    (0.0, 0.0, 1.0),
    (1e-9, -2e-9, -1.0),
    (1e-9, 2e-9, 1.0),
    (-1e-13, 0.0, -1.0),
    (0.3, -0.2, -1.0),
    (1.0, 0.0, 0.0),
    (0.0, -1.0, 0.0),
    (1.0, 1.0, -1e-12),
    (1.0, 1.0, 1e-12),
]


@pytest.mark.parametrize("dim", [2, 3])
def test_frames_are_right_handed_orthonormal(dim):
    """(n, t...) is orthonormal with determinant +1, including normals near -e_z and +e_z."""
    rng = np.random.default_rng(7)
    normals = rng.normal(size=(40, dim))
    if dim == 3:
        normals = np.vstack([normals, SPECIAL_3D])
    else:
        normals = np.vstack([normals, [(0.0, -1.0), (0.0, 1.0), (-1.0, 0.0), (1e-12, -1.0)]])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    contacts, F = frames_for_normals(normals)
    assert contacts.tangents.shape == (len(normals), dim - 1, dim)
    eye = np.broadcast_to(np.eye(dim), F.shape)
    np.testing.assert_allclose(F @ np.swapaxes(F, 1, 2), eye, atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(F), 1.0, atol=1e-14)
    # Every wall normal appears as some contact's normal (detection sorts by key).
    np.testing.assert_allclose(
        np.sort(contacts.normal, axis=0), np.sort(normals, axis=0), atol=1e-15
    )
    if dim == 2:
        np.testing.assert_array_equal(
            contacts.tangents[:, 0], np.stack([-contacts.normal[:, 1], contacts.normal[:, 0]], 1)
        )


def test_tangents_continuous_near_minus_z():
    """Tangents vary continuously as the normal approaches (0, 0, -1) from several sides."""
    eps = 1e-7
    normals = np.array([(0, 0, -1.0), (eps, 0, -1.0), (0, eps, -1.0), (-eps, -eps, -1.0)])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    contacts, _ = frames_for_normals(normals)
    order = np.argsort(contacts.j)[::-1]  # wall k is j = -1 - k
    t = contacts.tangents[order]
    assert np.max(np.abs(t - t[0])) < 1e-6


def cross2(w, r):
    """2D cross product of a scalar spin with a vector: w (-r_y, r_x)."""
    return w[:, None] * np.stack([-r[:, 1], r[:, 0]], axis=1)


def direct_relative_velocity(scene, contacts):
    """(v_i + w_i x r_i - v_j - w_j x r_j) in the contact frame, normal first."""
    v = np.where(scene.fixed[:, None], 0.0, scene.velocities)
    w = scene.angular_velocities
    w = np.where(scene.fixed, 0.0, w) if scene.dim == 2 else np.where(scene.fixed[:, None], 0, w)
    i, j, n = contacts.i, contacts.j, contacts.normal
    wall = j < 0
    jj = np.maximum(j, 0)
    r_i = -scene.radii[i, None] * n
    r_j = scene.radii[jj, None] * n
    cross = cross2 if scene.dim == 2 else np.cross
    vel_i = v[i] + cross(w[i], r_i)
    vel_j = np.where(wall[:, None], 0.0, v[jj] + cross(w[jj], r_j))
    return np.einsum("akd,ad->ak", frames(contacts), vel_i - vel_j)


@pytest.mark.parametrize("dim", [2, 3])
def test_jacobian_gives_relative_velocity(dim):
    """H u equals the contact-point relative velocity, for every kind of contact."""
    scene = lattice_scene(dim, seed=20 + dim, moving=True)
    contacts = detect_contacts(scene)
    problem = assemble(scene, contacts, 1e-3)
    u = generalized_velocity(scene, frictionless=False)
    assert u.size == scene.n_free * (3 if dim == 2 else 6)
    got = (problem.H @ u).reshape(contacts.nc, dim)
    expected = direct_relative_velocity(scene, contacts)
    scale = np.abs(expected).max()
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-13 * scale)
    # The set has every kind of contact, and the check is not vacuous.
    fixed_j = np.where(contacts.j >= 0, scene.fixed[np.maximum(contacts.j, 0)], False)
    kinds = {
        "free-free": ~scene.fixed[contacts.i] & ~fixed_j & (contacts.j >= 0),
        "free-fixed": scene.fixed[contacts.i] ^ fixed_j,
        "wall": contacts.j < 0,
    }
    for name, mask in kinds.items():
        assert mask.sum() >= 2, name
        assert np.abs(expected[mask]).min() > 0.0, name


@pytest.mark.parametrize("dim", [2, 3])
def test_jacobian_pieces_match_assemble(dim):
    """dof_layout + contact_jacobian give assemble's H; fixed grains have no unknowns."""
    scene = lattice_scene(dim, seed=30 + dim)
    contacts = detect_contacts(scene)
    first, per_grain = dof_layout(scene, frictionless=False)
    assert per_grain == (3 if dim == 2 else 6)
    np.testing.assert_array_equal(first[scene.fixed], -1)
    np.testing.assert_array_equal(first[scene.free], per_grain * np.arange(scene.n_free))
    H = contact_jacobian(contacts, first, per_grain, scene.n_free * per_grain)
    problem = assemble(scene, contacts, 1e-3)
    assert (H != problem.H).nnz == 0
    # Rotational columns do not depend on the radius: unit-norm rows of +-1 / cross products.
    rot = H.toarray().reshape(contacts.nc, dim, scene.n_free, per_grain)[..., dim:]
    assert np.all(rot[:, 0] == 0.0)  # the normal row never sees spin
    nz = np.abs(rot[np.abs(rot) > 1e-15])
    assert nz.max() <= 1.0 + 1e-15


@pytest.mark.parametrize("dim", [2, 3])
def test_frictionless_problem_has_normals_only(dim):
    """mu = mu_wall = 0: one row per contact, d translations per free grain."""
    scene = lattice_scene(dim, seed=40 + dim, mu=0.0, mu_wall=0.0, wall_mu=None, moving=True)
    assert scene.frictionless
    contacts = detect_contacts(scene)
    problem = assemble(scene, contacts, 1e-3)
    assert problem.contact_dim == 1
    assert problem.ndof == dim * scene.n_free
    assert problem.H.shape == (contacts.nc, dim * scene.n_free)
    u = generalized_velocity(scene, frictionless=True)
    np.testing.assert_array_equal(u, scene.velocities[scene.free].reshape(-1))
    expected = direct_relative_velocity(scene, contacts)[:, 0]
    np.testing.assert_allclose(problem.H @ u, expected, rtol=0, atol=1e-13)
    np.testing.assert_array_equal(problem.mass, np.repeat(scene.masses[scene.free], dim))


@pytest.mark.parametrize("dim", [2, 3])
def test_any_friction_keeps_tangents_and_rotations(dim):
    """Friction on grains only, or on one wall only, keeps the full frictional problem."""
    for kwargs in ({"mu": 0.0, "mu_wall": 0.4}, {"mu": 0.0, "mu_wall": 0.0, "wall_mu": 0.5}):
        scene = lattice_scene(dim, seed=50, **kwargs)
        assert not scene.frictionless
        contacts = detect_contacts(scene)
        problem = assemble(scene, contacts, 1e-3)
        assert problem.contact_dim == dim
        assert problem.H.shape == (dim * contacts.nc, scene.n_free * (3 if dim == 2 else 6))


@pytest.mark.parametrize("d_max", [-1e-3, float("nan"), float("inf")])
def test_bad_d_max_raises(d_max):
    """A negative or non-finite d_max is a SceneError naming d_max."""
    scene = lattice_scene(2, seed=0)
    with pytest.raises(SceneError, match="d_max"):
        detect_contacts(scene, d_max)


@pytest.mark.parametrize("size", [0, 1, 2, 1000])
def test_unique_ints_is_np_unique(size):
    """The sort-based distinct keys equal numpy's, repeats and extremes included."""
    rng = np.random.default_rng(size)
    a = rng.integers(-(2**62), 2**62, size)
    a = np.concatenate([a, a[: size // 3], rng.integers(0, 5, size)])
    np.testing.assert_array_equal(unique_ints(a), np.unique(a))
    assert unique_ints(a).dtype == a.dtype
