"""``cocd validate nscd``, the seed's Fig. 4: the same collapse with a convex backend
(the COCD scheme) and with ``nscd`` (the non-convex Coulomb law, Gauss-Seidel);
profiles at times in units of ``sqrt(H0 / g)`` and their relative difference. With
``nscd_twin_tol``, ``nscd`` is run a second time per packing at that tolerance, which
measures how far the reference itself moves with its tolerance."""

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
    """The options of ``cocd validate nscd``."""

    n: int = option(400, "Discs in the column.")
    dt: float = option(1e-3, "Time step (s).")
    times_T: tuple[float, ...] = option(
        (1.0, 2.0, 4.0, 8.0), "Profile times in units of sqrt(H0/g).", kind="floats", flag="--times"
    )
    mu: float = option(0.3, "Friction coefficient (grains and walls).")
    tol: float = option(1e-8, "Tolerance of the convex backend.", positive=True)
    nscd_tol: float = option(1e-5, "Tolerance of nscd.", positive=True)
    nscd_max_iter: int = option(100000, "Sweeps allowed to nscd per step.", positive=True)
    nscd_fallback: tuple[str, ...] = option(
        ("nscd", "nscd:newton=True"),
        "Backends tried when an nscd step fails (comma-separated), with their own options "
        "(not --nscd-symmetric; plain nscd sweeps forward): they solve the same non-convex "
        "law.",
        kind="names",
    )
    seeds: int = option(
        1, "Packings: the grains' radii drawn with seeds 0 .. seeds-1 (same lattice sites)."
    )
    nscd_twin_tol: float = option(
        0.0,
        "Tolerance of a second nscd run per packing: how far the reference moves with its "
        "tolerance (0: no twin).",
    )
    nscd_symmetric: bool = option(
        True,
        "Alternate nscd's sweep direction or not.",
        flag="--nscd-symmetric/--nscd-forward",
    )


