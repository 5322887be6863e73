"""``cocd validate avalanche``: avalanche and stop angles of a tilted granular layer.

A 2D layer of discs settled in a box (:func:`cocd.builders.static_box`) is
tilted by rotating gravity, ``g (sin t, -cos t)``, in steps of ``step_deg``
held ``hold`` seconds each:

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

Each friction coefficient is one sequence of holds; its row and holds are kept
in ``OUT/runs/avalanche/cells.csv`` and ``holds.csv``
(:class:`~cocd.bench.results.Results`, keyed on the coefficient and every other
option that shapes the result), so a command run again skips the coefficients
already measured with the same options (``fresh`` redoes them).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from cocd.bench import estimate
from cocd.bench.results import Results
from cocd.bench.study import option
from cocd.errors import CocdError, SolverError
from cocd.validate import _common as base
from cocd.validate._common import RunSettings, register

__all__ = ["STUDY", "Settings", "run", "surface_angle"]

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
    prof = mass_profile(scene, x_bins=edges, connected=False)
    ok = np.isfinite(prof.height)
    slope = float(np.polyfit(prof.x_centres[ok], prof.height[ok], 1)[0])
    return float(tilt_deg - math.degrees(math.atan(slope)))


@dataclass(frozen=True)
class Settings(RunSettings):
    """The options of ``cocd validate avalanche``."""

    mus: tuple[float, ...] = option((0.2, 0.4, 0.8), "Friction coefficients.", kind="floats")
    n: int = option(300, "Discs in the layer.")
    width_d: float = option(50.0, "Box width in diameters.")
    diameter: float = option(0.005, "Mean grain diameter (m).")
    start_deg: float = option(4.0, "First tilt (degrees).")
    step_deg: float = option(0.5, "Tilt step (degrees).")
    max_deg: float = option(45.0, "Largest tilt (degrees).")
    hold: float = option(0.15, "Seconds held at each tilt.")
    dt: float = option(1e-3, "Time step (s).")
    v_flow: float = option(0.01, "Mean grain speed (m/s) above which the layer flows.")
    seeds: int = option(1, "Packings: the layer built with seeds 0 .. seeds-1.")


def run(cfg: Settings, *, out: Path, progress: Callable[[str], Any] = print) -> pd.DataFrame:
    """Avalanche and stop angles of a tilted 2D layer against the friction coefficient.

    ``n`` discs of mean ``diameter`` in a box ``width_d`` diameters wide;
    ``v_flow`` is the flow threshold on the mean grain speed, in units of
    ``sqrt(g d)``. Returns the table written to ``avalanche.csv``, one row per
    friction coefficient.
    """
    from cocd.builders import static_box
    from cocd.stepper import Stepper

    mus = sorted(base.positive_list("mus", cfg.mus))
    n = base.positive_int("n", cfg.n, 10)
    width_d, diameter, step_deg, hold, dt, v_flow = base.positive_list(
        "width_d, diameter, step_deg, hold, dt, v_flow",
        [cfg.width_d, cfg.diameter, cfg.step_deg, cfg.hold, cfg.dt, cfg.v_flow],
    )
    if not (0.0 <= cfg.start_deg < cfg.max_deg < 90.0):
        raise CocdError(f"need 0 <= start_deg < max_deg < 90, got {cfg.start_deg}, {cfg.max_deg}")
    out = Path(out)
    folder = out / "runs" / "avalanche"
    setup = (
        f"n={n} solver={cfg.solver} tol={cfg.tol:g} fallback={cfg.fallback} dt={dt:g} "
        f"hold={hold:g} step={step_deg:g} start={cfg.start_deg:g} d={diameter:g} "
        f"width={width_d:g}d v_flow={v_flow:g}"
    )
    seeds = base.positive_int("seeds", cfg.seeds)
    cells = Results(
        folder / "cells.csv", CELL_COLUMNS, resume=not cfg.fresh, key=("seed", "mu", "setup")
    )
    holds_kept = Results(folder / "holds.csv", HOLD_COLUMNS, resume=not cfg.fresh,
                         key=("setup", "seed", "mu", "phase", "tilt_deg"))  # fmt: skip
    hold_steps = max(1, round(hold / dt))
    threshold = v_flow * math.sqrt(G * diameter)
    # A guide: up to the angle of repose near atan(mu) + 10 deg, then back down.
    holds = [
        2 * (math.degrees(math.atan(mu)) + 10.0 - cfg.start_deg) / step_deg
        for seed in range(seeds)
        for mu in mus
        if not cells.has(seed, mu, setup)
    ]
    estimate.announce(
        "avalanche", [(n, max(h, 2.0) * hold_steps) for h in holds], out=out, progress=progress
    )
    rows, traces = [], []
    for seed, mu in ((seed, mu) for seed in range(seeds) for mu in mus):
        done = cells.get(seed, mu, setup)
        if done is not None:
            rows.append({k: v for k, v in done.items() if k != "setup"})
            mine = holds_kept.frame()
            mine = mine[
                (mine.setup == setup)
                & (mine.seed.astype(int) == seed)
                & np.isclose(mine.mu.astype(float), mu)
            ]
            traces.append(mine.drop(columns="setup").reset_index(drop=True))
            progress(f"avalanche: mu = {mu:g}, seed {seed} already measured ({cells.path})")
            continue
        scene = static_box(
            2, n_grains=n, diameter=diameter, width=width_d * diameter, mu=mu, seed=seed
        )
        stepper = Stepper(scene, dt, solver=cfg.solver, tol=cfg.tol, fallback=cfg.fallback)
        trace: list[dict[str, Any]] = []
        tilt = cfg.start_deg
        progress(
            f"avalanche: mu = {mu:g}, seed {seed}, {scene.n_free} discs, tilting from {tilt:g} deg"
        )
        while _hold(stepper, tilt, hold_steps, "up", trace, seed) <= threshold:
            tilt += step_deg
            if tilt > cfg.max_deg:
                raise CocdError(f"avalanche, mu = {mu:g}: no flow up to {cfg.max_deg:g} deg")
        avalanche_deg = trace[-1]["surface_before_deg"]
        avalanche_tilt = tilt
        progress(f"avalanche: mu = {mu:g} flows at tilt {tilt:g} deg; lowering the tilt")
        while True:
            tilt -= step_deg
            if tilt < 0.0:
                raise CocdError(f"avalanche, mu = {mu:g}: still flowing at 0 deg")
            if _hold(stepper, tilt, hold_steps, "down", trace, seed) <= threshold:
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
            "compute_s": _compute_seconds(stepper.stats()),
        }
        progress(
            f"avalanche: mu = {mu:g}: avalanche at {avalanche_deg:.1f} deg, stops at tilt {tilt:g} "
            f"with its surface at {row['stop_deg']:.1f} deg"
        )
        for hold_row in trace:
            holds_kept.add({**hold_row, "setup": setup}, save=False)
        holds_kept.save()
        cells.add({**row, "setup": setup})  # last: marks the cell done
        rows.append(row)
        traces.append(pd.DataFrame(trace))
    table = pd.DataFrame(rows)
    trace_table = pd.concat(traces, ignore_index=True)
    trace_path = out / "avalanche_trace.csv"
    trace_table.to_csv(trace_path, index=False)
    table = table.astype({"seed": int})
    ensemble = base.ensemble(table, ["mu"], ["avalanche_deg", "stop_deg", "hysteresis_deg"])
    files = base.report.write_table(
        out,
        "avalanche_ensemble",
        ensemble,
        title="Avalanche and stop angles: mean and spread over the packings",
        intro="Per friction coefficient, over the packings (`seeds`): mean and sample standard "
        f"deviation (`_sd`) of the angles, in degrees; the tilt moves by {step_deg:g} deg a "
        "hold, which bounds how finely each packing's angles are known.",
    )
    figures = [
        _figure(out / "avalanche.png", ensemble, trace_table, threshold),
        trace_path,
        *files,
    ]
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
    summary = (
        f"A 2D layer of about {n} discs (d = {diameter * 1e3:g} mm) in a box {width_d:g} d "
        f"wide, {seeds} packing{'s' if seeds > 1 else ''}, tilted in {step_deg:g} deg steps "
        f"held {hold:g} s, `{cfg.solver}` at tol {cfg.tol:g}; flow when the mean speed exceeds "
        f"{v_flow:g} sqrt(g d). Avalanche and stop angles (mean +- spread over the packings): "
        f"**{angles}**. Both angles are read at tilt steps, so a hysteresis is resolved when it "
        "exceeds two tilt steps and twice its spread: "
        f"{'for mu = ' + ', '.join(resolved) if resolved else 'for no mu'}. "
        "A DEM shows avalanche > stop, both growing with friction; seed 001's continuum "
        "model, with a single friction angle, starts and stops at the same angle."
    )
    intro = (
        "`avalanche_tilt_deg`: the first tilt at whose end the layer flows; "
        "`avalanche_deg`: its surface's angle to the horizontal at the start of that hold; "
        "`stop_tilt_deg`: lowering the tilt, the first at whose end it is at rest; "
        "`stop_deg`: its surface's angle to the horizontal then (the angle of repose); "
        "`hysteresis_deg` = avalanche - stop. Every hold is in `avalanche_trace.csv`."
    )
    base.finish(
        out,
        "avalanche",
        "Avalanche and stop angles (seed 001)",
        table,
        intro,
        summary,
        figures,
        progress,
    )
    return table


def _compute_seconds(stats: pd.DataFrame) -> float:
    """Detection, set-up and solve seconds summed over a stepper's steps."""
    return float((stats.detect_time + stats.setup_time + stats.solve_time).sum())


def _hold(
    stepper: Any, tilt: float, steps: int, phase: str, trace: list[dict[str, Any]], seed: int
) -> float:
    """Tilt gravity by ``tilt`` degrees, take ``steps`` steps, record the hold in ``trace``;
    returns the mean grain speed at its end."""
    scene = stepper.scene
    a = math.radians(tilt)
    scene.gravity[:] = (G * math.sin(a), -G * math.cos(a))
    before = surface_angle(scene, tilt)
    try:
        stepper.run(steps)
    except SolverError as exc:
        raise CocdError(f"avalanche, mu = {scene.mu:g}, tilt {tilt:g} deg: {exc}") from None
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


def _figure(path: Path, ensemble: pd.DataFrame, trace: pd.DataFrame, threshold: float) -> Path:
    """Seed 001's Fig. 1: the surface's angle against the tilt, up and down, per friction
    coefficient (first packing); the grains' mean speed; the angles against mu."""
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
