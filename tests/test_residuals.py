"""Coulomb cone projections and the residuals that judge every backend's answer."""

from __future__ import annotations

import clarabel
import numpy as np
import pytest
from scipy.optimize import minimize_scalar

import solvers
from cocd import Scene, Wall, assemble, detect_contacts
from cocd.cones import project_coulomb, project_dual_coulomb
from cocd.residuals import (
    Residuals,
    ccp_residual,
    complementarity,
    cone_violation,
    coulomb_residual,
    dual_cone_violation,
    dynamics_residual,
    residuals,
)

G = 9.81
R0 = 0.01
DT = 1e-3


# -- cones ---------------------------------------------------------------------------
def random_points(m, seed, n=400):
    """Random vectors of all kinds (inside, polar, in between) and random mu, some mu = 0."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, m)) * 10.0 ** rng.uniform(-3, 3, (n, 1))
    mu = rng.uniform(0.0, 2.0, n)
    mu[::7] = 0.0
    return x, mu


def in_cone(p, mu, tol=1e-12):
    """|p_T| <= mu p_N up to a relative tolerance."""
    scale = np.linalg.norm(p, axis=1)
    return np.linalg.norm(p[:, 1:], axis=1) <= mu * p[:, 0] + tol * scale


@pytest.mark.parametrize("m", [2, 3])
def test_projection_moreau_decomposition(m):
    """P_K is idempotent, lands in K, and x - P_K(x) is orthogonal to it and in the polar."""
    x, mu = random_points(m, seed=m)
    p = project_coulomb(x, mu)
    scale = np.linalg.norm(x, axis=1)
    assert np.all(in_cone(p, mu))
    np.testing.assert_allclose(project_coulomb(p, mu), p, rtol=0, atol=1e-14 * scale.max())
    y = x - p
    assert np.all(np.abs(np.sum(p * y, axis=1)) <= 1e-13 * scale**2)
    # Polar cone {mu |y_T| <= -y_N}.
    assert np.all(mu * np.linalg.norm(y[:, 1:], axis=1) <= -y[:, 0] + 1e-13 * scale)
    # Moreau: x - P_K(x) = P_{K°}(x) = -P_{K*}(-x).
    np.testing.assert_allclose(y, -project_dual_coulomb(-x, mu), rtol=0, atol=1e-13 * scale.max())
    # The sample covers the three regions.
    inside = np.all(p == x, axis=1)
    polar = np.all(p == 0.0, axis=1)
    assert inside.sum() > 10 and polar.sum() > 10 and (~inside & ~polar).sum() > 10


def test_projection_one_component_is_max_zero():
    """m = 1: the cone is the half-line, P(x) = max(x, 0)."""
    x = np.random.default_rng(0).normal(size=(50, 1))
    np.testing.assert_array_equal(project_coulomb(x, 0.3), np.maximum(x, 0.0))


@pytest.mark.parametrize("m", [2, 3])
def test_projection_with_zero_friction(m):
    """mu = 0: the cone is the normal half-line, P(x) = (max(x_N, 0), 0)."""
    x = np.random.default_rng(1).normal(size=(50, m))
    expected = np.zeros_like(x)
    expected[:, 0] = np.maximum(x[:, 0], 0.0)
    np.testing.assert_array_equal(project_coulomb(x, 0.0), expected)


@pytest.mark.parametrize("m", [2, 3])
def test_projection_zero_friction_zero_tangent_negative_normal(m):
    """mu = 0, x = (-1, 0...): the projection is the apex 0 (and the dual projection x).

    Regression: ``0 <= mu * x_N`` holds as ``0 <= -0.0`` when mu = 0, and the
    projection used to return x itself.
    """
    x = np.zeros((1, m))
    x[0, 0] = -1.0
    np.testing.assert_array_equal(project_coulomb(x, 0.0), np.zeros((1, m)))
    np.testing.assert_array_equal(project_dual_coulomb(-x, 0.0), -x)


def brute_force_projection(x, mu):
    """Nearest point of K by a search over the boundary rays (plus x itself and 0)."""
    m = x.size
    best = np.zeros(m)
    if np.linalg.norm(x[1:]) <= mu * x[0]:
        return x.copy()

    def ray_point(phi):
        d = np.array([1.0, mu * np.cos(phi), mu * np.sin(phi)])[:m]
        return max(0.0, float(x @ d)) / float(d @ d) * d

    def dist(phi):
        return float(np.linalg.norm(x - ray_point(phi)))

    if m == 2:
        candidates = [ray_point(0.0), ray_point(np.pi)]
    else:
        grid = np.linspace(-np.pi, np.pi, 721)
        k = int(np.argmin([dist(phi) for phi in grid]))
        res = minimize_scalar(
            dist,
            bounds=(grid[max(k - 1, 0)], grid[min(k + 1, 720)]),
            method="bounded",
            options={"xatol": 1e-12},
        )
        candidates = [ray_point(res.x)]
    for c in candidates:
        if np.linalg.norm(x - c) < np.linalg.norm(x - best):
            best = c
    return best


@pytest.mark.parametrize("m", [2, 3])
def test_projection_matches_brute_force(m):
    """The closed form equals a numerical nearest-point search on a few points."""
    rng = np.random.default_rng(10 + m)
    x = rng.normal(size=(12, m))
    mu = rng.uniform(0.05, 1.5, 12)
    p = project_coulomb(x, mu)
    for a in range(12):
        np.testing.assert_allclose(p[a], brute_force_projection(x[a], mu[a]), atol=1e-7)


@pytest.mark.parametrize("m", [2, 3])
def test_dual_projection_lands_in_dual_cone(m):
    """P_{K*} lands in {mu |y_T| <= y_N}, is idempotent, and y - P_{K*}(y) lies in -K."""
    y, mu = random_points(m, seed=20 + m)
    q = project_dual_coulomb(y, mu)
    scale = np.linalg.norm(y, axis=1)
    assert np.all(mu * np.linalg.norm(q[:, 1:], axis=1) <= q[:, 0] + 1e-13 * scale)
    np.testing.assert_allclose(project_dual_coulomb(q, mu), q, rtol=0, atol=1e-13 * scale.max())
    assert np.all(in_cone(q - y, mu))
    assert np.all(np.abs(np.sum(q * (q - y), axis=1)) <= 1e-13 * scale**2)


# -- analytic answers ----------------------------------------------------------------
def disc_on_floor(dim, velocity=0.0, mu=0.3, mu_wall=None, height=R0, d_max=None):
    """One grain at ``height`` above a floor, horizontal velocity ``velocity``."""
    x = np.zeros((1, dim))
    x[0, -1] = height
    v = np.zeros((1, dim))
    v[0, 0] = velocity
    up = np.eye(dim)[-1]
    scene = Scene(x, R0, velocities=v, walls=[Wall(np.zeros(dim), up)], mu=mu, mu_wall=mu_wall)
    problem = assemble(scene, detect_contacts(scene, d_max), DT)
    return scene, problem


@pytest.mark.parametrize("dim", [2, 3])
def test_resting_disc_exact_answer_has_zero_residuals(dim):
    """U = (0, -g dt, 0), p = (m g dt, 0): every residual vanishes, u = 0."""
    scene, problem = disc_on_floor(dim)
    m = scene.masses[0]
    U = np.zeros(problem.ndof)
    U[dim - 1] = -G * DT
    np.testing.assert_allclose(problem.U, U, rtol=1e-15, atol=0)
    p = np.zeros((1, dim))
    p[0, 0] = m * G * DT
    u = problem.velocity(p)
    assert np.abs(u).max() < 1e-15
    assert ccp_residual(problem, p) < 1e-14
    assert coulomb_residual(problem, p) < 1e-14
    assert dynamics_residual(problem, u, p) < 1e-14
    r = residuals(problem, u, p)
    assert r.cone_violation_max == 0.0 and r.dual_violation_max < 1e-14
    assert r.complementarity_max < 1e-14


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("factor", [0.0, 2.0])
def test_resting_disc_wrong_answers(dim, factor):
    """p = 0 or 2 m g dt: ccp and Coulomb residuals are exactly 1 (|F| = |rho w| = |rho b|)."""
    scene, problem = disc_on_floor(dim)
    p = np.zeros((1, dim))
    p[0, 0] = factor * scene.masses[0] * G * DT
    assert ccp_residual(problem, p) == pytest.approx(1.0, rel=1e-12)
    assert coulomb_residual(problem, p) == pytest.approx(1.0, rel=1e-12)
    # u = U contradicts p = m g dt by exactly |M U|.
    exact = np.zeros((1, dim))
    exact[0, 0] = scene.masses[0] * G * DT
    assert dynamics_residual(problem, problem.U, exact) == pytest.approx(1.0, rel=1e-12)


@pytest.mark.parametrize("dim", [2, 3])
def test_sliding_disc_coulomb_answer(dim):
    """A fast sliding disc: the Coulomb law's answer has zero Coulomb residual, not zero ccp."""
    scene, problem = disc_on_floor(dim, velocity=1.0)
    pn = scene.masses[0] * G * DT
    slip = problem.b.reshape(1, dim)[0, 1:]
    p = np.concatenate([[pn], -0.3 * pn * slip / np.linalg.norm(slip)])[None, :]
    w = problem.relative_velocity(problem.velocity(p))
    assert abs(w[0, 0]) < 1e-15  # stays on the floor
    assert np.dot(w[0, 1:], slip) > 0.9 * np.dot(slip, slip)  # still sliding the same way
    assert coulomb_residual(problem, p) < 1e-13
    assert ccp_residual(problem, p) > 1e-3


