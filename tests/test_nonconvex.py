"""The non-convex Coulomb law: ``nscd`` and ``fp:<backend>`` against each other, against
analytic answers, and against the convexified law (COCD) where the two laws differ.

``nscd`` is non-linear Gauss-Seidel with an exact one-contact solver
(:mod:`solvers._nscd_local_kernels`); ``fp:<backend>`` is Cadoux's fixed point on convex
problems whose gaps are shifted by ``dt mu |w_T|``. Both are judged by
``coulomb_residual`` (the suite-wide check in conftest.py asserts it is at most
``10 tol`` for every ``optimal`` answer).

The two laws differ only at sliding contacts. For a grain sliding on a horizontal wall
with slip ``|w_T|``, the non-convex law keeps ``w_N = 0``: the contact stays closed and
the grain decelerates at ``mu g`` from the first step. The convexified constraint
``D/dt + v_N >= mu |w_T|`` is active while sliding, ``w_N = D^k/dt + v_N^{k+1} =
mu |w_T^{k+1}|``, so the gap at the end of every such step is exactly
``D^{k+1} = D^k + dt v_N^{k+1} = dt mu |w_T^{k+1}|``. Started touching the wall
(``D = 0``), the grain leaves it with ``v_N = mu |w_T|`` and flies; started at the
gap the scheme keeps (``dt mu v0``), it slides on a cushion ``dt mu |w_T^k|`` and its
normal impulse per step obeys ``q_k (1 + mu c) = g dt + mu c q_{k-1}`` (``q = p_N / m``,
``c = mu (1 + 1/kappa)`` the rate at which the slip falls per unit of ``q``,
``kappa = J / (m R^2)``), i.e. ``q_k = g dt (1 - lambda^k)`` with
``lambda = mu c / (1 + mu c)``: the deceleration tends to ``mu g`` geometrically.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
from test_conformance import velocity_error

import solvers
from cocd import (
    ProblemError,
    Scene,
    SolverNotFound,
    Stepper,
    Wall,
    assemble,
    box_3d,
    column_2d,
    detect_contacts,
    stack,
)
from cocd.residuals import coulomb_residual
from solvers import _nscd_local_kernels as kernels

DT = 1e-3
G = 9.81
MU = 0.3
RADIUS = 0.01
TOL = 1e-9
COULOMB = 1e-8
SAME_U = 1e-6
NONCONVEX = ["nscd", "fp:clarabel-dual", "fp:clarabel"]
#: Problems whose velocities are unique (a single contact; a chain of contacts).
UNIQUE = {"slide-2d", "slide-3d", "stack-2d", "stack-3d"}


def on_wall(dim: int, *, v0: float = 1.0, gap: float = 0.0, mu: float = MU) -> Scene:
    """One grain sliding at ``v0`` along x on a horizontal wall, ``gap`` above it, no spin."""
    x = np.zeros((1, dim))
    x[0, -1] = RADIUS + gap
    v = np.zeros((1, dim))
    v[0, 0] = v0
    return Scene(x, RADIUS, velocities=v, walls=[Wall(np.zeros(dim), np.eye(dim)[-1])], mu=mu)


def heap_3d() -> Scene:
    """27 spheres in a box, thrown with random velocities and spins: sliding contacts."""
    scene = box_3d(27, mu=0.4)
    rng = np.random.default_rng(0)
    scene.velocities[:] = rng.normal(0.0, 0.2, scene.velocities.shape)
    scene.angular_velocities[:] = rng.normal(0.0, 20.0, scene.angular_velocities.shape)
    return scene


def _build(name: str):
    """The step problem after a few steps of clarabel (COCD) on the scene."""
    scenes = {
        "slide-2d": (lambda: on_wall(2), 0),
        "slide-3d": (lambda: on_wall(3), 0),
        "column-2d": (lambda: column_2d(60), 20),
        "heap-3d": (heap_3d, 15),
        "stack-2d": (lambda: stack(10, dim=2, radius=RADIUS), 3),
        "stack-3d": (lambda: stack(10, dim=3, radius=RADIUS), 3),
    }
    make, steps = scenes[name]
    scene = make()
    Stepper(scene, DT, tol=1e-10).run(steps)
    return assemble(scene, detect_contacts(scene), DT)


@pytest.fixture(scope="module")
def problems():
    return functools.cache(_build)


# -- the local solver ----------------------------------------------------------
def _random_block(rng, m, generic=None):
    """A random SPD block: generic (coupled, anisotropic) or near a grain's."""
    if generic is None:
        generic = rng.random() < 0.5
    if generic:
        a = rng.normal(size=(m, m))
        W = a @ a.T + 0.02 * np.eye(m)
    else:
        W = np.diag(np.r_[1.0, np.full(m - 1, 3.5)]) * (1.0 + 0.2 * rng.normal(size=m)) ** 2
        W[0, 1:] = W[1:, 0] = 0.05 * rng.normal(size=m - 1)
    return W * 10.0 ** rng.uniform(-3, 3)


