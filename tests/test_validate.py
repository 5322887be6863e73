"""``cocd validate``: tiny versions of the seed paper's physics cases.

Each test runs a case on a few tens of discs and checks the direction of its
effect (a smaller time step converges; COCD and NSCD give close profiles; an
erodible layer lengthens the runout), the files it writes, and that running
it again only reads its run files.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import re
import shutil

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from cocd.bench import estimate
from cocd.cli import app
from cocd.errors import CocdError
from cocd.io.runfile import RunFile
from cocd.studies import stability
from cocd.validate import _common as validate
from cocd.validate import erodible, nscd, timestep

runner = CliRunner()


def _quiet(lines):
    return lines.append


def test_an_ensemble_of_packings_gives_mean_and_spread(tmp_path):
    """Two packings: the ensemble table holds their mean and sample spread, and the
    summary's numbers are those of the ensemble table."""
    case = dict(n=30, dts=[2e-3, 1e-3], times=[0.02], solver="clarabel", seeds=2)
    table = timestep.STUDY(out=tmp_path, progress=_quiet([]), **case)
    assert sorted(table.seed.unique()) == [0, 1]
    ensemble = pd.read_csv(tmp_path / "timestep_ensemble.csv")
    row = ensemble[(ensemble.dt == 2e-3) & (ensemble.t == 0.02)].iloc[0]
    errors = table[table.dt == 2e-3].profile_error
    assert errors.iloc[0] != errors.iloc[1]  # two packings, two collapses
    assert row.seeds == 2 and np.isclose(row.profile_error, errors.mean())
    assert np.isclose(row.profile_error_sd, errors.std(ddof=1))
    assert row.error_over_largest_dt == 1.0  # 2e-3 is the largest step
    fronts = table[table.dt == 1e-3].front_m / table[table.dt == 1e-3].d_mean_m
    ref = ensemble[(ensemble.dt == 1e-3) & (ensemble.t == 0.02)].iloc[0]
    assert np.isclose(ref.front_d, fronts.mean())
    summary = json.loads((tmp_path / "timestep.meta.json").read_text())["summary"]
    g = "{:.3g}".format
    assert f"dt = 0.002 s: {g(row.profile_error)} +- {g(row.profile_error_sd)}" in summary
    assert f"front of dt = 0.001 s: {g(ref.front_d)} +- {g(ref.front_d_sd)} d" in summary
    assert (tmp_path / "runs" / "timestep" / "n30_dt1e-03_s1" / "run.h5").exists()
    # Each packing's largest step has a twin at another solver tolerance: the two drift
    # apart by a measured, non-zero amount (the flow's sensitivity), smaller than the
    # time step's own error this early; the other steps have no twin.
    twins = table[table.dt == 2e-3].twin_error
    assert (twins > 0).all() and (twins < table[table.dt == 2e-3].profile_error).all()
    assert table[table.dt == 1e-3].twin_error.isna().all()
    assert np.isclose(row.twin_error, twins.mean())
    assert "differing only in the solver's tolerance (1e-08 and 1e-09)" in summary
    assert (tmp_path / "runs" / "timestep" / "n30_dt2e-03_tol1e-09_s1" / "run.h5").exists()


def test_runs_made_two_at_once_give_the_same_tables_and_are_read_back(tmp_path):
    """--workers 2 runs the packings in two processes on one thread each: the same
    numbers as one after another, every run's progress comes back, and a second call
    reads the kept runs back, solving nothing."""
    case = dict(n=30, dts=[2e-3, 1e-3], times=[0.02], solver="clarabel", seeds=2)
    apart, together = tmp_path / "apart", tmp_path / "together"
    environ = dict(os.environ)
    one = timestep.STUDY(out=apart, progress=_quiet([]), **case)
    lines: list[str] = []
    two = timestep.STUDY(out=together, progress=lines.append, workers=2, **case)
    pd.testing.assert_frame_equal(
        one.drop(columns="compute_s"), two.drop(columns="compute_s"), check_exact=True
    )
    labels = ["n30_dt2e-03", "n30_dt1e-03", "n30_dt2e-03_tol1e-09"]
    for label in labels + [f"{x}_s1" for x in labels]:
        assert any(line.startswith(f"timestep: {label} (") for line in lines), label
        assert any(re.match(rf"  {label}: step (\d+)/\1 ", line) for line in lines), label
    made = json.loads((together / "timestep.meta.json").read_text())
    assert made["work_units"] > 0
    again: list[str] = []
    timestep.STUDY(out=together, progress=again.append, workers=2, **case)
    assert not any(": step " in line for line in again)  # read back, nothing solved
    # The record keeps the time and work of the command that solved, and says when.
    read_back = json.loads((together / "timestep.meta.json").read_text())
    for key in ("elapsed_s", "work_units", "workers"):
        assert read_back[key] == made[key]
    assert read_back["timed"] == made["written"]
    with pytest.raises(CocdError, match="workers must be an integer >= 1, got 0"):
        timestep.STUDY(out=together, progress=_quiet([]), workers=0, **case)
    assert dict(os.environ) == environ  # the workers' one-thread settings stay theirs


def test_a_failed_run_among_workers_stops_the_rest_and_keeps_what_finished(tmp_path, monkeypatch):
    """Two workers, three runs, the first failing at once: its error is raised, the
    run beside it finishes and is kept, the third never starts; two runs in one
    folder are refused."""
    how = validate.RunSettings(solver="clarabel", tol=1e-8, fallback=())
    base = validate.base_params(30, 0.3)
    steps = dict(dt=1e-3, until=0.05, frame_dt=0.01)
    # The run beside the failing one is long enough to be running when the failure comes
    # (which takes a worker a second or two, more on a loaded machine): a slot freed by
    # its end before then would rightly start the third.
    jobs = [
        validate.collapse_job(tmp_path, "t", "bad", 0, {**base, "n_grains": -5}, how, **steps),
        validate.collapse_job(tmp_path, "t", "good", 0, base, how, **{**steps, "until": 0.25}),
        validate.collapse_job(tmp_path, "t", "later", 0, base, how, **steps),
    ]
    lines: list[str] = []
    with pytest.raises(CocdError, match="n_grains"):
        validate.collapse_runs(jobs, workers=2, progress=lines.append)
    assert (tmp_path / "runs" / "t" / "good" / "measured.json").exists()
    assert not (tmp_path / "runs" / "t" / "later").exists()
    assert any(line.startswith("  good: step 250/250") for line in lines)
    with pytest.raises(CocdError, match="two runs of the case would share the folder"):
        validate.collapse_runs([jobs[1], jobs[1]], workers=2, progress=lines.append)
    # Called again: the kept run is read back, and the one left is timed at its rate.
    monkeypatch.setattr(estimate, "_current", {})
    estimate.announce("t", [(30, 100)], out=tmp_path, progress=lines.append)
    validate.collapse_runs(jobs[1:], workers=1, progress=lines.append)
    rest = r"t: 1 of 2 runs kept; the rest should take \d+ s \(at the kept runs' rate\)"
    assert any(re.fullmatch(rest, line) for line in lines), lines


def test_the_time_announced_for_a_resumed_run_counts_only_its_steps_left(tmp_path, monkeypatch):
    """A run stopped part-way is resumed, not made again: the time said before it is
    that of the steps it has left."""
    how = validate.RunSettings(solver="clarabel", tol=1e-8, fallback=())
    params = validate.base_params(30, 0.3)
    short = validate.collapse_job(tmp_path, "t", "run", 0, params, how, dt=1e-3, until=0.09,
                                  frame_dt=0.01)  # fmt: skip
    validate.collapse_runs([short], progress=_quiet([]))
    (tmp_path / "runs" / "t" / "run" / "measured.json").unlink()
    longer = validate.collapse_job(tmp_path, "t", "run", 0, params, how, dt=1e-3, until=0.12,
                                   frame_dt=0.01)  # fmt: skip
    monkeypatch.setattr(estimate, "_current", {})
    lines: list[str] = []
    estimate.announce("t", [(longer.free_grains, longer.steps)], out=tmp_path,
                      progress=lines.append)  # fmt: skip
    validate.collapse_runs([longer], progress=lines.append)
    whole = estimate._current["seconds"]
    (rest,) = [line for line in lines if "0 of 1 runs kept, 1 partly made" in line]
    said = float(re.search(r"should take (\d+) s", rest).group(1))
    assert whole > 6.0 and said == pytest.approx(whole * 30 / 120, abs=1.0)  # 30 left
    assert any(line.endswith("resumed at step 90") for line in lines)
    # A run whose file holds every step is measured, not made.
    (tmp_path / "runs" / "t" / "run" / "measured.json").unlink()
    lines = []
    validate.collapse_runs([longer], progress=lines.append)
    assert any("0 of 1 runs kept, 1 made but not measured" in line for line in lines)
    # Started over (fresh), the whole run is made again: nothing is said of a rest.
    fresh = validate.collapse_job(tmp_path, "t", "run", 0, params,
                                  validate.RunSettings(solver="clarabel", tol=1e-8,
                                                       fallback=(), fresh=True),
                                  dt=1e-3, until=0.12, frame_dt=0.01)  # fmt: skip
    lines = []
    validate.collapse_runs([fresh], progress=lines.append)
    assert not any("partly made" in line for line in lines)


def test_a_runs_cost_counts_the_attempts_of_steps_taken_again():
    """A step redone with a wider margin cost its discarded attempts too: they are in
    the run's compute seconds; statistics written before ``redo_time`` existed sum
    the rest."""
    stats = pd.DataFrame(
        {"detect_time": [1.0, 2.0], "setup_time": [0.5, 0.5], "solve_time": [3.0, 4.0],
         "redo_time": [0.0, 7.0]}
    )  # fmt: skip
    assert validate.compute_seconds(stats) == pytest.approx(18.0)
    assert validate.compute_seconds(stats.drop(columns="redo_time")) == pytest.approx(11.0)


