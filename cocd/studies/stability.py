"""``cocd bench stability``: does a box of grains at rest stay at rest? (the seed's Fig. 3).

A box of grains is settled by rain deposition (:func:`cocd.builders.static_box`,
cached on disk), its velocities set to zero, and then advanced by every backend
at every tolerance ``eps`` for ``t_end`` units of ``T = sqrt(H / g)``, ``H``
being the height of the packing (the top of the highest grain above the
floor). A solver that answers each step accurately enough keeps the packing
still: the ratio of kinetic to total energy ``Ek / (Ek + Ep)`` stays tiny.
An inaccurate answer injects spurious velocities, and the packing creeps or
flows. The seed finds the box stays at rest for ``eps <= 1e-3`` and not above
(Mosek, 110 233 spheres).

``Ep`` is the gravitational potential energy of the free grains measured from
the floor (the wall whose normal points against gravity; the lowest grain's
bottom when there is no such wall), so ``Ep > 0`` and the ratio lies in
``[0, 1)``: measured from the origin, as :func:`cocd.measure.potential_energy`
does, ``Ep`` would depend on where the box sits.

Each (solver, eps) run is isolated in a child process by default
(``multiprocessing`` spawn): the child streams one message per step, so a
native crash or a backend that hangs past its time limit costs that run only
(its partial series is kept and its summary row says what happened), never
the whole command. Spawning costs about one to two seconds per run, small
against the runs themselves. A Python exception from the backend
(:class:`~cocd.errors.SolverError` when a step has no answer, or anything the
backend raises) ends the run the same way, in the child or in process.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from cocd.bench import estimate, select_solvers, study
from cocd.bench.study import StudySettings, option
from cocd.bench.worker import Worker
from cocd.builders import static_box
from cocd.errors import CocdError
from cocd.scene import Scene
from cocd.studies._stability_report import (
    BUDGET_NOTE,
    stability_thresholds,
    write_stability,
    write_thresholds,
)

__all__ = [
    "SERIES_COLUMNS",
    "STUDY",
    "SUMMARY_COLUMNS",
    "Settings",
    "floor_reference",
    "run",
    "stability_thresholds",
]

FloatArray = NDArray[np.float64]

#: Columns of ``stability.csv``, one row per step of every run.
SERIES_COLUMNS = [
    "solver",
    "tol",
    "step",
    "t_over_T",
    "energy_ratio",
    "iterations",
    "solve_s",
    "ccp_residual",
    "penetration",
]

#: Columns of ``stability_summary.csv``, one row per (solver, eps).
SUMMARY_COLUMNS = [
    "solver",
    "dim",
    "N",
    "dt",
    "tol",
    "steps_done",
    "steps_asked",
    "max_energy_ratio",
    "final_energy_ratio",
    "at_rest",
    "iterations",
    "solve_s",
    "ccp_residual",
    "max_penetration",
    "note",
]


#: Seconds allowed on top of ``1.5 time_limit`` between two messages of a child
#: (its start-up, the imports and the first contact detection included) before
#: it is killed as hung.
GRACE_S = 60.0

#: Seconds between two progress lines inside one run (slow backends on big boxes).
PROGRESS_S = 30.0


@dataclass(frozen=True)
class Settings(StudySettings):
    """The options of ``cocd bench stability``."""

    solvers: str | None = study.solvers()
    tols: tuple[float, ...] = option(
        (1e-1, 1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8),
        "Comma-separated tolerances.",
        kind="floats",
        aliases=("--eps-list",),
    )
    n: int = option(1000, "Spheres in the box.")
    dim: int = option(3, "2 or 3.")
    t_end: float = option(5.0, "Duration in units of sqrt(H/g).", positive=True)
    dt: float = option(1e-2, "Time step (s).", positive=True)
    threshold: float = option(1e-6, "At rest while Ek / (Ek + Ep) stays below this.", positive=True)
    time_limit: float | None = study.time_limit(600.0)  # None: no limit
    run_budget: float | None = option(
        None,
        "Wall seconds per (solver, eps) run; a run that spends them stops, not at rest.",
        positive=True,
    )


def run(
    cfg: Settings,
    *,
    out: Path,
    progress: Callable[[str], Any] = print,
    isolate: bool = True,
    grace: float = GRACE_S,
) -> pd.DataFrame:
    """Run the stability test and write its tables, plot and provenance under ``out``.

    ``isolate``: run each (solver, eps) in a child process (default). ``False`` runs in this
    process: faster for tiny runs, but a native crash ends the command; ``grace``: seconds
    added to the watchdog of isolated runs.

    Returns
    -------
    pandas.DataFrame
        The summary, columns :data:`SUMMARY_COLUMNS`. ``at_rest`` is True when
        every asked step was taken and the largest ratio is below
        ``threshold``; a run that failed is never at rest (its ``note`` says
        why and at which step).

    Raises
    ------
    CocdError
        Invalid arguments, unknown solver names
        (:class:`~cocd.errors.SolverNotFound`), or no named solver handles
        ``dim``.
    """
    eps_values = _check(cfg.tols, cfg.n, cfg.dim, cfg.threshold, grace)
    budget = math.inf if cfg.run_budget is None else float(cfg.run_budget)
    names = select_solvers(cfg.solvers, cfg.dim)
    if not names:
        raise CocdError(f"none of the solvers {cfg.solvers!r} handles {cfg.dim}D problems")
    out = Path(out)

    progress(f"stability: settling a {cfg.dim}D box of {cfg.n} grains (rain deposition, cached)")
    start = time.perf_counter()
    scene = static_box(cfg.dim, n_grains=int(cfg.n))
    x0, up = floor_reference(scene)
    free = scene.free
    heights = (scene.positions[free] - x0) @ up
    height = float(np.max(heights + scene.radii[free]))
    g = float(np.linalg.norm(scene.gravity))
    period = math.sqrt(height / g)
    n_steps = max(1, math.ceil(cfg.t_end * period / cfg.dt - 1e-9))
    # Ep from the floor = Ep from the origin (what the stepper records) + this shift.
    ep_shift = float(np.sum(scene.masses[free]) * (x0 @ scene.gravity))
    progress(
        f"stability: N = {scene.n_free}, H = {height:.4g} m, T = sqrt(H/g) = {period:.4g} s, "
        f"{n_steps} steps of {cfg.dt:g} s to t = {cfg.t_end:g} T "
        f"({time.perf_counter() - start:.1f} s to prepare)"
    )

    series: list[dict[str, Any]] = []
    summary: list[dict[str, Any]] = []
    runs = [(s, e) for s in names for e in eps_values]
    estimate.announce(
        "stability", [(scene.n_free, n_steps * len(runs))], out=out, progress=progress
    )
    for k, (solver, eps) in enumerate(runs, 1):
        args = (scene.copy(), solver, eps, cfg.dt, n_steps, cfg.time_limit, ep_shift, period)
        t0 = time.perf_counter()
        on_step = _ticker(progress, f"[{k}/{len(runs)}] {solver} eps={eps:.0e}", n_steps)
        if isolate:
            steps, note = _run_isolated(args, cfg.time_limit, grace, on_step, budget)
        else:
            steps, note = _run_here(args, on_step, budget)
        wall = time.perf_counter() - t0
        series += [{c: s[c] for c in SERIES_COLUMNS} for s in steps]
        row = _summary_row(
            steps, note, solver, eps, cfg.dim, scene.n_free, cfg.dt, n_steps, cfg.threshold
        )
        summary.append(row)
        verdict = "at rest" if row["at_rest"] else "NOT at rest"
        failed = f"; {row['note']}" if row["note"] else ""
        progress(
            f"[{k}/{len(runs)}] {solver} eps={eps:.0e}: {row['steps_done']}/{n_steps} steps, "
            f"max Ek/E = {row['max_energy_ratio']:.3g} -> {verdict} ({wall:.1f} s){failed}"
        )

    table = pd.DataFrame(summary, columns=SUMMARY_COLUMNS)
    steps_table = pd.DataFrame(series, columns=SERIES_COLUMNS)
    files = write_stability(
        out, table, steps_table, cfg.threshold, cfg.dim, scene.n_free, height, period, cfg.dt
    )
    files += write_thresholds(out, table, cfg.threshold, cfg.dim, cfg.t_end, cfg.dt)
    progress(f"stability: wrote {', '.join(str(f) for f in files)}")
    return table


def floor_reference(scene: Scene) -> tuple[FloatArray, FloatArray]:
    """A point of the floor and the unit vector up (against gravity).

    The floor is the wall whose normal is closest to ``up`` (within 1e-6 of
    it); without one, the plane through the lowest point of the free grains.
    """
    g = np.asarray(scene.gravity, dtype=np.float64)
    norm = float(np.linalg.norm(g))
    if norm == 0.0:
        raise CocdError("the stability test needs gravity, and the scene has none")
    up = -g / norm
    best = None
    for wall in scene.walls:
        align = float(np.asarray(wall.normal) @ up)
        if align > 1.0 - 1e-6 and (best is None or align > best[0]):
            best = (align, np.asarray(wall.point, dtype=np.float64))
    if best is not None:
        return best[1].copy(), up
    free = scene.free
    low = int(np.argmin(scene.positions[free] @ up - scene.radii[free]))
    point = scene.positions[free][low] - scene.radii[free][low] * up
    return np.asarray(point, dtype=np.float64), up


# -- one run ---------------------------------------------------------------------
RunArgs = tuple[Scene, str, float, float, int, float | None, float, float]


def _trajectory(
    scene: Scene,
    solver: str,
    eps: float,
    dt: float,
    n_steps: int,
    time_limit: float | None,
    ep_shift: float,
    period: float,
) -> Iterator[dict[str, Any]]:
    """Step the box; yield one ``step`` event per step, then ``done`` or ``error``."""
    from cocd.stepper import Stepper

    try:
        # Loose tolerances are what this test studies: overlaps they let through are
        # recorded (column penetration), not a failure.
        stepper = Stepper(
            scene, dt, solver=solver, tol=eps, time_limit=time_limit, on_penetration="record"
        )
        for _ in range(n_steps):
            rec = stepper.step()
            ek = rec.kinetic_energy
            ep = rec.potential_energy + ep_shift
            yield {
                "kind": "step",
                "solver": solver,
                "tol": eps,
                "step": rec.step,
                "t_over_T": rec.t / period,
                "energy_ratio": ek / (ek + ep) if ek + ep > 0.0 else float("nan"),
                "iterations": rec.iterations,
                "solve_s": rec.setup_time + rec.solve_time,
                "ccp_residual": rec.ccp_residual,
                "penetration": rec.penetration,
                "status": rec.status,
            }
    except Exception as exc:  # any backend failure ends this run, not the command
        yield {"kind": "error", "note": f"{type(exc).__name__}: {str(exc)[:300]}"}
        return
    yield {"kind": "done"}


def _ticker(
    progress: Callable[[str], Any], label: str, n_steps: int
) -> Callable[[dict[str, Any]], None]:
    """A per-step callback that prints a line at most every :data:`PROGRESS_S` seconds."""
    every = PROGRESS_S
    start = time.perf_counter()
    last = [start]

    def tick(event: dict[str, Any]) -> None:
        now = time.perf_counter()
        if now - last[0] >= every and event["step"] < n_steps:
            last[0] = now
            progress(
                f"{label}: step {event['step']}/{n_steps}, t/T = {event['t_over_T']:.2f}, "
                f"Ek/E = {event['energy_ratio']:.3g}, {event['iterations']} iterations, "
                f"{(now - start) / event['step']:.3g} s/step"
            )

    return tick


def _budget_note(budget: float, steps: list[dict[str, Any]]) -> str:
    return f"{BUDGET_NOTE} of {budget:g} s spent after step {len(steps)}"


def _run_here(
    args: RunArgs, on_step: Callable[[dict[str, Any]], None], budget: float = math.inf
) -> tuple[list[dict[str, Any]], str]:
    """Run in this process; the steps taken and a note (empty when all went well)."""
    steps: list[dict[str, Any]] = []
    start = time.perf_counter()
    for event in _trajectory(*args):
        if event["kind"] == "step":
            steps.append(event)
            on_step(event)
            if time.perf_counter() - start > budget and len(steps) < args[4]:
                return steps, _budget_note(budget, steps)
        elif event["kind"] == "error":
            return steps, str(event["note"])
    return steps, ""


def _child(emit: Callable[[Any], None], args: RunArgs) -> dict[str, Any] | None:
    """Child process: stream the trajectory's step events; the last event is the result."""
    for event in _trajectory(*args):
        if event["kind"] != "step":
            return event
        emit(event)
    return None


