"""Quirks of the conic backends SCS, ECOS and Mosek (the conformance suite is elsewhere).

Accuracy measured on the module's two problems: a 2D column (``column_2d(60)``
after 20 steps, 162 contacts) and a 3D heap (36 spheres in a box after 20
steps, 132 contacts). ``u err``: relative 2-norm distance of the velocities to
Clarabel's at tol 1e-10; iterations as counted by the backend:

=========  =====  ==========================  ==========================
backend    dim    tol = 1e-6: ccp, u err, it  tol = 1e-8: ccp, u err, it
=========  =====  ==========================  ==========================
scs        2D     4e-9, 2e-8, 75              4e-9, 2e-8, 75
scs        3D     8e-9, 7e-8, 75              2e-10, 1e-9, 100
scs-dual   2D     2e-12, 1e-11, 125           2e-12, 1e-11, 125
scs-dual   3D     2e-12, 8e-12, 125           2e-12, 8e-12, 125
ecos       2D     4e-8, 4e-10, 17             4e-12, 7e-13, 23
ecos       3D     3e-9, 4e-7, 12              1e-9, 6e-8, 13
=========  =====  ==========================  ==========================

SCS tests convergence every 25 iterations, and with Anderson acceleration its
first test that passes is often already far below ``tol``. The bounds
asserted below are these numbers with a margin.
"""

from __future__ import annotations

import numpy as np
import pytest

import cocd
import solvers
from cocd import Scene, SolverNotFound, Stepper, Wall
from cocd.residuals import ccp_residual
from cocd.stepper import match_impulses
from solvers import Request

REFERENCE_TOL = 1e-10


def heap(nx: int, nz: int, *, mu_wall: float | None = None, seed: int = 3) -> Scene:
    """Spheres on a jittered cubic lattice in a box open at the top."""
    rng = np.random.default_rng(seed)
    r = 0.005
    cells = np.stack(np.meshgrid(np.arange(nx), np.arange(nx), np.arange(nz), indexing="ij"), -1)
    n = nx * nx * nz
    x = cells.reshape(-1, 3) * 2.2 * r + 1.1 * r + rng.uniform(-0.05 * r, 0.05 * r, (n, 3))
    side = nx * 2.2 * r
    walls = [
        Wall((0, 0, 0), (0, 0, 1)),
        Wall((0, 0, 0), (1, 0, 0)),
        Wall((0, 0, 0), (0, 1, 0)),
        Wall((side, 0, 0), (-1, 0, 0)),
        Wall((0, side, 0), (0, -1, 0)),
    ]
    radii = r * (1 + 0.1 * (rng.random(n) - 0.5))
    return Scene(x, radii, walls=walls, mu=0.4, mu_wall=mu_wall)


def _stepped(scene: Scene, steps: int) -> Stepper:
    stepper = Stepper(scene, 1e-3, tol=REFERENCE_TOL)
    stepper.run(steps)
    return stepper


@pytest.fixture(scope="module")
def problems():
    """A 2D and a 3D step problem with their Clarabel reference answers."""
    out = {}
    for name, scene in (("2d", cocd.column_2d(60)), ("3d", heap(3, 4))):
        problem = _stepped(scene, 20).problem
        ref = solvers.solve(problem, "clarabel", tol=REFERENCE_TOL)
        assert ref.status == "optimal"
        out[name] = (problem, ref)
    return out


def _rel(a, b) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


# -- SCS -----------------------------------------------------------------------
@pytest.mark.parametrize("dim", ["2d", "3d"])
@pytest.mark.parametrize("solver", ["scs", "scs-dual"])
@pytest.mark.parametrize(("tol", "u_bound"), [(1e-6, 1e-5), (1e-8, 1e-7)])
def test_scs_agrees_with_clarabel(problems, dim, solver, tol, u_bound):
    problem, ref = problems[dim]
    sol = solvers.solve(problem, solver, tol=tol)
    assert sol.status == "optimal"
    assert ccp_residual(problem, sol.p) <= tol
    assert _rel(sol.u, ref.u) <= u_bound
    assert sol.iterations > 0 and sol.extras["solves"] >= 1


def test_scs_primal_warm_start_multipliers_invert_the_impulse_map():
    """The primal warm start needs the duals ``y`` whose impulses are ``p0``, mu = 0 included."""
    from solvers.scs_ import _multipliers

    rng = np.random.default_rng(0)
    mu = np.array([0.0, 0.3, 0.8])
    for dim in (2, 3):
        ndof = 3 if dim == 2 else 6
        problem = cocd.ConicProblem(
            dim=dim,
            contact_dim=dim,
            mass=np.ones(ndof),
            H=np.zeros((3 * dim, ndof)),
            D=np.zeros(3),
            mu=mu,
            dt=1e-3,
            U=np.ones(ndof),
        )
        p = rng.normal(size=(3, dim))
        p[:, 0] += 3.0
        p = cocd.project_coulomb(p, mu)
        form = problem.primal_conic_form()
        z = _multipliers(problem, p) / (form.mass_scale * form.velocity_scale)
        assert np.all(z.reshape(3, dim)[:, 0] >= 0.0)
        np.testing.assert_allclose(form.impulses(z), p, atol=1e-14)


