"""Iterative backends, cold and warm-started, beside clarabel on one mid-collapse step.

Usage::

    python benchmarks/iterative_table.py [--n 8308] [--tol 1e-6] [--time-limit 600]
        [--solvers pgs,apgd,nscd] [--out results]

Takes the 2D column state cached by ``backends_table.py`` (30 steps of collapse),
steps it once with ``clarabel`` to get the previous step's impulses, and solves
the following step with each backend: cold (no warm start) and warm (the previous
impulses matched by contact pair, as the stepper does). Each backend first solves
a tiny problem so that numba's compiled kernels are loaded before timing.
The stopping test is the backend's own mapping of ``tol`` (the framework's
``ccp_residual <= tol``; ``coulomb_residual`` for ``nscd``).

Writes ``<out>/iterative.csv`` and ``<out>/iterative.md``.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

import cocd
import solvers
from cocd.bench.report import write_meta
from cocd.residuals import ccp_residual, coulomb_residual
from cocd.stepper import match_impulses

sys.path.insert(0, str(Path(__file__).parent))
from backends_table import prepared_problem

COLUMNS = [
    "backend",
    "start",
    "status",
    "iterations",
    "solve_s",
    "ccp_residual",
    "coulomb_residual",
    "u_error",
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n", type=int, default=8308)
    parser.add_argument("--tol", type=float, default=1e-6)
    parser.add_argument("--time-limit", type=float, default=600.0)
    parser.add_argument("--solvers", default="pgs,apgd,nscd")
    parser.add_argument("--out", default="results")
    args = parser.parse_args()

    # State after 30 steps, then one clarabel step for the previous impulses.
    prepared_problem(2, args.n, 30)
    scene = cocd.column_2d(args.n)
    data = np.load(Path(__file__).parent / ".cache" / f"state-2d-{args.n}-30.npz")
    scene.positions[:] = data["positions"]
    scene.velocities[:] = data["velocities"]
    scene.angular_velocities[:] = data["angular_velocities"]
    scene.time = float(data["time"])
    stepper = cocd.Stepper(scene, 1e-3, tol=1e-8)
    stepper.step()
    prev_keys, prev_p = stepper.contacts.keys, stepper.solution.p
    contacts = cocd.detect_contacts(scene)
    problem = cocd.assemble(scene, contacts, 1e-3)
    warm = match_impulses(prev_keys, prev_p, contacts.keys)
    ref = solvers.solve(problem, "clarabel", tol=1e-10)
    scale = max(np.linalg.norm(ref.u), np.linalg.norm(problem.U))
    tiny = cocd.assemble(*_tiny())

    rows = []
    for name in ["clarabel", *args.solvers.split(",")]:
        info = solvers.get(name)
        solvers.solve(tiny, name, tol=args.tol)  # load compiled kernels
        for start in ("cold", "warm") if info.warm_start else ("cold",):
            begin = time.perf_counter()
            sol = solvers.solve(
                problem,
                name,
                tol=args.tol,
                warm_start=warm if start == "warm" else None,
                time_limit=args.time_limit,
            )
            wall = time.perf_counter() - begin
            row = {
                "backend": name,
                "start": start,
                "status": sol.status.value,
                "iterations": sol.iterations,
                "solve_s": wall,
                "ccp_residual": ccp_residual(problem, sol.p),
                "coulomb_residual": coulomb_residual(problem, sol.p),
                "u_error": float(np.linalg.norm(sol.u - ref.u) / scale),
            }
            print(row, flush=True)
            rows.append(row)

    table = pd.DataFrame(rows, columns=COLUMNS)
    out = Path(args.out)
    out.mkdir(exist_ok=True)
    table.to_csv(out / "iterative.csv", index=False)
    machine = f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"
    with open(out / "iterative.md", "w") as f:
        f.write("# Iterative backends on one mid-collapse step\n\n")
        f.write(
            f"`python {' '.join(sys.argv)}` on {machine}. 2D column, N = {scene.n_free}, "
            f"Nc = {problem.nc}, t = {scene.time:.3f} s, dt = 1e-3; tol {args.tol:g}. "
            "`u_error` is against clarabel at tol 1e-10, relative to max(||u_ref||, ||U||); "
            "`solve_s` is wall-clock time of `solvers.solve`.\n\n"
        )
        f.write(table.to_markdown(index=False, floatfmt=".3g"))
        f.write("\n")
    write_meta(
        out,
        "iterative",
        title="Iterative backends, cold and warm",
        files=[out / "iterative.csv", out / "iterative.md"],
    )
    print(table.to_string(index=False))


def _tiny():
    scene = cocd.stack(3, dim=2)
    return scene, cocd.detect_contacts(scene), 1e-3


if __name__ == "__main__":
    main()
