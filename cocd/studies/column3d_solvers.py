"""``cocd bench column3d-solvers``: the first-order 3D backends on one step of the seed's
3D column, with ``apgd``'s profile.

The step from ``t_start`` of the seed's column (:mod:`cocd.studies._column3d`:
trajectory by ``apgd`` at ``tol``, cached) is solved by every method of
:data:`METHODS`, after a tiny problem that loads its compiled kernels,
warm-started from the previous step's impulses matched by contact pair (and
cold for ``apgd``), to ``ccp_residual <= tol`` or the time limit. Besides the
harness's columns, a row gives the method's options, the time per iteration,
the colours of a coloured ``bgs``, and for ``apgd`` its restarts, backtracks,
the range of its Lipschitz estimate ``L`` and the iterations at which the
residual first fell below 1e-2 ... 1e-5. The summary adds the warm start's own
residual and that of zero impulses.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

import solvers as backends
from cocd.bench import report, schema, study
from cocd.bench.runner import warmup_problem
from cocd.bench.study import StudySettings, option
from cocd.errors import CocdError
from cocd.residuals import ccp_residual, coulomb_residual
from cocd.studies._column3d import check, column_step
from cocd.studies.table1 import D_SEED_3D, DT_3D, MU_3D

__all__ = ["COLUMNS", "METHODS", "STUDY", "Settings", "run"]

THRESHOLDS = (1e-2, 1e-3, 1e-4, 1e-5)

#: ``(backend, start, options)`` of each row, in order.
METHODS: list[tuple[str, str, dict[str, Any]]] = [
    ("apgd", "warm", {"scaling": "block"}),
    ("apgd", "cold", {"scaling": "block"}),
    ("apgd", "warm", {"scaling": "contact"}),
    ("bgs", "warm", {"order": "natural", "colour": True}),
    ("bgs", "warm", {"order": "natural", "colour": False}),
    ("bgs", "warm", {"order": "top-down", "colour": False}),
    ("bgs", "warm", {"order": "bottom-up", "colour": False}),
    ("pgs", "warm", {}),
]

#: The table's columns: the harness's, the method's options and apgd's profile.
COLUMNS = [
    "problem",
    "solver",
    "options",
    "start",
    "tol",
    *schema.SOLVE_COLUMNS,
    "s_per_iteration",
    "colours",
    "restarts",
    "backtracks",
    "L_min",
    "L_median",
    "L_max",
    *(f"it_to_{t:g}" for t in THRESHOLDS),
    "note",
]


@dataclass(frozen=True)
class Settings(StudySettings):
    """The options of ``cocd bench column3d-solvers``."""

    n: int = option(12293, "Spheres in the column (the seed's: 122932).")
    t_start: float = option(0.1, "Time (s) at the start of the solved step.")
    tol: float = option(1e-5, "Tolerance of the trajectory and of every method.", positive=True)
    time_limit: float = study.time_limit(60.0)


def _first_below(history: dict, threshold: float) -> float:
    it, ccp = history["ccp_iteration"], history["ccp"]
    hit = np.flatnonzero(ccp <= threshold)
    return float(it[hit[0]]) if hit.size else math.nan


def _row(
    problem: Any, name: str, start: str, options: dict, warm: Any, cfg: Settings
) -> dict[str, Any]:
    begin = time.perf_counter()
    sol = backends.solve(
        problem,
        name,
        tol=cfg.tol,
        warm_start=warm if start == "warm" else None,
        max_iter=10**6,
        time_limit=cfg.time_limit,
        **options,
    )
    wall = time.perf_counter() - begin
    row: dict[str, Any] = {
        "solver": name,
        "options": ", ".join(f"{k}={v}" for k, v in options.items()) or "-",
        "start": start,
        "tol": cfg.tol,
        "status": sol.status.value,
        "iterations": sol.iterations,
        "setup_s": sol.setup_time,
        "solve_s": sol.solve_time,
        "wall_s": wall,
        "s_per_iteration": sol.solve_time / max(sol.iterations, 1),
        "ccp_residual": ccp_residual(problem, sol.p),
        "coulomb_residual": coulomb_residual(problem, sol.p),
        "colours": sol.extras.get("colours", math.nan),
        "note": "",
    }
    if name == "apgd":
        h = sol.extras["history"]
        row.update(
            restarts=sol.extras["restarts"],
            backtracks=sol.extras["backtracks"],
            L_min=float(h["lipschitz"].min()),
            L_median=float(np.median(h["lipschitz"])),
            L_max=float(h["lipschitz"].max()),
            **{f"it_to_{t:g}": _first_below(h, t) for t in THRESHOLDS},
        )
    return row


def _summary(table: pd.DataFrame, setting: str, warm_r: float, zero_r: float) -> str:
    t = table.set_index(["solver", "options", "start"])
    aw = t.loc[("apgd", "scaling=block", "warm")]
    ac = t.loc[("apgd", "scaling=block", "cold")]
    acw = t.loc[("apgd", "scaling=contact", "warm")]
    bgs_rows = table[table.solver == "bgs"]
    best_bgs = bgs_rows.loc[bgs_rows.ccp_residual.idxmin()]
    pg = t.loc[("pgs", "-", "warm")]
    return (
        f"{setting} apgd (warm) {aw.status} after {aw.iterations} iterations in "
        f"{aw.solve_s:.3g} s ({1e3 * aw.s_per_iteration:.3g} ms each), {aw.restarts:.0f} restarts "
        f"and {aw.backtracks:.0f} backtracks, L from {aw.L_min:.3g} to {aw.L_max:.3g}; residual "
        f"below 1e-3 after {aw['it_to_0.001']:.0f} iterations, 1e-4 after "
        f"{aw['it_to_0.0001']:.0f}. Cold: {ac.iterations} iterations. With the per-contact "
        f"scalar scaling instead of the block one: {acw.iterations} iterations, "
        f"{acw.solve_s:.3g} s. The warm start's "
        f"residual is {warm_r:.3g}, zero impulses' {zero_r:.3g}. bgs at best "
        f"({best_bgs.options}) {best_bgs.status} with residual {best_bgs.ccp_residual:.3g} "
        f"after {best_bgs.iterations} sweeps ({1e3 * best_bgs.s_per_iteration:.3g} ms each); "
        f"pgs {pg.status} at {pg.ccp_residual:.3g} after {pg.iterations} sweeps."
    )


def run(cfg: Settings, *, out: Path, progress: Any = print) -> pd.DataFrame:
    """Every method on one step; writes ``column3d_solvers.csv`` and ``.md``."""
    if cfg.n < 1:
        raise CocdError(f"--n must be a positive integer, got {cfg.n}")
    check("--tol", cfg.tol)
    check("--t-start", cfg.t_start, strict=False)
    check("--time-limit", cfg.time_limit)
    seq = column_step(cfg.n, tol=cfg.tol, t_start=cfg.t_start, progress=progress)
    problem, warm, n_free = seq.problems[0], seq.warm_starts[0], seq.n_free
    rows = []
    for name, start, options in METHODS:
        # A tiny problem first: the method's compiled kernels load outside the timed solve.
        backends.solve(warmup_problem(3), name, tol=cfg.tol, time_limit=cfg.time_limit, **options)
        row = _row(problem, name, start, options, warm, cfg)
        rows.append({**row, "problem": seq.label})
        progress(
            f"column3d-solvers: {name} ({row['options']}) {start}: {row['status']}, "
            f"{row['iterations']} it, {row['solve_s']:.3g} s, ccp {row['ccp_residual']:.2e}"
        )
    table = pd.DataFrame(rows, columns=COLUMNS)

    warm_r = ccp_residual(problem, warm) if warm is not None else math.nan
    zero_r = ccp_residual(problem, np.zeros((problem.nc, problem.contact_dim)))
    setting = (
        f"Seed 3D column, {n_free} spheres (lattice, rough bed, 20 cm channel, mu = {MU_3D:g}), "
        f"dt = {DT_3D:g} s; the step from t = {seq.t_start:g} s, Nc = {problem.nc} "
        f"({problem.nc / n_free:.2f} per sphere, d_max = {D_SEED_3D:g} r); trajectory by apgd "
        f"at tol {cfg.tol:g}; every method to ccp_residual <= {cfg.tol:g} or "
        f"{cfg.time_limit:g} s."
    )
    title = "First-order 3D backends on a step of the seed's 3D column"
    summary = _summary(table, setting, warm_r, zero_r)
    report.publish(out, "column3d_solvers", table, title=title, intro=setting, summary=summary)
    progress(summary)
    return table


STUDY = study.register(
    study.Study(
        "column3d-solvers",
        "bench",
        Settings,
        run,
        outputs=("column3d_solvers",),
        help="The first-order 3D backends on one step of the seed's 3D column, with apgd's "
        "profile.",
    )
)