def test_a_run_partly_made_is_finished_before_a_new_one_starts(tmp_path):
    """Of the runs to make, one stopped part-way is taken up first, whatever its place
    in the list; the series come back in the list's order."""
    how = validate.RunSettings(solver="clarabel", tol=1e-8, fallback=())
    steps = dict(dt=1e-3, frame_dt=0.01)

    def job(name, until):
        return validate.collapse_job(tmp_path, "t", name, 0, validate.base_params(30, 0.3),
                                     how, until=until, **steps)  # fmt: skip

    validate.collapse_runs([job("second", 0.03)], progress=_quiet([]))
    (tmp_path / "runs" / "t" / "second" / "measured.json").unlink()
    lines: list[str] = []
    series = validate.collapse_runs([job("first", 0.05), job("second", 0.05)],
                                    progress=lines.append)  # fmt: skip
    starts = [line.split(" (")[0] for line in lines if line.startswith("t: ") and "(" in line]
    assert starts == ["t: second", "t: first"], lines
    assert any(line.endswith("resumed at step 30") for line in lines)
    assert [s.label for s in series] == ["first", "second"]
    # Each says where its steps were made, read back from its kept measurements too.
    from cocd.provenance import machine_name

    again = validate.collapse_runs([job("first", 0.05), job("second", 0.05)],
                                   progress=_quiet([]))  # fmt: skip
    for s in (*series, *again):
        assert s.machines == ((1, machine_name()),) and s.machine == machine_name()
    resumed = dataclasses.replace(series[0], machines=((1, ""), (7, "Other CPU, 64 cores")))
    assert resumed.machine == "not recorded from step 1; Other CPU, 64 cores from step 7"
    assert dataclasses.replace(series[0], machines=()).machine == "not recorded"


def test_a_run_measured_at_an_earlier_end_names_those_steps_machines(tmp_path, monkeypatch):
    """A run taken on elsewhere says so from the step it was taken on; measured at an
    end before that step, only the first machine made the steps measured."""
    import cocd.io.runfile as runfile
    from cocd.provenance import machine_name
    from cocd.runs import MEASURED_FILES, measured_other_ends

    how = validate.RunSettings(solver="clarabel", tol=1e-8, fallback=())

    def job(until):
        return validate.collapse_job(tmp_path, "t", "run", 0, validate.base_params(30, 0.3),
                                     how, dt=1e-3, until=until, frame_dt=0.01)  # fmt: skip

    here, other = machine_name(), "Other CPU, 64 cores"
    validate.collapse_runs([job(0.03)], progress=_quiet([]))
    monkeypatch.setattr(runfile, "machine_name", lambda: other)
    (later,) = validate.collapse_runs([job(0.05)], progress=_quiet([]))
    assert later.machines == ((1, here), (31, other))
    assert later.machine == f"{here} from step 1; {other} from step 31"
    folder = tmp_path / "runs" / "t" / "run"
    for kept in (*measured_other_ends(folder), *(folder / name for name in MEASURED_FILES)):
        kept.unlink(missing_ok=True)
    (earlier,) = validate.collapse_runs([job(0.03)], progress=_quiet([]))  # measured again
    assert earlier.steps == 30 and earlier.machines == ((1, here),)


def test_a_run_taken_on_to_a_later_end_is_still_read_at_the_earlier_one(tmp_path):
    """A case run again with a later ``until`` takes its run on; the measurements kept at
    the earlier end stay, and a run file past the end asked is measured at that end,
    as the run stopped there measured."""
    params = validate.base_params(30, 0.3)

    def job(until, tol=1e-8, fresh=False):
        how = validate.RunSettings(solver="clarabel", tol=tol, fallback=(), fresh=fresh)
        return validate.collapse_job(tmp_path, "t", "run", 0, params, how, dt=1e-3,
                                     until=until, frame_dt=0.01, profile_times=(0.05, 0.09),
                                     few=(0.1,))  # fmt: skip

    folder = tmp_path / "runs" / "t" / "run"
    aside = ["measured_to0.09s.json", "measured_to0.09s.npz", "measured_to0.09s_stats.parquet"]
    (short,) = validate.collapse_runs([job(0.09)], progress=_quiet([]))
    (longer,) = validate.collapse_runs([job(0.12)], progress=_quiet([]))
    assert longer.times[-1] == pytest.approx(0.12) and len(longer.stats) == 120
    assert sorted(f.name for f in folder.glob("measured_to*")) == aside

    def same(a, b):
        assert a.times == pytest.approx(b.times) and len(a.stats) == len(b.stats) == 90
        for name in ("front", "profiles", "speed_max", "speed_max_flow", "speed_few_flow"):
            np.testing.assert_allclose(getattr(a, name), getattr(b, name), err_msg=name)
        cols = ["step", "t", "nc", "iterations", "status"]
        pd.testing.assert_frame_equal(a.stats[cols], b.stats[cols])

    assert short.profiles.any() and short.speed_max_flow.any() and short.speed_few_flow.any()
    lines: list[str] = []
    (kept,) = validate.collapse_runs([job(0.09)], progress=lines.append)
    assert any(line.endswith("to t = 0.09 s (kept)") for line in lines), lines
    same(kept, short)
    for name in aside:
        (folder / name).unlink()
    (folder / "measured_to0.12s.json").write_text("{}\n")  # a stale record: replaced
    (folder / "measured_tools.json").write_text("{}\n")  # not a measurement: left alone
    (again,) = validate.collapse_runs([job(0.09)], progress=_quiet([]))
    same(again, short)
    assert again.steps_made == 0
    moved = json.loads((folder / "measured_to0.12s.json").read_text())
    assert moved["config"]["run"]["until"] == 0.12
    with RunFile(folder / "run.h5") as rf:
        assert int(rf.steps[-1]) == 120  # measured at 0.09 s, not run back
    # Only the end may differ from the run's, and it must fall on a saved frame.
    with pytest.raises(CocdError, match=r"cannot measure .*run.tol was 1e-08, now 1e-06"):
        validate.collapse_runs([job(0.09, tol=1e-6)], progress=_quiet([]))
    with pytest.raises(CocdError, match=r"no frame at t = 0.095 s .*0.01 s apart"):
        validate.collapse_runs([job(0.095)], progress=_quiet([]))
    # Both ends are kept: each is read back without the run file.
    (folder / "run.h5").rename(tmp_path / "run.h5")
    for until, n in ((0.09, 90), (0.12, 120)):
        lines = []
        (s,) = validate.collapse_runs([job(until)], progress=lines.append)
        assert len(s.stats) == n and any(line.endswith("(kept)") for line in lines)
    # Started over, a run keeps no measurement of another end.
    (tmp_path / "run.h5").rename(folder / "run.h5")
    validate.collapse_runs([job(0.09, fresh=True)], progress=_quiet([]))
    assert [f.name for f in folder.glob("measured_to*")] == ["measured_tools.json"]


def test_runs_kept_in_a_folder_of_their_own_serve_two_outputs(tmp_path):
    """`--runs` puts the run files apart from the tables: a second `--out` sharing them
    reads the runs back, no step taken, into the same table; a file in the way of the
    folder is a one-line error."""
    runs = tmp_path / "scratch"
    args = ["validate", "timestep", "--n", "30", "--dts", "2e-3,1e-3", "--times", "0.02",
            "--solver", "clarabel", "--runs", str(runs)]  # fmt: skip
    first = runner.invoke(app, [*args, "--out", str(tmp_path / "a")])
    assert first.exit_code == 0, first.output
    assert len(list((runs / "timestep").iterdir())) == 3  # two time steps and a twin
    assert not (tmp_path / "a" / "runs").exists()
    second = runner.invoke(app, [*args, "--out", str(tmp_path / "b")])
    assert second.exit_code == 0, second.output
    assert "(kept)" in second.output and "step " not in second.output
    assert not (tmp_path / "b" / "runs").exists()
    tables = [pd.read_csv(tmp_path / out / "timestep.csv") for out in ("a", "b")]
    pd.testing.assert_frame_equal(*(t.drop(columns="compute_s") for t in tables))
    (tmp_path / "file").write_text("")
    bad = runner.invoke(app, [*args[:-1], str(tmp_path / "file"), "--out", str(tmp_path / "c")])
    assert bad.exit_code == 2 and "a file is in the way of the folder" in bad.output
    assert "--runs" in bad.output and "Traceback" not in bad.output
    # The avalanche study keeps its cells there too, and refuses the file the same way.
    bad = runner.invoke(app, ["validate", "avalanche", "--runs", str(tmp_path / "file"),
                              "--out", str(tmp_path / "c")])  # fmt: skip
    assert bad.exit_code == 2 and "a file is in the way of the folder" in bad.output


def test_a_cases_scene_is_built_once_for_its_estimate_and_its_checks(tmp_path, monkeypatch):
    """A job's free grains are its scene's; jobs of the same column share one build, and
    the other packing's column is built apart."""
    import cocd.builders

    built = []
    real = cocd.builders.column_collapse

    def counted(*args, **kw):
        built.append(kw.get("seed"))
        return real(*args, **kw)

    monkeypatch.setattr(cocd.builders, "column_collapse", counted)
    monkeypatch.setattr(validate, "_BUILT", {})
    how = validate.RunSettings(solver="clarabel", tol=1e-8, fallback=())
    params = validate.base_params(30, 0.3)
    steps = dict(dt=1e-3, until=0.01, frame_dt=0.01)
    jobs = [validate.collapse_job(tmp_path, c, "run", seed, params, how, **steps)
            for c, seed in [("a", 0), ("b", 0), ("a", 1)]]  # fmt: skip
    counts = [job.free_grains for job in jobs + jobs]
    assert len(built) == 2 and counts[:3] == counts[3:]
    params0 = dict(jobs[0].params)
    scene = real(params0.pop("dim"), **params0)
    assert counts[0] == scene.n_free == 30
    x, r, column = scene.positions, scene.radii, scene.groups["column"]
    bed = scene.groups["bed"]
    column0 = validate.built_column(jobs[0].params)
    assert column0.length == np.max(x[column, 0] + r[column])
    assert column0.height == np.max(x[column, 1] + r[column]) - np.max(x[bed, 1] + r[bed])
    assert len(built) == 2  # read back, not built again


