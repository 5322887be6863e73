"""The ``cocd`` command."""

from __future__ import annotations

import subprocess
import sys

import pandas as pd
from typer.testing import CliRunner

from cocd.cli import app

runner = CliRunner()


def test_run_prints_per_step_statistics(tmp_path):
    out = tmp_path / "stats.csv"
    result = runner.invoke(app, ["run", "--n", "40", "--steps", "3", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "mean over 3 steps" in result.output
    lines = [ln for ln in result.output.splitlines() if ln.strip().startswith(("1 ", "2 ", "3 "))]
    assert len(lines) == 3
    df = pd.read_csv(out)
    assert len(df) == 3 and {"nc", "iterations", "ccp_residual"} <= set(df.columns)


def test_bad_options_give_one_line_and_status_2():
    result = runner.invoke(app, ["run", "--solver", "nope", "--steps", "1"])
    assert result.exit_code == 2
    assert "error: unknown solver 'nope'; available solvers:" in result.output
    assert "Traceback" not in result.output
    result = runner.invoke(app, ["run", "--dt", "0", "--steps", "1"])
    assert result.exit_code == 2
    assert "time step dt must be finite and > 0" in result.output


def test_solvers_lists_backends():
    result = runner.invoke(app, ["solvers"])
    assert result.exit_code == 0
    assert "clarabel" in result.output


def test_python_m_cocd_runs_the_default_scene():
    proc = subprocess.run(
        [sys.executable, "-m", "cocd", "run", "--n", "30", "--steps", "2"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    assert "mean over 2 steps" in proc.stdout
