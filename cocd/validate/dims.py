"""``cocd validate dims``, the seed's Fig. 7: the same collapse in 2D and in 3D.

A column R0 x H0 = 20 x 14 cm on a rough bed collapses on a horizontal plane
and on a slope, once as a 2D column of discs and once as a 3D column of spheres
of about the same size in a channel ``width`` wide (the seed's Table A.2, rows 5
and 6: 2154 discs, 112 459 spheres in a 20 cm channel, mu = 0.3, dt = 1e-3 s in
2D and 1e-2 s in 3D). Fronts and profiles are compared at the asked times. The
seed reads its Fig. 7 as: at t = 1 s the 2D front is about 12 % further than the
3D one on the horizontal plane and about 32 % further at 22 degrees, the
lateral walls and the extra freedom of spheres dissipating more in 3D. Several
sizes of the column (``--n2d`` and ``--n3d`` paired, equal grains in 2D and 3D) go
in one table, to see how the comparison moves as the grains approach the seed's.

The 3D runs are long (hours per run at the seed's size on two cores): every
simulation is a resumable run file, continued from its last frame when the case
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

from cocd.bench import estimate
from cocd.bench.study import option
from cocd.checks import first_repeat
from cocd.errors import CocdError
from cocd.validate import _common as base
from cocd.validate._common import CollapseSeries, LargeCollapseSettings, register

__all__ = ["SEED_FRONT_RATIO", "SEED_N2D", "SEED_N3D", "STUDY", "Settings", "run"]

#: The seed's 2D front over its 3D front at t = 1 s, by slope (degrees): "about 12 %
#: longer" on the horizontal plane and "about 32 %" at 22 degrees (seed 000, Sec. 4.2).
SEED_FRONT_RATIO = {0.0: 1.12, 22.0: 1.32}

#: The seed's column, R0 x H0 (m).
LENGTH, HEIGHT = 0.20, 0.14

#: The seed's grains in the column: discs in 2D, spheres in 3D (Table A.2, rows 5 and 6).
SEED_N2D, SEED_N3D = 2154, 112459


@dataclass(frozen=True)
class Settings(LargeCollapseSettings):
    """The options of ``cocd validate dims``."""

    n2d: tuple[int, ...] = option(
        (SEED_N2D,),
        "Discs in the 2D column, one count per size (comma-separated, paired with --n3d).",
        kind="ints",
        flag="--n2d",
    )
    n3d: tuple[int, ...] = option(
        (SEED_N3D,),
        "Spheres in the 3D column, one count per size (comma-separated, paired with --n2d).",
        kind="ints",
        flag="--n3d",
    )
    width: float = option(0.20, "Width W of the 3D channel (m).")
    slopes: tuple[float, ...] = option(
        (0.0, 22.0), "Bed slopes (degrees).", kind="numbers", flag="--slopes"
    )
    times: tuple[float, ...] = option(
        (0.4, 1.0), "Times of the compared profiles and fronts (s).", kind="floats"
    )
    mu: float = option(0.3, "Friction coefficient (grains and walls; the seed's 0.3).")
    dt2d: float = option(1e-3, "Time step of the 2D runs (s).", flag="--dt2d")
    dt3d: float = option(1e-2, "Time step of the 3D runs (s).", flag="--dt3d")
    bed_length: float = option(
        3.0,
        "Length of the rough bed (m), 15 R0: at 22 degrees the fronts of the seed's 2D "
        "column pass 6 R0 before t = 1 s.",
    )
    seeds: int = option(1, "Packings: the grains' radii drawn with seeds 0 .. seeds-1.")


def run(cfg: Settings, *, out: Path, progress: Callable[[str], Any] = print) -> pd.DataFrame:
    """Collapse the seed's column in 2D and in 3D at each slope and compare their fronts.

    Returns the table written to ``dims.csv``: per size (``n2d`` and ``n3d`` paired),
    slope, packing and time, the 2D and 3D fronts from the back wall (m and R0) and
    their ratio.
    """
    sizes = _sizes(cfg.n2d, cfg.n3d)
    width, dt2d, dt3d, bed = base.positives(
        width=cfg.width, dt2d=cfg.dt2d, dt3d=cfg.dt3d, bed_length=cfg.bed_length
    )
    if bed <= LENGTH:
        raise CocdError(f"bed_length must exceed the column's length {LENGTH:g} m, got {bed:g}")
    slopes = sorted(set(float(s) for s in cfg.slopes))
    if not slopes or any(not (0.0 <= s < 90.0) for s in slopes):
        raise CocdError(f"slopes must be in [0, 90), got {list(cfg.slopes)!r}")
    times = sorted(set(base.positive_list("times", cfg.times)))
    seeds = base.positive_int("seeds", cfg.seeds)
    frame2d = base.frame_interval([0.01, *times], [dt2d])
    # Every 3D step is a frame: a step can take minutes, so a stopped run loses one.
    if any(abs(t / dt3d - round(t / dt3d)) > 1e-6 for t in times):
        raise CocdError(f"the times {times} do not fall on whole numbers of 3D steps {dt3d:g}")
    frame3d = dt3d
    out = Path(out)
    jobs = []
    cases = []
    # Coarse sizes first; per packing the short 2D runs, then the 3D ones: with two
    # workers, the two slopes at once.
    for size, (n2, n3) in enumerate(sizes):
        for seed in range(seeds):
            for dim, n, dt, frame_dt in ((2, n2, dt2d, frame2d), (3, n3, dt3d, frame3d)):
                for slope in slopes:
                    cases.append((size, seed, slope, dim))
                    jobs.append(
                        _job(out, cfg, dim, n, slope, seed, dt, frame_dt, [0.0, *times], width, bed)
                    )
    estimate.announce(
        "dims",
        [(job.free_grains, job.steps) for job in jobs],
        out=out,
        progress=progress,
        workers=cfg.workers,
    )
    made = dict(zip(cases, base.collapse_runs(jobs, cfg.workers, progress), strict=True))
    rows = []
    for size in range(len(sizes)):
        for seed in range(seeds):
            for slope in slopes:
                two, three = made[size, seed, slope, 2], made[size, seed, slope, 3]
                for t in times:
                    rows.append(_row(two, three, slope, seed, t, bed))
    table = pd.DataFrame(rows)
    figure = _figure(out / "dims_profiles.png", made, sizes, seeds, slopes, times, cfg.mu, width)
    ensemble = base.ensemble(
        table,
        ["n_2d", "n_3d", "grain_scale", "slope_deg", "t"],
        ["front_2d_R0", "front_3d_R0", "front_ratio", "mass_end_2d_R0", "mass_end_3d_R0",
         "mass_end_ratio"],
        counts=["reached_end"],
    )  # fmt: skip
    last = ensemble[ensemble.t == times[-1]]
    said = " ".join(
        f"{n2} discs and {n3} spheres (grains {_grain_scale(n3):.2g} times the seed's): "
        + "; ".join(_said(r, times[-1]) for r in last[last.n_3d == n3].to_dict("records"))
        + "."
        for n2, n3 in sizes
    )
    cut = ensemble[ensemble.reached_end > 0]
    ends = (
        f" A front reached the bed's end ({bed:g} m) at "
        + ", ".join(
            f"{r.n_3d} spheres, {r.slope_deg:g} deg, t = {r.t:g} s ({r.reached_end} of {r.seeds})"
            for r in cut.itertuples()
        )
        + ": those fronts are cut short; lengthen the bed (`--bed-length`)."
        if len(cut)
        else ""
    )
    summary = (
        f"The seed's column (R0 x H0 = {LENGTH * 100:g} x {HEIGHT * 100:g} cm, mu = {cfg.mu:g}, "
        f"rough bed) in 2D (dt = {dt2d:g} s) and in a {width * 100:g} cm channel in 3D "
        f"(dt = {dt3d:g} s), `{cfg.solver}` at tol {cfg.tol:g}, {seeds} "
        f"packing{'s' if seeds > 1 else ''} per size. Fronts at t = {times[-1]:g} s, from "
        f"the back wall, mean +- sd over the packings: **{said}** The seed "
        f"({SEED_N2D} discs, {SEED_N3D} spheres) finds the 2D front about 12 % further at "
        "0 deg and about 32 % at 22 deg." + ends
    )
    intro = (
        "Fronts (:func:`cocd.measure.surface_front`, the side view in 3D: the highest "
        "grain across the width) from the back wall, in m and in R0 = "
        f"{LENGTH:g} m; `grain_scale`: the grains' size over the seed's, "
        f"({SEED_N3D} / n_3d)^(1/3); `front_ratio` = 2D / 3D; `seed_front_ratio`: the "
        "seed's at t = 1 s; "
        "`mass_end_*`: where the main mass's profile ends (the last bin, one diameter wide, "
        "where it stands above the bed; the grains running ahead of it in a thin trail are "
        "left out), in R0, and its 2D / 3D ratio; "
        "`reached_end`: a front (2D or 3D) within two diameters of the bed's end, cut short "
        "by it; `s_per_step_3d`: detection, set-up and solve per 3D step, steps taken "
        "again with a wider margin included."
    )
    files = base.report.write_table(
        out,
        "dims_ensemble",
        ensemble,
        title="The same collapse in 2D and in 3D: mean and spread over the packings",
        intro="Per size (`n_2d`, `n_3d`), slope and time, over the packings (`seeds`): mean "
        "and sample standard deviation (`_sd`, empty for one packing) of the fronts in R0 "
        "and of their ratio; `reached_end`: packings whose front was cut short by the "
        "bed's end.",
    )
    base.finish(
        out, "dims", "The same collapse in 2D and in 3D (Fig. 7)", table, intro, summary,
        [figure, *files], progress,
    )  # fmt: skip
    return table


def _job(
    out: Path,
    cfg: Settings,
    dim: int,
    n: int,
    slope: float,
    seed: int,
    dt: float,
    frame_dt: float,
    profile_times: list[float],
    width: float,
    bed: float,
) -> base.CollapseJob:
    """Packing ``seed``'s run of the column as ``n`` grains in ``dim`` dimensions on a
    bed sloping ``slope`` degrees."""
    params: dict[str, Any] = {
        "dim": dim,
        "n_grains": n,
        "length": LENGTH,
        "height": HEIGHT,
        "bed": "rough",
        "bed_length": bed,
        "slope_deg": slope,
        "mu": cfg.mu,
    }
    label = f"{dim}d_n{n}_slope{slope:g}_mu{cfg.mu:g}"
    if dim == 3:
        params["width"] = width
        label += f"_W{width * 100:g}cm"
    label += f"_bed{bed:g}m"
    return base.collapse_job(
        out,
        "dims",
        label,
        seed,
        params,
        cfg,
        what=f"{dim}D, {n} grains, slope {slope:g} deg, dt {dt:g} s",
        dt=dt,
        frame_dt=frame_dt,
        profile_times=profile_times,
    )


def _sizes(n2d: Any, n3d: Any) -> list[tuple[int, int]]:
    """The column's sizes: ``n2d`` and ``n3d`` paired, one count or several each,
    without repeats, coarsest first."""
    twos = list(n2d) if isinstance(n2d, (list, tuple)) else [n2d]
    threes = list(n3d) if isinstance(n3d, (list, tuple)) else [n3d]
    if len(twos) != len(threes):
        raise CocdError(
            f"n2d and n3d pair one size each: got {len(twos)} disc counts and "
            f"{len(threes)} sphere counts"
        )
    pairs = [
        (base.positive_int("n2d", a), base.positive_int("n3d", b))
        for a, b in zip(twos, threes, strict=True)
    ]
    if not pairs:
        raise CocdError("n2d and n3d are empty")
    for k, name in ((0, "n2d"), (1, "n3d")):
        counts = [p[k] for p in pairs]
        again = first_repeat(counts)
        if again is not None:
            raise CocdError(f"{name} repeats a count: {counts[again]} in {counts}")
    pairs.sort(key=lambda p: p[1])
    twos = [p[0] for p in pairs]
    if twos != sorted(twos):
        raise CocdError(
            "n2d and n3d pair the k-th disc count with the k-th sphere count: more spheres "
            f"go with more discs, got {', '.join(f'{a} with {b}' for a, b in pairs)}"
        )
    return pairs


def _grain_scale(n3d: int) -> float:
    """The grains' size over the seed's, for a 3D column of ``n3d`` spheres."""
    return (SEED_N3D / n3d) ** (1.0 / 3.0)


def _row(
    two: CollapseSeries, three: CollapseSeries, slope: float, seed: int, t: float, bed: float
) -> dict[str, Any]:
    """One packing's 2D and 3D runs compared at ``t``: a row of ``dims.csv``."""
    f2, f3 = _front_at(two, t), _front_at(three, t)
    m2, m3 = _mass_end(two, t), _mass_end(three, t)
    return {
        "slope_deg": slope,
        "seed": seed,
        "t": t,
        "n_2d": two.n_grains,
        "n_3d": three.n_grains,
        "grain_scale": _grain_scale(three.n_grains),
        "d_2d_mm": two.d_mean * 1e3,
        "d_3d_mm": three.d_mean * 1e3,
        "front_2d_m": f2,
        "front_3d_m": f3,
        "front_2d_R0": f2 / LENGTH,
        "front_3d_R0": f3 / LENGTH,
        "front_ratio": f2 / f3,
        "mass_end_2d_R0": m2 / LENGTH,
        "mass_end_3d_R0": m3 / LENGTH,
        "mass_end_ratio": m2 / m3,
        # A front at the bed's end is cut short: the ratio is not the flow's.
        "reached_end": base.cut_short(f2, bed, two.d_mean) or base.cut_short(f3, bed, three.d_mean),
        "seed_front_ratio": SEED_FRONT_RATIO.get(slope, math.nan) if t == 1.0 else math.nan,
        "compute_2d_s": two.compute_s,
        "compute_3d_s": three.compute_s,
        "steps_3d": three.steps,
        "s_per_step_3d": three.compute_s / max(three.steps, 1),
    }


