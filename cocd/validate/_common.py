"""What the seed validations share: running and measuring a column collapse.

Each case of ``cocd validate`` runs a few column collapses with
:func:`cocd.runs.run`, one run file per simulation under
``<out>/runs/<case>/<label>/run.h5`` (or under ``--runs``: :func:`runs_folder`),
then measures the saved frames and writes a table, figures and
``<case>.meta.json`` under ``<out>``, whose ``README.md`` is rebuilt from them.

Every simulation is resumable: a case run again continues each run file
from its last frame (a run killed half-way loses at most one frame
interval), and a finished run is only measured again. What a finished run
measured is kept beside its run file (:data:`cocd.runs.MEASURED_FILES`, a
few hundred kilobytes, committed with the results), so a case is rebuilt
from them without the run file. A case run again with a later ``until``
takes each run on from its end, and the measurements kept at the earlier end
stay beside the new ones (``measured_to<until>s.*``); a run file that went past
the end asked is measured at that end (the set kept before is moved aside in turn).
``fresh=True`` starts them over. A failed
step stops the case with a :class:`CocdError` naming it; the run files keep
what was computed.

Profiles are the free-surface height of the main connected mass (or, with
:attr:`CollapseJob.surface`, of every free grain) above the bed's top
(:func:`cocd.measure.mass_profile`), on bins one mean diameter wide, zero where
there is no grain. Fronts are those of the grains that
started in the column (:func:`cocd.measure.front_position`), measured from
the back wall; on an erodible bed the layer's grains do not count, so the
front is the column's, as in the experiments the seed compares with.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

from cocd.bench import estimate, report
from cocd.bench.study import Study, StudySettings, option
from cocd.bench.study import register as study_register
from cocd.errors import CocdError
from cocd.outputs import writable_folder
from cocd.runs import measured_names
from cocd.stepper import DEFAULT_PENETRATION_TOL

if TYPE_CHECKING:
    from cocd.io.runfile import Frame

FloatArray = NDArray[np.float64]

#: Seconds between two progress lines of one simulation.
PROGRESS_S = 20.0

#: Bins averaged into one for the coarse-grained profile errors (``*_4d`` columns):
#: one-diameter bins see single grains, four-diameter bins the mass.
COARSE = 4

#: Fraction of an erodible run, at its end, over which the front is averaged for
#: its runout.
RUNOUT_WINDOW = 0.1

#: Version of what :func:`measure_series` measures; kept measurements of another
#: version are measured again from their run file.
MEASURE_VERSION = 2

#: What a table's ``penetration_max`` (or ``penetration_max_<scheme>``) column holds.
PENETRATION_DOC = (
    "`penetration_max`: the largest overlap of two grains (or of a grain and a wall) at "
    "the end of a step of the run, in radii of the smaller; a step above "
    f"{DEFAULT_PENETRATION_TOL:g} is taken again with a wider margin."
)

#: Relative tolerance when a requested time is matched to a saved frame (in steps).
_FRAME_MATCH = 0.5


# -- running and measuring one collapse -------------------------------------------------
@dataclass(frozen=True)
class CollapseSeries:
    """What is measured on one simulated collapse.

    ``times``: the saved frames' times (s); ``front``: the flow's front at
    those times (:func:`cocd.measure.surface_front`), from the back wall (m);
    ``profiles``: the height above the bed per bin at the asked times (rows), on
    ``x_edges``; ``stats``: the run's per-step statistics (:attr:`compute_s`
    sums their detection, set-up and solve times, steps taken again included);
    ``n_grains``: the column's grains; ``d_mean``: their mean diameter (m).
    """

    label: str
    path: Path
    times: FloatArray
    front: FloatArray
    profile_times: FloatArray
    profiles: FloatArray
    x_edges: FloatArray
    stats: pd.DataFrame
    n_grains: int
    d_mean: float
    #: Steps solved to make it (0: read back from kept measurements).
    steps_made: int = 0
    #: The largest speed of a free grain at each saved frame (m/s), and of a free grain
    #: of the flow, not past the last frame's front by more than a diameter (on an
    #: erodible bed, the layer far ahead is left out); None when read back from
    #: measurements kept before they were measured.
    speed_max: FloatArray | None = None
    speed_max_flow: FloatArray | None = None
    #: At each saved frame (rows), for each of the job's shares ``few`` (columns): the
    #: speed that all the free grains of the flow (as for ``speed_max_flow``) but that
    #: share of the column's grain count stay at or below (the ``floor(share * n) + 1``-th
    #: largest; 0 when the flow holds fewer grains); None when not asked.
    speed_few_flow: FloatArray | None = None
    #: ``(first step, machine)`` (:func:`cocd.provenance.machine_name`) of each stretch
    #: of the run's steps (:attr:`cocd.io.runfile.RunFile.machines`): where its time was
    #: measured; empty for a run written before machines were recorded.
    machines: tuple[tuple[int, str], ...] = ()

    @property
    def machine(self) -> str:
        """Where the steps were made, in words: the machine, or each machine with
        the step it took the run on from; "not recorded" for steps made before
        machines were recorded."""
        if not self.machines:
            return "not recorded"
        if len(self.machines) == 1:
            return self.machines[0][1] or "not recorded"
        return "; ".join(f"{m or 'not recorded'} from step {k}" for k, m in self.machines)

    @property
    def steps(self) -> int:
        return len(self.stats)

    @property
    def penetration_max(self) -> float:
        """Largest end-of-step overlap of the run, relative to the smaller radius (NaN: a
        run file written before overlaps were measured)."""
        values = self.stats.penetration.to_numpy(dtype=float)
        return float(np.max(values)) if values.size and np.all(np.isfinite(values)) else np.nan

    @property
    def fallback_steps(self) -> int:
        """Steps answered by a fallback backend (the first one failed them)."""
        return int((self.stats.failures.fillna("") != "").sum())

    @property
    def compute_s(self) -> float:
        """Seconds of detection, set-up and solving summed over the steps, the
        attempts of steps taken again included (:func:`compute_seconds`)."""
        return compute_seconds(self.stats)


def compute_seconds(stats: pd.DataFrame) -> float:
    """Seconds of detection, set-up and solving summed over a run's steps (its
    per-step statistics), the attempts of a step taken again with a wider margin
    (``redo_time``) included: the run's cost, not only that of the answers kept."""
    spent = stats.detect_time + stats.setup_time + stats.solve_time
    if "redo_time" in stats:
        spent = spent + stats.redo_time.fillna(0.0)
    return float(spent.sum())