@pytest.mark.parametrize("m", [1, 2, 3])
def test_local_solver_is_exact(m):
    """Every branch it returns satisfies the one-contact law to rounding, for any mu."""
    rng = np.random.default_rng(m)
    seen = set()
    out = np.zeros(m)
    for _ in range(3000):
        W = _random_block(rng, m) if m > 1 else np.array([[10.0 ** rng.uniform(-3, 3)]])
        r = rng.normal(size=m) * 10.0 ** rng.uniform(-3, 3)
        mu = float(rng.choice([0.0, 0.1, 0.3, 1.0, 5.0]))
        branch = kernels.local_solve(W, np.linalg.inv(W), r, mu, out)
        seen.add(branch)
        scale = np.linalg.norm(r) * m / np.trace(W)
        assert kernels._local_residual(W, r, mu, out) <= 1e-12 * scale
        w = W @ out + r
        pt = np.linalg.norm(out[1:])
        if branch == kernels.SEPARATED:
            assert np.all(out == 0.0) and w[0] >= 0.0
        elif branch == kernels.STICK:
            assert out[0] >= 0.0 and pt <= mu * out[0] * (1 + 1e-12)
            if m > 1 and mu > 0:
                assert np.linalg.norm(w) <= 1e-10 * np.linalg.norm(r)
        else:
            assert out[0] > 0.0 and pt == pytest.approx(mu * out[0], rel=1e-12)
            assert abs(w[0]) <= 1e-10 * np.linalg.norm(r)
    assert seen == ({0, 1} if m == 1 else {0, 1, 2})


@pytest.mark.parametrize("m", [2, 3])
def test_fischer_burmeister_local_solver_with_exact_fallback(m):
    """The hybrid local solver always meets the one-contact law to rounding (Newton's
    answer is checked, the exact solver takes over when it misses); Newton answers most
    blocks from arbitrary starts, and at once from a solution."""
    rng = np.random.default_rng(10 + m)
    out = np.zeros(m)
    shared = np.zeros(m)
    work = kernels.fb_workspace(m)  # one scratch for every block, as a sweep keeps it
    newton = 0
    n = 2000
    for _ in range(n):
        W = _random_block(rng, m)
        Winv = np.linalg.inv(W)
        r = rng.normal(size=m) * 10.0 ** rng.uniform(-3, 3)
        mu = float(rng.choice([0.1, 0.3, 1.0, 5.0]))
        start = rng.normal(size=m) * np.linalg.norm(Winv @ r) if rng.random() < 0.5 else np.zeros(m)
        answered = kernels.local_solve_fb(W, Winv, r, mu, start, out)
        newton += answered
        # What the previous block left in the scratch changes nothing.
        assert kernels.local_solve_fb(W, Winv, r, mu, start, shared, work) == answered
        np.testing.assert_array_equal(shared, out)
        scale = np.linalg.norm(r) * m / np.trace(W)
        assert kernels._local_residual(W, r, mu, out) <= 1e-12 * scale
        exact = np.zeros(m)
        kernels.local_solve(W, Winv, r, mu, exact)
        again = np.zeros(m)
        assert kernels.local_solve_fb(W, Winv, r, mu, exact, again)
        assert np.allclose(again, exact, rtol=0.0, atol=1e-9 * scale)
    assert newton >= 0.8 * n