def test_twin_run_can_be_left_out_and_a_bad_twin_tolerance_is_refused(tmp_path):
    case = dict(n=30, dts=[2e-3, 1e-3], times=[0.02], solver="clarabel")
    table = timestep.STUDY(out=tmp_path, progress=_quiet([]), twin_tol=0.0, **case)
    assert "twin_error" not in table
    assert "twin_error" not in pd.read_csv(tmp_path / "timestep_ensemble.csv")
    meta = json.loads((tmp_path / "timestep.meta.json").read_text())
    assert (
        "twin" not in meta["summary"] and len(list((tmp_path / "runs" / "timestep").iterdir())) == 2
    )
    for bad in (1e-8, -1e-9, float("nan")):  # the run's own tolerance, negative, NaN
        result = runner.invoke(
            app,
            ["validate", "timestep", "--n", "30", "--twin-tol", str(bad), "--out", str(tmp_path)],
        )
        assert result.exit_code != 0 and "twin_tol must be 0 (no twin)" in result.output
        assert "Traceback" not in result.output


def test_smaller_time_steps_converge(tmp_path):
    lines: list[str] = []
    case = dict(n=30, dts=[2e-3, 1e-3, 5e-4], times=[0.02, 0.06], solver="clarabel")
    table = timestep.STUDY(out=tmp_path, progress=lines.append, **case)
    assert sorted(table.dt.unique()) == [5e-4, 1e-3, 2e-3]
    for t in (0.02, 0.06):
        err = table[table.t == t].set_index("dt").profile_error
        assert err[5e-4] == 0.0  # the reference against itself
        # Halving the step brings the profile closer to the reference, and every
        # profile is already within a few per cent of it.
        assert 0.0 < err[1e-3] < err[2e-3] < 0.05
    for name in ("timestep.csv", "timestep.md", "timestep_profiles.png", "timestep_error.png"):
        assert (tmp_path / name).stat().st_size > 0
    meta = json.loads((tmp_path / "timestep.meta.json").read_text())
    assert (
        "profile error against dt = 0.0005 s (mean +- spread over the packings)"
        in (meta["summary"])
    )
    assert "1 packing," in meta["summary"]
    readme = (tmp_path / "README.md").read_text()
    assert readme.startswith("# Validation against the seed papers")
    assert "Time step convergence (Fig. 2)" in readme
    # `cocd bench readme` rebuilds it under the heading it has.
    from cocd.bench.report import write_readme

    assert write_readme(tmp_path).read_text().startswith("# Validation against the seed papers")
    # Run again: every run file is complete, so nothing is stepped, same table.
    again: list[str] = []
    table2 = timestep.STUDY(out=tmp_path, progress=again.append, **case)
    assert not any("step " in line for line in again)
    pd.testing.assert_frame_equal(table.drop(columns="compute_s"), table2.drop(columns="compute_s"))


def test_a_case_is_rebuilt_from_its_kept_measurements_without_run_files(tmp_path):
    """A finished run keeps its measurements beside the run file; with the run files
    gone the case is rebuilt from them, same table, no step taken; another tolerance
    or other profile times are not answered from them."""
    case = dict(n=30, dts=[2e-3, 1e-3], times=[0.02], solver="clarabel")
    table = timestep.STUDY(out=tmp_path, progress=_quiet([]), **case)
    runs = sorted((tmp_path / "runs" / "timestep").iterdir())
    assert len(runs) == 3  # two time steps and the largest one's twin
    for folder in runs:
        assert {"measured.json", "measured.npz", "measured_stats.parquet"} <= {
            f.name for f in folder.iterdir()
        }
        (folder / "run.h5").unlink()
    again: list[str] = []
    first_work = json.loads((tmp_path / "timestep.meta.json").read_text())["work_units"]
    table2 = timestep.STUDY(out=tmp_path, progress=again.append, **case)
    assert not any("step " in line for line in again)
    assert not any((folder / "run.h5").exists() for folder in runs)
    # Nothing was solved: the record keeps the solves' work and time, so the next
    # estimate does not take the read-back's seconds for the solves' rate.
    assert first_work > 0
    assert json.loads((tmp_path / "timestep.meta.json").read_text())["work_units"] == first_work
    pd.testing.assert_frame_equal(table, table2)
    # Other profile times: the kept measurements do not answer, the runs are made again.
    lines: list[str] = []
    timestep.STUDY(out=tmp_path, progress=lines.append, **{**case, "times": [0.01, 0.02]})
    assert all((folder / "run.h5").exists() for folder in runs)
    # A damaged record is not trusted: the run is measured again from its run file.
    (runs[0] / "measured.json").write_text("{")
    table3 = timestep.STUDY(out=tmp_path, progress=_quiet([]), **case)
    pd.testing.assert_frame_equal(table.drop(columns="compute_s"), table3.drop(columns="compute_s"))


def test_cocd_and_nscd_profiles_are_close(tmp_path):
    table = nscd.STUDY(
        n=30,
        times_T=[0.5, 1.0],
        solver="clarabel",
        out=tmp_path,
        progress=_quiet([]),
    )
    assert list(table.t) == pytest.approx([0.06, 0.12])
    # Both schemes solve their own problem to tolerance.
    assert (table.max_residual_cocd <= 1e-5).all() and (table.max_residual_nscd <= 1e-2).all()
    # The convexification changes the profiles by a few per cent at most here.
    assert (table.profile_difference < 0.05).all()
    assert (table.profile_difference > 0.0).any()
    d = 0.03  # about one mean diameter of these discs
    assert np.all(np.abs(table.front_cocd_m - table.front_nscd_m) < d)


def test_cocd_against_nscd_over_two_packings_gives_mean_and_spread(tmp_path):
    table = nscd.STUDY(
        n=30, times_T=[1.0], solver="clarabel", seeds=2, out=tmp_path, progress=_quiet([])
    )
    assert sorted(table.seed) == [0, 1]
    ensemble = pd.read_csv(tmp_path / "nscd_ensemble.csv")
    (row,) = ensemble.itertuples()
    assert row.seeds == 2
    assert row.profile_difference == pytest.approx(table.profile_difference.mean())
    assert row.front_gap_d_sd == pytest.approx(table.front_gap_d.std(ddof=1))
    gap = (table.front_nscd_m - table.front_cocd_m) / table.d_mean_m
    np.testing.assert_allclose(table.front_gap_d, gap)
    summary = json.loads((tmp_path / "nscd.meta.json").read_text())["summary"]
    g = "{:.3g}".format
    assert f"gap NSCD - COCD {g(row.front_gap_d)} +- {g(row.front_gap_d_sd)} d" in summary
    assert "2 packings" in summary


def test_nscd_twin_measures_the_reference_against_its_own_tolerance(tmp_path):
    """--nscd-twin-tol runs nscd again per packing at another tolerance: its profile
    difference from the first nscd run and its front gap are columns of the table."""
    case = dict(n=30, times_T=[1.0], solver="clarabel", nscd_tol=1e-6, nscd_twin_tol=1e-3, seeds=2)
    table = nscd.STUDY(out=tmp_path, progress=_quiet([]), **case)
    runs = tmp_path / "runs" / "nscd"
    for row in table.itertuples():
        tail = f"_s{row.seed}" if row.seed else ""
        twin = runs / f"n30_nscd-symmetric_tol0.001{tail}" / "measured.npz"
        main = runs / f"n30_nscd-symmetric{tail}" / "measured.npz"
        with np.load(twin) as a, np.load(main) as b:
            front_twin = np.interp(row.t, a["times"], a["front"])
            front_nscd = np.interp(row.t, b["times"], b["front"])
            difference = validate.profile_error(a["profiles"][0], b["profiles"][0])
        assert row.nscd_twin_difference == pytest.approx(difference)
        assert row.nscd_twin_front_gap_d == pytest.approx((front_twin - front_nscd) / row.d_mean_m)
        # The looser tolerance moves NSCD, by less than the convexification does here.
        assert 0.0 < row.nscd_twin_difference < row.profile_difference
    summary = json.loads((tmp_path / "nscd.meta.json").read_text())["summary"]
    assert "NSCD at tol 0.001 against NSCD at 1e-06" in summary
    ensemble = pd.read_csv(tmp_path / "nscd_ensemble.csv")
    assert ensemble.nscd_twin_difference_4d.iloc[0] == pytest.approx(
        table.nscd_twin_difference_4d.mean()
    )
    # Without kept runs of the twin's tolerance, the rest is timed at the shipped rate,
    # not at that of the runs kept with other backends.
    for folder in runs.glob("n30_nscd-symmetric_tol0.001*"):
        shutil.rmtree(folder)
    lines: list[str] = []
    nscd.STUDY(out=tmp_path, progress=lines.append, **case)
    (rest,) = [line for line in lines if "4 of 6 runs kept" in line]
    assert "kept runs' rate" not in rest
    result = runner.invoke(
        app,
        [
            "validate",
            "nscd",
            "--n",
            "30",
            "--nscd-twin-tol",
            "1e-6",
            "--nscd-tol",
            "1e-6",
            "--out",
            str(tmp_path),
        ],
    )
    assert result.exit_code != 0 and "Traceback" not in result.output
    assert "nscd_twin_tol must be 0 (no twin) or a positive tolerance other than" in result.output