@dataclass(frozen=True)
class CollapseJob:
    """One packing's run of a validation case (:func:`collapse_job`): its folder, its
    column (``params``, :func:`cocd.builders.column_collapse`'s arguments), how it is
    run (backend, tolerance, fallbacks, whether to start over), its steps and frames,
    and how it is measured (:func:`collapse_series`)."""

    folder: Path
    label: str
    params: dict[str, Any]
    how: RunSettings
    announce: str
    dt: float
    until: float
    frame_dt: float
    profile_times: tuple[float, ...] = ()
    max_iter: int | None = None
    solver_options: dict[str, Any] | None = None
    bin_width: float | None = None
    x_max: float | None = None
    #: Profiles of the free surface (the highest free grain per bin) rather than of the
    #: main mass (:func:`cocd.measure.mass_profile`'s ``connected``).
    surface: bool = False
    #: Shares of the column's grain count left out of the flow's speed at each frame
    #: (:attr:`CollapseSeries.speed_few_flow`); none: not measured.
    few: tuple[float, ...] = ()

    @property
    def steps(self) -> float:
        return self.until / self.dt

    @property
    def free_grains(self) -> int:
        """Free grains of the run's scene, a bed layer's with the column's: the size of
        its step problems, which sets what a step costs."""
        return built_column(self.params).n_free


class BuiltColumn(NamedTuple):
    """What a case reads of a column's scene before and after its runs (to estimate
    them, and to see which of its columns are the same): its free grains, and the
    column's length and height (m) as built, its grains' reach from the back wall and
    above the bed's top."""

    n_free: int
    length: float
    height: float


#: Columns built in this process, by their parameters (a few numbers each: the scenes
#: themselves, up to tens of MB, are not kept).
_BUILT: dict[str, BuiltColumn] = {}


def built_column(params: Mapping[str, Any]) -> BuiltColumn:
    """:class:`BuiltColumn` of the scene :func:`cocd.builders.column_collapse` builds with
    ``params`` (``dim`` among them), built once per process."""
    import json

    from cocd.builders import column_collapse
    from cocd.measure import bed_top

    key = json.dumps(dict(params), sort_keys=True, default=repr)
    if key not in _BUILT:
        kw = dict(params)
        scene = column_collapse(kw.pop("dim"), **kw)
        x, r = scene.positions, scene.radii
        column = scene.groups["column"]
        _BUILT[key] = BuiltColumn(
            n_free=int(scene.n_free),
            length=float(np.max(x[column, 0] + r[column])),
            height=float(np.max(x[column, -1] + r[column])) - bed_top(scene),
        )
    return _BUILT[key]


def collapse_job(
    out: Path,
    case: str,
    label: str,
    seed: int,
    params: dict[str, Any],
    how: RunSettings,
    *,
    dt: float,
    frame_dt: float,
    until: float | None = None,
    profile_times: Sequence[float] = (),
    what: str = "",
    max_iter: int | None = None,
    solver_options: dict[str, Any] | None = None,
    bin_width: float | None = None,
    x_max: float | None = None,
    surface: bool = False,
    few: Sequence[float] = (),
) -> CollapseJob:
    """Packing ``seed``'s run of a validation case, in ``<runs>/<case>/<label>[_s<seed>]``
    (``<runs>``: :func:`runs_folder`).

    ``what`` describes the run in the progress line (default: backend and tolerance);
    ``until`` defaults to the last of ``profile_times``; the rest are
    :class:`CollapseJob`'s fields.
    """
    if until is None:
        if not profile_times:
            raise CocdError(f"{case}: a run needs an end time or profile times")
        until = max(profile_times)
    label = seed_label(label, seed)
    what = what or f"{how.solver}, tol {how.tol:g}"
    return CollapseJob(
        folder=runs_folder(how, out) / case / label,
        label=label,
        params=seed_params(params, seed),
        how=RunSettings(solver=how.solver, tol=how.tol, fallback=how.fallback, fresh=how.fresh),
        announce=f"{case}: {label} ({what}) to t = {until:g} s",
        dt=dt,
        until=until,
        frame_dt=frame_dt,
        profile_times=tuple(float(t) for t in profile_times),
        max_iter=max_iter,
        solver_options=solver_options,
        bin_width=bin_width,
        x_max=x_max,
        surface=surface,
        few=tuple(float(f) for f in few),
    )


