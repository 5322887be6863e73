"""Figures of a run file (PNG, matplotlib): ``cocd plot RUN.h5 KIND``.

- ``profiles``: the free-surface height ``h(x)`` of the main mass at up to
  eight frames (:func:`cocd.measure.mass_profile`);
- ``front``: the front position of the main mass against time
  (:func:`cocd.measure.front_position`), from the back of the initial mass;
- ``energy``: kinetic and potential energy against time (per frame, from the
  run's statistics);
- ``stats``: per step, the number of contacts, the backend's iterations and
  solve time, and the residuals (``ccp`` and ``coulomb``);
- ``snapshot``: one frame (the last by default): the grains as discs coloured
  by speed (glued grains grey), the force chains as lines between the centres
  of touching grains whose width follows the normal force, the walls, the
  time. A 3D run is seen from the side (``x`` against ``z``), the grains
  nearest the viewer (smallest ``y``) drawn last;
- ``movie``: the snapshots of every frame as a GIF (Pillow) or, for an
  ``.mp4`` output, an MP4 (ffmpeg, e.g. from the ``imageio-ffmpeg`` wheel).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from cocd.errors import CocdError
from cocd.io.runfile import RunFile

__all__ = ["KINDS", "draw_snapshot", "plot_run", "plot_scene"]

KINDS = ("profiles", "front", "energy", "stats", "snapshot", "movie")
#: Figure width (inches) of snapshots and movies; the height follows the scene.
_SNAPSHOT_WIDTH = 9.0
_MAX_PROFILES = 8


def plot_run(
    run_path: str | os.PathLike[str],
    kind: str,
    out: str | os.PathLike[str] | None = None,
    *,
    frame: int | None = None,
) -> Path:
    """Draw one figure of a run file; returns its path (default ``KIND.png`` beside the file).

    ``frame``: the frame of a ``snapshot`` (default the last; negative counts
    from the end). A ``movie`` is written to ``movie.gif`` by default.
    """
    if kind not in KINDS:
        raise CocdError(f"unknown plot {kind!r}; one of {', '.join(KINDS)}")
    if frame is not None and kind != "snapshot":
        raise CocdError(f"--frame is for a snapshot, not a {kind} plot")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    run_path = Path(run_path)
    target = plot_target(run_path, kind, out)
    with RunFile(run_path) as rf:
        if kind == "movie":
            target.parent.mkdir(parents=True, exist_ok=True)
            _movie(rf, plt, target)
            return target
        if kind == "snapshot":
            fig, _ = _snapshot(rf, plt, -1 if frame is None else frame)
        else:
            fig, _ = _DRAW[kind](rf, plt)
            fig.suptitle(_title(rf))
    fig.tight_layout()
    target.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(target, dpi=100 if kind == "snapshot" else 120)
    plt.close(fig)
    return target


def _title(rf: RunFile) -> str:
    """The run's folder, scene and size: what a figure is of."""
    free = int(_free(rf).sum())
    glued = rf.n_grains - free
    params = rf.config.get("params", {})
    mu = params.get("mu", rf.f["scene"].attrs.get("mu", float("nan")))
    size = f"N = {free}" + (f" (+{glued} glued)" if glued else "")
    return f"{rf.path.parent.name}: {rf.config.get('builder', '')}, {rf.dim}D, {size}, mu = {mu:g}"


def _snapshot(rf: RunFile, plt: Any, k: int) -> tuple[Any, Any]:
    n = rf.n_frames
    if not -n <= k < n:
        raise CocdError(f"{rf.path} has frames 0 to {n - 1}; there is no frame {k}")
    fr = rf.frame(k)
    scene = rf.scene(k)
    fig, ax = _snapshot_axes(plt, scene)
    draw_snapshot(ax, scene, fr.velocities, (fr.i, fr.j, fr.impulse[:, 0]), dt=_dt(rf))
    ax.set_title(f"{_title(rf)}\nt = {fr.time:.4g} s (step {fr.step})", fontsize=9)
    return fig, ax


def plot_target(
    run_path: str | os.PathLike[str], kind: str, out: str | os.PathLike[str] | None = None
) -> Path:
    """The file :func:`plot_run` writes: ``out`` (a figure's suffix added, a movie's
    checked) or ``KIND.png`` (``movie.gif``) beside the run file."""
    suffix = ".gif" if kind == "movie" else ".png"
    target = Path(out) if out is not None else Path(run_path).with_name(f"{kind}{suffix}")
    if kind == "movie":
        not_a_folder(target, "movie.gif")
        if target.suffix.lower() not in (".gif", ".mp4"):
            raise CocdError(f"a movie is written as .gif or .mp4, not {target.name!r}")
        return target
    return figure_path(target)


