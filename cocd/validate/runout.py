"""``cocd validate runout``: runout and deposit height against the column's aspect ratio.

2D columns of the same grains and the same cross-section area ``L0 H0``, with
aspect ratios ``a = H0 / L0`` from wide to tall, collapse on a rough
horizontal bed against a back wall (the half-collapse of the channel
experiments) until they stop. The final runout ``(L_f - L0) / L0`` and the
deposit's height ``H_f / H0`` are fitted by two power laws of ``a``, split
where the fit is best (the regime change).

What they are set against:

- contact dynamics in 2D (Staron and Hinch 2005; Lajeunesse, Monnier and
  Homsy 2005 in experiments): the runout grows linearly with ``a`` at small
  ``a`` and as about ``a^(2/3)`` above a transition near 2 to 3;
- the continuum simulations and experiments of seed 001 (Ionescu et al. 2015,
  Mangeney et al.): ``H0 / H_f ~ a^0.69`` in wide channels, with a regime
  change at ``a`` of order 3 to 7.

Every simulation is a resumable run file (:func:`cocd.validate._common.collapse_series`).
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
from cocd.bench.metrics import BEND_DRAWS, fit_two_power_laws
from cocd.bench.study import option
from cocd.errors import CocdError
from cocd.validate import _common as base
from cocd.validate._common import CollapseSettings, register

__all__ = ["STUDY", "Settings", "run"]

FloatArray = NDArray[np.float64]
G = 9.81


@dataclass(frozen=True)
class Settings(CollapseSettings):
    """The options of ``cocd validate runout``."""

    aspects: tuple[float, ...] = option(
        (0.5, 0.8, 1.2, 1.8, 2.7, 4.0, 6.0, 9.0, 13.0, 20.0),
        "Aspect ratios H0/L0.",
        kind="floats",
    )
    area: float = option(0.02, "Column cross-section L0 H0 (m^2).")
    diameter: float = option(0.007, "Mean grain diameter (m).")
    mu: float = option(0.5, "Friction coefficient (grains and walls).")
    dt: float = option(1e-3, "Time step (s).")
    rest_T: float = option(12.0, "Run time in units of sqrt(H0/g).", flag="--rest-T")
    min_time: float = option(1.0, "Shortest run (s), whatever the aspect ratio.")
    seeds: int = option(
        1, "Packings: the grains' radii drawn with seeds 0 .. seeds-1 (same lattice sites)."
    )


def run(cfg: Settings, *, out: Path, progress: Callable[[str], Any] = print) -> pd.DataFrame:
    """Collapse 2D columns of aspect ratios ``aspects`` and fit the runout and height laws.

    Each column has cross-section ``area`` (m^2), ``L0 = sqrt(area / a)``,
    ``H0 = sqrt(area a)``, grains of mean ``diameter`` on a rough bed long
    enough for the runout, and runs for ``max(min_time, rest_T sqrt(H0 / g))``
    seconds. Returns the table written to ``runout_scaling.csv``, one row per ``a``.
    """
    aspects = sorted(set(base.positive_list("aspects", cfg.aspects)))
    if len(aspects) < 6:
        raise CocdError("scaling needs at least 6 distinct aspect ratios (three per regime)")
    seeds = base.positive_int("seeds", cfg.seeds)
    area, diameter, dt, rest_T, min_time = base.positive_list(
        "area, diameter, dt, rest_T, min_time",
        [cfg.area, cfg.diameter, cfg.dt, cfg.rest_T, cfg.min_time],
    )
    out = Path(out)
    frame_dt = base.frame_interval([0.01], [dt])
    # About 0.8 of the column's area is discs.
    estimate.announce(
        "runout_scaling",
        [
            (
                0.8 * area / (math.pi * diameter**2 / 4),
                max(min_time, rest_T * math.sqrt(math.sqrt(area * a) / G)) / dt,
            )
            for a in aspects
            for _ in range(seeds)
        ],
        out=out,
        progress=progress,
        workers=cfg.workers,
    )
    cases = []
    jobs = []
    for seed, a in ((seed, a) for seed in range(seeds) for a in aspects):
        L0, H0 = math.sqrt(area / a), math.sqrt(area * a)
        until = max(min_time, rest_T * math.sqrt(H0 / G))
        until = math.ceil(until / frame_dt - 1e-9) * frame_dt
        # Room for the runout: the 2D laws give (Lf - L0)/L0 of about 2 a for small a,
        # about 3 a^(2/3) beyond; twice that, and at least 4 L0.
        bed = L0 * (1.0 + max(4.0, 2.0 * max(2.0 * a, 3.0 * a ** (2.0 / 3.0))))
        params = {
            "dim": 2,
            "diameter": diameter,
            "length": L0,
            "height": H0,
            "bed": "rough",
            "bed_length": bed,
            "mu": cfg.mu,
        }
        cases.append((seed, a, L0, H0, bed))
        jobs.append(
            base.collapse_job(
                out,
                "scaling",
                f"a{a:g}_d{diameter * 1e3:g}mm_mu{cfg.mu:g}",
                seed,
                params,
                cfg,
                what=f"L0 = {L0:.3f} m, H0 = {H0:.3f} m",
                dt=dt,
                until=until,
                frame_dt=frame_dt,
                profile_times=[until],
            )
        )
    rows = []
    made = base.collapse_runs(jobs, cfg.workers, progress)
    for (seed, a, L0, H0, bed), s in zip(cases, made, strict=True):
        L0_measured = float(s.front[0])
        Lf = float(s.front[-1])
        Hf = float(np.max(s.profiles[-1]))
        # Still moving? The front's speed over the last 0.1 s, in diameters per second.
        k = max(0, len(s.times) - 1 - round(0.1 / frame_dt))
        speed = (s.front[-1] - s.front[k]) / max(s.times[-1] - s.times[k], frame_dt)
        rows.append(
            {
                "seed": seed,
                "a": a,
                "L0_m": L0,
                "H0_m": H0,
                "n_grains": s.n_grains,
                "t_end": round(float(s.times[-1]), 9),
                "Lf_m": Lf,
                "runout": (Lf - L0_measured) / L0_measured,
                "Hf_m": Hf,
                "Hf_over_H0": Hf / H0,
                "front_speed_end_d_per_s": speed / s.d_mean,
                "reached_end": bool(np.max(s.front) >= bed - 2.0 * s.d_mean),
                "penetration_max": s.penetration_max,
                "compute_s": s.compute_s,
            }
        )
    table = pd.DataFrame(rows)
    fit_r = fit_two_power_laws(table.a, table.runout)
    fit_h = fit_two_power_laws(table.a, 1.0 / table.Hf_over_H0)
    for fit in (fit_r, fit_h):
        fit["n_low"] = float(sum(a < fit["a_c"] for a in aspects))
        fit["n_high"] = float(sum(a > fit["a_c"] for a in aspects))
    fits = pd.DataFrame(
        [
            {"quantity": "(Lf - L0)/L0", **fit_r},
            {"quantity": "H0/Hf", **fit_h},
        ]
    )
    ensemble = base.ensemble(table, ["a"], ["runout", "Hf_over_H0"])
    figures = [_figure(out / "runout_scaling.png", table, fit_r, fit_h, cfg.mu)]
    files = base.report.write_table(
        out,
        "runout_scaling_fit",
        fits,
        title="Power-law fits of runout and height against aspect ratio",
        intro="`k_low`, `c_low`: `y = c a^k` for `a < a_c`; `k_high`, `c_high` above; "
        "`k_all`: one law through every point; `k_*_ci`: half-width of the exponent's 95 % "
        "confidence interval (points taken as independent and the split as given: a lower "
        "bound on the uncertainty); `n_low`, `n_high`: aspect ratios on each side; "
        "`p_two_laws`: p-value of the two laws against the one (F ratio, its null drawn "
        "with the split searched afresh; small: the bend is real). Every packing's point "
        "is fitted.",
    )
    files += base.report.write_table(
        out,
        "runout_scaling_ensemble",
        ensemble,
        title="Runout and height against aspect ratio: mean and spread over the packings",
        intro="Per aspect ratio, over the packings (`seeds`): mean and sample standard "
        "deviation (`_sd`) of the runout (Lf - L0)/L0 and of Hf/H0.",
    )

    def law(fit: dict[str, float], side: str) -> str:
        return f"a^({fit[f'k_{side}']:.2f} +- {fit[f'k_{side}_ci']:.2f})"

    def bend(fit: dict[str, float], name: str) -> str:
        p = fit["p_two_laws"]
        if not math.isfinite(p):
            return f"{name}, too few ratios to test"
        verdict = "a bend" if p < 0.05 else "no bend told from the scatter"
        floor = 1.0 / (1 + BEND_DRAWS)
        return f"{name} p {'<= ' + format(floor, 'g') if p <= floor else f'= {p:.2g}'} ({verdict})"

    summary = (
        f"2D columns of area {area * 1e4:g} cm^2 (d = {diameter * 1e3:g} mm, mu = {cfg.mu:g}, "
        f"{_grains(table)} discs), {len(aspects)} aspect "
        f"ratios a = {', '.join(f'{a:g}' for a in aspects)}, {seeds} "
        f"packing{'s' if seeds > 1 else ''} each, `{cfg.solver}` at tol {cfg.tol:g}. "
        "Exponents with their 95 % intervals: runout (Lf - L0)/L0 ~ "
        f"**{law(fit_r, 'low')} below a = {fit_r['a_c']:.2g} ({fit_r['n_low']:.0f} ratios), "
        f"{law(fit_r, 'high')} above ({fit_r['n_high']:.0f})**; H0/Hf ~ **{law(fit_h, 'low')} "
        f"below a = {fit_h['a_c']:.2g} ({fit_h['n_low']:.0f} ratios), {law(fit_h, 'high')} "
        f"above ({fit_h['n_high']:.0f})**; one law through every point: runout "
        f"{law(fit_r, 'all')}, H0/Hf {law(fit_h, 'all')}. Two laws against one: "
        f"{bend(fit_r, 'runout')}; {bend(fit_h, 'H0/Hf')}. "
        "Seed 001 quotes H0/Hf ~ a^0.69 in wide channels and a^0.5 in narrow ones, with a "
        "regime change near a = 7 in the wide one; 2D contact dynamics (Staron and Hinch "
        "2005) gives a runout linear in a at small a and growing as about a^(2/3) above a of "
        "about 3."
    )
    moving = table[table.front_speed_end_d_per_s > 1.0]
    if len(moving):
        summary += (
            " Still creeping at the end (front faster than one diameter per second): a = "
            + ", ".join(f"{a:g}" for a in sorted(set(moving.a)))
            + "."
        )
    intro = (
        "`runout` = (Lf - L0)/L0 with the fronts of :func:`cocd.measure.surface_front` from "
        "the back wall; `Hf_m`: the deposit's highest point above the bed; "
        "`front_speed_end_d_per_s`: the front's speed over the last 0.1 s, in diameters per "
        "second (0: at rest); `reached_end`: the front came within two diameters of the "
        "bed's end."
    )
    base.finish(
        out,
        "runout_scaling",
        "Runout and height against aspect ratio (seed 001)",
        table,
        intro,
        summary,
        [*figures, *files],
        progress,
    )
    return table


def _grains(table: pd.DataFrame) -> str:
    """The columns' grain count, or its range."""
    low, high = int(table.n_grains.min()), int(table.n_grains.max())
    return f"{low}" if low == high else f"{low} to {high}"