@pytest.mark.parametrize("problem_name", ["column-2d", "heap-3d", "stack-3d"])
def test_nscd_local_strategies_agree(problem_name, problems):
    problem = problems(problem_name)
    exact = solvers.solve(problem, "nscd", tol=TOL)
    fb = solvers.solve(problem, "nscd", tol=TOL, local="fb")
    assert exact.status == fb.status == "optimal"
    assert coulomb_residual(problem, fb.p) <= COULOMB
    assert fb.extras["local"] == "fb" and exact.extras["local"] == "exact"
    assert fb.extras["local_newton"] > fb.extras["local_fallbacks"]
    if problem_name in UNIQUE:
        assert velocity_error(problem, fb.u, exact.u) <= SAME_U


def test_local_3d_sliding_every_angle_finder_agrees():
    """Newton from the stick trial, the roots of the quartic (from any start) and the
    last resort, a scan with bisection, find valid slip angles. The scan can miss a root
    next to the angles where ``W_NN - mu W_NT e <= 0`` (generic blocks, large mu): it is
    checked on grain-like blocks only."""
    rng = np.random.default_rng(7)
    checked = 0
    while checked < 300:
        generic = checked % 2 == 0
        W = _random_block(rng, 3, generic)
        r = rng.normal(size=3)
        mu = float(rng.choice([0.3, 1.0, 2.0]))
        out = np.zeros(3)
        if kernels.local_solve(W, np.linalg.inv(W), r, mu, out) != kernels.SLIDE:
            continue
        theta = np.arctan2(-out[2], -out[1])
        start = theta + rng.uniform(-np.pi, np.pi)
        finders = [kernels._polynomial_angle] + ([] if generic else [kernels._scan_angle])
        for finder in finders:
            ok, found = finder(W, r, mu, start)
            assert ok
            valid, f, _, g, scale = kernels._slide_eval(W, r, mu, found)
            assert valid and g >= 0.0 and abs(f) <= 1e-9 * scale
        checked += 1


# -- the two non-convex backends agree ------------------------------------------
@pytest.mark.parametrize(
    "problem_name", ["slide-2d", "slide-3d", "column-2d", "heap-3d", "stack-2d", "stack-3d"]
)
def test_nonconvex_backends_agree(problem_name, problems):
    problem = problems(problem_name)
    answers = {}
    for name in NONCONVEX:
        sol = solvers.solve(problem, name, tol=TOL)
        assert sol.status == "optimal", (name, sol.status, sol.extras.get("history"))
        assert coulomb_residual(problem, sol.p) <= COULOMB
        answers[name] = sol
    nscd = answers["nscd"]
    if problem_name in UNIQUE:
        for name in NONCONVEX[1:]:
            assert velocity_error(problem, answers[name].u, nscd.u) <= SAME_U, name
    if problem_name.startswith(("slide", "column", "heap")):
        # The cases exercise the sliding branch, where the two laws differ...
        assert nscd.extras["branches"]["slide"] >= 1
        # ...visibly: the convex answer is not a solution of the Coulomb law.
        cocd = solvers.solve(problem, "clarabel", tol=TOL)
        assert coulomb_residual(problem, cocd.p) > 1e3 * COULOMB


