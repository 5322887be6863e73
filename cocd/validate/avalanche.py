"""``cocd validate avalanche`` (2D) and ``avalanche3d``: avalanche and stop angles of a
tilted granular layer, and the grain friction that gives a target avalanche angle.

A layer of discs, or of spheres, settled in a box (:func:`cocd.builders.static_box`;
in 3D ``length_d`` along the slope and ``width_d`` across it, between sidewalls of
friction ``side_mu``) is tilted by rotating gravity,
``g (sin t, -cos t)`` or ``g (sin t, 0, -cos t)``, in steps of ``step_deg`` held
``hold`` seconds each:

- going up from ``start_deg``, the layer flows at the end of some hold (mean
  grain speed above ``v_flow``): the **avalanche angle** is its surface's angle
  to the horizontal at the start of that hold (the settled surface is nearly
  flat in the box, so close to the tilt);
- then going down one step at a time, the layer keeps flowing until a hold
  ends at rest: that tilt is the **stop tilt**, and the surface's angle to the
  horizontal then (fitted to the free surface away from the walls) is the
  **stop angle**, the angle of repose.

The hysteresis is ``avalanche - stop angle``: a granular material starts to
flow at a steeper slope than the one at which it stops (a DEM shows it; the
continuum model of seed 001, with one friction angle, cannot). Both angles
grow with the grains' friction coefficient.

Seed 001 sets its continuum friction to the tangent of its beads' measured avalanche
angle, 23.7 +- 1 degrees. A DEM's grain friction is not that coefficient: the
calibration (``<name>_calibration.csv``) interpolates the coefficient whose layer
avalanches at ``target_deg``, for a run at that coefficient to check.

Each friction coefficient and packing is one sequence of holds (``workers`` of them
at once); its row and holds are kept in ``cells.csv`` and ``holds.csv`` under
``OUT/runs/<name>`` (or ``--runs``; :class:`~cocd.bench.results.Results`, keyed
on the coefficient and every other option that shapes the result), so a command run
again skips the coefficients already measured with the same options (``fresh``
redoes them).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
import pandas as pd

from cocd.bench import estimate
from cocd.bench.results import Results
from cocd.bench.study import option
from cocd.errors import CocdError, SolverError
from cocd.outputs import writable_folder
from cocd.validate import _common as base
from cocd.validate._common import RunSettings, register

if TYPE_CHECKING:
    from cocd.scene import Scene

__all__ = ["STUDY", "STUDY_3D", "Settings", "Settings3D", "run", "surface_angle"]

G = 9.81
#: A friction coefficient's result, and one hold of its sequence.
CELL_COLUMNS = [
    "seed", "mu", "n_grains", "avalanche_tilt_deg", "avalanche_deg", "stop_tilt_deg", "stop_deg",
    "hysteresis_deg", "holds", "steps", "penetration_max", "compute_s", "setup",
]  # fmt: skip
HOLD_COLUMNS = [
    "seed", "mu", "phase", "tilt_deg", "t", "mean_speed", "surface_before_deg", "surface_after_deg",
    "setup",
]  # fmt: skip


#: The narrowest box whose surface :func:`surface_angle` can fit, in diameters: 3 from
#: each wall, at least 4 between, and room for the layer to pull off its walls.
MIN_WIDTH_D = 12.0


def surface_angle(scene: Any, tilt_deg: float, *, margin_d: float = 3.0) -> float:
    """Angle (degrees) of the layer's free surface to the horizontal, the box tilted by
    ``tilt_deg`` (gravity rotated towards +x).

    The surface heights (:func:`cocd.measure.mass_profile` on bins two mean diameters
    wide, ``margin_d`` diameters away from the side walls) are fitted by a line of
    slope ``s`` in the box; the surface then makes ``tilt - atan(s)`` with the
    horizontal (a flat surface, ``s = 0``, is inclined by the tilt).
    """
    from cocd.measure import mass_profile

    free = scene.free
    x = scene.positions[free]
    d = 2.0 * float(scene.radii[free].mean())
    lo = float(np.min(x[:, 0])) + margin_d * d
    hi = float(np.max(x[:, 0])) - margin_d * d
    if hi - lo < 4.0 * d:
        raise CocdError("the layer is too narrow to fit its surface")
    edges = np.arange(lo, hi + 1e-12, 2.0 * d)
    across = None
    if x.shape[1] == 3:
        # In 3D: strips two diameters wide across the box, as far from its side walls;
        # the surface is their heights' mean (one strip if the box is too narrow).
        y_lo, y_hi = float(np.min(x[:, 1])), float(np.max(x[:, 1]))
        if y_hi - y_lo >= 2.0 * margin_d * d + 2.0 * d:
            y_lo, y_hi = y_lo + margin_d * d, y_hi - margin_d * d
        across = np.arange(y_lo, y_hi + 1e-12, 2.0 * d)
        if across.size < 2:
            across = np.array([y_lo, y_hi])
    prof = mass_profile(scene, x_bins=edges, y_bins=across, connected=False)
    height = prof.mean_height
    ok = np.isfinite(height)
    slope = float(np.polyfit(prof.x_centres[ok], height[ok], 1)[0])
    return float(tilt_deg - math.degrees(math.atan(slope)))


@dataclass(frozen=True)
class Settings(RunSettings):
    """The options of ``cocd validate avalanche``."""

    #: Discs (2) or spheres (3); the name of the outputs.
    dim: ClassVar[int] = 2
    name: ClassVar[str] = "avalanche"

    mus: tuple[float, ...] = option((0.2, 0.4, 0.8), "Friction coefficients.", kind="floats")
    n: int = option(300, "Discs in the layer.")
    width_d: float = option(50.0, "Box width in diameters.")
    diameter: float = option(0.005, "Mean grain diameter (m).")
    start_deg: float = option(4.0, "First tilt (degrees).")
    step_deg: float = option(0.5, "Tilt step (degrees).")
    max_deg: float = option(45.0, "Largest tilt (degrees).")
    hold: float = option(0.15, "Seconds held at each tilt.")
    dt: float = option(1e-3, "Time step (s).")
    v_flow: float = option(
        0.01, "Mean grain speed, in units of sqrt(g d), above which the layer flows."
    )
    seeds: int = option(1, "Packings: the layer built with seeds 0 .. seeds-1.")
    target_deg: float = option(
        23.7,
        "Avalanche angle the grain friction is calibrated to (degrees; seed 001's glass "
        "beads: 23.7 +- 1).",
    )
    workers: int = option(
        1,
        "Sequences run at once, each in its own process on one thread (1: one after "
        "another, with the libraries' own threads).",
    )


@dataclass(frozen=True)
class Settings3D(Settings):
    """The options of ``cocd validate avalanche3d``: the same tilt in 3D."""

    dim: ClassVar[int] = 3
    name: ClassVar[str] = "avalanche3d"

    solver: str = option("apgd", "Convex backend of the COCD runs.")
    tol: float = option(1e-5, "Tolerance of the convex backend.", positive=True)
    n: int = option(2000, "Spheres in the layer.")
    length_d: float = option(40.0, "Box length along the slope, in diameters.")
    width_d: float = option(8.0, "Box width across the slope, in diameters.")
    start_deg: float = option(12.0, "First tilt (degrees).")
    side_mu: float = option(
        0.0,
        "Friction of the box's two walls along the slope, the channel's sidewalls (0: a "
        "wide channel, as seed 001's 20 cm flume is at 400 bead diameters).",
    )


@dataclass(frozen=True)
class _Sequence:
    """One packing and friction coefficient's tilt sequence (a worker's job)."""

    cfg: Settings
    seed: int
    mu: float
    hold_steps: int
    threshold: float

    @property
    def label(self) -> str:
        return f"{self.cfg.name}: mu = {self.mu:g}, seed {self.seed}"


def run(cfg: Settings, *, out: Path, progress: Callable[[str], Any] = print) -> pd.DataFrame:
    """Avalanche and stop angles of a tilted layer against the friction coefficient.

    ``n`` grains (discs or spheres, ``cfg.dim``) of mean ``diameter`` in a box
    ``width_d`` diameters wide (in 3D, ``length_d`` long and ``width_d`` across);
    ``v_flow`` is the flow threshold on the mean grain speed, in units of ``sqrt(g d)``.
    Returns the table written to ``<name>.csv`` (``avalanche`` or ``avalanche3d``), one
    row per friction coefficient and packing.
    """

    mus = sorted(set(base.positive_list("mus", cfg.mus)))
    n = base.positive_int("n", cfg.n, 10)
    width_d, diameter, step_deg, hold, dt, v_flow = base.positives(
        width_d=cfg.width_d, diameter=cfg.diameter, step_deg=cfg.step_deg, hold=cfg.hold,
        dt=cfg.dt, v_flow=cfg.v_flow,
    )  # fmt: skip
    if not (math.isfinite(cfg.target_deg) and 0.0 < cfg.target_deg < 90.0):
        raise CocdError(f"target_deg must be between 0 and 90 degrees, got {cfg.target_deg!r}")
    along = "width_d"
    length_d = width_d
    if isinstance(cfg, Settings3D):
        along, length_d = "length_d", base.positives(length_d=cfg.length_d)[0]
    if length_d < MIN_WIDTH_D:
        raise CocdError(
            f"{along} must be at least {MIN_WIDTH_D:g} diameters (the surface is fitted 3 "
            f"diameters away from each end wall), got {length_d:g}"
        )
    if not (0.0 <= cfg.start_deg < cfg.max_deg < 90.0):
        raise CocdError(f"need 0 <= start_deg < max_deg < 90, got {cfg.start_deg}, {cfg.max_deg}")
    out = Path(out)
    name = cfg.name
    folder = base.runs_folder(cfg, out) / name
    writable_folder(folder, "--runs" if cfg.runs is not None else "--out")
    setup = (
        f"n={n} solver={cfg.solver} tol={cfg.tol:g} fallback={cfg.fallback} dt={dt:g} "
        f"hold={hold:g} step={step_deg:g} start={cfg.start_deg:g} d={diameter:g} "
        f"width={width_d:g}d v_flow={v_flow:g}"
    )
    if isinstance(cfg, Settings3D):
        if not (math.isfinite(cfg.side_mu) and cfg.side_mu >= 0.0):
            raise CocdError(f"side_mu must be a number >= 0, got {cfg.side_mu!r}")
        setup += f" length={length_d:g}d side_mu={cfg.side_mu:g}"
    seeds = base.positive_int("seeds", cfg.seeds)
    workers = base.positive_int("workers", cfg.workers)
    cells = Results(
        folder / "cells.csv", CELL_COLUMNS, resume=not cfg.fresh, key=("seed", "mu", "setup")
    )
    holds_kept = Results(folder / "holds.csv", HOLD_COLUMNS, resume=not cfg.fresh,
                         key=("setup", "seed", "mu", "phase", "tilt_deg"))  # fmt: skip
    hold_steps = max(1, round(hold / dt))
    threshold = v_flow * math.sqrt(G * diameter)
    jobs = []
    # Coefficient by coefficient, so that sequences running at once are of different
    # packings: each builds its own (a packing is built once, then read from the cache).
    for mu, seed in ((mu, seed) for mu in mus for seed in range(seeds)):
        if cells.has(seed, mu, setup):
            progress(f"{name}: mu = {mu:g}, seed {seed} already measured ({cells.path})")
        else:
            jobs.append(_Sequence(cfg, seed, mu, hold_steps, threshold))
    # A guide: up to the angle of repose near atan(mu) + 10 deg, then back down.
    holds = [2 * (math.degrees(math.atan(j.mu)) + 10.0 - cfg.start_deg) / step_deg for j in jobs]
    estimate.announce(
        name,
        [(n, max(h, 2.0) * hold_steps) for h in holds],
        out=out,
        progress=progress,
        workers=min(workers, max(1, len(jobs))),
    )

    def keep(result: tuple[dict[str, Any], list[dict[str, Any]]]) -> None:
        row, trace = result
        for hold_row in trace:
            holds_kept.add({**hold_row, "setup": setup}, save=False)
        holds_kept.save()
        cells.add({**row, "setup": setup})  # last: marks the sequence done

    if workers == 1 or len(jobs) < 2:
        for job in jobs:
            keep(_sequence(job, progress))
    else:
        # Each packing is built once, several at once, before the sequences that share
        # it start (else two sequences of one new packing would both build it).
        firsts = list({job.seed: job for job in jobs}.values())
        if len(firsts) > 1:
            base.run_apart(_build, firsts, min(workers, len(firsts)), progress)
        else:
            _build(firsts[0], progress)
        base.run_apart(
            _sequence, jobs, min(workers, len(jobs)), progress, on_done=lambda _, r: keep(r)
        )
    rows, traces = [], []
    kept_holds = holds_kept.frame()
    for seed, mu in ((seed, mu) for seed in range(seeds) for mu in mus):
        done = cells.get(seed, mu, setup)
        if done is None:  # not reachable: every sequence either was kept or just ran
            raise CocdError(f"{name}: mu = {mu:g}, seed {seed} has no result")
        rows.append({k: v for k, v in done.items() if k != "setup"})
        mine = kept_holds[
            (kept_holds.setup == setup)
            & (kept_holds.seed.astype(int) == seed)
            & np.isclose(kept_holds.mu.astype(float), mu)
        ]
        traces.append(mine.drop(columns="setup").reset_index(drop=True))
    table = pd.DataFrame(rows)
    trace_table = pd.concat(traces, ignore_index=True)
    trace_path = out / f"{name}_trace.csv"
    trace_table.to_csv(trace_path, index=False)
    table = table.astype({"seed": int})
    ensemble = base.ensemble(table, ["mu"], ["avalanche_deg", "stop_deg", "hysteresis_deg"])
    files = base.report.write_table(
        out,
        f"{name}_ensemble",
        ensemble,
        title="Avalanche and stop angles: mean and spread over the packings",
        intro="Per friction coefficient, over the packings (`seeds`): mean and sample standard "
        f"deviation (`_sd`) of the angles, in degrees; the tilt moves by {step_deg:g} deg a "
        "hold, which bounds how finely each packing's angles are known.",
    )
    pm = base.pm
    angles = "; ".join(
        f"mu {r.mu:g}: {pm(r, 'avalanche_deg')} and {pm(r, 'stop_deg')} deg, hysteresis "
        f"{pm(r, 'hysteresis_deg')} deg"
        for _, r in ensemble.iterrows()
    )
    resolved = [
        f"{r.mu:g}"
        for _, r in ensemble.iterrows()
        if r.hysteresis_deg > 2.0 * step_deg
        and (not np.isfinite(r.hysteresis_deg_sd) or r.hysteresis_deg > 2.0 * r.hysteresis_deg_sd)
    ]
    calibration = calibrate(ensemble, cfg.target_deg)
    files += base.report.write_table(
        out,
        f"{name}_calibration",
        calibration,
        title="Grain friction for a target avalanche angle",
        intro="`mu`: the friction coefficient at which the mean avalanche angle "
        f"(`{name}_ensemble`) reaches `target_deg`, by linear interpolation between the "
        "two coefficients that bracket it (`mu_below`, `mu_above`, with their mean angles); "
        "`mu_low` and `mu_high`: the same for the target minus and plus "
        f"{CALIBRATION_BAND_DEG:g} deg (seed 001's band); NaN where the target is not "
        "bracketed. A run at `mu` checks it: `--mus` with that value.",
    )
    figures = [
        _figure(out / f"{name}.png", ensemble, trace_table, threshold, cfg.target_deg),
        trace_path,
        *files,
    ]
    grains = "discs" if cfg.dim == 2 else "spheres"
    box = (
        f"a box {width_d:g} d wide"
        if not isinstance(cfg, Settings3D)
        else f"a box {length_d:g} d long and {width_d:g} d wide, sidewall friction {cfg.side_mu:g}"
    )
    cal = calibration.iloc[0]
    found = (
        f"the mean avalanche angle reaches {cal.target_deg:g} deg at mu = {cal.mu:.3g}"
        if np.isfinite(cal.mu)
        else f"no two coefficients bracket an avalanche angle of {cal.target_deg:g} deg"
    )
    summary = (
        f"A {cfg.dim}D layer of about {n} {grains} (d = {diameter * 1e3:g} mm) in {box}, "
        f"{seeds} packing{'s' if seeds > 1 else ''}, tilted in {step_deg:g} deg steps "
        f"held {hold:g} s, `{cfg.solver}` at tol {cfg.tol:g}; flow when the mean speed exceeds "
        f"{v_flow:g} sqrt(g d). Avalanche and stop angles (mean +- spread over the packings): "
        f"**{angles}**. Both angles are read at tilt steps, so a hysteresis is resolved when it "
        "exceeds two tilt steps and twice its spread: "
        f"{'for mu = ' + ', '.join(resolved) if resolved else 'for no mu'}. "
        "A DEM shows avalanche > stop, both growing with friction; seed 001's continuum "
        "model, with a single friction angle, starts and stops at the same angle. "
        f"Calibration: {found}."
    )
    intro = (
        "`avalanche_tilt_deg`: the first tilt at whose end the layer flows; "
        "`avalanche_deg`: its surface's angle to the horizontal at the start of that hold; "
        "`stop_tilt_deg`: lowering the tilt, the first at whose end it is at rest; "
        "`stop_deg`: its surface's angle to the horizontal then (the angle of repose); "
        f"`hysteresis_deg` = avalanche - stop. Every hold is in `{name}_trace.csv`."
    )
    base.finish(
        out,
        name,
        f"Avalanche and stop angles in {cfg.dim}D (seed 001)",
        table,
        intro,
        summary,
        figures,
        progress,
    )
    return table


#: Seed 001's band on its beads' avalanche angle, 23.7 +- 1 degrees.
CALIBRATION_BAND_DEG = 1.0


def calibrate(ensemble: pd.DataFrame, target_deg: float) -> pd.DataFrame:
    """The friction coefficient at which the mean avalanche angle reaches ``target_deg``,
    and those of the target minus and plus :data:`CALIBRATION_BAND_DEG`: linear
    interpolation between the two coefficients of ``ensemble`` that bracket it (the first
    such pair going up in mu); NaN where none does. One row."""
    by_mu = ensemble.sort_values("mu")
    mu = by_mu.mu.to_numpy(dtype=float)
    angle = by_mu.avalanche_deg.to_numpy(dtype=float)

    def crossing(target: float) -> tuple[float, int]:
        for k in range(len(mu) - 1):
            lo, hi = angle[k], angle[k + 1]
            if min(lo, hi) <= target <= max(lo, hi) and lo != hi:
                return float(mu[k] + (target - lo) / (hi - lo) * (mu[k + 1] - mu[k])), k
        return math.nan, -1

    at, k = crossing(target_deg)
    return pd.DataFrame(
        [
            {
                "target_deg": target_deg,
                "mu": at,
                "mu_low": crossing(target_deg - CALIBRATION_BAND_DEG)[0],
                "mu_high": crossing(target_deg + CALIBRATION_BAND_DEG)[0],
                "mu_below": mu[k] if k >= 0 else math.nan,
                "angle_below_deg": angle[k] if k >= 0 else math.nan,
                "mu_above": mu[k + 1] if k >= 0 else math.nan,
                "angle_above_deg": angle[k + 1] if k >= 0 else math.nan,
            }
        ]
    )


def _sequence(
    job: _Sequence, progress: Callable[[str], Any]
) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """Tilt one packing up until it flows, then down until it stops: its row of the
    table and its holds. An error names the sequence (several may run at once)."""
    try:
        return _tilt(job, progress)
    except CocdError as exc:
        raise CocdError(f"{job.label}: {exc}") from None


def _build(job: _Sequence, progress: Callable[[str], Any]) -> None:
    """Build (or read from the cache) the packing of ``job``'s seed."""
    try:
        _box(job)
    except CocdError as exc:
        raise CocdError(f"{job.cfg.name}: packing {job.seed}: {exc}") from None


