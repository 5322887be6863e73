"""The step's ConicProblem: dual data, scalings, the primal conic and QP forms, validation."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from conftest import jittered_lattice

from cocd import ConicProblem, ProblemError, Scene, Wall, assemble, detect_contacts
from cocd.problem import generalized_velocity

G = 9.81
R0 = 0.01
DT = 1e-3


def small_problem(dim, *, seed, frictionless=False):
    """A jittered lattice with a fixed grain, a floor and a wall, squeezed: some contacts close."""
    rng = np.random.default_rng(seed)
    shape = (3, 3) if dim == 2 else (2, 2, 2)
    _, radii, x = jittered_lattice(rng, shape, R0, (0.8, 1.2), 2.46, 0.02)
    n = len(radii)
    x[:, -1] += 1.25 * R0
    up = np.eye(dim)[-1]
    walls = [Wall(np.zeros(dim), up), Wall(-1.25 * R0 * np.eye(dim)[0], np.eye(dim)[0], mu=0.6)]
    mu = 0.0 if frictionless else rng.uniform(0.1, 0.9)
    if frictionless:
        walls[1] = Wall(walls[1].point, walls[1].normal)
    scene = Scene(
        x,
        radii,
        density=rng.uniform(1000, 3000, n),
        velocities=-300.0 * (x - x.mean(axis=0)) + rng.normal(size=(n, dim)),
        angular_velocities=rng.normal(size=(n,) if dim == 2 else (n, 3)) / R0,
        walls=walls,
        gravity=rng.normal(size=dim) * G,
        mu=mu,
        mu_wall=0.0 if frictionless else 0.25,
        fixed=np.arange(n) == n - 1,
    )
    problem = assemble(scene, detect_contacts(scene), DT)
    assert problem.nc >= 4
    return scene, problem


PROBLEMS = [(2, False), (3, False), (2, True), (3, True)]
IDS = ["2d", "3d", "2d-frictionless", "3d-frictionless"]


@pytest.fixture(params=PROBLEMS, ids=IDS)
def case(request):
    dim, frictionless = request.param
    return small_problem(dim, seed=dim + 10 * frictionless, frictionless=frictionless)


def dense_W(problem):
    H = problem.H.toarray()
    return H @ np.diag(1.0 / problem.mass) @ H.T


def test_W_is_H_Minv_Ht(case):
    """W = H M^-1 H', symmetric positive semi-definite, and sparse."""
    _, problem = case
    W = dense_W(problem)
    assert sp.issparse(problem.W)
    np.testing.assert_allclose(problem.W.toarray(), W, rtol=1e-14, atol=1e-14 * np.abs(W).max())
    Ws = problem.W.toarray()
    np.testing.assert_allclose(Ws, Ws.T, rtol=0, atol=1e-14 * np.abs(W).max())
    assert np.linalg.eigvalsh(W).min() >= -1e-12 * np.abs(W).max()
    W2, b2 = problem.dual()
    assert W2 is problem.W and b2 is problem.b


def test_b_is_HU_plus_gap_rate(case):
    """b = H U + (D/dt, 0) and relative_velocity(u) = H u + (D/dt, 0)."""
    _, problem = case
    offset = np.zeros((problem.nc, problem.contact_dim))
    offset[:, 0] = problem.D / problem.dt
    np.testing.assert_allclose(problem.b, problem.H @ problem.U + offset.reshape(-1), rtol=1e-15)
    u = np.random.default_rng(0).normal(size=problem.ndof)
    np.testing.assert_allclose(
        problem.relative_velocity(u),
        (problem.H @ u).reshape(problem.nc, -1) + offset,
        rtol=1e-14,
    )


def test_assemble_mass_and_free_velocity(case):
    """M holds m (translations) and J / R^2 (rotations); U = u + dt g on translations."""
    scene, problem = case
    free = scene.free
    m, dim = scene.masses[free], scene.dim
    frictionless = problem.contact_dim == 1
    per = dim if frictionless else (3 if dim == 2 else 6)
    mass = problem.mass.reshape(-1, per)
    np.testing.assert_allclose(mass[:, :dim], np.repeat(m[:, None], dim, axis=1), rtol=1e-15)
    if not frictionless:
        factor = 0.5 if dim == 2 else 0.4
        np.testing.assert_allclose(mass[:, dim:], factor * m[:, None] * np.ones(per - dim))
    U = problem.U.reshape(-1, per)
    u = generalized_velocity(scene, frictionless).reshape(-1, per)
    np.testing.assert_allclose(U[:, :dim], scene.velocities[free] + DT * scene.gravity)
    np.testing.assert_array_equal(U[:, dim:], u[:, dim:])
    np.testing.assert_array_equal(problem.D, detect_contacts(scene).gap)


