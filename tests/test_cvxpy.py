"""The cvxpy backends (``cvxpy:<SOLVER>``): the modelling reference and its quirks.

The general agreement of every backend with ``clarabel`` is in
test_conformance.py; here: the impulses read from cvxpy's multipliers (sign and
shape of ``cp.SOC`` and inequality duals), the accuracy each cvxpy solver
reaches through cvxpy, QP-only solvers on 2D, what cvxpy's compilation costs,
and the options and statuses cvxpy adds.

Measured on these problems (tol 1e-8, against ``clarabel`` at 1e-10; u relative
to ``max(|u_ref|, |U|)``): ``cvxpy:CLARABEL`` takes clarabel's iterations and
agrees to 1e-10 in u and 5e-10 in p; ``cvxpy:ECOS`` to 1e-7 in u (heap) and
1e-9 in the unique p, after polishing on three problems of four (ECOS's own
answer stops near ccp 1e-6 on resting stacks); ``cvxpy:SCS`` at tol 1e-6
reaches ccp <= 3e-8 and u within 2e-6; ``cvxpy:OSQP`` (its polishing on) and
``cvxpy:PIQP`` agree to 2e-10 in u on the 2D column. The tests assert these
with a margin: u to 1e-6 (SCS 1e-5), unique p to 1e-5.
"""

from __future__ import annotations

import functools
import time

import cvxpy as cp
import numpy as np
import pytest
from test_conformance import clarabel_references, velocity_error

import solvers
from cocd import ProblemError, Scene, Stepper, Wall, box_3d, column_2d, stack
from cocd.residuals import ccp_residual
from solvers import Request, Status
from solvers.cvxpy_ import build_model, cvxpy_solve_problem

TOL = 1e-8
U_REL = 1e-6
P_REL = 1e-5


def _problem_after(scene, steps):
    stepper = Stepper(scene, 1e-3)
    stepper.run(steps)
    return stepper.problem


def _slope_scene(dim: int, degrees: float, radii) -> Scene:
    """Grains resting on a plane under gravity tilted by ``degrees``, mu = 0.3.

    In 3D the tilt is 30 degrees off the x axis, so friction has both tangential
    components.
    """
    theta = np.radians(degrees)
    radii = np.asarray(radii, dtype=float)
    x = np.zeros((radii.size, dim))
    x[:, 0] = 4.0 * radii.max() * np.arange(radii.size)
    x[:, -1] = radii
    g = np.zeros(dim)
    g[-1] = -9.81 * np.cos(theta)
    if dim == 2:
        g[0] = 9.81 * np.sin(theta)
    else:
        phi = np.radians(30.0)
        g[0], g[1] = 9.81 * np.sin(theta) * np.cos(phi), 9.81 * np.sin(theta) * np.sin(phi)
    return Scene(x, radii, walls=[Wall(np.zeros(dim), np.eye(dim)[-1])], gravity=g, mu=0.3)


BUILDERS = {
    "column-2d": lambda: _problem_after(column_2d(60), 20),
    # Spheres of three sizes sliding on a plane tilted by 55 degrees (rolling
    # would need mu >= 2/7 tan 55 = 0.41): friction on the cone's boundary.
    "wall-3d": lambda: _problem_after(_slope_scene(3, 55.0, [0.005, 0.004, 0.006]), 5),
    "heap-3d": lambda: _problem_after(box_3d(27, seed=3), 30),
    "stack-3d": lambda: _problem_after(stack(5, dim=3), 3),
    # Discs sliding down 60 degrees (rolling needs mu >= tan(60)/3 = 0.58).
    "slide-2d": lambda: _problem_after(_slope_scene(2, 60.0, [0.005, 0.004]), 5),
    "frictionless-3d": lambda: _problem_after(stack(4, dim=3, mu=0.0), 3),
}
#: Problems whose impulses are unique (no redundant contacts).
UNIQUE_P = {"wall-3d", "stack-3d", "slide-2d", "frictionless-3d"}


