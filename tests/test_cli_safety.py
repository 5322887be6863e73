"""The command line never loses a run or a computed answer, and says why in one line."""

from __future__ import annotations

import pandas as pd
import pytest
from typer.testing import CliRunner

from cocd.cli import app
from cocd.io.runfile import RunFile

runner = CliRunner()


def _run(*args: str):
    return runner.invoke(app, ["run", *args])


def _steps(folder) -> int:
    with RunFile(folder / "run.h5") as rf:
        return len(rf.stats())


def test_a_finished_run_is_never_replaced_without_force(tmp_path):
    out = tmp_path / "runs"
    assert _run("--steps", "3", "--out", str(out)).exit_code == 0
    assert runner.invoke(app, ["plot", str(out / "run.h5"), "stats"]).exit_code == 0
    (out / "notes.txt").write_text("mine")
    result = _run("--steps", "2", "--out", str(out))
    assert result.exit_code == 2
    assert result.output.strip() == (
        f"error: {out} already holds a run (3 steps to t = 0.003 s): "
        "--resume continues it, --force replaces it"
    )
    assert _steps(out) == 3 and (out / "stats.png").exists()
    result = _run("--steps", "2", "--out", str(out), "--force")
    assert result.exit_code == 0, result.output
    assert _steps(out) == 2
    assert len(pd.read_csv(out / "stats.csv")) == 2
    # The old run's plot went with it; the user's own file stays.
    assert not (out / "stats.png").exists() and (out / "notes.txt").read_text() == "mine"


def test_resume_needs_a_run_and_a_later_end(tmp_path):
    result = _run("--steps", "2", "--out", str(tmp_path / "empty"), "--resume")
    assert result.exit_code == 2
    assert "error: no run to resume in" in result.output and "leave out --resume" in result.output
    assert not (tmp_path / "empty" / "run.h5").exists()
    out = tmp_path / "done"
    assert _run("--steps", "3", "--out", str(out)).exit_code == 0
    result = _run("--until", "0.001", "--out", str(out), "--resume")
    assert result.exit_code == 2
    assert "already holds 3 steps to t = 0.003 s, past the end asked for (1 steps)" in result.output
    assert _steps(out) == 3
    # Resuming a finished run to its own end is not a mistake: nothing to do.
    assert _run("--steps", "3", "--out", str(out), "--resume").exit_code == 0
    assert _steps(out) == 3


@pytest.mark.unchecked_solutions  # the answer is not finite: the run must say so itself
def test_a_run_that_blows_up_ends_in_one_line_without_numpy_warnings(tmp_path):
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = _run("--dt", "1e-300", "--steps", "1", "--out", str(tmp_path / "r"))
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert lines[-1].startswith("error: step 1 (t = 1e-300 s")
    assert "returned non-finite velocities or impulses" in lines[-1]
    assert not [w for w in caught if issubclass(w.category, RuntimeWarning)], caught


def test_contradictory_options_are_refused_before_any_work(tmp_path):
    out = tmp_path / "x"
    result = _run("--steps", "2", "--until", "0.1", "--out", str(out))
    assert result.exit_code == 2
    assert result.output.strip() == "error: give --steps or --until, not both"
    result = _run("--steps", "2", "--out", str(out), "--resume", "--force")
    assert result.output.strip() == "error: give --resume or --force, not both"
    assert not out.exists()


def test_an_output_folder_that_cannot_be_made_is_refused_up_front(tmp_path):
    blocker = tmp_path / "file.txt"
    blocker.write_text("not a folder")
    result = _run("--steps", "2", "--out", str(blocker))
    assert result.exit_code == 2
    assert result.output.strip() == f"error: --out {blocker} is a file, not a folder"
    result = _run("--steps", "2", "--out", str(blocker / "sub"))
    assert result.exit_code == 2
    assert result.output.startswith(f"error: --out {blocker / 'sub'} cannot be written")
    assert "Traceback" not in result.output
    assert blocker.read_text() == "not a folder"