@pytest.mark.parametrize("dim", [2, 3])
def test_separated_contact_with_frictionless_wall(dim):
    """A disc 5 R0 above a frictionless floor in a frictional scene: p = 0 has residual 0."""
    _, problem = disc_on_floor(dim, mu=0.3, mu_wall=0.0, height=5 * R0, d_max=10 * R0)
    assert problem.nc == 1 and problem.contact_dim == dim
    p = np.zeros((1, dim))
    assert ccp_residual(problem, p) == 0.0
    assert coulomb_residual(problem, p) == 0.0


# -- unit invariance -----------------------------------------------------------------
def packing(dim, *, seed, unit=1.0, density=2500.0, spacing=2.46, shape=None):
    """A small jittered lattice on a floor, squeezed and falling; lengths in ``unit`` m."""
    rng = np.random.default_rng(seed)
    shape = shape or ((3, 3) if dim == 2 else (2, 2, 2))
    idx = np.indices(shape).reshape(dim, -1).T
    n = idx.shape[0]
    radii = R0 * rng.uniform(0.8, 1.2, n)
    x = spacing * R0 * idx + R0 * rng.uniform(-0.02, 0.02, (n, dim))
    x[:, -1] += 1.25 * R0
    # Converging, falling and random: some contacts close within the step, some do not.
    v = -300.0 * (x - x.mean(axis=0)) - 3.0 * np.eye(dim)[-1] + rng.normal(size=(n, dim))
    w = rng.normal(size=(n,) if dim == 2 else (n, 3)) / R0
    up = np.eye(dim)[-1]
    tilted = np.eye(dim)[0] + 0.2 * up
    walls = [Wall(np.zeros(dim), up), Wall(-1.25 * R0 * np.eye(dim)[0] / unit, tilted, mu=0.5)]
    gravity = -G * up / unit
    return Scene(
        x / unit,
        radii / unit,
        velocities=v / unit,
        angular_velocities=w,
        walls=walls,
        gravity=gravity,
        density=density,
        mu=0.3,
        fixed=np.arange(n) == n - 1,
    )