def _figure(
    path: Path,
    table: pd.DataFrame,
    fit_r: dict[str, float],
    fit_h: dict[str, float],
    mu: float,
) -> Path:
    """Runout and H0/Hf against a: every packing's point, the mean +- sd, the fitted laws."""
    plt = base.pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    a = table.a.to_numpy()
    table = table.assign(H0_over_Hf=1.0 / table.Hf_over_H0)
    stats = table.groupby("a")[["runout", "H0_over_Hf"]].agg(["mean", "std"])
    seeds = table.seed.nunique()
    for ax, column, fit, label in (
        (axes[0], "runout", fit_r, "(Lf - L0) / L0"),
        (axes[1], "H0_over_Hf", fit_h, "H0 / Hf"),
    ):
        ax.loglog(a, table[column], ".", color="0.6", label="each packing")
        ax.errorbar(
            stats.index,
            stats[column]["mean"],
            yerr=stats[column]["std"].fillna(0.0),
            fmt="o",
            capsize=3,
            label=f"mean +- sd ({seeds} packing{'s' if seeds > 1 else ''})",
        )
        if math.isfinite(fit["a_c"]):
            lo = np.geomspace(a.min(), fit["a_c"], 20)
            hi = np.geomspace(fit["a_c"], a.max(), 20)
            ax.loglog(lo, fit["c_low"] * lo ** fit["k_low"], "-", label=f"a^{fit['k_low']:.2f}")
            ax.loglog(hi, fit["c_high"] * hi ** fit["k_high"], "-", label=f"a^{fit['k_high']:.2f}")
        ax.set_xlabel("a = H0 / L0")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
    ref = np.geomspace(a.min(), a.max(), 20)
    axes[1].loglog(ref, (fit_h["c_all"]) * ref**0.69, "k:", label="a^0.69 (seed 001, wide)")
    for ax in axes:
        ax.legend(fontsize="small")
    fig.suptitle(f"2D collapses, {_grains(table)} discs, mu = {mu:g}")
    return base.save_figure(fig, path)


STUDY = register(
    "runout",
    Settings,
    run,
    help="Seed 001: runout and deposit height of 2D collapses against the aspect ratio.",
    outputs=("runout_scaling", "runout_scaling_fit"),
    aliases=("scaling",),
)