def test_problem_solve_checks_its_output_first_and_exits_on_what_it_got(tmp_path):
    import json

    import numpy as np

    from cocd import Stepper, column_2d

    stepper = Stepper(column_2d(60, mu=0.4), 1e-3, fclib_dir=tmp_path, fclib_steps=[8])
    stepper.run(9)
    problem = str(tmp_path / "step_000008.hdf5")
    # A folder that does not exist yet is created; the answer is kept.
    saved = tmp_path / "missing" / "dir" / "a.npz"
    result = runner.invoke(app, ["problem", "solve", problem, "--save-solution", str(saved)])
    assert result.exit_code == 0, result.output
    assert np.load(saved)["r"].size > 0
    # A place that cannot hold the file is refused before the solve.
    result = runner.invoke(app, ["problem", "solve", problem, "--save-solution", str(tmp_path)])
    assert result.exit_code == 2
    assert result.output.strip() == f"error: --save-solution {tmp_path} is a folder, not a file"
    blocked = saved / "b.npz"  # under a file
    result = runner.invoke(app, ["problem", "solve", problem, "--save-solution", str(blocked)])
    assert result.exit_code == 2
    assert result.output.strip() == (
        f"error: --save-solution folder {saved}: a file is in the way of the folder"
    )
    # Answered but not to the tolerance: status 3, and it says so.
    args = ["problem", "solve", problem, "--solver", "pgs:max_iter=2", "--tol", "1e-12", "--json"]
    result = runner.invoke(app, args)
    assert result.exit_code == 3
    assert json.loads(result.stdout)["status"] == "max_iter"
    assert "not solved to tol 1e-12: status max_iter" in result.stderr


def _progress(done: int, total: int, elapsed: float, this_call: int):
    from cocd.runs import Progress
    from cocd.stepper import StepRecord

    fields = {name: 0 for name in StepRecord.__dataclass_fields__}
    fields.update(step=done, t=done * 1e-3, solver="ipm", status="optimal", failures="")
    return Progress(StepRecord(**fields), done, total, elapsed, this_call)


def test_time_left_leaves_out_the_first_step_and_fits_80_columns():
    import io

    from rich.console import Console

    from cocd.cli import _ProgressDisplay

    # The first step took 10 s (compiling), the next ones 0.1 s each: 97 left.
    display = _ProgressDisplay(Console(file=io.StringIO(), width=80))
    display.update(_progress(1, 100, 10.0, 1))
    assert display.left(_progress(1, 100, 10.0, 1)) == "ETA ..."
    assert display.left(_progress(3, 100, 10.2, 3)) == "10 s left"
    # On a terminal 80 columns wide the count and the time left stay in view.
    screen = io.StringIO()
    live = _ProgressDisplay(Console(file=screen, width=80, force_terminal=True))
    with live:
        for k in range(1, 4):
            live.update(_progress(k, 300, 10.0 + 0.1 * (k - 1), k))
    import re

    text = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", screen.getvalue())
    last = [line for line in text.splitlines() if "/300" in line][-1]
    assert "3/300" in last and "30 s left" in last