def test_an_erodible_layer_lengthens_the_runout(tmp_path):
    lines: list[str] = []
    table = erodible.STUDY(
        n=60,
        slopes=[22.0],
        layers_d=[0.0, 3.0],
        until=0.6,
        bed_length=1.2,
        solver="clarabel",
        out=tmp_path,
        progress=_quiet(lines),
    )
    # The estimate sizes each run by its free grains, the layer's with the column's.
    assert f"the largest of {60 + table.n_layer.max()} grains" in lines[0]
    runout = table.set_index("layer_d").runout_m
    assert runout[0.0] > 0.1  # the column spreads down the slope
    # The seed's Fig. 9 and the experiments: the layer lengthens the runout.
    assert runout[3.0] > 1.2 * runout[0.0]
    assert table.set_index("layer_d").runout_ratio[3.0] == pytest.approx(runout[3.0] / runout[0.0])
    assert table.n_layer.iloc[0] == 0 and table.n_layer.iloc[1] > 100
    # R0 is the column's measured initial length, not a nominal 0.2 m.
    assert np.allclose(table.runout_over_R0, table.runout_m / table.front0_m)
    assert not table.reached_end.any()
    # At 0.6 s both fronts are still advancing down the slope, by many diameters a second.
    assert (table.end_speed_d_s > 5.0).all(), table.end_speed_d_s
    # An advancing front spans at least half its least-squares travel over the window.
    window = validate.RUNOUT_WINDOW * 0.6
    d = float(table.layer_mm.max()) / 3.0 * 1e-3  # the 3-diameter layer's thickness / 3
    travel = table.end_speed_d_s * d * window
    assert (table.end_range_R0 * table.front0_m >= 0.5 * travel).all()
    assert (tmp_path / "erodible_front.png").stat().st_size > 0


def test_erodible_gaps_between_layers_over_two_packings(tmp_path):
    """Two packings, two layers: the gap table holds each packing's runout difference in
    R0, averaged with its spread, and the summary quotes it."""
    study = dict(n=30, slopes=[22.0], until=0.2, bed_length=0.8, solver="clarabel", seeds=2)
    table = erodible.STUDY(**study, layers_d=[0.0, 3.0], out=tmp_path, progress=_quiet([]))
    assert sorted(table.seed) == [0, 0, 1, 1]
    per_seed = [
        (sub.set_index("layer_d").runout_m[3.0] - sub.set_index("layer_d").runout_m[0.0])
        / sub.front0_m.iloc[0]
        for _, sub in table.groupby("seed")
    ]
    (gap,) = pd.read_csv(tmp_path / "erodible_gaps.csv").itertuples()
    assert gap.seeds == 2 and (gap.from_layer_d, gap.to_layer_d) == (0.0, 3.0)
    assert gap.gap_R0 == pytest.approx(np.mean(per_seed))
    assert gap.gap_R0_sd == pytest.approx(np.std(per_seed, ddof=1))
    assert np.isnan(gap.seed_gap_R0)  # the seed quotes 3 to 5 grains only
    ensemble = pd.read_csv(tmp_path / "erodible_ensemble.csv").set_index("layer_d")
    ratios = table[table.layer_d == 3.0].runout_ratio
    assert ensemble.runout_ratio[3.0] == pytest.approx(ratios.mean())
    summary = json.loads((tmp_path / "erodible.meta.json").read_text())["summary"]
    g = "{:.3g}".format
    assert f"0 to 3 d at 22 deg: {g(gap.gap_R0)} +- {g(gap.gap_R0_sd)} R0" in summary
    # One layer alone (read back from the kept runs): no gap to give, an empty table.
    erodible.STUDY(**study, layers_d=[3.0], out=tmp_path, progress=_quiet([]))
    gaps = pd.read_csv(tmp_path / "erodible_gaps.csv")
    assert gaps.empty and {"gap_R0", "gap_R0_sd", "seed_gap_R0"} <= set(gaps.columns)


def test_erodible_gaps_against_the_seed_in_spreads():
    """From 3 to 5 grain layers the seed quotes a gap; the table says how many spreads
    the packings' mean lies from it."""
    rows = [
        {"slope_deg": 16.0, "seed": seed, "layer_d": layer, "runout_m": runout,
         "front0_m": 0.2, "reached_end": False}
        for seed, (r3, r5) in enumerate([(0.50, 0.60), (0.50, 0.64), (0.52, 0.56)])
        for layer, runout in ((3.0, r3), (5.0, r5))
    ]  # fmt: skip
    (gap,) = erodible._gaps(pd.DataFrame(rows), [3.0, 5.0]).itertuples()
    per_seed = np.array([0.10, 0.14, 0.04]) / 0.2
    assert gap.seed_gap_R0 == erodible.SEED_GAPS_3_TO_5[16.0] == 0.1
    assert gap.gap_R0 == pytest.approx(per_seed.mean())
    assert gap.seed_offset_sd == pytest.approx((per_seed.mean() - 0.1) / per_seed.std(ddof=1))


def test_runout_grows_with_the_aspect_ratio(tmp_path):
    from cocd.validate import runout

    table = runout.STUDY(
        aspects=[0.5, 0.7, 1.0, 1.4, 2.0, 4.0],
        area=0.004,
        diameter=0.01,
        dt=2e-3,
        solver="clarabel",
        rest_T=8.0,
        min_time=0.5,
        out=tmp_path,
        progress=_quiet([]),
    )
    # Taller columns run out further and lose more of their height.
    assert np.all(np.diff(table.runout) > 0.0)
    assert np.all(np.diff(1.0 / table.Hf_over_H0) > 0.0)
    assert not table.reached_end.any()
    assert (table.front_speed_end_d_per_s < 1.0).all()  # at rest at the end
    # Heights over the column as built, whose ratio is near the one asked.
    assert np.allclose(table.Hf_over_H0, table.Hf_m / table.H0_built_m)
    assert np.allclose(table.a_built, table.H0_built_m / table.L0_built_m)
    assert np.all(np.abs(np.log(table.a_built / table.a)) < np.log(2.0))
    fits = pd.read_csv(tmp_path / "runout_scaling_fit.csv").set_index("quantity")
    fit = fits.loc["(Lf - L0)/L0"]
    assert fit.k_all > 0.5 and 0.0 < fit.k_all_ci < 1.0
    assert fit.n_low == 3 and fit.n_high == 3  # three ratios a side, the least allowed
    summary = json.loads((tmp_path / "runout_scaling.meta.json").read_text())["summary"]
    assert f"a^({fit.k_all:.2f} +- {fit.k_all_ci:.2f})" in summary
    # Two laws against one: six ratios, one split, a p-value, quoted in the summary.
    assert 0.0 < fit.p_two_laws <= 1.0
    assert "Two laws against one: runout p " in summary
    assert (tmp_path / "runout_scaling.png").stat().st_size > 0


def test_runout3d_sidewall_friction_holds_the_column(tmp_path):
    """3D columns in a channel three diameters wide, with frictionless sidewalls and
    with rough ones: taller columns run out further in both, and the walls' friction
    shortens the runout and keeps more of the height."""
    from cocd.validate import runout

    aspects = [0.5, 0.7, 1.0, 1.4, 2.0, 4.0]
    lines: list[str] = []
    table = runout.STUDY_3D(
        aspects=aspects,
        area=0.004,
        diameter=0.01,
        width_d=3.0,
        side_mus=[0.0, 0.5],
        dt=5e-3,
        rest_T=8.0,
        min_time=0.5,
        tol=1e-4,
        out=tmp_path,
        progress=lines.append,
    )
    assert sorted(set(table.side_mu)) == [0.0, 0.5]
    assert (table.W_over_d == 3.0).all()
    assert np.allclose(table.W_over_H0, 0.03 / table.H0_m)
    # The same columns in both channels: the fronts start at the same grain.
    runs = tmp_path / "runs" / "scaling3d"
    starts = [
        np.load(runs / f"a1_d10mm_mu0.25_W3d_side{m:g}" / "measured.npz")["front"][0]
        for m in (0.0, 0.5)
    ]
    assert starts[0] == starts[1]
    assert not table.reached_end.any()
    by = table.set_index(["side_mu", "a"])
    for side_mu in (0.0, 0.5):
        assert by.runout[side_mu, 4.0] > 3.0 * by.runout[side_mu, 0.5]
        assert by.Hf_over_H0[side_mu, 4.0] < 0.6 * by.Hf_over_H0[side_mu, 0.5]
    rough, smooth = by.loc[0.5], by.loc[0.0]
    assert rough.runout.mean() < 0.9 * smooth.runout.mean()
    assert rough.Hf_over_H0.mean() > smooth.Hf_over_H0.mean()
    fits = pd.read_csv(tmp_path / "runout3d_scaling_fit.csv")
    assert sorted(zip(fits.side_mu, fits.quantity, strict=True)) == [
        (m, q) for m in (0.0, 0.5) for q in ("(Lf - L0)/L0", "H0/Hf")
    ]
    # Four grains along the column at a = 1 and at 1.4: the lattice builds one column for
    # both, run and fitted once per channel, at its built ratio.
    same = [line for line in lines if "builds the same column as a = 1 " in line]
    assert len(same) == 2 and all(line.startswith("runout3d_scaling: a = 1.4") for line in same)
    assert 1.4 not in set(table.a)
    for side_mu in (0.0, 0.5):
        built = table[table.side_mu == side_mu].sort_values("a").a_built
        assert np.all(np.diff(built) > 0.0)
    ensemble = pd.read_csv(tmp_path / "runout3d_scaling_ensemble.csv")
    assert len(ensemble) == 2 * (len(aspects) - 1)
    summary = json.loads((tmp_path / "runout3d_scaling.meta.json").read_text())["summary"]
    for side_mu, name in ((0.0, "Frictionless sidewalls"), (0.5, "Sidewall friction 0.5")):
        fit = fits[(fits.side_mu == side_mu) & (fits.quantity == "H0/Hf")].iloc[0]
        assert name in summary
        assert f"H0/Hf a^({fit.k_all:.2f} +- {fit.k_all_ci:.2f})" in summary
    assert (tmp_path / "runout3d_scaling.png").stat().st_size > 0
    assert not (tmp_path / "runout_scaling.csv").exists()  # kept apart from the 2D study


