"""``cocd sweep``: grids of runs on a local Dask cluster, resumable, robust to a lost worker."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pandas as pd
import pytest
from typer.testing import CliRunner

from cocd.cli import app
from cocd.config import ConfigError
from cocd.sweep import cells_of, load_sweep, parse_sweep, run_cell, run_sweep

distributed = pytest.importorskip("distributed")
runner = CliRunner()

SWEEP = """
name = "tiny"
steps = {steps}

[scenes.column]
builder = "column_2d"
params = {{ n_grains = {n} }}

[scenes.stack]
builder = "stack"
params = {{ n_grains = 3, dim = 3 }}

[grid]
scene = ["column", "stack"]
solver = ["clarabel", "apgd"]
tol = [1e-6, 1e-8]
"""

#: Columns that do not depend on where or when a cell ran.
DETERMINISTIC = [
    "cell",
    "scene",
    "solver",
    "tol",
    "status",
    "steps",
    "nc_mean",
    "iterations_mean",
    "iterations_max",
    "ccp_max",
    "coulomb_max",
    "kinetic_energy_final",
    "positions_checksum",
]


def _sweep_file(tmp_path: Path, steps: int = 4, n: int = 30) -> Path:
    path = tmp_path / "sweep.toml"
    path.write_text(SWEEP.format(steps=steps, n=n))
    return path


@pytest.fixture(scope="module")
def client():
    cluster = distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    )
    with distributed.Client(cluster) as c:
        yield c
    cluster.close()


def _one_by_one(spec, folder: Path) -> pd.DataFrame:
    rows = [pd.read_parquet(run_cell(cell, str(folder))) for cell in cells_of(spec)]
    return pd.concat(rows, ignore_index=True)


def _check_cells(spec, out: Path) -> pd.DataFrame:
    cells = cells_of(spec)
    files = sorted((out / "cells").glob("*.parquet"))
    assert sorted(f.stem for f in files) == sorted(c.id for c in cells)  # each exactly once
    for f in files:  # none corrupt
        row = pd.read_parquet(f)
        assert len(row) == 1 and row.cell.iloc[0] == f.stem
    table = pd.read_parquet(out / f"{spec.name}.parquet")
    assert list(table.cell) == [c.id for c in cells]
    return table


def test_sweep_on_two_workers_equals_the_cells_one_by_one(tmp_path, client):
    spec = load_sweep(_sweep_file(tmp_path))
    assert len(cells_of(spec)) == 8
    summary = run_sweep(spec, tmp_path / "out", client=client)
    assert (summary.cells, summary.ran, summary.skipped, summary.failed) == (8, 8, 0, 0)
    table = _check_cells(spec, tmp_path / "out")
    assert (table.status == "ok").all()
    assert len(set(table.host)) >= 1
    reference = _one_by_one(spec, tmp_path / "serial")
    pd.testing.assert_frame_equal(table[DETERMINISTIC], reference[DETERMINISTIC])
    # The convex answers are physical: the stack's cells end at rest.
    stack = table[table.scene == "stack"]
    assert (stack.kinetic_energy_final < 1e-12).all()
    assert (table.ccp_max <= table.tol).all()
    summary_md = (tmp_path / "out" / "tiny.md").read_text()
    assert "8 cells (2 scene x 2 solver x 2 tol)" in summary_md


def test_second_run_of_a_finished_sweep_does_no_work(tmp_path, client, monkeypatch):
    spec = load_sweep(_sweep_file(tmp_path))
    run_sweep(spec, tmp_path, client=client)
    stamps = {f: f.stat().st_mtime_ns for f in (tmp_path / "cells").glob("*.parquet")}

    def no_cluster(*args, **kwargs):
        raise AssertionError("a finished sweep started a cluster")

    monkeypatch.setattr("cocd.sweep._submit_all", no_cluster)
    summary = run_sweep(spec, tmp_path)
    assert (summary.ran, summary.skipped) == (0, 8)
    assert {f: f.stat().st_mtime_ns for f in (tmp_path / "cells").glob("*.parquet")} == stamps
    result = runner.invoke(app, ["sweep", str(tmp_path / "sweep.toml"), "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert "nothing to do" in result.output and "8 cells: 0 run, 8 already done" in result.output


def test_sweep_survives_a_killed_worker(tmp_path, client):
    # Longer cells, so that a worker is busy with one when it is killed.
    spec = load_sweep(_sweep_file(tmp_path, steps=40, n=80))
    killed: list[int] = []

    def kill_a_busy_worker(done: int, total: int, cell: str) -> None:
        if killed:
            return
        busy = [w for w, keys in client.processing().items() if keys]
        pids = client.run(os.getpid, workers=busy[:1])
        for pid in pids.values():
            os.kill(pid, signal.SIGKILL)
            killed.append(pid)

    summary = run_sweep(spec, tmp_path, client=client, progress=kill_a_busy_worker)
    assert killed, "no worker was busy when the first cell finished"
    assert (summary.cells, summary.failed) == (8, 0)
    table = _check_cells(spec, tmp_path)
    assert (table.status == "ok").all()
    client.wait_for_workers(2, timeout=60)  # the nanny restarted it


def test_interrupted_sweep_runs_only_the_missing_cells(tmp_path, client):
    spec = load_sweep(_sweep_file(tmp_path))
    cells = cells_of(spec)
    for cell in cells[:3]:  # as if a previous sweep had finished these
        run_cell(cell, str(tmp_path / "cells"))
    (tmp_path / "cells" / f"{cells[3].id}.parquet").write_bytes(b"truncated")
    (tmp_path / "cells" / "notes.parquet").write_bytes(b"mine")  # not a cell of this sweep
    notices: list[str] = []
    summary = run_sweep(spec, tmp_path, client=client, notice=notices.append)
    assert (summary.ran, summary.skipped) == (5, 3)
    # The unreadable cell file is kept aside, not deleted, and said; a file of no cell is
    # not touched.
    aside = tmp_path / "cells" / f"{cells[3].id}.parquet.unreadable"
    assert summary.set_aside == (str(aside),) and aside.read_bytes() == b"truncated"
    assert notices == [
        f"{aside}: a cell file that could not be read, kept aside; its cell runs again"
    ]
    assert (tmp_path / "cells" / "notes.parquet").read_bytes() == b"mine"
    (tmp_path / "cells" / "notes.parquet").unlink()
    _check_cells(spec, tmp_path)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('steps = 1\n[scenes.a]\nbuilder = "stack"\n[grid]\nscene = ["b"]\n', "not among"),
        ('steps = 1\n[scenes.a]\nbuilder = "stak"\n[grid]\nscene = ["a"]\n', "unknown builder"),
        (
            'steps = 1\n[scenes.a]\nbuilder = "stack"\n[grid]\nscene = ["a"]\ncolour = [1]\n',
            "unknown axis 'colour'",
        ),
        ('[scenes.a]\nbuilder = "stack"\n[grid]\nscene = ["a"]\n', "exactly one of steps"),
        (
            'steps = 1\n[scenes.a]\nbuilder = "stack"\nparams = { n_grains = 2 }\n[grid]\n'
            'scene = ["a"]\ntol = [-1.0]\n',
            "run.tol: Input should be greater than 0",
        ),
        (
            'steps = 1\nspeed = 2\n[scenes.a]\nbuilder = "stack"\n[grid]\nscene = ["a"]\n',
            "speed: unknown key",
        ),
        (
            'steps = 1\n[scenes.a]\nbuilder = "stack"\nparams = { n_grains = 2 }\n[grid]\n'
            'scene = ["a"]\nsolver = ["clarabel", "nope"]\n',
            "cell .*'solver': 'nope'.*unknown solver 'nope'",
        ),
        (
            'name = "../../out"\nsteps = 1\n[scenes.a]\nbuilder = "stack"\n[grid]\nscene = ["a"]\n',
            "name: must be a plain file name",
        ),
        (
            'steps = 1\n[scenes.a]\nbuilder = "stack"\n[grid]\nscene = ["a"]\ntol = [1e-6, 1e-6]\n',
            "axis 'tol' repeats 1e-06: its cells would run twice",
        ),
    ],
)
def test_bad_sweep_files_are_named(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_sweep(path)
    result = runner.invoke(app, ["sweep", str(path), "--out", str(tmp_path)])
    assert result.exit_code == 2 and "Traceback" not in result.output
    assert len(result.output.strip().splitlines()) == 1


def test_grid_expands_params_axes():
    spec = parse_sweep(
        {
            "steps": 1,
            "scenes": {"c": {"builder": "column_2d", "params": {"n_grains": 10}}},
            "grid": {"scene": ["c"], "params.n_grains": [10, 20], "dt": [1e-3, 5e-4]},
        }
    )
    cells = cells_of(spec)
    assert len(cells) == 4 and len({c.id for c in cells}) == 4
    assert [c.config["params"]["n_grains"] for c in cells] == [10, 10, 20, 20]
    assert [c.config["run"]["dt"] for c in cells] == [1e-3, 5e-4, 1e-3, 5e-4]


def test_a_sweep_with_failed_cells_exits_non_zero(tmp_path):
    path = tmp_path / "fails.toml"
    path.write_text(
        'name = "fails"\nsteps = 3\n[scenes.c]\nbuilder = "column_2d"\n'
        'params = { n_grains = 30 }\n[grid]\nscene = ["c"]\n'
        'solver = ["clarabel", "clarabel:max_iter=1"]\n'
    )
    spec = load_sweep(path)
    for cell in cells_of(spec):  # run here, so that the command only aggregates
        run_cell(cell, str(tmp_path / "out" / "cells"))
    result = runner.invoke(app, ["sweep", str(path), "--out", str(tmp_path / "out")])
    assert result.exit_code == 3
    assert "2 cells: 0 run, 2 already done, 1 failed" in result.stdout
    assert "1 of 2 cells failed" in result.stderr