def random_impulses(problem, seed):
    """Arbitrary impulses of the size m |b|, some inside the cones, some not."""
    rng = np.random.default_rng(seed)
    scale = float(np.mean(problem.mass)) * float(np.abs(problem.b).max())
    return scale * rng.normal(size=(problem.nc, problem.contact_dim))


@pytest.mark.parametrize("dim", [2, 3])
def test_residuals_do_not_depend_on_units(dim):
    """Millimetres or metres, light or heavy grains: the same residuals for the same answer."""
    metres = assemble(*_scene_contacts(packing(dim, seed=dim)))
    mm = assemble(*_scene_contacts(packing(dim, seed=dim, unit=1e-3)))
    heavy = assemble(*_scene_contacts(packing(dim, seed=dim, density=2500.0 * 7.3)))
    assert metres.nc == mm.nc == heavy.nc >= 4
    p = random_impulses(metres, seed=1)
    u = metres.velocity(p) * (1.0 + 1e-3)  # a slightly inconsistent velocity
    # Impulse = mass x velocity: mass scales with length^d, velocity with length.
    k_mm = 1e3 ** (dim + 1)
    cases = [(mm, k_mm * p, 1e3 * u), (heavy, 7.3 * p, u)]
    reference = residuals(metres, u, p)
    assert reference.ccp > 1e-2 and reference.coulomb > 1e-2 and reference.dynamics > 1e-6
    for problem, pp, uu in cases:
        got = residuals(problem, uu, pp)
        for name, value in reference.as_dict().items():
            assert getattr(got, name) == pytest.approx(value, rel=1e-10), name


def _scene_contacts(scene):
    return scene, detect_contacts(scene), DT


# -- primal/dual consistency ---------------------------------------------------------
def dual_objective(problem, p):
    p = p.reshape(-1)
    return 0.5 * p @ (problem.W @ p) + p @ problem.b