def not_a_folder(path: Path, example: str = "figure.png") -> Path:
    """``path``, unless it names a folder (an existing one, ``.`` or ``..``): then a
    one-line :class:`CocdError`, as a figure or movie is a file."""
    if path.name in ("", ".", "..") or path.is_dir():
        raise CocdError(
            f"{str(path) or '.'} is a folder: give the file to write, e.g. {path / example}"
        )
    return path


def figure_path(path: str | os.PathLike[str]) -> Path:
    """``path`` as the file a figure is saved to: ``.png`` added when it has no suffix
    (as matplotlib would, so the path said is the path written); a suffix matplotlib
    cannot write is refused, naming those it can."""
    from matplotlib.backend_bases import FigureCanvasBase

    path = not_a_folder(Path(path))
    if not path.suffix:
        return path.with_name(path.name + ".png")
    kinds = FigureCanvasBase.get_supported_filetypes()
    if path.suffix[1:].lower() not in kinds:
        raise CocdError(
            f"a figure cannot be written as {path.suffix!r} ({path}); "
            f"use one of {', '.join('.' + k for k in sorted(kinds))}"
        )
    return path


def plot_scene(scene: Any, path: Path | str, *, title: str = "") -> Path:
    """Save a snapshot of ``scene`` as it is (grains coloured by their speed, walls,
    glued grains) to ``path``; return the path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = _snapshot_axes(plt, scene)
    draw_snapshot(ax, scene, scene.velocities)
    if title:
        ax.set_title(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return Path(path)


def _dt(rf: RunFile) -> float:
    return float(rf.config.get("run", {}).get("dt", float("nan")))


def _snapshot_axes(plt: Any, scene: Any) -> tuple[Any, Any]:
    lo, hi = _extent(scene)
    aspect = (hi[1] - lo[1]) / max(hi[0] - lo[0], 1e-12)
    height = float(np.clip(_SNAPSHOT_WIDTH * aspect + 1.2, 2.5, 9.0))
    fig, ax = plt.subplots(figsize=(_SNAPSHOT_WIDTH, height))
    return fig, ax


def _extent(scene: Any) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper corners of the grains in the view's plane (x, last coordinate)."""
    x = scene.positions[:, [0, -1]]
    r = scene.radii[:, None]
    lo, hi = (x - r).min(axis=0), (x + r).max(axis=0)
    pad = 0.03 * float(max(hi - lo)) + float(r.max())
    return lo - pad, hi + pad


def draw_snapshot(
    ax: Any,
    scene: Any,
    velocities: np.ndarray | None = None,
    chains: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    *,
    dt: float = float("nan"),
) -> None:
    """Draw ``scene`` on ``ax``: discs coloured by speed, force chains, walls.

    ``chains``: ``(i, j, normal impulse)`` of the contacts; lines join the
    centres of grain pairs (``j >= 0``) whose impulse is positive, with a
    width that grows with it. ``dt`` turns impulses into forces for the label.
    """
    from matplotlib.collections import EllipseCollection, LineCollection

    x = scene.positions
    r = scene.radii
    dim = x.shape[1]
    view = x[:, [0, dim - 1]]
    order = np.argsort(-x[:, 1]) if dim == 3 else np.arange(len(r))  # far grains first
    speed = np.zeros(len(r)) if velocities is None else np.linalg.norm(velocities, axis=1)
    fixed = np.asarray(scene.fixed, dtype=bool)
    free = order[~fixed[order]]
    glued = order[fixed[order]]
    if glued.size:
        ax.add_collection(EllipseCollection(
            2 * r[glued], 2 * r[glued], np.zeros(glued.size), units="xy", offsets=view[glued],
            offset_transform=ax.transData, facecolors="0.6", edgecolors="0.35", linewidths=0.2,
        ))  # fmt: skip
    if free.size:
        discs = EllipseCollection(
            2 * r[free], 2 * r[free], np.zeros(free.size), units="xy", offsets=view[free],
            offset_transform=ax.transData, cmap="viridis", edgecolors="k", linewidths=0.1,
        )  # fmt: skip
        discs.set_array(speed[free])
        discs.set_clim(0.0, max(float(speed[free].max()), 1e-12))
        ax.add_collection(discs)
        ax.figure.colorbar(discs, ax=ax, label="speed (m/s)", fraction=0.04, pad=0.02)
    if chains is not None:
        i, j, pn = (np.asarray(a) for a in chains)
        pair = (j >= 0) & (pn > 0)
        if pair.any():
            force = pn[pair]
            width = 0.3 + 2.7 * np.sqrt(force / force.max())
            segments = np.stack([view[i[pair]], view[j[pair]]], axis=1)
            ax.add_collection(LineCollection(list(segments), linewidths=width, colors="crimson",
                                             alpha=0.8))  # fmt: skip
            biggest = float(force.max()) / dt if np.isfinite(dt) and dt > 0 else float("nan")
            unit = "N/m" if dim == 2 else "N"
            label = f"force chains (widest {biggest:.3g} {unit})" if np.isfinite(biggest) else (
                "force chains")  # fmt: skip
            ax.plot([], [], color="crimson", lw=2, label=label)
            ax.legend(loc="upper right", fontsize=8)
    lo, hi = _extent(scene)
    for wall in scene.walls:
        n = np.asarray(wall.normal, dtype=float)
        p = np.asarray(wall.point, dtype=float)
        nv, pv = n[[0, dim - 1]], p[[0, dim - 1]]
        if dim == 3 and abs(n[1]) > 0.99:  # a side wall, parallel to the view
            continue
        tangent = np.array([-nv[1], nv[0]])
        span = float(np.linalg.norm(hi - lo)) * 2
        ends = np.stack([pv - span * tangent, pv + span * tangent])
        ax.plot(ends[:, 0], ends[:, 1], color="k", lw=1.5)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("z (m)" if dim == 3 else "y (m)")


