"""The ``cocd`` command: ``run`` without a scene file, ``solvers``, bad options."""

from __future__ import annotations

import subprocess
import sys

import pandas as pd
from typer.testing import CliRunner

from cocd.cli import app

runner = CliRunner()


def test_run_without_scene_file_runs_the_default_collapse(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    result = runner.invoke(app, ["run", "--steps", "3"])
    assert result.exit_code == 0, result.output
    assert "default: column_2d(n_grains=300" in result.output
    # Not a terminal: plain progress lines, the last one at the last step.
    assert "step 3/3" in result.output
    assert "3 steps, 2 frames" in result.output
    stats = pd.read_csv(tmp_path / "cocd-runs" / "default" / "stats.csv")
    assert list(stats.step) == [1, 2, 3]
    assert (stats.ccp_residual <= 1e-8).all() and (stats.nc > 0).all()


def test_bad_options_give_one_line_and_status_2(tmp_path):
    out = ["--out", str(tmp_path)]
    result = runner.invoke(app, ["run", "--solver", "nope", "--steps", "1", *out])
    assert result.exit_code == 2
    assert "error: unknown solver 'nope'; available solvers:" in result.output
    assert "Traceback" not in result.output
    result = runner.invoke(app, ["run", "--dt", "0", "--steps", "1", *out])
    assert result.exit_code == 2
    assert result.output.strip() == "error: command line: run.dt: Input should be greater than 0"


def test_solvers_lists_backends():
    result = runner.invoke(app, ["solvers"])
    assert result.exit_code == 0
    assert "clarabel" in result.output


def test_python_m_cocd_runs_the_default_scene(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "cocd", "run", "--steps", "2", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    assert "2 steps, 2 frames" in proc.stdout
    assert (tmp_path / "run.h5").exists() and (tmp_path / "stats.csv").exists()
