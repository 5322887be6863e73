"""``cocd bench backends`` and ``cocd bench iterative``: every backend on one step, and the
iterative ones cold and warm."""

from __future__ import annotations

import numpy as np
import pandas as pd
from typer.testing import CliRunner

from cocd.cli import app
from cocd.studies import backends, iterative

runner = CliRunner()


def test_every_named_backend_answers_one_2d_and_one_3d_step(tmp_path, monkeypatch):
    monkeypatch.setenv("COCD_CACHE", str(tmp_path / "cache"))
    args = ["--n2d", "60", "--n3d", "30", "--solvers", "clarabel,pgs,qp:piqp", "--tol", "1e-7"]
    result = runner.invoke(app, ["bench", "backends", *args, "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    table = pd.read_csv(tmp_path / "backends.csv")
    assert list(table.columns) == backends.COLUMNS
    assert list(table.problem.unique()) == ["column-2d", "box-3d"]
    # Linear-cone backends get the 3D friction cone as a pyramid, and say so.
    assert set(table[table.dim == 3].solver) == {"clarabel", "pgs", "qp:piqp:facets=8"}
    exact = table[~table.solver.str.contains("facets")]
    assert (exact.status == "optimal").all() and (exact.ccp_residual <= 1e-6).all()
    # Every exact answer is the reference's velocity, to the tolerance's order.
    assert (exact.u_error < 1e-4).all()
    assert (table.Nc > 0).all() and (table.tol == 1e-7).all()


def test_a_warm_start_saves_iterations(tmp_path, monkeypatch):
    monkeypatch.setenv("COCD_CACHE", str(tmp_path / "cache"))
    table = iterative.STUDY(n=80, solvers=("pgs", "apgd"), out=tmp_path, progress=lambda s: None)
    by = table.set_index(["solver", "start"])
    assert set(by.index) == {("clarabel", "cold"), ("pgs", "cold"), ("pgs", "warm"),
                             ("apgd", "cold"), ("apgd", "warm")}  # fmt: skip
    assert (table.status == "optimal").all()
    for name in ("pgs", "apgd"):
        assert by.loc[(name, "warm"), "iterations"] < by.loc[(name, "cold"), "iterations"]
    assert (tmp_path / "iterative.md").exists()


def test_bad_sizes_and_names_are_one_line_errors(tmp_path):
    import scipy.sparse as sp

    from cocd.io import write_problem
    from cocd.io.problems import LocalProblem

    (tmp_path / "problems").mkdir()
    one = LocalProblem(sp.eye(3), np.array([-1.0, 0.0, 0.0]), np.array([0.3]), 3)
    write_problem(tmp_path / "problems" / "one.hdf5", one)
    for args, message in (
        (["backends", "--n2d", "1"], "n2d must be an integer >= 2"),
        (["backends", "--solvers", "nope"], "unknown solver 'nope'"),
        (["iterative", "--solvers", "nope"], "unknown solver 'nope'"),
        (["backends", "--solvers", ","], "no solver is named in ','"),
        (["external", str(tmp_path / "problems"), "--solvers", " , "], "no solver is named"),
    ):
        result = runner.invoke(app, ["bench", *args, "--out", str(tmp_path)])
        assert result.exit_code == 2, (args, result.output)
        assert message in result.output and "Traceback" not in result.output
