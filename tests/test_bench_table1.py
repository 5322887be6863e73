"""``cocd bench table1`` at a tiny scale: files, columns, accuracy, failures as rows."""

from __future__ import annotations

import json
from typing import ClassVar

import pandas as pd
import pytest
from typer.testing import CliRunner

from cocd.bench import runner
from cocd.bench.states import StepSequence
from cocd.cli import app
from cocd.errors import CocdError
from cocd.studies import _table1_report, table1

# Scale 0.001 gives columns of 20 and 51 discs (the seed's 1109 and 8308 fall under the
# 20-disc floor, 20488 rounds to 20, 50772 to 51).
TINY = dict(scale=0.001, cases=["2d"], steps=2, t_start_2d=0.02)


@pytest.fixture
def cache(tmp_path, monkeypatch):
    path = tmp_path / "cache"
    monkeypatch.setenv("COCD_CACHE", str(path))
    return path


def test_table1_tiny_run(tmp_path, cache):
    out = tmp_path / "results"
    lines: list[str] = []
    df = table1.STUDY(
        solvers="clarabel,scs-dual", time_limit=60.0, out=out, progress=lines.append, **TINY
    )
    for name in ("table1.csv", "table1.md", "table1.meta.json"):
        assert (out / name).exists(), name
    csv = pd.read_csv(out / "table1.csv", keep_default_na=False)
    assert list(csv.columns) == table1.COLUMNS
    assert list(df.columns) == table1.COLUMNS

    ours = df[df.source == "this machine"]
    assert sorted(ours.N.unique()) == [20, 51]
    assert len(ours) == 2 * 2  # two columns x two solvers, one eps
    assert set(ours.tol) == {1e-8} and set(ours.dim) == {2}
    clarabel = ours[ours.solver == "clarabel"]
    assert (clarabel.steps_ok == "2/2").all()
    assert (clarabel.ccp_residual <= 1e-7).all()
    assert (clarabel.start == "cold").all()
    assert (ours[ours.solver == "scs-dual"].start == "warm").all()
    assert (ours.iterations > 0).all() and (ours.wall_s > 0).all()
    assert (ours.Nc > 0).all()
    # Detected with the seed's threshold; the count per grain is beside the seed's.
    assert (ours.d_max_r == table1.D_SEED_2D).all()
    assert ours.Nc_per_grain.to_numpy() == pytest.approx((ours.Nc / ours.N).to_numpy())

    seed = df[df.source == table1.SEED]
    assert len(seed) == 4
    assert set(seed.N) == {8308, 50772, 122932}
    row = seed[(seed.dim == 3) & (seed.tol == 1e-5)].iloc[0]
    assert row.iterations == 11 and row.wall_s == pytest.approx(269.9)
    assert seed.ccp_residual.isna().all()
    assert seed[seed.dim == 3].Nc_per_grain.iloc[0] == pytest.approx(829505 / 122932)

    md = (out / "table1.md").read_text()
    assert "N scaled by 0.001 for this 2-core machine" in md
    assert "trajectory by clarabel" in md
    meta = json.loads((out / "table1.meta.json").read_text())
    assert meta["files"] == ["table1.csv", "table1.md"]
    assert "| clarabel" in meta["summary"]
    # The fastest backend with every step optimal, per size, from the same rows.
    assert "Fastest backend with every step optimal:" in meta["summary"]
    for n in (20, 51):
        rows = ours[(ours.N == n) & (ours.steps_ok == "2/2")]
        best = rows.loc[rows.wall_s.idxmin()]
        assert f"- {n} discs, eps 1e-08: {best.solver}," in meta["summary"]
    assert any("recording" in line for line in lines)
    assert any("clarabel eps 1e-08 step 2/2" in line for line in lines)
    # The recorded problems are cached, so that every later run reuses them.
    assert list((cache / "bench").glob("table1-column-2d-20-*.pkl"))


def test_fastest_backend_needs_every_step_optimal():
    nan = float("nan")
    mine = dict(source=table1.THIS_MACHINE, dim=2, N=100, tol=1e-8)
    table = pd.DataFrame(
        [
            {**mine, "solver": "fast", "steps_ok": "9/10", "wall_s": 0.1},
            {**mine, "solver": "ipm", "steps_ok": "10/10", "wall_s": 0.5},
            {**mine, "solver": "clarabel", "steps_ok": "10/10", "wall_s": 2.0},
            {**mine, "N": 200, "solver": "ipm", "steps_ok": "0/10", "wall_s": 1.0},
            {**mine, "N": 200, "solver": "clarabel", "steps_ok": "0/0", "wall_s": nan},
        ]
    )
    assert _table1_report.fastest(table) == [
        "- 100 discs, eps 1e-08: ipm, 0.5 s per step; clarabel 2 s (4 times as long)",
        "- 200 discs, eps 1e-08: no backend solved every step to optimal",
    ]


