"""``cocd bench column3d-ipm``: what a direct interior point costs on the seed's 3D column.

For each size, the step from ``t_start`` of the seed's column
(:mod:`cocd.studies._column3d`: trajectory by ``apgd`` at ``tol``, cached) is
handed to ``ipm`` (PARDISO on two threads, loaded by a tiny problem first) for
three iterations without the polish: the order of its Newton matrix ``K``, the
entries of K's upper triangle and of its Cholesky factor, one numerical
factorisation's time (mean of three) and the set-up's (ordering and symbolic
factorisation included). ``--full`` also solves that size's step to ``tol`` (at
most 40 iterations, no polish). The last row extrapolates the factor's entries
and the factorisation time to the seed's 122 932 spheres with the exponents
fitted between the two largest sizes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

import solvers as backends
from cocd.bench import report, study
from cocd.bench.runner import warmup_problem
from cocd.bench.study import StudySettings, option
from cocd.errors import CocdError
from cocd.residuals import ccp_residual
from cocd.studies._column3d import check, column_step
from cocd.studies.table1 import D_SEED_3D, DT_3D, MU_3D, SEED_N_3D
from solvers.base import installed

__all__ = ["STUDY", "Settings", "run"]

#: Interior-point iterations of the measured solve, and the most of the full one.
MEASURED_ITERATIONS, FULL_ITERATIONS = 3, 40
#: ``ipm``'s linear solver and its threads.
IPM: dict[str, Any] = {"polish": False, "linsolve": "pardiso", "threads": 2}


@dataclass(frozen=True)
class Settings(StudySettings):
    """The options of ``cocd bench column3d-ipm``."""

    sizes: tuple[int, ...] = option(
        (6000, 12293, 30733), "Spheres in the column, one step each (two at least).", kind="ints"
    )
    full: int = option(12293, "Size whose step is also solved to tol (0: none).")
    tol: float = option(1e-5, "Tolerance of the trajectory and of the full solve.", positive=True)
    t_start: float = option(0.1, "Time (s) at the start of the measured step.")


def _check(cfg: Settings) -> list[int]:
    sizes = sorted(set(cfg.sizes))
    if len(sizes) < 2:
        raise CocdError(f"--sizes needs two different sizes at least, got {cfg.sizes!r}")
    if cfg.full != 0 and cfg.full not in sizes:
        raise CocdError(f"--full must be 0 or one of --sizes {sizes}, got {cfg.full}")
    check("--tol", cfg.tol)
    check("--t-start", cfg.t_start, strict=False)
    if not installed("pypardiso"):
        raise CocdError("cocd bench column3d-ipm needs PARDISO: pip install 'cocd[pardiso]'")
    return sizes


def _row(n: int, cfg: Settings, progress: Any) -> dict[str, Any]:
    seq = column_step(n, tol=cfg.tol, t_start=cfg.t_start, progress=progress)
    problem, n_free = seq.problems[0], seq.n_free
    sol = backends.solve(problem, "ipm", tol=cfg.tol, max_iter=MEASURED_ITERATIONS, **IPM)
    ex = sol.extras
    row: dict[str, Any] = {
        "N": n_free,
        "Nc": problem.nc,
        "Nc_per_sphere": problem.nc / n_free,
        "K_order": ex["system_size"],
        "K_upper_nnz": ex["system_nnz"],
        "L_nnz": ex["factor_nnz"],
        "L_GB": 8e-9 * ex["factor_nnz"],
        "factor_s": ex["times"]["factor"] / ex["factorisations"],
        "setup_s": sol.setup_time,
        "source": f"measured ({MEASURED_ITERATIONS} iterations)",
    }
    if n == cfg.full:
        full = backends.solve(problem, "ipm", tol=cfg.tol, max_iter=FULL_ITERATIONS, **IPM)
        history = full.extras["history"]
        row.update(
            full_status=full.status.value,
            full_iterations=full.iterations,
            full_solve_s=full.solve_time,
            full_ccp=ccp_residual(problem, full.p),
            full_best_iteration=int(np.nanargmin([h[3] for h in history])),
        )
    progress(
        f"column3d-ipm: N = {n_free}, Nc = {problem.nc}, L_nnz = {row['L_nnz']:.3g}, "
        f"factor {row['factor_s']:.3g} s, set-up {row['setup_s']:.3g} s"
        + (f"; full: {row['full_status']}, ccp {row['full_ccp']:.2e}" if "full_ccp" in row else "")
    )
    return row


def _extrapolated(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
    """The seed's size, from the power laws through the two largest sizes ``a`` < ``b``."""
    ratio = math.log(b["N"] / a["N"])
    e_fill = math.log(b["L_nnz"] / a["L_nnz"]) / ratio
    e_time = math.log(b["factor_s"] / a["factor_s"]) / ratio
    grow = SEED_N_3D / b["N"]
    seed_fill = b["L_nnz"] * grow**e_fill
    return {
        "N": SEED_N_3D,
        "L_nnz": seed_fill,
        "L_GB": 8e-9 * seed_fill,
        "factor_s": b["factor_s"] * grow**e_time,
        "source": f"extrapolated: L ~ N^{e_fill:.2f}, time ~ N^{e_time:.2f}",
    }