def run(cfg: Settings, *, out: Path, progress: Callable[[str], Any] = print) -> pd.DataFrame:
    """The same 2D collapse with a convex backend (COCD) and with ``nscd``.

    ``times_T`` are in units of ``T = sqrt(H0 / g)``; each is rounded to a
    whole number of 10 ms frames. ``nscd_symmetric``: alternate the direction of
    nscd's sweeps (symmetric Gauss-Seidel), which got through a step of the
    400-disc collapse where forward sweeps stalled above 1e-5 for 100 000 sweeps.
    The two orders stall on different steps: a step of a 2000-disc packing that
    symmetric sweeps and Newton left above 1e-5 after 100 000 sweeps took 85 125
    forward ones, hence forward sweeps first among the fallbacks.
    Returns the table written to ``nscd.csv``: per time, the relative difference
    of the two profiles and both fronts (and, with ``nscd_twin_tol``, the twin's
    ``nscd_twin_*`` columns against the first nscd run).
    """
    from cocd.builders import G

    n = base.positive_int("n", cfg.n)
    (dt,) = base.positives(dt=cfg.dt)
    times_T = sorted(base.positive_list("times_T", cfg.times_T))
    out = Path(out)
    params = base.base_params(n, cfg.mu)
    height = float(params.get("height", 0.14))
    period = math.sqrt(height / G)
    frame_dt = base.frame_interval([0.01], [dt])
    times = sorted({round(t * period / frame_dt) * frame_dt for t in times_T})
    if times[0] <= 0.0:
        raise CocdError(f"times_T {times_T} round to t = 0 s: ask for later times")
    seeds = base.positive_int("seeds", cfg.seeds)
    from solvers.registry import requested

    for backend in cfg.nscd_fallback:  # named, with their options, before the COCD runs
        requested(backend, {}, {})
    twin_tol = base.twin_tolerance("nscd_twin_tol", cfg.nscd_twin_tol, cfg.nscd_tol, "nscd_tol")
    per_seed = 3 if twin_tol else 2
    estimate.announce(
        "nscd",
        [(n, per_seed * seeds * round(max(times) / dt))],
        out=out,
        progress=progress,
        workers=cfg.workers,
    )
    nscd_options: dict[str, Any] = {
        "max_iter": cfg.nscd_max_iter,
        "solver_options": {"symmetric": cfg.nscd_symmetric},
    }
    nscd_how = dataclasses.replace(
        cfg, solver="nscd", tol=cfg.nscd_tol, fallback=tuple(cfg.nscd_fallback)
    )
    runs: list[tuple[Any, dict[str, Any], str]] = [
        (cfg, {}, f"n{n}_{cfg.solver.replace(':', '-')}"),
        (nscd_how, nscd_options, f"n{n}_nscd" + ("-symmetric" if cfg.nscd_symmetric else "")),
    ]
    if twin_tol:  # nscd again, at the twin's tolerance
        twin_how = dataclasses.replace(nscd_how, tol=twin_tol)
        runs.append((twin_how, nscd_options, f"{runs[1][2]}_tol{twin_tol:g}"))
    steps: dict[str, Any] = {"dt": dt, "frame_dt": frame_dt, "profile_times": times}
    jobs = [
        base.collapse_job(out, "nscd", label, seed, params, how, **steps, **extra)
        for seed in range(seeds)
        for how, extra, label in runs
    ]
    made = base.collapse_runs(jobs, cfg.workers, progress)
    every = [made[per_seed * seed : per_seed * (seed + 1)] for seed in range(seeds)]
    first = every[0]
    rows: list[dict[str, Any]] = []
    for seed, mine in enumerate(every):
        rows += _rows(mine, times, period, seed)
    table = pd.DataFrame(rows)
    ensemble = base.ensemble(table, ["t", "t_over_T"], [*_ENSEMBLE, *(_TWIN if twin_tol else ())])
    files = report.write_table(
        out,
        "nscd_ensemble",
        ensemble,
        title="COCD against NSCD (Fig. 4): mean and spread over the packings",
        intro="Per time, over the packings (`seeds` of them): mean and sample standard "
        "deviation (`_sd`, empty for one packing) of the profile differences and of the "
        "fronts in mean diameters from the back wall (`front_*_d`) and their gap "
        "(`front_gap_d` = NSCD - COCD)"
        + (
            f"; `nscd_twin_*`: the same for NSCD at tol {twin_tol:g} against NSCD at "
            f"{cfg.nscd_tol:g}."
            if twin_tol
            else "."
        ),
    )
    figures = [
        base.profile_figure(
            out / "nscd_profiles.png",
            first[:2],
            [f"COCD ({cfg.solver}, tol {cfg.tol:g})", f"NSCD (nscd, tol {cfg.nscd_tol:g})"],
        ),
        _front_figure(out / "nscd_front.png", [mine[:2] for mine in every], period, cfg),
    ]
    firsts = table.groupby("seed").first()
    fallbacks = int(firsts.fallback_steps_nscd.sum())
    twin_fallbacks = int(firsts.fallback_steps_nscd_twin.sum()) if twin_tol else 0
    summary = _summary(ensemble, seeds, first[0], period, dt, cfg, fallbacks, twin_fallbacks)
    intro = (
        "`profile_difference` = ||h_nscd - h_cocd|| / ||h_cocd|| over bins one mean diameter "
        "wide, `profile_difference_4d` over profiles averaged on 4 diameters; fronts "
        "(`surface_front`, a grain's reach) from the back wall in metres and in mean "
        "diameters (`_d`); `seed`: the packing; residuals are each scheme's own "
        "(`ccp_residual` for COCD, `coulomb_residual` for NSCD); `compute_s_*`: detection, "
        "set-up and solve time of each whole run, steps taken again included"
        + (
            f"; `nscd_twin_*`: NSCD at tol {twin_tol:g} against NSCD at {cfg.nscd_tol:g}, "
            "profile difference relative to the latter and front gap (twin - NSCD) in "
            "diameters; `compute_s_nscd_twin`, `fallback_steps_nscd_twin`: the twin's cost "
            "and steps answered by the fallback."
            if twin_tol
            else "."
        )
    )
    base.finish(
        out,
        "nscd",
        "COCD against NSCD (Fig. 4)",
        table,
        intro,
        summary,
        [*files, *figures],
        progress,
    )
    return table


_ENSEMBLE = (
    "profile_difference",
    "profile_difference_4d",
    "front_cocd_d",
    "front_nscd_d",
    "front_gap_d",
)

#: The twin's columns (``nscd_twin_tol``): NSCD at another tolerance against NSCD.
_TWIN = (
    "nscd_twin_difference",
    "nscd_twin_difference_4d",
    "nscd_twin_front_gap_d",
)


def _rows(runs: list[Any], times: list[float], period: float, seed: int) -> list[dict]:
    """One row per time of one packing: the two runs' profiles and fronts compared (and
    NSCD's twin against NSCD, when there is one)."""
    cocd_run, nscd_run, *twin = runs
    rows = []
    for k, t in enumerate(times):
        front_cocd = float(np.interp(t, cocd_run.times, cocd_run.front))
        front_nscd = float(np.interp(t, nscd_run.times, nscd_run.front))
        d = cocd_run.d_mean
        difference, difference_4d = base.profile_errors(nscd_run.profiles[k], cocd_run.profiles[k])
        row: dict[str, Any] = {
            "seed": seed,
            "t": t,
            "t_over_T": t / period,
            "profile_difference": difference,
            "profile_difference_4d": difference_4d,
            "front_cocd_m": front_cocd,
            "front_nscd_m": front_nscd,
            "front0_m": float(cocd_run.front[0]),
            "d_mean_m": d,
            "front_cocd_d": front_cocd / d,
            "front_nscd_d": front_nscd / d,
            "front_gap_d": (front_nscd - front_cocd) / d,
        }
        for s, name in ((cocd_run, "cocd"), (nscd_run, "nscd")):
            row[f"compute_s_{name}"] = s.compute_s
            row[f"penetration_max_{name}"] = s.penetration_max
            row[f"fallback_steps_{name}"] = s.fallback_steps
            row[f"max_residual_{name}"] = float(
                (s.stats.ccp_residual if name == "cocd" else s.stats.coulomb_residual).max()
            )
        if twin:
            (other,) = twin
            (row["nscd_twin_difference"], row["nscd_twin_difference_4d"]) = base.profile_errors(
                other.profiles[k], nscd_run.profiles[k]
            )
            row["nscd_twin_front_gap_d"] = (
                float(np.interp(t, other.times, other.front)) - front_nscd
            ) / d
            row["compute_s_nscd_twin"] = other.compute_s
            row["fallback_steps_nscd_twin"] = other.fallback_steps
        rows.append(row)
    return rows