def test_fp_counts_inner_iterations(problems):
    problem = problems("column-2d")
    sol = solvers.solve(problem, "fp:clarabel-dual", tol=TOL)
    history = sol.extras["history"]
    assert sol.extras["outer"] == len(history) >= 2
    assert sol.iterations == sum(inner for _, _, inner, _ in history)
    assert history[-1][3] <= TOL
    # The first outer iteration is the convex (COCD) problem itself.
    first = solvers.solve(problem, "clarabel-dual", tol=0.1 * TOL)
    assert history[0][3] == pytest.approx(coulomb_residual(problem, first.p), rel=1e-3)


def test_warm_start_from_a_solution(problems):
    problem = problems("column-2d")
    ref = solvers.solve(problem, "nscd", tol=TOL)
    again = solvers.solve(problem, "nscd", tol=TOL, warm_start=ref.p)
    assert again.iterations == 0 and again.status == "optimal"
    fp = solvers.solve(problem, "fp:scs-dual", tol=TOL, warm_start=ref.p)
    assert fp.status == "optimal" and fp.extras["outer"] <= 2


# -- resting stack: analytic impulses --------------------------------------------
@pytest.mark.parametrize("dim", [2, 3])
def test_resting_stack_nscd(dim):
    n = 10
    scene = stack(n, radius=RADIUS, dim=dim)
    stepper = Stepper(scene, DT, solver="nscd", tol=1e-10)
    stepper.run(20)
    assert np.abs(scene.velocities).max() < 1e-8
    contacts, p = stepper.contacts, stepper.solution.p
    assert contacts is not None
    m = scene.masses[0]
    heights = np.where(
        contacts.j >= 0,
        0.5 * (scene.positions[contacts.i, -1] + scene.positions[np.maximum(contacts.j, 0), -1]),
        0.0,
    )
    touching = contacts.gap < 1e-9
    pn = p[touching, 0][np.argsort(-heights[touching])]
    assert pn.size == n
    # Contact k from the top carries the weight of the k grains above it.
    np.testing.assert_allclose(pn, np.arange(1, n + 1) * m * G * DT, rtol=1e-6)
    np.testing.assert_allclose(p[:, 1:], 0.0, atol=1e-9 * m * G * DT)
    # Nothing slides: the convex and non-convex laws agree.
    problem = assemble(scene, detect_contacts(scene), DT)
    nscd = solvers.solve(problem, "nscd", tol=1e-10)
    cocd = solvers.solve(problem, "clarabel", tol=1e-10)
    assert velocity_error(problem, nscd.u, cocd.u) <= SAME_U
    np.testing.assert_allclose(nscd.p[:, 0], cocd.p[:, 0], rtol=1e-6, atol=1e-9 * m * G * DT)


# -- a grain sliding on a wall: where the laws differ -----------------------------
def _slide(dim, solver, gap, steps):
    """Step a grain sliding on the wall; rows per step: v_x, gap, normal velocity, slip."""
    scene = on_wall(dim, gap=gap)
    stepper = Stepper(scene, DT, solver=solver, tol=1e-10)
    rows = []
    for _ in range(steps):
        stepper.step()
        problem, solution = stepper.problem, stepper.solution
        assert problem is not None and solution is not None
        w = problem.relative_velocity(problem.velocity(solution.p))[0]
        rows.append(
            (
                scene.velocities[0, 0],
                scene.positions[0, -1] - RADIUS,
                scene.velocities[0, -1],
                float(np.linalg.norm(w[1:])),
            )
        )
    return np.array(rows).T


def _lambda(dim):
    kappa = 0.5 if dim == 2 else 0.4  # J / (m R^2): disc, sphere
    c = MU * (1.0 + 1.0 / kappa)
    return MU * c / (1.0 + MU * c)