def collapse_series(job: CollapseJob, progress: Callable[[str], Any] = print) -> CollapseSeries:
    """Run (or resume, or just read) ``job``'s ``column_collapse`` and measure it.

    Frames are saved every ``job.frame_dt`` seconds (a whole number of steps).
    Profiles are measured at ``job.profile_times``, each of which must fall on a
    saved frame; bins are ``job.bin_width`` wide (default: one mean diameter) from
    the back wall to ``job.x_max`` (default: the bed's end), of the main mass or, with
    ``job.surface``, of the free surface.
    """
    from cocd.errors import SolverError
    from cocd.io.runfile import RunFile
    from cocd.runs import MEASURED_FILES, RUN_FILE, Progress, measured_other_ends, run

    config, key = _run_key(job)
    folder, label, how = job.folder, job.label, job.how
    writable_folder(folder, "run folder")
    last = [time.perf_counter()]

    def tick(p: Progress) -> None:
        now = time.perf_counter()
        if now - last[0] >= PROGRESS_S or p.done == p.total:
            last[0] = now
            rec = p.record
            progress(
                f"  {label}: step {p.done}/{p.total}  t {rec.t:.4f} s  Nc {rec.nc}  "
                f"it {rec.iterations}  ({p.elapsed:.0f} s this call)"
            )

    if how.fresh:
        for name in MEASURED_FILES:
            (folder / name).unlink(missing_ok=True)
        for stale in measured_other_ends(folder):
            stale.unlink()
    else:
        kept = read_measured(folder, key, label)
        if kept is not None:
            return kept
        if _steps_held(job) > job.steps + 0.5:  # gone on past this end: measured there
            from cocd.runs import _check_same

            with RunFile(folder / RUN_FILE) as rf:
                _check_same(rf.config, config.resolved(), folder / RUN_FILE, earlier=True)
            return _measure_kept(job, key, folder / RUN_FILE, until=job.until)
    try:
        summary = run(
            config,
            folder,
            resume=not how.fresh,
            force=how.fresh,
            progress=tick,
            source=str(folder),
        )
    except SolverError as exc:
        raise CocdError(
            f"{label}: {exc}; the run file {folder / RUN_FILE} keeps the frames before it "
            "(run the case again to resume, or change the solver or tolerance)"
        ) from None
    if summary.resumed_from_step and summary.steps > summary.resumed_from_step:
        progress(f"  {label}: resumed at step {summary.resumed_from_step}")
    series = _measure_kept(job, key, summary.path)
    return dataclasses.replace(series, steps_made=summary.steps - (summary.resumed_from_step or 0))


def _measure_kept(
    job: CollapseJob, key: dict[str, Any], path: Path, until: float | None = None
) -> CollapseSeries:
    """Measure ``job``'s run file (to ``until``, if given) and keep what it measured."""
    series = measure_series(
        path,
        job.label,
        job.profile_times,
        job.bin_width,
        job.x_max,
        job.dt,
        job.surface,
        job.few,
        until,
    )
    write_measured(job.folder, key, series)
    return series


def _run_key(job: CollapseJob) -> tuple[Any, dict[str, Any]]:
    """The run's configuration, and the key its kept measurements are filed under."""
    from cocd.config import RunConfig

    how, dt, frame_dt = job.how, job.dt, job.frame_dt
    every = max(1, round(frame_dt / dt))
    if abs(every * dt - frame_dt) > 1e-9 * frame_dt:
        raise CocdError(f"frame interval {frame_dt:g} s is not a whole number of steps of {dt:g}")
    run_table: dict[str, Any] = {
        "dt": dt,
        "until": job.until,
        "solver": how.solver,
        "tol": how.tol,
        "frame_every": every,
        "fallback": list(how.fallback),
        "solver_options": dict(job.solver_options or {}),
    }
    if job.max_iter is not None:
        run_table["max_iter"] = job.max_iter
    config = RunConfig.model_validate(
        {"builder": "column_collapse", "params": job.params, "run": run_table}
    )
    key = {
        "version": MEASURE_VERSION,
        "config": config.resolved(),
        "measure": {
            "profile_times": [float(t) for t in job.profile_times],
            "bin_width": job.bin_width,
            "x_max": job.x_max,
            # Only when set: the keys of the measurements kept before it stay the same.
            **({"surface": True} if job.surface else {}),
            **({"few": list(job.few)} if job.few else {}),
        },
    }
    return config, key


def write_measured(folder: Path, key: dict[str, Any], series: CollapseSeries) -> None:
    """Keep the measurements of a finished run in ``folder``
    (:data:`cocd.runs.MEASURED_FILES`): small enough to commit with the results, so
    that a case is measured again without the run file (every frame) or a rerun."""
    import json

    _set_aside(folder, key)
    record, npz, stats = measured_names()
    (folder / record).unlink(missing_ok=True)  # the old record goes first
    arrays = {
        "times": series.times,
        "front": series.front,
        "profile_times": series.profile_times,
        "profiles": series.profiles,
        "x_edges": series.x_edges,
    }
    for name in ("speed_max", "speed_max_flow", "speed_few_flow"):
        if getattr(series, name) is not None:
            arrays[name] = getattr(series, name)
    np.savez_compressed(folder / npz, **arrays)  # type: ignore[arg-type]
    series.stats.to_parquet(folder / stats, index=False)
    meta = {
        **key,
        "n_grains": series.n_grains,
        "d_mean": series.d_mean,
        "machines": [list(m) for m in series.machines],
    }
    tmp = folder / f"{record}.tmp"  # written last: its presence means the rest is whole
    tmp.write_text(json.dumps(meta, indent=1, default=str) + "\n")
    tmp.replace(folder / record)


def _set_aside(folder: Path, key: dict[str, Any]) -> None:
    """Move the kept measurements in ``folder`` to :func:`measured_names` of their end when
    ``key`` asks for another end of the same run, so that both stay (a run taken on to a
    later end is still read at the earlier one, and one measured at an earlier end still
    at its own). A set kept there before goes first, its record first, and the record
    moves last: a move cut short leaves no record beside another set's arrays."""
    import json

    try:
        meta = json.loads((folder / measured_names()[0]).read_text())
        end = meta["config"]["run"]["until"]
    except (OSError, ValueError, KeyError, TypeError):
        return
    if end is None or end == key["config"].get("run", {}).get("until"):
        return
    names = measured_names(float(end))
    for aside in names:
        (folder / aside).unlink(missing_ok=True)
    for name, aside in reversed(list(zip(measured_names(), names, strict=True))):
        if (folder / name).exists():
            (folder / name).replace(folder / aside)