def test_rho_is_m_over_trace(case):
    """rho_a = m / trace(W_aa), computed from the dense diagonal blocks."""
    _, problem = case
    m = problem.contact_dim
    W = dense_W(problem)
    traces = [np.trace(W[a * m : (a + 1) * m, a * m : (a + 1) * m]) for a in range(problem.nc)]
    np.testing.assert_allclose(problem.rho, m / np.array(traces), rtol=1e-14)


@pytest.mark.parametrize("dim", [2, 3])
def test_rho_of_a_disc_on_a_wall(dim):
    """One grain on a wall: rho = m/2 (disc, 2D) and 3m/8 (sphere, 3D)."""
    x = np.zeros((1, dim))
    x[0, -1] = R0
    scene = Scene(x, R0, walls=[Wall(np.zeros(dim), np.eye(dim)[-1])])
    problem = assemble(scene, detect_contacts(scene), DT)
    m = scene.masses[0]
    assert problem.rho[0] == pytest.approx(m / 2 if dim == 2 else 3 * m / 8, rel=1e-14)
    # The velocity scale is the violation |P_K(-b)| = g dt; the mass scale the mean mass.
    ms, vs = problem.scales
    assert vs == pytest.approx(G * DT, rel=1e-14)
    assert ms == pytest.approx(np.mean(problem.mass), rel=1e-15)


def test_primal_form_cones(case):
    """2D: one nonneg cone of 2 nc rows; 3D: nc SOCs of 3; frictionless: nc nonneg rows."""
    _, problem = case
    form = problem.primal_conic_form()
    nc, m = problem.nc, problem.contact_dim
    if m == 1:
        assert form.cones == [("nonneg", nc)]
    elif m == 2:
        assert form.cones == [("nonneg", 2 * nc)]
    else:
        assert form.cones == [("soc", 3)] * nc
    rows = sum(size for _, size in form.cones)
    assert form.A.shape == (rows, problem.ndof) and form.b.shape == (rows,)
    assert form.P.shape == (problem.ndof, problem.ndof)
    np.testing.assert_array_equal(form.q, 0.0)
    np.testing.assert_allclose(form.P.diagonal(), problem.mass / form.mass_scale, rtol=1e-15)
    assert (form.P - sp.diags(form.P.diagonal())).nnz == 0


def sample_duals(problem, seed, count):
    """``count`` draws of :func:`random_duals` from ``default_rng(seed)``."""
    rng = np.random.default_rng(seed)
    return [random_duals(problem, rng) for _ in range(count)]


def random_duals(problem, rng):
    """Random z in the dual of the primal form's cones (nonneg, or SOC: self-dual)."""
    nc, m = problem.nc, problem.contact_dim
    if m < 3:
        z = rng.uniform(0.0, 1.0, (nc, 2 if m == 2 else 1))
        z[rng.uniform(size=z.shape) < 0.3] = 0.0
        return z.reshape(-1)
    z = rng.normal(size=(nc, 3))
    z[:, 0] = np.linalg.norm(z[:, 1:], axis=1) * rng.uniform(1.0, 2.0, nc)
    z[0, 0] = np.linalg.norm(z[0, 1:])  # one on the boundary
    return z.reshape(-1)


def test_impulses_from_duals_lie_in_the_coulomb_cone(case):
    """form.impulses(z) is in K for z in the dual cones, boundary z giving boundary p."""
    _, problem = case
    form = problem.primal_conic_form()
    for z in sample_duals(problem, 1, 20):
        p = form.impulses(z)
        assert p.shape == (problem.nc, problem.contact_dim)
        assert np.all(p[:, 0] >= 0.0)
        if problem.contact_dim > 1:
            pt = np.linalg.norm(p[:, 1:], axis=1)
            assert np.all(pt <= problem.mu * p[:, 0] * (1 + 1e-12))
    if problem.contact_dim > 1:
        # A single active half-plane (2D) or a boundary SOC dual (3D) is a sliding impulse.
        z = np.zeros(form.b.size)
        z[:3] = (1.0, 0.0, 0.0) if problem.contact_dim == 2 else (1.0, 0.6, -0.8)
        p = form.impulses(z)
        assert np.linalg.norm(p[0, 1:]) == pytest.approx(problem.mu[0] * p[0, 0], rel=1e-14)


def test_kkt_stationarity_is_momentum_balance(case):
    """P x + q + A'z = 0 with x = -P^-1 A'z gives M(u - U) = H'p, p = impulses(z)."""
    _, problem = case
    form = problem.primal_conic_form()
    for z in sample_duals(problem, 2, 5):
        x = -(form.A.T @ z) / form.P.diagonal()
        np.testing.assert_allclose(form.P @ x + form.q + form.A.T @ z, 0.0, atol=1e-12)
        u = form.velocity(x)
        p = form.impulses(z)
        lhs = problem.mass * (u - problem.U)
        rhs = problem.H.T @ p.reshape(-1)
        np.testing.assert_allclose(lhs, rhs, rtol=0, atol=1e-12 * np.abs(rhs).max())
        np.testing.assert_allclose(u, problem.velocity(p), rtol=0, atol=1e-12 * np.abs(u).max())


