"""``cocd validate runout`` and ``runout3d``: runout and deposit height against the
column's aspect ratio.

Columns of the same grains and the same cross-section area ``L0 H0``, with
aspect ratios ``a = H0 / L0`` from wide to tall, collapse on a rough
horizontal bed against a back wall (the half-collapse of the channel
experiments) until they stop. The final runout ``(L_f - L0) / L0`` and the
deposit's height ``H_f / H0`` are fitted by two power laws of ``a``, split
where the fit is best (the regime change).

``runout`` collapses 2D columns of discs. ``runout3d`` collapses columns of
spheres in a channel ``width_d`` diameters wide, once per sidewall friction in
``side_mus``: seed 001's wide channel is its 3D collapse with frictionless
sidewalls, its narrow one a channel with the beads' wall friction 0.23.

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
from typing import Any, ClassVar

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from cocd.bench import estimate
from cocd.bench.metrics import BEND_DRAWS, fit_two_power_laws
from cocd.bench.study import option
from cocd.errors import CocdError
from cocd.validate import _common as base
from cocd.validate._common import CollapseSettings, register

__all__ = ["STUDY", "STUDY_3D", "Settings", "Settings3D", "run"]

FloatArray = NDArray[np.float64]
G = 9.81


@dataclass(frozen=True)
class Settings(CollapseSettings):
    """The options of ``cocd validate runout``."""

    #: Discs (2) or spheres (3); the name of the outputs.
    dim: ClassVar[int] = 2
    name: ClassVar[str] = "runout_scaling"

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


@dataclass(frozen=True)
class Settings3D(Settings):
    """The options of ``cocd validate runout3d``: columns of spheres in a channel."""

    dim: ClassVar[int] = 3
    name: ClassVar[str] = "runout3d_scaling"

    solver: str = option("apgd", "Convex backend of the COCD runs.")
    tol: float = option(1e-5, "Tolerance of the convex backend.", positive=True)
    aspects: tuple[float, ...] = option(
        (1.0, 1.4, 1.9, 2.7, 3.8, 5.3, 6.3, 7.4, 10.0, 14.0),
        "Aspect ratios H0/L0 asked (seed 001: logarithmically from 1 to 20). The lattice "
        "holds whole grains along the column: at the default size these build ten "
        "distinct columns, of ratios 1.2 to 25.",
        kind="floats",
    )
    area: float = option(0.01, "Column cross-section L0 H0 along the channel (m^2).")
    diameter: float = option(0.005, "Mean grain diameter (m).")
    mu: float = option(
        0.25,
        "Friction coefficient of the grains and of the back wall (0.25: layers of these "
        "spheres avalanche at 24.5 +- 0.8 degrees in cocd validate avalanche3d, inside seed "
        "001's 23.7 +- 1 for its beads).",
    )
    width_d: float = option(6.0, "Channel width W, in mean diameters.")
    side_mus: tuple[float, ...] = option(
        (0.0, 0.23),
        "Sidewall friction coefficients, one channel each (0: seed 001's wide channel, "
        "frictionless sidewalls; 0.23: its beads on the walls of its narrow channel).",
        kind="numbers",
    )


def run(cfg: Settings, *, out: Path, progress: Callable[[str], Any] = print) -> pd.DataFrame:
    """Collapse columns of aspect ratios ``aspects`` and fit the runout and height laws.

    Each column has cross-section ``area`` (m^2) along the flow, ``L0 = sqrt(area / a)``,
    ``H0 = sqrt(area a)``, grains of mean ``diameter`` on a rough bed long enough for
    the runout, and runs for ``max(min_time, rest_T sqrt(H0 / g))`` seconds. In 3D
    (:class:`Settings3D`) the channel is ``width_d`` diameters wide and each column
    runs once per sidewall friction of ``side_mus``, each fitted apart. Returns the
    table written to ``<name>.csv`` (``runout_scaling`` or ``runout3d_scaling``), one
    row per run.
    """
    aspects = sorted(set(base.positive_list("aspects", cfg.aspects)))
    if len(aspects) < 6:
        raise CocdError("scaling needs at least 6 distinct aspect ratios (three per regime)")
    seeds = base.positive_int("seeds", cfg.seeds)
    area, diameter, dt, rest_T, min_time = base.positives(
        area=cfg.area, diameter=cfg.diameter, dt=cfg.dt, rest_T=cfg.rest_T,
        min_time=cfg.min_time,
    )  # fmt: skip
    for a in aspects:  # a column shorter or lower than 2 diameters is no column
        short = min(math.sqrt(area / a), math.sqrt(area * a))
        if short < 2.0 * diameter:
            raise CocdError(
                f"aspect ratio {a:g} gives a column {short:.3g} m "
                f"{'long' if a > 1 else 'high'}, less than 2 diameters of {diameter:g} m; "
                "use a smaller diameter or a larger area"
            )
    channels: list[float | None] = [None]
    width_d = math.nan
    if isinstance(cfg, Settings3D):
        width_d = base.positives(width_d=cfg.width_d)[0]
        if width_d < 2.0:
            raise CocdError(f"width_d must be at least 2 diameters, got {width_d:g}")
        if not cfg.side_mus or any(not (math.isfinite(m) and m >= 0.0) for m in cfg.side_mus):
            raise CocdError(f"side_mus must be numbers >= 0, got {list(cfg.side_mus)!r}")
        channels = list(dict.fromkeys(float(m) for m in cfg.side_mus))
    name, dim = cfg.name, cfg.dim
    out = Path(out)
    frame_dt = base.frame_interval([0.01], [dt])
    cases = []
    jobs = []
    built: dict[tuple[Any, ...], float] = {}
    # Channel by channel, then packing by packing: a channel's laws are complete first.
    for side_mu, seed, a in (
        (m, seed, a) for m in channels for seed in range(seeds) for a in aspects
    ):
        L0, H0 = math.sqrt(area / a), math.sqrt(area * a)
        until = max(min_time, rest_T * math.sqrt(H0 / G))
        until = math.ceil(until / frame_dt - 1e-9) * frame_dt
        # Room for the runout: the 2D laws give (Lf - L0)/L0 of about 2 a for small a,
        # about 3 a^(2/3) beyond; twice that, and at least 4 L0.
        bed = L0 * (1.0 + max(4.0, 2.0 * max(2.0 * a, 3.0 * a ** (2.0 / 3.0))))
        params: dict[str, Any] = {
            "dim": dim,
            "diameter": diameter,
            "length": L0,
            "height": H0,
            "bed": "rough",
            "bed_length": bed,
            "mu": cfg.mu,
        }
        label = f"a{a:g}_d{diameter * 1e3:g}mm_mu{cfg.mu:g}"
        if side_mu is not None:
            params.update(width=width_d * diameter, mu_side=side_mu)
            label += f"_W{width_d:g}d_side{side_mu:g}"
        # The lattice holds a whole number of grains along the column: two ratios can
        # build the same column, which is run and fitted once, at its built ratio.
        column = base.built_column(base.seed_params(params, seed))
        L_built, H_built = column.length, column.height
        same = (side_mu, seed, round(L_built / diameter, 6), round(H_built / diameter, 6))
        if same in built:
            progress(
                f"{name}: a = {a:g} builds the same column as a = {built[same]:g} "
                f"({L_built / diameter:.1f} x {H_built / diameter:.1f} diameters, "
                f"a = {H_built / L_built:.3g} as built): run once"
            )
            continue
        built[same] = a
        cases.append((side_mu, seed, a, L0, H0, bed, L_built, H_built))
        jobs.append(
            base.collapse_job(
                out,
                "scaling" if dim == 2 else "scaling3d",
                label,
                seed,
                params,
                cfg,
                what=f"L0 = {L0:.3f} m, H0 = {H0:.3f} m"
                + ("" if side_mu is None else f", sidewall friction {side_mu:g}"),
                dt=dt,
                until=until,
                frame_dt=frame_dt,
                profile_times=[until],
            )
        )
    estimate.announce(
        name,
        [(job.free_grains, job.steps) for job in jobs],
        out=out,
        progress=progress,
        workers=cfg.workers,
    )
    rows = []
    made = base.collapse_runs(jobs, cfg.workers, progress)
    for (side_mu, seed, a, L0, H0, bed, L_built, H_built), s in zip(cases, made, strict=True):
        L0_measured = float(s.front[0])
        Lf = float(s.front[-1])
        Hf = float(np.max(s.profiles[-1]))
        # Still moving? The front's speed over the last 0.1 s, in diameters per second.
        k = max(0, len(s.times) - 1 - round(0.1 / frame_dt))
        speed = (s.front[-1] - s.front[k]) / max(s.times[-1] - s.times[k], frame_dt)
        channel = (
            {}
            if side_mu is None
            else {"side_mu": side_mu, "W_over_d": width_d, "W_over_H0": width_d * diameter / H0}
        )
        rows.append(
            {
                **channel,
                "seed": seed,
                "a": a,
                "L0_m": L0,
                "H0_m": H0,
                "a_built": H_built / L_built,
                "L0_built_m": L_built,
                "H0_built_m": H_built,
                "n_grains": s.n_grains,
                "t_end": round(float(s.times[-1]), 9),
                "Lf_m": Lf,
                "runout": (Lf - L0_measured) / L0_measured,
                "Hf_m": Hf,
                "Hf_over_H0": Hf / H_built,
                "front_speed_end_d_per_s": speed / s.d_mean,
                "reached_end": base.cut_short(s.front, bed, s.d_mean),
                "penetration_max": s.penetration_max,
                "compute_s": s.compute_s,
            }
        )
    table = pd.DataFrame(rows)
    by_channel = [(m, table if m is None else table[table.side_mu == m]) for m in channels]
    fit_rows = []
    for side_mu, sub in by_channel:
        ratios = sub.groupby("a").a_built.mean()  # one per asked ratio: its columns' mean
        # Built ratios to 3 digits: packings of one column differ by their largest grain
        # (parts per 10 000), which must not count as distinct ratios in the fit.
        built_a = sub.a_built.map(lambda v: float(f"{v:.3g}"))
        for quantity, y in (("(Lf - L0)/L0", sub.runout), ("H0/Hf", 1.0 / sub.Hf_over_H0)):
            fit = fit_two_power_laws(built_a, y)
            fit["n_low"] = float((ratios < fit["a_c"]).sum())
            fit["n_high"] = float((ratios > fit["a_c"]).sum())
            head = {} if side_mu is None else {"side_mu": side_mu}
            fit_rows.append({**head, "quantity": quantity, **fit})
    fits = pd.DataFrame(fit_rows)
    keys = ["a"] if dim == 2 else ["side_mu", "a"]
    ensemble = base.ensemble(
        table, keys, ["a_built", "runout", "Hf_over_H0"], counts=["reached_end"]
    )
    figures = [_figure(out / f"{name}.png", table, fits, cfg.mu, width_d)]
    per_channel = "" if dim == 2 else " One pair of fits per sidewall friction `side_mu`."
    files = base.report.write_table(
        out,
        f"{name}_fit",
        fits,
        title="Power-law fits of runout and height against aspect ratio",
        intro="`k_low`, `c_low`: `y = c a^k` for `a < a_c`; `k_high`, `c_high` above; "
        "fitted against the built ratio `a_built`; "
        "`k_all`: one law through every point; `k_*_ci`: half-width of the exponent's 95 % "
        "confidence interval (points taken as independent and the split as given: a lower "
        "bound on the uncertainty); `n_low`, `n_high`: aspect ratios on each side; "
        "`p_two_laws`: p-value of the two laws against the one (F ratio, its null drawn "
        "with the split searched afresh; small: the bend is real). Every packing's point "
        "is fitted." + per_channel,
    )
    files += base.report.write_table(
        out,
        f"{name}_ensemble",
        ensemble,
        title="Runout and height against aspect ratio: mean and spread over the packings",
        intro="Per aspect ratio asked"
        + ("" if dim == 2 else " and sidewall friction")
        + ", over the packings (`seeds`): mean and sample standard "
        "deviation (`_sd`) of the built ratio `a_built`, of the runout (Lf - L0)/L0 and of "
        "Hf/H0; `reached_end`: packings whose front came within two diameters of the bed's "
        "end (runout cut short).",
    )

    def law(fit: pd.Series, side: str) -> str:
        return f"a^({fit[f'k_{side}']:.2f} +- {fit[f'k_{side}_ci']:.2f})"

    def bend(fit: pd.Series, what: str) -> str:
        p = fit["p_two_laws"]
        if not math.isfinite(p):
            return f"{what}, too few ratios to test"
        verdict = "a bend" if p < 0.05 else "no bend told from the scatter"
        floor = 1.0 / (1 + BEND_DRAWS)
        return f"{what} p {'<= ' + format(floor, 'g') if p <= floor else f'= {p:.2g}'} ({verdict})"

    def laws(fit_r: pd.Series, fit_h: pd.Series) -> str:
        return (
            "Exponents with their 95 % intervals: runout (Lf - L0)/L0 ~ "
            f"**{law(fit_r, 'low')} below a = {fit_r['a_c']:.2g} ({fit_r['n_low']:.0f} ratios), "
            f"{law(fit_r, 'high')} above ({fit_r['n_high']:.0f})**; H0/Hf ~ "
            f"**{law(fit_h, 'low')} below a = {fit_h['a_c']:.2g} ({fit_h['n_low']:.0f} ratios), "
            f"{law(fit_h, 'high')} above ({fit_h['n_high']:.0f})**; one law through every "
            f"point: runout {law(fit_r, 'all')}, H0/Hf {law(fit_h, 'all')}. Two laws against "
            f"one: {bend(fit_r, 'runout')}; {bend(fit_h, 'H0/Hf')}."
        )

    packings = f"{seeds} packing{'s' if seeds > 1 else ''} each, `{cfg.solver}` at tol {cfg.tol:g}"
    kinds = table.groupby("a").a_built.mean()
    ratios = (
        f"{len(kinds)} aspect ratios a = {', '.join(f'{a:.3g}' for a in kinds)} as built "
        f"(asked: {', '.join(f'{a:g}' for a in kinds.index)})"
    )
    if dim == 2:
        fit_r, fit_h = fits.iloc[0], fits.iloc[1]
        summary = (
            f"2D columns of area {area * 1e4:g} cm^2 (d = {diameter * 1e3:g} mm, "
            f"mu = {cfg.mu:g}, {_grains(table)} discs), {ratios}, {packings}. " + laws(fit_r, fit_h)
        )
    else:
        summary = (
            f"3D columns of {area * 1e4:g} cm^2 along a channel W = {width_d:g} d wide "
            f"(d = {diameter * 1e3:g} mm, grain and back-wall mu = {cfg.mu:g}, "
            f"{_grains(table)} spheres), {ratios}, {packings}."
        )
        for side_mu, _ in by_channel:
            chan = fits[fits.side_mu == side_mu]
            kind = "frictionless sidewalls" if side_mu == 0 else f"sidewall friction {side_mu:g}"
            summary += f" **{kind.capitalize()}**: " + laws(chan.iloc[0], chan.iloc[1])
    summary += (
        " Seed 001 quotes H0/Hf ~ a^0.69 in wide channels and a^0.5 in narrow ones, with a "
        "regime change near a = 7 in the wide one; 2D contact dynamics (Staron and Hinch "
        "2005) gives a runout linear in a at small a and growing as about a^(2/3) above a of "
        "about 3."
    )
    cut = table[table.reached_end]
    if len(cut):
        summary += (
            " Cut short by the bed's end (the front within two diameters of it): a = "
            + ", ".join(f"{a:g}" for a in sorted(set(cut.a)))
            + "; those runouts are lower bounds."
        )
    moving = table[table.front_speed_end_d_per_s > 1.0]
    if len(moving):
        summary += (
            " Still creeping at the end (front faster than one diameter per second): a = "
            + ", ".join(f"{a:g}" for a in sorted(set(moving.a)))
            + "."
        )
    intro = (
        "`a`, `L0_m`, `H0_m`: the column asked; `a_built`, `L0_built_m`, `H0_built_m`: the "
        "column the lattice holds (a whole number of grains along it), against which the "
        "laws are fitted; "
        "`runout` = (Lf - L0)/L0 with the fronts of :func:`cocd.measure.surface_front` from "
        "the back wall; `Hf_m`: the deposit's highest point above the bed, `Hf_over_H0` "
        "over the built height; "
        "`front_speed_end_d_per_s`: the front's speed over the last 0.1 s, in diameters per "
        "second (0: at rest); `reached_end`: the front came within two diameters of the "
        "bed's end."
    )
    if dim == 3:
        intro += (
            " `side_mu`: the sidewalls' friction; `W_over_d`, `W_over_H0`: the channel's "
            "width in diameters and in column heights. Heights and fronts are the side "
            "view: the highest grain across the width."
        )
    base.finish(
        out,
        name,
        "Runout and height against aspect ratio (seed 001)" + ("" if dim == 2 else ", 3D channels"),
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


def _figure(path: Path, table: pd.DataFrame, fits: pd.DataFrame, mu: float, width_d: float) -> Path:
    """Runout and H0/Hf against a: every packing's point, the mean +- sd and the fitted
    laws, per sidewall friction in 3D."""
    from matplotlib.ticker import LogLocator, NullFormatter, ScalarFormatter

    plt = base.pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    table = table.assign(H0_over_Hf=1.0 / table.Hf_over_H0)
    a = table.a_built.to_numpy()
    seeds = table.seed.nunique()
    three_d = "side_mu" in table
    channels = sorted(set(table.side_mu)) if three_d else [None]
    for i, side_mu in enumerate(channels):
        sub = table if side_mu is None else table[table.side_mu == side_mu]
        chan = fits if side_mu is None else fits[fits.side_mu == side_mu]
        tag = "" if side_mu is None else f"sidewall mu {side_mu:g}: "
        colour = f"C{2 * i}"
        stats = sub.groupby("a")[["a_built", "runout", "H0_over_Hf"]].agg(["mean", "std"])
        for ax, column, fit, label in (
            (axes[0], "runout", chan.iloc[0], "(Lf - L0) / L0"),
            (axes[1], "H0_over_Hf", chan.iloc[1], "H0 / Hf"),
        ):
            ax.loglog(sub.a_built, sub[column], ".", color="0.6")
            ax.errorbar(
                stats["a_built"]["mean"],
                stats[column]["mean"],
                yerr=stats[column]["std"].fillna(0.0),
                fmt="o",
                color=colour,
                capsize=3,
                label=f"{tag}mean +- sd ({seeds} packing{'s' if seeds > 1 else ''})",
            )
            if math.isfinite(fit["a_c"]):
                lo = np.geomspace(a.min(), fit["a_c"], 20)
                hi = np.geomspace(fit["a_c"], a.max(), 20)
                ax.loglog(lo, fit["c_low"] * lo ** fit["k_low"], "-", color=f"C{2 * i + 1}",
                          label=f"{tag}a^{fit['k_low']:.2f}, a^{fit['k_high']:.2f}")  # fmt: skip
                ax.loglog(hi, fit["c_high"] * hi ** fit["k_high"], "-", color=f"C{2 * i + 1}")
            ax.set_xlabel("a = H0 / L0, as built")

            ax.set_ylabel(label)
            ax.grid(True, which="both", alpha=0.3)
    # Seed 001's laws of H0/Hf, through the fitted prefactor of the smoothest channel
    # (wide) and of the roughest (narrow).
    ref = np.geomspace(a.min(), a.max(), 20)
    heights = fits[fits.quantity == "H0/Hf"]
    if three_d:
        heights = heights.sort_values("side_mu")
    if not three_d or heights.iloc[0]["side_mu"] == 0:
        axes[1].loglog(ref, float(heights.iloc[0]["c_all"]) * ref**0.69, "k:",
                       label="a^0.69 (seed 001, wide)")  # fmt: skip
    if three_d and heights.iloc[-1]["side_mu"] > 0:
        axes[1].loglog(ref, float(heights.iloc[-1]["c_all"]) * ref**0.5, "k--",
                       label="a^0.5 (seed 001, narrow)")  # fmt: skip
    axes[0].plot([], [], ".", color="0.6", label="each packing")
    for ax in axes:
        ax.legend(fontsize="small")
        for axis in (ax.xaxis, ax.yaxis):  # 1, 2, 5, 10, 20: not 10^0, 10^1
            axis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
            axis.set_major_formatter(ScalarFormatter())
            axis.set_minor_formatter(NullFormatter())
    if three_d:
        fig.suptitle(
            f"3D collapses, {_grains(table)} spheres, mu = {mu:g}, channel {width_d:g} d wide"
        )
    else:
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
STUDY_3D = register(
    "runout3d",
    Settings3D,
    run,
    help="Seed 001: runout and deposit height of 3D collapses against the aspect ratio, "
    "in a channel with frictionless sidewalls and in one with wall friction.",
    outputs=("runout3d_scaling", "runout3d_scaling_fit"),
)