def test_dims_compares_the_same_collapse_in_2d_and_3d(tmp_path):
    """Fig. 7 in small: a column of discs and one of spheres, on the flat and at 22
    degrees. Both spread with time, further down the slope; run again, both are read
    back."""
    from cocd.validate import dims

    kwargs = dict(
        n2d=100, n3d=300, width=0.05, times=[0.1, 0.3], dt2d=2e-3, bed_length=0.42, tol=1e-4
    )
    table = dims.STUDY(out=tmp_path, progress=_quiet([]), **kwargs)
    assert sorted(zip(table.slope_deg, table.t, strict=True)) == [
        (0.0, 0.1), (0.0, 0.3), (22.0, 0.1), (22.0, 0.3)
    ]  # fmt: skip
    by = table.set_index(["slope_deg", "t"])
    for dim in ("2d", "3d"):
        front = by[f"front_{dim}_R0"]
        assert front[0.0, 0.3] > front[0.0, 0.1] > 0.95  # from about R0, spreading
        assert front[22.0, 0.3] > front[0.0, 0.3]  # further down the slope
    assert np.allclose(table.front_ratio, table.front_2d_m / table.front_3d_m)
    # The main mass ends behind the front (its trail of grains ahead left out), within a
    # bin (one diameter), and past the column's start.
    for dim in ("2d", "3d"):
        mass_end = table[f"mass_end_{dim}_R0"] * dims.LENGTH
        assert np.all(mass_end <= table[f"front_{dim}_m"] + 1e-3 * table[f"d_{dim}_mm"])
        assert np.all(mass_end > 0.9 * dims.LENGTH)
    assert np.allclose(table.mass_end_ratio, table.mass_end_2d_R0 / table.mass_end_3d_R0)
    assert np.allclose(table.front_2d_R0 * dims.LENGTH, table.front_2d_m)
    assert table.seed_front_ratio.isna().all()  # the seed's ratios are at t = 1 s
    assert (table.n_2d == 100).all() and (table.n_3d == 300).all()
    assert (table.steps_3d == 30).all()  # dt3d = 0.01 s to 0.3 s
    # Down the slope the fronts reach the bed's end (0.42 m, 2.1 R0) by t = 0.3 s.
    cut = (by.front_2d_m >= 0.42 - 2e-3 * by.d_2d_mm) | (by.front_3d_m >= 0.42 - 2e-3 * by.d_3d_mm)
    assert list(by.reached_end) == list(cut)
    assert by.reached_end[22.0, 0.3] and not by.reached_end[0.0, 0.3]
    summary = json.loads((tmp_path / "dims.meta.json").read_text())["summary"]
    assert ("cut short" in summary) == bool(by.reached_end.any())
    assert f"ratio {by.front_ratio[22.0, 0.3]:.3g}" in summary  # one packing: no spread
    assert f"3D {by.front_3d_R0[0.0, 0.3]:.2g} R0" in summary
    ensemble = pd.read_csv(tmp_path / "dims_ensemble.csv").set_index(["slope_deg", "t"])
    assert ensemble.front_ratio[22.0, 0.3] == pytest.approx(by.front_ratio[22.0, 0.3])
    assert (tmp_path / "dims_profiles.png").stat().st_size > 0
    lines: list[str] = []
    again = dims.STUDY(out=tmp_path, progress=lines.append, **kwargs)
    assert sum(line.endswith("(kept)") for line in lines) == 4
    pd.testing.assert_frame_equal(again, table)
    # A run whose measurements are lost but whose file is whole is measured again, not
    # made again.
    kept_3d = sorted((tmp_path / "runs" / "dims").glob("3d_*/measured.json"))
    kept_3d[0].unlink()
    lines = []
    pd.testing.assert_frame_equal(dims.STUDY(out=tmp_path, progress=lines.append, **kwargs), table)
    assert any("3 of 4 runs kept, 1 made but not measured" in line for line in lines)
    # A second, finer size beside the first, whose runs are read back: one table and
    # one ensemble over both sizes, coarsest first, each size's grains against the seed's.
    both = dims.STUDY(out=tmp_path, progress=_quiet([]), **{**kwargs, "n2d": (150, 100),
                      "n3d": (500, 300)})  # fmt: skip
    assert list(both.n_3d.unique()) == [300, 500] and list(both.n_2d.unique()) == [100, 150]
    pd.testing.assert_frame_equal(
        both[both.n_3d == 300].reset_index(drop=True).drop(columns="grain_scale"),
        table.drop(columns="grain_scale"),
    )
    assert np.allclose(both.grain_scale, (dims.SEED_N3D / both.n_3d) ** (1 / 3))
    fine = both[both.n_3d == 500]
    assert (fine.d_3d_mm < both[both.n_3d == 300].d_3d_mm.min()).all()
    ensemble = pd.read_csv(tmp_path / "dims_ensemble.csv")
    assert len(ensemble) == 8 and list(ensemble.n_3d) == [300] * 4 + [500] * 4
    row = ensemble[(ensemble.n_3d == 500) & (ensemble.slope_deg == 22.0) & (ensemble.t == 0.3)]
    assert row.front_ratio.iloc[0] == pytest.approx(
        fine[(fine.slope_deg == 22.0) & (fine.t == 0.3)].front_ratio.iloc[0]
    )
    summary = json.loads((tmp_path / "dims.meta.json").read_text())["summary"]
    assert "100 discs and 300 spheres" in summary and "150 discs and 500 spheres" in summary
    # The runs to make are timed at the rate of the kept runs of their kind: with one 3D
    # run kept, at its rate; with the 2D runs alone kept, not at theirs.
    kept_3d = sorted((tmp_path / "runs" / "dims").glob("3d_n300_*/measured.json"))
    for kept in kept_3d[:1]:
        kept.unlink()
        (kept.parent / "run.h5").unlink()
    lines = []
    dims.STUDY(out=tmp_path, progress=lines.append, **kwargs)
    (rest,) = [line for line in lines if "3 of 4 runs kept" in line]
    assert rest.endswith("(at the kept runs' rate)")
    for kept in kept_3d:
        kept.unlink()
        (kept.parent / "run.h5").unlink()
    lines = []
    dims.STUDY(out=tmp_path, progress=lines.append, **kwargs)
    (rest,) = [line for line in lines if "2 of 4 runs kept" in line]
    assert "kept runs' rate" not in rest


