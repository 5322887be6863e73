"""``cocd bench nscd-local``: ``nscd``'s two local solvers on the same step problems.

``local="exact"`` solves each contact's law in closed form; ``local="fb"`` is
Newton on the Fischer-Burmeister function with the exact solver as fallback. A
2D column after 60 ms of collapse and a 3D box after 20 ms of settling
(:data:`T_START`; stepped with ``clarabel``, dt 1e-3, cached by
:func:`cocd.bench.states.record_steps`): the next step's problem is solved
with each, in this process (the counts of local solves ended by Newton and by
the fallback are the backend's own), after a two-sweep solve that loads the
compiled kernels. ``iterations`` are sweeps; ``p_diff`` is
``||p - p_exact|| / ||p_exact||``, against the exact local solver's impulses.
Quote the ratio of the two times from one run.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

import solvers as backends
from cocd.bench import report, schema, study
from cocd.bench.states import StepSequence, record_steps
from cocd.bench.study import StudySettings, option
from cocd.builders import box_3d, column_2d
from cocd.errors import CocdError
from cocd.problem import ConicProblem
from cocd.residuals import residuals

__all__ = ["COLUMNS", "LOCALS", "STUDY", "Settings", "run"]

#: The local solvers compared, the reference first.
LOCALS = ("exact", "fb")
#: Seconds of simulated time (dt = 1e-3 s) before the solved step of each case.
T_START = {2: 0.060, 3: 0.020}
DT = 1e-3
COLUMNS = [
    "problem",
    "dim",
    "N",
    "Nc",
    "dt",
    "solver",
    "local",
    "tol",
    *schema.SOLVE_COLUMNS,
    "newton",
    "fallback",
    "p_diff",
    "note",
]


@dataclass(frozen=True)
class Settings(StudySettings):
    """The options of ``cocd bench nscd-local``."""

    n2d: int = option(400, "Discs in the 2D column.")
    n3d: int = option(500, "Spheres in the 3D box.")
    tol: float = option(1e-6, "Tolerance on the Coulomb residual.", positive=True)
    time_limit: float = study.time_limit(600.0)


def _check(cfg: Settings) -> None:
    for name, value in (("n2d", cfg.n2d), ("n3d", cfg.n3d)):
        if int(value) != value or value < 2:
            raise CocdError(f"--{name} must be an integer >= 2, got {value!r}")


def _case(dim: int, n: int, progress: Any) -> StepSequence:
    label, build = ("column-2d", column_2d) if dim == 2 else ("box-3d", box_3d)
    return record_steps(
        label, lambda: build(n), dt=DT, t_start=T_START[dim], n_steps=1, progress=progress
    )


def _row(problem: ConicProblem, local: str, cfg: Settings) -> tuple[dict[str, Any], Any]:
    """One timed solve with ``local``: the row and the impulses."""
    backends.solve(problem, "nscd", tol=cfg.tol, local=local, max_iter=2)  # loads the kernels
    start = time.perf_counter()
    sol = backends.solve(problem, "nscd", tol=cfg.tol, local=local, time_limit=cfg.time_limit)
    wall = time.perf_counter() - start
    res = residuals(problem, sol.u, sol.p)
    row = {
        "solver": "nscd",
        "local": local,
        "tol": cfg.tol,
        "status": sol.status.value,
        "iterations": sol.iterations,
        "setup_s": sol.setup_time,
        "solve_s": sol.solve_time,
        "wall_s": wall,
        "ccp_residual": res.ccp,
        "coulomb_residual": res.coulomb,
        "newton": int(sol.extras.get("local_newton", 0)),
        "fallback": int(sol.extras.get("local_fallbacks", 0)),
        "note": "" if sol.found else f"stopped: {sol.status.value}",
    }
    return row, np.asarray(sol.p)


def run(cfg: Settings, *, out: Path, progress: Any = print) -> pd.DataFrame:
    """Both local solvers on one 2D and one 3D step; writes ``nscd_local.csv`` and ``.md``."""
    _check(cfg)
    rows = []
    ratios = []
    for dim, n in ((2, int(cfg.n2d)), (3, int(cfg.n3d))):
        seq = _case(dim, n, report.throttled(progress, 10.0))
        problem = seq.problems[0]
        case = {"problem": seq.label, "dim": dim, "N": seq.n_free, "Nc": problem.nc, "dt": DT}
        walls = {}
        p_exact = None
        for local in LOCALS:
            row, p = _row(problem, local, cfg)
            if p_exact is None:
                p_exact = p
            scale = max(float(np.linalg.norm(p_exact)), 1e-300)
            row["p_diff"] = float(np.linalg.norm(p - p_exact)) / scale
            rows.append({c: {**case, **row}.get(c) for c in COLUMNS})
            walls[local] = row["wall_s"]
            progress(
                f"{seq.label}: nscd local={local}: {row['status']}, {row['iterations']} sweeps, "
                f"{row['wall_s']:.3g} s, coulomb {row['coulomb_residual']:.2e}, "
                f"newton {row['newton']}, fallback {row['fallback']}"
            )
        ratio = walls["fb"] / max(walls["exact"], 1e-12)
        ratios.append(f"{seq.label} (N = {seq.n_free}, Nc = {problem.nc}): {ratio:.2g}")
        progress(f"{seq.label}: fb / exact wall time = {ratio:.2g}")
    table = pd.DataFrame(rows, columns=COLUMNS)
    title = "nscd's local solvers, exact and Fischer-Burmeister"
    intro = (
        f"tol {cfg.tol:g} on the Coulomb residual, time limit {cfg.time_limit:g} s; "
        "solved in one process. `iterations` are sweeps; `newton` and `fallback` count the "
        "local solves ended by Newton and by the exact fallback; `p_diff` is against "
        "`local=exact`."
    )
    summary = "fb / exact wall time: " + "; ".join(ratios) + "."
    report.publish(out, "nscd_local", table, title=title, intro=intro, summary=summary)
    return table


STUDY = study.register(
    study.Study(
        "nscd-local",
        "bench",
        Settings,
        run,
        outputs=("nscd_local",),
        help="nscd's two local solvers (exact, Fischer-Burmeister Newton) on one 2D and one "
        "3D step.",
    )
)
