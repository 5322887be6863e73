"""``cocd bench nscd-local`` and ``cocd bench profile``, run on tiny columns from the
command line."""

from __future__ import annotations

import json

import pandas as pd
import pytest
from typer.testing import CliRunner

import solvers
from cocd.cli import app
from cocd.studies import nscd_local

runner = CliRunner()


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """One step-problem cache for the module: the profile runs share their recording."""
    return tmp_path_factory.mktemp("cache")


def bench(*args):
    result = runner.invoke(app, ["bench", *map(str, args)])
    assert result.exit_code == 0, result.output
    return result.output


def test_both_local_solvers_reach_the_tolerance_and_agree(tmp_path, monkeypatch, cache):
    monkeypatch.setenv("COCD_CACHE", str(cache))
    bench("nscd-local", "--n2d", 60, "--n3d", 40, "--tol", 1e-6, "--out", tmp_path)
    table = pd.read_csv(tmp_path / "nscd_local.csv", keep_default_na=False)
    assert list(table.columns) == nscd_local.COLUMNS
    assert list(zip(table.problem, table.local, strict=True)) == [
        ("column-2d", "exact"), ("column-2d", "fb"), ("box-3d", "exact"), ("box-3d", "fb"),
    ]  # fmt: skip
    assert (table.status == "optimal").all() and (table.solver == "nscd").all()
    assert (table.coulomb_residual <= 1e-6).all() and (table.tol == 1e-6).all()
    assert (table.Nc > 0).all() and (table.wall_s > 0).all()
    # The same reactions from both local solvers.
    assert (table.p_diff < 1e-6).all()
    fb, exact = table[table.local == "fb"], table[table.local == "exact"]
    assert (fb.newton > 0).all() and (exact.newton == 0).all() and (exact.fallback == 0).all()
    meta = json.loads((tmp_path / "nscd_local.meta.json").read_text())
    assert "fb / exact wall time" in meta["summary"]
    assert "nscd_local.md" in (tmp_path / "README.md").read_text()


def test_the_profile_lists_the_backends_solve_function(tmp_path, monkeypatch, cache):
    monkeypatch.setenv("COCD_CACHE", str(cache))
    common = ("--n", 40, "--trajectory", "clarabel", "--out", tmp_path)
    output = bench("profile", *common, "--top", 12, "--detect")
    function = solvers.get("ipm").entry.split(":")[1]
    text = (tmp_path / "profile_ipm.txt").read_text()
    assert function in text and "--- by tottime ---" in text
    assert "detect_contacts" in text  # --detect profiles detection too
    assert "ipm: optimal" in output and "by own time" in output
    meta = json.loads((tmp_path / "profile_ipm.meta.json").read_text())
    assert meta["files"] == ["profile_ipm.txt"] and "ipm: optimal" in meta["summary"]
    # A name with options makes a file name; another step of the same recording.
    bench("profile", *common, "--solver", "qp:piqp", "--step", 9, "--top", 5)
    other = (tmp_path / "profile_qp_piqp.txt").read_text()
    assert solvers.get("qp:piqp").entry.split(":")[1] in other
    assert "detect_contacts" not in other
    readme = (tmp_path / "README.md").read_text()
    assert "profile_ipm.txt" in readme and "profile_qp_piqp.txt" in readme


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["nscd-local", "--n2d", "1"], "--n2d must be an integer >= 2"),
        (["nscd-local", "--tol", "0"], "--tol must be a finite number > 0"),
        (["profile", "--step", "10"], "--step must be 0 to 9"),
        (["profile", "--solver", "nope"], "unknown solver 'nope'"),
        (["profile", "--top", "0"], "--top must be >= 1"),
    ],
)
def test_bad_options_are_one_line_errors(tmp_path, args, message):
    result = runner.invoke(app, ["bench", *args, "--out", str(tmp_path)])
    assert result.exit_code == 2, (args, result.output)
    assert message in result.output and "Traceback" not in result.output
    assert len(result.output.strip().splitlines()) == 1
    assert not (tmp_path / "README.md").exists()