def test_flume_steeper_runs_further_and_stops_later_and_its_measures_are_the_frames(tmp_path):
    """Seed 001's flume in small: a pile on an erodible bed in a channel with rough
    sidewalls, on the flat and at 12 degrees. On the flat it comes to rest, the front
    before the whole flow; down the slope the deposit is lower at the back wall, runs
    further and stops later, if at all (its surface creeps in bursts: whether it is
    still at 1 s depends on the threads' order of summation). The rest time and the
    height are those of the run file's frames; run again, both runs are read back."""
    from cocd.io.runfile import RunFile
    from cocd.validate import flume

    kwargs = dict(
        slopes=[12.0, 0.0], diameter=0.01, length=0.08, height=0.04, width=0.04, layer=0.02,
        bed_length=0.5, dt=5e-3, until=1.0, tol=1e-4,
    )  # fmt: skip
    table = flume.STUDY(out=tmp_path, progress=_quiet([]), **kwargs)
    assert list(table.slope_deg) == [0.0, 12.0]
    assert (table.W_over_d == 4.0).all() and not table.reached_end.any()
    flat, slope = (table.iloc[k] for k in (0, 1))
    assert not flat.still_moving and flat.t_front_s <= flat.t_f_s < 1.0  # the front first
    assert flat.speed_end <= 0.01
    assert slope.Hf_over_H0 < 0.7 * flat.Hf_over_H0 and slope.runout_m >= flat.runout_m
    if slope.still_moving:
        assert slope.speed_end > 0.01 and np.isnan(slope.t_f_s)
    else:
        assert slope.t_f_s > flat.t_f_s
    assert 0.0 < flat.Hf_m < flat.H0_m
    # The layer's surface far downstream, the height at the back wall and the rest time,
    # read again from the flat run's frames.
    with RunFile(tmp_path / "runs" / "flume" / "slope0_d10mm_W4cm_L0.5m_mu0.25" / "run.h5") as rf:
        scene = rf.scene(0)
        free, r = ~scene.fixed, rf.radii
        base = float(np.max(scene.positions[scene.fixed, 2] + r[scene.fixed]))
        last = rf.frame(-1).positions
        top = last[free, 2] + r[free]
        back = last[free, 0] < 0.01
        assert flat.Hf_m == pytest.approx(top[back].max() - base - flat.bed_top_m)
        # Bins of 1 cm whose centres lie 3 diameters past the front, short of the end
        # wall's 2 diameters (the bed ends at 0.5 m); some hold no grain centre.
        x_bin = np.floor(last[free, 0] / 0.01)
        bins = [k for k in range(50) if flat.front_m + 0.03 < k * 0.01 + 0.005 < 0.48]
        tops = [top[x_bin == k].max() - base for k in bins if (x_bin == k).any()]
        assert len(tops) >= flume.FAR_BINS and flat.bed_top_m == pytest.approx(np.median(tops))
        # The deposit's edge: the first bin ahead of the gate standing less than 2 mm above.
        edge = next(k for k in range(8, 50) if (x_bin == k).any() and top[x_bin == k].max()
                    - base - flat.bed_top_m < 0.002)  # fmt: skip
        assert flat.runout_m == pytest.approx(edge * 0.01 - 0.08)
        # The rest time of the flow (grains not past the final front by more than a
        # diameter), and of every free grain.
        flow_speeds = []  # the flow's grains' speeds, per frame
        for column, near in (("t_f_s", True), ("t_f_all_s", False)):
            speeds = []
            for k in range(rf.n_frames):
                frame = rf.frame(k)
                keep = free & (frame.positions[:, 0] <= flat.front_m + 0.01 if near else True)
                speed = np.linalg.norm(frame.velocities[keep], axis=1)
                speeds.append(speed.max())
                if near:
                    flow_speeds.append(np.sort(speed)[::-1])
            moving = [k for k in range(rf.n_frames) if speeds[k] > 0.01]
            assert moving and moving[-1] < rf.n_frames - 1
            assert flat[column] == pytest.approx(rf.times[moving[-1] + 1])
        assert flat.t_f_all_s >= flat.t_f_s
        # Rest times that a few rattlers do not fail: from when at most as many grains of
        # the flow as 0.1 % and 1 % of the pile's count are faster than 0.01 m/s; and the
        # speed all but those stay under, at every frame.
        pile = len(range(rf.n_grains)[scene.groups["column"]])
        assert (table.n_pile == pile).all() and pile >= 100  # 1 % lets one grain go
        trace = pd.read_csv(tmp_path / "flume_trace.csv")
        flat_trace = trace[trace.slope_deg == 0.0]
        for name, share in (("permil", 1e-3), ("pct", 1e-2)):
            busy = [k for k in range(rf.n_frames) if (flow_speeds[k] > 0.01).sum() > share * pile]
            assert busy and flat[f"t_f_{name}_s"] == pytest.approx(rf.times[busy[-1] + 1])
            few = [v[int(share * pile)] if v.size > share * pile else 0.0 for v in flow_speeds]
            assert flat_trace[f"speed_{name}_flow"].to_numpy() == pytest.approx(few, rel=1e-3)
            assert flat[f"speed_end_{name}"] == pytest.approx(few[-1], rel=1e-3)
        assert flat.t_f_pct_s <= flat.t_f_permil_s <= flat.t_f_s
        ke = rf.stats().kinetic_energy.to_numpy()
        assert flat.ke_end_over_peak == pytest.approx(ke[-1] / ke.max()) and ke[-1] < ke.max()
    summary = json.loads((tmp_path / "flume.meta.json").read_text())["summary"]
    assert f"Hf / H0 {flat.Hf_over_H0:.3g}" in summary
    assert f"at rest at {flat.t_f_s:.3g} s" in summary
    assert f"(all but 0.1 % of the pile's count at rest from {flat.t_f_permil_s:.3g} s)" in summary
    assert (tmp_path / "flume_profiles.png").stat().st_size > 0
    # Every frame's front from the gate and largest speeds, and their figure.
    trace = pd.read_csv(tmp_path / "flume_trace.csv")
    for row in (flat, slope):
        run = trace[trace.slope_deg == row.slope_deg]
        assert len(run) == row.steps + 1 and run.t.iloc[-1] == pytest.approx(1.0)
        assert run.front_m.iloc[-1] == pytest.approx(row.front_m - 0.08)
        assert run.speed_max_flow.iloc[-1] == pytest.approx(row.speed_end)
        assert (run.speed_max_flow <= run.speed_max).all()
        assert (run.speed_pct_flow <= run.speed_permil_flow).all()
        assert (run.speed_permil_flow <= run.speed_max_flow).all()
    assert (tmp_path / "flume_front.png").stat().st_size > 0
    lines: list[str] = []
    again = flume.STUDY(out=tmp_path, progress=lines.append, **kwargs)
    assert sum(line.endswith("(kept)") for line in lines) == 2
    # The time announced from the recorded rate is said to be for work already done.
    assert re.fullmatch(r"flume: .*expected .*", lines[0])
    assert "flume: 2 of 2 runs kept; nothing is left to solve" in lines
    pd.testing.assert_frame_equal(again, table)
    # Kept without the speeds of the flow but a few, a run is measured again from its
    # run file, not solved again.
    kept = tmp_path / "runs" / "flume" / "slope0_d10mm_W4cm_L0.5m_mu0.25" / "measured.npz"
    with np.load(kept) as data:
        arrays = {name: data[name] for name in data.files if name != "speed_few_flow"}
    np.savez_compressed(kept, **arrays)
    lines.clear()
    again = flume.STUDY(out=tmp_path, progress=lines.append, **kwargs)
    assert sum(line.endswith("(kept)") for line in lines) == 1
    assert not any(": step " in line for line in lines)
    pd.testing.assert_frame_equal(again, table)
    with np.load(kept) as data:
        assert "speed_few_flow" in data.files
    # --kept-only tables what is measured: the second packings, asked but not made, are
    # said and left out, and nothing runs.
    lines.clear()
    again = flume.STUDY(out=tmp_path, progress=lines.append, seeds=2, kept_only=True, **kwargs)
    pd.testing.assert_frame_equal(again, table)
    assert sorted(line for line in lines if "left out" in line) == [
        f"slope{s}_d10mm_W4cm_L0.5m_mu0.25_s1: not measured yet, left out (--kept-only)"
        for s in (0, 12)
    ]
    assert not any(": step " in line for line in lines)
    assert not (tmp_path / "runs" / "flume" / "slope0_d10mm_W4cm_L0.5m_mu0.25_s1").exists()
    with pytest.raises(CocdError, match="--kept-only tables the kept runs and --fresh makes"):
        flume.STUDY(out=tmp_path, kept_only=True, fresh=True, **kwargs)


def test_flume_summary_gives_the_smallest_share_every_packing_reaches():
    """The summary's rest time robust to rattlers: the smallest share of the pile's count
    that every packing reaches, else the largest share, with how many packings reach it."""
    from cocd.validate import _common as base
    from cocd.validate import flume

    nan = np.nan
    table = pd.DataFrame(
        {
            "seed": [0, 1, 0, 1, 0, 1, 0, 1],
            "slope_deg": [0.0, 0.0, 10.0, 10.0, 15.0, 15.0, 20.0, 20.0],
            "t_f_s": nan,
            "t_f_permil_s": [1.0, 1.2, 1.5, nan, nan, nan, nan, nan],
            "t_f_pct_s": [0.8, 1.0, 1.1, 1.3, 1.9, nan, nan, nan],
            "still_moving": True,
            "reached_end": False,
            "n_free": 100,
        }
    )
    for column in ("t_front_s", "Hf_m", "Hf_over_H0", "runout_m", "runout_over_L0"):
        table[column] = 0.5
    columns = ["t_f_s", "t_f_permil_s", "t_f_pct_s", "t_front_s", "Hf_m", "Hf_over_H0",
               "runout_m", "runout_over_L0"]  # fmt: skip
    ensemble = base.ensemble(
        table, ["slope_deg"], columns, ["still_moving", "reached_end"], reached=columns[:3]
    )
    text = flume._summary(
        ensemble, table, 0.004, 0.2, 0.1, 0.06, 0.02, 1.52, 0.01, 2.2, flume.Settings()
    )
    assert "0 deg: " in text and "(all but 0.1 % of the pile's count at rest from 1.1 +- " in text
    assert "(all but 1 % of the pile's count at rest from 1.2 +- " in text  # 10 deg
    assert "(all but 1 % of the pile's count at rest from 1.9 s in 1 of 2 packings)" in text
    assert "(more than 1 % of the pile's count moving at 2.2 s)" in text  # 20 deg


def test_avalanche_angle_exceeds_stop_angle_and_both_grow_with_friction(tmp_path, monkeypatch):
    from cocd.validate.avalanche import STUDY as avalanche

    kwargs = dict(n=60, width_d=20, step_deg=1.0, hold=0.1, start_deg=6, solver="clarabel")
    table = avalanche(mus=[0.1, 0.6], out=tmp_path, progress=_quiet([]), **kwargs)
    low, high = table.iloc[0], table.iloc[1]
    assert (table.avalanche_deg >= table.stop_deg).all()
    assert high.avalanche_deg > low.avalanche_deg and high.stop_deg > low.stop_deg
    assert 5.0 < low.stop_deg < 45.0 and 5.0 < high.avalanche_deg < 45.0
    trace = pd.read_csv(tmp_path / "avalanche_trace.csv")
    assert set(trace.phase) == {"up", "down"}
    # Run again: each friction coefficient already measured is read back, not re-run.
    lines: list[str] = []
    again = avalanche(mus=[0.1, 0.6], out=tmp_path, progress=lines.append, **kwargs)
    assert sum("already measured" in line for line in lines) == 2
    assert np.allclose(again.avalanche_deg, table.avalanche_deg)
    pd.testing.assert_frame_equal(pd.read_csv(tmp_path / "avalanche_trace.csv"), trace)
    # Kept by coefficient and by the options that shape it: another solver is a new cell.
    cells = pd.read_csv(tmp_path / "runs" / "avalanche" / "cells.csv")
    assert len(cells) == 2 and cells.setup.str.contains("solver=clarabel tol=").all()
    # A second packing: the first is read back, the ensemble holds mean and spread.
    lines = []
    both = avalanche(mus=[0.1], seeds=2, out=tmp_path, progress=lines.append, **kwargs)
    assert sum("already measured" in line for line in lines) == 1
    assert sorted(both.seed) == [0, 1]
    ensemble = pd.read_csv(tmp_path / "avalanche_ensemble.csv").set_index("mu")
    angles = both.avalanche_deg
    assert ensemble.avalanche_deg[0.1] == pytest.approx(angles.mean())
    assert ensemble.avalanche_deg_sd[0.1] == pytest.approx(angles.std(ddof=1))

    # Two at once, on an empty packing cache: the packings are built first (one per
    # process, or here in this one for a single packing), then the sequences run on
    # them; the same angles as one after another.
    monkeypatch.setenv("COCD_CACHE", str(tmp_path / "cache"))
    apart = avalanche(
        mus=[0.1], seeds=2, workers=2, out=tmp_path / "apart", progress=_quiet([]), **kwargs
    )
    ordered = both.sort_values("seed").avalanche_deg.to_numpy()
    assert np.allclose(apart.sort_values("seed").avalanche_deg, ordered)
    monkeypatch.setenv("COCD_CACHE", str(tmp_path / "cache1"))
    one = avalanche(mus=[0.1, 0.6], workers=2, out=tmp_path / "one", progress=_quiet([]), **kwargs)
    assert np.allclose(one.sort_values("mu").avalanche_deg, table.avalanche_deg)


