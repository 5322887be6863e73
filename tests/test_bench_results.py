"""The harness's one result schema, its resumable tables and ``cocd bench upgrade``."""

from __future__ import annotations

import json
import re

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from cocd.bench import schema
from cocd.bench.report import write_meta, write_readme, write_table
from cocd.bench.results import Results
from cocd.cli import app
from cocd.errors import CocdError

runner = CliRunner()
COLUMNS = ["problem", "solver", "tol", "status", "iterations", "wall_s", "note"]


def test_rows_are_kept_by_key_and_resumed(tmp_path):
    path = tmp_path / "t.csv"
    table = Results(path, COLUMNS)
    table.add(dict(problem="a", solver="ipm", tol=1e-8, status="optimal", iterations=12))
    table.add(dict(problem="a", solver="ipm", tol=1e-5, status="optimal", iterations=7))
    # The same key replaces its row.
    table.add(dict(problem="a", solver="ipm", tol=1e-8, status="optimal", iterations=13))
    assert len(table) == 2 and table.get("a", "ipm", 1e-8)["iterations"] == 13
    assert list(pd.read_csv(path).iterations) == [13, 7]
    assert not list(tmp_path.glob(".*.tmp"))
    # Read back: a tol parsed from the file is the tol computed (1e-8 == 0.1 * 1e-7).
    again = Results(path, COLUMNS, resume=True)
    assert again.resumed == 2 and again.has("a", "ipm", 0.1 * 1e-7)
    assert again.has(problem="a", solver="ipm", tol=1e-5) and not again.has("a", "scs", 1e-5)
    assert again.get("a", "ipm", 1e-5)["note"] == "" and np.isnan(
        again.get("a", "ipm", 1e-5)["wall_s"]
    )
    # Without resume the earlier rows are not read (the file is replaced at the first add).
    assert len(Results(path, COLUMNS)) == 0
    with pytest.raises(TypeError, match="the key is"):
        again.has("a", "ipm")


def test_a_table_of_earlier_names_is_resumed_under_the_new_ones(tmp_path):
    path = tmp_path / "t.csv"
    pd.DataFrame(
        {"problem": ["a"], "backend": ["apgd"], "eps": [1e-6], "warm": ["yes"],
         "time_per_step_s": [0.5], "status": ["optimal"]}
    ).to_csv(path, index=False)  # fmt: skip
    table = Results(path, [*COLUMNS, "start"], resume=True, keep=lambda r: r["start"] == "warm")
    row = table.get("a", "apgd", 1e-6)
    assert row is not None and row["wall_s"] == 0.5 and row["start"] == "warm"
    up = schema.upgrade(pd.read_csv(path))
    assert list(up.columns) == ["problem", "solver", "tol", "start", "wall_s", "status"]


def test_a_table_without_the_key_is_not_resumed(tmp_path):
    path = tmp_path / "t.csv"
    pd.DataFrame({"problem": ["a"], "status": ["optimal"]}).to_csv(path, index=False)
    with pytest.raises(
        CocdError, match=r"cannot resume from .*t\.csv: it has no solver, tol column"
    ):
        Results(path, COLUMNS, resume=True)
    path.write_text('a,"b\n')
    with pytest.raises(CocdError, match="cannot resume"):
        Results(path, COLUMNS, resume=True)


def _old_results(out):
    """A results folder as an earlier version wrote it."""
    old = pd.DataFrame(
        {"case": ["c1", "c1"], "solver": ["ipm", "apgd"], "eps": [1e-8, 1e-8],
         "warm": ["no", "yes"], "time_per_step_s": [0.25, 1.5]}
    )  # fmt: skip
    files = write_table(out, "old", old, title="An old table", command="cocd bench old")
    summary = old.to_markdown(index=False)
    write_meta(out, "old", title="An old table", files=files, summary=summary, command="x")
    write_readme(out)
    return old


