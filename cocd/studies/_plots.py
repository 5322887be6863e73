"""The studies' figures: work-precision and performance profiles, the stability series."""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from cocd.bench.metrics import performance_profile, performance_ratios

if TYPE_CHECKING:
    from cocd.studies.precision import _Instance

#: Accuracy targets on ``ccp_residual`` of the precision study's profiles and geometric
#: means (dotted lines in its plots).
TARGETS = (1e-4, 1e-6, 1e-8)
#: The precision study's two starts (one column of plots each).
STARTS = ("cold", "warm")


# -- plots --------------------------------------------------------------------
def plot_precision(
    rows: pd.DataFrame,
    inst: _Instance,
    names: Sequence[str],
    warm_capable: set[str],
    out: Path,
) -> Path:
    """Wall time against ccp_residual (top) and u_error (bottom), cold and warm."""
    from matplotlib.figure import Figure
    from matplotlib.ticker import FuncFormatter

    fig = Figure(figsize=(11, 8.5), layout="constrained")
    axes = fig.subplots(2, 2, sharey=True)
    data = rows[rows["problem"] == inst.label]
    palette = colours(names)
    # Seconds read as plain numbers (0.2, 5), not 5 x 10^0; over more than a
    # decade only 1, 2 and 5 of each, so that the labels do not overlap.
    walls = data["wall_s"][data["wall_s"] > 0]
    wide = walls.size > 0 and walls.max() > 10.0 * walls.min()
    digits = (1, 2, 5) if wide else tuple(range(1, 10))
    seconds = FuncFormatter(partial(seconds_label, digits=digits))
    for col, start in enumerate(STARTS):
        for row_k, error in enumerate(("ccp_residual", "u_error")):
            ax = axes[row_k, col]
            plotted = False
            for name in names:
                runs = data[(data["solver"] == name) & (data["start"] == start)]
                runs = runs[np.isfinite(runs[error]) & (runs[error] > 0) & (runs["wall_s"] > 0)]
                if runs.empty:
                    continue
                runs = runs.sort_values("tol", ascending=False)
                borrowed = start == "warm" and name not in warm_capable
                ax.plot(
                    runs[error],
                    runs["wall_s"],
                    marker="o",
                    markersize=4,
                    linestyle="--" if borrowed else "-",
                    markerfacecolor="none" if borrowed else palette[name],
                    color=palette[name],
                )
                plotted = True
            if error == "ccp_residual":
                ax.set_title(f"{start} start")
            if plotted:
                ax.set_xscale("log")
                ax.set_yscale("log")
                ax.yaxis.set_major_formatter(seconds)
                ax.yaxis.set_minor_formatter(seconds)
                ax.grid(True, which="major", alpha=0.3)
                if error == "ccp_residual":
                    for target in TARGETS:
                        ax.axvline(target, color="grey", linestyle=":", linewidth=0.8)
            else:
                # A log axis with nothing on it has no limits to draw.
                ax.text(0.5, 0.5, "no answers", transform=ax.transAxes, ha="center")
            ax.set_xlabel(f"{error} (log scale; left is more accurate)")
            if col == 0:
                ax.set_ylabel("wall time per solve (s, log scale)")
    legend(fig, names, palette, dashed="dashed, hollow: no warm start (its cold runs)")
    fig.suptitle(
        f"{inst.label}: {inst.dim}D, N = {inst.n_free}, Nc = {inst.problem.nc}, dt = {inst.dt:g} s "
        f"(one point per tolerance; dotted: targets {', '.join(f'{t:g}' for t in TARGETS)})"
    )
    path = out / f"precision_{inst.label}.png"
    fig.savefig(path, dpi=110)
    return path


