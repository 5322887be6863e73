"""Quirks of the ``qp:<name>`` backends (qpsolvers): 2D agreement with clarabel,
frictionless 3D, faceted 3D friction and its error bound, warm starts, native
settings and statuses. The general conformance suite is test_conformance.py."""

from __future__ import annotations

import numpy as np
import pytest

import solvers
import solvers.qpsolvers_ as qpmod
from cocd import Scene, Stepper, Wall, assemble, column_2d, detect_contacts, stack
from cocd.errors import ProblemError
from cocd.residuals import ccp_residual
from solvers.qpsolvers_ import facet_error_bound

G = 9.81
R = 0.01
TOL = 1e-8
EXACT_U = 1e-6  # interior point and active set: relative velocity error against clarabel
FIRST_ORDER_U = 1e-4  # osqp, scs, qpalm (measured: 1e-12, thanks to polishing)

QP_BACKENDS = sorted(n for n in solvers.registered() if n.startswith("qp:"))


def _need(name: str) -> None:
    reason = solvers.unavailable().get(name)
    if reason is not None:
        pytest.skip(f"{name} unavailable: {reason}")


def _m_norm(problem, du) -> float:
    return float(np.sqrt(np.sum(problem.mass * du**2)))


def _dual_objective(problem, p) -> float:
    p = p.reshape(-1)
    return float(0.5 * p @ (problem.W @ p) + problem.b @ p)


@pytest.fixture(scope="module")
def packing_2d():
    """A 60-disc column 20 steps into its collapse, and clarabel's answer at 1e-10."""
    stepper = Stepper(column_2d(60), 1e-3)
    stepper.run(20)
    problem = stepper.problem
    ref = solvers.solve(problem, "clarabel", tol=1e-10)
    assert ref.status == "optimal"
    return problem, ref


def heap_3d(seed: int = 0, mu: float = 0.4, speed: float = 0.2) -> Scene:
    """Three touching spheres on a floor, a fourth on top, in random motion (9 contacts)."""
    s = 2 * R
    base = np.array([[0.0, 0.0], [s, 0.0], [s / 2, s * np.sqrt(3) / 2]])
    top = np.append(base.mean(axis=0), R + s * np.sqrt(2 / 3))
    x = np.vstack([np.column_stack([base, np.full(3, R)]), top])
    rng = np.random.default_rng(seed)
    return Scene(
        x,
        R,
        velocities=speed * rng.standard_normal((4, 3)),
        angular_velocities=speed / R * rng.standard_normal((4, 3)),
        walls=[Wall(np.zeros(3), (0, 0, 1))],
        mu=mu,
    )


@pytest.fixture(scope="module")
def heap():
    scene = heap_3d()
    problem = assemble(scene, detect_contacts(scene), 1e-3)
    ref = solvers.solve(problem, "clarabel", tol=1e-9)
    assert ref.status == "optimal" and problem.contact_dim == 3 and problem.nc == 9
    w = problem.relative_velocity(ref.u)
    sliding = (np.linalg.norm(w[:, 1:], axis=1) > 1e-6) & (ref.p[:, 0] > 0)
    assert sliding.sum() >= 3  # the faceting matters: several contacts slide
    return problem, ref


# -- 2D: every qp backend against clarabel ------------------------------------
@pytest.mark.parametrize("backend", QP_BACKENDS)
def test_2d_packing_agrees_with_clarabel(backend, packing_2d):
    _need(backend)
    problem, ref = packing_2d
    info = solvers.get(backend)
    sol = solvers.solve(problem, backend, tol=TOL)
    assert sol.status == "optimal", f"{sol.status} {sol.extras}"
    assert ccp_residual(problem, sol.p) <= 10 * TOL
    err = np.linalg.norm(sol.u - ref.u) / np.linalg.norm(ref.u)
    assert err <= (FIRST_ORDER_U if info.first_order else EXACT_U), f"relative u error {err:.2e}"
    assert sol.extras["qp_solver"] == backend[3:]
    assert isinstance(sol.extras["native_status"], str) and sol.extras["native_status"]
    assert "approximation" not in sol.extras
    if sol.extras["iterations_reported"]:
        assert sol.iterations > 0
    else:
        assert sol.iterations == 0


# -- frictionless 3D, facets ignored, 3D friction needs facets ------------------
def test_frictionless_3d_stack_rests_with_analytic_impulses():
    _need("qp:osqp")
    n, dt = 5, 1e-3
    scene = stack(n, radius=R, dim=3, mu=0.0)
    stepper = Stepper(scene, dt, solver="qp:osqp")
    stepper.run(10)
    problem, sol = stepper.problem, stepper.solution
    assert problem.is_qp and problem.contact_dim == 1
    assert sol.status == "optimal" and "approximation" not in sol.extras
    assert np.abs(scene.velocities).max() < 1e-8
    # Contact k from the top carries the weight of the k grains above it.
    m = scene.masses[0]
    np.testing.assert_allclose(np.sort(sol.p[:, 0]), np.arange(1, n + 1) * m * G * dt, rtol=1e-6)
    ref = solvers.solve(problem, "clarabel", tol=1e-10)
    np.testing.assert_allclose(sol.p, ref.p, rtol=1e-6, atol=1e-12)


