"""Time one step of a 2D column of about 8000 discs with a backend.

Usage::

    python benchmarks/step_2d_column.py [--n 8308] [--solver clarabel] [--tol 1e-8]
        [--warmup-steps 0] [--dt 1e-3]

Prints N, Nc, iterations, setup and solve time and the framework's residuals
for one step (after ``--warmup-steps`` steps of collapse, with the same backend).
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np

import cocd
import solvers
from cocd.residuals import residuals


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n", type=int, default=8308)
    parser.add_argument("--solver", default="clarabel")
    parser.add_argument("--tol", type=float, default=1e-8)
    parser.add_argument("--dt", type=float, default=1e-3)
    parser.add_argument("--warmup-steps", type=int, default=0)
    args = parser.parse_args()

    scene = cocd.column_2d(args.n)
    stepper = cocd.Stepper(scene, args.dt, solver=args.solver, tol=args.tol)
    if args.warmup_steps:
        stepper.run(args.warmup_steps)

    start = time.perf_counter()
    contacts = cocd.detect_contacts(scene)
    problem = cocd.assemble(scene, contacts, args.dt)
    detect = time.perf_counter() - start
    start = time.perf_counter()
    solution = solvers.solve(problem, solver=args.solver, tol=args.tol)
    wall = time.perf_counter() - start
    res = residuals(problem, solution.u, solution.p)

    print(
        f"machine        {platform.processor() or platform.machine()}, {platform.python_version()}"
    )
    print(f"scene          2D column, N = {scene.n_free}, t = {scene.time:.4f} s, dt = {args.dt:g}")
    print(f"contacts       Nc = {problem.nc} (unknowns {problem.ndof}, rows {problem.H.shape[0]})")
    print(f"detect+assemble {detect:.3f} s")
    print(f"solver         {args.solver}, tol {args.tol:g}, status {solution.status.value}")
    print(f"iterations     {solution.iterations}")
    print(f"setup time     {solution.setup_time:.3f} s")
    print(f"solve time     {solution.solve_time:.3f} s (wall {wall:.3f} s)")
    for key in ("attempts", "polish_time"):
        if key in solution.extras:
            print(f"{key:14s} {solution.extras[key]}")
    print(f"ccp_residual   {res.ccp:.3e}")
    print(f"coulomb_resid. {res.coulomb:.3e}")
    print(f"dynamics_resid.{res.dynamics:.3e}")
    print(f"cone viol. max {res.cone_violation_max:.3e}")
    print(f"max |p|        {np.abs(solution.p).max():.3e}")


if __name__ == "__main__":
    main()