def test_ctrl_c_in_a_terminal_says_where_and_how_to_resume(tmp_path):
    import re
    import signal
    import sys

    import pexpect

    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "cocd", "run", "--steps", "5000", "--frame-every", "2"]
    cmd += ["--out", str(out)]

    # A shell that runs the tests in the background may ignore SIGINT, and a library
    # may have left it blocked in this process: children inherit both. The command
    # gets the default handling, and the signal mask, a terminal user has.
    def as_in_a_terminal() -> None:
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})

    child = pexpect.spawn(
        cmd[0], cmd[1:], encoding="utf-8", timeout=120, dimensions=(24, 80),
        preexec_fn=as_in_a_terminal,
    )  # fmt: skip
    while True:  # a few steps in, a few frames written
        child.expect(r"(\d+)/5000")
        if int(child.match.group(1)) >= 6:
            break
    child.sendintr()  # Ctrl-C on the terminal
    if child.expect([r"interrupted at", pexpect.TIMEOUT], timeout=20) == 1:
        child.kill(signal.SIGINT)  # a wrapper (e.g. timeout(1)) kept the terminal's ^C away
        child.expect(r"interrupted at")
    child.expect(r" step (\d+) \(t = [0-9.e-]+ s\); (\S+) keeps frames up to step (\d+)")
    reached, kept = int(child.match.group(1)), int(child.match.group(3))
    assert child.match.group(2) == str(out / "run.h5") and 0 < kept <= reached
    child.expect(r"continue with: (.*) --resume")
    command = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", child.match.group(1)).strip()
    assert command == f"cocd run --steps 5000 --frame-every 2 --out {out}"
    child.expect(pexpect.EOF)
    child.close()
    assert child.exitstatus == 130
    # The run file is whole: the run goes on from its last frame.
    result = _run("--steps", str(kept + 2), "--frame-every", "2", "--out", str(out), "--resume")
    assert result.exit_code == 0, result.output
    assert f"resumed from step {kept}" in result.output
    assert _steps(out) == kept + 2


def test_the_readmes_problem_solve_example_is_solved(tmp_path):
    import json
    import re
    from pathlib import Path

    import pytest

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    line = re.search(r"cocd problem solve (fc2d_\S+) (.*?) --json", readme)
    assert line is not None
    path = Path(__file__).resolve().parents[2] / "shared" / "data" / "external" / line.group(1)
    if not path.exists():
        pytest.skip(f"{path} is not here")
    args = ["problem", "solve", str(path), *line.group(2).split(), "--json"]
    result = runner.invoke(app, [*args, "--save-solution", str(tmp_path / "answer.npz")])
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["status"] == "optimal"


def test_snapshot_movie_show_and_builders_from_the_command_line(tmp_path):
    from pathlib import Path

    from PIL import Image

    out = tmp_path / "run"
    assert _run("--steps", "4", "--frame-every", "2", "--out", str(out)).exit_code == 0
    result = runner.invoke(app, ["plot", str(out / "run.h5"), "snapshot", "--frame", "1"])
    assert result.exit_code == 0, result.output
    assert Image.open(out / "snapshot.png").size[0] > 800
    result = runner.invoke(app, ["plot", str(out / "run.h5"), "movie"])
    assert result.exit_code == 0, result.output
    movie = Image.open(out / "movie.gif")
    assert getattr(movie, "n_frames", 1) == 3  # steps 0, 2, 4
    result = runner.invoke(app, ["plot", str(out / "run.h5"), "snapshot", "--frame", "7"])
    assert result.exit_code == 2
    assert "has frames 0 to 2; there is no frame 7" in result.output
    result = runner.invoke(
        app, ["plot", str(out / "run.h5"), "movie", "--out", str(tmp_path / "m.avi")]
    )
    assert result.exit_code == 2 and "a movie is written as .gif or .mp4" in result.output
    # The scene before any step: the glued bed grains are counted apart.
    example = Path(__file__).resolve().parents[1] / "examples" / "column_collapse.toml"
    png = tmp_path / "scene.png"
    result = runner.invoke(app, ["show", str(example), "--out", str(png)])
    assert result.exit_code == 0, result.output
    assert "583 grains, 488 free and 95 glued" in result.output
    assert "potential contacts" in result.output and png.stat().st_size > 10_000
    result = runner.invoke(app, ["builders"])
    assert result.exit_code == 0
    assert (
        "column_collapse" in result.output and "erodible_thickness (default 0.0)" in result.output
    )