@pytest.mark.parametrize("dim", [2, 3])
def test_clarabel_answer_is_primal_dual_consistent(dim):
    """Clarabel's (u, p): u = U + M^-1 H'p, p minimises the dual, p_a . w_a = 0."""
    problem = assemble(*_scene_contacts(packing(dim, seed=100 + dim)))
    sol = solvers.solve(problem, "clarabel", tol=1e-10)
    assert sol.found
    p, u = sol.p, sol.u
    active = p[:, 0] > 1e-6 * np.abs(p).max()
    assert 2 <= active.sum() < problem.nc  # some contacts push, some do not
    np.testing.assert_allclose(u, problem.velocity(p), rtol=0, atol=1e-8 * np.abs(u).max())
    assert dynamics_residual(problem, u, p) < 1e-8

    w = problem.relative_velocity(problem.velocity(p))
    scale = np.abs(p).max() * np.abs(problem.b).max()
    assert np.all(np.abs(np.sum(p * w, axis=1)) < 1e-8 * scale)
    assert complementarity(problem, p).max() < 1e-8
    # Strong duality: primal value + dual value + 1/2 U'MU = 0, i.e. the contact work.
    du = u - problem.U
    gap = 0.5 * du @ (problem.mass * du) + dual_objective(problem, p)
    assert abs(gap) < 1e-8 * abs(dual_objective(problem, p))

    rng = np.random.default_rng(dim)
    f0 = dual_objective(problem, p)
    for _ in range(50):
        step = 10.0 ** rng.uniform(-4, -1) * np.abs(p).max()
        q = project_coulomb(p + step * rng.normal(size=p.shape), problem.mu)
        assert dual_objective(problem, q) >= f0 - 1e-9 * abs(f0)


@pytest.mark.parametrize("dim", [2, 3])
def test_primal_form_duals_are_the_impulses(dim):
    """Clarabel on the primal form: its x and its duals z give u = U + M^-1 H'p."""
    problem = assemble(*_scene_contacts(packing(dim, seed=110 + dim)))
    form = problem.primal_conic_form()
    cones = [
        clarabel.NonnegativeConeT(k) if kind == "nonneg" else clarabel.SecondOrderConeT(k)
        for kind, k in form.cones
    ]
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    for name in ("tol_gap_abs", "tol_gap_rel", "tol_feas"):
        setattr(settings, name, 1e-12)
    sol = clarabel.DefaultSolver(form.P, form.q, form.A, form.b, cones, settings).solve()
    assert str(sol.status).endswith("Solved")
    u, p = form.velocity(np.asarray(sol.x)), form.impulses(np.asarray(sol.z))
    assert (p[:, 0] > 1e-6 * p[:, 0].max()).sum() >= 2
    np.testing.assert_allclose(u, problem.velocity(p), rtol=0, atol=1e-8 * np.abs(u).max())
    assert dynamics_residual(problem, u, p) < 1e-8
    assert ccp_residual(problem, p) < 1e-7


@pytest.mark.parametrize("dim", [2, 3])
def test_clarabel_grain_near_frictionless_wall(dim):
    """A grain 0.25 R0 above a smooth floor in a frictional scene: p = 0, u = U.

    Regression: with the mu = 0 projection bug the exact answer scored ccp 1 and
    the polished answer was a negative (attractive) normal impulse.
    """
    _, problem = disc_on_floor(dim, mu=0.3, mu_wall=0.0, height=1.25 * R0)
    assert problem.nc == 1 and problem.contact_dim == dim
    sol = solvers.solve(problem, "clarabel", tol=1e-8)
    assert sol.status == solvers.Status.OPTIMAL
    assert np.all(sol.p[:, 0] >= 0.0)
    scale = np.abs(problem.U).max()
    np.testing.assert_allclose(sol.p, 0.0, atol=1e-8 * problem.mass[0] * scale)
    np.testing.assert_allclose(sol.u, problem.U, rtol=0, atol=1e-8 * scale)


@pytest.mark.parametrize("dim", [2, 3])
def test_residuals_fields_equal_the_functions(dim):
    """residuals() gathers exactly the values of the individual functions."""
    problem = assemble(*_scene_contacts(packing(dim, seed=200 + dim)))
    p = random_impulses(problem, seed=3)
    u = problem.velocity(p) + 1e-3
    r = residuals(problem, u, p)
    assert isinstance(r, Residuals)
    cv, dv, cp = (f(problem, p) for f in (cone_violation, dual_cone_violation, complementarity))
    expected = {
        "ccp": ccp_residual(problem, p),
        "coulomb": coulomb_residual(problem, p),
        "dynamics": dynamics_residual(problem, u, p),
        "cone_violation_max": cv.max(),
        "cone_violation_rms": np.sqrt(np.mean(cv**2)),
        "dual_violation_max": dv.max(),
        "dual_violation_rms": np.sqrt(np.mean(dv**2)),
        "complementarity_max": cp.max(),
        "complementarity_rms": np.sqrt(np.mean(cp**2)),
    }
    assert r.as_dict() == pytest.approx(expected, rel=1e-15)
    assert min(expected.values()) > 0.0
    assert cv.shape == dv.shape == cp.shape == (problem.nc,)