@pytest.mark.parametrize("solver", ["scs", "scs-dual"])
def test_scs_warm_start_from_a_resting_step_needs_no_iteration(solver):
    """A stack at rest: the previous step's impulses are this step's answer."""
    stepper = _stepped(cocd.stack(4, dim=3, mu=0.5), 5)
    prev_keys, prev_p = stepper.contacts.keys, stepper.solution.p
    stepper.step()
    problem = stepper.problem
    p0 = match_impulses(prev_keys, prev_p, stepper.contacts.keys)
    cold = solvers.solve(problem, solver, tol=1e-8)
    warm = solvers.solve(problem, solver, tol=1e-8, warm_start=p0)
    assert warm.status == cold.status == "optimal"
    assert cold.iterations >= 25
    assert warm.iterations < cold.iterations
    assert warm.iterations == 0  # SCS checks convergence at iteration 0
    scale = np.abs(cold.p).max()
    np.testing.assert_allclose(warm.p, cold.p, atol=1e-9 * scale)


def test_scs_warm_start_reduces_iterations_in_a_settling_heap():
    """Ten steps of a settling heap, each solved cold and from the previous step's impulses.

    Measured (tol 1e-8): primal 1100 -> 925 iterations, dual 1475 -> 1000; the
    velocities differ by at most 2e-7 relative.
    """
    stepper = _stepped(heap(3, 3), 40)
    totals = {"scs": [0, 0], "scs-dual": [0, 0]}
    for _ in range(10):
        prev_keys, prev_p = stepper.contacts.keys, stepper.solution.p
        stepper.step()
        problem, ref = stepper.problem, stepper.solution
        p0 = match_impulses(prev_keys, prev_p, stepper.contacts.keys)
        for solver, counts in totals.items():
            cold = solvers.solve(problem, solver, tol=1e-8)
            warm = solvers.solve(problem, solver, tol=1e-8, warm_start=p0)
            assert cold.status == warm.status == "optimal"
            counts[0] += cold.iterations
            counts[1] += warm.iterations
            # The warm start does not change the answer, to the accuracy asked.
            assert _rel(warm.u, cold.u) <= 2e-6
            assert _rel(warm.u, ref.u) <= 2e-6
    for solver, (cold_total, warm_total) in totals.items():
        assert warm_total < cold_total, (solver, cold_total, warm_total)


def test_scs_with_smooth_walls_zero_cones_and_warm_start():
    """Smooth walls in a rough heap give zero cones in the dual (SCS's ``z`` cone)."""
    stepper = _stepped(heap(2, 2, mu_wall=0.0), 15)
    problem, ref = stepper.problem, stepper.solution
    kinds = {kind for kind, _ in problem.dual_conic_form().cones}
    assert kinds == {"zero", "nonneg", "soc"}
    for solver in ("scs", "scs-dual"):
        cold = solvers.solve(problem, solver, tol=1e-8)
        warm = solvers.solve(problem, solver, tol=1e-8, warm_start=ref.p)
        assert cold.status == warm.status == "optimal"
        assert _rel(cold.u, ref.u) <= 1e-6
        assert warm.iterations < cold.iterations


def test_scs_unknown_and_mapped_options_are_refused(problems):
    problem, _ = problems["2d"]
    with pytest.raises(cocd.ProblemError, match=r"'eps_abs'.*follow"):
        solvers.solve(problem, "scs", eps_abs=1e-3)
    with pytest.raises(cocd.ProblemError, match="'bogus'"):
        solvers.solve(problem, "scs-dual", bogus=1)
    sol = solvers.solve(problem, "scs", tol=1e-6, linear_solver="qdldl")
    assert sol.status == "optimal"


def test_scs_iteration_cap_gives_its_best_guess(problems):
    """At the cap SCS returns ``solved (inaccurate ...)``: judged, polished, never dropped."""
    problem, _ = problems["3d"]
    sol = solvers.solve(problem, "scs", tol=1e-10, max_iter=5)
    assert "inaccurate" in sol.extras["native_status"]
    assert sol.status in ("optimal", "inaccurate")
    assert sol.iterations <= 5 * sol.extras["solves"]
    assert np.all(np.isfinite(sol.p))