def test_slack_is_the_scaled_constraint(case):
    """s = b - A x is (D/dt + N u, mu T u) / velocity_scale, or its two half-planes in 2D."""
    _, problem = case
    form = problem.primal_conic_form()
    vs = form.velocity_scale
    x = np.random.default_rng(3).normal(size=problem.ndof)
    u = form.velocity(x)
    assert np.allclose(u, problem.U + vs * x, rtol=1e-15, atol=0)
    s = form.b - form.A @ x
    w = problem.relative_velocity(u)
    mu = problem.mu
    if problem.contact_dim == 1:
        expected = w[:, 0]
    elif problem.contact_dim == 2:
        expected = np.stack([w[:, 0] + mu * w[:, 1], w[:, 0] - mu * w[:, 1]], axis=1)
    else:
        expected = np.concatenate([w[:, :1], mu[:, None] * w[:, 1:]], axis=1)
    expected = expected.reshape(-1) / vs
    np.testing.assert_allclose(s, expected, rtol=0, atol=1e-12 * np.abs(expected).max())
    # The objective is the primal's, divided by mass_scale * velocity_scale^2.
    du = u - problem.U
    scaled = 0.5 * x @ (form.P @ x) * form.mass_scale * vs**2
    assert scaled == pytest.approx(0.5 * du @ (problem.mass * du), rel=1e-13)


def test_qp_form(case):
    """QP forms for 2D and frictionless problems, ProblemError for 3D friction."""
    _, problem = case
    if problem.dim == 3 and problem.contact_dim == 3:
        assert not problem.is_qp
        with pytest.raises(ProblemError, match="3D"):
            problem.qp_form()
        return
    assert problem.is_qp
    P, q, G_, h = problem.qp_form()
    form = problem.primal_conic_form()
    assert (P != form.P).nnz == 0 and (G_ != form.A).nnz == 0
    np.testing.assert_array_equal(q, form.q)
    np.testing.assert_array_equal(h, form.b)
    # G x <= h is exactly the constraint: it holds at x = 0 iff b(U) is in the dual cone.
    w = problem.b.reshape(problem.nc, -1)
    if problem.contact_dim == 1:
        feasible = w[:, 0] >= 0
    else:
        feasible = problem.mu * np.abs(w[:, 1]) <= w[:, 0]
    holds = (h >= 0).reshape(problem.nc, -1).all(axis=1)
    np.testing.assert_array_equal(holds, feasible)
    assert 0 < feasible.sum() < problem.nc


def valid_problem_kwargs():
    return {
        "dim": 2,
        "contact_dim": 2,
        "mass": np.ones(3),
        "H": sp.csr_matrix(np.arange(6.0).reshape(2, 3)),
        "D": np.array([1e-3]),
        "mu": np.array([0.3]),
        "dt": 1e-3,
        "U": np.array([0.0, -G * 1e-3, 0.0]),
    }


def test_valid_problem_builds():
    """The base data of the validation tests is accepted."""
    problem = ConicProblem(**valid_problem_kwargs())
    assert (problem.nc, problem.ndof) == (1, 3)


@pytest.mark.parametrize(
    ("change", "culprit"),
    [
        ({"H": sp.csr_matrix(np.ones((3, 3)))}, "H has shape"),
        ({"H": sp.csr_matrix(np.ones((2, 4)))}, "H has shape"),
        ({"dt": 0.0}, "dt"),
        ({"dt": -1e-3}, "dt"),
        ({"dt": float("nan")}, "dt"),
        ({"U": np.array([0.0, np.nan, 0.0])}, r"U\[\d+\] is nan: U must be finite"),
        ({"mu": np.array([-0.1])}, "friction"),
        ({"mass": np.array([1.0, 0.0, 1.0])}, "mass"),
        ({"mass": np.array([1.0, 1.0, -2.0])}, "mass"),
        ({"D": np.array([np.inf])}, r"D\[0\] is inf: D must be finite"),
        ({"contact_dim": 3}, "contact_dim"),
        ({"dim": 4}, "dim"),
    ],
    ids=lambda v: str(v)[:30] if isinstance(v, str) else None,
)
def test_problem_validation(change, culprit):
    """Invalid data raises ProblemError naming the culprit."""
    kwargs = valid_problem_kwargs()
    kwargs.update(change)
    with pytest.raises(ProblemError, match=culprit):
        ConicProblem(**kwargs)


@pytest.mark.parametrize("dt", [0.0, -1e-3, float("nan"), float("inf")])
def test_assemble_rejects_bad_dt(dt):
    """assemble refuses a non-positive or non-finite time step."""
    scene, _ = small_problem(2, seed=0)
    with pytest.raises(ProblemError, match="dt"):
        assemble(scene, detect_contacts(scene), dt)