def test_facets_ignored_without_friction_cones(packing_2d):
    _need("qp:osqp")
    problem, ref = packing_2d
    sol = solvers.solve(problem, "qp:osqp:facets=8", tol=TOL)
    assert sol.status == "optimal" and "approximation" not in sol.extras
    assert np.linalg.norm(sol.u - ref.u) <= EXACT_U * np.linalg.norm(ref.u)


def test_3d_friction_without_facets_raises():
    _need("qp:osqp")
    stepper = Stepper(stack(3, radius=R, dim=3, mu=0.3), 1e-3)
    stepper.run(2)
    with pytest.raises(ProblemError, match="facets"):
        solvers.solve(stepper.problem, "qp:osqp", tol=TOL)
    for bad in ("qp:osqp:facets=2", "qp:osqp:facets=8.5", "qp:osqp:facets=many"):
        with pytest.raises(ProblemError, match="facets must be an integer >= 3"):
            solvers.solve(stepper.problem, bad, tol=TOL)


# -- faceted 3D friction --------------------------------------------------------
@pytest.mark.parametrize("backend", QP_BACKENDS)
def test_faceted_answer_in_cones_and_within_bound(backend, heap):
    _need(backend)
    problem, ref = heap
    sol = solvers.solve(problem, f"{backend}:facets=8", tol=TOL)
    assert sol.found, f"{sol.status} {sol.extras.get('native_status')}"
    assert sol.extras["approximation"] == "facets=8"
    # Inscribed pyramid: inside the circular cones (not merely within the suite's slack).
    pt = np.linalg.norm(sol.p[:, 1:], axis=1)
    assert np.all(sol.p[:, 0] >= 0.0)
    assert np.all(pt <= problem.mu * sol.p[:, 0] * (1 + 1e-12) + 1e-300)
    err = _m_norm(problem, sol.u - ref.u)
    bound = facet_error_bound(problem, ref.p, 8)
    scale = _m_norm(problem, ref.u - problem.U)
    assert 0.0 < err <= bound + 1e-6 * scale, f"error {err:.3e} > bound {bound:.3e}"
    assert bound < 0.5 * scale  # the bound says something: 8 facets, 1 - cos(pi/8) = 0.076


def test_faceted_error_falls_with_more_facets(heap):
    _need("qp:osqp")
    problem, ref = heap
    f_ref = _dual_objective(problem, ref.p)
    scale = abs(f_ref)
    errors, gaps, bounds = [], [], []
    for k in (4, 8, 32):
        sol = solvers.solve(problem, f"qp:osqp:facets={k}", tol=TOL)
        assert sol.status == "optimal" and sol.extras["approximation"] == f"facets={k}"
        errors.append(_m_norm(problem, sol.u - ref.u))
        gaps.append(_dual_objective(problem, sol.p) - f_ref)
        bounds.append(facet_error_bound(problem, ref.p, k))
    assert errors[0] > errors[1] > errors[2] > 0.0
    assert bounds[0] > bounds[1] > bounds[2]
    assert all(e <= b for e, b in zip(errors, bounds, strict=True))
    # Nested pyramids K_4 ⊂ K_8 ⊂ K_32 ⊂ K: the optimal value can only fall towards f(p*).
    assert gaps[0] >= gaps[1] >= gaps[2] >= -1e-7 * scale
    # Every cone slides or sticks the same way: about O(1/k) for the velocities here.
    assert errors[2] < 0.25 * errors[0]


@pytest.mark.parametrize("k", [4, 8])
def test_sphere_sliding_between_facets_decelerates_at_mu_cos_pi_over_k(k):
    """A sphere sliding along angle pi/k, half-way between two facet directions:
    friction mu cos(pi/k) m g in the faceted model, mu m g in the exact one."""
    _need("qp:osqp")
    mu, v0, dt = 0.2, 1.0, 1e-3
    direction = np.array([np.cos(np.pi / k), np.sin(np.pi / k), 0.0])

    def deceleration(solver, mu_eff):
        # Start at the model's steady gap under a sliding grain, dt mu_eff |slip|: the
        # transient then decays 10 times per step.
        scene = Scene(
            [[0.0, 0.0, R + dt * mu_eff * v0]],
            R,
            velocities=(v0 * direction)[None, :],
            walls=[Wall(np.zeros(3), (0, 0, 1))],
            mu=mu,
        )
        stepper = Stepper(scene, dt, solver=solver, tol=TOL)
        stepper.run(10)
        v_start = scene.velocities[0].copy()
        stepper.run(20)  # rolling starts after v0 / (3.5 mu_eff g), > 140 steps
        assert stepper.solution.found
        return (v_start - scene.velocities[0]) / (20 * dt)

    a_facets = deceleration(f"qp:osqp:facets={k}", mu * np.cos(np.pi / k))
    a_exact = deceleration("clarabel", mu)
    assert a_facets @ direction == pytest.approx(mu * np.cos(np.pi / k) * G, rel=1e-6)
    assert a_exact @ direction == pytest.approx(mu * G, rel=1e-6)
    # By symmetry about the sliding direction, no sideways friction.
    assert np.linalg.norm(np.cross(a_facets, direction)) < 1e-6 * mu * G


