"""Scene files, run files, resume after a kill, ParaView export and plots."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from cocd.cli import app
from cocd.config import BUILDERS, ConfigError, build_scene, load_config, parse_config
from cocd.errors import OverlapError
from cocd.io.runfile import RunFile, RunFileError
from cocd.runs import run

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = sorted((ROOT / "examples").glob("*.toml"))
runner = CliRunner()

SCENE = """
builder = "column_2d"

[params]
n_grains = 60
mu = 0.3

[run]
dt = 1e-3
steps = {steps}
solver = "clarabel"
tol = 1e-9
frame_every = {every}
"""


def _scene_file(tmp_path: Path, steps: int = 20, every: int = 5) -> Path:
    path = tmp_path / "scene.toml"
    path.write_text(SCENE.format(steps=steps, every=every))
    return path


# -- scene files ---------------------------------------------------------------------------
def test_one_example_per_builder_and_each_runs(tmp_path):
    names = {load_config(p).builder for p in EXAMPLES}
    assert names == set(BUILDERS)
    assert len(EXAMPLES) == len(BUILDERS)
    for path in EXAMPLES:
        config = load_config(path)
        data = config.model_dump()
        data["run"].update(steps=2, until=None, frame_every=1)
        summary = run(parse_config(data, str(path)), tmp_path / path.stem)
        assert summary.steps == 2 and summary.frames == 3, path.name
        with RunFile(summary.path) as rf:
            assert rf.n_frames == 3 and list(rf.steps) == [0, 1, 2]
            assert rf.config["builder"] == config.builder


def test_seed_run_files_run_at_a_small_size(tmp_path):
    # The seeds' full-size runs (examples/seed/) take hours: check that each file is
    # valid and runs, with its grain count cut down.
    seed_files = sorted((ROOT / "examples" / "seed").glob("*.toml"))
    assert seed_files
    for path in seed_files:
        data = load_config(path).model_dump()
        data["params"].pop("diameter", None)
        data["params"]["n_grains"] = 60
        data["run"].update(steps=1, until=None, frame_every=1)
        summary = run(parse_config(data, str(path)), tmp_path / path.stem)
        assert summary.steps == 1 and summary.frames == 2, path.name


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('builder = "column_2d"\ncolour = 3\n', "scene.toml: colour: unknown key"),
        ('builder = "column_2d"\n[run]\nsteps = 1\nfoo = 2\n', "scene.toml: run.foo: unknown key"),
        ('builder = "column_2d"\n[run]\ndt = "fast"\n', "scene.toml: run.dt: Input should be"),
        ('builder = "column_2d"\n[run]\ndt = -1e-3\n', "run.dt: Input should be greater than 0"),
        ('builder = "column_2d"\n[run]\nframe_every = 0\n', "run.frame_every: Input should be"),
        ('builder = "column_2d"\n[params]\nn_grains = "many"\n', "params.n_grains: Input should"),
        ('builder = "column_2d"\n[params]\nradius = 1\n', "params.radius: unknown argument"),
        ('builder = "column_2d"\n[params]\nn_grains = -5\n', "n_grains must be an integer >= 1"),
        ('builder = "stack"\n[params]\nn_grains = 2\nradius = -0.01\n', "radius"),
        ('builder = "disc_tower"\n', "builder: unknown builder 'disc_tower'"),
        ("[params]\nn = 3\n", "builder: Field required"),
        ('builder = "column_2d"\n[run\n', "not valid TOML"),
    ],
)
def test_bad_scene_files_give_one_line_and_status_2(tmp_path, text, message):
    path = tmp_path / "scene.toml"
    path.write_text(text)
    result = runner.invoke(app, ["run", str(path), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.output
    assert message in lines[0]
    with pytest.raises(ConfigError):
        build_scene(load_config(path), str(path))


def test_missing_scene_file_is_named(tmp_path):
    result = runner.invoke(app, ["run", str(tmp_path / "nowhere.toml")])
    assert result.exit_code == 2
    assert result.output.strip() == f"error: scene file {tmp_path / 'nowhere.toml'} does not exist"


def test_resolved_configuration_holds_every_default():
    config = parse_config({"builder": "column_2d", "params": {"n_grains": 10}})
    resolved = config.resolved()
    assert resolved["params"]["n_grains"] == 10 and resolved["params"]["aspect"] == 0.7
    assert resolved["run"]["solver"] == "clarabel" and resolved["run"]["frame_every"] == 10


# -- run files -----------------------------------------------------------------------------
def test_run_file_holds_frames_contacts_and_statistics(tmp_path):
    scene = _scene_file(tmp_path, steps=12, every=5)
    result = runner.invoke(app, ["run", str(scene), "--out", str(tmp_path / "out")])
    assert result.exit_code == 0, result.output
    with RunFile(tmp_path / "out" / "run.h5") as rf:
        assert list(rf.steps) == [0, 5, 10, 12]
        assert np.allclose(rf.times, [0.0, 0.005, 0.010, 0.012], rtol=0, atol=1e-12)
        assert rf.n_grains == 60 and rf.dim == 2
        stats = rf.stats()
        assert list(stats.step) == list(range(1, 13))
        assert (stats.ccp_residual <= 1e-9).all()
        first, last = rf.frame(0), rf.frame(-1)
        assert first.nc == 0 and last.nc == stats.nc.iloc[-1]
        assert last.impulse.shape == (last.nc, 2)
        scene = rf.scene(-1)
        assert np.array_equal(scene.positions, last.positions)
        assert scene.time == pytest.approx(0.012)
        assert rf.scene_file == scene_path_text(tmp_path)
    assert (tmp_path / "out" / "stats.csv").exists()


def test_run_file_impulses_of_a_resting_stack_carry_the_weight(tmp_path):
    config = parse_config(
        {
            "builder": "stack",
            "params": {"n_grains": 3, "dim": 2, "radius": 0.005},
            "run": {"steps": 3, "frame_every": 1, "tol": 1e-10},
        }
    )
    run(config, tmp_path)
    with RunFile(tmp_path / "run.h5") as rf:
        frame = rf.frame(-1)
        mass = 2500.0 * np.pi * 0.005**2
        floor = frame.j < 0
        assert floor.sum() == 1 and frame.nc == 3
        # Bottom contact: three weights; the others two and one (impulses over dt = 1 ms).
        carried = np.sort(frame.impulse[:, 0]) / (mass * 9.81 * 1e-3)
        assert np.allclose(carried, [1.0, 2.0, 3.0], rtol=1e-6)
        assert frame.impulse[floor, 0][0] / (mass * 9.81e-3) == pytest.approx(3.0, rel=1e-6)
        assert np.allclose(frame.velocities, 0.0, atol=1e-9)


def scene_path_text(tmp_path: Path) -> str:
    return (tmp_path / "scene.toml").read_text()


def test_resume_continues_a_shorter_run_and_later_until(tmp_path):
    full = parse_config(
        {"builder": "column_2d", "params": {"n_grains": 40}, "run": {"steps": 14, "frame_every": 4}}
    )
    short = parse_config(
        {"builder": "column_2d", "params": {"n_grains": 40}, "run": {"steps": 6, "frame_every": 4}}
    )
    run(full, tmp_path / "a")
    run(short, tmp_path / "b")
    summary = run(full, tmp_path / "b", resume=True)
    assert summary.resumed_from_step == 6 and summary.steps == 14
    with RunFile(tmp_path / "a" / "run.h5") as a, RunFile(tmp_path / "b" / "run.h5") as b:
        assert list(b.steps) == [0, 4, 6, 8, 12, 14]
        assert np.array_equal(a.frame(-1).positions, b.frame(-1).positions)
        assert np.array_equal(a.frame(-1).velocities, b.frame(-1).velocities)
        assert np.array_equal(a.frame(-1).impulse, b.frame(-1).impulse)
        assert list(b.stats().step) == list(range(1, 15))


def test_a_run_file_says_which_machine_made_which_steps(tmp_path, monkeypatch):
    """A run's steps are timed on the machine that made them: the run file records it,
    and a run resumed on another machine records where that one took it on; a file
    written before machines were recorded says so ("") for its first steps."""
    import cocd.io.runfile as runfile
    from cocd.provenance import machine_name

    def config(steps):
        return parse_config({"builder": "column_2d", "params": {"n_grains": 30},
                             "run": {"steps": steps, "frame_every": 2}})  # fmt: skip

    run(config(4), tmp_path)
    with RunFile(tmp_path / "run.h5") as rf:
        assert rf.machines == [(1, machine_name())]
    run(config(6), tmp_path, resume=True)  # the same machine: nothing to add
    with RunFile(tmp_path / "run.h5") as rf:
        assert rf.machines == [(1, machine_name())]
    here, other = machine_name(), "Other CPU, 64 cores"

    def resume_on(machine, steps):
        monkeypatch.setattr(runfile, "machine_name", lambda: machine)
        run(config(steps), tmp_path, resume=True)
        with RunFile(tmp_path / "run.h5") as rf:
            return rf.machines

    assert resume_on(other, 8) == [(1, here), (7, other)]
    # Opened again on a third machine with no step left to make: it made none, and the
    # machine that takes the run on next is recorded from the next step.
    assert resume_on("Third CPU, 8 cores", 8) == [(1, here), (7, other), (9, "Third CPU, 8 cores")]
    assert resume_on(here, 10) == [(1, here), (7, other), (9, here)]
    with h5py.File(tmp_path / "run.h5", "a") as f:
        f.attrs["machines"] = "not a list"
    with RunFile(tmp_path / "run.h5") as rf:  # unreadable: not recorded, the run still read
        assert rf.machines == [] and rf.n_frames > 0
    with h5py.File(tmp_path / "run.h5", "a") as f:
        del f.attrs["machines"]
    assert resume_on(other, 12) == [(1, ""), (11, other)]


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="needs 2 cores to give a run fewer")
def test_the_machine_says_when_a_run_had_fewer_threads_than_cores(monkeypatch):
    """Runs made several at once, each on one thread, take longer a step: the machine
    recorded with their steps says so."""
    import numba

    from cocd.provenance import cpu_name, machine_name

    monkeypatch.setattr(numba, "get_num_threads", lambda: 1)
    assert machine_name() == f"{cpu_name()}, {os.cpu_count()} cores, on 1 thread"
    monkeypatch.setattr(numba, "get_num_threads", lambda: os.cpu_count())
    assert machine_name() == f"{cpu_name()}, {os.cpu_count()} cores"


def test_resume_refuses_another_scene_or_time_step(tmp_path):
    base = {"builder": "column_2d", "params": {"n_grains": 30}, "run": {"steps": 2}}
    run(parse_config(base), tmp_path)
    other = {**base, "params": {"n_grains": 31}}
    with pytest.raises(RunFileError, match="another scene"):
        run(parse_config(other), tmp_path, resume=True)
    finer = {**base, "run": {"steps": 2, "dt": 5e-4}}
    with pytest.raises(RunFileError, match=r"run.dt was 0.001, now 0.0005"):
        run(parse_config(finer), tmp_path, resume=True)
    other_solver = {**base, "run": {"steps": 2, "solver": "scs"}}
    with pytest.raises(RunFileError, match=r"run.solver was 'clarabel', now 'scs'"):
        run(parse_config(other_solver), tmp_path, resume=True)
    # A larger iteration cap (after a step that hit the smaller one) is allowed.
    capped = {**base, "run": {"steps": 3, "max_iter": 500}}
    assert run(parse_config(capped), tmp_path, resume=True).steps == 3
    # So is a fallback added at the end of the list, not another list.
    longer = {**base, "run": {"steps": 4, "max_iter": 500, "fallback": ["scs"]}}
    assert run(parse_config(longer), tmp_path, resume=True).steps == 4
    other = {**base, "run": {"steps": 5, "max_iter": 500, "fallback": ["ecos"]}}
    with pytest.raises(RunFileError, match=r"run.fallback was \['scs'\], now \['ecos'\]"):
        run(parse_config(other), tmp_path, resume=True)
    # A refused resume (an end before the file's) leaves the file's configuration alone.
    short = {**base, "run": {"steps": 1, "max_iter": 500, "fallback": ["scs", "ecos"]}}
    with pytest.raises(RunFileError, match="already holds 4 steps"):
        run(parse_config(short), tmp_path, resume=True)
    with RunFile(tmp_path / "run.h5") as rf:
        assert rf.config["run"]["fallback"] == ["scs"] and rf.config["run"]["steps"] == 4


def test_resume_accepts_the_runs_own_small_overlaps(tmp_path):
    """A state the run reached may overlap by its solver's tolerance (more than an
    initial scene may): resuming from it is not refused."""
    base = {"builder": "column_2d", "params": {"n_grains": 30}, "run": {"steps": 2}}
    run(parse_config(base), tmp_path)
    with h5py.File(tmp_path / "run.h5", "r+") as f:
        x = f["frames/positions"][-1]
        r = f["scene/radii"][:]
        # Push grain 1 into grain 0 by 1e-4 of its radius (the initial limit is 1e-6).
        d = x[1] - x[0]
        gap = np.linalg.norm(d) - r[0] - r[1]
        x[1] -= d / np.linalg.norm(d) * (gap + 1e-4 * min(r[0], r[1]))
        f["frames/positions"][-1] = x
    with RunFile(tmp_path / "run.h5") as rf, pytest.raises(OverlapError):
        parse_config(base).stepper(rf.scene(-1))
    longer = {**base, "run": {"steps": 4}}
    assert run(parse_config(longer), tmp_path, resume=True).steps == 4


def test_not_a_run_file_is_named(tmp_path):
    path = tmp_path / "run.h5"
    with h5py.File(path, "w") as f:
        f["x"] = 1
    with pytest.raises(RunFileError, match="not a cocd run file"):
        RunFile(path)
    (tmp_path / "junk.h5").write_bytes(b"not hdf5 at all")
    result = runner.invoke(app, ["plot", str(tmp_path / "junk.h5"), "stats"])
    assert result.exit_code == 2 and "not a readable HDF5 file" in result.output


def _complete_frames(path: Path) -> int:
    try:
        with RunFile(path, live=True) as rf:
            return rf.n_frames
    except RunFileError:
        return 0


def test_run_killed_mid_way_resumes_to_the_uninterrupted_state(tmp_path):
    scene = _scene_file(tmp_path, steps=80, every=5)
    # The uninterrupted run, in this process.
    ref = runner.invoke(app, ["run", str(scene), "--out", str(tmp_path / "ref")])
    assert ref.exit_code == 0, ref.output
    # The same run in a child process, killed (SIGKILL) once it has written a few frames.
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "cocd", "run", str(scene), "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    try:
        while _complete_frames(out / "run.h5") < 4:
            assert proc.poll() is None, proc.stderr.read() if proc.stderr else ""
            assert time.monotonic() < deadline, "the child wrote no frames"
            time.sleep(0.02)
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    assert proc.returncode == -signal.SIGKILL
    with RunFile(out / "run.h5") as rf:
        killed_at = int(rf.steps[-1])
        kept = rf.frame(-1).positions.copy()
    assert 15 <= killed_at < 80, "the child finished before it was killed"
    # Resumed: every frame present once, the last complete frame untouched, and
    # the final state equal to the uninterrupted run's.
    res = runner.invoke(app, ["run", str(scene), "--out", str(out), "--resume"])
    assert res.exit_code == 0, res.output
    assert f"resumed from step {killed_at}" in res.output
    with RunFile(tmp_path / "ref" / "run.h5") as a, RunFile(out / "run.h5") as b:
        assert list(b.steps) == list(a.steps) == list(range(0, 81, 5))
        k = list(b.steps).index(killed_at)
        assert np.array_equal(b.frame(k).positions, kept)
        for name in ("positions", "velocities", "angular_velocities", "impulse", "keys"):
            assert np.array_equal(getattr(a.frame(-1), name), getattr(b.frame(-1), name)), name
        sa, sb = a.stats(), b.stats()
        assert list(sb.step) == list(range(1, 81))
        assert np.array_equal(sa.iterations, sb.iterations)


# -- ParaView export and plots --------------------------------------------------------------
def _vtu(path: Path) -> ET.Element:
    piece = ET.parse(path).getroot().find("UnstructuredGrid/Piece")
    assert piece is not None
    return piece


def test_vtu_export_is_read_back(tmp_path):
    scene = _scene_file(tmp_path, steps=10, every=5)
    assert runner.invoke(app, ["run", str(scene), "--out", str(tmp_path)]).exit_code == 0
    result = runner.invoke(app, ["export", "vtu", str(tmp_path / "run.h5"), "--every", "2"])
    assert result.exit_code == 0, result.output
    vtu = tmp_path / "vtu"
    with RunFile(tmp_path / "run.h5") as rf:
        assert rf.n_frames == 3  # steps 0, 5, 10: frames 0 and 2 (every 2), and the last
        frames = [rf.frame(k) for k in (0, 2)]
        n = rf.n_grains
        radii = rf.radii
    for name in ("grains", "contacts"):
        entries = ET.parse(vtu / f"{name}.pvd").getroot().findall("Collection/DataSet")
        assert [e.get("file") for e in entries] == [f"{name}_000000.vtu", f"{name}_000002.vtu"]
        assert [float(e.get("timestep", "nan")) for e in entries] == pytest.approx([0.0, 0.01])
    import meshio

    for frame in frames:
        grains = _vtu(vtu / f"grains_{frame.index:06d}.vtu")
        assert int(grains.get("NumberOfPoints", -1)) == n
        names = {a.get("Name") for a in grains.findall("PointData/DataArray")}
        assert {"radius", "velocity", "speed", "angular_velocity", "fixed", "id"} <= names
        contacts = _vtu(vtu / f"contacts_{frame.index:06d}.vtu")
        assert int(contacts.get("NumberOfCells", -1)) == frame.nc
        names = {a.get("Name") for a in contacts.findall("CellData/DataArray")}
        assert {"normal_impulse", "normal_force", "tangential_impulse", "gap"} <= names
    mesh = meshio.read(vtu / "grains_000002.vtu")
    assert np.allclose(mesh.point_data["radius"], radii)
    assert np.allclose(mesh.points[:, :2], frames[1].positions)
    assert np.allclose(mesh.point_data["speed"], np.linalg.norm(frames[1].velocities, axis=1))
    lines = meshio.read(vtu / "contacts_000002.vtu")
    assert lines.cells[0].type == "line" and len(lines.cells[0].data) == frames[1].nc
    assert np.allclose(lines.cell_data["normal_impulse"][0], frames[1].impulse[:, 0])
    # A wall contact's segment ends on the wall: here the floor, y = 0.
    wall = np.flatnonzero(frames[1].j < 0)
    assert wall.size
    ends = lines.points[lines.cells[0].data[wall, 1]]
    floor = frames[1].normal[wall, 1] > 0.9
    assert np.allclose(ends[floor, 1], 0.0, atol=1e-9)


@pytest.mark.parametrize("kind", ["profiles", "front", "energy", "stats"])
def test_plots_are_written(tmp_path, kind):
    scene = _scene_file(tmp_path, steps=10, every=5)
    assert runner.invoke(app, ["run", str(scene), "--out", str(tmp_path)]).exit_code == 0
    result = runner.invoke(app, ["plot", str(tmp_path / "run.h5"), kind])
    assert result.exit_code == 0, result.output
    assert (tmp_path / f"{kind}.png").stat().st_size > 10_000


def test_unknown_plot_and_missing_run_file_are_named(tmp_path):
    result = runner.invoke(app, ["plot", str(tmp_path / "run.h5"), "stats"])
    assert result.exit_code == 2
    assert result.output.strip() == f"error: run file {tmp_path / 'run.h5'} does not exist"
    scene = _scene_file(tmp_path, steps=2, every=1)
    assert runner.invoke(app, ["run", str(scene), "--out", str(tmp_path)]).exit_code == 0
    result = runner.invoke(app, ["plot", str(tmp_path / "run.h5"), "colours"])
    assert result.exit_code == 2
    assert "unknown plot 'colours'; one of profiles, front, energy, stats" in result.output


def test_front_plot_over_an_erodible_bed_follows_the_flow_not_the_layer(tmp_path):
    # The README's example: a column on a 1 cm erodible layer 4 R0 long. The main
    # mass's foremost grain is the layer's end (0.8 m); the flow's front starts at
    # the column's foot (R0 = 0.2 m) and moves on smoothly.
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from cocd.plots import _front

    example = Path(__file__).resolve().parents[1] / "examples" / "column_collapse.toml"
    args = ["run", str(example), "--until", "0.1", "--out", str(tmp_path)]
    assert runner.invoke(app, args).exit_code == 0
    with RunFile(tmp_path / "run.h5") as rf:
        fig, ax = _front(rf, plt)
        d = 2.0 * float(rf.radii.mean())
    plt.close(fig)
    front = np.asarray(ax.lines[0].get_ydata())
    assert front[0] == pytest.approx(0.2, abs=2 * d)
    assert (front < 0.4).all()
    assert (np.diff(front) >= -1.01 * d).all()
    assert front[-1] > front[0] + d
    assert "erodible" in ax.get_title()


def test_a_parameter_added_to_a_builder_keeps_older_runs_resumable(tmp_path):
    """A run file written before its builder gained a parameter (whose default keeps the
    old scene) still resumes; a value other than the default is another scene."""
    import copy

    from cocd.config import RunConfig
    from cocd.runs import _check_same

    config = RunConfig.model_validate(
        {"builder": "column_collapse", "params": {"dim": 2, "n_grains": 30},
         "run": {"dt": 1e-3, "steps": 2}}
    )  # fmt: skip
    new = config.resolved()
    assert new["params"]["mu_side"] is None
    old = copy.deepcopy(new)
    del old["params"]["mu_side"]  # as written before column_collapse had mu_side
    _check_same(old, new, tmp_path / "run.h5")
    _check_same(new, old, tmp_path / "run.h5")
    old["params"]["mu_side"] = 0.3
    with pytest.raises(RunFileError, match="another scene"):
        _check_same(old, new, tmp_path / "run.h5")
    del old["params"]["mu_side"]
    old["params"]["no_such_parameter"] = 1  # not a parameter of today's builder
    with pytest.raises(RunFileError, match="another scene"):
        _check_same(old, new, tmp_path / "run.h5")


# -- one step exported as a problem ---------------------------------------------------------
def test_a_step_exported_from_a_run_file_is_the_step_the_run_took(tmp_path):
    """Step 15 is taken again from the frame of step 10 (five steps replayed): the FCLib
    file holds its problem with the answer the run wrote in its frame of step 15."""
    from cocd.io import read_problem
    from cocd.io.fclib import read_fclib_solution

    scene = _scene_file(tmp_path, steps=20, every=5)
    assert runner.invoke(app, ["run", str(scene), "--out", str(tmp_path)]).exit_code == 0
    run_file = str(tmp_path / "run.h5")
    res = runner.invoke(app, ["export", "fclib", run_file, "--step", "15"])
    assert res.exit_code == 0, res.output
    path = tmp_path / "step_000015.hdf5"
    with RunFile(run_file) as rf:
        frame = rf.frame(list(rf.steps).index(15))
        stats = rf.stats().set_index("step")
    assert "taken again from the frame of step 10:" in res.output
    assert f"{frame.nc} contacts" in res.output
    assert f"{stats.iterations[15]} iterations (the run: {frame.nc} contacts" in res.output
    problem = read_problem(path)
    solution = read_fclib_solution(path)
    assert problem.nc == frame.nc == stats.nc[15] and solution is not None
    r = np.asarray(solution.r).reshape(frame.nc, -1)
    scale = np.abs(frame.impulse).max()
    assert np.allclose(r, frame.impulse, rtol=0.0, atol=1e-9 * scale)
    from cocd.residuals import ccp_residual

    assert ccp_residual(problem.conic, r) < 1e-7  # the run's tol is 1e-9
    # Its file is not replaced without --force; steps outside the run are named.
    again = runner.invoke(app, ["export", "fclib", run_file, "--step", "15"])
    assert again.exit_code == 2 and "--force replaces it" in again.output
    assert "error: the output " in again.output and "--out" not in again.output  # none given
    forced = runner.invoke(app, ["export", "fclib", run_file, "--step", "15", "--force"])
    assert forced.exit_code == 0, forced.output
    for step in ("0", "21"):
        bad = runner.invoke(app, ["export", "fclib", run_file, "--step", step])
        assert bad.exit_code == 2 and "--step must be between 1 and 20" in bad.output
    # Each step from the last frame before it: step 10 from that of step 5, step 1 from
    # the initial one; with no --step, the last step.
    for step, start in ((1, 0), (10, 5), (11, 10)):
        out = str(tmp_path / f"s{step}.hdf5")
        res = runner.invoke(app, ["export", "fclib", run_file, "--step", str(step), "--out", out])
        assert res.exit_code == 0, res.output
        assert f"step {step} (t = " in res.output
        assert f"taken again from the frame of step {start}:" in res.output
        assert read_problem(out).nc == stats.nc[step]
    last = runner.invoke(app, ["export", "fclib", run_file, "--out", str(tmp_path / "x.hdf5")])
    assert last.exit_code == 0 and "step 20 (t = " in last.output
    # A folder for --out, and a run file whose configuration this cocd cannot run.
    folder = runner.invoke(app, ["export", "fclib", run_file, "--out", str(tmp_path)])
    assert folder.exit_code == 2 and "is a folder, not a file" in folder.output
    with h5py.File(run_file, "a") as f:
        config = json.loads(f.attrs["config"])
        config["run"]["no_such_option"] = 1
        f.attrs["config"] = json.dumps(config)
    bad = runner.invoke(app, ["export", "fclib", run_file, "--out", str(tmp_path / "y.hdf5")])
    assert bad.exit_code == 2 and "its configuration is not one this cocd runs" in bad.output
    assert "no_such_option" in bad.output and "Traceback" not in bad.output


def test_a_frame_pointer_of_infinity_is_a_damaged_run_file(tmp_path):
    # Found by the fuzzing of run files: an infinite row pointer overflowed to int.
    config = parse_config(
        {"builder": "column_2d", "params": {"n_grains": 20},
         "run": {"steps": 2, "frame_every": 1, "solver": "clarabel"}},
        "scene.toml",
    )  # fmt: skip
    path = run(config, tmp_path).path
    with h5py.File(path, "r+") as f:
        del f["contacts/ptr"]
        f["contacts/ptr"] = np.array([np.inf, 1.0, 2.0])
    with RunFile(path) as rf, pytest.raises(RunFileError, match="damaged or incomplete"):
        rf.frame(0)