def test_table1_resume_keeps_rows_and_solves_the_rest(tmp_path, cache):
    """Rows already in table1.csv are kept as they are; only missing ones are solved."""
    out = tmp_path / "results"
    first = table1.STUDY(solvers="clarabel", time_limit=60.0, out=out, progress=print, **TINY)
    lines: list[str] = []
    again = table1.STUDY(
        solvers="clarabel,apgd",
        time_limit=60.0,
        out=out,
        progress=lines.append,
        resume=True,
        **TINY,
    )
    ours = again[again.source == "this machine"]
    assert len(ours) == 2 * 2
    kept = ours[ours.solver == "clarabel"].reset_index(drop=True)
    before = first[first.source == "this machine"].reset_index(drop=True)
    # The very same measurements, not new solves.
    assert list(kept.wall_s) == list(before.wall_s)
    assert not any("clarabel eps" in line for line in lines)
    assert any("apgd eps 1e-08 step 2/2" in line for line in lines)
    assert (ours[ours.solver == "apgd"].steps_ok == "2/2").all()
    csv = pd.read_csv(out / "table1.csv", keep_default_na=False)
    assert len(csv[csv.source == "this machine"]) == 4
    # Every row read back: nothing is solved or recorded the third time.
    lines.clear()
    table1.STUDY(
        solvers="clarabel,apgd",
        time_limit=60.0,
        out=out,
        progress=lines.append,
        resume=True,
        **TINY,
    )
    assert sum("every row read from the previous table" in line for line in lines) == 2
    # Resumed with fewer backends, the other rows are kept too: nothing is lost.
    fewer = table1.STUDY(solvers="apgd", time_limit=60.0, out=out, progress=print, resume=True,
                         **TINY)  # fmt: skip
    assert len(fewer[fewer.source == "this machine"]) == 4
    # A table written under the earlier column names is resumed as well.
    old = pd.read_csv(out / "table1.csv", keep_default_na=False, na_values=[""])
    old = old.rename(columns={"tol": "eps", "wall_s": "time_per_step_s", "start": "warm"})
    old["warm"] = old["warm"].map({"cold": "no", "warm": "yes"})
    old.to_csv(out / "table1.csv", index=False)
    lines.clear()
    upgraded = table1.STUDY(
        solvers="clarabel,apgd", time_limit=60.0, out=out, progress=lines.append, resume=True,
        **TINY,
    )  # fmt: skip
    assert sum("every row read from the previous table" in line for line in lines) == 2
    mine = upgraded[upgraded.source == "this machine"].reset_index(drop=True)
    assert list(mine.wall_s) == list(ours.wall_s) and set(mine.start) == {"cold", "warm"}
    (out / "table1.csv").write_text("not,a,table\n1,2,3\n")
    with pytest.raises(CocdError, match="cannot resume"):
        table1.STUDY(solvers="clarabel", time_limit=60.0, out=out, resume=True, **TINY)


def test_table1_timeout_is_a_row(tmp_path, cache):
    # pgs checks its deadline before its first sweep, and its set-up alone takes longer
    # than this limit: a cheap, deterministic time-out.
    out = tmp_path / "results"
    df = table1.STUDY(
        solvers="pgs",
        time_limit=1e-6,
        out=out,
        progress=lambda line: None,
        **{**TINY, "scale": 0.0004},
    )
    ours = df[df.source == "this machine"]
    assert len(ours) == 1
    row = ours.iloc[0]
    assert row.steps_ok == "0/2"
    assert "time_limit" in row.note and "1 not run" in row.note


def test_table1_row_budget_stops_a_row(tmp_path, cache):
    # Any solve takes more than a nanosecond: each row stops after its first step.
    df = table1.STUDY(
        solvers="clarabel",
        time_limit=60.0,
        out=tmp_path / "results",
        progress=lambda line: None,
        row_budget=1e-9,
        **{**TINY, "scale": 0.0004},
    )
    row = df[df.source == "this machine"].iloc[0]
    assert row.steps_ok == "1/2"
    assert "row budget of 1e-09 s spent after 1 steps" in row.note
    with pytest.raises(CocdError, match="--row-budget must be a finite number > 0"):
        table1.STUDY(solvers="clarabel", time_limit=60.0, out=tmp_path, row_budget=0.0, **TINY)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(cases=["4d"]), "cases must be among"),
        (dict(cases=[]), "cases must be among"),
        (dict(scale=0.0), "scale must be in (0, 1]"),
        (dict(scale=1.5), "scale must be in (0, 1]"),
        (dict(steps=0), "steps must be an integer >= 1"),
        (dict(time_limit=0.0), "--time-limit must be a finite number > 0"),
        (dict(solvers="nope"), "unknown solver 'nope'"),
    ],
)
def test_table1_bad_arguments_raise(tmp_path, cache, kwargs, message):
    args = dict(solvers="clarabel", time_limit=10.0, out=tmp_path, **TINY)
    args.update(kwargs)
    with pytest.raises(CocdError, match=message.replace("(", r"\(").replace(")", r"\)")):
        table1.STUDY(progress=lambda line: None, **args)
    assert not (tmp_path / "table1.csv").exists()