@pytest.mark.parametrize("dim", [2, 3])
def test_nscd_keeps_a_sliding_contact_closed(dim):
    (_, gap, vn, slip) = _slide(dim, "nscd", 0.0, 60)
    assert slip.min() > 0.1  # sliding throughout (rolling starts near t = 0.1 s)
    assert np.abs(gap).max() <= 1e-10
    assert np.abs(vn).max() <= 1e-8
    # The same first step with the convexified law lifts the grain off by dt mu |slip|.
    (_, gap_c, vn_c, slip_c) = _slide(dim, "clarabel", 0.0, 1)
    assert vn_c[0] == pytest.approx(MU * slip_c[0], rel=1e-6)
    assert gap_c[0] == pytest.approx(DT * MU * slip_c[0], rel=1e-6)


@pytest.mark.parametrize("dim", [2, 3])
def test_convexified_law_slides_on_a_gap_dt_mu_slip(dim):
    """Started on the gap it keeps, COCD slides on a cushion dt mu |slip| at every step."""
    (_, gap, _, slip) = _slide(dim, "clarabel", DT * MU * 1.0, 40)
    assert slip.min() > 0.1
    ratio = gap / (DT * MU * slip)
    assert np.all((ratio > 0.5) & (ratio < 1.5))
    np.testing.assert_allclose(ratio, 1.0, rtol=1e-6)


@pytest.mark.parametrize("dim", [2, 3])
def test_sliding_deceleration_is_mu_g(dim):
    steps = 40
    v0 = 1.0
    (vx, _, _, slip) = _slide(dim, "nscd", 0.0, steps)
    assert slip.min() > 0.1
    decel = -np.diff(np.r_[v0, vx]) / DT
    np.testing.assert_allclose(decel, MU * G, rtol=1e-6)

    (vx, _, _, slip) = _slide(dim, "clarabel", DT * MU * v0, steps)
    assert slip.min() > 0.1
    decel = -np.diff(np.r_[v0, vx]) / DT
    k = np.arange(1, steps + 1)
    np.testing.assert_allclose(decel, MU * G * (1.0 - _lambda(dim) ** k), rtol=1e-6)
    settled = k >= 12  # lambda^12 < 1e-7
    np.testing.assert_allclose(decel[settled], MU * G, rtol=1e-6)


# -- failures are answers, not exceptions ------------------------------------------
@pytest.mark.unchecked_solutions
def test_nscd_stops_at_max_iter_with_its_best_answer(problems):
    problem = problems("column-2d")
    sol = solvers.solve(problem, "nscd", tol=1e-14, max_iter=3)
    assert sol.status == "max_iter" and sol.iterations == 3
    history = [res for _, res in sol.extras["history"]]
    assert coulomb_residual(problem, sol.p) == pytest.approx(min(history))
    assert np.all(sol.p[:, 0] >= 0.0)
    assert np.all(np.abs(sol.p[:, 1]) <= problem.mu * sol.p[:, 0] * (1 + 1e-12))


@pytest.mark.unchecked_solutions
def test_fp_stops_at_max_outer(problems):
    problem = problems("column-2d")
    sol = solvers.solve(problem, "fp:clarabel-dual", tol=1e-14, max_outer=2)
    assert sol.status == "max_iter" and sol.extras["outer"] == 2


def test_bad_names_and_options(problems):
    problem = problems("slide-2d")
    with pytest.raises(ProblemError, match="convex"):
        solvers.solve(problem, "fp:nscd")
    with pytest.raises(ProblemError, match="convex"):
        solvers.solve(problem, "fp:fp:clarabel")
    # solvers.solve lets only ProblemError, SolverError and TypeError out of a backend:
    # an unknown inner name is a ProblemError caused by the registry's SolverNotFound.
    with pytest.raises(ProblemError, match=r"no-such-backend.*available solvers") as info:
        solvers.solve(problem, "fp:no-such-backend")
    assert isinstance(info.value.__cause__, SolverNotFound)
    with pytest.raises(ProblemError, match="colour"):
        solvers.solve(problem, "nscd", colour="red")
    with pytest.raises(ProblemError, match="local must be one of"):
        solvers.solve(problem, "nscd", local="newton")
    with pytest.raises(ProblemError, match="colour"):
        solvers.solve(problem, "fp:clarabel", colour="red")
    assert solvers.get("fp:clarabel-dual").convex is False


