"""``cocd bench backends``: every available backend on one 2D step and one 3D step.

The 2D problem is a column of discs after 30 steps of collapse, the 3D one a box
of spheres after 20 steps of settling (both stepped with ``clarabel`` and cached
by :func:`cocd.bench.states.record_steps`). Each backend solves it in the
harness's child process (after a tiny problem that loads its compiled code),
under a wall-clock limit and a memory cap, so that a
backend that runs out of time or memory is a row saying so. ``u_error`` is
against ``clarabel`` at tol 1e-10, relative to ``max(||u_ref||, ||U||)``. 3D
friction is offered to the QP backends as an 8-facet pyramid (``facets=8``: an
approximation, whose residuals show its error); first-order QP backends and
cvxpy's are left out there.

``solves`` counts the native solves made to reach ``ccp_residual <= tol`` and
``polished`` says whether the active-set polish (:mod:`solvers.polish`) was
accepted. Failed rows carry no residuals.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

import solvers as backends
from cocd.bench import report, solver_names, study
from cocd.bench.runner import ROW_COLUMNS, Worker, default_memory_gb, warmup_problem
from cocd.bench.states import StepSequence, record_steps
from cocd.bench.study import StudySettings, option
from cocd.builders import box_3d, column_2d
from cocd.errors import CocdError
from cocd.problem import ConicProblem

__all__ = ["COLUMNS", "STUDY", "Settings", "one_step", "run", "timed_row"]

#: The table's columns: the case, then the harness's row (less the dynamics residual,
#: zero on a step problem), then the native solves made.
COLUMNS = [
    "problem",
    "dim",
    "N",
    "Nc",
    "tol",
    *(c for c in ROW_COLUMNS if c != "dynamics_residual"),
    "solves",
]
#: Seconds (of simulated time, dt = 1e-3 s) before the recorded step of each case.
T_START = {2: 0.030, 3: 0.020}
REFERENCE_TOL = 1e-10
#: Seconds allowed to the tiny problem that loads a backend's compiled code.
WARMUP_LIMIT_S = 60.0


def one_step(dim: int, n: int, n_steps: int = 1, progress: Any = None) -> StepSequence:
    """The 2D column (``dim`` 2) or 3D box (``dim`` 3) of ``n`` grains, stepped to
    :data:`T_START` with ``clarabel``, and its next ``n_steps`` step problems."""
    label, build = ("column-2d", column_2d) if dim == 2 else ("box-3d", box_3d)
    return record_steps(
        label, lambda: build(n), dt=1e-3, t_start=T_START[dim], n_steps=n_steps, progress=progress
    )


def timed_row(
    worker: Worker,
    seq: StepSequence,
    problem: ConicProblem,
    name: str,
    cfg: Any,
    ref_u: Any,
    progress: Any,
    start: str = "",
    **solve: Any,
) -> dict[str, Any]:
    """``name`` on ``problem`` in ``worker`` after a tiny problem that loads its compiled
    code; the row carries the case's columns and is reported in one line."""
    worker.solve_row(warmup_problem(seq.dim), name, cfg.tol, time_limit=WARMUP_LIMIT_S)
    row = worker.solve_row(problem, name, cfg.tol, time_limit=cfg.time_limit, ref_u=ref_u, **solve)
    row.update(
        problem=seq.label, dim=seq.dim, N=seq.n_free, Nc=problem.nc, tol=cfg.tol, start=start
    )
    progress(
        f"{seq.label}: {name} {start}: {row['status']}, {row['iterations']} it, "
        f"{row['wall_s']:.3g} s, ccp {row['ccp_residual']:.2e} {row.get('note') or ''}"
    )
    return row


@dataclass(frozen=True)
class Settings(StudySettings):
    """The options of ``cocd bench backends``."""

    solvers: str | None = study.solvers(help="Comma-separated backends (default: every one here).")
    n2d: int = option(8308, "Discs in the 2D column.")
    n3d: int = option(2000, "Spheres in the 3D box.")
    tol: float = option(1e-8, "Tolerance asked of every backend.", positive=True)
    time_limit: float = study.time_limit(300.0)
    memory_gb: float | None = study.memory_gb()


def run(cfg: Settings, *, out: Path, progress: Any = print) -> pd.DataFrame:
    """Every backend on one step of each case; writes ``backends.csv`` and ``.md``."""
    for name, value in (("n2d", cfg.n2d), ("n3d", cfg.n3d)):
        if int(value) != value or value < 2:
            raise CocdError(f"{name} must be an integer >= 2, got {value!r}")
    names = solver_names(cfg.solvers) or backends.available()  # unknown names fail here
    # Dense BLAS paths (proxqp, daqp, ...) would add a thread per core to the solver's own.
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    memory = default_memory_gb() if cfg.memory_gb is None else cfg.memory_gb
    rows = []
    for dim, n in ((2, cfg.n2d), (3, cfg.n3d)):
        seq = one_step(dim, int(n), progress=report.throttled(progress, 10.0))
        problem = seq.problems[0]
        ref = backends.solve(problem, "clarabel", tol=REFERENCE_TOL)
        with Worker(memory_gb=memory, grace=60.0) as worker:
            for name in names:
                info = backends.get(name)
                run_name = name
                if info.linear_cones_only and not problem.is_qp:
                    if info.first_order or "cvxpy" in name:
                        continue
                    run_name = f"{name}:facets=8"
                row = timed_row(worker, seq, problem, run_name, cfg, ref.u, progress)
                rows.append({c: row.get(c) for c in COLUMNS})
    table = pd.DataFrame(rows, columns=COLUMNS)
    title = "Every backend on one step"
    intro = (
        f"tol {cfg.tol:g}, time limit {cfg.time_limit:g} s and memory cap {memory:g} GiB "
        f"per backend, OPENBLAS_NUM_THREADS={os.environ['OPENBLAS_NUM_THREADS']}; "
        "`u_error` against clarabel at tol 1e-10."
    )
    report.publish(out, "backends", table, title=title, intro=intro)
    return table


STUDY = study.register(
    study.Study(
        "backends",
        "bench",
        Settings,
        run,
        outputs=("backends",),
        help="Every available backend on one 2D step and one 3D step, judged by the same "
        "residuals.",
    )
)
