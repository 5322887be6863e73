"""Runs: a scene file in, a run file out, resumable after a crash.

:func:`run` builds the scene a :class:`~cocd.config.RunConfig` describes,
advances it with a :class:`~cocd.stepper.Stepper` and writes a run file
(:mod:`cocd.io.runfile`): a frame every ``frame_every`` steps (and the last
step), the statistics of every step. With ``resume=True`` it continues a run
file from its last complete frame; the steps it then takes are the ones the
uninterrupted run would have taken (same state, same warm start), so it ends
in the same final state.
"""

from __future__ import annotations

import os
import re
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cocd.config import RunConfig, build_scene, parse_config, same_params
from cocd.io.runfile import RunFile, RunFileError, RunWriter
from cocd.scene import Scene
from cocd.stepper import Stepper, StepRecord

__all__ = [
    "DERIVED_FILES",
    "RUN_FILE",
    "Progress",
    "RunSummary",
    "existing_run",
    "export_step",
    "measured_names",
    "run",
]

#: Name of the run file in the output folder.
RUN_FILE = "run.h5"
#: Files that cocd writes beside a run file from it (statistics, default plots):
#: replaced with the run (``force=True``), since they would describe the old one.
#: What ``cocd validate`` keeps of a finished run (:mod:`cocd.validate._common`).
MEASURED_FILES = ("measured.json", "measured.npz", "measured_stats.parquet")
#: The same, kept for another end of the run when it was measured at a new one
#: (``measured_to2.2s.json``, ...; :func:`measured_names`).
MEASURED_OTHER_ENDS = re.compile(r"measured_to[0-9.e+-]+s(\.json|\.npz|_stats\.parquet)")
DERIVED_FILES = (
    "stats.csv",
    "profiles.png",
    "front.png",
    "energy.png",
    "stats.png",
    *MEASURED_FILES,
)

#: Keys of the resolved configuration that may change when a run is resumed: the end,
#: and the iteration cap (a step that hit the cap failed and was not written, so a run
#: resumed with a larger cap takes the steps an uninterrupted run with it would have).
#: The fallback list may grow at its end, for the same reason: the steps taken before
#: never reached the backends added.
_RESUMABLE_CHANGES = {"until", "steps", "max_iter"}


@dataclass(frozen=True)
class Progress:
    """What a progress display is told after every step."""

    record: StepRecord
    done: int  # steps taken, this call and before
    total: int  # steps of the whole run
    elapsed: float  # wall seconds of this call
    steps_this_call: int


@dataclass(frozen=True)
class RunSummary:
    path: Path
    steps: int
    frames: int
    resumed_from_step: int
    wall_time: float