def test_table1_cli(tmp_path, cache):
    # Scale 0.0004 leaves a single 20-disc column: 110 preparation steps to t = 0.11 s.
    out = tmp_path / "results"
    result = CliRunner().invoke(
        app,
        [
            "bench", "table1", "--scale", "0.0004", "--cases", "2d", "--steps", "1",
            "--solvers", "clarabel", "--out", str(out),
        ],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    df = pd.read_csv(out / "table1.csv", keep_default_na=False)
    ours = df[df.source == "this machine"]
    assert list(ours.N) == [20] and list(ours.steps_ok) == ["1/1"]
    assert (out / "README.md").exists()
    bad = CliRunner().invoke(app, ["bench", "table1", "--cases", "5d", "--out", str(out)])
    assert bad.exit_code == 2 and "cases must be among" in bad.output


class FakeWorker:
    """Answers like :class:`~cocd.bench.runner.Worker`.

    clarabel runs out of time; scs-dual fails on its first problem at eps 1e-8
    (each (solver, eps) starts with one warm-up call).
    """

    calls: ClassVar[list[tuple[str, float]]] = []

    def __init__(self, memory_gb=None, grace=30.0):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        pass

    def solve_row(self, problem, solver, tol, *, warm_start=None, time_limit=None, **kw):
        FakeWorker.calls.append((solver, tol))
        row = dict(solver=solver, iterations=5, wall_s=0.5, ccp_residual=1e-9)
        row["coulomb_residual"] = 1e-9
        if solver == "clarabel":
            return {**row, "status": "time_limit", "note": "killed after 930 s"}
        if (solver, tol) == ("scs-dual", 1e-8) and FakeWorker.calls.count((solver, tol)) == 2:
            return {**row, "status": "error", "note": "ValueError: boom"}
        return {**row, "status": "optimal", "note": ""}


def test_table1_3d_time_limit_skips_tighter_eps(tmp_path, cache, monkeypatch):
    # A fake trajectory and worker: the 3D bookkeeping without a 3D simulation.
    problem = runner.warmup_problem(3, 1e-2)

    def fake_record(label, make, *, dt, t_start, n_steps, solver, tol, progress, prep_tol, d_max):
        assert (dt, t_start, solver, tol, prep_tol) == (1e-2, 1.0, "clarabel-dual", 1e-8, 1e-6)
        assert d_max == pytest.approx(table1.D_SEED_3D * make().radii.mean())
        return StepSequence(
            label=label, dim=3, n_free=3, dt=dt, t_start=t_start,
            problems=[problem] * n_steps, impulses=[None] * n_steps,
            warm_starts=[None] + [problem.b.reshape(-1, 3) * 0] * (n_steps - 1),
            trajectory_solver=solver, trajectory_tol=tol,
        )  # fmt: skip

    FakeWorker.calls = []
    monkeypatch.setattr(table1, "record_steps", fake_record)
    monkeypatch.setattr(table1, "Worker", FakeWorker)
    df = table1.STUDY(
        solvers="clarabel,scs-dual",
        scale=0.0001,
        cases=["3d"],
        steps=3,
        time_limit=600.0,
        out=tmp_path,
        progress=lambda line: None,
    )
    ours = df[df.source == "this machine"].set_index(["solver", "tol"])
    assert list(ours.index) == [
        ("clarabel", 1e-8),
        ("scs-dual", 1e-8),
        ("clarabel", 1e-5),
        ("scs-dual", 1e-5),
    ]
    assert set(ours.N) == {12} and set(ours.dim) == {3}  # round(0.0001 * 122932)
    # clarabel: out of time on the first problem at 1e-5, not run at all at 1e-8.
    assert ours.loc[("clarabel", 1e-5), "steps_ok"] == "0/3"
    assert "killed after 930 s" in ours.loc[("clarabel", 1e-5), "note"]
    assert "not run: time limit" in ours.loc[("clarabel", 1e-8), "note"]
    assert ("clarabel", 1e-8) not in FakeWorker.calls
    # scs-dual: all well at 1e-5; an error on the first problem at 1e-8 ends that row.
    assert ours.loc[("scs-dual", 1e-5), "steps_ok"] == "3/3"
    assert ours.loc[("scs-dual", 1e-5), "iterations"] == 5
    assert ours.loc[("scs-dual", 1e-8), "steps_ok"] == "0/3"
    assert "ValueError: boom" in ours.loc[("scs-dual", 1e-8), "note"]
    assert "2 not run" in ours.loc[("scs-dual", 1e-8), "note"]
    assert FakeWorker.calls.count(("scs-dual", 1e-8)) == 2
    assert ours.loc[("scs-dual", 1e-5), "start"] == "warm"
    assert ours.loc[("clarabel", 1e-8), "start"] == "cold"