def _said(r: dict[str, Any], t: float) -> str:
    """One slope's fronts at ``t`` in the summary: 2D, 3D, their ratio (the seed's beside
    it at 1 s) and that of the main masses' ends."""
    seed = SEED_FRONT_RATIO.get(r["slope_deg"], math.nan)
    return (
        f"{r['slope_deg']:g} deg: 2D {base.pm(r, 'front_2d_R0', 2)} R0, 3D "
        f"{base.pm(r, 'front_3d_R0', 2)} R0, ratio {base.pm(r, 'front_ratio', 3)}"
        + (f" (seed {seed:.2f})" if t == 1.0 and math.isfinite(seed) else "")
        + f", of the main masses' ends {base.pm(r, 'mass_end_ratio', 3)}"
    )


def _mass_end(series: CollapseSeries, t: float) -> float:
    """Where the main mass's profile at ``t`` ends: the far edge of its last bin above
    the bed (m from the back wall)."""
    k = int(np.argmin(np.abs(np.asarray(series.profile_times) - t)))
    above = np.flatnonzero(series.profiles[k] > 0.0)
    return float(series.x_edges[above[-1] + 1]) if above.size else math.nan


def _front_at(series: CollapseSeries, t: float) -> float:
    """The front at the saved frame nearest ``t``."""
    k = int(np.argmin(np.abs(series.times - t)))
    return float(series.front[k])


