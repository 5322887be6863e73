"""Block Gauss-Seidel (``bgs``): the exact local solver, the sweep order and the colouring.

The local problem of one contact, ``min 1/2 p'Wp + r'p`` over its Coulomb cone, is
checked on random blocks against its optimality conditions (natural map zero to
rounding) and against Clarabel; the three sweep orders on a resting stack (each gives
Clarabel's impulses), and the descent of the dual objective sweep after sweep on a 3D box.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

import cocd
import solvers
from cocd.builders import tall_stack
from cocd.cones import project_coulomb
from cocd.errors import ProblemError
from cocd.residuals import ccp_residual

pytestmark = pytest.mark.skipif("bgs" not in solvers.available(), reason="bgs needs numba")


def _random_block(rng, m):
    a = rng.standard_normal((m, m))
    return a @ a.T + 0.05 * np.eye(m)


@pytest.mark.parametrize("m", [1, 2, 3])
def test_local_answer_satisfies_the_cone_complementarity(m):
    from solvers._bgs_kernels import local_ccp

    rng = np.random.default_rng(m)
    kinds = np.zeros(3, dtype=int)
    for _ in range(3000):
        W = _random_block(rng, m)
        r = rng.standard_normal(m)
        mu = float(rng.choice([0.0, 0.1, 0.5, 1.0, 2.0]))
        previous = project_coulomb(rng.standard_normal((1, m)), np.array([mu]))[0]
        out = np.zeros(m)
        kinds[local_ccp(W, np.linalg.inv(W), r, mu, previous, out)] += 1
        assert out[0] >= 0.0
        if m > 1:
            assert np.linalg.norm(out[1:]) <= mu * out[0] * (1 + 1e-12) + 1e-300
        w = W @ out + r
        step = m / np.trace(W)
        natural = out - project_coulomb((out - step * w)[None], np.array([mu]))[0]
        assert np.linalg.norm(natural) <= 1e-11 * max(1.0, step * np.linalg.norm(r))
    if m > 1:  # every branch was met: apex, interior, boundary
        assert np.all(kinds > 100)


def test_local_answer_matches_clarabel():
    cp = pytest.importorskip("cvxpy")
    from solvers._bgs_kernels import local_ccp

    rng = np.random.default_rng(7)
    for _ in range(20):
        W = _random_block(rng, 3)
        r = rng.standard_normal(3)
        mu = 0.4
        out = np.zeros(3)
        local_ccp(W, np.linalg.inv(W), r, mu, np.zeros(3), out)
        p = cp.Variable(3)
        objective = cp.Minimize(0.5 * cp.quad_form(p, cp.psd_wrap(W)) + r @ p)
        cp.Problem(objective, [cp.SOC(mu * p[0], p[1:])]).solve(
            solver="CLARABEL", tol_gap_abs=1e-10, tol_gap_rel=1e-10, tol_feas=1e-10
        )
        f = 0.5 * out @ W @ out + r @ out
        f_ref = 0.5 * p.value @ W @ p.value + r @ p.value
        assert f <= f_ref + 1e-7 * max(1.0, abs(f_ref))
        np.testing.assert_allclose(out, p.value, atol=1e-6 * max(1.0, np.abs(p.value).max()))


def _stack_problem():
    scene = tall_stack(30, dim=2, mu=0.3)
    stepper = cocd.Stepper(scene, 1e-3, solver="clarabel")
    stepper.run(3)
    return cocd.assemble(scene, cocd.detect_contacts(scene), 1e-3)


@pytest.mark.parametrize("order", ["natural", "top-down", "bottom-up"])
def test_every_order_gives_clarabels_impulses(order):
    problem = _stack_problem()
    sol = solvers.solve(problem, "bgs", tol=1e-10, order=order)
    assert sol.status is solvers.Status.OPTIMAL
    ref = solvers.solve(problem, "clarabel", tol=1e-10)
    np.testing.assert_allclose(sol.p, ref.p, rtol=1e-6, atol=1e-7 * np.abs(ref.p).max())


def test_every_sweep_lowers_the_dual_objective():
    # Exact block minimisation: block coordinate descent, monotone (a scalar
    # projected step with omega > 1 need not be).
    scene = cocd.box_3d(200, mu=0.5)
    cocd.Stepper(scene, 1e-3, solver="clarabel").run(30)  # 663 contacts, 270 sweeps to 1e-10
    problem = cocd.assemble(scene, cocd.detect_contacts(scene), 1e-3)
    W, b = problem.W, problem.b

    def objective(p):
        x = p.reshape(-1)
        return 0.5 * x @ (W @ x) + b @ x

    from solvers._bgs_kernels import bgs_sweep
    from solvers.nscd_ import contact_blocks

    H, nc, m = problem.H, problem.nc, problem.contact_dim
    indptr, indices = H.indptr.astype(np.int64), H.indices.astype(np.int64)
    inv_mass = 1.0 / problem.mass
    blocks, inverses = contact_blocks(problem, indptr, indices, H.data, inv_mass)
    p = np.zeros((nc, m))
    v = problem.velocity(p)
    order, starts = np.arange(nc, dtype=np.int64), np.array([0, nc], dtype=np.int64)
    values = [0.0]
    for _ in range(15):
        bgs_sweep(indptr, indices, H.data, inv_mass, problem.offset, blocks, inverses,
                  problem.mu, p, v, order, starts, 0.0)  # fmt: skip
        values.append(objective(p))
    scale = abs(values[-1])
    assert all(later <= earlier + 1e-12 * scale for earlier, later in itertools.pairwise(values))
    assert values[-1] < values[0]


def test_colours_share_no_unknown():
    from solvers._bgs_kernels import greedy_colours

    scene = cocd.box_3d(300, mu=0.4)
    cocd.Stepper(scene, 1e-3, solver="clarabel").run(10)
    problem = cocd.assemble(scene, cocd.detect_contacts(scene), 1e-3)
    H, m = problem.H, problem.contact_dim
    order = np.arange(problem.nc, dtype=np.int64)
    colour = greedy_colours(order, H.indptr.astype(np.int64), H.indices.astype(np.int64), m,
                            H.shape[1])  # fmt: skip
    assert colour.min() == 0 and 1 < colour.max() < 40
    for c in range(colour.max() + 1):
        rows = np.flatnonzero(np.repeat(colour == c, m))
        touched = np.concatenate([H.indices[H.indptr[i] : H.indptr[i + 1]] for i in rows])
        per_contact = [
            np.unique(H.indices[H.indptr[a * m] : H.indptr[a * m + m]])
            for a in np.flatnonzero(colour == c)
        ]
        assert sum(len(u) for u in per_contact) == len(np.unique(touched))
    # Coloured and sequential sweeps solve the same problem.
    coloured = solvers.solve(problem, "bgs", tol=1e-9, colour=True)
    sequential = solvers.solve(problem, "bgs", tol=1e-9)
    assert coloured.extras["colours"] == colour.max() + 1
    assert sequential.extras["colours"] == 1
    for sol in (coloured, sequential):
        assert sol.status is solvers.Status.OPTIMAL
        assert ccp_residual(problem, sol.p) <= 1e-9


@pytest.mark.parametrize(
    "options, match",
    [({"order": "random"}, "order must be one of"), ({"omega": 1.2}, "no option 'omega'")],
)
def test_bad_options_raise(options, match):
    problem = _stack_problem()
    with pytest.raises(ProblemError, match=match):
        solvers.solve(problem, "bgs", **options)
