"""``cocd bench hard``: every backend on the hard cases, failures as rows."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from conftest import run_study
from typer.testing import CliRunner

from cocd.builders import HARD_CASES
from cocd.cli import app
from cocd.errors import CocdError
from cocd.studies import hard

TOL = 1e-6
CASES = ["wedged_grain", "fast_impact", "wedged_grain_3d"]
STATED = [
    "case",
    "dim",
    "N",
    "Nc",
    "solver",
    "status",
    "steps_done",
    "iterations",
    "wall_s",
    "ccp_residual",
    "coulomb_residual",
    "dynamics_residual",
    "energy_drift",
    "note",
]


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    out = tmp_path_factory.mktemp("hard")
    settings = dict(solvers="clarabel,pgs", cases=CASES, steps=2, tol=TOL, time_limit=30.0)
    return run_study(hard.STUDY, out, **settings)


def test_files_and_columns(result):
    out, table, lines = result
    for name in ("hard.csv", "hard.md", "hard_matrix.md", "hard.png", "hard.meta.json"):
        assert (out / name).is_file(), name
    assert (out / "hard.png").stat().st_size > 1000
    csv = pd.read_csv(out / "hard.csv")
    assert set(STATED) <= set(csv.columns)
    assert len(csv) == len(table) == len(CASES) * 2
    assert list(dict.fromkeys(csv["case"])) == CASES
    assert lines[0].startswith("hard: ") and "; expected " in lines[0]  # the estimate first
    assert len(lines) == len(table) + 1
    meta = json.loads((out / "hard.meta.json").read_text())
    assert meta["name"] == "hard"
    assert "| case | clarabel | pgs |" in meta["summary"]
    assert {"hard.csv", "hard.md", "hard_matrix.md", "hard.png"} <= set(meta["files"])
    assert (out / "hard_matrix.md").read_text().count("| wedged_grain") == 2


def test_clarabel_rows_are_accurate_and_dissipative(result):
    _, table, _ = result
    rows = table[table["solver"] == "clarabel"]
    assert list(rows["status"]) == ["ok"] * len(CASES)
    assert (rows["steps_done"] == 2).all()
    assert (rows["ccp_residual"] <= 10 * TOL).all()
    # Rigid contacts dissipate: no energy may be created beyond the tolerance.
    assert (rows["energy_drift"] <= TOL).all(), rows[["case", "energy_drift"]]
    impact = rows[rows["case"] == "fast_impact"].iloc[0]
    assert impact["energy_drift"] < -0.5  # the impact destroys most of the kinetic energy
    assert impact["N"] == 6 and impact["Nc"] >= 1 and impact["dt"] == hard.case_dt("fast_impact")
    at_rest = rows[rows["case"] == "wedged_grain"].iloc[0]
    assert abs(at_rest["energy_drift"]) <= TOL


def test_matrix_cells(result):
    _, table, _ = result
    matrix = hard.matrix_markdown(table)
    row = next(line for line in matrix.splitlines() if line.startswith("| fast_impact "))
    assert row.split("|")[2].strip().startswith("ok ")


def test_case_dt_follows_the_builder():
    assert hard.case_dt("fast_impact") == pytest.approx(1e-3)
    assert hard.case_dt("jammed_box") == hard.DEFAULT_DT


def test_energy_scale_at_rest_and_in_motion():
    masses, radii, g = np.array([2.0]), np.array([0.5]), np.array([0.0, -10.0])
    assert hard.energy_scale(0.0, masses, radii, g) == pytest.approx(20.0)
    assert hard.energy_scale(100.0, masses, radii, g) == pytest.approx(100.0)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"cases": ["no_such_case"]}, "unknown hard case.*known: heavy_on_light_1e3"),
        ({"steps": 0}, "steps must be"),
        ({"tol": 0.0}, "tol must be"),
        ({"solvers": "nope"}, "unknown solver 'nope'"),
    ],
)
def test_bad_arguments(tmp_path, kwargs, match):
    args = dict(
        solvers="clarabel",
        cases=["wedged_grain"],
        steps=1,
        tol=TOL,
        time_limit=10.0,
        memory_gb=None,
        out=tmp_path,
    )
    args.update(kwargs)
    with pytest.raises(CocdError, match=match):
        hard.STUDY(**args)
    assert not (tmp_path / "hard.csv").exists()


def test_solver_failure_is_a_row(tmp_path):
    # A 0.1 ms budget at tol 1e-12: PGS cannot settle a 50-grain stack.
    table = hard.STUDY(
        solvers="pgs",
        cases=["tall_stack_50"],
        steps=2,
        tol=1e-12,
        time_limit=1e-4,
        out=tmp_path,
        progress=lambda line: None,
    )
    row = table.iloc[0]
    assert row["status"] in ("time_limit", "max_iter")
    assert row["steps_done"] == 0 and np.isnan(row["ccp_residual"])
    assert "step 1" in row["note"] and "pgs" in row["note"]
    assert "| tall_stack_50 | " + row["status"] in (tmp_path / "hard_matrix.md").read_text()


def test_killed_child_is_a_row(tmp_path):
    # No grace: the wall-clock limit (3 ms) runs out while the child starts.
    table = hard.STUDY(
        solvers="clarabel",
        cases=["wedged_grain", "zero_gap"],
        steps=2,
        tol=TOL,
        time_limit=1e-3,
        out=tmp_path,
        progress=lambda line: None,
        grace=0.0,
    )
    assert list(table["status"]) == ["time_limit", "time_limit"]
    assert table["note"].str.contains("killed after").all()
    assert (tmp_path / "hard.png").is_file()


def test_cli(tmp_path):
    case = "wedged_grain"
    assert case in HARD_CASES
    args = ["bench", "hard", "--cases", case, "--solvers", "clarabel", "--steps", "1"]
    result = CliRunner().invoke(app, [*args, "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    table = pd.read_csv(tmp_path / "hard.csv")
    assert list(table["status"]) == ["ok"] and table["steps_done"].iloc[0] == 1
    assert (tmp_path / "README.md").is_file()
    assert "| wedged_grain | ok " in (tmp_path / "README.md").read_text()
    # The time is announced before the solves and recorded; the next run scales from it.
    assert "hard: 1 solve, the largest of" in result.output
    meta = json.loads((tmp_path / "hard.meta.json").read_text())
    assert meta["elapsed_s"] > 0 and meta["work_units"] > 0
    again = CliRunner().invoke(app, [*args, "--out", str(tmp_path)])
    assert again.exit_code == 0, again.output
    assert f"scaled from the run recorded in {tmp_path / 'hard.meta.json'}" in again.output
    bad = CliRunner().invoke(app, ["bench", "hard", "--cases", "nope", "--out", str(tmp_path)])
    assert bad.exit_code == 2
    assert "unknown hard case" in bad.output