@pytest.fixture(scope="module")
def problems():
    return functools.cache(lambda name: BUILDERS[name]())


@pytest.fixture(scope="module")
def references(problems):
    return clarabel_references(problems)


def _p_error(p, p_ref):
    return np.linalg.norm(p - p_ref) / np.linalg.norm(p_ref)


@pytest.mark.parametrize("name", ["column-2d", "wall-3d", "heap-3d", "stack-3d"])
@pytest.mark.parametrize("backend", ["cvxpy:CLARABEL", "cvxpy:ECOS"])
def test_interior_point_solvers_give_clarabels_answer(backend, name, problems, references):
    problem, ref = problems(name), references(name)
    sol = solvers.solve(problem, backend, tol=TOL)
    assert sol.status == Status.OPTIMAL
    assert ccp_residual(problem, sol.p) <= TOL
    assert velocity_error(problem, sol.u, ref.u) <= U_REL
    if name in UNIQUE_P:
        assert _p_error(sol.p, ref.p) <= P_REL
    assert sol.iterations > 0
    assert sol.solver == backend
    assert sol.extras["cvxpy_solver"] == backend.split(":")[1]


@pytest.mark.parametrize("name", ["slide-2d", "wall-3d", "frictionless-3d"])
def test_impulses_from_each_kind_of_multiplier(name, problems, references):
    """Half-planes (2D), ``cp.SOC`` pairs (3D) and plain inequalities (frictionless)."""
    problem, ref = problems(name), references(name)
    sol = solvers.solve(problem, "cvxpy:CLARABEL", tol=1e-10, polish=False)
    # The multipliers alone, unpolished, are clarabel's impulses.
    assert _p_error(sol.p, ref.p) <= 1e-7
    if problem.contact_dim > 1:
        # Every grain slides: friction on the boundary of its cone, against the motion.
        pt = np.linalg.norm(sol.p[:, 1:], axis=1)
        np.testing.assert_allclose(pt, problem.mu * sol.p[:, 0], rtol=1e-6)
        slip = problem.relative_velocity(sol.u)[:, 1:]
        assert np.all(np.sum(slip * sol.p[:, 1:], axis=1) < 0.0)
    else:
        # A resting frictionless stack: the k-th contact from the top carries k weights.
        weight = problem.mass[0] * 9.81 * problem.dt
        np.testing.assert_allclose(np.sort(sol.p[:, 0]), weight * np.arange(1, 5), rtol=1e-8)


@pytest.mark.parametrize("name", ["column-2d", "wall-3d", "heap-3d", "stack-3d"])
def test_scs_through_cvxpy_reaches_the_target(name, problems, references):
    """SCS at tol 1e-6 (first order: native eps = tol, then polishing) meets it,
    with velocities within 1e-5 of clarabel's."""
    problem, ref = problems(name), references(name)
    sol = solvers.solve(problem, "cvxpy:SCS", tol=1e-6)
    assert sol.status == Status.OPTIMAL
    assert ccp_residual(problem, sol.p) <= 1e-6
    assert velocity_error(problem, sol.u, ref.u) <= 1e-5


@pytest.mark.parametrize("backend", ["cvxpy:OSQP", "cvxpy:PIQP"])
def test_qp_only_solvers_take_2d_and_refuse_3d_friction(backend, problems, references):
    problem, ref = problems("column-2d"), references("column-2d")
    sol = solvers.solve(problem, backend, tol=TOL)
    assert sol.status == Status.OPTIMAL
    assert velocity_error(problem, sol.u, ref.u) <= U_REL
    assert ccp_residual(problem, sol.p) <= TOL
    slide = problems("slide-2d")
    assert _p_error(solvers.solve(slide, backend, tol=TOL).p, references("slide-2d").p) <= P_REL
    # Called directly (solvers.solve refuses earlier), the backend refuses too.
    with pytest.raises(ProblemError, match="linear cones only"):
        cvxpy_solve_problem(
            problems("stack-3d"), Request(tol=TOL), cvxpy_solver=backend.split(":")[1]
        )