def test_nscd_sweep_reads_the_2d_law_in_place_as_local_solve_gives_it():
    """The sweep solves a 2D contact from its block's scalars, read in place; a sweep
    that calls ``local_solve`` on every contact's block gives the same impulses, on a
    thrown heap with separating, sticking and sliding contacts and a frictionless one."""
    from solvers._contact_kernels import contact_rest, move_contact
    from solvers._iterative import Contacts, contact_blocks
    from solvers._nscd_kernels import LOCAL_EXACT, nscd_sweeps

    scene = column_2d(60, mu=0.4)
    rng = np.random.default_rng(3)
    thrown = rng.random(scene.n_grains) < 0.5
    scene.velocities[thrown] = rng.normal(0.0, 0.3, (thrown.sum(), 2))
    scene.angular_velocities[thrown] = rng.normal(0.0, 30.0, thrown.sum())
    problem = assemble(scene, detect_contacts(scene), DT)
    c = Contacts.of(problem, sort=True)
    W, Winv = contact_blocks(problem, c.indptr, c.indices, c.data, c.inv_mass)
    mu = c.mu.copy()
    mu[0] = 0.0
    p0 = np.zeros((problem.nc, 2))
    p, v = p0.copy(), problem.velocity(p0)
    nscd_sweeps(c.indptr, c.indices, c.data, c.inv_mass, c.offset, W, Winv, mu, p, v,
                3, True, 1.0, c.shift, LOCAL_EXACT, np.zeros(2, dtype=np.int64))  # fmt: skip
    q, u = p0.copy(), problem.velocity(p0)
    r, out, seen = np.empty(2), np.empty(2), set()
    for sweep in range(3):
        order = range(problem.nc) if sweep % 2 == 0 else reversed(range(problem.nc))
        for a in order:
            contact_rest(a, c.indptr, c.indices, c.data, u, c.offset, W, q, c.shift, r)
            seen.add((kernels.local_solve(W[a], Winv[a], r, mu[a], out), mu[a] > 0))
            move_contact(a, out, c.indptr, c.indices, c.data, c.inv_mass, q, u)
    assert {(kernels.SEPARATED, True), (kernels.STICK, True), (kernels.SLIDE, True)} <= seen
    assert any(not rough for _, rough in seen)
    assert np.allclose(p, q, rtol=1e-12, atol=1e-15 * np.abs(q).max())
    assert np.abs(q).max() > 0


@pytest.mark.parametrize("problem_name", ["column-2d", "heap-3d"])
def test_nscd_tests_the_framework_coulomb_residual(problem_name, problems):
    """NSCD stops on a one-pass kernel of ``coulomb_residual``: the two agree to rounding
    at an answer and away from one, and the test history ends where the answer is."""
    from solvers._contact_kernels import restart_velocity
    from solvers._iterative import Contacts

    problem = problems(problem_name)
    c = Contacts.of(problem, sort=True)
    answer = solvers.solve(problem, "nscd", tol=1e-6)
    for p in (answer.p, 0.5 * answer.p, np.zeros_like(answer.p)):
        p = np.ascontiguousarray(p.reshape(problem.nc, -1))
        v = np.empty(problem.U.shape)
        restart_velocity(c.indptr, c.indices, c.data, c.inv_mass, problem.U, p, v)
        assert np.allclose(v, problem.velocity(p), rtol=1e-12, atol=1e-14)
        framework = coulomb_residual(problem, p)
        assert c.natural_map(p, v, coulomb=True) == pytest.approx(framework, rel=1e-10)
        assert framework > 0 or p is answer.p
    assert answer.extras["history"][-1][1] == pytest.approx(
        coulomb_residual(problem, answer.p), rel=1e-10
    )
