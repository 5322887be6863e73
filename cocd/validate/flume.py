"""``cocd validate flume``: seed 001's flume collapses with its glass beads (runs B00 to
B20), as grains.

A pile ``L0 x H0`` (seed 001: aspect ratio about 0.5, ``H0`` about 10 cm) stands
against the back wall of a channel ``W = 6 cm`` wide whose glass sidewalls have
friction ``mu_w = 0.23``, on an erodible bed of the same grains about 2 cm thick,
and is released at t = 0; the whole flume is tilted by 0 to 20 degrees. Seed 001
(Sec. 4.2, its Table 2) measures for each slope:

- the rest time ``t_f``: when no velocity exceeds 0.01 m/s anywhere;
- the final upslope height ``H_f``, at the back wall;
- the runout from the gate ``L_f - L0``: the length of the continuous deposit whose
  height exceeds 2 mm (Balmforth and Kerswell 2005);

and states that the front stops before the whole flow does. The experiment's 0.5 mm
beads are far out of reach: the grains here are the largest that keep the channel 15
diameters wide (4 mm), and the grain friction is the one whose layers avalanche at
the beads' 23.7 +- 1 degrees (``cocd validate avalanche3d``), not the continuum's 0.44.

The runs are long (tens of thousands of spheres, hundreds of steps): every
simulation is a resumable run file, continued from its last frame when the command
is run again (:func:`cocd.validate._common.collapse_series`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from cocd.bench import estimate
from cocd.bench.study import option
from cocd.errors import CocdError
from cocd.validate import _common as base
from cocd.validate._common import CollapseSeries, LargeCollapseSettings, register

__all__ = ["SEED_SLOPES", "STUDY", "Settings", "run"]

FloatArray = NDArray[np.float64]

#: Seed 001's bed inclinations for its glass beads, runs B00 to B20 (degrees).
SEED_SLOPES = (0.0, 5.0, 10.0, 15.0, 20.0)

#: Bins of the bed downstream of the final front that give its surface at the end.
FAR_BINS = 5

#: The front has settled once it stays within one bin (a diameter) of its final place.
#: Its reading changes in whole bins, each a diameter give or take the grains' places
#: (3.99 or 4.05 mm for 4 mm grains), so the test allows half a bin more: a one-bin
#: flicker is always in, two bins always out.
FRONT_BINS = 1.5

#: Rest times robust to rattlers: from when no grain of the flow is faster than the rest
#: speed but at most this share of the pile's grain count (0.1 % and, for the criterion's
#: sensitivity, 1 %); the grains counted are the flow's, the bed under it included.
FEW = {"permil": 1e-3, "pct": 1e-2}
#: The figure's line style for each share of ``FEW``, in its order, and its word in the title.
FEW_STYLES = (("-", "solid"), ("--", "dashed"))


@dataclass(frozen=True)
class Settings(LargeCollapseSettings):
    """The options of ``cocd validate flume``."""

    slopes: tuple[float, ...] = option(
        SEED_SLOPES, "Flume inclinations (degrees; seed 001's B00 to B20).", kind="numbers"
    )
    diameter: float = option(
        0.004, "Mean grain diameter (m); 4 mm keeps the 6 cm channel 15 diameters wide."
    )
    length: float = option(0.20, "Pile length L0 along the flume (m).")
    height: float = option(0.10, "Pile height H0 (m); seed 001: a = H0 / L0 about 0.5.")
    width: float = option(0.06, "Channel width W (m; seed 001's 6 cm).")
    layer: float = option(0.02, "Thickness of the erodible bed (m; seed 001's 2 cm).")
    bed_length: float = option(1.52, "Length of the flume's bed (m; seed 001's 152 cm).")
    mu: float = option(
        0.25,
        "Friction of the grains and of the back wall (0.25: layers of these spheres "
        "avalanche at 24.5 +- 0.8 degrees in cocd validate avalanche3d, inside the beads' "
        "23.7 +- 1).",
    )
    side_mu: float = option(0.23, "Friction of the sidewalls (seed 001's beads on glass).")
    dt: float = option(1e-2, "Time step (s).")
    until: float = option(
        3.0, "Simulated time (s); a later one takes the kept runs on from their end."
    )
    rest_speed: float = option(
        0.01, "At rest: no free grain faster than this (m/s; seed 001's criterion)."
    )
    threshold: float = option(
        0.002, "The deposit's edge: where it stands less than this above the bed (m)."
    )
    seeds: int = option(1, "Packings: the grains' radii drawn with seeds 0 .. seeds-1.")
    kept_only: bool = option(
        False,
        "Table the runs of those asked that are already measured and run none (the others "
        "are said and left out): the tables of a set of packings still being made.",
    )


def run(cfg: Settings, *, out: Path, progress: Callable[[str], Any] = print) -> pd.DataFrame:
    """Collapse seed 001's pile in its flume at each slope; rest time, height and runout.

    Returns the table written to ``flume.csv``: one row per slope and packing.
    """
    slopes = sorted({float(s) for s in cfg.slopes})
    if not slopes or any(not (0.0 <= s < 90.0) for s in slopes):
        raise CocdError(f"slopes must be in [0, 90) degrees, got {list(cfg.slopes)!r}")
    d, L0, H0, W, layer, bed, dt, until, rest_speed, threshold = base.positives(
        diameter=cfg.diameter, length=cfg.length, height=cfg.height, width=cfg.width,
        layer=cfg.layer, bed_length=cfg.bed_length, dt=cfg.dt, until=cfg.until,
        rest_speed=cfg.rest_speed, threshold=cfg.threshold,
    )  # fmt: skip
    if W < 2.0 * d:
        raise CocdError(f"width must be at least 2 diameters ({2.0 * d:g} m), got {W:g}")
    if bed < L0 + 10.0 * d:
        raise CocdError(
            f"bed_length must exceed the pile's length {L0:g} m by 10 diameters, got {bed:g}"
        )
    if not (math.isfinite(cfg.side_mu) and cfg.side_mu >= 0.0):
        raise CocdError(f"side_mu must be a number >= 0, got {cfg.side_mu!r}")
    seeds = base.positive_int("seeds", cfg.seeds)
    base.whole_steps(until, dt)
    out = Path(out)
    cases = [(seed, slope) for seed in range(seeds) for slope in slopes]
    jobs = []
    for seed, slope in cases:
        params = {
            "dim": 3,
            "diameter": d,
            "length": L0,
            "height": H0,
            "width": W,
            "slope_deg": slope,
            "mu": cfg.mu,
            "mu_side": float(cfg.side_mu),
            "bed": "rough",
            "erodible_thickness": layer,
            "bed_length": bed,
        }
        label = f"slope{slope:g}_d{d * 1e3:g}mm_W{W * 100:g}cm_L{bed:g}m_mu{cfg.mu:g}"
        # Every step is a frame: a step can take a minute, so a stopped run loses one.
        jobs.append(
            base.collapse_job(
                out,
                "flume",
                label,
                seed,
                params,
                cfg,
                what=f"slope {slope:g} deg, W = {W / d:.3g} d",
                dt=dt,
                until=until,
                frame_dt=dt,
                profile_times=[0.0, until],
                surface=True,
                few=tuple(FEW.values()),
            )
        )
    if cfg.kept_only:
        if cfg.fresh:
            raise CocdError(
                "--kept-only tables the kept runs and --fresh makes them again: give one"
            )
        jobs, cases = base.kept_only(jobs, cases, progress)
    estimate.announce(
        "flume",
        [(job.free_grains, job.steps) for job in jobs],
        out=out,
        progress=progress,
        workers=cfg.workers,
    )
    made = base.collapse_runs(jobs, cfg.workers, progress)
    table = pd.DataFrame(
        [
            _row(s, seed, slope, L0, W, rest_speed, threshold)
            for (seed, slope), s in zip(cases, made, strict=True)
        ]
    )
    rest_times = ["t_f_s", *(f"t_f_{name}_s" for name in FEW)]  # not every packing's
    ensemble = base.ensemble(
        table,
        ["slope_deg"],
        [*rest_times, "t_front_s", "Hf_m", "Hf_over_H0", "runout_m", "runout_over_L0"],
        counts=["still_moving", "reached_end"],
        reached=rest_times,
    )
    files = base.report.write_table(
        out,
        "flume_ensemble",
        ensemble,
        title="Seed 001's flume collapses: mean and spread over the packings",
        intro="Per slope, over the packings (`seeds`): mean and sample standard deviation "
        "(`_sd`, empty for one packing); `still_moving`: packings not at rest at the end "
        "(no rest time); `reached_end`: packings whose deposit reached the bed's end; a "
        "rest time's `_n`: the packings that reached it, over which its mean and spread "
        "are taken.",
    )
    trace = _trace(made, cases, L0)
    files += base.report.write_table(
        out,
        "flume_trace",
        trace,
        title="Seed 001's flume collapses: the front and the largest speeds at every frame",
        intro="Per slope and packing, at every saved frame: `front_m`, the front "
        "(:func:`cocd.measure.surface_front`) from the gate (x = L0; seed 001's Fig. 9a); "
        "`speed_max_flow`, `speed_max`: the largest speed of a free grain of the flow (not "
        "past the final front by more than a diameter) and of any free grain (m/s); "
        "`speed_permil_flow`, `speed_pct_flow`: the speed that all grains of the flow but "
        "0.1 % and 1 % of the pile's grain count stay at or below (m/s).",
        floatfmt=".4g",
    )
    reach = L0 + float(np.nanmax(table.runout_m))
    figure = _figure(out / "flume_profiles.png", made, cases, L0, reach, cfg)
    front_figure = _front_figure(out / "flume_front.png", trace, table, rest_speed, cfg)
    summary = _summary(ensemble, table, d, L0, H0, W, layer, bed, dt, until, cfg)
    intro = (
        "Seed 001's measures, on the final frame's profile (the highest grain across the "
        "width, in bins one diameter wide) above the erodible bed's surface (`bed_top_m`, "
        "above the glued grains: the layer's median top downstream of the deposit's front; "
        "the start's, `bed_top0_m`, downstream of the pile, when the deposit reaches the "
        "end): `Hf_m`, the height at the back wall; "
        "`runout_m`, from the gate (x = L0) to the first bin where the deposit stands less "
        f"than `threshold` ({threshold:g} m) above that surface: the continuous deposit; "
        "`H0_m`: the pile as built, measured the same way at t = 0; "
        f"`t_f_s`: the rest time, from which no free grain of the flow (not past the final "
        f"front by more than a diameter) is faster than {rest_speed:g} m/s (NaN: moving at "
        "the end, `still_moving`), and `quiet_s`, how long the run went on after it (a "
        "short one may be a pause between bursts); `t_f_permil_s`, `t_f_pct_s`: the same "
        "with as many grains of the flow (the bed under it included) allowed to be faster "
        "as 0.1 % and 1 % of the pile's grain count (a rest time that a few rattlers do "
        "not fail), and `speed_end_permil`, `speed_end_pct`: the speed all but those stay "
        "under at the end (m/s); "
        "`t_f_all_s`: the same over every free "
        "grain, the bed far ahead included (seed 001's 'whole domain'); `speed_end`, "
        "`speed_end_all`: the largest speeds at the end (m/s); `t_front_s`: from when "
        "the front (:func:`cocd.measure.surface_front`) stays within one bin (a diameter) "
        "of its final place (less than 1.5 bins from it, so that a one-bin flicker counts "
        "whatever its exact reading); `ke_end_over_peak`: the grains' kinetic energy "
        "after the last step over its largest, a measure of rest that one rattler does not "
        "fail alone; "
        "`front_m`: the front at the end, from the back wall; `W_over_d`: the channel in "
        "diameters; `n_free`: free grains (pile and bed); `n_pile`: the pile's grains; "
        "`s_per_step`: detection, set-up and solve per step, the attempts of steps taken "
        "again with a wider margin included; `redos`: those attempts; `machine`: where "
        "the steps were made (CPU, cores, and threads when fewer than the cores)."
    )
    base.finish(
        out,
        "flume",
        "Seed 001's flume collapses (runs B00 to B20)",
        table,
        intro,
        summary,
        [*files, figure, front_figure],
        progress,
    )
    return table


def front_settled(times: FloatArray, front: FloatArray, bin_width: float) -> float:
    """From when ``front`` stays within one bin of its last value (NaN if it has none).

    The front's reading changes in whole bins, each ``bin_width`` give or take the
    grains' places, so a reading less than :data:`FRONT_BINS` bins away counts as the
    same place or the next one: a one-bin flicker is settled, a two-bin one is not.
    """
    if not np.isfinite(front[-1]):
        return np.nan
    return _holds_from(times, np.abs(front - front[-1]) < FRONT_BINS * bin_width)


def _holds_from(times: FloatArray, holds: np.ndarray) -> float:
    """The first saved time from which ``holds`` is true to the end (NaN if false at the end)."""
    broken = np.nonzero(~holds)[0]
    if not broken.size:
        return float(times[0])
    return np.nan if broken[-1] == times.size - 1 else float(times[broken[-1] + 1])


def _row(
    s: CollapseSeries,
    seed: int,
    slope: float,
    L0: float,
    W: float,
    rest_speed: float,
    threshold: float,
) -> dict[str, Any]:
    edges = s.x_edges
    centres = 0.5 * (edges[:-1] + edges[1:])
    first, last = s.profiles[0], s.profiles[-1]
    d, bed_end = s.d_mean, float(edges[-1])
    # The bed's surface: the erodible layer's median top downstream of the pile at the
    # start, and of the final front at the end (a loose layer settles), short of the end
    # wall. A bin without a grain centred in it reads 0 (the loose lattice leaves one in
    # about fifty empty until the flow reaches it): left out. A deposit that reaches the
    # end leaves no such bin: the start's surface is used, and the row is cut short.
    wall = centres < bed_end - 2.0 * d
    top0 = float(np.median(first[(centres > L0 + 3.0 * d) & wall & (first > 0)]))
    front = float(s.front[-1]) if np.isfinite(s.front[-1]) else L0
    far = (centres > front + 3.0 * d) & wall & (last > 0)
    top = float(np.median(last[far])) if far.sum() >= FAR_BINS else top0
    thickness = last - top
    ahead = np.nonzero((centres > L0) & (last > 0))[0]
    thin = ahead[thickness[ahead] < threshold]
    end = min(max(float(edges[thin[0]]) if thin.size else bed_end, L0), bed_end)
    t_f, flow_end = _rest(s.times, s.speed_max_flow, rest_speed)
    t_f_all, all_end = _rest(s.times, s.speed_max, rest_speed)
    few: dict[str, float] = {}
    for j, name in enumerate(FEW):
        speeds = None if s.speed_few_flow is None else s.speed_few_flow[:, j]
        few[f"t_f_{name}_s"], few[f"speed_end_{name}"] = _rest(s.times, speeds, rest_speed)
    t_front = front_settled(s.times, s.front, d)
    stats = s.stats
    return {
        "seed": seed,
        "slope_deg": slope,
        "W_over_d": W / s.d_mean,
        "d_mm": s.d_mean * 1e3,
        "n_free": int(stats.n.iloc[0]) if len(stats) else 0,
        "n_pile": s.n_grains,
        "t_end": round(float(s.times[-1]), 9),
        "bed_top0_m": top0,
        "bed_top_m": top,
        "H0_m": float(first[0] - top0),
        "Hf_m": float(last[0] - top),
        "Hf_over_H0": float((last[0] - top) / (first[0] - top0)),
        "front_m": float(s.front[-1]),
        "runout_m": float(end - L0),
        "runout_over_L0": float((end - L0) / L0),
        "t_f_s": t_f,
        "quiet_s": float(s.times[-1]) - t_f if np.isfinite(t_f) else 0.0,
        "t_front_s": t_front,
        "speed_end": flow_end,
        "still_moving": not np.isfinite(t_f),
        **few,
        "t_f_all_s": t_f_all,
        "speed_end_all": all_end,
        "reached_end": bool(
            base.cut_short(s.front, bed_end, d) or far.sum() < FAR_BINS or end >= bed_end - 2 * d
        ),
        "ke_end_over_peak": _ke_ratio(stats),
        "steps": s.steps,
        "redos": int(stats.redos.sum()) if "redos" in stats else 0,
        "iterations_mean": float(stats.iterations.mean()) if len(stats) else np.nan,
        "s_per_step": s.compute_s / s.steps if s.steps else np.nan,
        "compute_s": s.compute_s,
        "penetration_max": s.penetration_max,
        "machine": s.machine,
    }


def _ke_ratio(stats: pd.DataFrame) -> float:
    """The grains' kinetic energy after the last step over its largest (NaN: none)."""
    ke = stats.kinetic_energy.to_numpy(dtype=float) if len(stats) else np.zeros(0)
    return float(ke[-1] / ke.max()) if ke.size and ke.max() > 0 else np.nan


