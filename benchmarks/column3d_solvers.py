"""The first-order 3D backends on one step of the seed's 3D column, with apgd's profile.

Usage::

    python benchmarks/column3d_solvers.py [--n 12293] [--t-start 0.1] [--tol 1e-5]
                                          [--time-limit 60] [--out results]

The seed's 3D collapse (Table 1 rows 3-4): ``column_collapse(3, n_grains=N,
width=0.2, bed="rough", mu=0.3)`` (lattice packing, released at t = 0),
dt = 1e-2 s, potential contacts below 0.98 mean radii (the threshold that gives
the seed's 6.75 per sphere at t = 1 s, :data:`cocd.studies.table1.D_SEED_3D`).
The column is advanced by ``apgd`` at ``tol`` to ``--t-start`` (cached, see
:func:`cocd.bench.states.record_steps`) and the next step's problem is solved
by every method, warm-started from the previous step's impulses matched by
contact pair (and cold for ``apgd``), to ``ccp_residual <= tol`` or the time
limit.

Rows: ``apgd`` warm and cold with its default block-Jacobi scaling, and warm
with the per-contact scalar one (``scaling="contact"``); ``bgs`` (block Gauss-Seidel, exact local
solves) coloured on the threads numba has, and sequential in its three orders;
``pgs`` (scalar projected step). Columns: iterations (sweeps), set-up and solve
time, the residual reached, and for ``apgd`` its profile: restarts,
backtracks, the range of the step's Lipschitz estimate ``L``, and the
iterations at which the residual first fell below 1e-2, 1e-3, 1e-4 and 1e-5.
The warm start's own residual and that of zero impulses are in the summary.
Writes ``OUT/column3d_solvers.csv``, ``.md`` and ``.meta.json``.
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
from cocd.studies.table1 import CHANNEL_WIDTH, D_SEED_3D, DT_3D, MU_3D

THRESHOLDS = (1e-2, 1e-3, 1e-4, 1e-5)

METHODS = [
    ("apgd", "warm", {"scaling": "block"}),
    ("apgd", "cold", {"scaling": "block"}),
    ("apgd", "warm", {"scaling": "contact"}),
    ("bgs", "warm", {"order": "natural", "colour": True}),
    ("bgs", "warm", {"order": "natural", "colour": False}),
    ("bgs", "warm", {"order": "top-down", "colour": False}),
    ("bgs", "warm", {"order": "bottom-up", "colour": False}),
    ("pgs", "warm", {}),
]


def _first_below(history: dict, threshold: float) -> float:
    it, ccp = history["ccp_iteration"], history["ccp"]
    hit = np.flatnonzero(ccp <= threshold)
    return float(it[hit[0]]) if hit.size else math.nan


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n", type=int, default=12293, help="column spheres (seed: 122932)")
    parser.add_argument("--t-start", type=float, default=0.1)
    parser.add_argument("--tol", type=float, default=1e-5)
    parser.add_argument("--time-limit", type=float, default=60.0)
    parser.add_argument("--out", type=Path, default=Path("results"))
    args = parser.parse_args()

    make = partial(
        cocd.column_collapse, 3, n_grains=args.n, width=CHANNEL_WIDTH, bed="rough", mu=MU_3D
    )
    d_max = D_SEED_3D * float(make().radii.mean())
    seq = record_steps(
        f"column3d-solvers-{args.n}",
        make,
        dt=DT_3D,
        t_start=args.t_start,
        n_steps=1,
        solver="apgd",
        tol=args.tol,
        d_max=d_max,
        progress=print,
    )
    problem, warm = seq.problems[0], seq.warm_starts[0]
    n_free = seq.n_free
    rows = []
    for name, start, options in METHODS:
        sol = solvers.solve(
            problem,
            name,
            tol=args.tol,
            warm_start=warm if start == "warm" else None,
            max_iter=10**6,
            time_limit=args.time_limit,
            **options,
        )
        row = {
            "backend": name,
            "options": ", ".join(f"{k}={v}" for k, v in options.items()) or "-",
            "start": start,
            "status": sol.status.value,
            "iterations": sol.iterations,
            "setup_s": sol.setup_time,
            "solve_s": sol.solve_time,
            "s_per_iteration": sol.solve_time / max(sol.iterations, 1),
            "ccp_residual": ccp_residual(problem, sol.p),
            "colours": sol.extras.get("colours", math.nan),
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
        rows.append(row)
        print(pd.DataFrame(rows[-1:]).to_string(index=False, header=len(rows) == 1), flush=True)
    table = pd.DataFrame(rows)

    warm_r = ccp_residual(problem, warm) if warm is not None else math.nan
    zero_r = ccp_residual(problem, np.zeros((problem.nc, problem.contact_dim)))
    setting = (
        f"Seed 3D column, {n_free} spheres (lattice, rough bed, 20 cm channel, mu = {MU_3D:g}), "
        f"dt = {DT_3D:g} s; the step from t = {seq.t_start:g} s, Nc = {problem.nc} "
        f"({problem.nc / n_free:.2f} per sphere, d_max = {D_SEED_3D:g} r); trajectory by apgd "
        f"at tol {args.tol:g}; every method to ccp_residual <= {args.tol:g} or "
        f"{args.time_limit:g} s."
    )
    title = "First-order 3D backends on a step of the seed's 3D column"
    files = write_table(args.out, "column3d_solvers", table, title=title, intro=setting)

    t = table.set_index(["backend", "options", "start"])
    aw = t.loc[("apgd", "scaling=block", "warm")]
    ac = t.loc[("apgd", "scaling=block", "cold")]
    acw = t.loc[("apgd", "scaling=contact", "warm")]
    bgs_rows = table[table.backend == "bgs"]
    best_bgs = bgs_rows.loc[bgs_rows.ccp_residual.idxmin()]
    pg = t.loc[("pgs", "-", "warm")]
    summary = (
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
    files.append(write_meta(args.out, "column3d_solvers", title=title, files=files,
                            summary=summary))  # fmt: skip
    print(table.to_markdown(index=False, floatfmt=".3g"))
    print(summary)


if __name__ == "__main__":
    main()
