"""The iterative backends ``pgs`` (projected Gauss-Seidel) and ``apgd`` (Nesterov, restart).

Both stop on the framework's ``ccp_residual <= tol``, so at tol 1e-8 an
``optimal`` answer is held by the suite-wide check (conftest.py) to
``ccp_residual <= 10 tol`` and asserted here to ``<= tol``. On the analytic
scenes (resting stacks, a sphere rolling on a slope) and on random 2D and 3D
packings (``column_2d(200)`` after 30 steps, 566 contacts; ``box_3d(100,
mu=0.4)`` after 20 steps, 340 contacts) both reach 1e-8 and give Clarabel's
velocities to 1e-4 of the step's velocity scale.

Warm start is measured on a step of a collapsing column (``column_2d(400)``
after 60 steps, 1118 contacts) at tol 1e-6, not 1e-8: on that step PGS
stagnates near ``ccp = 6e-8`` for tens of thousands of sweeps (the impulses
creep along an almost self-equilibrated loop of contacts in the corner, a
direction where ``W`` is nearly singular), so at 1e-8 cold and warm would both
stop at ``max_iter``. Measured on it (cold / warm): PGS 7295 / 4335 sweeps to
1e-6; APGD 628 / 504 iterations to 1e-6, 3667 / 976 to 1e-8.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import cocd
import solvers
from cocd import Scene, Stepper, Wall
from cocd.cones import project_coulomb
from cocd.errors import ProblemError
from cocd.residuals import ccp_residual
from cocd.stepper import match_impulses
from solvers._apgd_kernels import step_and_length
from solvers._contact_kernels import project_cones

ITERATIVE = ["pgs", "bgs", "apgd"]
TOL = 1e-8
U_AGREEMENT = 1e-4
DT = 1e-3
G = 9.81

pytestmark = pytest.mark.skipif(
    any(name not in solvers.available() for name in ITERATIVE),
    reason="pgs and apgd need numba",
)


# -- problems ------------------------------------------------------------------
def _next_problem(stepper: Stepper) -> cocd.ConicProblem:
    scene = stepper.scene
    return cocd.assemble(scene, cocd.detect_contacts(scene), DT)


@pytest.fixture(scope="module")
def packings() -> dict[str, cocd.ConicProblem]:
    """The next step's problem of a 2D column after 30 steps and of a 3D box after 20."""
    column = Stepper(cocd.column_2d(200), DT)
    column.run(30)
    box = Stepper(cocd.box_3d(100, mu=0.4), DT)
    box.run(20)
    return {"column-2d": _next_problem(column), "box-3d": _next_problem(box)}


@pytest.fixture(scope="module")
def references(packings) -> dict[str, solvers.Solution]:
    return {name: solvers.solve(pr, "clarabel", tol=TOL) for name, pr in packings.items()}


@pytest.fixture(scope="module")
def collapse() -> tuple[cocd.ConicProblem, np.ndarray]:
    """A mid-collapse step of a 400-disc column and the previous step's impulses, matched."""
    stepper = Stepper(cocd.column_2d(400), DT)
    stepper.run(60)
    contacts = cocd.detect_contacts(stepper.scene)
    problem = cocd.assemble(stepper.scene, contacts, DT)
    p0 = match_impulses(stepper.contacts.keys, stepper.solution.p, contacts.keys)
    return problem, p0


def _velocity_error(problem, u, u_ref) -> float:
    scale = max(np.linalg.norm(u_ref), np.linalg.norm(problem.U))
    return float(np.linalg.norm(u - u_ref) / scale)


def _assert_in_cones(problem, p) -> None:
    assert np.all(np.isfinite(p))
    assert np.all(p[:, 0] >= 0.0)
    if problem.contact_dim > 1:
        excess = np.linalg.norm(p[:, 1:], axis=1) - problem.mu * p[:, 0] * (1.0 + 1e-12)
        assert np.all(excess <= 1e-300)


# -- the per-contact projection kernel ---------------------------------------------
@pytest.mark.parametrize("m", [1, 2, 3])
def test_projection_kernel_matches_the_core(m):
    rng = np.random.default_rng(m)
    x = rng.standard_normal((400, m))
    mu = rng.choice([0.0, 0.3, 1.0, 2.5], size=400)
    x[:20, 1:] = 0.0  # on the axis, both signs of x_N
    x[20:40] = 0.0
    out = np.empty_like(x)
    project_cones(x, mu, out)
    np.testing.assert_allclose(out, project_coulomb(x, mu), rtol=1e-14, atol=1e-15)


