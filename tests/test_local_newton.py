"""``nscd``'s local form with ``newton=True``: semismooth Newton on the Alart-Curnier
function after Gauss-Seidel sweeps (:mod:`solvers._local_newton`), and global problems
solved on their condensed form."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from conftest import assert_coulomb_law, external, random_local

import solvers
from cocd.errors import ProblemError
from cocd.residuals import coulomb_residual
from cocd.external import condense, solve_external
from cocd.io import problems as problem_module
from cocd.io import read_problem
from cocd.io.problems import GlobalProblem, LocalProblem
from solvers._local_newton import alart_curnier
from solvers.local import LocalData, solve_local


def _phi(r, u, mu, rho):
    nc, m = r.shape
    phi, A, B = np.empty_like(r), np.empty((nc, m, m)), np.empty((nc, m, m))
    alart_curnier(r, u, mu, rho, phi, A, B, True)
    return phi, A, B


# -- the Jacobian ----------------------------------------------------------------------
@pytest.mark.parametrize("m", [1, 2, 3])
def test_alart_curnier_jacobian_matches_finite_differences(m):
    """At points away from the kinks (every branch: separated, sticking, sliding), the
    blocks A = dPhi/dr and B = dPhi/du are the derivatives of Phi."""
    rng = np.random.default_rng(m)
    nc = 60
    mu = rng.uniform(0.1, 1.0, nc)
    rho = rng.uniform(0.5, 2.0, nc)
    r, u = rng.normal(size=(nc, m)), rng.normal(size=(nc, m))
    phi, A, B = _phi(r, u, mu, rho)
    h = 1e-7
    branches = set()
    for a in range(nc):
        xn = r[a, 0] - rho[a] * u[a, 0]
        xt = r[a, 1:] - rho[a] * u[a, 1:]
        s = mu[a] * max(xn, 0.0)
        if abs(xn) < 1e-3 or (m > 1 and abs(np.linalg.norm(xt) - s) < 1e-3):
            continue  # too near a kink for a difference quotient
        branches.add((xn > 0, m > 1 and np.linalg.norm(xt) <= s))
        for k in range(m):
            for which, M in (("r", A), ("u", B)):
                rr, uu = r.copy(), u.copy()
                (rr if which == "r" else uu)[a, k] += h
                diff = (_phi(rr, uu, mu, rho)[0][a] - phi[a]) / h
                assert np.allclose(diff, M[a, :, k], atol=1e-5), (a, k, which)
    assert (True, False) in branches and (False, False) in branches
    if m > 1:
        assert (True, True) in branches  # sticking, inside the disc


def test_alart_curnier_vanishes_exactly_on_coulombs_law():
    """Separated (r = 0, u_N > 0), sticking (u = 0) and sliding (u_N = 0, r_T = -mu r_N
    u_T / |u_T|) contacts give Phi = 0; a violated one does not."""
    r = np.array([[0.0, 0.0, 0.0], [1.0, 0.1, -0.2], [2.0, -0.6, 0.8]])
    u = np.array([[0.3, 0.5, -0.1], [0.0, 0.0, 0.0], [0.0, 3.0, -4.0]])
    mu, rho = np.array([0.5, 0.5, 0.5]), np.array([1.0, 0.7, 2.0])
    phi, _, _ = _phi(r, u, mu, rho)
    assert np.abs(phi).max() < 1e-15
    phi, _, _ = _phi(r, u + 0.1, mu, rho)
    assert np.abs(phi).max() > 1e-3


# -- the hybrid ------------------------------------------------------------------------
def hyperstatic(nc: int, ndof: int, m: int, seed: int, mu: float = 0.4) -> LocalProblem:
    """The condensed problem of rigid bodies with more contact rows than unknowns:
    ``W = H' M^-1 H`` of rank ``ndof`` < ``m nc``, the usual case of a packing, where
    Gauss-Seidel converges slowly and a plain Newton step is singular."""
    rng = np.random.default_rng(seed)
    H = rng.normal(size=(ndof, m * nc))
    mass = rng.uniform(1.0, 2.0, ndof)
    v_free = rng.normal(size=ndof)
    W = H.T @ (H / mass[:, None])
    q = H.T @ v_free
    q.reshape(nc, m)[:, 0] -= 1.0  # closing
    return LocalProblem(W=sp.csc_matrix(W), q=q, mu=np.full(nc, mu), dim=m)


@pytest.mark.parametrize("m", [2, 3])
def test_newton_finishes_a_hyperstatic_problem(m):
    local = hyperstatic(nc=30, ndof=40, m=m, seed=m)
    data = LocalData.of(local)
    assert np.linalg.matrix_rank(local.W.toarray()) == 40 < 30 * m
    sol = solve_local(data, "nscd", 1e-12, criterion="natural_map", newton=True, max_iter=5000)
    assert sol.status == "optimal", sol.extras["newton_stops"]
    assert local.natural_map_error(sol.p) <= 1e-12
    assert sol.extras["newton_steps"] >= 1 and sol.iterations == (
        sol.extras["sweeps"] + sol.extras["newton_steps"]
    )
    assert_coulomb_law(sol.p, sol.u.reshape(-1, m), local.mu, 1e-9)
    # Gauss-Seidel alone, given the same budget, stops short.
    plain = solve_local(data, "nscd", 1e-12, criterion="natural_map", max_iter=sol.iterations)
    assert plain.status == "max_iter"


def test_newton_solves_a_non_symmetric_w_and_keeps_the_default_criterion():
    local = random_local(20, 3, seed=3, skew=0.1, mu=0.5)
    data = LocalData.of(local)
    sol = solve_local(data, "nscd", 1e-13, newton=True)  # criterion="residual"
    assert sol.status == "optimal" and sol.extras["criterion"] == "residual"
    assert sol.extras["error"] <= 1e-13
    assert_coulomb_law(sol.p, sol.u.reshape(-1, 3), local.mu, 1e-9)


def test_a_contact_without_a_diagonal_block():
    """A contact whose block row and column of W are empty (it sees no body) is stored
    with a zero diagonal block; it separates when q_N > 0, and Newton still runs."""
    local = hyperstatic(nc=12, ndof=16, m=3, seed=7)
    W = local.W.tolil()
    W[0:3, :] = 0.0
    W[:, 0:3] = 0.0
    q = local.q.copy()
    q[0:3] = [1.0, 0.2, -0.1]
    data = LocalData(sp.csr_matrix(W), q, local.mu, 3)
    assert data.W[0:3].nnz == 0
    sol = solve_local(data, "nscd", 1e-12, criterion="natural_map", newton=True)
    assert sol.status == "optimal"
    assert np.all(sol.p[0] == 0.0)


def test_limits_and_bad_options():
    data = LocalData.of(hyperstatic(nc=30, ndof=40, m=3, seed=11))
    capped = solve_local(data, "nscd", 1e-300, newton=True, max_iter=40)
    assert capped.status == "max_iter" and capped.iterations <= 40
    timed = solve_local(data, "nscd", 1e-300, newton=True, time_limit=0.05, max_iter=10**9)
    assert timed.status == "time_limit" and np.all(np.isfinite(timed.p))
    with pytest.raises(ProblemError, match="newton must be True or False"):
        solve_local(data, "nscd", 1e-8, newton="yes")
    with pytest.raises(ProblemError, match="pgs has no option 'newton'"):
        solve_local(data, "pgs", 1e-8, newton=True)
    conic = GlobalProblem.from_conic(
        __import__("cocd.bench.runner", fromlist=["warmup_problem"]).warmup_problem(2)
    ).conic
    plain = solvers.solve(conic, "nscd", newton=False, tol=1e-10)
    assert plain.status == "optimal"
    # On a step problem newton=True runs the same hybrid on W = H M^-1 H' and b: the
    # framework's Coulomb residual meets the tolerance and the velocities agree.
    hybrid = solvers.solve(conic, "nscd", newton=True, tol=1e-10)
    assert hybrid.status == "optimal" and hybrid.extras["newton"]
    assert coulomb_residual(conic, hybrid.p) <= 1e-10
    np.testing.assert_allclose(hybrid.u, plain.u, atol=1e-9)  # m/s
    with pytest.raises(ProblemError, match="newton must be True or False"):
        solvers.solve(conic, "nscd", newton="yes")


# -- global problems on their condensed form -------------------------------------------
def random_global(nc: int, m: int, seed: int) -> GlobalProblem:
    """Two bodies of 12 unknowns each with a full (non-diagonal) mass block."""
    rng = np.random.default_rng(seed)
    blocks = []
    for _ in range(2):
        L = rng.normal(size=(12, 12))
        blocks.append(L @ L.T + 12 * np.eye(12))
    M = sp.block_diag(blocks, format="csc")
    H = sp.csc_matrix(rng.normal(size=(24, m * nc)))
    f = rng.normal(size=24)
    w = np.zeros(m * nc)
    w[::m] = 0.5
    return GlobalProblem(M=M, H=H, f=f, w=w, mu=np.full(nc, 0.3), dim=m)


def test_dense_condensation_is_the_sparse_one(monkeypatch):
    problem = random_global(10, 3, seed=1)
    dense, seconds = condense(problem)
    assert seconds > 0
    monkeypatch.setattr(problem_module, "DENSE_MASS", 0)
    sparse, _ = condense(problem)
    scale = abs(sparse.W).max()
    assert abs(dense.W - sparse.W).max() <= 1e-12 * scale
    assert np.allclose(dense.q, sparse.q, rtol=0, atol=1e-12 * np.abs(sparse.q).max())
    Minv = np.linalg.inv(problem.M.toarray())
    H = problem.H.toarray()
    assert np.allclose(dense.W.toarray(), H.T @ Minv @ H, atol=1e-12 * scale)


def test_a_global_problem_goes_to_the_local_form_condensed():
    problem = random_global(10, 3, seed=2)
    rec, ans = solve_external(problem, "nscd", 1e-10, criterion="natural_map", newton=True)
    assert rec["note"] == "local form (condensed)" and rec["status"] == "optimal"
    assert rec["natural_map_error"] <= 1e-10
    # The answer in the global terms: M v = H r + f, u = H' v + w.
    assert np.allclose(problem.M @ ans.v, problem.H @ ans.r + problem.f)
    assert np.allclose(ans.u, problem.H.T @ ans.v + problem.w)
    assert_coulomb_law(ans.r.reshape(-1, 3), ans.u.reshape(-1, 3), problem.mu, 1e-7)
    other, _ = solve_external(problem, "clarabel", 1e-10)
    assert other["note"] != "local form (condensed)"


# -- the files -------------------------------------------------------------------------
@pytest.mark.parametrize(
    "name, tol",
    [
        ("BoxesStack1-i100000-32.hdf5.dat", 1e-12),
        ("fc2d_granularflowonwall_02020_00213.dat", 1e-8),
        ("spheres-in-a-box-98-i10000-256-10.hdf5", 1e-12),
    ],
)
def test_newton_reaches_what_gauss_seidel_alone_does_not(name, tol):
    """On these files nscd's sweeps stall (5e-7 on fc2d_02020, 1.5e-5 on BoxesStack
    after 20 000 sweeps); with Newton they reach the tolerance."""
    problem = read_problem(external(name))
    rec, _ = solve_external(
        problem, "nscd", tol, criterion="natural_map", newton=True, time_limit=60
    )
    assert rec["status"] == "optimal" and rec["natural_map_error"] <= tol