def test_version_provenance_and_units(tmp_path):
    import json
    import subprocess
    import sys

    import cocd

    proc = subprocess.run(
        [sys.executable, "-m", "cocd", "--version"], capture_output=True, text=True, check=False
    )
    assert proc.returncode == 0 and proc.stdout.startswith(f"cocd {cocd.__version__}")
    out = tmp_path / "run"
    assert _run("--steps", "2", "--out", str(out)).exit_code == 0
    with RunFile(out / "run.h5") as rf:
        attrs = dict(rf.f.attrs)
    assert attrs["cocd_version"] == cocd.__version__
    units = json.loads(attrs["units"])
    assert units["impulse"] == "N s/m" and units["velocities"] == "m/s"  # 2D: per metre
    header = (out / "stats.csv").read_text().splitlines()[0].split(",")
    assert {"t_s", "solve_time_s", "kinetic_energy_J_per_m", "ccp_residual"} <= set(header)


def test_run_help_lists_the_run_keys_with_brackets_intact():
    result = runner.invoke(app, ["run", "--help"])
    assert result.exit_code == 0
    assert "override the scene file's [run] table" in result.output
    for key in ("dt (0.001)", "frame_every (10)", "d_max (none)", "on_penetration ('redo')"):
        assert key in result.output


def test_bench_and_validate_write_outside_the_committed_results_by_default():
    # (tests/test_bench_stability.py runs a study without --out.)
    from cocd.bench.study import DEFAULT_OUT as OUTS

    assert OUTS["bench"].parts[0] == OUTS["validate"].parts[0] == "cocd-results"
    result = runner.invoke(app, ["sweep", "--help"])
    assert "default cocd-results/sweeps/<name>" in result.output


def test_provenance_is_modified_by_code_changes_not_by_results_written(tmp_path):
    """A checkout's commit is "modified" when its code changes, not when a command
    writes results into the tree (a figure is written before its record)."""
    import importlib.util
    import shutil
    import subprocess

    import cocd.provenance

    if shutil.which("git") is None:
        pytest.skip("git is not installed")
    (tmp_path / "cocd").mkdir()
    (tmp_path / "results").mkdir()
    copy = tmp_path / "cocd" / "provenance.py"
    shutil.copy(cocd.provenance.__file__, copy)
    (tmp_path / "results" / "figure.png").write_text("old")

    def git(*args: str) -> None:
        subprocess.run(
            ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-c", "commit.gpgsign=false",
             *args],
            cwd=tmp_path, check=True, capture_output=True,
        )  # fmt: skip

    git("init", "-q")
    git("add", ".")
    git("commit", "-qm", "first")
    spec = importlib.util.spec_from_file_location("provenance_copy", copy)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.provenance()["dirty"] is False and module.provenance()["commit"]
    (tmp_path / "results" / "figure.png").write_text("new")
    module.provenance.cache_clear()
    assert module.provenance()["dirty"] is False
    copy.write_text(copy.read_text() + "\n# changed\n")
    module.provenance.cache_clear()
    assert module.provenance()["dirty"] is True


def test_files_a_run_writes_are_not_taken_from_a_folder_without_a_run(tmp_path):
    """Someone's stats.csv in the output folder is not replaced unless --force; a run.h5
    that is a folder is named; a run that failed before its first step holds nothing
    and is replaced by the next plain run."""
    out = tmp_path / "theirs"
    out.mkdir()
    (out / "stats.csv").write_text("mine")
    result = _run("--steps", "2", "--out", str(out))
    assert result.exit_code == 2
    assert result.output.strip() == (
        f"error: {out} holds a stats.csv but no run file: a run would replace it; "
        "--force does, or give another --out"
    )
    assert (out / "stats.csv").read_text() == "mine" and not (out / "run.h5").exists()
    assert _run("--steps", "2", "--out", str(out), "--force").exit_code == 0
    assert len(pd.read_csv(out / "stats.csv")) == 2

    (tmp_path / "odd" / "run.h5").mkdir(parents=True)
    result = _run("--steps", "2", "--out", str(tmp_path / "odd"), "--force")
    assert result.exit_code == 2
    assert (
        result.output.strip()
        == f"error: --out {tmp_path / 'odd'}: run.h5 there is a folder, not a run file"
    )

    failed = tmp_path / "failed"
    result = _run("--steps", "2", "--out", str(failed), "--solver", "clarabel:no_such=1")
    assert result.exit_code == 2 and "no_such" in result.output
    with RunFile(failed / "run.h5") as rf:
        assert len(rf.stats()) == 0
    assert _run("--steps", "2", "--out", str(failed)).exit_code == 0
    assert _steps(failed) == 2