def test_avalanche_in_3d_two_at_once_and_the_friction_for_a_target_angle(tmp_path):
    """Spheres in a square box, two sequences in two processes: the same physics as in
    2D, the outputs under their own name, the calibration read from the ensemble."""
    from cocd.validate.avalanche import STUDY_3D as avalanche3d

    # About 2.5 diameters deep; a duplicated coefficient is run once.
    kwargs = dict(
        n=400, length_d=12, width_d=12, mus=[0.3, 0.8, 0.3], start_deg=14, step_deg=3.0, hold=0.05
    )
    table = avalanche3d(workers=2, out=tmp_path, progress=_quiet([]), **kwargs)
    assert len(table) == 2
    low, high = table.set_index("mu").loc[0.3], table.set_index("mu").loc[0.8]
    assert (table.n_grains == 400).all()
    assert (table.avalanche_deg >= table.stop_deg).all()
    assert high.avalanche_deg > low.avalanche_deg
    assert 10.0 < low.avalanche_deg < 45.0 and 10.0 < high.avalanche_deg < 45.0
    assert not (tmp_path / "avalanche.csv").exists()  # the 2D study's outputs are apart
    trace = pd.read_csv(tmp_path / "avalanche3d_trace.csv")
    assert set(trace.phase) == {"up", "down"} and set(trace.mu) == {0.3, 0.8}
    (cal,) = pd.read_csv(tmp_path / "avalanche3d_calibration.csv").itertuples()
    target = 0.5 * (low.avalanche_deg + high.avalanche_deg)
    assert cal.target_deg == 23.7
    cells = pd.read_csv(tmp_path / "runs" / "avalanche3d" / "cells.csv")
    assert cells.setup.str.endswith(" side_mu=0").all()  # frictionless sidewalls by default
    # Run again with the midpoint as the target: both sequences are read back, and the
    # coefficient found is the midpoint's.
    lines: list[str] = []
    again = avalanche3d(target_deg=target, out=tmp_path, progress=lines.append, **kwargs)
    assert sum("already measured" in line for line in lines) == 2
    assert np.allclose(again.avalanche_deg, table.avalanche_deg)
    (cal,) = pd.read_csv(tmp_path / "avalanche3d_calibration.csv").itertuples()
    assert cal.mu == pytest.approx(0.55) and (cal.mu_below, cal.mu_above) == (0.3, 0.8)


def test_calibration_interpolates_between_the_bracketing_coefficients():
    from cocd.validate.avalanche import calibrate

    ensemble = pd.DataFrame({"mu": [0.8, 0.2, 0.4], "avalanche_deg": [26.0, 14.0, 22.0]})
    (row,) = calibrate(ensemble, 23.0).itertuples()
    assert row.mu == pytest.approx(0.4 + 0.4 / 4.0)  # 1 of the 4 degrees from 0.4 to 0.8
    assert row.mu_low == pytest.approx(0.4) and row.mu_high == pytest.approx(0.6)
    assert (row.mu_below, row.angle_below_deg, row.mu_above) == (0.4, 22.0, 0.8)
    # Not bracketed: NaN, not an extrapolation.
    (row,) = calibrate(ensemble, 30.0).itertuples()
    assert math.isnan(row.mu) and math.isnan(row.mu_below)


def test_two_power_laws_are_recovered():
    from cocd.bench.metrics import fit_two_power_laws

    a = np.geomspace(0.5, 10.0, 8)
    y = np.where(a < 3.0, 2.0 * a, 2.0 * 3.0 ** (1 / 3) * a ** (2 / 3))
    fit = fit_two_power_laws(a, y)
    assert fit["k_low"] == pytest.approx(1.0) and fit["k_high"] == pytest.approx(2 / 3)
    assert 2.0 < fit["a_c"] < 4.5
    with pytest.raises(CocdError, match="positive, finite"):
        fit_two_power_laws([1.0, 2.0], [1.0, -1.0])
    # Three noisy packings per ratio: the 95 % intervals hold the true exponents (fixed
    # seed), narrow with the noise, and a side needs three distinct ratios.
    rng = np.random.default_rng(3)
    aa = np.repeat(np.geomspace(0.5, 20.0, 10), 3)
    yy = np.where(aa < 3.0, 2.0 * aa, 2.0 * 3.0 ** (1 / 3) * aa ** (2 / 3))
    noisy = fit_two_power_laws(aa, yy * np.exp(rng.normal(0.0, 0.05, aa.size)))
    assert abs(noisy["k_low"] - 1.0) < noisy["k_low_ci"] < 0.3
    assert abs(noisy["k_high"] - 2 / 3) < noisy["k_high_ci"] < 0.3
    assert noisy["p_two_laws"] < 0.01  # the bend is real
    # One law with the same noise: the best split is not told from the scatter.
    straight = fit_two_power_laws(aa, 2.0 * aa**0.8 * np.exp(rng.normal(0.0, 0.05, aa.size)))
    assert straight["p_two_laws"] > 0.05
    # A law exact to rounding: no bend at all, whatever the exponent.
    for k in (0.8, 0.9, 1.0):
        assert fit_two_power_laws(aa, 2.0 * aa**k)["p_two_laws"] == 1.0
    few = fit_two_power_laws([1.0, 2.0, 3.0, 4.0, 5.0], [1.0, 2.0, 3.0, 3.5, 4.0])
    assert math.isnan(few["a_c"]) and math.isfinite(few["k_all_ci"])


def test_a_tighter_tolerance_keeps_a_box_at_rest(tmp_path):
    stability.STUDY(
        solvers="apgd",
        tols=[1e-1, 1e-5],
        n=40,
        dim=2,
        t_end=3.0,
        dt=1e-2,
        time_limit=None,
        run_budget=None,
        isolate=False,
        out=tmp_path,
        progress=_quiet([]),
    )
    summary = pd.read_csv(tmp_path / "stability_summary.csv").set_index("tol")
    table = pd.read_csv(tmp_path / "stability_threshold.csv")
    # A loose answer injects motion; a tight one keeps the box still.
    assert summary.loc[1e-5, "at_rest"] and not summary.loc[1e-1, "at_rest"]
    assert summary.loc[1e-5, "max_energy_ratio"] < 1e-3 * summary.loc[1e-1, "max_energy_ratio"]
    row = table.set_index("solver").loc["apgd"]
    assert row.largest_eps_at_rest == 1e-5 and row.consistent
    assert "stability_threshold" in (tmp_path / "README.md").read_text()
    sens = pd.read_csv(tmp_path / "stability_criterion.csv")
    assert sorted(sens.threshold.unique()) == [1e-8, 1e-7, 1e-6, 1e-5, 1e-4]


def test_profile_error_and_thresholds():
    assert validate.profile_error([1.0, 2.0], [1.0, 2.0]) == 0.0
    assert validate.profile_error([0.0, 2.0], [1.0, 2.0]) == pytest.approx(1 / math.sqrt(5))
    with pytest.raises(CocdError, match="empty"):
        validate.profile_error([1.0], [0.0])
    with pytest.raises(CocdError, match="different bins"):
        validate.profile_error([1.0], [1.0, 2.0])
    summary = pd.DataFrame(
        {
            "solver": ["a"] * 3 + ["b"] * 2,
            "tol": [1e-1, 1e-2, 1e-3, 1e-1, 1e-2],
            "steps_done": [5, 5, 5, 5, 2],
            "steps_asked": [5] * 5,
            "at_rest": [False, True, True, False, False],
        }
    )
    th = stability.stability_thresholds(summary).set_index("solver")
    assert th.loc["a", "largest_eps_at_rest"] == 1e-2 and th.loc["a", "consistent"]
    assert math.isnan(th.loc["b", "largest_eps_at_rest"]) and not th.loc["b", "consistent"]
    assert th.loc["b", "unfinished"] == "0.01"
    # The same runs judged with other at-rest criteria.
    from cocd.studies._stability_report import criterion_sensitivity

    runs = summary.assign(max_energy_ratio=[1e-3, 1e-6, 1e-8, 1e-9, 1e-9])
    sens = criterion_sensitivity(runs, (1e-5, 1e-7)).set_index(["threshold", "solver"])
    assert sens.loc[(1e-5, "a"), "largest_eps_at_rest"] == 1e-2
    assert sens.loc[(1e-7, "a"), "largest_eps_at_rest"] == 1e-3
    assert sens.loc[(1e-5, "b"), "largest_eps_at_rest"] == 1e-1  # its 0.01 run was cut