def _box(job: _Sequence) -> Scene:
    """The settled layer of ``job``'s seed with its friction (packings are cached)."""
    from cocd.builders import static_box

    cfg, seed, mu = job.cfg, job.seed, job.mu
    return static_box(
        cfg.dim,
        n_grains=cfg.n,
        diameter=cfg.diameter,
        width=cfg.width_d * cfg.diameter,
        length=cfg.length_d * cfg.diameter if isinstance(cfg, Settings3D) else None,
        mu=mu,
        mu_side=cfg.side_mu if isinstance(cfg, Settings3D) else None,
        seed=seed,
    )


def _tilt(
    job: _Sequence, progress: Callable[[str], Any]
) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    from cocd.stepper import Stepper

    cfg, seed, mu = job.cfg, job.seed, job.mu
    scene = _box(job)
    stepper = Stepper(scene, cfg.dt, solver=cfg.solver, tol=cfg.tol, fallback=cfg.fallback)
    trace: list[dict[str, Any]] = []
    tilt = cfg.start_deg
    grains = "discs" if cfg.dim == 2 else "spheres"
    progress(f"{job.label}, {scene.n_free} {grains}, tilting from {tilt:g} deg")
    while _hold(stepper, tilt, job.hold_steps, "up", trace, seed) <= job.threshold:
        tilt += cfg.step_deg
        if tilt > cfg.max_deg:
            raise CocdError(f"no flow up to {cfg.max_deg:g} deg")
    avalanche_deg = trace[-1]["surface_before_deg"]
    avalanche_tilt = tilt
    progress(f"{job.label} flows at tilt {tilt:g} deg; lowering the tilt")
    while True:
        tilt -= cfg.step_deg
        if tilt < 0.0:
            raise CocdError("still flowing at 0 deg")
        if _hold(stepper, tilt, job.hold_steps, "down", trace, seed) <= job.threshold:
            break
    row = {
        "seed": seed,
        "mu": mu,
        "n_grains": scene.n_free,
        "avalanche_tilt_deg": avalanche_tilt,
        "avalanche_deg": avalanche_deg,
        "stop_tilt_deg": tilt,
        "stop_deg": trace[-1]["surface_after_deg"],
        "hysteresis_deg": avalanche_deg - trace[-1]["surface_after_deg"],
        "holds": len(trace),
        "steps": stepper.step_count,
        "penetration_max": float(stepper.stats().penetration.max()),
        "compute_s": base.compute_seconds(stepper.stats()),
    }
    progress(
        f"{job.label}: avalanche at {avalanche_deg:.1f} deg, stops at tilt {tilt:g} "
        f"with its surface at {row['stop_deg']:.1f} deg"
    )
    return row, trace