def _rest(times: FloatArray, speeds: FloatArray | None, rest_speed: float) -> tuple[float, float]:
    """The rest time, from which every saved frame's speed (the largest, or the one the
    flow's grains but a few stay under) is at most ``rest_speed`` (NaN: moving at the
    end, or not measured), and the last frame's."""
    if speeds is None:
        return np.nan, np.nan
    return _holds_from(times, speeds <= rest_speed), float(speeds[-1])


def _figure(
    path: Path,
    made: list[CollapseSeries],
    cases: list[tuple[int, float]],
    L0: float,
    reach: float,
    cfg: Settings,
) -> Path:
    """The final deposit's profile above the flume's glued bed, per slope (seed 001's
    Fig. 8, right-hand column), every packing, with the pile as built."""
    plt = base.pyplot()
    slopes = sorted({slope for _, slope in cases})
    fig, axes = plt.subplots(len(slopes), 1, figsize=(9, 2.2 * len(slopes)), squeeze=False)
    for ax, slope in zip(axes[:, 0], slopes, strict=True):
        for (seed, sl), s in zip(cases, made, strict=True):
            if sl != slope:
                continue
            centres = 0.5 * (s.x_edges[:-1] + s.x_edges[1:])
            first, last = (np.where(h > 0, h, np.nan) for h in (s.profiles[0], s.profiles[-1]))
            if seed == 0:  # bins without a grain centred in them are left blank
                ax.plot(centres, first, color="0.6", lw=1, label="t = 0")
            ax.plot(centres, last, lw=1.2, label=f"t = {s.times[-1]:g} s, packing {seed}")
        ax.axvline(L0, color="0.3", ls=":", lw=1)
        ax.set_xlim(0.0, 1.2 * reach)
        ax.set_title(
            f"slope {slope:g} deg, N = {made[0].n_grains} in the pile, mu = {cfg.mu:g}, "
            f"mu_w = {cfg.side_mu:g}",
            fontsize=9,
        )
        ax.set_ylabel("h (m)")
        ax.grid(True, alpha=0.3)
    axes[-1, 0].set_xlabel("x from the back wall (m); dotted: the gate")
    axes[0, 0].legend(fontsize=7)
    return base.save_figure(fig, path)


