"""What a direct interior point costs on the seed's 3D column: fill and time per factorisation.

Usage::

    python benchmarks/column3d_ipm.py [--sizes 6000,12293,30733] [--full 12293]
                                      [--tol 1e-5] [--out results]

For each column size, the step from t = 0.1 s of the seed's 3D column (as in
``benchmarks/column3d_solvers.py``: lattice packing, rough bed, 20 cm channel,
mu = 0.3, dt = 1e-2 s, d_max = 0.98 r, trajectory by ``apgd`` at ``tol``,
cached) is handed to ``ipm`` (PARDISO on two threads: extra ``pardiso``) for three iterations,
without the polish: the rows give the order of its Newton matrix ``K`` (the
generalized velocities), the entries of K's upper triangle and of its Cholesky
factor, and the time of one numerical factorisation (mean of three) and of the
set-up (ordering and symbolic factorisation included). ``--full`` also solves
that size's step to ``tol`` (at most 40 iterations, no polish) and reports the
iterations and the residual reached. The last rows extrapolate the factor's
entries and the factorisation time to the seed's 122 932 spheres with the
exponents fitted between the two largest sizes. Writes
``OUT/column3d_ipm.csv``, ``.md`` and ``.meta.json``.
"""

from __future__ import annotations

import argparse
import math
from functools import partial
from pathlib import Path

import numpy as np
import pandas as pd

import cocd
import solvers
from cocd.bench.report import write_meta, write_table
from cocd.bench.states import record_steps
from cocd.residuals import ccp_residual
from cocd.studies.table1 import CHANNEL_WIDTH, D_SEED_3D, DT_3D, MU_3D, SEED_N_3D


def step_problem(n: int, tol: float, t_start: float) -> tuple[cocd.ConicProblem, int]:
    """The step from ``t_start`` of the seed's column of ``n`` spheres (cached)."""
    make = partial(cocd.column_collapse, 3, n_grains=n, width=CHANNEL_WIDTH, bed="rough", mu=MU_3D)
    d_max = D_SEED_3D * float(make().radii.mean())
    seq = record_steps(
        f"column3d-solvers-{n}", make, dt=DT_3D, t_start=t_start, n_steps=1, solver="apgd",
        tol=tol, d_max=d_max, progress=print,
    )  # fmt: skip
    return seq.problems[0], seq.n_free


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", default="6000,12293,30733")
    parser.add_argument("--full", type=int, default=12293, help="size solved to tol (0: none)")
    parser.add_argument("--tol", type=float, default=1e-5)
    parser.add_argument("--t-start", type=float, default=0.1)
    parser.add_argument("--out", type=Path, default=Path("results"))
    args = parser.parse_args()
    sizes = sorted(int(s) for s in args.sizes.split(","))

    rows = []
    for n in sizes:
        problem, n_free = step_problem(n, args.tol, args.t_start)
        sol = solvers.solve(
            problem, "ipm", tol=args.tol, max_iter=3, polish=False, linsolve="pardiso", threads=2
        )
        ex = sol.extras
        row = {
            "N": n_free,
            "Nc": problem.nc,
            "Nc_per_sphere": problem.nc / n_free,
            "K_order": ex["system_size"],
            "K_upper_nnz": ex["system_nnz"],
            "L_nnz": ex["factor_nnz"],
            "L_GB": 8e-9 * ex["factor_nnz"],
            "factor_s": ex["times"]["factor"] / ex["factorisations"],
            "setup_s": sol.setup_time,
            "source": "measured (3 iterations)",
        }
        if n == args.full:
            full = solvers.solve(
                problem,
                "ipm",
                tol=args.tol,
                max_iter=40,
                polish=False,
                linsolve="pardiso",
                threads=2,
            )
            history = full.extras["history"]
            row.update(
                full_status=full.status.value,
                full_iterations=full.iterations,
                full_solve_s=full.solve_time,
                full_ccp=ccp_residual(problem, full.p),
                full_best_iteration=int(np.nanargmin([h[3] for h in history])),
            )
        rows.append(row)
        print(pd.DataFrame(rows[-1:]).to_string(index=False, header=len(rows) == 1), flush=True)

    a, b = rows[-2], rows[-1]
    ratio = math.log(b["N"] / a["N"])
    e_fill = math.log(b["L_nnz"] / a["L_nnz"]) / ratio
    e_time = math.log(b["factor_s"] / a["factor_s"]) / ratio
    grow = SEED_N_3D / b["N"]
    seed_fill = b["L_nnz"] * grow**e_fill
    rows.append(
        {
            "N": SEED_N_3D,
            "L_nnz": seed_fill,
            "L_GB": 8e-9 * seed_fill,
            "factor_s": b["factor_s"] * grow**e_time,
            "source": f"extrapolated: L ~ N^{e_fill:.2f}, time ~ N^{e_time:.2f}",
        }
    )
    table = pd.DataFrame(rows)
    title = "A direct interior point on the seed's 3D column: fill and factorisation time"
    intro = (
        f"The step from t = {args.t_start:g} s of the seed's 3D column (lattice, rough bed, "
        f"20 cm channel, mu = {MU_3D:g}, dt = {DT_3D:g} s, d_max = {D_SEED_3D:g} r, "
        f"trajectory by apgd at tol {args.tol:g}), ipm with PARDISO on two threads. "
        "`K_order`: unknowns of the Newton system (6 per sphere); `L_nnz`: entries of its "
        "Cholesky factor; `factor_s`: one numerical factorisation; `setup_s`: ordering and "
        "symbolic factorisation included."
    )
    files = write_table(args.out, "column3d_ipm", table, title=title, intro=intro)
    seed = rows[-1]
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
    files.append(write_meta(args.out, "column3d_ipm", title=title, files=files, summary=summary))
    print(table.to_markdown(index=False, floatfmt=".3g"))
    print(summary)


if __name__ == "__main__":
    main()