# -- ECOS ----------------------------------------------------------------------
@pytest.mark.parametrize("dim", ["2d", "3d"])
def test_ecos_agrees_with_clarabel(problems, dim):
    problem, ref = problems[dim]
    sol = solvers.solve(problem, "ecos", tol=1e-8)
    assert sol.status == "optimal"
    assert _rel(sol.u, ref.u) <= 1e-6
    # The duals of the contact rows are Clarabel's multipliers (same scale, same sign).
    assert _rel(sol.p, ref.p) <= 1e-5


@pytest.mark.parametrize("dim", ["2d", "3d"])
def test_ecos_epigraph_objective_is_the_quadratic(problems, dim):
    """At ECOS's answer ``t = 1/2 x'Px``: the epigraph cone is tight."""
    problem, _ = problems[dim]
    sol = solvers.solve(problem, "ecos", tol=1e-8, polish=False)
    form = problem.primal_conic_form()
    x = (sol.u - problem.U) / form.velocity_scale  # ECOS's own x (not polished)
    quadratic = 0.5 * float(x @ (form.P @ x))
    t = sol.extras["epigraph_t"]
    assert quadratic > 0.0
    assert abs(t - quadratic) <= 1e-8 * quadratic
    assert abs(sol.extras["objective"] - quadratic) <= 1e-8 * quadratic
    # ...and it is the optimal value Clarabel finds for the quadratic form.
    clarabel = solvers.solve(problem, "clarabel", tol=1e-10, polish=False)
    assert abs(clarabel.extras["objective"] - quadratic) <= 1e-7 * quadratic


def test_ecos_has_no_warm_start(problems):
    problem, ref = problems["2d"]
    assert not solvers.get("ecos").warm_start
    with pytest.warns(UserWarning, match="does not use a warm start"):
        sol = solvers.solve(problem, "ecos", tol=1e-6, warm_start=ref.p)
    assert sol.status == "optimal"


# -- Mosek ---------------------------------------------------------------------
def _mosek_usable() -> bool:
    return "mosek" in solvers.available()


@pytest.mark.skipif(_mosek_usable(), reason="Mosek has a licence here")
@pytest.mark.parametrize("name", ["mosek", "mosek-dual"])
def test_mosek_without_licence_is_listed_unavailable(problems, name):
    pytest.importorskip("mosek")
    reason = solvers.unavailable()[name]
    assert "licen" in reason.lower()
    assert name not in solvers.available()
    problem, _ = problems["2d"]
    with pytest.raises(SolverNotFound, match=rf"'{name}' is registered but unavailable.*[Ll]icen"):
        solvers.solve(problem, name)


@pytest.mark.skipif(_mosek_usable(), reason="Mosek has a licence here")
@pytest.mark.parametrize("dim", ["2d", "3d"])
def test_mosek_backends_build_and_configure_up_to_the_licence_check(problems, dim):
    """Called directly, past the registry, each backend builds its task, sets every
    parameter and fails only where Mosek checks out a licence, in ``optimize``."""
    mosek = pytest.importorskip("mosek")
    from solvers.mosek_ import mosek_dual_solve_problem, mosek_solve_problem

    problem, _ = problems[dim]
    for solve in (mosek_solve_problem, mosek_dual_solve_problem):
        with pytest.raises(mosek.Error, match=r"[Ll]icen"):
            solve(problem, Request(tol=1e-8, max_iter=50, time_limit=10.0), num_threads=1)
        with pytest.raises(cocd.ProblemError, match="'bogus'"):
            solve(problem, Request(tol=1e-8), bogus=1)


@pytest.mark.skipif(not _mosek_usable(), reason="Mosek needs a licence")
@pytest.mark.parametrize("dim", ["2d", "3d"])
@pytest.mark.parametrize("name", ["mosek", "mosek-dual"])
def test_mosek_agrees_with_clarabel(problems, dim, name):
    problem, ref = problems[dim]
    sol = solvers.solve(problem, name, tol=1e-8)
    assert sol.status == "optimal"
    assert _rel(sol.u, ref.u) <= 1e-6


def _read_task(task):
    """``(c, F, g, [(domain type, afe indices)])`` of a Mosek task, read back from Mosek."""
    import mosek
    import scipy.sparse as sp

    n, nafe = task.getnumvar(), task.getnumafe()
    rows, cols, vals = task.getafeftrip()
    F = sp.csr_matrix((np.asarray(vals), (np.asarray(rows), np.asarray(cols))), shape=(nafe, n))
    g = np.asarray(task.getafegslice(0, nafe))
    bk, _, _ = task.getvarboundslice(0, n)
    assert all(k == mosek.boundkey.fr for k in bk)
    assert task.getobjsense() == mosek.objsense.minimize
    accs = []
    for i in range(task.getnumacc()):
        kind = str(task.getdomaintype(task.getaccdomain(i))).split(".")[-1]
        assert not np.any(np.asarray(task.getaccb(i)))
        accs.append((kind, np.asarray(task.getaccafeidxlist(i))))
    return np.asarray(task.getc()), F, g, accs