def plot_profiles(
    costs: dict[float, NDArray[np.float64]], names: Sequence[str], n_instances: int, out: Path
) -> Path:
    """One Dolan-Moré profile panel per target."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(4.6 * len(costs), 4.4), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, len(costs), sharey=True))
    palette = colours(names)
    for ax, (target, c) in zip(axes, costs.items(), strict=True):
        ratios = performance_ratios(c)
        finite = ratios[np.isfinite(ratios)]
        top = max(10.0, 2.0 * float(finite.max())) if finite.size else 10.0
        taus = np.geomspace(1.0, top, 400)
        profile = performance_profile(c, taus)
        for s, name in enumerate(names):
            ax.plot(taus, profile[:, s], drawstyle="steps-post", color=palette[name], lw=1.5)
        ax.set_xscale("log")
        ax.set_ylim(-0.02, 1.02)
        ax.set_xlim(1.0, top)
        ax.grid(True, alpha=0.3)
        ax.set_title(f"ccp_residual <= {target:g} ({n_instances} instances)")
        ax.set_xlabel("tau: time over the best solver's time (log scale)")
    axes[0].set_ylabel("fraction of instances within tau of the best")
    legend(fig, names, palette)
    fig.suptitle("Performance profiles (Dolan-Moré): higher and further left is better")
    path = out / "precision_profile.png"
    fig.savefig(path, dpi=110)
    return path


def seconds_label(value: float, _pos: object = None, *, digits: Sequence[int] = (1, 2, 5)) -> str:
    """``value`` as ``%g`` when its leading digit is one of ``digits``, else no label."""
    if not value > 0:
        return ""
    leading = value / 10.0 ** math.floor(math.log10(value) + 1e-9)
    return f"{value:g}" if min(abs(leading - k) for k in digits) < 1e-6 else ""


def legend(fig: Any, names: Sequence[str], colours: dict[str, Any], dashed: str = "") -> None:
    """One legend for every panel, under them, so that it hides no curve."""
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], color=colours[n], marker="o", markersize=4) for n in names]
    labels = list(names)
    if dashed:
        handles.append(
            Line2D([], [], color="black", linestyle="--", marker="o", markerfacecolor="none")
        )
        labels.append(dashed)
    fig.legend(handles, labels, loc="outside lower center", ncols=min(len(labels), 6), fontsize=9)


def colours(names: Sequence[str]) -> dict[str, Any]:
    from matplotlib import colormaps

    cmap = colormaps["tab10" if len(names) <= 10 else "tab20"]
    return {name: cmap(k % cmap.N) for k, name in enumerate(names)}


def plot_stability(
    path: Path,
    table: pd.DataFrame,
    steps: pd.DataFrame,
    threshold: float,
    dim: int,
    n_free: int,
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import colors
    from matplotlib.lines import Line2D

    names = list(dict.fromkeys(table["solver"])) or ["(none)"]
    eps_all = sorted(set(table["tol"])) or [1.0]
    ncols = min(3, len(names))
    nrows = math.ceil(len(names) / ncols)
    fig, axes = plt.subplots(
        nrows, ncols, figsize=(4.2 * ncols, 3.2 * nrows), squeeze=False, sharey=True
    )
    norm = colors.LogNorm(vmin=min(eps_all), vmax=max(eps_all) * (1.0 + 1e-12))
    cmap = plt.get_cmap("viridis")
    for ax, name in zip(axes.flat, names, strict=False):
        for eps in eps_all:
            part = steps[(steps["solver"] == name) & (steps["tol"] == eps)]
            if part.empty:
                continue
            # The log axis cannot show an exact zero; such points are masked.
            y = part["energy_ratio"].to_numpy(dtype=np.float64)
            y = np.where(y > 0.0, y, np.nan)
            ax.plot(part["t_over_T"], y, color=cmap(norm(eps)), lw=1.2)
            row = table[(table["solver"] == name) & (table["tol"] == eps)]
            if not row.empty and row["steps_done"].iloc[0] < row["steps_asked"].iloc[0]:
                ax.plot(part["t_over_T"].iloc[-1], y[-1], "x", color=cmap(norm(eps)), ms=7)
        ax.axhline(threshold, color="crimson", ls="--", lw=1.0)
        ax.set_yscale("log")
        ax.set_title(name)
        ax.set_xlabel("t / sqrt(H/g)")
        ax.grid(True, which="major", alpha=0.3)
    for ax in axes[:, 0]:
        ax.set_ylabel("Ek / (Ek + Ep)")
    for ax in list(axes.flat)[len(names) :]:
        ax.set_visible(False)
    # One legend for all panels, with every eps even if a panel lacks a curve.
    handles = [Line2D([], [], color=cmap(norm(e)), label=f"{e:.0e}") for e in eps_all]
    handles.append(Line2D([], [], color="crimson", ls="--", label="threshold"))
    fig.legend(handles=handles, title="tol", loc="center right", fontsize=8)
    fig.suptitle(f"Box at rest, {n_free} grains in {dim}D (x: run ended early)")
    fig.tight_layout(rect=(0.0, 0.0, 0.9, 1.0))
    fig.savefig(path, dpi=120)
    plt.close(fig)