@pytest.mark.parametrize("m", [1, 2, 3])
def test_fused_apgd_step_kernel_matches_the_core(m):
    rng = np.random.default_rng(10 + m)
    y, g = rng.standard_normal((2, 500, m))
    mu = rng.choice([0.0, 0.3, 1.0, 2.5], size=500)
    out, d = np.empty_like(y), np.empty_like(y)
    dd = step_and_length(y, g, 0.7, mu, out, d)
    expected = project_coulomb(y - 0.7 * g, mu)
    np.testing.assert_allclose(out, expected, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(d, expected - y, rtol=1e-13, atol=1e-15)
    assert dd == pytest.approx(float(np.sum((expected - y) ** 2)), rel=1e-12)


@pytest.mark.parametrize("scaling", ["block", "contact"])
@pytest.mark.parametrize("operator", ["auto", "csr"])
def test_apgd_incremental_gradient_matches_a_fresh_one(packings, scaling, operator):
    # g(y + d) = g(y) + S W S d, with and without a Delassus shift.
    from solvers.apgd_ import _ScaledDual, component_scaling

    for shift in (0.0, 1e-3):
        problem = packings["box-3d"]
        problem = dataclasses.replace(problem, delassus_shift=shift)
        s = component_scaling(problem, scaling)
        scaled = _ScaledDual(problem, s, operator)
        assert scaled.operator == ("blocks" if operator == "auto" else "csr")
        rng = np.random.default_rng(3)
        y, d = rng.standard_normal((2, problem.nc, problem.contact_dim))
        z = np.empty(scaled.ndof)
        curvature = scaled.curvature(d, z, float(np.sum(d * d)))
        assert curvature == pytest.approx(float(np.sum(d * scaled.product(d))), rel=1e-12)
        out = np.empty_like(y)
        scaled.update_gradient(scaled.gradient(y), z, d, out)
        np.testing.assert_allclose(out, scaled.gradient(y + d), rtol=1e-11, atol=1e-11)


@pytest.mark.parametrize("name", ["box-3d", "column-2d"])
def test_apgd_block_scaling_gives_unit_diagonal_and_the_framework_natural_map(packings, name):
    # S W S has a unit diagonal (spheres and discs: tangential entries equal), and the
    # kernel's natural map read from (q, g) is the framework's one of p = s q.
    from solvers._apgd_kernels import natural_map_sq_par
    from solvers.apgd_ import _ScaledDual, component_scaling

    problem = packings[name]
    s = component_scaling(problem, "block")
    scaled = _ScaledDual(problem, s)
    e = np.zeros((problem.nc, problem.contact_dim))
    for a in range(0, problem.nc, max(1, problem.nc // 7)):
        for k in range(problem.contact_dim):
            e[a, k] = 1.0
            assert scaled.product(e)[a, k] == pytest.approx(1.0, rel=1e-12)
            e[a, k] = 0.0
    rng = np.random.default_rng(4)
    p = project_coulomb(rng.standard_normal((problem.nc, problem.contact_dim)), problem.mu)
    q = p / s
    g = scaled.gradient(q)
    u = problem.contact_velocity(p).reshape(p.shape)
    expected = p - project_coulomb(p - problem.rho[:, None] * u, problem.mu)
    value = natural_map_sq_par(q, g, s, problem.rho, problem.mu)
    assert value == pytest.approx(float(np.sum(expected**2)), rel=1e-10)


def test_projection_kernel_frictionless_cone_excludes_negative_normal():
    """mu = 0: (x_N < 0, 0) satisfies |x_T| <= mu x_N but is not in the cone."""
    x = np.array([[-1.0, 0.0, 0.0], [-1.0, 0.5, 0.0], [2.0, 0.0, 0.0], [2.0, 3.0, 4.0]])
    out = np.empty_like(x)
    project_cones(x, np.zeros(4), out)
    np.testing.assert_array_equal(out, [[0, 0, 0], [0, 0, 0], [2, 0, 0], [2, 0, 0]])


# -- analytic scenes ----------------------------------------------------------------
@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("name", ITERATIVE)
def test_resting_stack_impulses(name, dim):
    """Contact k from the top carries the weight of the k grains above it: k m g dt."""
    n = 10
    scene = cocd.stack(n, dim=dim)
    stepper = Stepper(scene, DT, solver=name, tol=TOL)
    stepper.run(20)
    assert np.abs(scene.velocities).max() < 1e-8
    contacts, p = stepper.contacts, stepper.solution.p
    assert stepper.solution.status == "optimal"
    j = np.maximum(contacts.j, 0)
    heights = np.where(
        contacts.j >= 0, 0.5 * (scene.positions[contacts.i, -1] + scene.positions[j, -1]), 0.0
    )
    touching = contacts.gap < 1e-9
    pn = p[touching, 0][np.argsort(-heights[touching])]
    assert pn.size == n
    weight = scene.masses[0] * G * DT
    np.testing.assert_allclose(pn, np.arange(1, n + 1) * weight, rtol=1e-6)
    np.testing.assert_allclose(p[:, 1:], 0.0, atol=1e-6 * weight)
    # The stepper warm-starts from the previous step: at rest that is the answer.
    assert stepper.records[-1].iterations < stepper.records[0].iterations


def _slope(dim: int, degrees: float) -> Scene:
    theta = math.radians(degrees)
    g = np.zeros(dim)
    g[0], g[-1] = G * math.sin(theta), -G * math.cos(theta)
    x = np.zeros((1, dim))
    x[0, -1] = 0.01
    return Scene(x, 0.01, walls=[Wall(np.zeros(dim), np.eye(dim)[-1])], gravity=g, mu=0.3)


@pytest.mark.parametrize("degrees", [20.0, 55.0])
@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("name", ITERATIVE)
def test_grain_on_a_slope_matches_clarabel(name, dim, degrees):
    """Rolling (20 degrees) and sliding (55 degrees), a few steps after release."""
    stepper = Stepper(_slope(dim, degrees), DT)
    stepper.run(5)
    problem = _next_problem(stepper)
    ref = solvers.solve(problem, "clarabel", tol=TOL)
    sol = solvers.solve(problem, name, tol=TOL)
    assert sol.status == "optimal"
    assert ccp_residual(problem, sol.p) <= TOL
    assert _velocity_error(problem, sol.u, ref.u) <= U_AGREEMENT


# -- random packings ----------------------------------------------------------------
@pytest.mark.parametrize("packing", ["column-2d", "box-3d"])
@pytest.mark.parametrize("name", ITERATIVE)
def test_packing_reaches_tol_and_agrees_with_clarabel(name, packing, packings, references):
    problem, ref = packings[packing], references[packing]
    sol = solvers.solve(problem, name, tol=TOL)
    assert sol.status == "optimal", sol.extras["native_status"]
    assert ccp_residual(problem, sol.p) <= TOL
    assert _velocity_error(problem, sol.u, ref.u) <= U_AGREEMENT
    np.testing.assert_allclose(sol.u, problem.velocity(sol.p))
    history = sol.extras["history"]
    assert history["ccp"][-1] <= TOL
    assert history["dp"].size == sol.iterations


@pytest.mark.parametrize("name", ITERATIVE)
def test_warm_start_takes_fewer_iterations(name, collapse):
    problem, p0 = collapse
    cold = solvers.solve(problem, name, tol=1e-6)
    warm = solvers.solve(problem, name, tol=1e-6, warm_start=p0)
    assert cold.status == warm.status == "optimal"
    assert warm.iterations < cold.iterations


@pytest.mark.parametrize("name", ITERATIVE)
def test_optimal_warm_start_needs_no_iteration(name, packings, references):
    problem = packings["box-3d"]
    first = solvers.solve(problem, name, tol=TOL)
    again = solvers.solve(problem, name, tol=TOL, warm_start=first.p)
    assert again.status == "optimal" and again.iterations == 0


# -- options and limits -------------------------------------------------------------
@pytest.mark.parametrize("omega", [0.6, 1.25])
@pytest.mark.parametrize("packing", ["column-2d", "box-3d"])
def test_pgs_over_relaxation_converges(omega, packing, packings, references):
    """omega rho_a lambda_max(W_aa) < 2 is a descent step: omega < 4/3 for discs."""
    problem = packings[packing]
    sol = solvers.solve(problem, "pgs", tol=TOL, omega=omega)
    assert sol.status == "optimal"
    assert _velocity_error(problem, sol.u, references[packing].u) <= U_AGREEMENT


@pytest.mark.parametrize("omega", [0.0, 2.0, -0.5, 2.5, float("nan"), "fast"])
def test_pgs_omega_outside_0_2_raises(omega, packings):
    with pytest.raises(ProblemError, match="omega"):
        solvers.solve(packings["column-2d"], "pgs", omega=omega)


@pytest.mark.parametrize("packing", ["column-2d", "box-3d"])
def test_apgd_scalings_agree_with_clarabel(packing, packings, references):
    problem = packings[packing]
    for scaling in ("block", "contact"):
        sol = solvers.solve(problem, "apgd", tol=TOL, scaling=scaling)
        assert sol.status == "optimal"
        assert ccp_residual(problem, sol.p) <= TOL
        assert _velocity_error(problem, sol.u, references[packing].u) <= U_AGREEMENT


def test_apgd_unknown_scaling_raises(packings):
    with pytest.raises(ProblemError, match="scaling must be one of block, contact"):
        solvers.solve(packings["column-2d"], "apgd", scaling="diagonal")


@pytest.mark.parametrize("name", ITERATIVE)
def test_unknown_option_raises(name, packings):
    with pytest.raises(ProblemError, match="no option 'rho'"):
        solvers.solve(packings["column-2d"], name, rho=2.0)


@pytest.mark.parametrize("packing", ["column-2d", "box-3d"])
@pytest.mark.parametrize("name", ITERATIVE)
def test_max_iter_returns_finite_impulses_in_cones(name, packing, packings):
    problem = packings[packing]
    sol = solvers.solve(problem, name, tol=TOL, max_iter=3)
    assert sol.status == "max_iter"
    assert sol.iterations == 3
    _assert_in_cones(problem, sol.p)
    assert np.all(np.isfinite(sol.u))
    assert sol.extras["ccp"] == pytest.approx(ccp_residual(problem, sol.p), rel=1e-6)


@pytest.mark.parametrize("name", ITERATIVE)
def test_time_limit(name, packings):
    problem = packings["column-2d"]
    sol = solvers.solve(problem, name, tol=1e-14, time_limit=1e-6)
    assert sol.status == "time_limit"
    _assert_in_cones(problem, sol.p)


# -- the Jacobian by contact blocks ----------------------------------------------
def _scene_problem(dim: int, mu: float, steps: int) -> cocd.ConicProblem:
    """A collapsing column's next problem: grain-grain and grain-bed contacts."""
    scene = cocd.builders.column_collapse(dim, n_grains=200 if dim == 2 else 300, mu=mu)
    dt = 1e-3 if dim == 2 else 1e-2
    stepper = Stepper(scene, dt, solver="clarabel", tol=1e-8)
    stepper.run(steps)
    return cocd.assemble(scene, cocd.detect_contacts(scene), dt)


@pytest.mark.parametrize("dim, mu", [(2, 0.3), (2, 0.0), (3, 0.3), (3, 0.0)])
def test_contact_blocks_give_the_csr_products(dim, mu):
    """A scene's Jacobian, scaled by rows as apgd scales it, is read as blocks whose
    products are the CSR ones to rounding, on one thread or in per-thread shares."""
    import scipy.sparse as sp

    from cocd.contacts import unknowns_per_grain
    from solvers._blocks import contact_blocks
    from solvers.apgd_ import component_scaling

    problem = _scene_problem(dim, mu, steps=5)
    m = problem.contact_dim
    H = sp.csr_matrix(sp.diags(component_scaling(problem, "block").reshape(-1)) @ problem.H)
    blocks = contact_blocks(H, m, dim, unknowns_per_grain(dim, m == 1))
    assert blocks is not None
    assert (blocks.first[:, 0] >= 0).all() and (blocks.first[:, 1] < 0).any()  # bed contacts
    rng = np.random.default_rng(5)
    p, base = rng.standard_normal((2, H.shape[0]))
    z, scale = rng.standard_normal(H.shape[1]), 1.0 / problem.mass
    ht = np.empty(H.shape[1])
    blocks.rmatvec(p, ht)
    np.testing.assert_allclose(ht, H.T @ p, rtol=1e-13, atol=1e-13 * np.abs(H.T @ p).max())
    out = np.empty(H.shape[0])
    blocks.matvec_scaled_add(scale, z, base, out)
    expected = base + H @ (scale * z)
    np.testing.assert_allclose(out, expected, rtol=1e-13, atol=1e-13 * np.abs(expected).max())
    for buffers in (None, np.zeros((3, H.shape[1]))):  # on one thread, in three shares
        blocks._buffers = buffers
        again = np.empty(H.shape[1])
        blocks.rmatvec(p, again)
        np.testing.assert_allclose(again, ht, rtol=1e-13, atol=1e-13 * np.abs(ht).max())
    # The grains of every contact swapped (the free grain on the minus side, the first
    # grain of a pair on it too): the same matrix up to its layout, read as exactly.
    nc, per_grain = problem.nc, unknowns_per_grain(dim, m == 1)
    perm = np.arange(H.shape[1]).reshape(-1, per_grain)[::-1].reshape(-1)
    swapped = sp.csr_matrix(H[:, perm])
    flipped = contact_blocks(swapped, m, dim, per_grain)
    assert flipped is not None
    pairs = blocks.first[:, 1] >= 0
    np.testing.assert_array_equal(flipped.T[pairs], -blocks.T[pairs])  # read from grain j
    flipped.matvec_scaled_add(scale[perm], z[perm], base, out)
    np.testing.assert_allclose(out, expected, rtol=1e-13, atol=1e-13 * np.abs(expected).max())
    assert nc == blocks.T.shape[0]


def test_a_jacobian_without_the_block_structure_stays_csr():
    """Three grains in a contact, a second grain's entry that is not the first's with
    the sign of a translation, or an entry missing: no blocks."""
    import scipy.sparse as sp

    from solvers._blocks import contact_blocks

    problem = _scene_problem(2, 0.3, steps=2)
    H = sp.csr_matrix(problem.H)
    assert contact_blocks(H, 2, 2, 3) is not None
    pair = np.flatnonzero(np.diff(H.indptr) == 6)[0]  # a row on two grains
    lo = H.indptr[pair]
    flipped = H.copy()
    flipped.data[lo + 3] = -flipped.data[lo + 3]  # the second grain's first entry
    assert contact_blocks(flipped, 2, 2, 3) is None
    missing = H.tolil()
    missing[pair, H.indices[lo + 3]] = 0.0
    assert contact_blocks(sp.csr_matrix(missing), 2, 2, 3) is None
    grains = {H.indices[lo] // 3, H.indices[lo + 3] // 3}
    other = next(g for g in range(H.shape[1] // 3) if g not in grains)
    third = H.tolil()
    third[pair, 3 * other] = 1.0  # a grain neither of the pair
    assert contact_blocks(sp.csr_matrix(third), 2, 2, 3) is None
    rotation = H.copy()  # the second grain's rotational entry negated
    rotation.data[lo + 5] = -rotation.data[lo + 5]
    assert contact_blocks(rotation, 2, 2, 3) is None
    zero = sp.csr_matrix(  # an entry on one grain, a stored zero on the other
        (np.array([1.0, 0.0]), np.array([0, 4]), np.array([0, 2, 2])), shape=(2, 6)
    )
    assert contact_blocks(zero, 2, 2, 3) is None
    assert contact_blocks(H, 2, 2, 4) is None  # 600 unknowns, not in blocks of 4 here
    assert contact_blocks(H[:, :-1], 2, 2, 3) is None  # not a whole number of grains


@pytest.mark.parametrize("dim, mu", [(2, 0.3), (3, 0.3), (3, 0.0)])
def test_apgd_through_blocks_answers_as_through_csr(dim, mu):
    problem = _scene_problem(dim, mu, steps=20 if dim == 2 else 3)
    fast = solvers.solve(problem, "apgd", tol=TOL)
    plain = solvers.solve(problem, "apgd", tol=TOL, operator="csr")
    assert fast.extras["operator"] == "blocks" and plain.extras["operator"] == "csr"
    assert fast.status is plain.status is solvers.Status.OPTIMAL
    assert ccp_residual(problem, fast.p) <= TOL
    assert abs(fast.iterations - plain.iterations) <= max(2, plain.iterations // 10)
    scale = np.abs(plain.p).max()
    np.testing.assert_allclose(fast.p, plain.p, atol=1e-5 * scale)
    with pytest.raises(ProblemError, match="apgd: operator must be one of auto, csr, got 'x'"):
        solvers.solve(problem, "apgd", tol=TOL, operator="x")


@pytest.mark.parametrize("m", [1, 2, 3])
def test_apgd_differences_sum_the_natural_map_in_the_same_pass(m):
    from solvers._apgd_kernels import differences, natural_map_sq_par

    rng = np.random.default_rng(6)
    nc = 500
    x_new, x, g_new, g_x, g_y = rng.standard_normal((5, nc, m))
    s, rho, mu = rng.uniform(0.5, 2.0, (nc, m)), rng.uniform(0.5, 2.0, nc), rng.uniform(0, 1, nc)
    delta, dg = np.empty((2, nc, m))
    *parts, nat = differences(x_new, x, g_new, g_x, g_y, s, delta, dg, rho, mu, True)
    assert nat == pytest.approx(natural_map_sq_par(x_new, g_new, s, rho, mu), rel=1e-12)
    *same, none = differences(x_new, x, g_new, g_x, g_y, s, delta, dg, rho, mu, False)
    # The same sums, up to the order in which threads add them up.
    assert none == 0.0 and same == pytest.approx(parts, rel=1e-12)
    np.testing.assert_array_equal(delta, x_new - x)
    assert parts[0] == pytest.approx(float(np.sum(g_x * delta + 0.5 * delta * (g_new - g_x))))
