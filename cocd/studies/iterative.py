"""``cocd bench iterative``: the iterative backends, cold and warm-started, beside
``clarabel`` on one mid-collapse step.

The 2D column of :mod:`cocd.studies.backends` is stepped with ``clarabel`` to
30 ms and once more, for the previous step's impulses; the step after is solved
by each backend cold (no warm start) and warm (those impulses matched by
contact pair, as the stepper does), in the harness's child process. Each
backend first solves a tiny problem there, so that compiled kernels are loaded
before it is timed. The stopping test is the backend's own mapping of ``tol``
(the framework's ``ccp_residual <= tol``; ``coulomb_residual`` for ``nscd``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

import solvers as backends
from cocd.bench import report, solver_names, study
from cocd.bench.runner import Worker, default_memory_gb
from cocd.bench.study import StudySettings, option
from cocd.studies.backends import REFERENCE_TOL, one_step, timed_row

__all__ = ["COLUMNS", "STUDY", "Settings", "run"]

COLUMNS = [
    "problem",
    "N",
    "Nc",
    "solver",
    "start",
    "tol",
    "status",
    "iterations",
    "wall_s",
    "ccp_residual",
    "coulomb_residual",
    "u_error",
    "note",
]


@dataclass(frozen=True)
class Settings(StudySettings):
    """The options of ``cocd bench iterative``."""

    solvers: str = study.solvers("pgs,apgd,nscd", help="Iterative backends (comma-separated).")
    n: int = option(8308, "Discs in the 2D column.")
    tol: float = option(1e-6, "Tolerance asked of every backend.", positive=True)
    time_limit: float = study.time_limit(600.0)
    memory_gb: float | None = study.memory_gb()


def run(cfg: Settings, *, out: Path, progress: Any = print) -> pd.DataFrame:
    """Each backend cold and warm on one step; writes ``iterative.csv`` and ``.md``."""
    names = ["clarabel", *solver_names(cfg.solvers)]  # unknown names fail here
    infos = {name: backends.get(name) for name in names}
    seq = one_step(2, cfg.n, n_steps=2, progress=report.throttled(progress, 10.0))
    problem, warm = seq.problems[1], seq.warm_starts[1]
    ref = backends.solve(problem, "clarabel", tol=REFERENCE_TOL)
    memory = default_memory_gb() if cfg.memory_gb is None else cfg.memory_gb
    rows = []
    with Worker(memory_gb=memory, grace=60.0) as worker:
        for name in names:
            for start in ("cold", "warm") if infos[name].warm_start else ("cold",):
                guess = warm if start == "warm" else None
                row = timed_row(
                    worker, seq, problem, name, cfg, ref.u, progress, start, warm_start=guess
                )
                rows.append({c: row.get(c) for c in COLUMNS})
    table = pd.DataFrame(rows, columns=COLUMNS)
    title = "Iterative backends, cold and warm"
    intro = (
        f"2D column, N = {seq.n_free}, Nc = {problem.nc}, t = {seq.t_start + seq.dt:.3f} s, "
        f"dt = {seq.dt:g} s; tol {cfg.tol:g}. `u_error` is against clarabel at tol 1e-10, "
        "relative to max(||u_ref||, ||U||); `wall_s` is the wall-clock time of the solve."
    )
    report.publish(out, "iterative", table, title=title, intro=intro)
    return table


STUDY = study.register(
    study.Study(
        "iterative",
        "bench",
        Settings,
        run,
        outputs=("iterative",),
        help="The iterative backends, cold and warm-started, beside clarabel on one "
        "mid-collapse step.",
    )
)