def test_objective_compiles_without_auxiliary_variables(problems, references):
    """``1/2 sum(M/ms x^2)`` reaches the solver as a diagonal ``P`` on ``ndof``
    variables; ``sum_squares(sqrt(M/ms) x)`` would add ``ndof`` more, and HiGHS's QP
    solver rejects that form as non-convex."""
    problem = problems("column-2d")
    model = build_model(problem)
    data, _, _ = model.cvx.get_problem_data("CLARABEL")
    assert data["P"].shape == (problem.ndof, problem.ndof)
    assert data["A"].shape == (2 * problem.nc, problem.ndof)
    sol = solvers.solve(problems("slide-2d"), "cvxpy:HIGHS", tol=TOL)
    assert sol.status == Status.OPTIMAL
    assert _p_error(sol.p, references("slide-2d").p) <= P_REL


def test_setup_time_is_cvxpys_compilation(problems, monkeypatch):
    compiling: list[float] = []
    real = cp.Problem.get_problem_data

    def timed(self, *args, **kwargs):
        begin = time.perf_counter()
        try:
            return real(self, *args, **kwargs)
        finally:
            compiling.append(time.perf_counter() - begin)

    monkeypatch.setattr(cp.Problem, "get_problem_data", timed)
    problem = problems("heap-3d")
    begin = time.perf_counter()
    sol = solvers.solve(problem, "cvxpy:CLARABEL", tol=TOL)
    wall = time.perf_counter() - begin
    # The first compilation (get_problem_data called by the backend) and the
    # cached fast path of every solve are set-up; the rest is solving.
    assert len(compiling) == 1 + sol.extras["solves"]
    first_compile = compiling[0]
    assert sol.extras["compile_time"] > first_compile > 0.0
    assert sol.setup_time == pytest.approx(sol.extras["build_time"] + sol.extras["compile_time"])
    assert 0.0 < sol.solve_time < wall
    assert sol.setup_time + sol.solve_time <= wall
    assert sol.extras["native_solve_time"] <= sol.solve_time


def test_options_cvxpy_refuses_or_passes_on(problems):
    problem = problems("stack-3d")
    ok = solvers.solve(problem, "cvxpy:CLARABEL", tol=TOL, direct_solve_method="qdldl")
    assert ok.status == Status.OPTIMAL
    with pytest.raises(ProblemError, match="has no setting 'bogus'"):
        solvers.solve(problem, "cvxpy:CLARABEL", bogus=1)
    with pytest.raises(ProblemError, match="'tol_feas' is set by cocd"):
        solvers.solve(problem, "cvxpy:CLARABEL", tol_feas=1e-3)
    with pytest.raises(ProblemError, match="'eps_abs' is set by cocd"):
        solvers.solve(problems("column-2d"), "cvxpy:OSQP", eps_abs=1e-3)
    with pytest.raises(ProblemError, match="'max_iters' is set by cocd"):
        solvers.solve(problem, "cvxpy:ECOS", max_iters=3)
    with pytest.raises(ProblemError, match="takes no 'facets'"):
        solvers.solve(problem, "cvxpy:CLARABEL:facets=8")


def test_statuses_from_cvxpy(problems, monkeypatch):
    problem = problems("heap-3d")
    capped = solvers.solve(problem, "cvxpy:CLARABEL", tol=TOL, max_iter=2)
    assert capped.status == Status.MAX_ITER
    assert capped.extras["native_status"] == "user_limit"
    assert capped.iterations == 2

    def failing(self, *args, **kwargs):
        raise cp.error.SolverError("Solver 'CLARABEL' failed.")

    monkeypatch.setattr(cp.Problem, "solve", failing)
    failed = solvers.solve(problem, "cvxpy:CLARABEL", tol=TOL)
    assert failed.status == Status.ERROR
    assert not failed.found
    assert failed.extras["native_status"].startswith("solver_error")