def test_an_output_named_on_the_command_line_is_replaced_only_with_force(tmp_path):
    """plot, show, export vtu and problem solve keep a file already at the --out (or
    --save-solution) they are given, naming --force, which replaces it; their default
    outputs, made again from the run or scene, are replaced."""
    from pathlib import Path

    from cocd import Stepper, column_2d

    out = tmp_path / "run"
    assert _run("--steps", "2", "--out", str(out)).exit_code == 0
    run_file = str(out / "run.h5")
    mine = tmp_path / "mine"
    mine.mkdir()
    example = str(Path(__file__).resolve().parents[1] / "examples" / "column_collapse.toml")
    Stepper(column_2d(40, mu=0.4), 1e-3, fclib_dir=tmp_path, fclib_steps=[1]).run(2)
    problem = str(tmp_path / "step_000001.hdf5")
    cases = [
        (["plot", run_file, "energy", "--out"], mine / "fig.png", "--out"),
        (["show", example, "--out"], mine / "scene.png", "--out"),
        (["export", "vtu", run_file, "--out"], mine, "--out"),
        (["problem", "solve", problem, "--save-solution"], mine / "a.npz", "--save-solution"),
    ]
    for args, target, option in cases:
        kept = target / "grains.pvd" if target.is_dir() else target
        kept.write_text("mine")
        result = runner.invoke(app, [*args, str(target)])
        assert result.exit_code == 2, (args, result.output)
        assert result.output.strip() == f"error: {option} {kept} exists: --force replaces it"
        assert kept.read_text() == "mine"
        result = runner.invoke(app, [*args, str(target), "--force"])
        assert result.exit_code == 0, (args, result.output)
        assert kept.read_bytes() != b"mine"
    # The file written is the one checked: a figure's suffix added, a series' frames.
    (mine / "bare.png").write_text("mine")
    result = runner.invoke(app, ["plot", run_file, "energy", "--out", str(mine / "bare")])
    assert result.output.strip() == f"error: --out {mine / 'bare.png'} exists: --force replaces it"
    frames = tmp_path / "frames"
    frames.mkdir()
    (frames / "grains_000000.vtu").write_text("mine")
    result = runner.invoke(app, ["export", "vtu", run_file, "--out", str(frames)])
    assert result.exit_code == 2 and "grains_000000.vtu exists" in result.output
    assert (frames / "grains_000000.vtu").read_text() == "mine"
    # The defaults are made again without --force.
    for args in (["plot", run_file, "energy"], ["export", "vtu", run_file]):
        assert runner.invoke(app, args).exit_code == 0
        result = runner.invoke(app, args)
        assert result.exit_code == 0, result.output