def run(
    config: RunConfig,
    out: str | Path,
    *,
    resume: bool = False,
    scene_file: str = "",
    progress: Callable[[Progress], None] | None = None,
    source: str = "scene file",
    scene: Scene | None = None,
    force: bool = False,
) -> RunSummary:
    """Advance the configured scene to its end, writing ``out/run.h5``.

    An existing run file in ``out`` is never replaced unless ``force`` is
    given, or it holds no step (a run that failed before its first, e.g. on a
    backend's bad option): then it goes, with the files cocd derived from it
    (:data:`DERIVED_FILES`). With ``resume`` the run continues from the file's
    last complete frame; the file's configuration must be the same as
    ``config`` except ``until``/``steps`` (a finished run resumed with a later
    ``until`` goes on). With ``resume`` and no run file in ``out`` (or one
    without a step), the run starts afresh. ``scene``: the scene the
    configuration builds, if already built (it is advanced in place).
    """
    path = Path(out) / RUN_FILE
    resolved = config.resolved()
    rc = config.run
    if resume and force:
        raise RunFileError("give resume or force, not both")
    empty = path.exists() and holds_no_step(path)  # nothing in it to lose
    if path.exists() and (empty or not resume):
        if not (force or empty):
            raise RunFileError(
                f"{Path(out)} already holds a run ({existing_run(path)}): "
                "--resume continues it, --force replaces it"
            )
        for name in (RUN_FILE, *DERIVED_FILES):
            (Path(out) / name).unlink(missing_ok=True)
        for stale in measured_other_ends(Path(out)):
            stale.unlink()
    stepper: Stepper | None = None
    if resume and path.exists():
        with RunFile(path) as old:
            _check_same(old.config, resolved, path)
            held = old.frame(-1)
        if config.n_steps() < held.step:  # refused before the file records the new config
            raise RunFileError(
                f"{Path(out)} already holds {held.step} steps to t = {held.time:.4g} s, past "
                f"the end asked for ({config.n_steps()} steps): give a later until, or more steps"
            )
        writer = RunWriter.resume(path, config=resolved)
        with RunFile(path) as rf:
            scene, records, previous, start_step = _state_at(rf, rf.n_frames - 1, rf.records())
            frames = rf.n_frames
    else:
        if scene is None:
            scene = build_scene(config, source)
        stepper = config.stepper(scene)  # bad settings are refused before a run file is made
        writer = RunWriter.create(path, scene, resolved, scene_file)
        records, previous, frames, start_step = [], None, 1, 0
    try:
        if stepper is None:
            stepper = config.stepper(scene, resumed=start_step > 0)
        stepper.restore(records, previous)
        total = config.n_steps()  # steps of the whole run, from t = 0
        begin = time.perf_counter()
        taken = 0
        while stepper.step_count < total:
            record = stepper.step()
            taken += 1
            writer.append_stats(record)
            if record.step % rc.frame_every == 0 or record.step == total:
                assert stepper.solution is not None
                writer.append_frame(record.step, scene, stepper.contacts, stepper.solution.p)
                frames += 1
            if progress is not None:
                progress(Progress(record, record.step, total, time.perf_counter() - begin, taken))
        wall = time.perf_counter() - begin
    finally:
        writer.close()
    return RunSummary(path, stepper.step_count, frames, start_step, wall)


def export_step(
    run_path: str | Path,
    step: int | None = None,
    out: str | Path | None = None,
    *,
    force: bool = False,
) -> tuple[Path, StepRecord, StepRecord, int]:
    """Take step ``step`` of a run again from its run file and write its problem, with
    the answer, as an FCLib global problem (:meth:`cocd.stepper.Stepper.export_step`).

    The step starts from the last frame before it, with that frame's contacts and
    impulses as its warm start; the steps between, if any, are taken again, as a
    resumed run takes them. ``step``: 1 to the run's last step (None: the last).
    ``out``: default ``step_<step>.hdf5`` beside the run file; an existing file is
    replaced only with ``force``. Returns the file, the step's statistics as taken
    again and as the run recorded them (their iterations and contacts agree, up to
    the rounding of sums over threads), and the step of the frame it started from.
    """
    from cocd.errors import CocdError
    from cocd.outputs import writable_file

    with RunFile(run_path) as rf:
        records = rf.records()
        done = len(records)
        if done == 0:
            raise CocdError(f"{run_path} holds no step yet")
        k = done if step is None else int(step)
        if not 1 <= k <= done:
            raise CocdError(
                f"--step must be between 1 and {done} (the steps of {run_path}), got {k}"
            )
        target = Path(run_path).parent / f"step_{k:06d}.hdf5" if out is None else Path(out)
        if target.exists() and os.path.samefile(target, run_path):
            raise CocdError(f"--out {target} is the run file itself: give another file")
        writable_file(target, "--out" if out is not None else "the output", replace=force)
        config = parse_config(
            rf.config, f"{run_path} (its configuration is not one this cocd runs)", params=False
        )
        frame = int(np.searchsorted(rf.steps, k - 1, side="right")) - 1
        scene, before, previous, start = _state_at(rf, frame, records)
    stepper = config.stepper(scene, resumed=start > 0)
    stepper.restore(before, previous)
    while stepper.step_count < k:
        stepper.step()
    return stepper.export_step(target), stepper.records[-1], records[k - 1], start