def _figure(
    path: Path,
    made: dict[tuple[int, int, float, int], CollapseSeries],
    sizes: list[tuple[int, int]],
    seeds: int,
    slopes: list[float],
    times: list[float],
    mu: float,
    width: float,
) -> Path:
    """Fig. 7: per size (rows) and slope (columns), the profiles of the main mass at t = 0
    and the asked times, 2D dashed, 3D solid, and the fronts on the bed (2D down, 3D up
    triangles; the first packing)."""
    plt = base.pyplot()
    fig, axes = plt.subplots(
        len(sizes), len(slopes), figsize=(6 * len(slopes), 3.6 * len(sizes)), squeeze=False
    )
    for size, (row, (n2, n3)) in enumerate(zip(axes, sizes, strict=True)):
        for ax, slope in zip(row, slopes, strict=True):
            reach = LENGTH
            for dim, style, mark in ((2, "--", "v"), (3, "-", "^")):
                s = made[size, 0, slope, dim]
                centres = 0.5 * (s.x_edges[1:] + s.x_edges[:-1])
                for k, t in enumerate(s.profile_times):
                    ax.plot(centres, s.profiles[k], style, color=f"C{k}",
                            label=f"{dim}D, t = {t:g} s")  # fmt: skip
                    # The front (grains ahead of the main mass included) on the bed.
                    front = _front_at(s, t)
                    ax.plot([front], [0.0], mark, color=f"C{k}", ms=7, clip_on=False)
                    reach = max(reach, front)
            ax.set_xlim(0.0, 1.15 * reach)
            seed = SEED_FRONT_RATIO.get(slope)
            ax.set_title(
                f"{n2} discs, {n3} spheres, slope {slope:g} deg"
                + (f"\n(seed: 2D front {100 * (seed - 1):.0f} % further at 1 s)" if seed else ""),
                fontsize="medium",
            )
            ax.set_xlabel("x from the back wall (m)")
            ax.grid(True, alpha=0.3)
        row[0].set_ylabel("h (m)")
    axes[0][0].legend(fontsize="small")
    fig.suptitle(
        f"2D (dashed, fronts v) and 3D (in a {width * 100:g} cm channel, solid, fronts ^), "
        f"mu = {mu:g}" + (f"; packing 0 of {seeds}" if seeds > 1 else "")
    )
    return base.save_figure(fig, path)


STUDY = register(
    "dims",
    Settings,
    run,
    help="Fig. 7: the same collapse in 2D and in 3D, on a horizontal bed and on a slope.",
)