def read_measured(folder: Path, key: dict[str, Any], label: str) -> CollapseSeries | None:
    """The kept measurements of the same run to the same end, measured the same way,
    else None: the latest ones, or the set moved aside for that end
    (:func:`measured_names`) when the run was measured at another end."""
    until = key["config"].get("run", {}).get("until")
    for names in (measured_names(), *([measured_names(float(until))] if until else [])):
        series = _read_measured(folder, names, key, label)
        if series is not None:
            return series
    return None


def _read_measured(
    folder: Path, names: tuple[str, str, str], key: dict[str, Any], label: str
) -> CollapseSeries | None:
    import json

    from cocd.runs import _check_same

    path, npz, parquet = (folder / name for name in names)
    if not path.exists():
        return None
    try:
        meta = json.loads(path.read_text())
        _check_same(meta["config"], key["config"], path)
    except (ValueError, KeyError, CocdError):
        return None
    # The same length of run, measured the same way by the same version of cocd.
    ran, asked = meta["config"].get("run", {}), key["config"].get("run", {})
    kept = [ran.get("until"), ran.get("steps"), meta.get("measure"), meta.get("version")]
    wanted = [asked.get("until"), asked.get("steps"), key["measure"], key["version"]]
    if kept != json.loads(json.dumps(wanted, default=str)):
        return None
    try:
        with np.load(npz) as data:
            arrays = {name: np.asarray(data[name]) for name in data.files}
        stats = pd.read_parquet(parquet)
    except (OSError, ValueError, KeyError):  # missing or damaged: measure the run again
        return None
    if key["measure"].get("surface") and "speed_max_flow" not in arrays:  # written with it
        return None
    if key["measure"].get("few") and "speed_few_flow" not in arrays:
        return None
    return CollapseSeries(
        label=label,
        path=path,
        times=arrays["times"],
        front=arrays["front"],
        profile_times=arrays["profile_times"],
        profiles=arrays["profiles"],
        x_edges=arrays["x_edges"],
        stats=stats,
        n_grains=int(meta["n_grains"]),
        d_mean=float(meta["d_mean"]),
        speed_max=arrays.get("speed_max"),
        speed_max_flow=arrays.get("speed_max_flow"),
        speed_few_flow=arrays.get("speed_few_flow"),
        machines=tuple((int(k), str(m)) for k, m in meta.get("machines", [])),
    )


def measure_series(
    path: Path,
    label: str,
    profile_times: Sequence[float],
    bin_width: float | None,
    x_max: float | None,
    dt: float,
    surface_profiles: bool = False,
    few: Sequence[float] = (),
    until: float | None = None,
) -> CollapseSeries:
    """Measure the run file at ``path`` (to its frame at ``until`` if given, the run
    having gone on past it; else to its last)."""
    from cocd.io.runfile import RunFile
    from cocd.measure import bed_surface, bed_top, mass_profile, surface_front

    with RunFile(path) as rf:
        scene0 = rf.scene(0)
        column = np.zeros(rf.n_grains, dtype=bool)
        column[scene0.groups["column"]] = True
        r = rf.radii
        d_mean = 2.0 * float(r[column].mean())
        base = bed_top(scene0)
        free = ~scene0.fixed
        if x_max is None:
            x_max = float(np.max(scene0.positions[:, 0] + r))
        width = d_mean if bin_width is None else bin_width
        edges = np.arange(0.0, x_max + width, width)
        surface = bed_surface(scene0, edges)  # the erodible layer's top, else the bed's
        times = rf.times.copy()
        n = rf.n_frames
        if until is not None:
            n = int(np.count_nonzero(times <= until + _FRAME_MATCH * dt))
            if n == 0 or abs(times[n - 1] - until) > _FRAME_MATCH * dt:
                spacing = float(times[1] - times[0]) if times.size > 1 else 0.0
                raise CocdError(
                    f"{label}: {path} saves no frame at t = {until:g} s (its frames are "
                    f"{spacing:g} s apart, to t = {times[-1]:g} s): ask an end on one of them"
                )
            times = times[:n]

        def frame_at(k: int) -> Frame:  # the last frame, read first, is not read again
            return last if k == n - 1 else rf.frame(k)

        def front_at(frame: Frame) -> float:
            return float(
                surface_front(frame.positions, r, x_bins=edges, surface=surface, mask=free)
            )

        # The flow's grains are those not past the last frame's front by more than a
        # diameter: the last frame is read first for that front, then each frame once,
        # and no other frame's grains are held (a 3D flume's 220 frames would take 120 MB).
        last = rf.frame(n - 1)
        last_front = front_at(last)
        reach = last_front + d_mean if np.isfinite(last_front) else np.inf
        front, speed_max, speed_max_flow = np.empty(n), np.empty(n), np.empty(n)
        # The few fastest grains left out: the (floor(share * n) + 1)-th largest speed.
        ranks = [math.floor(share * int(column.sum())) for share in few]
        speed_few_flow = np.zeros((n, len(ranks)))
        for k in range(n):
            frame = frame_at(k)
            front[k] = last_front if k == n - 1 else front_at(frame)
            speed = np.sqrt(np.sum(frame.velocities[free] ** 2, axis=1))
            flow = speed[frame.positions[free, 0] <= reach]
            speed_max[k] = float(np.max(speed))
            speed_max_flow[k] = float(np.max(flow, initial=0.0))
            # One partition puts every asked rank in place (0 where the flow is smaller).
            kept = [(j, flow.size - 1 - rank) for j, rank in enumerate(ranks) if rank < flow.size]
            if kept:
                ordered = np.partition(flow, [at for _, at in kept])
                for j, at in kept:
                    speed_few_flow[k, j] = float(ordered[at])
        profiles = []
        for t in profile_times:
            k = int(np.argmin(np.abs(times - t)))
            if abs(times[k] - t) > _FRAME_MATCH * dt:
                raise CocdError(f"{label}: no frame saved at t = {t:g} s in {path}")
            prof = mass_profile(
                frame_at(k).positions, r, x_bins=edges, mask=free, connected=not surface_profiles
            )
            profiles.append(np.nan_to_num(prof.height - base, nan=0.0).clip(min=0.0))
        stats = rf.stats()
        if until is not None:  # the steps to that frame
            stats = stats[stats["t"] <= until + _FRAME_MATCH * dt].reset_index(drop=True)
        n_grains = int(column.sum())
        last_step = int(stats["step"].iloc[-1]) if len(stats) else 0
        machines = tuple(rf.machines_to(last_step))
    return CollapseSeries(
        label=label,
        path=path,
        times=times,
        front=front,
        profile_times=np.asarray(profile_times, dtype=float),
        profiles=np.asarray(profiles).reshape(len(profile_times), len(edges) - 1),
        x_edges=edges,
        stats=stats,
        n_grains=n_grains,
        d_mean=d_mean,
        speed_max=speed_max,
        speed_max_flow=speed_max_flow,
        speed_few_flow=speed_few_flow if ranks else None,
        machines=machines,
    )