def _state_at(
    rf: RunFile, frame: int, records: list[StepRecord]
) -> tuple[Scene, list[StepRecord], tuple[Any, Any] | None, int]:
    """What a stepper continues from at saved frame ``frame``: the scene, the steps'
    statistics up to it (of ``records``, the run file's), the warm start of the next
    step (the frame's contact keys and impulses; None at the initial frame) and the
    frame's step."""
    held = rf.frame(frame)
    previous = (held.keys, held.impulse[:, : rf.contact_dim]) if held.step > 0 else None
    return rf.scene(frame), records[: held.step], previous, held.step


def holds_no_step(path: Path) -> bool:
    """Whether ``path`` is a readable run file without a step: a run that stopped before
    its first (a backend's bad option, say) holds nothing a new run would lose."""
    import h5py

    try:  # a file a run still writes (or a killed run) opens only live: not this one
        with h5py.File(path, "r"):
            pass
        with RunFile(path) as rf:
            return rf.n_frames == 1 and len(rf.records()) == 0
    except (RunFileError, OSError, KeyError, AttributeError):
        return False


def existing_run(path: Path) -> str:
    """A few words on the run file at ``path``: its steps and end time, or that it is damaged."""
    try:
        with RunFile(path) as rf:
            stats = rf.stats()
            if len(stats) == 0:
                return "no step yet"
            return f"{int(stats.step.iloc[-1])} steps to t = {float(stats.t.iloc[-1]):.4g} s"
    except (RunFileError, OSError, KeyError, AttributeError):
        return "a run file that cannot be read"


def measured_names(until: float | None = None) -> tuple[str, str, str]:
    """The files of a kept measurement (:data:`MEASURED_FILES`), or, with ``until``,
    those it is moved to when the run is measured at another end
    (``measured_to2.2s.json``, ...; :data:`MEASURED_OTHER_ENDS`)."""
    if until is None:
        return MEASURED_FILES
    tag = f"measured_to{until:.12g}s"
    return f"{tag}.json", f"{tag}.npz", f"{tag}_stats.parquet"


def measured_other_ends(folder: Path) -> list[Path]:
    """The files of :data:`MEASURED_OTHER_ENDS` in ``folder``."""
    return [
        f
        for f in folder.glob("measured_to*")
        if MEASURED_OTHER_ENDS.fullmatch(f.name) and f.is_file()
    ]


def _check_same(
    old: dict[str, Any], new: dict[str, Any], path: Path, *, earlier: bool = False
) -> None:
    """Refuse to resume a run file with another scene or other run parameters; with
    ``earlier``, to measure it at an earlier end as a run made with ``new`` (only its end
    may differ then)."""
    verb = "measure" if earlier else "resume"
    builder = str(new.get("builder"))
    if old.get("builder") != builder or not same_params(
        builder, old.get("params") or {}, new.get("params") or {}
    ):
        raise RunFileError(
            f"cannot {verb} {path}: it holds a run of another scene "
            f"({old.get('builder')} {old.get('params')})"
        )
    old_run, new_run = old.get("run", {}), new.get("run", {})
    for key in sorted(set(old_run) | set(new_run)):
        if key in ({"until", "steps"} if earlier else _RESUMABLE_CHANGES):
            continue
        if not earlier and key == "fallback" and _extends(old_run.get(key), new_run.get(key)):
            continue
        if not _equal(old_run.get(key), new_run.get(key)):
            raise RunFileError(
                f"cannot {verb} {path}: run.{key} was {old_run.get(key)!r}, "
                f"now {new_run.get(key)!r}"
                + (" (give it as it was, or --fresh to make the run again)" if earlier else "")
            )


def _extends(old: Any, new: Any) -> bool:
    """Whether the list ``new`` is ``old`` with backends added at its end."""
    old, new = list(old or []), list(new or [])
    return len(new) >= len(old) and new[: len(old)] == old


def _equal(a: Any, b: Any) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return bool(np.isclose(a, b, rtol=1e-12, atol=0.0))
    return bool(a == b)
