"""``cocd bench stability``: the seed's Fig. 3 test (a box at rest stays at rest)."""

from __future__ import annotations

import json
import time

import numpy as np
import pandas as pd
import pytest
from conftest import run_study
from typer.testing import CliRunner

import solvers
from cocd.builders import static_box
from cocd.cli import app
from cocd.errors import CocdError, SolverNotFound
from cocd.studies import stability

N = 30  # the CLI test's box, so that one rain deposition serves every test
THRESHOLD = 1e-6
BASE = dict(n=N, dim=2, t_end=1.0, dt=1e-2, threshold=THRESHOLD, time_limit=60.0)


@pytest.fixture(scope="module", autouse=True)
def cache(tmp_path_factory):
    """One packing cache for the module: the box is deposited once."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("COCD_CACHE", str(tmp_path_factory.mktemp("cocd-cache")))
        yield


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    """clarabel at 1e-8, apgd loose (1e-1) and tight (1e-6), in process."""
    out = tmp_path_factory.mktemp("stability")
    settings = dict(solvers="clarabel,apgd", tols=[1e-1, 1e-6, 1e-8], **BASE)
    out, table, lines = run_study(stability.STUDY, out, isolate=False, **settings)
    return table, out, lines


def _row(table: pd.DataFrame, solver: str, eps: float) -> pd.Series:
    rows = table[(table["solver"] == solver) & np.isclose(table["tol"], eps)]
    assert len(rows) == 1
    return rows.iloc[0]


def test_files_and_columns(result):
    table, out, lines = result
    for name in (
        "stability.csv",
        "stability_summary.csv",
        "stability_summary.md",
        "stability.png",
        "stability.meta.json",
    ):
        assert (out / name).is_file(), name
    assert list(table.columns) == stability.SUMMARY_COLUMNS
    assert list(pd.read_csv(out / "stability_summary.csv").columns) == stability.SUMMARY_COLUMNS
    series = pd.read_csv(out / "stability.csv")
    assert list(series.columns) == stability.SERIES_COLUMNS
    assert len(table) == 6  # 2 solvers x 3 eps
    assert (series.groupby(["solver", "tol"]).size() == table["steps_asked"].iloc[0]).all()
    assert (series["t_over_T"] > 0).all() and series["t_over_T"].max() >= BASE["t_end"]
    assert f"**{THRESHOLD:g}**" in (out / "stability_summary.md").read_text()
    meta = json.loads((out / "stability.meta.json").read_text())
    assert set(meta["files"]) >= {"stability.csv", "stability_summary.md", "stability.png"}
    assert "| clarabel" in meta["summary"] and "1e-08" in meta["summary"]
    assert any(line.startswith("[6/6]") for line in lines)


def test_number_of_steps_follows_packing_height(result):
    table, _, _ = result
    scene = static_box(2, n_grains=N)
    height = float(np.max(scene.positions[:, 1] + scene.radii))  # floor at y = 0
    expected = int(np.ceil(BASE["t_end"] * np.sqrt(height / 9.81) / BASE["dt"]))
    assert (table["steps_asked"] == expected).all()
    assert (table["N"] == N).all() and (table["dim"] == 2).all()


def test_interior_point_keeps_box_at_rest(result):
    table, out, _ = result
    row = _row(table, "clarabel", 1e-8)
    assert row["at_rest"]
    assert row["steps_done"] == row["steps_asked"]
    assert row["max_energy_ratio"] < THRESHOLD
    assert row["ccp_residual"] <= 10 * 1e-8
    series = pd.read_csv(out / "stability.csv")
    mine = series[(series["solver"] == "clarabel") & np.isclose(series["tol"], 1e-8)]
    assert (mine["energy_ratio"] >= 0).all() and (mine["energy_ratio"] < THRESHOLD).all()


def test_loose_tolerance_sets_box_in_motion(result):
    table, _, _ = result
    loose, tight = _row(table, "apgd", 1e-1), _row(table, "apgd", 1e-6)
    assert tight["at_rest"] and not loose["at_rest"]
    assert loose["steps_done"] == loose["steps_asked"]  # it moved; it did not fail
    assert loose["max_energy_ratio"] > 1e3 * tight["max_energy_ratio"]


@pytest.mark.parametrize(
    "change",
    [
        dict(tols=[]),
        dict(tols=[1e-3, 0.0]),
        dict(tols=[-1e-3]),
        dict(tols=[float("nan")]),
        dict(n=0),
        dict(dim=1),
        dict(dim=4),
        dict(t_end=0.0),
        dict(t_end=-1.0),
        dict(dt=0.0),
        dict(threshold=0.0),
        dict(threshold=-1e-6),
        dict(time_limit=0.0),
    ],
)
def test_bad_inputs_raise(change, tmp_path):
    kwargs = {**BASE, "tols": [1e-8], **change}
    with pytest.raises(CocdError):
        stability.STUDY(solvers="clarabel", out=tmp_path, **kwargs)
    assert not (tmp_path / "stability.csv").exists()


def test_unknown_solver_raises(tmp_path):
    with pytest.raises(SolverNotFound):
        stability.STUDY(solvers="no-such-solver", tols=[1e-8], out=tmp_path, **BASE)
    assert issubclass(SolverNotFound, CocdError)


def test_backend_failure_is_a_row(tmp_path, monkeypatch):
    """A backend raising mid-run ends that run only; its partial series is kept."""
    real = solvers.solve
    calls = {"n": 0}

    def flaky(problem, solver="clarabel", tol=1e-8, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 3:
            raise RuntimeError("backend exploded")
        return real(problem, solver, tol, *args, **kwargs)

    monkeypatch.setattr(solvers, "solve", flaky)
    monkeypatch.setattr(stability, "PROGRESS_S", 0.0)  # a line for every step
    lines: list[str] = []
    table = stability.STUDY(
        solvers="clarabel",
        tols=[1e-8, 1e-6],
        out=tmp_path,
        progress=lines.append,
        isolate=False,
        **BASE,
    )
    failed, fine = _row(table, "clarabel", 1e-8), _row(table, "clarabel", 1e-6)
    assert failed["steps_done"] == 2 and not failed["at_rest"]
    assert "RuntimeError: backend exploded" in failed["note"]
    assert fine["steps_done"] == fine["steps_asked"] and fine["at_rest"]
    series = pd.read_csv(tmp_path / "stability.csv")
    assert (np.isclose(series["tol"], 1e-8)).sum() == 2
    meta = json.loads((tmp_path / "stability.meta.json").read_text())
    assert "failed at step 3" in meta["summary"]
    assert any("clarabel eps=1e-08: step 2/" in line for line in lines)


def test_run_budget_stops_a_slow_run(tmp_path, monkeypatch):
    """A run that spends its wall-time budget keeps its steps and is not at rest."""
    real = solvers.solve

    def slow(*args, **kwargs):
        time.sleep(0.2)
        return real(*args, **kwargs)

    monkeypatch.setattr(solvers, "solve", slow)
    table = stability.STUDY(
        solvers="clarabel",
        tols=[1e-8],
        out=tmp_path,
        progress=lambda _: None,
        isolate=False,
        run_budget=0.3,
        **BASE,
    )
    row = _row(table, "clarabel", 1e-8)
    assert 1 <= row["steps_done"] < row["steps_asked"]
    assert row["note"].startswith("run budget of 0.3 s") and not row["at_rest"]
    meta = json.loads((tmp_path / "stability.meta.json").read_text())
    assert f"budget spent at step {row['steps_done']}" in meta["summary"]
    with pytest.raises(CocdError, match="--run-budget must be a finite number > 0"):
        stability.STUDY(solvers="clarabel", tols=[1e-8], out=tmp_path, run_budget=0.0, **BASE)


def test_child_failure_and_hang_are_rows(tmp_path):
    """In a child process: a backend error is a row; so is a child killed by the watchdog."""
    # One iteration per solve: clarabel stops with status max_iter at step 1, on any
    # machine (a microsecond time limit let a lightly loaded one finish a tiny solve).
    table = stability.STUDY(
        solvers="clarabel:max_iter=1",
        tols=[1e-8],
        out=tmp_path / "error",
        progress=lambda _: None,
        **BASE,
    )
    row = _row(table, "clarabel:max_iter=1", 1e-8)
    assert row["steps_done"] == 0 and not row["at_rest"]
    assert "SolverError" in row["note"] and "status max_iter" in row["note"]
    # No grace: the child cannot even start within 1.5 ms, so it is killed as hung.
    table = stability.STUDY(
        solvers="clarabel",
        tols=[1e-8],
        out=tmp_path / "hang",
        progress=lambda _: None,
        grace=0.0,
        **{**BASE, "time_limit": 1e-3},
    )
    row = _row(table, "clarabel", 1e-8)
    assert row["note"].startswith("killed") and not row["at_rest"]


def test_cli_end_to_end(tmp_path, monkeypatch):
    # Without --out the results go to cocd-results/, never into a committed results/.
    monkeypatch.chdir(tmp_path)
    args = ["bench", "stability", "--n", "30", "--dim", "2", "--solvers", "clarabel"]
    args += ["--eps-list", "1e-8", "--t-end", "0.5", "--run-budget", "600"]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, res.output
    assert not (tmp_path / "results").exists()
    tmp_path = tmp_path / "cocd-results"
    table = pd.read_csv(tmp_path / "stability_summary.csv")
    assert len(table) == 1 and bool(table["at_rest"].iloc[0])
    assert table["steps_done"].iloc[0] == table["steps_asked"].iloc[0] >= 1
    assert (tmp_path / "stability.png").is_file()
    assert "Stability" in (tmp_path / "README.md").read_text()


def test_cli_rejects_bad_eps(tmp_path):
    args = ["bench", "stability", "--n", "30", "--dim", "2", "--solvers", "clarabel"]
    res = CliRunner().invoke(app, [*args, "--eps-list", "0", "--out", str(tmp_path)])
    assert res.exit_code == 2
