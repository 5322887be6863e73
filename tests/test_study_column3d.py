"""``cocd bench column3d-ipm`` and ``cocd bench column3d-solvers`` on a small seed column."""

from __future__ import annotations

import json

import pandas as pd
import pytest
from typer.testing import CliRunner

from cocd.cli import app
from cocd.studies import column3d_solvers

runner = CliRunner()

#: Two steps of a few hundred spheres: one to t = 0.01 s, then the recorded one.
SMALL = ["--t-start", "0.01", "--tol", "1e-5"]


@pytest.fixture(autouse=True)
def _cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("COCD_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))


def _bench(*args: str):
    return runner.invoke(app, ["bench", *args])


def test_ipm_measures_each_size_and_solves_one_to_tol(tmp_path):
    args = ["--sizes", "300,200", "--full", "300", *SMALL, "--out", str(tmp_path)]
    result = _bench("column3d-ipm", *args)
    assert result.exit_code == 0, result.output
    table = pd.read_csv(tmp_path / "column3d_ipm.csv")
    measured, seed = table.iloc[:2], table.iloc[2]
    assert list(measured.N) == [200, 300] and (measured.K_order == 6 * measured.N).all()
    assert (measured.L_nnz > measured.K_upper_nnz).all() and (measured.factor_s > 0).all()
    # The size solved to tol: a direct interior point reaches it.
    full = measured.iloc[1]
    assert full.full_status == "optimal" and full.full_ccp <= 1e-5
    assert seed.N == 122932 and seed.source.startswith("extrapolated")
    meta = json.loads((tmp_path / "column3d_ipm.meta.json").read_text())
    assert meta["files"] == ["column3d_ipm.csv", "column3d_ipm.md"]
    assert "Solved to tol at 300 spheres: optimal" in meta["summary"]
    assert "column3d_ipm" in (tmp_path / "README.md").read_text()


def test_solvers_writes_every_method_under_the_harness_names(tmp_path):
    args = ["--n", "300", *SMALL, "--time-limit", "30", "--out", str(tmp_path)]
    result = _bench("column3d-solvers", *args)
    assert result.exit_code == 0, result.output
    table = pd.read_csv(tmp_path / "column3d_solvers.csv", keep_default_na=False, na_values=[""])
    assert list(table.columns) == column3d_solvers.COLUMNS and "backend" not in table.columns
    assert list(table.solver) == [name for name, _, _ in column3d_solvers.METHODS]
    assert (table.status == "optimal").all() and (table.ccp_residual <= 1e-5).all()
    apgd = table[table.solver == "apgd"]
    assert (apgd["it_to_1e-05"] <= apgd.iterations).all() and (apgd.L_min > 0).all()
    assert (table.problem == "column3d-solvers-300").all()
    assert (tmp_path / "column3d_solvers.md").exists()
    meta = json.loads((tmp_path / "column3d_solvers.meta.json").read_text())
    assert "apgd (warm) optimal" in meta["summary"]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["column3d-ipm", "--sizes", "300"], "--sizes needs two different sizes"),
        (["column3d-ipm", "--sizes", "200,300", "--full", "250"], "--full must be 0 or one"),
        (["column3d-ipm", "--sizes", "0,300"], "--sizes must be positive integers"),
        (["column3d-solvers", "--n", "0"], "--n must be a positive integer"),
        (["column3d-solvers", "--tol", "-1"], "--tol must be a finite number > 0"),
        (["column3d-solvers", "--time-limit", "0"], "--time-limit must be a finite number > 0"),
    ],
)
def test_bad_options_are_one_line_errors(tmp_path, args, message):
    result = _bench(*args, "--out", str(tmp_path))
    assert result.exit_code != 0, result.output
    assert message in result.output and "Traceback" not in result.output
    assert len(result.output.strip().splitlines()) == 1, result.output
    assert not (tmp_path / "column3d_ipm.csv").exists()
