"""nscd's two local solvers on the same step problems: exact (closed forms) and hybrid
(Fischer-Burmeister Newton with the exact solver as fallback).

Usage::

    python benchmarks/nscd_local.py [--n2d 400] [--n3d 500] [--tol 1e-6]

A 2D column of ``--n2d`` discs after 60 steps of collapse and a 3D box of
``--n3d`` spheres after 20 steps (``clarabel``, dt 1e-3); the next step's problem
is solved by ``nscd`` with ``local="exact"`` and ``local="fb"``, each after a
short untimed solve that loads its compiled kernels. Prints sweeps, wall time,
the Coulomb residual and how many local solves Newton and the fallback ended.
Quote the ratio of the two times, measured in one run.
"""

from __future__ import annotations

import argparse
import time

import pandas as pd

import cocd
import solvers
from cocd.contacts import detect_contacts
from cocd.problem import assemble


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n2d", type=int, default=400)
    parser.add_argument("--n3d", type=int, default=500)
    parser.add_argument("--tol", type=float, default=1e-6)
    args = parser.parse_args()
    cases = [
        (f"column_2d({args.n2d})", lambda: cocd.column_2d(args.n2d), 60),
        (f"box_3d({args.n3d})", lambda: cocd.box_3d(args.n3d), 20),
    ]
    rows = []
    for name, make, steps in cases:
        scene = make()
        cocd.Stepper(scene, 1e-3, solver="clarabel", tol=1e-8).run(steps)
        problem = assemble(scene, detect_contacts(scene), 1e-3)
        for local in ("exact", "fb"):
            solvers.solve(problem, "nscd", tol=args.tol, local=local, max_iter=2)
            start = time.perf_counter()
            sol = solvers.solve(problem, "nscd", tol=args.tol, local=local)
            wall = time.perf_counter() - start
            rows.append(
                {
                    "problem": name,
                    "nc": problem.nc,
                    "local": local,
                    "status": sol.status.value,
                    "sweeps": sol.iterations,
                    "wall_s": wall,
                    "coulomb_residual": sol.extras["coulomb_residual"],
                    "newton": sol.extras.get("local_newton", 0),
                    "fallback": sol.extras.get("local_fallbacks", 0),
                }
            )
    table = pd.DataFrame(rows)
    print(table.to_markdown(index=False, floatfmt=".3g"))
    for name, sub in table.groupby("problem", sort=False):
        t = sub.set_index("local").wall_s
        print(f"{name}: fb / exact wall time = {t['fb'] / t['exact']:.1f}")


if __name__ == "__main__":
    main()