def _hold(
    stepper: Any, tilt: float, steps: int, phase: str, trace: list[dict[str, Any]], seed: int
) -> float:
    """Tilt gravity by ``tilt`` degrees, take ``steps`` steps, record the hold in ``trace``;
    returns the mean grain speed at its end."""
    scene = stepper.scene
    a = math.radians(tilt)
    # Towards +x, the box's floor normal to the last axis: (sin, -cos) or (sin, 0, -cos).
    scene.gravity[:] = 0.0
    scene.gravity[0] = G * math.sin(a)
    scene.gravity[-1] = -G * math.cos(a)
    before = surface_angle(scene, tilt)
    try:
        stepper.run(steps)
    except SolverError as exc:
        raise CocdError(f"tilt {tilt:g} deg: {exc}") from None
    speed = float(np.mean(np.linalg.norm(scene.velocities[scene.free], axis=1)))
    trace.append(
        {
            "seed": seed,
            "mu": scene.mu,
            "phase": phase,
            "tilt_deg": tilt,
            "t": scene.time,
            "mean_speed": speed,
            "surface_before_deg": before,
            "surface_after_deg": surface_angle(scene, tilt),
        }
    )
    return speed


def _figure(
    path: Path, ensemble: pd.DataFrame, trace: pd.DataFrame, threshold: float, target: float
) -> Path:
    """Seed 001's Fig. 1: the surface's angle against the tilt, up and down, per friction
    coefficient (first packing); the grains' mean speed; the angles against mu, with the
    calibration target and seed 001's band on it."""
    plt = base.pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    first = trace[trace.seed.astype(int) == int(trace.seed.astype(int).min())]
    for mu, sub in first.groupby("mu"):
        for phase, style in (("up", "-o"), ("down", "--s")):
            part = sub[sub.phase == phase]
            axes[0].plot(part.tilt_deg, part.surface_after_deg, style, ms=3,
                         label=f"mu {mu:g} {phase}")  # fmt: skip
            axes[1].semilogy(
                part.tilt_deg, np.maximum(part.mean_speed, 1e-12), style, ms=3,
                label=f"mu {mu:g} {phase}",
            )  # fmt: skip
    lim = [float(first.tilt_deg.min()), float(first.tilt_deg.max())]
    axes[0].plot(lim, lim, "k:", lw=0.8, label="surface = tilt")
    axes[0].set_xlabel("tilt (deg)")
    axes[0].set_ylabel("surface angle at the end of the hold (deg)")
    axes[0].legend(fontsize=7)
    axes[0].grid(True, alpha=0.3)
    axes[1].axhline(threshold, color="k", lw=0.8, ls=":")
    axes[1].set_xlabel("tilt (deg)")
    axes[1].set_ylabel("mean grain speed at the end of the hold (m/s)")
    axes[1].legend(fontsize=7)
    axes[1].grid(True, alpha=0.3)
    for column, style, label in (
        ("avalanche_deg", "o-", "avalanche (surface angle)"),
        ("stop_deg", "s-", "stop (surface angle)"),
    ):
        axes[2].errorbar(ensemble.mu, ensemble[column], yerr=ensemble[f"{column}_sd"].fillna(0.0),
                         fmt=style, capsize=3, label=label)  # fmt: skip
    axes[2].axhspan(target - CALIBRATION_BAND_DEG, target + CALIBRATION_BAND_DEG, color="0.85",
                    label=f"target {target:g} +- {CALIBRATION_BAND_DEG:g} deg")  # fmt: skip
    axes[2].set_xlabel("mu")
    axes[2].set_ylabel("angle (deg)")
    axes[2].legend()
    axes[2].grid(True, alpha=0.3)
    return base.save_figure(fig, path)


STUDY = register(
    "avalanche",
    Settings,
    run,
    help="Seed 001: avalanche and stop angles of a tilted layer against grain friction.",
)
STUDY_3D = register(
    "avalanche3d",
    Settings3D,
    run,
    help="Seed 001: avalanche and stop angles of a tilted 3D layer of spheres; the grain "
    "friction for a target avalanche angle.",
)