def test_file_system_refusals_are_one_line_errors(tmp_path):
    """A file where a folder is needed, or a folder where a file is, anywhere under any
    command, ends in one line and exit 2, not a traceback; the input run is never the
    output."""
    out = tmp_path / "r"
    assert _run("--steps", "2", "--out", str(out)).exit_code == 0
    run_file = str(out / "run.h5")
    (tmp_path / "afile").write_text("x")
    scene = tmp_path / "scene.toml"
    scene.write_text('builder = "stack"\n[params]\nn_grains = 3\n')
    for args, message in (
        (["export", "vtu", run_file, "--out", str(tmp_path / "afile")], "a file is in the way"),
        (["plot", str(out), "energy"], f"{out} is a folder, not a run file"),
        (["export", "fclib", run_file, "--out", run_file, "--force"], "is the run file itself"),
        (["plot", run_file, "energy", "--out", str(tmp_path / "p.txt")], "as '.txt'"),
        (["bench", "readme", "--out", str(tmp_path / "afile")], "is a file"),
        (["plot", run_file, "energy", "--out", str(tmp_path)], f"{tmp_path} is a folder"),
        (["plot", run_file, "energy", "--out", "."], "error: . is a folder"),
        (["plot", run_file, "energy", "--out", ""], "error: . is a folder"),
        (["plot", run_file, "movie", "--out", ".."], "error: .. is a folder"),
        (["show", str(scene), "--out", str(out)], f"{out} is a folder"),
    ):  # fmt: skip
        result = runner.invoke(app, args)
        assert result.exit_code == 2, (args, result.output)
        assert len(result.output.strip().splitlines()) == 1, (args, result.output)
        assert message in result.output, (args, result.output)
    assert _steps(out) == 2  # the run file is still the run
    # Without a suffix a figure is a PNG, and the path said is the path written.
    result = runner.invoke(app, ["plot", run_file, "energy", "--out", str(tmp_path / "e")])
    assert result.exit_code == 0 and result.output.strip() == f"wrote {tmp_path / 'e.png'}"
    assert (tmp_path / "e.png").exists()


def test_an_error_from_the_system_anywhere_is_one_line(tmp_path, monkeypatch):
    """The root command turns an OSError no command foresaw into its one line."""
    import errno

    import cocd.plots

    def refused(*args, **kwargs):
        raise PermissionError(errno.EACCES, "Permission denied", str(tmp_path / "x.png"))

    out = tmp_path / "r"
    assert _run("--steps", "1", "--out", str(out)).exit_code == 0
    monkeypatch.setattr(cocd.plots, "plot_run", refused)
    result = runner.invoke(app, ["plot", str(out / "run.h5"), "energy"])
    assert result.exit_code == 2
    assert result.output.strip() == f"error: Permission denied: '{tmp_path / 'x.png'}'"


def test_a_readme_cocd_did_not_write_is_not_replaced(tmp_path):
    """`cocd bench readme` and every study refuse, before any work, an --out whose
    README.md is someone else's; one cocd wrote is rebuilt."""
    from cocd.bench.report import README_MARK, write_readme

    (tmp_path / "README.md").write_text("# Mine\n\nmy notes\n")
    result = runner.invoke(app, ["bench", "readme", "--out", str(tmp_path)])
    assert result.exit_code == 2 and "was not written by cocd" in result.output
    result = runner.invoke(app, ["bench", "hard", "--cases", "zero_gap", "--out", str(tmp_path)])
    assert result.exit_code == 2 and "was not written by cocd" in result.output
    assert (tmp_path / "README.md").read_text() == "# Mine\n\nmy notes\n"
    assert not list(tmp_path.glob("*.csv"))
    ours = tmp_path / "ours"
    ours.mkdir()
    write_readme(ours, heading="Ours")
    assert README_MARK in (ours / "README.md").read_text()
    assert runner.invoke(app, ["bench", "readme", "--out", str(ours)]).exit_code == 0


def test_bad_study_options_are_refused_before_any_work(tmp_path):
    """Tolerances, time limits and memory caps are positive; a share of the energy is
    below 1; a list of names does not repeat one."""
    for args in (
        ["bench", "backends", "--tol", "0"],
        ["bench", "iterative", "--time-limit", "nan"],
        ["bench", "backends", "--memory-gb", "-1"],
        ["validate", "nscd", "--nscd-tol", "0"],
        ["validate", "nscd", "--nscd-max-iter", "0"],
    ):
        result = runner.invoke(app, [*args, "--out", str(tmp_path)])
        assert result.exit_code == 2, (args, result.output)
        assert "must be a finite number > 0" in result.output, (args, result.output)
        assert not list(tmp_path.glob("*.csv"))
    result = runner.invoke(app, ["bench", "stability", "--threshold", "2", "--out", str(tmp_path)])
    assert result.exit_code == 2 and "below 1" in result.output
    args = ["validate", "nscd", "--nscd-fallback", "nosuch", "--out", str(tmp_path)]
    result = runner.invoke(app, args)
    assert result.exit_code == 2 and "unknown solver 'nosuch'" in result.output
    assert not list(tmp_path.glob("runs/*"))
    args = ["bench", "hard", "--cases", "zero_gap,zero_gap", "--out", str(tmp_path)]
    result = runner.invoke(app, args)
    assert result.exit_code == 2 and "--cases repeats 'zero_gap'" in result.output


