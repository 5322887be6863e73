"""Every available backend on one 2D step and one 3D step, judged by the same residuals.

Usage::

    python benchmarks/backends_table.py [--n2d 8308] [--n3d 2000] [--tol 1e-8]
        [--time-limit 300] [--memory-gb 12] [--solvers a,b,...] [--out results]

The 2D problem is a column of discs after 30 steps of collapse, the 3D one a box
of spheres after 20 steps of settling (both stepped with ``clarabel``; the states
are cached under ``benchmarks/.cache``). Each backend solves the next step's
problem in its own process, with a wall-clock limit and a memory cap, so that a
backend that runs out of time or memory is a row saying so. The velocity error
is against ``clarabel`` at tol 1e-10, relative to ``max(||u_ref||, ||U||)``.
3D friction is offered to the QP backends as an 8-facet pyramid (marked
``facets=8``: an approximation, whose residuals show its error).

``solves`` counts the native solves made to reach ``ccp_residual <= tol`` and
``polished`` says whether the active-set polish (:mod:`solvers.polish`) was
accepted, i.e. whether the final accuracy is the polish's rather than the
backend's own. Failed rows carry no residuals.

Writes ``<out>/backends.csv`` and ``<out>/backends.md``.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
from pathlib import Path

import numpy as np
import pandas as pd

import cocd
import solvers
from cocd.bench.report import write_meta
from cocd.bench.runner import Worker

CACHE = Path(__file__).parent / ".cache"
COLUMNS = [
    "problem",
    "dim",
    "N",
    "Nc",
    "backend",
    "formulation",
    "status",
    "iterations",
    "setup_s",
    "solve_s",
    "ccp_residual",
    "coulomb_residual",
    "u_error",
    "solves",
    "polished",
    "note",
]


def prepared_problem(dim: int, n: int, steps: int) -> cocd.ConicProblem:
    """The step problem after ``steps`` clarabel steps, cached on disk."""
    CACHE.mkdir(exist_ok=True)
    path = CACHE / f"state-{dim}d-{n}-{steps}.npz"
    scene = cocd.column_2d(n) if dim == 2 else cocd.box_3d(n)
    if path.exists():
        data = np.load(path)
        scene.positions[:] = data["positions"]
        scene.velocities[:] = data["velocities"]
        scene.angular_velocities[:] = data["angular_velocities"]
        scene.time = float(data["time"])
    else:
        stepper = cocd.Stepper(scene, 1e-3)
        for k in range(steps):
            r = stepper.step()
            print(f"  preparing {dim}D N={n}: step {k + 1}/{steps}, Nc={r.nc}", flush=True)
        np.savez(
            path,
            positions=scene.positions,
            velocities=scene.velocities,
            angular_velocities=scene.angular_velocities,
            time=scene.time,
        )
    return cocd.assemble(scene, cocd.detect_contacts(scene), 1e-3)


def run_backend(worker: Worker, problem, name, tol, time_limit, ref_u) -> dict:
    """One row: ``name`` on ``problem`` in the harness's child process."""
    row = worker.solve_row(problem, name, tol, time_limit=time_limit, ref_u=ref_u)
    keep = {c: row.get(c) for c in COLUMNS if c in row}
    return {**keep, "backend": name, "solves": row.get("solves")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n2d", type=int, default=8308)
    parser.add_argument("--n3d", type=int, default=2000)
    parser.add_argument("--tol", type=float, default=1e-8)
    parser.add_argument("--time-limit", type=float, default=300.0)
    parser.add_argument("--memory-gb", type=float, default=12.0)
    parser.add_argument("--solvers", default="")
    parser.add_argument("--out", default="results")
    args = parser.parse_args()

    # Dense BLAS paths (proxqp, daqp, ...) oversubscribe a small machine with one
    # thread per core on top of the solver's own; pin them, and say so below.
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    names = args.solvers.split(",") if args.solvers else solvers.available()
    rows = []
    for label, dim, n, steps in (("column-2d", 2, args.n2d, 30), ("box-3d", 3, args.n3d, 20)):
        problem = prepared_problem(dim, n, steps)
        ref = solvers.solve(problem, "clarabel", tol=1e-10)
        with Worker(memory_gb=args.memory_gb, grace=60.0) as worker:
            for name in names:
                info = solvers.get(name)
                run_name = name
                if info.linear_cones_only and not problem.is_qp:
                    if info.first_order or "cvxpy" in name:
                        continue
                    run_name = f"{name}:facets=8"
                print(f"{label}: {run_name} ...", flush=True)
                row = run_backend(worker, problem, run_name, args.tol, args.time_limit, ref.u)
                row.update(
                    problem=label,
                    dim=dim,
                    N=problem.ndof // (3 if dim == 2 else 6),
                    Nc=problem.nc,
                    backend=run_name,
                )
                print(
                    f"   {row.get('status')} {row.get('solve_s', float('nan')):.3g} s "
                    f"ccp {row.get('ccp_residual', float('nan')):.2e} {row.get('note', '')}",
                    flush=True,
                )
                rows.append(row)

    table = pd.DataFrame(rows, columns=COLUMNS)
    out = Path(args.out)
    out.mkdir(exist_ok=True)
    table.to_csv(out / "backends.csv", index=False)
    machine = f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"
    with open(out / "backends.md", "w") as f:
        f.write("# Every backend on one step\n\n")
        f.write(
            f"`python {' '.join(sys.argv)}` on {machine}; tol {args.tol:g}, time limit "
            f"{args.time_limit:g} s, memory cap {args.memory_gb:g} GiB per backend.\n\n"
        )
        f.write(table.to_markdown(index=False, floatfmt=".3g"))
        f.write("\n")
    write_meta(
        out,
        "backends",
        title="One step of every backend",
        files=[out / "backends.csv", out / "backends.md"],
    )
    print(table.to_string(index=False))


if __name__ == "__main__":
    main()