def _trace(made: list[CollapseSeries], cases: list[tuple[int, float]], L0: float) -> pd.DataFrame:
    """Every frame's front from the gate and largest speeds, per slope and packing."""
    parts = []
    for (seed, slope), s in zip(cases, made, strict=True):
        n = s.times.size
        none = np.full(n, np.nan)
        parts.append(
            pd.DataFrame(
                {
                    "slope_deg": slope,
                    "seed": seed,
                    "t": np.round(s.times, 9),
                    "front_m": s.front - L0,
                    "speed_max_flow": none if s.speed_max_flow is None else s.speed_max_flow,
                    "speed_max": none if s.speed_max is None else s.speed_max,
                    **{
                        f"speed_{name}_flow": none
                        if s.speed_few_flow is None
                        else s.speed_few_flow[:, j]
                        for j, name in enumerate(FEW)
                    },
                }
            )
        )
    return pd.concat(parts, ignore_index=True).sort_values(["slope_deg", "seed", "t"])


def _front_figure(
    path: Path, trace: pd.DataFrame, table: pd.DataFrame, rest_speed: float, cfg: Settings
) -> Path:
    """The front from the gate against time, per slope and packing (seed 001's Fig. 9a),
    marked where it settled (``t_front_s``); in the middle, the flow's largest speed
    against the rest speed (seed 001's 0.01 m/s by default); below, the speeds that all
    of the flow's grains stay under but 0.1 % and 1 % of the pile's count, from which
    the rest times robust to rattlers are read."""
    plt = base.pyplot()
    fig, (top, middle, bottom) = plt.subplots(3, 1, figsize=(8, 9.5), sharex=True)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    slopes = sorted(set(trace.slope_deg))
    for k, slope in enumerate(slopes):
        colour = colours[k % len(colours)]
        for seed, run in trace[trace.slope_deg == slope].groupby("seed"):
            label = f"{slope:g} deg" if seed == min(trace.seed) else None
            top.plot(run.t, run.front_m, color=colour, lw=1.2, label=label)
            middle.semilogy(run.t, run.speed_max_flow, color=colour, lw=0.8)
            for name, (style, _) in zip(FEW, FEW_STYLES, strict=True):
                speed = run[f"speed_{name}_flow"].to_numpy(dtype=float)
                bottom.semilogy(
                    run.t, np.where(speed > 0, speed, np.nan), style, color=colour, lw=0.8
                )
            row = table[(table.slope_deg == slope) & (table.seed == seed)].iloc[0]
            if np.isfinite(row.t_front_s):
                settled = np.interp(row.t_front_s, run.t, run.front_m)
                top.plot([row.t_front_s], [settled], "o", color=colour, ms=4)
    middle.axhline(rest_speed, color="0.3", ls=":", lw=1)
    pile = ", ".join(str(n) for n in sorted(set(table.n_pile)))
    bottom.axhline(rest_speed, color="0.3", ls=":", lw=1)
    top.set_ylabel("front from the gate (m)")
    top.set_title(
        f"N = {int(table.n_free.iloc[0])} free spheres, mu = {cfg.mu:g}, mu_w = {cfg.side_mu:g}; "
        "dots: the front settled",
        fontsize=9,
    )
    top.legend(fontsize=8)
    middle.set_ylabel("largest speed in the flow (m/s)")
    middle.set_title(f"dotted: seed 001's rest criterion, {rest_speed:g} m/s", fontsize=9)
    bottom.set_ylabel("speed of the flow but a few (m/s)")
    bottom.set_title(
        "the speed all grains of the flow stay under but "
        + " and ".join(
            f"{share * 100:g} % ({word})"
            for share, (_, word) in zip(FEW.values(), FEW_STYLES, strict=True)
        )
        + f" of the pile's {pile} grains",
        fontsize=9,
    )
    bottom.set_xlabel("t (s)")
    for ax in (top, middle, bottom):
        ax.grid(True, alpha=0.3)
    return base.save_figure(fig, path)


