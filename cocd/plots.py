"""Figures of a run file (PNG, matplotlib): ``cocd plot RUN.h5 KIND``.

- ``profiles``: the free-surface height ``h(x)`` of the main mass at up to
  eight frames (:func:`cocd.measure.mass_profile`);
- ``front``: the front position of the main mass against time
  (:func:`cocd.measure.front_position`), from the back of the initial mass;
- ``energy``: kinetic and potential energy against time (per frame, from the
  run's statistics);
- ``stats``: per step, the number of contacts, the backend's iterations and
  solve time, and the residuals (``ccp`` and ``coulomb``).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from cocd.errors import CocdError
from cocd.io.runfile import RunFile

__all__ = ["KINDS", "plot_run"]

KINDS = ("profiles", "front", "energy", "stats")
_MAX_PROFILES = 8


def plot_run(
    run_path: str | os.PathLike[str], kind: str, out: str | os.PathLike[str] | None = None
) -> Path:
    """Draw one figure of a run file; returns the PNG's path (default beside the file)."""
    if kind not in KINDS:
        raise CocdError(f"unknown plot {kind!r}; one of {', '.join(KINDS)}")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    run_path = Path(run_path)
    target = Path(out) if out is not None else run_path.with_name(f"{kind}.png")
    with RunFile(run_path) as rf:
        fig, _ = _DRAW[kind](rf, plt)
        fig.suptitle(f"{run_path.name}: {rf.config.get('builder', '')} ({rf.dim}D)")
    fig.tight_layout()
    target.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(target, dpi=120)
    plt.close(fig)
    return target


def _free(rf: RunFile) -> np.ndarray:
    return ~np.asarray(rf.f["scene/fixed"][:], dtype=bool)


def _profiles(rf: RunFile, plt: Any) -> tuple[Any, Any]:
    from cocd.measure import mass_profile

    fig, ax = plt.subplots(figsize=(8, 4))
    free = _free(rf)
    picks = np.unique(np.linspace(0, rf.n_frames - 1, min(_MAX_PROFILES, rf.n_frames)).astype(int))
    x_all = [rf.frame(k).positions[free, 0] for k in picks]
    lo = min(float(x.min()) for x in x_all) - float(rf.radii.max())
    hi = max(float(x.max()) for x in x_all) + float(rf.radii.max())
    bins = np.linspace(lo, hi, max(10, int((hi - lo) / (2.0 * float(rf.radii.mean())))))
    for k in picks:
        frame = rf.frame(k)
        prof = mass_profile(frame.positions, rf.radii, x_bins=bins, mask=free)
        ax.plot(prof.x_centres, prof.mean_height, label=f"t = {frame.time:.3g} s")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("h (m)")
    ax.set_ylim(bottom=0.0)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    return fig, ax


def _front(rf: RunFile, plt: Any) -> tuple[Any, Any]:
    """The front against time, measured as fits the scene.

    Over an erodible layer every grain touches every other through the layer,
    so the foremost grain of the connected mass is the layer's end: the front
    is then where the free surface stands above the layer's initial top
    (:func:`~cocd.measure.surface_front`, bins of one mean diameter). Otherwise
    it is the foremost surface of the main mass (:func:`~cocd.measure.front_position`).
    """
    from cocd.measure import bed_surface, front_position, surface_front

    free = _free(rf)
    scene0 = rf.scene(0)
    layer = scene0.groups.get("layer", slice(0, 0))
    erodible = layer.stop > layer.start
    r = rf.radii
    back = float(np.min(scene0.positions[free, 0] - r[free]))
    if erodible:
        d_mean = 2.0 * float(r[free].mean())
        x_end = float(np.max(scene0.positions[:, 0] + r))
        edges = np.arange(back, x_end + d_mean, d_mean)
        surface = bed_surface(scene0, edges)
    times, fronts = [], []
    for k in range(rf.n_frames):
        frame = rf.frame(k)
        times.append(frame.time)
        if erodible:
            fronts.append(
                surface_front(frame.positions, r, x_bins=edges, surface=surface, mask=free)
            )
        else:
            fronts.append(front_position(frame.positions, r, mask=free))
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.plot(times, np.asarray(fronts) - back, "o-", ms=3)
    ax.set_xlabel("t (s)")
    how = "free surface above the erodible layer" if erodible else "foremost grain of the mass"
    ax.set_ylabel("front from the back of the mass (m)")
    ax.set_title(f"front: {how}", fontsize=9)
    ax.grid(True, alpha=0.3)
    return fig, ax


def _energy(rf: RunFile, plt: Any) -> tuple[Any, Any]:
    stats = rf.stats()
    if not len(stats):
        raise CocdError(f"{rf.path}: no step recorded yet: nothing to plot")
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.plot(stats.t, stats.kinetic_energy, label="kinetic")
    ax.plot(stats.t, stats.potential_energy - stats.potential_energy.iloc[-1], label="potential")
    unit = "J/m" if rf.dim == 2 else "J"
    ax.set_xlabel("t (s)")
    ax.set_ylabel(f"energy ({unit}; potential from its final value)")
    ax.grid(True, alpha=0.3)
    ax.legend()
    return fig, ax


def _stats(rf: RunFile, plt: Any) -> tuple[Any, Any]:
    stats = rf.stats()
    if not len(stats):
        raise CocdError(f"{rf.path}: no step recorded yet: nothing to plot")
    fig, axes = plt.subplots(2, 2, figsize=(10, 6), sharex=True)
    axes[0, 0].plot(stats.t, stats.nc)
    axes[0, 0].set_ylabel("contacts")
    axes[0, 1].plot(stats.t, stats.iterations)
    axes[0, 1].set_ylabel("iterations")
    axes[1, 0].semilogy(stats.t, stats.solve_time)
    axes[1, 0].set_ylabel("solve time (s)")
    for name in ("ccp_residual", "coulomb_residual"):
        values = np.maximum(stats[name].to_numpy(dtype=float), 1e-300)
        axes[1, 1].semilogy(stats.t, values, label=name.removesuffix("_residual"))
    axes[1, 1].set_ylabel("residual")
    axes[1, 1].legend()
    for ax in axes[1]:
        ax.set_xlabel("t (s)")
    for ax in axes.flat:
        ax.grid(True, alpha=0.3)
    return fig, axes


_DRAW = {"profiles": _profiles, "front": _front, "energy": _energy, "stats": _stats}