def profile_error(h: ArrayLike, reference: ArrayLike) -> float:
    """Relative profile error ``||h - h_ref|| / ||h_ref||`` (2-norm over the bins)."""
    h = np.asarray(h, dtype=float)
    ref = np.asarray(reference, dtype=float)
    if h.shape != ref.shape:
        raise CocdError(f"profiles on different bins: {h.shape} and {ref.shape}")
    norm = float(np.linalg.norm(ref))
    if norm == 0.0:
        raise CocdError("the reference profile is empty")
    return float(np.linalg.norm(h - ref) / norm)


def profile_errors(h: ArrayLike, reference: ArrayLike) -> tuple[float, float]:
    """:func:`profile_error` on one-diameter bins and on bins :data:`COARSE` times wider."""
    return profile_error(h, reference), profile_error(
        coarsen(h, COARSE), coarsen(reference, COARSE)
    )


def coarsen(h: ArrayLike, k: int) -> FloatArray:
    """A profile on bins ``k`` times wider: the mean of each run of ``k`` bins (the last
    run padded with zeros)."""
    h = np.asarray(h, dtype=float)
    pad = (-h.size) % k
    return np.asarray(np.concatenate([h, np.zeros(pad)]).reshape(-1, k).mean(axis=1))


def ensemble(
    table: pd.DataFrame,
    keys: Sequence[str],
    columns: Sequence[str],
    counts: Sequence[str] = (),
    reached: Sequence[str] = (),
) -> pd.DataFrame:
    """Mean and sample spread over the packings (rows sharing ``keys``): per group,
    ``seeds`` (rows), and for each of ``columns`` its mean and ``<column>_sd`` (sample
    standard deviation, NaN for one packing); for each of ``counts`` (flags), how many
    of the group's packings have it set. A packing without a value (NaN: a rest time
    not reached) is left out of the mean and spread; for each of ``reached``,
    ``<column>_n`` says how many of the group's packings have one, so each of
    ``reached`` must be one of ``columns``."""
    stray = [name for name in reached if name not in columns]
    if stray:
        raise ValueError(f"ensemble: reached names {stray} that are not among the columns averaged")
    grouped = table.groupby(list(keys), sort=True)
    out = grouped.size().rename("seeds").to_frame()
    for column in columns:
        out[column] = grouped[column].mean()
        out[f"{column}_sd"] = grouped[column].std(ddof=1)
        if column in reached:
            out[f"{column}_n"] = grouped[column].count().astype(int)
    for column in counts:
        out[column] = grouped[column].sum().astype(int)
    return out.reset_index()


#: A front within this many mean diameters of the bed's end is cut short by it.
END_MARGIN_D = 2.0


def cut_short(front: ArrayLike, bed: float, d_mean: float) -> bool:
    """Whether a front (or any of a series of them) came within :data:`END_MARGIN_D`
    mean diameters ``d_mean`` of the end of a bed ``bed`` long: it may have run further
    on a longer bed, so its runout is not the flow's. Fronts not measured (NaN: no bin
    carried the flow) are left out."""
    fronts = np.asarray(front, dtype=float).reshape(-1)
    fronts = fronts[np.isfinite(fronts)]
    return bool(fronts.size and fronts.max() >= bed - END_MARGIN_D * d_mean)


def pm(row: Any, column: str, digits: int = 3) -> str:
    """``mean +- spread`` of an :func:`ensemble` row (the mean alone for one packing)."""
    sd = row[f"{column}_sd"]
    text = f"{row[column]:.{digits}g}"
    return text + ("" if not np.isfinite(sd) else f" +- {sd:.{digits}g}")


#: The worker processes' environment: every thread pool (MKL's PARDISO, OpenMP,
#: OpenBLAS, numba) on one thread, so that the runs share the cores instead of
#: fighting for them. On 2 cores, 30 steps of a 5725-grain Fig. 9 run took the same
#: time on one thread as on two, and two such runs at once about 1.25 times as long.
ONE_THREAD = dict.fromkeys(
    ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS"), "1"
)

#: Seconds between two looks at the worker processes.
_POLL_S = 0.5


