"""``cocd validate timestep``, the seed's Fig. 2: a 2D collapse on a rough bed at
several time steps; mass profiles at a few times and their relative error
against the smallest step, ``||h_dt - h_ref|| / ||h_ref||``.

With ``--seeds K`` the collapse is run from K packings (the column built with seeds
0 to K-1), each against its own smallest step; ``timestep_ensemble`` gives, per time
step and time, the mean and spread (sample standard deviation) over the packings of
the profile errors and of the front in mean diameters, and the summary's numbers are
computed from it.

A twin of each packing's largest-step run, the same but for the solver's tolerance
(``--twin-tol``), measures how far two runs drift apart from a perturbation the size
of the solver's tolerance: the grain-scale sensitivity of the flow, the floor under
which no time step's error can be told from chance (``twin_error``)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from cocd.bench import estimate, report
from cocd.bench.study import option
from cocd.errors import CocdError
from cocd.validate import _common as base
from cocd.validate._common import CollapseSettings, register


@dataclass(frozen=True)
class Settings(CollapseSettings):
    """The options of ``cocd validate timestep``."""

    n: int = option(400, "Discs in the column.")
    dts: tuple[float, ...] = option((1e-3, 1e-4, 5e-5), "Time steps (s).", kind="floats")
    times: tuple[float, ...] = option((0.02, 0.06, 0.3), "Profile times (s).", kind="floats")
    mu: float = option(0.3, "Friction coefficient (grains and walls).")
    tol: float = option(1e-8, "Tolerance of the convex backend.", positive=True)
    seeds: int = option(
        1, "Packings: the grains' radii drawn with seeds 0 .. seeds-1 (same lattice sites)."
    )
    twin_tol: float = option(
        1e-9,
        "Tolerance of a twin run at the largest time step: how far two runs differing only "
        "in the solver's tolerance drift apart (0: no twin).",
    )


def run(cfg: Settings, *, out: Path, progress: Callable[[str], Any] = print) -> pd.DataFrame:
    """Profiles of one 2D collapse at several time steps; error against the smallest.

    Returns the table written to ``timestep.csv``: one row per (dt, t) with
    the profile error against the smallest ``dt`` and the front position.
    """
    n = base.positive_int("n", cfg.n)
    dts = sorted(set(base.positive_list("dts", cfg.dts)), reverse=True)
    times = sorted(base.positive_list("times", cfg.times))
    if len(dts) < 2:
        raise CocdError("timestep needs at least two time steps")
    out = Path(out)
    params = base.base_params(n, cfg.mu)
    frame_dt = base.frame_interval(times, dts)
    seeds = base.positive_int("seeds", cfg.seeds)
    twin_tol = base.twin_tolerance("twin_tol", cfg.twin_tol, cfg.tol)
    estimate.announce(
        "timestep",
        [(n, round(max(times) / dt)) for dt in dts for _ in range(seeds)]
        + [(n, round(max(times) / dts[0]))] * (seeds if twin_tol > 0 else 0),
        out=out,
        progress=progress,
        workers=cfg.workers,
    )

    def job(seed: int, dt: float, label: str, how: Settings) -> base.CollapseJob:
        return base.collapse_job(
            out, "timestep", label, seed, params, how, dt=dt, frame_dt=frame_dt, profile_times=times
        )

    jobs = []
    for seed in range(seeds):
        jobs += [job(seed, dt, f"n{n}_dt{dt:.0e}", cfg) for dt in dts]
        if twin_tol > 0:  # the largest step's run again, at the twin's tolerance
            twin_how = dataclasses.replace(cfg, tol=twin_tol)
            jobs.append(job(seed, dts[0], f"n{n}_dt{dts[0]:.0e}_tol{twin_tol:g}", twin_how))
    made = base.collapse_runs(jobs, cfg.workers, progress)
    per_seed = len(dts) + (twin_tol > 0)
    rows = []
    for seed in range(seeds):
        mine = made[seed * per_seed : (seed + 1) * per_seed]
        twin = mine[len(dts)] if twin_tol > 0 else None
        rows += _rows(mine[: len(dts)], dts, times, seed, twin)
    first = made[: len(dts)]
    table = pd.DataFrame(rows)
    if twin_tol == 0:
        table = table.drop(columns="twin_error")
    ref = first[-1]
    ensemble = _ensemble(table)
    files = report.write_table(
        out,
        "timestep_ensemble",
        ensemble,
        title="Time step convergence (Fig. 2): mean and spread over the packings",
        intro="Per time step and time, over the packings (`seeds` of them): the mean and "
        "sample standard deviation (`_sd`, empty for one packing) of the profile errors "
        "and of the front in mean diameters (`front_d`); `error_over_largest_dt`: the mean "
        "profile error divided by that of the largest time step at the same time"
        + (
            "; `twin_error` (largest step only): its profile against its twin's, the same "
            "run at another solver tolerance."
            if twin_tol > 0
            else "."
        ),
    )
    figures = [
        base.profile_figure(out / "timestep_profiles.png", first, [f"dt = {d:g} s" for d in dts])
    ]
    plt = base.pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 4))
    for t in times:
        sub = ensemble[(ensemble.t == t) & (ensemble.dt > dts[-1])]
        bars = ax.errorbar(sub.dt, sub.profile_error, yerr=sub.profile_error_sd.fillna(0.0),
                           marker="o", capsize=3, label=f"t = {t:g} s")  # fmt: skip
        if "twin_error" in sub:
            floor = sub.twin_error.dropna()
            if len(floor) and float(floor.iloc[0]) > 0:
                ax.axhline(float(floor.iloc[0]), ls=":", color=bars.lines[0].get_color(),
                           label=f"twin runs, t = {t:g} s")  # fmt: skip
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("dt (s)")
    ax.set_ylabel(f"profile error against dt = {dts[-1]:g} s")
    ax.set_title(
        f"{ref.n_grains} discs, mu = {cfg.mu:g}, {seeds} packing{'s' if seeds > 1 else ''} "
        "(mean +- sd)",
        fontsize="medium",
    )
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    figures.append(base.save_figure(fig, out / "timestep_error.png"))

    summary = _summary(ensemble, dts, seeds, ref, cfg)
    intro = (
        "`profile_error` = ||h_dt - h_ref|| / ||h_ref|| over bins one mean diameter wide "
        f"(h: free-surface height above the bed; reference dt = {dts[-1]:g} s), "
        "`profile_error_4d` the same on the profiles averaged over 4 diameters (a single "
        "grain's jump between neighbouring one-diameter bins counts less); "
        "`front_m`: the flow's front from the back wall (surface_front); `seed`: the "
        "packing; "
        + (
            "`twin_error`: the largest step's profile against its twin's, run at "
            f"tol {twin_tol:g} instead of {cfg.tol:g} (empty for the other steps); "
            if twin_tol > 0
            else ""
        )
        + "`compute_s`: detection, set-up and solve time of the whole run, steps "
        "taken again with a wider margin included."
    )
    base.finish(
        out,
        "timestep",
        "Time step convergence (Fig. 2)",
        table,
        intro,
        summary,
        [*files, *figures],
        progress,
    )
    return table


def _rows(
    series: list[Any], dts: list[float], times: list[float], seed: int, twin: Any = None
) -> list[dict]:
    """One row per (dt, t) of one packing, against its smallest step; the largest step's
    rows also against its ``twin`` (``twin_error``, NaN elsewhere)."""
    ref = series[-1]
    rows = []
    for j, (s, dt) in enumerate(zip(series, dts, strict=True)):
        for k, t in enumerate(times):
            twin_error = math.nan
            if twin is not None and j == 0:
                twin_error = base.profile_error(s.profiles[k], twin.profiles[k])
            error, error_4d = base.profile_errors(s.profiles[k], ref.profiles[k])
            rows.append(
                {
                    "seed": seed,
                    "dt": dt,
                    "t": t,
                    "profile_error": error,
                    "profile_error_4d": error_4d,
                    "front_m": float(np.interp(t, s.times, s.front)),
                    "front_ref_m": float(np.interp(t, ref.times, ref.front)),
                    "twin_error": twin_error,
                    "d_mean_m": s.d_mean,
                    "steps": s.steps,
                    "mean_nc": float(s.stats.nc.mean()),
                    "penetration_max": s.penetration_max,
                    "compute_s": s.compute_s,
                }
            )
    return rows


def _ensemble(table: pd.DataFrame) -> pd.DataFrame:
    """Mean and sample spread over the packings, per (dt, t)."""
    tab = table.assign(front_d=table.front_m / table.d_mean_m)
    columns = ["profile_error", "profile_error_4d", "front_d"]
    if "twin_error" in tab and tab.twin_error.notna().any():
        columns.append("twin_error")
    out = base.ensemble(tab, ["dt", "t"], columns)
    # Each step's mean error against the largest step's at the same time: the
    # convergence the seed's Fig. 2 shows (1 for the largest step, 0 for the reference).
    largest = out[out.dt == out.dt.max()].set_index("t").profile_error
    out["error_over_largest_dt"] = out.profile_error.to_numpy() / largest.reindex(out.t).to_numpy()
    return out.sort_values(["dt", "t"], ascending=[False, True])


def _summary(ensemble: pd.DataFrame, dts: list[float], seeds: int, ref: Any, cfg: Any) -> str:
    """The summary, every number taken from ``ensemble``."""
    last = max(ensemble.t)
    at_last = ensemble[ensemble.t == last].set_index("dt")
    parts = [
        f"dt = {dt:g} s: {base.pm(at_last.loc[dt], 'profile_error')} "
        f"({base.pm(at_last.loc[dt], 'profile_error_4d')} on 4 d), front "
        f"{base.pm(at_last.loc[dt], 'front_d')} d"
        for dt in dts[:-1]
    ]
    text = (
        f"2D collapse of {ref.n_grains} discs (d = {ref.d_mean * 1e3:.2f} mm, mu = {cfg.mu:g}, "
        f"rough horizontal bed), {seeds} packing{'s' if seeds > 1 else ''}, `{cfg.solver}` at "
        f"tol {cfg.tol:g}, dt = {', '.join(f'{d:g}' for d in dts)} s. At t = {last:g} s, "
        f"profile error against dt = {dts[-1]:g} s (mean +- spread over the packings): "
        + "; ".join(parts)
        + f"; front of dt = {dts[-1]:g} s: {base.pm(at_last.loc[dts[-1]], 'front_d')} d."
    )
    if 1e-3 in at_last.index and 1e-4 in at_last.index and 1e-4 != dts[-1]:
        ratio = at_last.loc[1e-4, "profile_error"] / at_last.loc[1e-3, "profile_error"]
        verdict = "at most half" if ratio <= 0.5 else "more than half"
        text += (
            f" The mean error of dt = 1e-4 s is {base.fmt(ratio)} times that of 1e-3 s ({verdict})."
        )
    if "twin_error" in ensemble:
        twin = at_last.loc[dts[0]]
        text += (
            f" Two runs at dt = {dts[0]:g} s differing only in the solver's tolerance "
            f"({cfg.tol:g} and {cfg.twin_tol:g}) differ by {base.pm(twin, 'twin_error')} at "
            f"t = {last:g} s: the grain-scale sensitivity, below which no step's error is "
            "told from chance."
        )
    return text + (
        " The seed (Fig. 2, 2D) finds the profiles of dt = 1e-3 s 'very close, with only "
        "slight differences' to those of 5e-5 s, and those of 1e-4 s in excellent agreement."
    )


STUDY = register(
    "timestep",
    Settings,
    run,
    help="Fig. 2: profiles of a 2D collapse at several time steps, error against the smallest.",
)