def _in_cone(kind: str, v, tol: float) -> bool:
    if kind == "rzero":
        return bool(np.abs(v).max() <= tol)
    if kind == "r":
        return True
    if kind == "rplus":
        return bool(v.min() >= -tol)
    if kind == "quadratic_cone":
        return bool(v[0] >= np.linalg.norm(v[1:]) - tol)
    assert kind == "rquadratic_cone"
    return bool(min(v[0], v[1]) >= -tol and 2 * v[0] * v[1] >= v[2:] @ v[2:] - tol)


def _clarabel_native(form):
    """Clarabel's own ``(x, z)`` for a conic form, solved tight."""
    import clarabel
    import scipy.sparse as sp

    make = {
        "zero": clarabel.ZeroConeT,
        "nonneg": clarabel.NonnegativeConeT,
        "soc": clarabel.SecondOrderConeT,
    }
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    settings.tol_gap_abs = settings.tol_gap_rel = settings.tol_feas = 1e-12
    cones = [make[kind](size) for kind, size in form.cones]
    P = sp.triu(form.P, format="csc")
    sol = clarabel.DefaultSolver(P, form.q, form.A, form.b, cones, settings).solve()
    assert str(sol.status).endswith("Solved")
    return sol


_DUAL_DOMAIN = {"rzero": "r", "rplus": "rplus", "quadratic_cone": "quadratic_cone"}


@pytest.mark.parametrize("case", ["2d", "3d", "3d-smooth-walls"])
@pytest.mark.parametrize("formulation", ["primal", "dual"])
def test_mosek_model_and_dual_signs_without_a_licence(problems, case, formulation):
    """Build the Mosek task (no licence needed), read it back, and check it with Clarabel's answer.

    Mosek's dual of ``min c'x, Fx + g in D`` is ``max -g'y, F'y = c, y in D*``.
    Clarabel's ``(x, z)`` extended by ``t = 1/2 x'Px`` and the objective cone's
    multiplier ``(1, t, -w)`` must be a primal-dual optimal pair of the task,
    with ``z`` as the ACC duals of the contact rows: the model, the cone order
    and the sign the backend reads impulses with are all checked.
    """
    mosek = pytest.importorskip("mosek")
    from solvers.mosek_ import build_dual_task, build_primal_task

    if case == "3d-smooth-walls":
        problem = _stepped(heap(2, 2, mu_wall=0.0), 15).problem
    else:
        problem = problems[case][0]
    form = problem.primal_conic_form() if formulation == "primal" else problem.dual_conic_form()
    native = _clarabel_native(form)
    x, z = np.asarray(native.x), np.asarray(native.z)
    with mosek.Task() as task:
        if formulation == "primal":
            build_primal_task(task, form)
        else:
            build_dual_task(task, form)
        c, F, g, accs = _read_task(task)
    t = 0.5 * float(x @ (form.P @ x))
    xx = np.concatenate([x, [t]])
    fx = F @ xx + g
    *contact_accs, (objective_kind, objective_rows) = accs
    assert objective_kind == "rquadratic_cone"
    y = np.zeros(F.shape[0])
    y[: z.size] = z
    y[objective_rows] = np.concatenate([[1.0, t], -fx[objective_rows][2:]])
    scale = max(1.0, float(np.abs(c).max()))
    assert np.abs(F.T @ y - c).max() <= 1e-9 * scale  # dual feasible: F'y = c
    for kind, rows in contact_accs:
        assert _in_cone(kind, fx[rows], 1e-9)
        assert _in_cone(_DUAL_DOMAIN[kind], y[rows], 1e-9)
    assert _in_cone(objective_kind, fx[objective_rows], 1e-9)
    assert _in_cone(objective_kind, y[objective_rows], 1e-9)
    primal, dual = float(c @ xx), float(-g @ y)
    assert abs(primal - dual) <= 1e-8 * max(1.0, abs(primal))  # no duality gap
    assert abs(primal - native.obj_val) <= 1e-8 * max(1.0, abs(primal))
    if case == "3d-smooth-walls":
        kinds = {kind for kind, _ in contact_accs}
        assert kinds == (
            {"rzero", "rplus", "quadratic_cone"} if formulation == "dual" else {"quadratic_cone"}
        )
