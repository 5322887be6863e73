"""``cocd validate``: the physics of the seed paper, reproduced at this machine's scale.

Each case runs a few column collapses (or a static box) with
:func:`cocd.runs.run`, one run file per simulation under
``<out>/runs/<case>/<label>/run.h5``, then measures the saved frames and
writes a table, figures and ``<case>.meta.json`` under ``<out>``
(default ``cocd-results/validation``), whose ``README.md`` is rebuilt from them.

- ``timestep`` (the seed's Fig. 2): a 2D collapse on a rough horizontal bed
  with several time steps; mass profiles at a few times and their relative
  error against the smallest step, ``||h_dt - h_ref|| / ||h_ref||``.
- ``nscd`` (Fig. 4): the same collapse with a convex backend (the COCD
  scheme) and with ``nscd`` (the non-convex Coulomb law, Gauss-Seidel);
  profiles at times in units of ``sqrt(H0 / g)`` and their relative difference.
- ``erodible`` (Fig. 9): collapses on a slope over erodible layers of several
  thicknesses (in mean diameters); front position against time, and the
  runout of each layer relative to the bed without a layer.
- ``stability`` (Fig. 3): the tolerance at which each backend keeps a static
  box at rest (:mod:`cocd.bench.stability`), and the largest tolerance that
  still does.

Every simulation is resumable: a case run again continues each run file
from its last frame (a run killed half-way loses at most one frame
interval), and a finished run is only measured again. ``fresh=True``
starts them over. A failed step stops the case with a :class:`CocdError`
naming it; the run files keep what was computed.

Profiles are the free-surface height of the main connected mass above the
bed's top (:func:`cocd.measure.mass_profile`), on bins one mean diameter
wide, zero where there is no grain. Fronts are those of the grains that
started in the column (:func:`cocd.measure.front_position`), measured from
the back wall; on an erodible bed the layer's grains do not count, so the
front is the column's, as in the experiments the seed compares with.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

from cocd.bench import estimate, report
from cocd.errors import CocdError

__all__ = [
    "CASES",
    "CollapseSeries",
    "coarsen",
    "collapse_series",
    "erodible",
    "nscd",
    "profile_error",
    "stability",
    "timestep",
]

FloatArray = NDArray[np.float64]

#: The cases of ``cocd validate`` (``scaling``: :mod:`cocd.bench.runout`;
#: ``avalanche``: :mod:`cocd.bench.avalanche`).
CASES = ("timestep", "nscd", "erodible", "stability", "scaling", "avalanche")

#: Seconds between two progress lines of one simulation.
PROGRESS_S = 20.0

#: Bins averaged into one for the coarse-grained profile errors (``*_4d`` columns):
#: one-diameter bins see single grains, four-diameter bins the mass.
COARSE = 4

#: Fraction of an erodible run, at its end, over which the front is averaged for
#: its runout.
RUNOUT_WINDOW = 0.1

#: Relative tolerance when a requested time is matched to a saved frame (in steps).
_FRAME_MATCH = 0.5


# -- running and measuring one collapse -------------------------------------------------
@dataclass(frozen=True)
class CollapseSeries:
    """What is measured on one simulated collapse.

    ``times``: the saved frames' times (s); ``front``: the flow's front at
    those times (:func:`cocd.measure.surface_front`), from the back wall (m);
    ``profiles``: the height above the bed per bin at the asked times (rows), on
    ``x_edges``; ``stats``: the run's per-step statistics (:attr:`compute_s`
    sums their detection, set-up and solve times); ``n_grains``: the column's
    grains; ``d_mean``: their mean diameter (m).
    """

    label: str
    path: Path
    times: FloatArray
    front: FloatArray
    profile_times: FloatArray
    profiles: FloatArray
    x_edges: FloatArray
    stats: pd.DataFrame
    n_grains: int
    d_mean: float

    @property
    def steps(self) -> int:
        return len(self.stats)

    @property
    def penetration_max(self) -> float:
        """Largest end-of-step overlap of the run, relative to the smaller radius (NaN: a
        run file written before overlaps were measured)."""
        values = self.stats.penetration.to_numpy(dtype=float)
        return float(np.max(values)) if values.size and np.all(np.isfinite(values)) else np.nan

    @property
    def compute_s(self) -> float:
        """Seconds of detection, set-up and solving summed over the steps."""
        s = self.stats
        return float((s.detect_time + s.setup_time + s.solve_time).sum())


def collapse_series(
    folder: Path,
    params: dict[str, Any],
    *,
    label: str,
    dt: float,
    until: float,
    frame_dt: float,
    solver: str,
    tol: float,
    profile_times: Sequence[float] = (),
    max_iter: int | None = None,
    fallback: Sequence[str] = (),
    solver_options: dict[str, Any] | None = None,
    bin_width: float | None = None,
    x_max: float | None = None,
    fresh: bool = False,
    progress: Callable[[str], Any] = print,
) -> CollapseSeries:
    """Run (or resume, or just read) one ``column_collapse`` and measure it.

    ``params`` are :func:`cocd.builders.column_collapse`'s arguments. Frames
    are saved every ``frame_dt`` seconds (a whole number of steps). Profiles
    are measured at ``profile_times``, each of which must fall on a saved
    frame; bins are ``bin_width`` wide (default: one mean diameter) from the
    back wall to ``x_max`` (default: the bed's end).
    """
    from cocd.config import RunConfig
    from cocd.errors import SolverError
    from cocd.runs import RUN_FILE, Progress, run

    every = max(1, round(frame_dt / dt))
    if abs(every * dt - frame_dt) > 1e-9 * frame_dt:
        raise CocdError(f"frame interval {frame_dt:g} s is not a whole number of steps of {dt:g}")
    run_table: dict[str, Any] = {
        "dt": dt,
        "until": until,
        "solver": solver,
        "tol": tol,
        "frame_every": every,
        "fallback": list(fallback),
        "solver_options": dict(solver_options or {}),
    }
    if max_iter is not None:
        run_table["max_iter"] = max_iter
    config = RunConfig.model_validate(
        {"builder": "column_collapse", "params": params, "run": run_table}
    )
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    last = [time.perf_counter()]

    def tick(p: Progress) -> None:
        now = time.perf_counter()
        if now - last[0] >= PROGRESS_S or p.done == p.total:
            last[0] = now
            rec = p.record
            progress(
                f"  {label}: step {p.done}/{p.total}  t {rec.t:.4f} s  Nc {rec.nc}  "
                f"it {rec.iterations}  ({p.elapsed:.0f} s this call)"
            )

    try:
        summary = run(
            config, folder, resume=not fresh, force=fresh, progress=tick, source=str(folder)
        )
    except SolverError as exc:
        raise CocdError(
            f"{label}: {exc}; the run file {folder / RUN_FILE} keeps the frames before it "
            "(run the case again to resume, or change the solver or tolerance)"
        ) from None
    if summary.resumed_from_step and summary.steps > summary.resumed_from_step:
        progress(f"  {label}: resumed at step {summary.resumed_from_step}")
    return _measure(summary.path, label, profile_times, bin_width, x_max, dt)


def _measure(
    path: Path,
    label: str,
    profile_times: Sequence[float],
    bin_width: float | None,
    x_max: float | None,
    dt: float,
) -> CollapseSeries:
    from cocd.io.runfile import RunFile
    from cocd.measure import bed_surface, mass_profile, surface_front

    with RunFile(path) as rf:
        scene0 = rf.scene(0)
        column = np.zeros(rf.n_grains, dtype=bool)
        column[scene0.groups["column"]] = True
        r = rf.radii
        d_mean = 2.0 * float(r[column].mean())
        bed = scene0.groups.get("bed", slice(0, 0))
        base = float(np.max(scene0.positions[bed, -1] + r[bed])) if bed.stop > bed.start else 0.0
        free = ~scene0.fixed
        if x_max is None:
            x_max = float(np.max(scene0.positions[:, 0] + r))
        width = d_mean if bin_width is None else bin_width
        edges = np.arange(0.0, x_max + width, width)
        surface = bed_surface(scene0, edges)  # the erodible layer's top, else the bed's
        times = rf.times.copy()
        front = np.array(
            [
                surface_front(rf.frame(k).positions, r, x_bins=edges, surface=surface, mask=free)
                for k in range(rf.n_frames)
            ]
        )
        profiles = []
        for t in profile_times:
            k = int(np.argmin(np.abs(times - t)))
            if abs(times[k] - t) > _FRAME_MATCH * dt:
                raise CocdError(f"{label}: no frame saved at t = {t:g} s in {path}")
            prof = mass_profile(rf.frame(k).positions, r, x_bins=edges, mask=free)
            profiles.append(np.nan_to_num(prof.height - base, nan=0.0).clip(min=0.0))
        stats = rf.stats()
        n_grains = int(column.sum())
    return CollapseSeries(
        label=label,
        path=path,
        times=times,
        front=front,
        profile_times=np.asarray(profile_times, dtype=float),
        profiles=np.asarray(profiles).reshape(len(profile_times), len(edges) - 1),
        x_edges=edges,
        stats=stats,
        n_grains=n_grains,
        d_mean=d_mean,
    )


def profile_error(h: ArrayLike, reference: ArrayLike) -> float:
    """Relative profile error ``||h - h_ref|| / ||h_ref||`` (2-norm over the bins)."""
    h = np.asarray(h, dtype=float)
    ref = np.asarray(reference, dtype=float)
    if h.shape != ref.shape:
        raise CocdError(f"profiles on different bins: {h.shape} and {ref.shape}")
    norm = float(np.linalg.norm(ref))
    if norm == 0.0:
        raise CocdError("the reference profile is empty")
    return float(np.linalg.norm(h - ref) / norm)


def coarsen(h: ArrayLike, k: int) -> FloatArray:
    """A profile on bins ``k`` times wider: the mean of each run of ``k`` bins (the last
    run padded with zeros)."""
    h = np.asarray(h, dtype=float)
    pad = (-h.size) % k
    return np.asarray(np.concatenate([h, np.zeros(pad)]).reshape(-1, k).mean(axis=1))


def _base_params(n: int, mu: float, slope: float = 0.0, **extra: Any) -> dict[str, Any]:
    return {"dim": 2, "n_grains": int(n), "bed": "rough", "mu": mu, "slope_deg": slope, **extra}


def _positive_int(name: str, value: int, low: int = 1) -> int:
    if int(value) != value or value < low:
        raise CocdError(f"{name} must be an integer >= {low}, got {value!r}")
    return int(value)


def _positive_list(name: str, values: Sequence[float]) -> list[float]:
    out = [float(v) for v in values]
    if not out or any(not (math.isfinite(v) and v > 0.0) for v in out):
        raise CocdError(f"{name} must be positive numbers, got {list(values)!r}")
    return out


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig: Any, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    _plt().close(fig)
    return path


def _finish(
    out: Path,
    name: str,
    title: str,
    table: pd.DataFrame,
    intro: str,
    summary: str,
    figures: list[Path],
    progress: Callable[[str], Any],
) -> None:
    files = report.write_table(out, name, table, title=title, intro=intro)
    report.write_meta(out, name, title=title, files=[*files, *figures], summary=summary)
    readme = report.write_readme(out, heading="Validation against the seed papers")
    progress(f"{name}: wrote {', '.join(str(f) for f in [*files, *figures])}; {readme}")


def _fmt(x: float) -> str:
    return f"{x:.3g}"


# -- timestep: the seed's Fig. 2 ---------------------------------------------------------
def timestep(
    *,
    n: int = 400,
    dts: Sequence[float] = (1e-3, 1e-4, 5e-5),
    times: Sequence[float] = (0.02, 0.06, 0.30),
    mu: float = 0.3,
    solver: str = "ipm",
    tol: float = 1e-8,
    fallback: Sequence[str] = ("clarabel",),
    out: Path = Path("results/validation"),
    fresh: bool = False,
    progress: Callable[[str], Any] = print,
) -> pd.DataFrame:
    """Profiles of one 2D collapse at several time steps; error against the smallest.

    Returns the table written to ``timestep.csv``: one row per (dt, t) with
    the profile error against the smallest ``dt`` and the front position.
    """
    n = _positive_int("n", n)
    dts = sorted(_positive_list("dts", dts), reverse=True)
    times = sorted(_positive_list("times", times))
    if len(dts) < 2:
        raise CocdError("timestep needs at least two time steps")
    out = Path(out)
    params = _base_params(n, mu)
    frame_dt = _frame_interval(times, dts)
    estimate.announce(
        "timestep", [(n, round(max(times) / dt)) for dt in dts], out=out, progress=progress
    )
    series = []
    for dt in dts:
        label = f"n{n}_dt{dt:.0e}"
        progress(f"timestep: {label} ({solver}, tol {tol:g}) to t = {max(times):g} s")
        series.append(
            collapse_series(
                out / "runs" / "timestep" / label,
                params,
                label=label,
                dt=dt,
                until=max(times),
                frame_dt=frame_dt,
                solver=solver,
                tol=tol,
                fallback=fallback,
                profile_times=times,
                fresh=fresh,
                progress=progress,
            )
        )
    ref = series[-1]
    rows = []
    for s, dt in zip(series, dts, strict=True):
        for k, t in enumerate(times):
            rows.append(
                {
                    "dt": dt,
                    "t": t,
                    "profile_error": profile_error(s.profiles[k], ref.profiles[k]),
                    "profile_error_4d": profile_error(
                        coarsen(s.profiles[k], COARSE), coarsen(ref.profiles[k], COARSE)
                    ),
                    "front_m": float(np.interp(t, s.times, s.front)),
                    "front_ref_m": float(np.interp(t, ref.times, ref.front)),
                    "steps": s.steps,
                    "mean_nc": float(s.stats.nc.mean()),
                    "penetration_max": s.penetration_max,
                    "compute_s": s.compute_s,
                }
            )
    table = pd.DataFrame(rows)
    figures = [
        _profile_figure(out / "timestep_profiles.png", series, [f"dt = {d:g} s" for d in dts])
    ]
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5.5, 4))
    for t in times:
        sub = table[(table.t == t) & (table.dt > dts[-1])]
        ax.loglog(sub.dt, sub.profile_error, "o-", label=f"t = {t:g} s")
    ax.set_xlabel("dt (s)")
    ax.set_ylabel(f"profile error against dt = {dts[-1]:g} s")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    figures.append(_save(fig, out / "timestep_error.png"))

    coarse = table[table.dt == dts[0]]
    errors = ", ".join(
        f"{_fmt(e)} ({_fmt(e4)} on 4 d) at t = {t:g} s"
        for t, e, e4 in zip(coarse.t, coarse.profile_error, coarse.profile_error_4d, strict=True)
    )
    summary = (
        f"2D collapse of {ref.n_grains} discs (d = {ref.d_mean * 1e3:.2f} mm, mu = {mu:g}, "
        f"rough horizontal bed), `{solver}` at tol {tol:g}, dt = "
        f"{', '.join(f'{d:g}' for d in dts)} s. Profile error of dt = {dts[0]:g} s against "
        f"dt = {dts[-1]:g} s: **{errors}**. The seed (Fig. 2, 2D) finds the profiles of "
        "dt = 1e-3 s 'very close, with only slight differences' to those of 5e-5 s, "
        "and those of 1e-4 s in excellent agreement."
    )
    intro = (
        "`profile_error` = ||h_dt - h_ref|| / ||h_ref|| over bins one mean diameter wide "
        f"(h: free-surface height above the bed; reference dt = {dts[-1]:g} s), "
        "`profile_error_4d` the same on the profiles averaged over 4 diameters (a single "
        "grain's jump between neighbouring one-diameter bins counts less); "
        "`front_m`: the flow's front from the back wall (surface_front); `compute_s`: detection, "
        "set-up and solve time of the whole run."
    )
    _finish(
        out, "timestep", "Time step convergence (Fig. 2)", table, intro, summary, figures, progress
    )
    return table


def _frame_interval(times: Sequence[float], dts: Sequence[float]) -> float:
    """A frame interval on which every asked time and every step falls: 0.01 s or finer."""
    for frame_dt in (1e-2, 5e-3, 2e-3, 1e-3, 5e-4, 1e-4):
        ok = all(abs(t / frame_dt - round(t / frame_dt)) < 1e-6 for t in times)
        ok = ok and all(abs(frame_dt / d - round(frame_dt / d)) < 1e-6 for d in dts)
        ok = ok and all(frame_dt >= d - 1e-15 for d in dts)
        if ok:
            return frame_dt
    raise CocdError(
        f"the times {list(times)} do not fall on whole numbers of the steps {list(dts)}"
    )


def _profile_figure(path: Path, series: list[CollapseSeries], labels: list[str]) -> Path:
    plt = _plt()
    times = series[0].profile_times
    fig, axes = plt.subplots(1, len(times), figsize=(4.2 * len(times), 3.4), squeeze=False)
    reach = max(
        float(s.x_edges[np.nonzero(s.profiles.max(axis=0) > 0)[0].max() + 1])
        for s in series
        if s.profiles.max() > 0
    )
    for k, (ax, t) in enumerate(zip(axes[0], times, strict=True)):
        for s, lab in zip(series, labels, strict=True):
            centres = 0.5 * (s.x_edges[:-1] + s.x_edges[1:])
            ax.plot(centres, s.profiles[k], label=lab, lw=1.2)
        ax.set_title(f"t = {t:g} s")
        ax.set_xlim(0.0, 1.05 * reach)
        ax.set_xlabel("x (m)")
        ax.grid(True, alpha=0.3)
    axes[0][0].set_ylabel("h (m)")
    axes[0][0].legend(fontsize=8)
    return _save(fig, path)


# -- nscd: the seed's Fig. 4 -------------------------------------------------------------
def nscd(
    *,
    n: int = 400,
    dt: float = 1e-3,
    times_T: Sequence[float] = (1.0, 2.0, 4.0, 8.0),
    mu: float = 0.3,
    convex: str = "ipm",
    tol: float = 1e-8,
    nscd_tol: float = 1e-5,
    nscd_max_iter: int = 100000,
    nscd_symmetric: bool = True,
    fallback: Sequence[str] = ("clarabel",),
    out: Path = Path("results/validation"),
    fresh: bool = False,
    progress: Callable[[str], Any] = print,
) -> pd.DataFrame:
    """The same 2D collapse with a convex backend (COCD) and with ``nscd``.

    ``times_T`` are in units of ``T = sqrt(H0 / g)``; each is rounded to a
    whole number of 10 ms frames. ``nscd_symmetric``: alternate the direction of
    nscd's sweeps (symmetric Gauss-Seidel), which got through a step of the
    400-disc collapse where forward sweeps stalled above 1e-5 for 100 000 sweeps.
    Returns the table written to ``nscd.csv``: per time, the relative difference
    of the two profiles and both fronts.
    """
    from cocd.builders import G

    n = _positive_int("n", n)
    (dt,) = _positive_list("dt", [dt])
    times_T = sorted(_positive_list("times_T", times_T))
    out = Path(out)
    params = _base_params(n, mu)
    height = float(params.get("height", 0.14))
    period = math.sqrt(height / G)
    frame_dt = _frame_interval([0.01], [dt])
    times = sorted({round(t * period / frame_dt) * frame_dt for t in times_T})
    if times[0] <= 0.0:
        raise CocdError(f"times_T {times_T} round to t = 0 s: ask for later times")
    estimate.announce("nscd", [(n, 2 * round(max(times) / dt))], out=out, progress=progress)
    runs = []
    for solver, solver_tol, extra in (
        (convex, tol, {"fallback": fallback}),
        (
            "nscd",
            nscd_tol,
            {"max_iter": nscd_max_iter, "solver_options": {"symmetric": nscd_symmetric}},
        ),
    ):
        label = f"n{n}_{solver.replace(':', '-')}"
        if solver == "nscd" and nscd_symmetric:
            label += "-symmetric"
        progress(f"nscd: {label} (tol {solver_tol:g}) to t = {max(times):g} s")
        runs.append(
            collapse_series(
                out / "runs" / "nscd" / label,
                params,
                label=label,
                dt=dt,
                until=max(times),
                frame_dt=frame_dt,
                solver=solver,
                tol=solver_tol,
                profile_times=times,
                fresh=fresh,
                progress=progress,
                **extra,
            )
        )
    cocd_run, nscd_run = runs
    rows = []
    for k, t in enumerate(times):
        rows.append(
            {
                "t": t,
                "t_over_T": t / period,
                "profile_difference": profile_error(nscd_run.profiles[k], cocd_run.profiles[k]),
                "profile_difference_4d": profile_error(
                    coarsen(nscd_run.profiles[k], COARSE), coarsen(cocd_run.profiles[k], COARSE)
                ),
                "front_cocd_m": float(np.interp(t, cocd_run.times, cocd_run.front)),
                "front_nscd_m": float(np.interp(t, nscd_run.times, nscd_run.front)),
            }
        )
    table = pd.DataFrame(rows)
    for s, name in ((cocd_run, "cocd"), (nscd_run, "nscd")):
        table[f"compute_s_{name}"] = s.compute_s
        table[f"penetration_max_{name}"] = s.penetration_max
        table[f"max_residual_{name}"] = float(
            (s.stats.ccp_residual if name == "cocd" else s.stats.coulomb_residual).max()
        )
    figures = [
        _profile_figure(
            out / "nscd_profiles.png",
            runs,
            [f"COCD ({convex}, tol {tol:g})", f"NSCD (nscd, tol {nscd_tol:g})"],
        )
    ]
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 4))
    for s, name in ((cocd_run, "COCD"), (nscd_run, "NSCD")):
        ax.plot(s.times / period, (s.front - s.front[0]) / 0.2, label=name)
    ax.set_xlabel("t / sqrt(H0 / g)")
    ax.set_ylabel("(r_f - R0) / R0")
    ax.grid(True, alpha=0.3)
    ax.legend()
    figures.append(_save(fig, out / "nscd_front.png"))
    diffs = ", ".join(
        f"{_fmt(d)} ({_fmt(d4)} on 4 d) at t = {tt:.2g} T"
        for tt, d, d4 in zip(
            table.t_over_T, table.profile_difference, table.profile_difference_4d, strict=True
        )
    )
    final = table.iloc[-1]
    summary = (
        f"2D collapse of {cocd_run.n_grains} discs (mu = {mu:g}, rough horizontal bed, "
        f"dt = {dt:g} s, T = sqrt(H0/g) = {period:.4g} s), COCD with `{convex}` at tol "
        f"{tol:g} against `nscd` (exact Coulomb law, "
        f"{'symmetric ' if nscd_symmetric else ''}Gauss-Seidel) at tol {nscd_tol:g}. "
        f"Relative profile difference: **{diffs}**; fronts at t = {final.t_over_T:.2g} T: "
        f"{final.front_cocd_m:.4f} m (COCD) and {final.front_nscd_m:.4f} m (NSCD). "
        "The seed (Fig. 4: 7740 discs in COCD against 6036 in a published NSCD run) "
        "finds the two methods' profiles 'very close'."
    )
    intro = (
        "`profile_difference` = ||h_nscd - h_cocd|| / ||h_cocd|| over bins one mean diameter "
        "wide, `profile_difference_4d` over profiles averaged on 4 diameters; residuals are "
        "each scheme's own (`ccp_residual` for COCD, `coulomb_residual` for NSCD); "
        "`compute_s_*`: detection, set-up and solve time of each whole run."
    )
    _finish(out, "nscd", "COCD against NSCD (Fig. 4)", table, intro, summary, figures, progress)
    return table


# -- erodible: the seed's Fig. 9 ---------------------------------------------------------
def erodible(
    *,
    n: int = 400,
    slopes: Sequence[float] = (22.0,),
    layers_d: Sequence[float] = (0.0, 3.0, 5.0),
    until: float = 2.0,
    dt: float = 1e-3,
    mu: float = 0.9,
    bed_length: float = 1.5,
    solver: str = "ipm",
    tol: float = 1e-6,
    fallback: Sequence[str] = ("clarabel",),
    out: Path = Path("results/validation"),
    fresh: bool = False,
    progress: Callable[[str], Any] = print,
) -> pd.DataFrame:
    """2D collapses on slopes over erodible layers; front against time.

    ``layers_d``: layer thicknesses in mean grain diameters (0: the rough bed
    alone). The runout at ``until`` is the front's travel ``r_f(t) - r_f(0)``, with
    ``r_f(t)`` averaged over the last ``RUNOUT_WINDOW`` of the run;
    ``runout_ratio`` divides it by that of the same slope without a layer.
    Returns the table written to ``erodible.csv``, one row per (slope, layer).
    """
    n = _positive_int("n", n)
    slopes = [float(s) for s in slopes]
    if not slopes or any(not (0.0 <= s < 90.0) for s in slopes):
        raise CocdError(f"slopes must be in [0, 90) degrees, got {slopes!r}")
    layers = [float(h) for h in layers_d]
    if not layers or any(not (math.isfinite(h) and h >= 0.0) for h in layers):
        raise CocdError(f"layer thicknesses must be >= 0 diameters, got {layers!r}")
    layers = sorted(set(layers))
    (until, dt, bed_length) = _positive_list("until, dt, bed_length", [until, dt, bed_length])
    out = Path(out)
    from cocd.builders import column_collapse

    d_mean = 2.0 * float(column_collapse(2, n_grains=n, cache=False).radii.mean())
    frame_dt = _frame_interval([0.01], [dt])
    window = RUNOUT_WINDOW * until
    estimate.announce(
        "erodible",
        [(n, round(until / dt) * len(slopes) * len(layers))],
        out=out,
        progress=progress,
    )
    rows = []
    fronts: dict[tuple[float, float], CollapseSeries] = {}
    for slope in slopes:
        for layer in layers:
            label = f"n{n}_slope{slope:g}_layer{layer:g}d"
            params = _base_params(
                n,
                mu,
                slope,
                erodible_thickness=layer * d_mean,
                bed_length=bed_length,
            )
            progress(f"erodible: {label} (layer {layer * d_mean * 1e3:.1f} mm) to t = {until:g} s")
            s = collapse_series(
                out / "runs" / "erodible" / label,
                params,
                label=label,
                dt=dt,
                until=until,
                frame_dt=frame_dt,
                solver=solver,
                tol=tol,
                fallback=fallback,
                fresh=fresh,
                progress=progress,
            )
            fronts[(slope, layer)] = s
            rows.append(
                {
                    "slope_deg": slope,
                    "layer_d": layer,
                    "layer_mm": layer * d_mean * 1e3,
                    "t": float(s.times[-1]),
                    "front0_m": float(s.front[0]),
                    "front_m": float(s.front[-1]),
                    # Averaged over the last RUNOUT_WINDOW of the run: the front of a
                    # thin flow wobbles by a few diameters from frame to frame.
                    "runout_m": float(np.mean(s.front[s.times >= s.times[-1] - window]))
                    - float(s.front[0]),
                    # The front within two diameters of the bed's end: runout cut short.
                    "reached_end": bool(np.max(s.front) >= bed_length - 2.0 * s.d_mean),
                    "n_layer": int(s.stats.n.iloc[0]) - s.n_grains,
                    "steps": s.steps,
                    "penetration_max": s.penetration_max,
                    "compute_s": s.compute_s,
                }
            )
    table = pd.DataFrame(rows)
    base = table[table.layer_d == layers[0]].set_index("slope_deg").runout_m
    table["runout_ratio"] = table.runout_m / table.slope_deg.map(base)
    table["runout_over_R0"] = table.runout_m / 0.2

    plt = _plt()
    fig, axes = plt.subplots(1, len(slopes), figsize=(5.5 * len(slopes), 4), squeeze=False)
    for ax, slope in zip(axes[0], slopes, strict=True):
        for layer in layers:
            s = fronts[(slope, layer)]
            ax.plot(s.times, (s.front - s.front[0]) / 0.2, label=f"layer {layer:g} d")
        ax.set_title(f"slope {slope:g} deg")
        ax.set_xlabel("t (s)")
        ax.grid(True, alpha=0.3)
    axes[0][0].set_ylabel("(r_f - R0) / R0")
    axes[0][0].legend()
    figures = [_save(fig, out / "erodible_front.png")]
    parts = []
    for slope in slopes:
        sub = table[table.slope_deg == slope]
        ratios = ", ".join(
            f"{r:.3g} ({h:g} d)"
            for h, r in zip(sub.layer_d, sub.runout_ratio, strict=True)
            if h > 0
        )
        cut = [f"{h:g} d" for h, e in zip(sub.layer_d, sub.reached_end, strict=True) if e]
        note = f" (the front reached the bed's end with {', '.join(cut)})" if cut else ""
        parts.append(f"at {slope:g} deg: {ratios}{note}")
    summary = (
        f"2D collapses of {n} discs (d = {d_mean * 1e3:.2f} mm, mu = {mu:g}, rough bed "
        f"{bed_length:g} m long), `{solver}` at tol {tol:g}, dt = {dt:g} s, to t = {until:g} s. "
        f"Runout at t = {until:g} s (the front averaged over the last {RUNOUT_WINDOW * until:g} s) "
        "relative to the same slope without a layer: "
        f"**{'; '.join(parts)}**. The seed (Fig. 9, 2D, d = 1 mm, 44 996 discs) finds the "
        "runout growing with the layer's thickness, more on steeper slopes: the fronts of "
        "the 3 and 5 mm layers differ by about 10 % of R0 at 16 deg, 30 % at 19 deg and "
        "110 % at 22 deg."
    )
    intro = (
        "Layers in mean diameters d of the column's grains; `runout_m` = front travel "
        "r_f(t) - r_f(0) of the flow (surface_front: entrained layer grains count), r_f(t) "
        "averaged over the last tenth of the run; `front_m`: the front at the end; "
        "`runout_ratio`: against the same slope with no layer; `n_layer`: grains in the layer; "
        "`reached_end`: the front came within two diameters of the bed's end (runout cut short)."
    )
    _finish(
        out,
        "erodible",
        "Runout on erodible beds (Fig. 9)",
        table,
        intro,
        summary,
        figures,
        progress,
    )
    return table


# -- stability: the seed's Fig. 3 ---------------------------------------------------------
def stability(
    *,
    solvers: str | list[str] | None = "ipm,clarabel,scs,apgd,pgs,nscd",
    eps_list: Sequence[float] = (1e-1, 1e-2, 1e-3, 1e-4, 1e-6),
    n: int = 300,
    dim: int = 3,
    t_end: float = 5.0,
    dt: float = 1e-2,
    threshold: float = 1e-6,
    time_limit: float | None = 30.0,
    run_budget: float | None = 60.0,
    isolate: bool = True,
    out: Path = Path("results/validation"),
    progress: Callable[[str], Any] = print,
) -> pd.DataFrame:
    """The largest tolerance at which each backend keeps a static box at rest.

    Runs :func:`cocd.bench.stability.run` into ``out`` and adds
    ``stability_threshold.csv``: per backend, the largest ``eps`` at rest and
    whether every smaller ``eps`` it completed was at rest too.
    """
    from cocd.bench import stability as mod

    out = Path(out)
    summary = mod.run(
        solvers=solvers,
        eps_list=list(eps_list),
        n=n,
        dim=dim,
        t_end=t_end,
        dt=dt,
        threshold=threshold,
        time_limit=time_limit,
        out=out,
        progress=progress,
        run_budget=run_budget,
        isolate=isolate,
    )
    table = stability_thresholds(summary)
    parts = []
    for row in table.itertuples():
        if math.isnan(row.largest_eps_at_rest):
            parts.append(f"`{row.solver}` never")
        else:
            parts.append(f"`{row.solver}` {row.largest_eps_at_rest:g}")
    text = (
        f"Largest tolerance at which a {dim}D box of {summary.N.iloc[0]} grains stays at rest "
        f"(Ek/E < {threshold:g} over {t_end:g} sqrt(H/g), dt = {dt:g} s): **{', '.join(parts)}**. "
        "The seed (Fig. 3, Mosek, 110 233 spheres) keeps its box at rest for eps <= 1e-3."
    )
    files = report.write_table(
        out,
        "stability_threshold",
        table,
        title="Stability threshold per backend (Fig. 3)",
        intro="`largest_eps_at_rest`: the largest tolerance whose run stayed at rest; "
        "`consistent`: every smaller tolerance that ran to its end was at rest too; "
        "`unfinished`: tolerances stopped by their time budget or a failed step.",
    )
    report.write_meta(
        out,
        "stability_threshold",
        title="Stability threshold per backend (Fig. 3)",
        files=files,
        summary=text,
    )
    readme = report.write_readme(out, heading="Validation against the seed papers")
    progress(f"stability: wrote {', '.join(str(f) for f in files)}; {readme}")
    return table


def stability_thresholds(summary: pd.DataFrame) -> pd.DataFrame:
    """Per backend of a stability summary: the largest tolerance at rest."""
    rows = []
    for solver, sub in summary.groupby("solver", sort=False):
        sub = sub.sort_values("eps", ascending=False)
        done = sub[sub.steps_done == sub.steps_asked]
        rest = done[done.at_rest.astype(bool)]
        largest = float(rest.eps.max()) if len(rest) else math.nan
        below = done[done.eps <= largest] if len(rest) else done.iloc[0:0]
        rows.append(
            {
                "solver": solver,
                "largest_eps_at_rest": largest,
                "consistent": bool(below.at_rest.astype(bool).all()) if len(rest) else False,
                "unfinished": ", ".join(
                    f"{e:g}" for e in sub.eps[sub.steps_done < sub.steps_asked]
                ),
            }
        )
    return pd.DataFrame(rows)
