"""Profile one recorded Table 1 step (2D column, mid-collapse) with one backend.

Usage::

    python benchmarks/profile_step.py [--n 8308] [--solver ipm] [--tol 1e-8]
        [--step 0] [--top 25] [--trajectory ipm]

Reads (or records) the step problems ``cocd bench table1 --scale 1`` uses for
a column of N discs (from t = 0.11 s, the seed's contact threshold), solves
step ``--step`` once to load the backend, then once under cProfile. Prints
the backend's own phase times when it keeps them and the functions with the
largest cumulative and own times.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import time
from functools import partial

import solvers
from cocd.bench.states import record_steps
from cocd.builders import column_2d
from cocd.residuals import ccp_residual
from cocd.studies import table1


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n", type=int, default=8308)
    parser.add_argument("--solver", default="ipm")
    parser.add_argument("--tol", type=float, default=1e-8)
    parser.add_argument("--step", type=int, default=0)
    parser.add_argument("--top", type=int, default=25)
    parser.add_argument("--trajectory", default="ipm")
    args = parser.parse_args()

    make = partial(column_2d, args.n)
    scene = make()
    seq = record_steps(
        f"table1-column-2d-{args.n}",
        make,
        dt=table1.DT_2D,
        t_start=0.11,
        n_steps=10,
        solver=args.trajectory,
        tol=table1.TRAJECTORY_TOL,
        d_max=table1.D_SEED_2D * float(scene.radii.mean()),
        progress=print,
    )
    problem = seq.problems[args.step]
    print(f"N = {args.n}, Nc = {problem.nc}, unknowns {problem.ndof}")
    solvers.solve(problem, args.solver, tol=args.tol)  # load and compile
    start = time.perf_counter()
    sol = solvers.solve(problem, args.solver, tol=args.tol)
    wall = time.perf_counter() - start
    print(
        f"{args.solver}: {sol.status.value}, {sol.iterations} iterations, wall {wall:.3f} s, "
        f"ccp_residual {ccp_residual(problem, sol.p):.2e}"
    )
    for key in ("times", "factorisations", "linsolve", "system_nnz", "factor_nnz"):
        if key in sol.extras:
            value = sol.extras[key]
            if isinstance(value, dict):
                value = ", ".join(f"{k} {v:.3f}" for k, v in value.items())
            print(f"  {key}: {value}")

    profiler = cProfile.Profile()
    profiler.enable()
    solvers.solve(problem, args.solver, tol=args.tol)
    profiler.disable()
    for order in ("cumulative", "tottime"):
        text = io.StringIO()
        pstats.Stats(profiler, stream=text).sort_stats(order).print_stats(args.top)
        print(f"--- by {order} ---")
        print("\n".join(line for line in text.getvalue().splitlines() if line.strip()))


if __name__ == "__main__":
    main()