def test_bad_arguments_are_one_line_errors(tmp_path):
    out = ["--out", str(tmp_path)]
    for args, message in (
        (["timestep", "--dts", "1e-3"], "at least two time steps"),
        (["timestep", "--dts", "1e-3,abc"], "--dts must be comma-separated numbers"),
        (["timestep", "--dts", "1e-3,3e-4"], "do not fall on whole numbers"),
        (["timestep", "--n", "0"], "n must be an integer >= 1"),
        (["erodible", "--layers", "0,-3"], "layer thicknesses must be >= 0"),
        (["erodible", "--slopes", "95"], "slopes must be in [0, 90)"),
        (["nscd", "--solver", "nope", "--n", "10"], "unknown solver 'nope'"),
        (["runout", "--aspects", "1,2,3,4"], "at least 6 distinct aspect ratios"),
        (["runout", "--aspects", "1,1,1,1,1,1"], "at least 6 distinct aspect ratios"),
        (
            ["runout3d", "--aspects", "1,2,3,4,5,1e5"],
            "aspect ratio 100000 gives a column 0.000316 m long",
        ),
        (["runout", "--aspects", "1e-5,1,2,3,4,5"], "m high, less than 2 diameters"),
        (["runout3d", "--side-mus", "0,-0.1"], "side_mus must be numbers >= 0"),
        (["runout3d", "--width-d", "1"], "width_d must be at least 2 diameters"),
        (["dims", "--slopes", "0,95"], "slopes must be in [0, 90)"),
        (["dims", "--times", "0.405"], "do not fall on whole numbers of 3D steps"),
        (["dims", "--bed-length", "0.1"], "bed_length must exceed"),
        (["dims", "--n2d", "100,200", "--n3d", "300"], "n2d and n3d pair one size each"),
        (["dims", "--n2d", "100,100", "--n3d", "300,400"], "n2d repeats a count"),
        (["dims", "--n2d", "538,239", "--n3d", "4165,14057"], "more spheres go with more discs"),
        (["avalanche", "--mus", "0.3,-1"], "--mus must be positive numbers"),
        (["avalanche", "--width-d", "8"], "width_d must be at least 12 diameters"),
        (["avalanche3d", "--length-d", "8"], "length_d must be at least 12 diameters"),
        (["avalanche3d", "--target-deg", "95"], "target_deg must be between 0 and 90"),
        (["avalanche3d", "--side-mu", "-0.1"], "side_mu must be a number >= 0"),
        (["flume", "--width", "0.005"], "width must be at least 2 diameters"),
        (["flume", "--bed-length", "0.2"], "bed_length must exceed the pile's length"),
        (["flume", "--slopes", "0,95"], "slopes must be in [0, 90)"),
        (["flume", "--side-mu", "-0.1"], "side_mu must be a number >= 0"),
        (["flume", "--until", "0.015"], "is not a whole number of steps"),
        (["erodible", "--until", "0.0015"], "until 0.0015 s is not a whole number of steps"),
        (["flume", "--diameter", "-0.004"], "diameter must be a positive number, got -0.004"),
        (["flume", "--length", "0.001"], "length 0.001 m is less than a grain"),
        (["flume", "--rest-speed", "0"], "rest_speed must be a positive number, got 0"),
        (["runout", "--dt", "nan"], "dt must be a positive number, got nan"),
    ):
        result = runner.invoke(app, ["validate", *args, *out])
        assert result.exit_code == 2, (args, result.output)
        assert message in result.output, (args, result.output)
        assert "Traceback" not in result.output


def test_backends_and_workers_are_refused_before_any_work(tmp_path):
    """Refused when the settings are made: no time estimate, no scene, no run file."""
    for args, message in (
        (["flume", "--solver", "nope"], "unknown solver 'nope'"),
        (["dims", "--fallback", "clarabel,nope"], "unknown solver 'nope'"),
        (["flume", "--solver", "apgd:polish=maybe"], "apgd: polish must be True or False"),
        (["flume", "--workers", "0"], "workers must be an integer >= 1, got 0"),
    ):
        result = runner.invoke(app, ["validate", *args, "--out", str(tmp_path)])
        assert result.exit_code == 2, (args, result.output)
        lines = result.output.strip().splitlines()
        assert len(lines) == 1 and message in lines[0], (args, result.output)
    assert not list(tmp_path.rglob("run.h5"))


def test_ensemble_gives_mean_spread_and_flag_counts_per_group():
    """Three packings of one case and one of another: mean, sample spread (none for
    one packing) and how many packings have each flag set."""
    table = pd.DataFrame(
        {
            "slope": [0.0, 0.0, 0.0, 22.0],
            "front": [1.0, 2.0, 3.0, 5.0],
            "reached_end": [True, False, True, False],
        }
    )
    out = validate.ensemble(table, ["slope"], ["front"], counts=["reached_end"])
    assert list(out.seeds) == [3, 1]
    assert list(out.front) == [2.0, 5.0]
    assert out.front_sd[0] == pytest.approx(1.0) and math.isnan(out.front_sd[1])
    assert list(out.reached_end) == [2, 0] and out.reached_end.dtype.kind == "i"
    assert "front_n" not in out  # counted only when asked


def test_ensemble_counts_the_packings_that_reached_a_time_it_averages():
    """A rest time one packing of two did not reach is averaged over the one that did,
    and ``_n`` says so: a mean over fewer packings than ``seeds`` is never silent."""
    table = pd.DataFrame({"slope": [0.0, 0.0, 20.0, 20.0], "t_rest": [1.0, 2.0, 3.0, math.nan]})
    out = validate.ensemble(table, ["slope"], ["t_rest"], reached=["t_rest"])
    assert list(out.seeds) == [2, 2]
    assert list(out.t_rest_n) == [2, 1] and out.t_rest_n.dtype.kind == "i"
    assert list(out.t_rest) == [1.5, 3.0] and math.isnan(out.t_rest_sd[1])
    # A count asked of a column not averaged would be dropped without a word: refused.
    with pytest.raises(ValueError, match=r"\['t_stop'\].*not among the columns"):
        validate.ensemble(table, ["slope"], ["t_rest"], reached=["t_stop"])


def test_a_front_within_two_diameters_of_the_bed_end_is_cut_short():
    d = 0.01
    assert not validate.cut_short([0.5, 0.97], bed=1.0, d_mean=d)
    assert validate.cut_short([0.5, 0.985, 0.9], bed=1.0, d_mean=d)  # any of the series
    assert validate.cut_short(0.995, bed=1.0, d_mean=d)
    assert validate.cut_short([0.5, math.nan, 0.999], bed=1.0, d_mean=d)  # NaN: unmeasured
    assert not validate.cut_short([math.nan], bed=1.0, d_mean=d)
    assert not validate.cut_short([], bed=1.0, d_mean=d)


def test_a_note_naming_rows_the_run_did_not_make_leaves_the_readme_but_not_the_run(tmp_path):
    """A case run with other rows than its note was written for (e.g. one slope of five)
    writes its tables and says in one line that the README was not rebuilt: it does not
    end in an error after hours of runs."""
    args = ["validate", "timestep", "--n", "30", "--dts", "2e-3,1e-3", "--times", "0.02",
            "--solver", "clarabel", "--twin-tol", "0", "--out", str(tmp_path)]  # fmt: skip
    first = runner.invoke(app, args)
    assert first.exit_code == 0, first.output
    assert f"wrote {tmp_path / 'README.md'}" in first.output
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "timestep.md").write_text("Error {{timestep.profile_error[dt=5e-4]}}.\n")
    readme = (tmp_path / "README.md").read_text()
    (tmp_path / "timestep.csv").unlink()
    again = runner.invoke(app, args)
    assert again.exit_code == 0, again.output
    assert "Traceback" not in again.output
    assert f"wrote {tmp_path / 'README.md'}" not in again.output
    said = " ".join(again.output.split())
    assert f"{tmp_path / 'README.md'} not rebuilt: timestep.md:" in said
    assert "0 rows match, not one" in said and f"cocd bench readme --out {tmp_path}" in said
    assert (tmp_path / "timestep.csv").exists() and (tmp_path / "README.md").read_text() == readme


def test_a_table_with_overlaps_defines_them_once_for_every_study(tmp_path):
    """``penetration_max`` (or ``_<scheme>``) is defined in the table's text, with its
    unit, by the one publishing step every validation goes through; a table without it
    is left as its study wrote it."""
    with_overlaps = pd.DataFrame({"seed": [0], "penetration_max_cocd": [3e-3]})
    validate.finish(tmp_path, "a", "A", with_overlaps, "Intro.", "", [], lambda _: None)
    text = (tmp_path / "a.md").read_text()
    assert "Intro. `penetration_max`:" in text and "in radii of the smaller" in text
    assert "above 0.01 is taken again" in text
    validate.finish(tmp_path, "b", "B", pd.DataFrame({"seed": [0]}), "Intro.", "", [], print)
    assert "penetration_max" not in (tmp_path / "b.md").read_text()


def test_flume_front_settles_within_a_bin_whatever_the_bins_reading():
    """A front that flickers by one bin, read as 4.05 mm or 3.99 mm for 4 mm bins, has
    settled; two bins away it has not; a front that never has a value never settles."""
    from cocd.validate.flume import front_settled

    times = np.arange(8) * 0.1
    d = 0.004
    final = 0.090
    one_bin = np.array([0.070, 0.086, final + 0.00405, final, final - 0.00399, final, final, final])
    assert front_settled(times, one_bin, d) == pytest.approx(0.1)
    two_bins = one_bin.copy()
    two_bins[5] = final + 0.00805
    assert front_settled(times, two_bins, d) == pytest.approx(0.6)
    assert front_settled(times, np.full(8, final), d) == 0.0
    assert np.isnan(front_settled(times, np.full(8, np.nan), d))
