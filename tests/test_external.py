"""External problems solved by cocd's backends: agreement, the stepper's export, the commands."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import scipy.sparse as sp
from conftest import external
from typer.testing import CliRunner

import solvers
from cocd.builders import box_3d, column_2d
from cocd.cli import app
from cocd.external import describe, not_applicable, solve_external
from cocd.io import read_problem, write_problem
from cocd.io.fclib import read_fclib_solution
from cocd.io.problems import GlobalProblem, LocalProblem
from cocd.stepper import Stepper

GRANULAR_2D = [
    "fc2d_granularflowonwall_00667_00000.dat",
    "fc2d_granularflowonwall_02020_00213.dat",
]
runner = CliRunner()


def have(name: str) -> bool:
    return solvers.resolve(name)[0].unavailable_reason() is None


def _stepped(dim: int, tmp_path: Path, solver: str = "clarabel"):
    scene = column_2d(60, mu=0.4) if dim == 2 else box_3d(40, mu=0.4)
    stepper = Stepper(scene, 1e-3, solver=solver, tol=1e-9, fclib_dir=tmp_path, fclib_steps=[8])
    stepper.run(10)
    return stepper


# -- the stepper writes steps other tools can solve ----------------------------------
@pytest.mark.parametrize("dim", [2, 3])
def test_exported_step_is_the_step_problem(tmp_path, dim):
    stepper = _stepped(dim, tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["step_000008.hdf5"]
    path = stepper.export_step(tmp_path / "last.hdf5")
    g = read_problem(path)
    stored = read_fclib_solution(path)
    problem, solution = stepper.problem, stepper.solution
    assert isinstance(g, GlobalProblem) and stored is not None
    assert (g.nc, g.ndof, g.dim) == (problem.nc, problem.ndof, dim)
    assert np.array_equal(g.M.diagonal(), problem.mass)
    assert np.array_equal(g.H.T.toarray(), problem.H.toarray())
    assert np.array_equal(stored.r, solution.p.reshape(-1))
    assert np.allclose(stored.v, problem.velocity(solution.p), rtol=1e-13, atol=1e-15)
    # The stored answer satisfies the file's equations and the convex law.
    assert np.allclose(g.M @ stored.v, g.H @ stored.r + g.f, rtol=0, atol=1e-12)
    assert np.allclose(stored.u, g.H.T @ stored.v + g.w, rtol=0, atol=1e-12)
    record, answer = solve_external(g, "clarabel", 1e-9)
    assert record["status"] == "optimal" and record["ccp_residual"] <= 1e-9
    assert np.allclose(answer.r, stored.r, rtol=0, atol=1e-6 * np.abs(stored.r).max())


def test_frictionless_step_is_written_with_zero_friction(tmp_path):
    scene = column_2d(40, mu=0.0)
    stepper = Stepper(scene, 1e-3, solver="clarabel", tol=1e-9)
    stepper.run(5)
    g = read_problem(stepper.export_step(tmp_path / "s.hdf5"))
    assert g.dim == 2 and np.all(g.mu == 0.0)
    record, answer = solve_external(g, "clarabel", 1e-9)
    assert record["status"] == "optimal"
    assert np.allclose(answer.r.reshape(-1, 2)[:, 0], stepper.solution.p[:, 0], rtol=0, atol=1e-6)
    assert np.allclose(answer.r.reshape(-1, 2)[:, 1], 0.0, atol=1e-9)


# -- backends agree on the same external problem -------------------------------------
def test_global_and_condensed_local_give_the_same_answer(tmp_path):
    stepper = _stepped(3, tmp_path)
    g = read_problem(tmp_path / "step_000008.hdf5")
    local = g.local()
    rg, ag = solve_external(g, "clarabel", 1e-10)  # velocity-based on the global form
    rl, al = solve_external(local, "clarabel-dual", 1e-10)  # impulse-based on the local form
    assert rg["status"] == rl["status"] == "optimal"
    scale = np.abs(ag.r).max()
    assert np.allclose(ag.u, al.u, rtol=0, atol=1e-6 * np.abs(ag.u).max())
    # Normal impulses are unique here (a heap at rest on a floor).
    assert np.allclose(ag.r[0::3], al.r[0::3], rtol=0, atol=1e-4 * scale)
    assert rg["natural_map_error"] == pytest.approx(g.natural_map_error(al.r), rel=0.5, abs=1e-9)
    assert stepper.problem is not None


def test_sliding_contact_convex_and_coulomb_answers_differ_as_they_should():
    # One 2D contact, W = I, q = (-1, 2): Coulomb slides with r = (1, -0.5);
    # the convex problem opens a gap instead: r on the cone's edge, u_N = mu |u_T|.
    local = LocalProblem(W=sp.identity(2), q=np.array([-1.0, 2.0]), mu=np.array([0.5]), dim=2)
    rec, ans = solve_external(local, "nscd", 1e-10)
    assert rec["natural_map_error"] <= 1e-9
    assert np.allclose(ans.r, [1.0, -0.5], atol=1e-8)
    rec, ans = solve_external(local, "clarabel", 1e-10)
    assert rec["ccp_residual"] <= 1e-9 and rec["natural_map_error"] > 1e-2
    u = ans.u
    assert u[0] == pytest.approx(0.5 * abs(u[1]), abs=1e-7)


# -- the 2D granular problems from Siconos --------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("name", GRANULAR_2D)
def test_granular_2d_local_problems_are_solved_by_several_backends(name):
    problem = read_problem(external(name))
    assert isinstance(problem, LocalProblem) and problem.dim == 2
    # Two impulse-based convex backends solve the convex problem on the file's own W
    # (02020 is indefinite by the rounding of its 6 printed digits: its factor is
    # shifted, and the shift is carried so that W itself is solved).
    convex = {}
    for solver in ("clarabel-dual", "scs-dual"):
        rec, ans = solve_external(problem, solver, 1e-10)
        assert rec["status"] == "optimal" and rec["ccp_residual"] <= 1e-8, (solver, rec)
        convex[solver] = ans
    a, b = convex.values()
    # w = W r + q of the convex problem is unique; so are the impulses when W is definite.
    assert np.allclose(a.u, b.u, rtol=0, atol=1e-6 * max(np.abs(a.u).max(), 1e-300))
    if problem.shift == 0.0:
        assert np.allclose(a.r, b.r, rtol=0, atol=1e-6 * max(np.abs(a.r).max(), 1e-300))
    # The non-convex reference solves Coulomb's law itself in the file's terms.
    rec, ans = solve_external(problem, "nscd", 1e-10, max_iter=4000)
    assert rec["natural_map_error"] <= 1e-6, rec
    # The convex answer is not the Coulomb one where contacts slide.
    if problem.nc > 1000:
        assert solve_external(problem, "clarabel-dual", 1e-10)[0]["natural_map_error"] > 1e-4


def test_fixed_point_solves_the_small_granular_problem():
    problem = read_problem(external(GRANULAR_2D[0]))
    rec, ans = solve_external(problem, "fp:clarabel-dual", 1e-10)
    assert rec["natural_map_error"] <= 1e-6, rec
    nscd = solve_external(problem, "nscd", 1e-10)[1]
    assert np.allclose(ans.r, nscd.r, rtol=0, atol=1e-6 * max(np.abs(nscd.r).max(), 1e-300))


# -- the commands --------------------------------------------------------------------
def test_problem_info_and_solve_commands(tmp_path):
    stepper = _stepped(2, tmp_path)
    path = stepper.export_step(tmp_path / "s.hdf5")
    result = runner.invoke(app, ["problem", "info", str(path), "--json"])
    assert result.exit_code == 0, result.output
    info = json.loads(result.output)
    assert info["kind"] == "global" and info["nc"] == stepper.problem.nc
    sol_path = tmp_path / "answer.npz"
    result = runner.invoke(
        app,
        [
            "problem",
            "solve",
            str(path),
            "--solver",
            "clarabel-dual",
            "--tol",
            "1e-9",
            "--json",
            "--save-solution",
            str(sol_path),
        ],
    )
    assert result.exit_code == 0, result.output
    record = json.loads(result.output)
    assert set(record) >= {
        "problem",
        "kind",
        "dim",
        "nc",
        "ndof",
        "solver",
        "status",
        "iterations",
        "setup_s",
        "solve_s",
        "ccp_residual",
        "coulomb_residual",
        "natural_map_error",
    }
    assert record["status"] == "optimal" and record["ccp_residual"] <= 1e-9
    saved = np.load(sol_path)
    g = read_problem(path)
    assert set(saved.files) == {"r", "u", "v"}
    # Independently checkable: the saved arrays satisfy the file's equations.
    assert np.allclose(g.M @ saved["v"], g.H @ saved["r"] + g.f, atol=1e-12)
    assert np.allclose(saved["u"], g.H.T @ saved["v"] + g.w, atol=1e-12)
    assert g.natural_map_error(saved["r"]) == pytest.approx(record["natural_map_error"])


def test_problem_commands_fail_with_one_line(tmp_path):
    bad = tmp_path / "bad.dat"
    bad.write_text("7\n")
    for args in (
        ["problem", "info", str(tmp_path / "none.hdf5")],
        ["problem", "solve", str(bad)],
    ):
        result = runner.invoke(app, args)
        assert result.exit_code == 2, result.output
        assert result.output.startswith("error: ") and "Traceback" not in result.output
    g = GlobalProblem.from_conic(_stepped(2, tmp_path).problem)
    path = write_problem(tmp_path / "g.hdf5", g)
    result = runner.invoke(app, ["problem", "solve", str(path), "--solver", "nope"])
    assert result.exit_code == 2 and "unknown solver 'nope'" in result.output


def test_describe_and_applicability(tmp_path):
    g = GlobalProblem.from_conic(_stepped(3, tmp_path).problem)
    info = describe(g)
    assert info["kind"] == "global" and info["M_diagonal"] is True
    assert info["W_symmetry_error"] <= 1e-15
    assert not_applicable(g, "clarabel") is None
    assert not_applicable(g, "nscd") is None
    if have("qp:piqp"):
        assert "linear cones" in not_applicable(g, "qp:piqp")
    assert "unknown solver" in not_applicable(g, "nope")


def test_bench_external_writes_table_and_profiles(tmp_path):
    folder = tmp_path / "problems"
    folder.mkdir()
    for dim in (2, 3):
        stepper = _stepped(dim, tmp_path / f"steps{dim}")
        stepper.export_step(folder / f"step{dim}d.hdf5")
    (folder / "broken.dat").write_text("2\n3\n0\n")
    (folder / "README.md").write_text("not a problem")
    out = tmp_path / "out"
    result = runner.invoke(
        app,
        [
            "bench",
            "external",
            str(folder),
            "--solvers",
            "clarabel,clarabel-dual,nscd",
            "--time-limit",
            "60",
            "--out",
            str(out),
        ],
    )
    assert result.exit_code == 0, result.output
    table = pd.read_csv(out / "external.csv")
    assert set(table.problem) == {"step2d.hdf5", "step3d.hdf5", "broken.dat"}
    assert table.loc[table.problem == "broken.dat", "status"].tolist() == ["unreadable"]
    solved = table[table.problem != "broken.dat"]
    convex = solved[solved.solver.isin(["clarabel", "clarabel-dual"])]
    assert len(convex) == 4 and (convex.ccp_residual <= 1e-8).all()
    assert (out / "external_profiles.png").stat().st_size > 10_000
    assert "external" in (out / "README.md").read_text()


def test_indefinite_by_rounding_w_is_solved_exactly_by_w_based_backends():
    # A Delassus operator of 8 contacts on 6 unknowns, then rounded so that it is
    # indefinite by 1e-7 of its scale, as a file printed with few digits is.
    rng = np.random.default_rng(7)
    B = rng.normal(size=(16, 6))
    W = B @ B.T
    lam, V = np.linalg.eigh(W)
    lam[lam < 1e-8 * lam.max()] = -1e-7 * lam.max()
    W = (V * lam) @ V.T
    W = 0.5 * (W + W.T)
    # Feasible: q = B U + (gap rates >= 0, 0): stopping every body satisfies the law.
    c = np.zeros((8, 2))
    c[:, 0] = rng.uniform(0.0, 0.1, 8)
    q = B @ rng.normal(size=6) + c.reshape(-1)
    local = LocalProblem(W=sp.csc_matrix(W), q=q, mu=np.full(8, 0.4), dim=2)
    assert local.shift > 0.0
    conic = local.conic
    assert conic.delassus_shift == local.shift
    assert np.allclose(conic.W.toarray(), W, rtol=0, atol=1e-10 * np.abs(W).max())
    assert np.allclose(conic.contact_velocity(np.ones((8, 2))).reshape(-1), W @ np.ones(16) + q)
    for solver in ("pgs", "clarabel-dual", "apgd"):
        rec, ans = solve_external(local, solver, 1e-9, max_iter=200_000)
        assert rec["ccp_residual"] <= 1e-8, (solver, rec)
        # Judged on the file's W directly.
        assert np.allclose(ans.u, W @ ans.r + q)
    rec, ans = solve_external(local, "nscd", 1e-10, max_iter=100_000)
    assert rec["natural_map_error"] <= 1e-8, rec
    # The primal is built on the shifted factor and says so.
    rec, _ = solve_external(local, "clarabel", 1e-9)
    assert "W + " in rec["note"]