def collapse_runs(
    jobs: Sequence[CollapseJob], workers: int = 1, progress: Callable[[str], Any] = print
) -> list[CollapseSeries]:
    """Run (or resume, or read back) ``jobs``, their series in the same order.

    ``workers`` > 1 runs that many at once, each in a process of its own with its
    libraries on one thread (:data:`ONE_THREAD`); their progress lines come back to
    ``progress``. Runs whose measurements are kept are read back here, without a
    process. After a failed run no other starts: the running ones finish (and are
    kept), then its error is raised. An interrupt stops the workers, whose runs
    resume from their last frame next time. Runs partly made are taken up first, those
    furthest on before the others, so a run begun is finished before a new one starts.
    """
    workers = positive_int("workers", workers)
    folders = [job.folder for job in jobs]
    twice = sorted({str(f) for f in folders if folders.count(f) > 1})
    if twice:
        raise CocdError(f"two runs of the case would share the folder {twice[0]}")
    series: list[CollapseSeries | None] = [None] * len(jobs)
    todo = []
    for k, job in enumerate(jobs):
        kept = None if job.how.fresh else _kept(job)
        if kept is not None:
            progress(job.announce + " (kept)")
            series[k] = kept
        else:
            todo.append(k)
    # Steps the runs to make already hold in their run files (resumed, not made again).
    held = {k: 0 if jobs[k].how.fresh else _steps_held(jobs[k]) for k in todo}
    whole = sum(1 for k in todo if held[k] > 0 and held[k] >= jobs[k].steps - 0.5)
    partly = sum(1 for k in todo if held[k] > 0) - whole
    if jobs and (len(todo) < len(jobs) or partly or whole):
        units = [estimate.work([(job.free_grains, job.steps)]) for job in jobs]
        left = {
            k: estimate.work([(jobs[k].free_grains, max(jobs[k].steps - held[k], 0.0))])
            for k in todo
        }
        what = f"{len(jobs) - len(todo)} of {len(jobs)} runs kept"
        estimate.kept(
            sum(left.values()) / sum(units),
            what
            + (f", {partly} partly made" if partly else "")
            + (f", {whole} made but not measured" if whole else ""),
            progress,
            measured=_kept_rate(jobs, series, todo, left),
            runs=len(todo),
        )
    # The runs furthest on go first, so that a session cut short finishes the runs it
    # had started before it begins new ones (the order of the series is kept).
    todo.sort(key=lambda k: -held[k])
    if workers == 1 or len(todo) < 2:
        for k in todo:
            series[k] = _collapse(jobs[k], progress)
    else:
        made = run_apart(_collapse, [jobs[k] for k in todo], min(workers, len(todo)), progress)
        for k, s in zip(todo, made, strict=True):
            series[k] = s
    done = [(job, s) for job, s in zip(jobs, series, strict=True) if s is not None]
    for job, s in done:
        estimate.made(job.free_grains, s.steps_made)  # none for a run read back
    return [s for _, s in done]


def _steps_held(job: CollapseJob) -> int:
    """Steps already in ``job``'s run file (0: none, or a file that cannot be read)."""
    from cocd.io.runfile import RunFile
    from cocd.runs import RUN_FILE

    path = job.folder / RUN_FILE
    if not path.exists():
        return 0
    try:
        with RunFile(path) as rf:
            return int(rf.steps[-1]) if rf.n_frames else 0
    except (OSError, CocdError):
        return 0


def _kept_rate(
    jobs: Sequence[CollapseJob],
    series: Sequence[CollapseSeries | None],
    todo: Sequence[int],
    units: Mapping[int, float],
) -> tuple[float, float] | None:
    """``(seconds, work units)`` of the runs to make, each kind (:func:`_way`) timed at
    the rate of the kept runs of that kind, for :func:`cocd.bench.estimate.kept`; None
    when a kind to make has no kept run (an ipm run's rate says little of an nscd
    run's, nor a 2D run's of a 3D one's, whose steps need many more iterations per
    grain)."""
    spent: dict[tuple[Any, ...], list[float]] = {}
    for job, s in zip(jobs, series, strict=True):
        if s is not None:
            done = spent.setdefault(_way(job), [0.0, 0.0])
            done[0] += s.compute_s
            done[1] += estimate.work([(job.free_grains, s.steps)])
    seconds = 0.0
    for k in todo:
        kind = spent.get(_way(jobs[k]))
        if kind is None or not (kind[0] > 0.0 and kind[1] > 0.0):
            return None
        seconds += kind[0] / kind[1] * units[k]
    return seconds, sum(units[k] for k in todo)


def _way(job: CollapseJob) -> tuple[Any, ...]:
    """What sets a run's rate per unit of work besides its size: backend, tolerance and
    dimension."""
    return (job.how.solver, job.how.tol, job.params.get("dim"))


def kept_only(
    jobs: Sequence[CollapseJob], cases: Sequence[Any], progress: Callable[[str], Any] = print
) -> tuple[list[CollapseJob], list[Any]]:
    """The ``jobs`` whose measurements are kept, with their ``cases``: a table of what is
    measured so far, with nothing run. Each job left out is said; none kept is an error."""
    keep = [k for k, job in enumerate(jobs) if _kept(job) is not None]
    for k, job in enumerate(jobs):
        if k not in keep:
            progress(f"{job.folder.name}: not measured yet, left out (--kept-only)")
    if not keep:
        raise CocdError("--kept-only: none of the runs asked is measured yet")
    return [jobs[k] for k in keep], [cases[k] for k in keep]


def _kept(job: CollapseJob) -> CollapseSeries | None:
    _, key = _run_key(job)
    return read_measured(job.folder, key, job.label)


def _collapse(job: CollapseJob, progress: Callable[[str], Any]) -> CollapseSeries:
    progress(job.announce)
    return collapse_series(job, progress)


def _worker(task: Callable[[Any, Callable[[str], Any]], Any], job: Any, conn: Any) -> None:
    """A worker process: ``task(job, progress)``, sending its progress lines, then its
    result or its error, through ``conn``. An interrupt is the parent's to handle; a stop
    from the parent ends the task as an interrupt would (a run file keeps its frames)."""
    import signal

    def stop(*_: Any) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, stop)
    try:
        conn.send(("done", task(job, lambda line: conn.send(("line", line)))))
    except KeyboardInterrupt:  # stopped by the parent, which knows why
        pass
    except Exception as exc:  # sent to the parent, which raises it
        try:
            conn.send(("error", exc))
        except Exception:  # not picklable: its message
            conn.send(("error", CocdError(f"{job.label}: {exc}")))
    finally:
        conn.close()


