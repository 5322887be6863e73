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
import multiprocessing as mp
import os
import pickle
import platform
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

import cocd
import solvers
from cocd.bench.report import write_meta
from cocd.residuals import ccp_residual, coulomb_residual

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


def _child(problem_path: str, name: str, tol: float, time_limit: float, memory_gb: float, queue):
    limit = int(memory_gb * 2**30)
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    with open(problem_path, "rb") as f:
        problem = pickle.load(f)
    try:
        sol = solvers.solve(problem, name, tol=tol, time_limit=time_limit)
        queue.put(
            (
                "ok",
                sol.u,
                sol.p,
                sol.status.value,
                sol.iterations,
                sol.setup_time,
                sol.solve_time,
                sol.extras.get("approximation", ""),
                len(sol.extras.get("attempts", [])),
                any(a[3] for a in sol.extras.get("attempts", [])),
            )
        )
    except MemoryError:
        queue.put(("error", f"out of memory (cap {memory_gb:g} GiB)"))
    except Exception as exc:  # the harness reports every failure as a row
        queue.put(("error", f"{type(exc).__name__}: {str(exc)[:200]}"))


def run_backend(problem_path, problem, name, tol, time_limit, memory_gb, ref_u):
    ctx = mp.get_context("spawn")
    queue = ctx.Queue()
    proc = ctx.Process(target=_child, args=(problem_path, name, tol, time_limit, memory_gb, queue))
    start = time.perf_counter()
    proc.start()
    grace = time_limit * 1.5 + 60
    result = None
    while proc.is_alive() and time.perf_counter() - start < grace:
        try:
            result = queue.get(timeout=1.0)
            break
        except Exception:
            continue
    if result is None and not queue.empty():
        result = queue.get()
    proc.join(timeout=5)
    if proc.is_alive():
        proc.kill()
        proc.join()
    row = {"backend": name, "formulation": solvers.get(name).formulation}
    if result is None:
        code = proc.exitcode
        why = "killed after time limit" if code is None or code < 0 else f"exit code {code}"
        return {
            **row,
            "status": "time_limit" if code is None or code < 0 else "error",
            "note": f"{why} ({time.perf_counter() - start:.0f} s)",
        }
    if result[0] == "error":
        return {**row, "status": "error", "note": result[1]}
    _, u, p, status, iterations, setup, solve, approximation, solves, polished = result
    row.update(
        status=status,
        iterations=iterations,
        setup_s=setup,
        solve_s=solve,
        solves=solves,
        polished=polished,
        note=approximation,
    )
    if status not in ("optimal", "inaccurate"):
        return row  # no answer: no residuals
    scale = max(np.linalg.norm(ref_u), np.linalg.norm(problem.U))
    return {
        **row,
        "ccp_residual": ccp_residual(problem, p),
        "coulomb_residual": coulomb_residual(problem, p),
        "u_error": float(np.linalg.norm(u - ref_u) / scale),
    }


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
        with tempfile.NamedTemporaryFile(suffix=".pkl", delete=False) as f:
            pickle.dump(problem, f)
            path = f.name
        try:
            for name in names:
                info = solvers.get(name)
                run_name = name
                if info.linear_cones_only and not problem.is_qp:
                    if info.first_order or "cvxpy" in name:
                        continue
                    run_name = f"{name}:facets=8"
                print(f"{label}: {run_name} ...", flush=True)
                row = run_backend(
                    path, problem, run_name, args.tol, args.time_limit, args.memory_gb, ref.u
                )
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
        finally:
            os.unlink(path)

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
