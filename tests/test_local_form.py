"""The local form of nscd and pgs: Gauss-Seidel on u = W r + q with W itself (solvers.local)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from conftest import assert_coulomb_law, external, random_local

import solvers
from cocd.errors import CocdError, ProblemError
from cocd.external import judge, not_applicable, solve_external
from cocd.io import read_problem
from cocd.io.problems import LocalProblem
from cocd.residuals import ccp_residual, coulomb_residual
from solvers._nscd_local_kernels import local_solve
from solvers.local import LocalData, local_backends, solve_local

CAPSULES = ["Capsules-i100-1090.dat", "Capsules-i125-1213.hdf5"]


# -- the one-contact solver on a block that is not symmetric ---------------------------
@pytest.mark.parametrize("dim", [2, 3])
def test_one_contact_solver_reads_a_non_symmetric_block(dim):
    rng = np.random.default_rng(7)
    for _ in range(200):
        A = rng.normal(size=(dim, dim))
        W = A @ A.T + dim * np.eye(dim) + 0.3 * (lambda S: S - S.T)(rng.normal(size=(dim, dim)))
        rest = rng.normal(size=dim)
        out = np.empty(dim)
        local_solve(W, np.linalg.inv(W), rest, 0.6, out)
        u = W @ out + rest
        assert_coulomb_law(out[None, :], u[None, :], np.array([0.6]), 1e-9)


# -- agreement with the ConicProblem path on a symmetric W -----------------------------
@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("solver", ["nscd", "pgs"])
def test_symmetric_local_form_agrees_with_the_conic_path(solver, dim):
    local = random_local(12, dim, seed=dim)
    tol = 1e-10
    conic = solvers.solve(local.conic, solver, tol, max_iter=100_000)
    mine = solve_local(LocalData.of(local), solver, tol, max_iter=100_000)
    assert conic.status == mine.status == "optimal"
    # The same numbers as the framework's residual of the conic path.
    residual = coulomb_residual if solver == "nscd" else ccp_residual
    assert residual(local.conic, mine.p) <= tol
    assert mine.extras["error"] == pytest.approx(residual(local.conic, mine.p), rel=1e-6)
    scale = np.abs(conic.p).max()
    assert np.allclose(mine.p, conic.p, rtol=0, atol=1e-7 * scale)
    u_conic = local.conic.contact_velocity(conic.p).reshape(-1)
    assert np.allclose(mine.u, u_conic, rtol=0, atol=1e-7 * np.abs(u_conic).max())
    assert np.allclose(mine.u, local.W @ mine.p.reshape(-1) + local.q)


def test_local_judge_is_the_conic_judge_when_w_is_symmetric():
    local = random_local(10, 3, seed=4)
    r = np.abs(np.random.default_rng(0).normal(size=(10, 3)))
    mine = judge(local, r)
    assert mine["ccp_residual"] == pytest.approx(ccp_residual(local.conic, r), rel=1e-9)
    assert mine["coulomb_residual"] == pytest.approx(coulomb_residual(local.conic, r), rel=1e-9)
    assert mine["natural_map_error"] == local.natural_map_error(r)


# -- a W that is not symmetric ----------------------------------------------------------
@pytest.mark.parametrize("dim", [2, 3])
def test_nscd_local_form_solves_a_non_symmetric_w(dim):
    local = random_local(15, dim, seed=10 + dim, skew=0.1, mu=0.5)
    assert local.symmetry_error() > 1e-2
    with pytest.raises(ProblemError, match="W is not symmetric"):
        local.conic  # noqa: B018
    tol = 1e-10
    rec, ans = solve_external(local, "nscd", tol, criterion="natural_map")
    assert rec["status"] == "optimal" and rec["note"] == "local form"
    assert rec["natural_map_error"] <= tol
    assert np.allclose(ans.u, local.W @ ans.r + local.q)
    r, u = ans.r.reshape(-1, dim), ans.u.reshape(-1, dim)
    assert_coulomb_law(r, u, local.mu, 1e-8)
    assert (r[:, 0] > 0).any() and (r[:, 0] == 0).any()  # some contacts push, some separate
    # With the framework's criterion too (its scaled Coulomb residual, on W).
    rec, _ = solve_external(local, "nscd", tol)
    assert rec["status"] == "optimal" and rec["coulomb_residual"] <= tol


def test_pgs_local_form_solves_the_convex_problem_of_a_non_symmetric_w():
    local = random_local(15, 3, seed=21, skew=0.1, mu=0.5)
    sol = solve_local(LocalData.of(local), "pgs", 1e-10, max_iter=100_000)
    assert sol.status == "optimal"
    r, u = sol.p, sol.u.reshape(-1, 3)
    # K ∋ r ⊥ u ∈ K*: r in its cone, mu |u_T| <= u_N, r . u = 0, contact by contact.
    scale = max(np.abs(r).max(), np.abs(u).max())
    assert np.all(np.linalg.norm(r[:, 1:], axis=1) <= local.mu * r[:, 0] + 1e-8 * scale)
    assert np.all(local.mu * np.linalg.norm(u[:, 1:], axis=1) <= u[:, 0] + 1e-8 * scale)
    assert np.all(np.abs(np.sum(r * u, axis=1)) <= 1e-8 * scale**2)


def test_options_warm_start_and_limits():
    data = LocalData.of(random_local(15, 3, seed=5, skew=0.05))
    plain = solve_local(data, "nscd", 1e-10)
    assert plain.status == "optimal" and plain.extras["branches"]["slide"] >= 0
    for options in ({"symmetric": True}, {"relax": 0.9}, {"local": "fb"}):
        other = solve_local(data, "nscd", 1e-10, **options)
        assert other.status == "optimal", options
        assert np.allclose(other.u, plain.u, atol=1e-6 * np.abs(plain.u).max()), options
    warm = solve_local(data, "nscd", 1e-10, warm_start=plain.p)
    assert warm.status == "optimal" and warm.iterations <= 2
    capped = solve_local(data, "nscd:max_iter=2", 1e-14)
    assert capped.status == "max_iter" and capped.iterations == 2
    assert len(capped.extras["history"]) == 2
    assert capped.extras["error"] <= capped.extras["history"].min() + 1e-300
    assert solve_local(data, "pgs", 1e-10, omega=1.2, check_every=3).status == "optimal"


def test_time_limit_ends_a_long_solve():
    data = LocalData.of(random_local(40, 3, seed=6, mu=2.0))
    sol = solve_local(data, "pgs", 1e-300, time_limit=0.05, max_iter=10**9)
    assert sol.status == "time_limit" and sol.iterations > 16
    assert np.all(np.isfinite(sol.p))


# -- the Capsules files, whose W is not symmetric ----------------------------------------
@pytest.mark.parametrize("name", CAPSULES)
def test_capsules_are_solved_by_nscd_and_refused_by_clarabel(name):
    problem = read_problem(external(name))
    assert isinstance(problem, LocalProblem) and problem.symmetry_error() > 1e-4
    rec, ans = solve_external(problem, "nscd", 1e-8, time_limit=30)
    assert rec["status"] == "optimal", rec
    assert rec["natural_map_error"] <= 5e-8 and rec["coulomb_residual"] <= 1e-8
    assert ans is not None and np.allclose(ans.u, problem.W @ ans.r + problem.q)
    assert not_applicable(problem, "nscd") is None
    assert not_applicable(problem, "pgs") is None
    if solvers.resolve("clarabel")[0].unavailable_reason() is None:
        with pytest.raises(ProblemError) as info:
            solve_external(problem, "clarabel", 1e-8)
        message = str(info.value)
        assert "\n" not in message and "clarabel needs a factor" in message
        assert "W is not symmetric" in message and "nscd" in message
        assert "clarabel needs" in not_applicable(problem, "clarabel")


# -- bad input ----------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("W", "q", "mu", "dim", "match"),
    [
        (np.eye(6), np.zeros(5), np.ones(2), 3, "q has 5 entries"),
        (np.eye(6), np.zeros(6), np.ones(3), 3, "mu has 3 entries"),
        (np.eye(6), np.zeros(6), [0.3, -0.1], 3, "mu\\[1\\] is -0.1"),
        (np.ones((6, 4)), np.zeros(6), np.ones(2), 3, "square"),
        (np.eye(6), np.zeros(6), np.ones(2), 4, "dim must be 1, 2 or 3"),
        (np.eye(5), np.zeros(5), np.ones(2), 3, "not a multiple"),
        (np.eye(6), np.full(6, np.nan), np.ones(2), 3, "q has non-finite"),
    ],
)
def test_bad_local_data_is_a_one_line_problem_error(W, q, mu, dim, match):
    with pytest.raises(ProblemError, match=match) as info:
        LocalData(W, q, mu, dim)
    assert "\n" not in str(info.value)


def test_bad_requests_are_one_line_errors():
    data = LocalData(np.eye(6), -np.ones(6), np.full(2, 0.3), 3)
    bad = [
        ({"solver": "clarabel"}, "'clarabel' has no local form"),
        ({"solver": "nscd", "omega": 1.2}, "nscd has no option 'omega'"),
        ({"solver": "nscd", "tol": -1.0}, "tol must be"),
        ({"solver": "pgs", "max_iter": 0}, "max_iter must be"),
        ({"solver": "pgs", "time_limit": 0.0}, "time_limit must be"),
        ({"solver": "nscd", "warm_start": np.zeros(5)}, "warm_start has 5 entries"),
        ({"solver": "nscd", "criterion": "nope"}, "criterion must be"),
        ({"solver": "nscd", "relax": 3.0}, "relax must be"),
        ({"solver": "pgs", "omega": 2.5}, "omega must be"),
    ]
    for kwargs, match in bad:
        with pytest.raises(ProblemError, match=match) as info:
            solve_local(data, **kwargs)
        assert "\n" not in str(info.value), kwargs
    with pytest.raises(CocdError, match="unknown solver"):
        solve_local(data, "nope")
    assert local_backends() == ["nscd", "pgs"]


def test_no_contact_and_one_contact():
    empty = solve_local(LocalData(sp.csr_matrix((0, 0)), np.zeros(0), np.zeros(0), 2), "nscd")
    assert empty.status == "optimal" and empty.p.shape == (0, 2)
    # One 2D contact, W = I, q = (-1, 2): Coulomb slides with r = (1, -0.5).
    one = solve_local(LocalData(np.eye(2), np.array([-1.0, 2.0]), [0.5], 2), "nscd", 1e-12)
    assert one.status == "optimal" and np.allclose(one.p, [[1.0, -0.5]])
    assert one.extras["branches"] == {"separated": 0, "stick": 0, "slide": 1}