def run_apart(
    task: Callable[[Any, Callable[[str], Any]], Any],
    jobs: Sequence[Any],
    workers: int,
    progress: Callable[[str], Any],
    on_done: Callable[[int, Any], Any] | None = None,
) -> list[Any]:
    """``task(job, progress)`` for every job, ``workers`` at once, each in a process of its
    own started with its libraries on one thread (:data:`ONE_THREAD`); the results in the
    jobs' order. ``task`` is a module-level function (it is pickled to the process) and a
    job has a ``label``. Progress lines come back to ``progress``; ``on_done(k, result)``
    is called as job ``k`` finishes (to keep it at once). After a failure no other job
    starts: the running ones finish, then its error is raised. Ctrl-C or SIGTERM stops
    the processes as an interrupt would."""
    import multiprocessing
    import signal
    import threading
    from multiprocessing.connection import wait

    # Ctrl-C, or a batch system's SIGTERM, is noted here and acted on by the loop at its
    # next look (raised from the handler, it could land in a finaliser and be lost).
    asked: list[int] = []
    handlers = {}
    if threading.current_thread() is threading.main_thread():
        for number in (signal.SIGINT, signal.SIGTERM):
            if signal.getsignal(number) is not signal.SIG_IGN:
                handlers[number] = signal.signal(number, lambda n, _: asked.append(n))
    try:
        context = multiprocessing.get_context("spawn")
        return _run_with(task, jobs, workers, progress, context, wait, asked, on_done)
    finally:
        for number, handler in handlers.items():
            signal.signal(number, signal.SIG_DFL if handler is None else handler)


def _run_with(
    task: Callable[[Any, Callable[[str], Any]], Any],
    jobs: Sequence[Any],
    workers: int,
    progress: Callable[[str], Any],
    context: Any,
    wait: Callable[..., Any],
    asked: list[int],
    on_done: Callable[[int, Any], Any] | None = None,
) -> list[Any]:
    results: dict[int, Any] = {}
    running: dict[Any, tuple[int, Any]] = {}  # parent's end of the pipe -> (job, process)
    waiting = list(range(len(jobs)))
    failure: BaseException | None = None
    saved = {name: os.environ.get(name) for name in ONE_THREAD}
    try:
        while running or (waiting and failure is None):
            if asked:
                raise KeyboardInterrupt
            while waiting and failure is None and len(running) < workers:
                k = waiting.pop(0)
                mine, theirs = context.Pipe(duplex=False)
                process = context.Process(target=_worker, args=(task, jobs[k], theirs), daemon=True)
                os.environ.update(ONE_THREAD)  # what the process starts with
                try:
                    process.start()
                finally:
                    _restore(saved)
                theirs.close()
                running[mine] = (k, process)
            ready: list[Any] = list(wait(list(running), timeout=_POLL_S))
            for conn in ready:
                k, process = running[conn]
                try:
                    kind, value = conn.recv()
                except EOFError:  # the process ended without a word
                    process.join()
                    kind, value = (
                        "error",
                        CocdError(
                            f"{jobs[k].label}: its process stopped (exit code {process.exitcode}); "
                            "what finished is kept, and the case run again takes up the rest"
                        ),
                    )
                if kind == "line":
                    progress(value)
                    continue
                del running[conn]
                conn.close()
                process.join()
                if kind == "done":
                    results[k] = value
                    if on_done is not None:
                        on_done(k, value)
                elif failure is None:
                    failure = value
    except BaseException:
        for _, process in running.values():
            process.terminate()  # the run stops as if interrupted, keeping its frames
        for _, process in running.values():
            process.join()
        raise
    if failure is not None:
        raise failure
    return [results[k] for k in range(len(jobs))]


def _restore(saved: dict[str, str | None]) -> None:
    for name, value in saved.items():
        if value is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = value


def runs_folder(how: RunSettings, out: Path) -> Path:
    """Where a study's run files, and the measurements kept beside them, go: ``--runs``
    (relative to the current folder), or ``out/runs``; a file in the way of ``--runs``
    is a one-line error."""
    if how.runs is None:
        return Path(out) / "runs"
    path = Path(how.runs)
    if path.exists() and not path.is_dir():
        raise CocdError(f"--runs {path}: a file is in the way of the folder")
    return path


def seed_label(label: str, seed: int) -> str:
    """A run's label for packing ``seed``: seed 0 keeps the plain label (earlier runs resume)."""
    return label + (f"_s{seed}" if seed else "")


def seed_params(params: dict[str, Any], seed: int) -> dict[str, Any]:
    """The column's parameters for packing ``seed`` (seed 0: the builder's default)."""
    return {**params, "seed": seed} if seed else dict(params)


def base_params(n: int, mu: float, slope: float = 0.0, **extra: Any) -> dict[str, Any]:
    return {"dim": 2, "n_grains": int(n), "bed": "rough", "mu": mu, "slope_deg": slope, **extra}


def positive_int(name: str, value: int, low: int = 1) -> int:
    if int(value) != value or value < low:
        raise CocdError(f"{name} must be an integer >= {low}, got {value!r}")
    return int(value)


def twin_tolerance(name: str, value: float, tol: float, tol_name: str = "tol") -> float:
    """A twin run's tolerance: 0 (no twin) or a positive one other than ``tol``."""
    twin = float(value)
    if twin != 0 and not (math.isfinite(twin) and twin > 0 and not math.isclose(twin, tol)):
        raise CocdError(
            f"{name} must be 0 (no twin) or a positive tolerance other than {tol_name} "
            f"({tol:g}), not {value!r}"
        )
    return twin


def positive_list(name: str, values: Sequence[float]) -> list[float]:
    """One setting's list of values as floats, each finite and positive."""
    out = [float(v) for v in values]
    if not out or not all(math.isfinite(v) and v > 0.0 for v in out):
        raise CocdError(f"{name} must be positive numbers, got {list(values)!r}")
    return out