def test_cocd_bench_upgrade_renames_columns_and_says_so(tmp_path):
    out = tmp_path / "results"
    old = _old_results(out)
    before = {p.name: p.read_text() for p in out.iterdir()}
    dry = runner.invoke(app, ["bench", "upgrade", str(out), "--dry-run"])
    assert dry.exit_code == 0 and "would rename in" in dry.output
    assert {p.name: p.read_text() for p in out.iterdir()} == before
    result = runner.invoke(app, ["bench", "upgrade", str(out)])
    assert result.exit_code == 0, result.output
    assert "eps -> tol" in result.output and "time_per_step_s -> wall_s" in result.output
    new = pd.read_csv(out / "old.csv")
    assert list(new.columns) == ["case", "solver", "tol", "start", "wall_s"]
    assert list(new.start) == ["cold", "warm"] and list(new.wall_s) == list(old.time_per_step_s)
    md = (out / "old.md").read_text()
    header = md.split("\n\n")[-1].splitlines()[0]
    assert re.search(r"\|\s+tol\s+\|", header) and "eps" not in header and "| warm " in md
    meta = json.loads((out / "old.meta.json").read_text())
    assert meta["columns_renamed"]["names"] == {"eps": "tol", "warm": "start",
                                                "time_per_step_s": "wall_s"}  # fmt: skip
    assert "wall_s" in meta["summary"] and "time_per_step_s" not in meta["summary"]
    readme = (out / "README.md").read_text()
    assert "Columns renamed by `cocd bench upgrade`" in readme and "| `tol` |" in readme
    again = runner.invoke(app, ["bench", "upgrade", str(out)])
    assert again.exit_code == 0 and "already uses the current names" in again.output


def test_cocd_bench_upgrade_keeps_values_and_writes_nothing_when_a_file_fails(tmp_path):
    out = tmp_path / "results"
    out.mkdir()
    # An integer column with a blank: pandas would read it as floats (13 -> 13.0).
    (out / "a.csv").write_text("solver,eps,iterations\nipm,1e-08,13\napgd,1e-08,\n")
    (out / "b.csv").write_text('solver,eps\n"unclosed,1\n')  # cannot be read
    result = runner.invoke(app, ["bench", "upgrade", str(out)])
    assert result.exit_code == 2 and "cannot upgrade" in result.output and "b.csv" in result.output
    assert (out / "a.csv").read_text() == "solver,eps,iterations\nipm,1e-08,13\napgd,1e-08,\n"
    (out / "b.csv").unlink()
    assert runner.invoke(app, ["bench", "upgrade", str(out)]).exit_code == 0
    assert (out / "a.csv").read_text() == "solver,tol,iterations\nipm,1e-08,13\napgd,1e-08,\n"


def test_cocd_bench_upgrade_of_no_folder_is_one_line(tmp_path):
    result = runner.invoke(app, ["bench", "upgrade", str(tmp_path / "none")])
    assert result.exit_code == 2
    assert result.output.strip().splitlines() == [
        f"error: {tmp_path / 'none'} is not a folder of results"
    ]