def _front_figure(
    path: Path, every: list[list[base.CollapseSeries]], period: float, cfg: Settings
) -> Path:
    """Fronts on the seed's axes, ``(r_f - R0) / R0`` against ``t / sqrt(H0/g)``, every
    saved frame: the mean over the packings with a band of one sample standard deviation."""
    plt = base.pyplot()
    fig, ax = plt.subplots(figsize=(6, 4))
    for k, name in ((0, f"COCD ({cfg.solver})"), (1, "NSCD (nscd)")):
        runs = [pair[k] for pair in every]
        t = runs[0].times
        curves = np.array(
            [np.interp(t, s.times, (s.front - s.front[0]) / s.front[0]) for s in runs]
        )
        mean = curves.mean(axis=0)
        (line,) = ax.plot(t / period, mean, label=name)
        if len(runs) > 1:
            sd = curves.std(axis=0, ddof=1)
            ax.fill_between(t / period, mean - sd, mean + sd, color=line.get_color(), alpha=0.25)
    seeds = len(every)
    ax.set_title(
        f"N = {every[0][0].n_grains}, mu = {cfg.mu:g}, {seeds} packing{'s' if seeds > 1 else ''}"
        + (" (mean, band: +- sd)" if seeds > 1 else "")
    )
    ax.set_xlabel("t / sqrt(H0 / g)")
    ax.set_ylabel("(r_f - R0) / R0")
    ax.grid(True, alpha=0.3)
    ax.legend()
    return base.save_figure(fig, path)


def _summary(
    ensemble: pd.DataFrame,
    seeds: int,
    ref: Any,
    period: float,
    dt: float,
    cfg: Settings,
    fallbacks: int,
    twin_fallbacks: int = 0,
) -> str:
    """The summary, every number taken from ``ensemble``."""
    pm = base.pm
    diffs = "; ".join(
        f"t = {row.t_over_T:.2g} T: {pm(row, 'profile_difference')} "
        f"({pm(row, 'profile_difference_4d')} on 4 d)"
        for _, row in ensemble.iterrows()
    )
    final = ensemble.iloc[-1]
    twin = ""
    if "nscd_twin_difference" in ensemble:
        twin = (
            f"NSCD at tol {cfg.nscd_twin_tol:g} against NSCD at {cfg.nscd_tol:g}, the "
            "reference's own sensitivity to its tolerance: profiles differ by "
            + "; ".join(
                f"{pm(row, 'nscd_twin_difference')} "
                f"({pm(row, 'nscd_twin_difference_4d')} on 4 d) at {row.t_over_T:.2g} T"
                for _, row in ensemble.iterrows()
            )
            + f", fronts by {pm(final, 'nscd_twin_front_gap_d')} d at "
            f"{final.t_over_T:.2g} T; the twin's steps answered by the fallback: "
            f"{twin_fallbacks}. "
        )
    return (
        f"2D collapse of {ref.n_grains} discs (mu = {cfg.mu:g}, rough horizontal bed, "
        f"dt = {dt:g} s, T = sqrt(H0/g) = {period:.4g} s), {seeds} "
        f"packing{'s' if seeds > 1 else ''}, COCD with `{cfg.solver}` at tol "
        f"{cfg.tol:g} against `nscd` (exact Coulomb law, "
        f"{'symmetric ' if cfg.nscd_symmetric else ''}Gauss-Seidel) at tol {cfg.nscd_tol:g}. "
        f"Relative profile difference (mean +- spread over the packings): **{diffs}**. "
        f"Fronts at t = {final.t_over_T:.2g} T: {pm(final, 'front_cocd_d')} d (COCD) and "
        f"{pm(final, 'front_nscd_d')} d (NSCD) from the back wall, gap NSCD - COCD "
        f"{pm(final, 'front_gap_d')} d. Steps of `nscd` answered by its fallback "
        f"(`{', '.join(cfg.nscd_fallback) or 'none'}`, the same law): "
        f"{int(fallbacks)} over the packings. "
        + twin
        + "The seed (Fig. 4: 7740 discs in COCD against 6036 in a published NSCD run) "
        "finds the two methods' profiles 'very close'."
    )


STUDY = register(
    "nscd",
    Settings,
    run,
    help="Fig. 4: the same 2D collapse with a convex backend (COCD) and with nscd.",
)