def positives(**settings: float) -> list[float]:
    """Several settings of one value each, as floats in the order given; the error
    names the first that is not a finite positive number."""
    for name, value in settings.items():
        v = float(value)
        if not (math.isfinite(v) and v > 0.0):
            raise CocdError(f"{name} must be a positive number, got {v:g}")
    return [float(v) for v in settings.values()]


def whole_steps(until: float, dt: float) -> int:
    """The steps of ``dt`` to ``until``; a one-line error unless they are a whole number
    (a run would otherwise end past the time asked for)."""
    steps = round(until / dt)
    if abs(steps * dt - until) > 1e-6 * dt:
        raise CocdError(f"until {until:g} s is not a whole number of steps of {dt:g} s")
    return steps


def pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig: Any, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    pyplot().close(fig)
    return path


def finish(
    out: Path,
    name: str,
    title: str,
    table: pd.DataFrame,
    intro: str,
    summary: str,
    figures: list[Path],
    progress: Callable[[str], Any],
) -> None:
    """Publish a validation's table and README section. A table with overlaps
    (``penetration_max`` or ``penetration_max_<scheme>``) has them defined after
    ``intro``: one definition for every study."""
    if any(str(c).startswith("penetration_max") for c in table.columns):
        intro = f"{intro.rstrip()} {PENETRATION_DOC}"
    files = report.publish(
        out, name, table, title=title, intro=intro, summary=summary, figures=figures
    )
    progress(f"{name}: wrote {', '.join(str(f) for f in files)}")


def fmt(x: float) -> str:
    return f"{x:.3g}"


def frame_interval(times: Sequence[float], dts: Sequence[float]) -> float:
    """A frame interval on which every asked time and every step falls: 0.01 s or finer."""
    for frame_dt in (1e-2, 5e-3, 2e-3, 1e-3, 5e-4, 1e-4):
        ok = all(abs(t / frame_dt - round(t / frame_dt)) < 1e-6 for t in times)
        ok = ok and all(abs(frame_dt / d - round(frame_dt / d)) < 1e-6 for d in dts)
        ok = ok and all(frame_dt >= d - 1e-15 for d in dts)
        if ok:
            return frame_dt
    raise CocdError(
        f"the times {list(times)} do not fall on whole numbers of the steps {list(dts)}"
    )


def profile_figure(path: Path, series: list[CollapseSeries], labels: list[str]) -> Path:
    plt = pyplot()
    times = series[0].profile_times
    fig, axes = plt.subplots(1, len(times), figsize=(4.2 * len(times), 3.4), squeeze=False)
    reach = max(
        float(s.x_edges[np.nonzero(s.profiles.max(axis=0) > 0)[0].max() + 1])
        for s in series
        if s.profiles.max() > 0
    )
    for k, (ax, t) in enumerate(zip(axes[0], times, strict=True)):
        for s, lab in zip(series, labels, strict=True):
            centres = 0.5 * (s.x_edges[:-1] + s.x_edges[1:])
            ax.plot(centres, s.profiles[k], label=lab, lw=1.2)
        ax.set_title(f"t = {t:g} s")
        ax.set_xlim(0.0, 1.05 * reach)
        ax.set_xlabel("x (m)")
        ax.grid(True, alpha=0.3)
    axes[0][0].set_ylabel("h (m)")
    axes[0][0].legend(fontsize=8)
    return save_figure(fig, path)


@dataclass(frozen=True)
class RunSettings(StudySettings):
    """The options every seed validation has: how its simulations are solved and resumed."""

    solver: str = option("ipm", "Convex backend of the COCD runs.")
    tol: float = option(1e-6, "Tolerance of the convex backend.", positive=True)
    fallback: tuple[str, ...] = option(
        ("clarabel",), "Backends tried when a step fails (comma-separated).", kind="names"
    )
    fresh: bool = option(False, "Start the runs over instead of resuming them.")
    runs: Path | None = option(
        None,
        "Folder of the run files and the measurements kept beside them (default: OUT/runs; "
        "a relative path is from the current folder). Runs of several GB can live on a "
        "scratch disk, and two --out can share them, one command at a time: the tables of "
        "the same runs to another --until, beside the first.",
    )

    def __post_init__(self) -> None:
        """An unknown or unusable backend is refused here, before any scene is built."""
        super().__post_init__()
        import solvers

        for name in (self.solver, *self.fallback):
            solvers.requested(name, {}, {})  # its options in the name too


@dataclass(frozen=True)
class CollapseSettings(RunSettings):
    """The options of the cases made of column collapses, which can run several at once."""

    workers: int = option(
        1,
        "Runs simulated at once, each in its own process on one thread (1: one after "
        "another, with the libraries' own threads).",
    )

    def __post_init__(self) -> None:
        super().__post_init__()
        positive_int("workers", self.workers)  # before any scene is built


@dataclass(frozen=True)
class LargeCollapseSettings(CollapseSettings):
    """The options of the cases whose 3D runs reach tens of thousands of spheres: a
    first-order backend at the seed's 3D tolerance, and no fallback."""

    solver: str = option("apgd", "Convex backend of the runs.")
    tol: float = option(
        1e-5, "Tolerance of the convex backend (the seed's 3D choice).", positive=True
    )
    fallback: tuple[str, ...] = option(
        (),
        "Backends tried when a step fails (comma-separated; none by default: a direct "
        "solver on a step of tens of thousands of spheres needs hours and tens of GB, and "
        "a failed step stops the run, which resumes from its last frame).",
        kind="names",
    )


def register(name: str, settings: type, run: Callable[..., Any], **kw: Any) -> Study:
    """Record a seed validation as a ``cocd validate`` study."""
    kw.setdefault("outputs", (name,))
    return study_register(Study(name, "validate", settings, run, **kw))