def _summary(
    ensemble: pd.DataFrame,
    table: pd.DataFrame,
    d: float,
    L0: float,
    H0: float,
    W: float,
    layer: float,
    bed: float,
    dt: float,
    until: float,
    cfg: Settings,
) -> str:
    """The summary, every number taken from ``ensemble`` and ``table``."""
    pm = base.pm
    parts = []
    for row in ensemble.to_dict("records"):
        moving = int(row["still_moving"])
        rest = (
            f"at rest at {pm(row, 't_f_s')} s"
            + (f" ({moving} of {row['seeds']} still moving at {until:g} s)" if moving else "")
            if moving < row["seeds"]
            else f"still moving at {until:g} s"
        )
        for name, share in FEW.items():  # the smallest share that every packing reaches
            quiet = int(row[f"t_f_{name}_s_n"])
            if quiet == row["seeds"] or share == max(FEW.values()):
                break
        few = (
            f"all but {share * 100:g} % of the pile's count at rest from "
            f"{pm(row, f't_f_{name}_s')} s"
            + (f" in {quiet} of {row['seeds']} packings" if quiet < row["seeds"] else "")
            if quiet
            else f"more than {share * 100:g} % of the pile's count moving at {until:g} s"
        )
        parts.append(
            f"{row['slope_deg']:g} deg: Hf / H0 {pm(row, 'Hf_over_H0')}, runout from the "
            f"gate {pm(row, 'runout_m')} m, {rest} ({few}), front within a bin of "
            f"its last place from {pm(row, 't_front_s')} s"
        )
    n_free = ", ".join(str(n) for n in sorted(set(table.n_free)))
    return (
        f"Seed 001's pile, L0 x H0 = {L0 * 100:g} x {H0 * 100:g} cm, in a {W * 100:g} cm "
        f"channel ({W / d:.3g} diameters of {d * 1e3:g} mm) with sidewall friction "
        f"{cfg.side_mu:g}, on an erodible bed {layer * 100:g} cm thick and {bed:g} m long "
        f"({n_free} free spheres), grain friction {cfg.mu:g}, dt = {dt:g} s, `{cfg.solver}` "
        f"at tol {cfg.tol:g}, to t = {until:g} s; mean +- spread over the packings: "
        f"**{'; '.join(parts)}**. Seed 001 (0.5 mm beads, a continuum with mu = 0.44) "
        "finds the front stopping before the whole flow, and the rest time depending on "
        "the slope."
    )


STUDY = register(
    "flume",
    Settings,
    run,
    help="Seed 001's flume collapses (B00 to B20): rest time, final height and runout "
    "from the gate against slope.",
)