# -- warm start ----------------------------------------------------------------
@pytest.mark.parametrize(
    ("backend", "kind"), [("qp:osqp", "primal"), ("qp:proxqp", "primal and dual")]
)
def test_warm_start_keeps_answer_and_saves_iterations(backend, kind, packing_2d):
    _need(backend)
    problem, _ = packing_2d
    cold = solvers.solve(problem, backend, tol=TOL)
    warm = solvers.solve(problem, backend, tol=TOL, warm_start=cold.p)
    assert cold.status == warm.status == "optimal"
    assert cold.extras["warm_start"] == "none given"
    assert warm.extras["warm_start"] == kind
    assert np.linalg.norm(warm.u - cold.u) <= 1e-7 * np.linalg.norm(cold.u)
    assert 0 < cold.iterations and warm.iterations <= cold.iterations
    if kind == "primal and dual":  # started at the answer: nothing left to do
        assert warm.iterations < cold.iterations


def test_warm_start_refused_where_qpsolvers_drops_it(packing_2d):
    """piqp takes no starting point through qpsolvers: the registry says so, and
    solve() warns and drops the warm start instead of pretending to use it."""
    _need("qp:piqp")
    assert not solvers.get("qp:piqp").warm_start
    problem, ref = packing_2d
    with pytest.warns(UserWarning, match="does not use a warm start"):
        sol = solvers.solve(problem, "qp:piqp", tol=TOL, warm_start=ref.p)
    assert sol.status == "optimal"
    assert sol.extras["warm_start"] == "none given"
    assert "warnings" not in sol.extras


# -- native settings and statuses ----------------------------------------------
@pytest.mark.parametrize("backend", QP_BACKENDS)
def test_unknown_native_setting_raises(backend, packing_2d):
    _need(backend)
    if qpmod._native_names(backend[3:]) is None:
        pytest.skip(f"{backend}: setting names are not checked (see solvers.qpsolvers_)")
    problem, _ = packing_2d
    with pytest.raises(ProblemError, match="no_such_setting"):
        solvers.solve(problem, backend, tol=TOL, no_such_setting=1)


def test_native_settings_pass_through_and_tolerances_follow_tol(packing_2d):
    _need("qp:osqp")
    problem, ref = packing_2d
    sol = solvers.solve(problem, "qp:osqp", tol=TOL, polishing=False, rho=0.2)
    assert sol.status == "optimal"
    assert np.linalg.norm(sol.u - ref.u) <= FIRST_ORDER_U * np.linalg.norm(ref.u)
    with pytest.raises(ProblemError, match="eps_abs"):
        solvers.solve(problem, "qp:osqp", tol=TOL, eps_abs=1e-3)
    with pytest.raises(ProblemError, match="initvals"):
        solvers.solve(problem, "qp:osqp", tol=TOL, initvals=np.zeros(problem.ndof))


@pytest.mark.parametrize(
    ("backend", "native"),
    [
        ("qp:osqp", "OSQP_MAX_ITER_REACHED"),
        ("qp:proxqp", "PROXQP_MAX_ITER_REACHED"),
        ("qp:piqp", "PIQP_MAX_ITER_REACHED"),
        ("qp:clarabel", "MaxIterations"),
        ("qp:scs", "solved (inaccurate - reached max_iters)"),
    ],
)
def test_iteration_limit_is_a_status_not_an_exception(backend, native, packing_2d):
    _need(backend)
    problem, _ = packing_2d
    sol = solvers.solve(problem, backend, tol=TOL, max_iter=1)
    assert sol.status == "max_iter"
    assert sol.extras["native_status"] == native
    assert not sol.found


def test_dense_backends_refuse_huge_problems(packing_2d, monkeypatch):
    _need("qp:quadprog")
    problem, _ = packing_2d
    monkeypatch.setattr(qpmod, "DENSE_ENTRIES_LIMIT", 1000)
    with pytest.raises(ProblemError, match="dense G"):
        solvers.solve(problem, "qp:quadprog", tol=TOL)