def _run_isolated(
    args: RunArgs,
    time_limit: float | None,
    grace: float,
    on_step: Callable[[dict[str, Any]], None],
    budget: float = math.inf,
) -> tuple[list[dict[str, Any]], str]:
    """Run in a fresh child (:class:`~cocd.bench.worker.Worker`); a crash, a silence
    longer than the watchdog or a spent ``budget`` (wall seconds for the whole run)
    ends the run."""
    silence = math.inf if time_limit is None else 1.5 * time_limit + grace
    with Worker() as worker:
        outcome = worker.run(_child, args, silence=silence, budget=budget, on_event=on_step)
    steps = outcome.events
    if outcome.status == "done":
        return steps, "" if outcome.result is None else str(outcome.result.get("note", ""))
    if outcome.status == "budget":
        return steps, _budget_note(budget, steps)
    if outcome.status == "time_limit":
        return steps, (
            f"killed: no answer for {outcome.silent:.0f} s after step {len(steps)} "
            f"(limit 1.5 x time_limit + {grace:g} s)"
        )
    if outcome.note.startswith(("killed by signal", "child exited")):
        return steps, f"child process died ({outcome.note}) after step {len(steps)}"
    return steps, outcome.note


def _summary_row(
    steps: list[dict[str, Any]],
    note: str,
    solver: str,
    eps: float,
    dim: int,
    n_free: int,
    dt: float,
    n_steps: int,
    threshold: float,
) -> dict[str, Any]:
    ratio = np.array([s["energy_ratio"] for s in steps], dtype=np.float64)
    done = len(steps)
    inaccurate = sum(s["status"] != "optimal" for s in steps)
    notes = [note] if note else []
    if inaccurate:
        notes.append(f"{inaccurate} inaccurate step{'s' if inaccurate > 1 else ''}")

    def stat(values: list[float], how: Callable[[FloatArray], Any]) -> float:
        return float(how(np.array(values, dtype=np.float64))) if values else float("nan")

    max_ratio = float(np.max(ratio)) if done else float("nan")
    ccp = [s["ccp_residual"] for s in steps if np.isfinite(s["ccp_residual"])]
    return {
        "solver": solver,
        "dim": dim,
        "N": n_free,
        "dt": dt,
        "tol": eps,
        "steps_done": done,
        "steps_asked": n_steps,
        "max_energy_ratio": max_ratio,
        "final_energy_ratio": float(ratio[-1]) if done else float("nan"),
        # A run that stopped early did not show that the box stays at rest.
        "at_rest": bool(done == n_steps and not note and max_ratio < threshold),
        "iterations": stat([s["iterations"] for s in steps], np.mean),
        "solve_s": stat([s["solve_s"] for s in steps], np.mean),
        "ccp_residual": stat(ccp, np.max),
        "max_penetration": stat(
            [s["penetration"] for s in steps if np.isfinite(s.get("penetration", np.nan))], np.max
        ),
        "note": "; ".join(notes),
    }


