"""``cocd bench table1``: the seed's Table 1 (iterations and time per step), for every backend.

Two cases, as in the seed (section 3.4, Table 1):

- *variation of N* (2D): a column of ``N`` discs (20 cm wide, aspect 0.7,
  :func:`~cocd.builders.column_2d`) collapsing; ``dt = 1e-3`` s, ``eps = 1e-8``,
  statistics over the steps from ``t = 0.11`` s, for the seed's four
  ``N = 1109, 8308, 20488, 50772`` times ``scale``;
- *variation of mu* (3D): a column of ``122932 * scale`` spheres (R0 x H0 =
  20 x 14 cm in a 20 cm wide channel, on a rough bed of glued grains,
  :func:`~cocd.builders.column_collapse`, ``mu = 0.3``) collapsing, as in the
  seed (its box at rest is this collapse's initial state); ``dt = 1e-2`` s,
  ``eps = 1e-8`` and ``1e-5``, statistics over the steps from ``t = 1`` s.

The seed counts Nc potential contacts (pairs closer than its threshold D,
section 3.3) but does not give D: both cases detect contacts with the fixed
threshold that gives the seed's Nc per grain at the start of the recorded
steps (:data:`D_SEED_2D`, :data:`D_SEED_3D`, in mean radii, found by
``cocd bench seed-contacts``), so that the problems are the size of
the seed's. Every step of the trajectory is checked for overlaps at its end
(:class:`~cocd.stepper.Stepper`).

Each case's step problems are recorded once along one accurate trajectory
(:func:`~cocd.bench.states.record_steps`, cached), then every backend solves
the same problems in a :class:`~cocd.bench.runner.Worker` (time limit, memory
cap). ``eps`` is the ``tol`` handed to each backend; what the rows compare are
the framework's residuals (:mod:`cocd.residuals`). The seed's own rows (Mosek,
2 x 8 cores) are added for reference.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

import solvers
from cocd.bench import estimate, select_solvers, study
from cocd.bench.metrics import finite_max, finite_mean
from cocd.bench.report import throttled
from cocd.bench.results import Results
from cocd.bench.runner import Worker, default_memory_gb, warmup_problem
from cocd.bench.states import StepSequence, cache_path, record_steps
from cocd.bench.study import StudySettings, option
from cocd.builders import column_2d, column_collapse
from cocd.errors import CocdError
from cocd.scene import Scene
from cocd.studies._table1_report import fmt, seed_rows, write_table1
from cocd.studies._table1_setup import (
    CASE_2D,
    CASE_3D,
    CHANNEL_WIDTH,
    COLUMNS,
    D_SEED_2D,
    D_SEED_3D,
    DT_2D,
    DT_3D,
    EPS_2D,
    EPS_3D,
    MIN_GRAINS,
    MU_3D,
    PHASES,
    PREP_TOL_3D,
    SEED,
    SEED_N_2D,
    SEED_N_3D,
    SEED_ROWS,
    THIS_MACHINE,
    TRAJECTORY_TOL,
)

#: The seed's set-up and the table's columns are this module's too.
__all__ = [
    "CASE_2D",
    "CASE_3D",
    "CHANNEL_WIDTH",
    "COLUMNS",
    "DT_2D",
    "DT_3D",
    "D_SEED_2D",
    "D_SEED_3D",
    "EPS_2D",
    "EPS_3D",
    "MIN_GRAINS",
    "MU_3D",
    "PHASES",
    "PREP_TOL_3D",
    "SEED",
    "SEED_N_2D",
    "SEED_N_3D",
    "SEED_ROWS",
    "STUDY",
    "THIS_MACHINE",
    "TRAJECTORY_TOL",
    "Settings",
    "run",
]

#: What names a row: a column's size and contact threshold, the backend and its tol
#: (rows of another threshold were solved on other problems).
KEY = ("dim", "N", "d_max_r", "solver", "tol")
#: Statuses for which the backend returned within its limits (timed and counted).
_RETURNED = ("optimal", "inaccurate", "max_iter")
#: Statuses after which the rest of a case is not worth the time.
_FAILED = ("error", "time_limit", "infeasible")


@dataclass(frozen=True)
class Settings(StudySettings):
    """The options of ``cocd bench table1``."""

    solvers: str | None = study.solvers()
    scale: float = option(0.1, "Multiply the seed's grain counts by this (0 < S <= 1).")
    scale_3d: float | None = option(None, "The 3D case's own scale (default: --scale).")
    cases: tuple[str, ...] = option(("2d", "3d"), "Which halves: 2d, 3d or 2d,3d.", kind="names")
    steps: int = option(10, "Steps averaged per row.")
    time_limit: float = study.time_limit(600.0)
    memory_gb: float | None = study.memory_gb()
    resume: bool = study.resume("table1")
    row_budget: float | None = option(
        None, "Seconds of solving after which a row stops (slow backends).", positive=True
    )
    trajectory_solver: str | None = option(
        None,
        "Backend that steps each column to the recorded steps (default: clarabel, "
        "clarabel-dual in 3D).",
        flag="--trajectory",
    )


def run(
    cfg: Settings,
    *,
    out: Path,
    t_start_2d: float = 0.11,
    t_start_3d: float = 1.0,
    progress: Callable[[str], None] = print,
) -> pd.DataFrame:
    """Run the Table 1 cases with every selected backend; write ``table1.csv/.md/.meta.json``.

    ``t_start_2d, t_start_3d``: time (s) of the first recorded step, 2D and 3D.

    Returns
    -------
    pandas.DataFrame
        One row per case, ``N``, ``eps`` and backend (:data:`COLUMNS`), then
        the seed's rows.

    Raises
    ------
    CocdError
        For an unknown case, ``scale`` outside (0, 1], ``steps < 1`` or an unknown
        backend (a time limit or memory cap that is not > 0 is refused by
        :class:`Settings` itself).
    """
    scale, steps, wanted = _check(cfg.scale, cfg.cases, cfg.steps)
    if cfg.scale_3d is not None and "3d" not in wanted:
        raise CocdError("--scale-3d scales the 3D case, which --cases leaves out")
    scale_3d, _, _ = _check(scale if cfg.scale_3d is None else cfg.scale_3d, cfg.cases, steps)
    cap = default_memory_gb() if cfg.memory_gb is None else float(cfg.memory_gb)
    done = Results(
        Path(out) / "table1.csv",
        COLUMNS,
        resume=cfg.resume,
        key=KEY,
        keep=lambda row: row["source"] == THIS_MACHINE,
    )
    trajectory = {dim: _trajectory_solver(cfg.trajectory_solver, dim) for dim in (2, 3)}
    # Both lists first, so that a bad name fails before any work.
    names = {dim: select_solvers(cfg.solvers, dim) for dim in (2, 3) if f"{dim}d" in wanted}
    for dim, chosen in names.items():
        if not chosen:
            progress(f"table1: no selected backend solves {dim}D problems; {dim}D skipped")
    start = time.perf_counter()

    def write() -> pd.DataFrame:
        # Every row kept: a resumed run that stops keeps the earlier rows it had not reached.
        table = pd.DataFrame(_ordered(done.rows) + seed_rows(), columns=COLUMNS)
        write_table1(
            out,
            table,
            (scale, scale_3d),
            steps,
            wanted,
            trajectory,
            t_start_2d,
            t_start_3d,
            cfg.time_limit,
        )
        return table

    def emit(row: dict[str, Any]) -> None:
        done.add(row, save=False)  # written with the seed's rows by write()
        write()

    plan: list[_Case] = []
    if names.get(2):
        for n in sorted({max(MIN_GRAINS, round(scale * n)) for n in SEED_N_2D}):
            make: Callable[[], Scene] = partial(column_2d, n)
            plan.append(_Case(CASE_2D, f"table1-column-2d-{n}", make, DT_2D, t_start_2d, EPS_2D,
                              2, scale, None, D_SEED_2D))  # fmt: skip
    if names.get(3):
        n = max(1, round(scale_3d * SEED_N_3D))
        make = partial(column_collapse, 3, n_grains=n, width=CHANNEL_WIDTH, bed="rough", mu=MU_3D)
        plan.append(_Case(CASE_3D, f"table1-column-3d-{n}", make, DT_3D, t_start_3d, EPS_3D, 3,
                          scale_3d, PREP_TOL_3D, D_SEED_3D))  # fmt: skip

    def prep_steps(c: _Case) -> int:
        """Steps of the trajectory to the recorded ones: none when they are cached."""
        scene = c.make()
        d_max = c.d_max_r * float(scene.radii.mean())
        path, _ = cache_path(c.label, scene, c.dt, c.t_start, steps, trajectory[c.dim],
                             TRAJECTORY_TOL, c.prep_tol, d_max)  # fmt: skip
        return 0 if path.is_file() else round(c.t_start / c.dt) + steps

    estimate.announce(
        "table1",
        [
            (
                int(c.label.rsplit("-", 1)[1]),
                prep_steps(c) + steps * len(c.eps_list) * len(names[c.dim]),
            )
            for c in plan
        ],
        out=Path(out),
        progress=progress,
    )
    for c in plan:
        _run_case(c, cfg, steps, names[c.dim], trajectory[c.dim], cap, progress, done, emit)
    table = write()
    progress(f"table1: done in {time.perf_counter() - start:.0f} s")
    return table


# -- one case -----------------------------------------------------------------
@dataclass(frozen=True)
class _Case:
    """One half of Table 1 at one size: its builder, time step, first recorded time,
    tolerances, scale, tolerance of the steps before ``t_start``, and detection
    threshold in mean radii."""

    case: str
    label: str
    make: Callable[[], Scene]
    dt: float
    t_start: float
    eps_list: list[float]
    dim: int
    scale: float
    prep_tol: float | None
    d_max_r: float


def _run_case(
    c: _Case,
    cfg: Settings,
    steps: int,
    names: list[str],
    trajectory: str,
    memory_gb: float,
    progress: Callable[[str], None],
    done: Results,
    emit: Callable[[dict[str, Any]], None],
) -> None:
    """Record one case's step problems, then run every backend on them at every eps.

    Contacts are detected with the fixed threshold ``c.d_max_r`` mean radii. Each
    finished row goes to ``emit``; rows found in ``done`` are emitted as they are.
    """
    time_limit, row_budget = cfg.time_limit, cfg.row_budget
    scene = c.make()
    dim, n = scene.dim, scene.n_free
    d_max = c.d_max_r * float(scene.radii.mean())
    todo = []
    for name in names:
        for eps in sorted(c.eps_list, reverse=True):
            earlier = done.get(dim, n, c.d_max_r, name, eps)
            if earlier is not None:
                emit(earlier)
            else:
                todo.append((name, eps))
    if not todo:
        progress(f"{c.label}: every row read from the previous table")
        return
    base = dict(
        source=THIS_MACHINE, case=c.case, dim=dim, N=n, dt=c.dt, scale=c.scale,
        steps_ok=f"0/{steps}", d_max_r=c.d_max_r,
    )  # fmt: skip
    progress(
        f"{c.label}: {n} grains, recording {steps} steps from t = {c.t_start:g} s "
        f"with {trajectory} (tol {TRAJECTORY_TOL:g})"
    )
    try:
        seq = record_steps(
            c.label,
            c.make,
            dt=c.dt,
            t_start=c.t_start,
            n_steps=steps,
            solver=trajectory,
            tol=TRAJECTORY_TOL,
            prep_tol=c.prep_tol,
            progress=throttled(progress, 10.0, always=lambda line: "recording" in line),
            d_max=d_max,
        )
    except CocdError as exc:
        # No problems to compare on: every backend gets a row saying why.
        note = f"no step problems: trajectory ({trajectory}) failed: {str(exc)[:200]}"
        progress(f"{c.label}: {note}")
        for name, eps in todo:
            emit({**base, "Nc": np.nan, "Nc_per_grain": np.nan, "tol": eps, "solver": name,
                  "start": "cold", "note": note})  # fmt: skip
        return
    nc = float(np.mean([p.nc for p in seq.problems]))
    built = "read from the cache" if seq.build_time == 0.0 else f"{seq.build_time:.0f} s"
    progress(f"{c.label}: {len(seq.problems)} problems, mean Nc = {nc:.0f} ({built})")
    base["Nc"] = nc
    base["Nc_per_grain"] = nc / n
    # Kept alive while the worker uses it (the worker keys problems by identity).
    warmup = warmup_problem(dim, c.dt)
    # Loosest eps first: a backend out of time there would be at a tighter eps too.
    timed_out_at: dict[str, float] = {}
    with Worker(memory_gb=memory_gb) as worker:
        for name, eps in todo:
            if name in timed_out_at:
                row = {
                    **base,
                    "tol": eps,
                    "solver": name,
                    "start": "warm" if _takes_warm_start(name, seq) else "cold",
                    "note": "not run: time limit on the first problem at eps "
                    f"{timed_out_at[name]:g}",
                }
            else:
                # Imports and JIT compilation in the worker would otherwise be timed
                # as part of the first step.
                worker.solve_row(warmup, name, eps, time_limit=time_limit)
                stats = _solver_rows(
                    worker, seq, name, eps, time_limit, c.label, progress, row_budget
                )
                row = {**base, "tol": eps, "solver": name, **stats}
                if stats["first_status"] == "time_limit":
                    timed_out_at[name] = eps
            emit({k: v for k, v in row.items() if k in COLUMNS})


def _solver_rows(
    worker: Worker,
    seq: StepSequence,
    name: str,
    eps: float,
    time_limit: float,
    label: str,
    progress: Callable[[str], None],
    row_budget: float | None = None,
) -> dict[str, Any]:
    """Solve every problem of ``seq`` with ``name``; the statistics of one table row.

    With ``row_budget``, the row stops once its solves have taken that many
    seconds; its means are over the steps solved, and its note says so.
    """
    warm = _takes_warm_start(name, seq)
    answers: list[dict[str, Any]] = []
    total = len(seq.problems)
    spent = 0.0
    stopped = ""
    for k, problem in enumerate(seq.problems):
        ws = seq.warm_starts[k] if warm else None
        row = worker.solve_row(problem, name, eps, warm_start=ws, time_limit=time_limit)
        answers.append(row)
        progress(
            f"{label}: {name} eps {eps:g} step {k + 1}/{total}: {row['status']}, "
            f"{fmt(row.get('iterations'))} it, {fmt(row.get('wall_s'), '.3g')} s, "
            f"ccp {fmt(row.get('ccp_residual'), '.2g')}"
        )
        if k == 0 and row["status"] in _FAILED:
            # The first problem is like the others: the rest would fail the same way.
            break
        spent += float(row.get("wall_s") or 0.0)
        if row_budget is not None and spent >= row_budget and k + 1 < total:
            stopped = f"row budget of {row_budget:g} s spent after {k + 1} steps"
            break
    return _summarise(answers, total, warm, stopped)


def _ordered(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """This machine's rows as the seed lists them: by dimension, N, tighter eps first;
    backends in the order they were run."""
    first: dict[str, int] = {}
    for k, r in enumerate(rows):
        first.setdefault(r["solver"], k)
    return sorted(rows, key=lambda r: (r["dim"], r["N"], r["tol"], first[r["solver"]]))


def _takes_warm_start(name: str, seq: StepSequence) -> bool:
    return bool(solvers.get(name).warm_start) and any(w is not None for w in seq.warm_starts)


def _summarise(
    answers: list[dict[str, Any]], total: int, warm: bool, stopped: str = ""
) -> dict[str, Any]:
    """Means (iterations, wall time) over returned solves, max residuals, and what went wrong."""
    statuses = [str(a.get("status")) for a in answers]
    returned = [a for a, s in zip(answers, statuses, strict=True) if s in _RETURNED]
    ok = sum(s == "optimal" for s in statuses)
    notes = []
    bad = Counter(s for s in statuses if s != "optimal")
    if bad:
        notes.append(", ".join(f"{s} on {c} step{'s' * (c > 1)}" for s, c in bad.items()))
    details = {str(a.get("note") or "") for a in answers} - {""}
    notes += sorted(details)
    if stopped:
        notes.append(stopped)
    elif len(answers) < total:
        notes.append(f"stopped after the first problem ({total - len(answers)} not run)")
    return {
        "start": "warm" if warm else "cold",
        "steps_ok": f"{ok}/{total}",
        "iterations": finite_mean(returned, "iterations"),
        "wall_s": finite_mean(returned, "wall_s"),
        "ccp_residual": finite_max(answers, "ccp_residual"),
        "coulomb_residual": finite_max(answers, "coulomb_residual"),
        "factorisations": finite_mean(returned, "factorisations"),
        **{
            f"t_{phase}_s": finite_mean([a.get("phases") or {} for a in returned], phase)
            for phase in PHASES
        },
        "note": "; ".join(notes)[:300],
        "first_status": statuses[0] if statuses else "",
    }


# -- helpers ------------------------------------------------------------------
def _check(scale: float, cases: Sequence[str], steps: int) -> tuple[float, int, list[str]]:
    """Validated ``scale``, ``steps`` and cases (lower case, each once, in order)."""
    try:
        s = float(scale)
    except (TypeError, ValueError):
        raise CocdError(f"scale must be a number in (0, 1], got {scale!r}") from None
    if not (math.isfinite(s) and 0.0 < s <= 1.0):
        raise CocdError(f"scale must be in (0, 1], got {scale!r}")
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 1:
        raise CocdError(f"steps must be an integer >= 1, got {steps!r}")
    if isinstance(cases, str):
        cases = [cases]
    wanted = list(dict.fromkeys(str(c).strip().lower() for c in cases))
    unknown = [c for c in wanted if c not in ("2d", "3d")]
    if unknown or not wanted:
        raise CocdError(f"cases must be among '2d' and '3d', got {list(cases)!r}")
    return s, int(steps), wanted


def _trajectory_solver(name: str | None, dim: int) -> str:
    if name is not None:
        solvers.get(name)  # an unknown name fails here, before any work
        return name
    if dim == 3 and "clarabel-dual" in solvers.available():
        return "clarabel-dual"
    return "clarabel"


STUDY = study.register(
    study.Study(
        "table1",
        "bench",
        Settings,
        run,
        help="The seed's Table 1: iterations and time per step against N, dt and eps.",
        outputs=("table1", "table1_summary"),
    )
)