def test_options_one_would_ignore_are_refused(tmp_path, monkeypatch):
    """An option and its old name given together, or an option for a case the others
    leave out, is a one-line error: never one of them silently dropped."""
    from cocd.errors import CocdError
    from cocd.studies import scaling, table1

    def work(*args, **kwargs):
        raise CocdError("reached the work")

    monkeypatch.setattr(scaling, "Results", work)
    monkeypatch.setattr(table1, "Results", work)
    out = ["--out", str(tmp_path)]
    for args, message in (
        (["bench", "stability", "--tols", "1e-3", "--eps-list", "1e-4"],
         "--tols and --eps-list name one option: give one of them"),
        (["bench", "scaling", "--packings", "column", "--n3d-box", "30"],
         "--n3d-box sizes the box packing, which --packings leaves out"),
        (["bench", "table1", "--cases", "2d", "--scale-3d", "0.5"],
         "--scale-3d scales the 3D case, which --cases leaves out"),
        (["bench", "table1", "--cases", "2d,3d", "--scale-3d", "0.5"], "reached the work"),
    ):  # fmt: skip
        result = runner.invoke(app, [*args, *out])
        assert result.exit_code == 2, (args, result.output)
        assert result.output.strip() == f"error: {message}", args
    # The old name alone still works (it is read as the new one).
    monkeypatch.setattr("cocd.bench.study.writable_folder", work)
    result = runner.invoke(app, ["bench", "stability", "--eps-list", "0", *out])
    assert result.output.strip() == "error: --eps-list must be positive numbers, got '0'"


def test_a_run_still_writing_its_first_frame_is_not_taken_for_an_empty_one(tmp_path):
    """A run file another process writes (or a killed run left) is not replaced by a
    plain run, even before its first step reaches the disk."""
    import subprocess
    import sys

    from cocd.runs import holds_no_step

    failed = tmp_path / "failed"
    _run("--steps", "2", "--out", str(failed), "--solver", "clarabel:no_such=1")
    path = failed / "run.h5"
    assert holds_no_step(path)
    writer = (  # opens the file as a run's writer does, and holds it
        "import h5py, sys, time\n"
        f"f = h5py.File({str(path)!r}, 'a', libver='latest')\n"
        "f.swmr_mode = True\nprint('open', flush=True)\ntime.sleep(60)\n"
    )
    child = subprocess.Popen([sys.executable, "-c", writer], stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout is not None and child.stdout.readline().strip() == "open"
        assert not holds_no_step(path)
        result = _run("--steps", "2", "--out", str(failed))
        assert result.exit_code == 2 and "already holds a run" in result.output
    finally:
        child.kill()
        child.wait()


def test_bad_solver_options_are_refused_before_a_run_file_is_made(tmp_path):
    scene = tmp_path / "scene.toml"
    scene.write_text(
        'builder = "stack"\n[params]\nn_grains = 3\n[run]\nsolver = "ipm"\n'
        "solver_options = {max_iter = -5}\n"
    )
    out = tmp_path / "out"
    result = _run(str(scene), "--steps", "2", "--out", str(out))
    assert result.exit_code == 2
    assert result.output.strip().splitlines()[-1] == (
        "error: solver_options cannot set 'max_iter', which the stepper gives the backend"
    )
    assert not (out / "run.h5").exists()