def test_a_note_takes_its_numbers_from_the_tables(tmp_path):
    """`cocd bench readme` fills a note's placeholders from the tables beside it: one
    cell, an aggregate, a format; a placeholder without its row is a one-line error."""
    table = pd.DataFrame(
        {
            "t": [0.1, 0.2, 0.3],
            "case": ["a", "b", "b"],
            "error": [0.5, 0.25, 0.125],
            "rest_s": [1.5, None, 2.0],
            "steps": [220, 220, 220],
            "dt": [0.01, 0.01, 0.01 * (1 + 1e-12)],
            "bound": [float("inf")] * 3,
            "limit": [float("inf"), 5.0, 5.0],
        }
    )
    write_table(tmp_path, "demo", table, title="Demo")
    write_meta(tmp_path, "demo", title="Demo", files=["demo.csv"], summary="")
    # The same study's tables to a later end, written to a folder under the first.
    write_table(tmp_path / "to4s", "demo", table.assign(error=table.error / 10), title="Demo")
    notes = tmp_path / "notes"
    notes.mkdir()
    (notes / "demo.md").write_text(
        "Later, {{to4s/demo.error[t=0.2]}}. "
        "At t = 0.2 s the error is {{demo.error[t=0.2]}} ({{demo.error[t=0.2]:.1%}}); "
        "case b ranges to {{max demo.error[case=b]}} over {{count demo.error[case=b]}} rows. "
        "At rest from {{demo.rest_s[t=0.1]:.2f|never}} s and "
        "{{demo.rest_s[t=0.2]:.2f|not by the end}}; {{demo.rest_s[t=0.3]|none}} s, "
        "{{max demo.rest_s[t=0.2] | never}}. Each of {{count demo.steps}} runs made "
        "{{same demo.steps}} steps of {{same demo.dt}} s; the cases {{same demo.case[t=0.3]}}; "
        "no bound ({{same demo.bound}}); {{count demo.t[limit=5]}} limits of 5."
    )
    result = runner.invoke(app, ["bench", "readme", "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    text = (tmp_path / "README.md").read_text()
    assert "Later, 0.025. At t = 0.2 s the error is 0.25 (25.0%); case b ranges" in text
    assert "case b ranges to 0.25 over 2 rows." in text
    # An empty cell is written as the placeholder says, after its bar; a full one as
    # its format says (the default when none is given before the bar).
    assert "At rest from 1.50 s and not by the end; 2 s, never." in text
    # `same` is the value every row that matches holds (numbers as rows are matched).
    assert "Each of 3 runs made 220 steps of 0.01 s; the cases b; no bound (inf)" in text
    assert "; 2 limits of 5." in text  # an infinity matches only itself
    # Each way of naming what the table does not hold is refused, naming the placeholder.
    for bad, why in (
        ("{{demo.error[t=0.4]}}", "0 rows match, not one"),
        ("{{demo.error[case=b]}}", "2 rows match, not one"),
        ("{{demo.speed[t=0.1]}}", "has no column 'speed'"),
        ("{{other.error}}", "no table"),
        ("{{to2s/demo.error[t=0.1]}}", "no table"),
        ("{{../demo.error[t=0.1]}}", "not a placeholder cocd can read"),
        ("{{demo.error[time=0.1]}}", "bad condition"),
        ("{{max demo.error[case=c]}}", "no row matches"),
        ("{{demo.rest_s[t=0.2]:.2f}}", "the cell is empty"),
        ("{{demo.rest_s[t=0.2]|}}", "not a placeholder cocd can read"),
        ("{{same demo.error}}", "the rows that match differ (0.5, 0.25, 0.125)"),
        ("{{same demo.case}}", "the rows that match differ (a, b)"),
        ("{{same demo.limit}}", "the rows that match differ (inf, 5.0)"),
        ("{{same demo.rest_s[case=b]}}", "the rows that match differ"),
        ("{{same demo.steps[case=c]}}", "no row matches"),
        ("{{demo.error[t=0.1]:}}", "not a placeholder cocd can read"),
    ):
        (notes / "demo.md").write_text(f"A number: {bad}.")
        result = runner.invoke(app, ["bench", "readme", "--out", str(tmp_path)])
        assert result.exit_code != 0
        assert why in result.output and bad in result.output
        assert "Traceback" not in result.output


def test_every_committed_note_finds_its_numbers_in_its_tables():
    """The notes under results/ fill every placeholder from the tables beside them: a
    table remade without a row a note quotes fails here, not silently in the README."""
    from pathlib import Path

    from cocd.bench.report import fill_note

    root = Path(__file__).resolve().parent.parent / "results"
    notes = sorted(root.glob("**/notes/*.md"))
    assert notes
    for note in notes:
        filled = fill_note(note.read_text(), note.parent.parent, note.name)
        assert "{{" not in filled, note