def run(cfg: Settings, *, out: Path, progress: Any = print) -> pd.DataFrame:
    """Fill and factorisation time of ``ipm`` per size; writes ``column3d_ipm.csv`` and ``.md``."""
    sizes = _check(cfg)
    # A tiny problem first: PARDISO and the compiled kernels load outside the timed solves.
    backends.solve(warmup_problem(3), "ipm", tol=cfg.tol, max_iter=MEASURED_ITERATIONS, **IPM)
    rows = [_row(n, cfg, progress) for n in sizes]
    b = rows[-1]
    seed = _extrapolated(rows[-2], b)
    rows.append(seed)
    table = pd.DataFrame(rows)
    title = "A direct interior point on the seed's 3D column: fill and factorisation time"
    intro = (
        f"The step from t = {cfg.t_start:g} s of the seed's 3D column (lattice, rough bed, "
        f"20 cm channel, mu = {MU_3D:g}, dt = {DT_3D:g} s, d_max = {D_SEED_3D:g} r, "
        f"trajectory by apgd at tol {cfg.tol:g}), ipm with PARDISO on two threads. "
        "`K_order`: unknowns of the Newton system (6 per sphere); `L_nnz`: entries of its "
        "Cholesky factor; `factor_s`: one numerical factorisation; `setup_s`: ordering and "
        "symbolic factorisation included."
    )
    summary = (
        f"{intro} At {b['N']} spheres the factor has {b['L_nnz']:.3g} entries "
        f"({b['L_GB']:.3g} GB) and one factorisation takes {b['factor_s']:.3g} s; "
        f"extrapolated to {SEED_N_3D} spheres ({seed['source'].split(': ')[1]}): "
        f"{seed['L_GB']:.3g} GB and {seed['factor_s']:.3g} s per factorisation, i.e. "
        f"{seed['factor_s'] * 11:.3g} s for the seed's 11 Mosek iterations at eps 1e-5."
    )
    full_rows = [r for r in rows if "full_iterations" in r]
    if full_rows:
        f = full_rows[0]
        summary += (
            f" Solved to tol at {f['N']} spheres: {f['full_status']} after "
            f"{f['full_iterations']} iterations in {f['full_solve_s']:.3g} s, residual "
            f"{f['full_ccp']:.3g} (best at iteration {f['full_best_iteration']})."
        )
    report.publish(out, "column3d_ipm", table, title=title, intro=intro, summary=summary)
    progress(summary)
    return table


STUDY = study.register(
    study.Study(
        "column3d-ipm",
        "bench",
        Settings,
        run,
        outputs=("column3d_ipm",),
        help="A direct interior point's fill and factorisation time on the seed's 3D column, "
        "extrapolated to its full size.",
    )
)