# -- checks and outputs ----------------------------------------------------------
def _check(
    tols: Sequence[float],
    n: int,
    dim: int,
    threshold: float,
    grace: float,
) -> list[float]:
    """Validate the arguments; the tolerances as floats."""
    if dim not in (2, 3):
        raise CocdError(f"dim must be 2 or 3, got {dim!r}")
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise CocdError(f"n (the number of grains) must be an integer >= 1, got {n!r}")
    try:
        eps_values = [float(e) for e in tols]
    except (TypeError, ValueError):
        raise CocdError(f"tols must be a list of numbers, got {tols!r}") from None
    if not eps_values:
        raise CocdError("tols is empty: give at least one tolerance")
    bad = [e for e in eps_values if not (math.isfinite(e) and e > 0.0)]
    if bad:
        raise CocdError(f"every eps must be finite and > 0, got {bad}")
    if threshold >= 1.0:  # Ek / (Ek + Ep) never reaches 1: every run would count as at rest
        raise CocdError(f"threshold is a share of the energy, below 1, got {threshold!r}")
    if not (grace >= 0.0):
        raise CocdError(f"grace must be >= 0, got {grace!r}")
    return eps_values


STUDY = study.register(
    study.Study(
        "stability",
        "bench",
        Settings,
        run,
        help="The seed's Fig. 3: does a box at rest stay at rest, for each solver and eps, "
        "and the largest eps that keeps it at rest.",
        outputs=("stability_summary", "stability_threshold"),
    )
)


@dataclass(frozen=True)
class SeedSettings(Settings):
    """The defaults ``cocd validate stability`` has: a smaller box, the backends of the
    validation, six tolerances (1e-5 the seed's), a time limit and a budget per run."""

    solvers: str | None = study.solvers("ipm,clarabel,scs,apgd,pgs,nscd")
    tols: tuple[float, ...] = option(
        (1e-1, 1e-2, 1e-3, 1e-4, 1e-5, 1e-6),
        "Comma-separated tolerances.",
        kind="floats",
        aliases=("--eps-list",),
    )
    n: int = option(300, "Grains in the box.")
    time_limit: float | None = study.time_limit(30.0)
    run_budget: float | None = option(60.0, "Wall seconds per (solver, eps) run.", positive=True)


#: The old command ``cocd validate stability``, hidden: the same study with its defaults.
SEED_STUDY = study.register(
    study.Study(
        "stability",
        "validate",
        SeedSettings,
        run,
        outputs=STUDY.outputs,
        help="Old name of `cocd bench stability`, with the defaults it had.",
        hidden=True,
    )
)
