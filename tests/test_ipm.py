"""The ``ipm`` backend: its cone algebra, its reduced matrix, its linear solvers.

Its answers are checked against ``clarabel`` on every problem of the
conformance suite (tests/test_conformance.py); here are the parts that suite
cannot see.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.sparse as sp

import solvers
from cocd import Stepper, assemble, box_3d, column_2d, detect_contacts
from cocd.errors import ProblemError
from solvers.base import installed as _installed
from solvers.ipm_ import LINSOLVES, ReducedSystem, _Cones

MODULE = {"pardiso": "pypardiso", "cholmod": "cvxopt", "qdldl": "qdldl"}


def _interior_pair(rng, n_lin, k):
    s_l = rng.uniform(0.1, 2.0, n_lin)
    z_l = rng.uniform(0.1, 2.0, n_lin)
    s_q = rng.normal(size=(k, 3))
    z_q = rng.normal(size=(k, 3))
    s_q[:, 0] = np.linalg.norm(s_q[:, 1:], axis=1) + rng.uniform(0.05, 1.0, k)
    z_q[:, 0] = np.linalg.norm(z_q[:, 1:], axis=1) + rng.uniform(0.05, 1.0, k)
    cones = _Cones(n_lin, k)
    return cones, cones.join(s_l, s_q), cones.join(z_l, z_q)


def test_nesterov_todd_scaling_identities():
    rng = np.random.default_rng(0)
    cones, s, z = _interior_pair(rng, 4, 5)
    sc = cones.scaling(s, z)
    lam = cones.apply_w(sc, z)
    assert np.allclose(lam, cones.apply_w(sc, s, inverse=True), rtol=1e-12, atol=1e-14)
    v = rng.normal(size=s.size)
    assert np.allclose(cones.apply_w(sc, cones.apply_w(sc, v), inverse=True), v)
    # Theta = W^-2 block by block.
    theta_lin, theta_soc = cones.theta_blocks(sc)
    W = np.column_stack([cones.apply_w(sc, e) for e in np.eye(s.size)])
    Winv2 = np.linalg.inv(W @ W)
    assert np.allclose(theta_lin, np.diag(Winv2)[:4])
    for c in range(5):
        rows = slice(4 + 3 * c, 7 + 3 * c)
        assert np.allclose(theta_soc[c], Winv2[rows, rows])
    # lambda o (lambda \ r) = r.
    r = rng.normal(size=s.size)
    assert np.allclose(cones.product(lam, cones.divide(lam, r)), r)


def test_max_step_lands_on_the_cone_boundary():
    rng = np.random.default_rng(1)
    cones, s, _ = _interior_pair(rng, 0, 200)
    d = rng.normal(size=s.size) * 3.0
    alpha = cones.max_step(s, d)
    assert 0.0 < alpha < 1e30
    _, inside = cones.split(s + 0.999 * alpha * d)
    _, outside = cones.split(s + 1.001 * alpha * d)
    margin_in = inside[:, 0] - np.linalg.norm(inside[:, 1:], axis=1)
    margin_out = outside[:, 0] - np.linalg.norm(outside[:, 1:], axis=1)
    assert margin_in.min() >= 0.0 and margin_out.min() < 0.0


@pytest.mark.parametrize("dim", [2, 3])
def test_reduced_matrix_is_p_plus_a_theta_a(dim):
    scene = column_2d(150, seed=3) if dim == 2 else box_3d(120, seed=3, mu=0.4)
    stepper = Stepper(scene, 1e-3, tol=1e-9)
    stepper.run(15)
    form = stepper.problem.primal_conic_form()
    A = sp.csr_matrix(form.A)
    A.sort_indices()
    n_lin = sum(size for kind, size in form.cones if kind == "nonneg")
    k = sum(1 for kind, _ in form.cones if kind == "soc")
    pdiag = form.P.diagonal()
    red = ReducedSystem(A, n_lin, k, pdiag)
    if dim == 2:  # the two half-planes of a contact (or more rows on one disc) are one group
        assert n_lin == 2 * stepper.problem.nc
        assert stepper.problem.nc / 2 <= red.n_lin_groups <= stepper.problem.nc
    rng = np.random.default_rng(4)
    theta_lin = rng.uniform(1e-3, 1e3, n_lin)
    B = rng.normal(size=(k, 3, 3))
    theta_soc = np.einsum("kij,klj->kil", B, B)
    pattern = red.pattern
    out = red.fill(theta_lin, theta_soc)
    mine = sp.csr_matrix((out, pattern.indices, pattern.indptr), pattern.shape).toarray()
    blocks = [sp.diags(theta_lin)] + [sp.csr_matrix(t) for t in theta_soc]
    expected = np.triu((sp.diags(pdiag) + A.T @ sp.block_diag(blocks) @ A).toarray())
    assert np.allclose(mine, expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())


@pytest.mark.parametrize("dim", [2, 3])
def test_every_installed_linear_solver_gives_the_same_answer(dim):
    scene = column_2d(300, seed=5) if dim == 2 else box_3d(150, seed=5, mu=0.4)
    stepper = Stepper(scene, 1e-3, tol=1e-10)
    stepper.run(20)
    problem = stepper.problem
    ref = solvers.solve(problem, "clarabel", tol=1e-10)
    scale = max(np.linalg.norm(ref.u), np.linalg.norm(problem.U))
    used = [name for name in LINSOLVES if _installed(MODULE[name])]
    assert "qdldl" in used
    for name in used:
        sol = solvers.solve(problem, "ipm", tol=1e-9, linsolve=name)
        assert sol.status == "optimal", (name, sol.extras["history"][-3:])
        assert sol.extras["linsolve"] == name
        assert np.linalg.norm(sol.u - ref.u) <= 1e-6 * scale, name
        assert sol.iterations <= 40
        # One numerical factorisation per iteration (more when a pivot forces a shift).
        assert sol.extras["factorisations"] >= sol.iterations - 1
        assert sol.extras["system_size"] == problem.H.shape[1]
        if name == "pardiso":  # the factor holds K's upper triangle and its fill
            assert sol.extras["factor_nnz"] >= sol.extras["system_nnz"]
            # Counted afresh for every matrix (PARDISO's handle is shared by solves).
            smaller = dataclasses.replace(problem, H=problem.H[: 3 * problem.contact_dim],
                                          D=problem.D[:3], mu=problem.mu[:3])  # fmt: skip
            other = solvers.solve(smaller, "ipm", tol=1e-9, linsolve=name)
            assert other.extras["factor_nnz"] < sol.extras["factor_nnz"]
        else:
            assert sol.extras["factor_nnz"] is None


def test_sliding_contact_is_finished_by_the_polish():
    # One sphere sliding down a 55 degree slope: the interior point stalls on the
    # degenerate sliding contact, the active-set polish finishes it.
    from test_conformance import _slope

    stepper = Stepper(_slope(3, 55.0), 1e-3, tol=1e-10)
    stepper.run(5)
    scene = stepper.scene
    problem = assemble(scene, detect_contacts(scene), 1e-3)  # the next step
    sol = solvers.solve(problem, "ipm", tol=1e-10)
    assert sol.status == "optimal" and sol.extras["polished"] is True
    ref = solvers.solve(problem, "clarabel", tol=1e-10)
    assert np.allclose(sol.u, ref.u, rtol=0, atol=1e-8 * np.linalg.norm(ref.u))
    # It slides: the tangential speed grows by about g (sin - mu cos) dt.
    g = 9.81 * (np.sin(np.radians(55.0)) - 0.3 * np.cos(np.radians(55.0)))
    assert sol.u[0] == pytest.approx(scene.velocities[0, 0] + g * 1e-3, rel=1e-4)
    unpolished = solvers.solve(problem, "ipm", tol=1e-10, polish=False)
    assert unpolished.extras["polished"] is False
    # The polish starts no Newton solve once its time budget is spent.
    from solvers.polish import polish_impulses

    p0 = unpolished.p
    same, info = polish_impulses(problem, p0, target=1e-10, time_budget=0.0)
    assert info["out_of_time"] and info["accepted"] == 0 and np.array_equal(same, p0)
    done, info = polish_impulses(problem, p0, target=1e-10, time_budget=60.0)
    assert not info["out_of_time"] and info["ccp_after"] <= 1e-10


def test_bad_options_are_named():
    problem = _first_problem()
    with pytest.raises(ProblemError, match="linsolve must be one of"):
        solvers.solve(problem, "ipm", linsolve="superlu")
    with pytest.raises(ProblemError, match="ipm has no option 'colour'"):
        solvers.solve(problem, "ipm", colour="red")


def test_threads_follow_the_option_then_mkl_num_threads(monkeypatch):
    """PARDISO's threads: the option, else MKL_NUM_THREADS (Dask's workers and
    `cocd validate --workers` set it to 1), else 2; a bad value is named."""
    from solvers.ipm_ import _threads

    monkeypatch.delenv("MKL_NUM_THREADS", raising=False)
    assert _threads({}) == 2
    monkeypatch.setenv("MKL_NUM_THREADS", "1")
    assert _threads({}) == 1 and _threads({"threads": 3}) == 3
    monkeypatch.setenv("MKL_NUM_THREADS", "many")
    with pytest.raises(ProblemError, match="MKL_NUM_THREADS must be a positive integer"):
        _threads({})
    with pytest.raises(ProblemError, match="the option threads must be a positive integer"):
        _threads({"threads": -1})
    # Only PARDISO takes threads: the others ignore a bad MKL_NUM_THREADS.
    problem = _first_problem()
    assert solvers.solve(problem, "ipm", linsolve="qdldl").extras["threads"] is None
    if _installed("pypardiso"):
        monkeypatch.setenv("MKL_NUM_THREADS", "1")
        assert solvers.solve(problem, "ipm", linsolve="pardiso").extras["threads"] == 1


def _first_problem():
    stepper = Stepper(column_2d(30), 1e-3)
    stepper.step()
    return stepper.problem


def test_gondzio_correctors_keep_the_answer_and_save_iterations():
    scene = column_2d(600, seed=7)
    stepper = Stepper(scene, 1e-3, tol=1e-10)
    stepper.run(30)
    problem = stepper.problem
    plain = solvers.solve(problem, "ipm", tol=1e-9, correctors=0)
    corrected = solvers.solve(problem, "ipm", tol=1e-9, correctors=2)
    assert plain.status == corrected.status == "optimal"
    scale = max(np.linalg.norm(plain.u), np.linalg.norm(problem.U))
    assert np.linalg.norm(corrected.u - plain.u) <= 1e-6 * scale
    assert corrected.iterations < plain.iterations