def _movie(rf: RunFile, plt: Any, target: Path) -> None:
    from matplotlib import animation

    if target.suffix.lower() == ".mp4":
        try:
            import imageio_ffmpeg

            plt.rcParams["animation.ffmpeg_path"] = imageio_ffmpeg.get_ffmpeg_exe()
        except ImportError:
            pass
        if not animation.writers.is_available("ffmpeg"):
            raise CocdError(
                "an MP4 needs ffmpeg (pip install imageio-ffmpeg); a .gif needs nothing more"
            )
        writer: Any = animation.FFMpegWriter(fps=10)
    else:
        writer = animation.PillowWriter(fps=10)
    scenes = [rf.scene(k) for k in range(rf.n_frames)]
    corners = [_extent(s) for s in scenes]
    lo = np.min([c[0] for c in corners], axis=0)
    hi = np.max([c[1] for c in corners], axis=0)
    fig, ax = _snapshot_axes(plt, scenes[0])
    top = max(float(np.linalg.norm(s.velocities, axis=1).max(initial=0.0)) for s in scenes)
    with writer.saving(fig, str(target), dpi=55):
        for k in range(rf.n_frames):
            fig.clf()
            ax = fig.add_subplot(1, 1, 1)
            fr = rf.frame(k)
            draw_snapshot(ax, scenes[k], fr.velocities, (fr.i, fr.j, fr.impulse[:, 0]),
                          dt=_dt(rf))  # fmt: skip
            for c in ax.collections:
                if c.get_array() is not None:
                    c.set_clim(0.0, max(top, 1e-12))
            ax.set_xlim(lo[0], hi[0])
            ax.set_ylim(lo[1], hi[1])
            ax.set_title(f"{_title(rf)}\nt = {fr.time:.4g} s", fontsize=9)
            writer.grab_frame()
    plt.close(fig)


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
    _tidy([ax], len(stats))
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
    _tidy(axes.flat, len(stats))
    return fig, axes


def _tidy(axes: Any, points: int) -> None:
    """Readable on short runs too: markers on few points, no crowded minor log labels."""
    from matplotlib.ticker import MaxNLocator, NullFormatter

    for ax in axes:
        ax.grid(True, alpha=0.3)
        ax.xaxis.set_major_locator(MaxNLocator(nbins=6))
        if ax.get_yscale() == "log":
            low, high = ax.get_ylim()
            if high < 10.0 * low:  # less than a decade: a linear axis reads better
                ax.set_yscale("linear")
                ax.ticklabel_format(axis="y", style="sci", scilimits=(-2, 3))
            else:
                ax.yaxis.set_minor_formatter(NullFormatter())
        if points <= 30:
            for line in ax.get_lines():
                line.set_marker("o")
                line.set_markersize(3)


_DRAW = {"profiles": _profiles, "front": _front, "energy": _energy, "stats": _stats}
