"""The detection threshold that gives the seed's potential contacts per grain.

Usage::

    python benchmarks/seed_contacts.py [--n2d 8308] [--n3d 1229] [--out results]

The seed's Table 1 counts Nc potential contacts (pairs closer than its
threshold D, section 3.3) without giving D: 37 331 for 8308 discs and
238 659 for 50 772 (4.49 and 4.70 per disc), 829 505 for 122 932 spheres
(6.75 per sphere). This advances Table 1's two columns to the start of their
recorded steps, as ``cocd bench table1`` does (2D: ``column_2d(N)``, ``ipm`` at
1e-8 to t = 0.11 s; 3D: the rough-bed column in a 20 cm channel, ``apgd`` at
1e-6 with ``clarabel-dual`` as fallback, to t = 1 s), counts the potential
contacts per free grain for fixed thresholds D = 0.25 to 2.5 mean radii, and
interpolates the D at which the count is the seed's. Writes
``OUT/seed_contacts.csv``, ``.md`` and ``.meta.json``; ``cocd.studies.table1``
uses the D found (``D_SEED_2D``, ``D_SEED_3D``).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import pandas as pd

import cocd
from cocd.bench.report import write_meta, write_table
from cocd.studies.table1 import CHANNEL_WIDTH, MU_3D, SEED_ROWS

FACTORS = [0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0, 2.5]


def advance(
    scene: cocd.Scene, dt: float, until: float, solver: str, tol: float, fallback=()
) -> cocd.Scene:
    stepper = cocd.Stepper(scene, dt, solver=solver, tol=tol, fallback=fallback)
    start = time.perf_counter()
    while scene.time < until - 1e-9:
        r = stepper.step()
        if r.step % 10 == 0:
            wall = time.perf_counter() - start
            print(f"  t = {r.t:.3f} s, Nc = {r.nc}, {wall:.0f} s", flush=True)
    return scene


def curve(label: str, scene: cocd.Scene, target: float) -> list[dict]:
    r_mean = float(scene.radii.mean())
    rows = []
    for f in FACTORS:
        nc = cocd.detect_contacts(scene, f * r_mean).nc
        rows.append({"case": label, "D_over_r": f, "Nc": nc, "Nc_per_grain": nc / scene.n_free})
    per = np.array([r["Nc_per_grain"] for r in rows])
    d = float(np.interp(target, per, FACTORS))
    nc = cocd.detect_contacts(scene, d * r_mean).nc
    rows.append(
        {
            "case": label,
            "D_over_r": round(d, 3),
            "Nc": nc,
            "Nc_per_grain": nc / scene.n_free,
            "seed_Nc_per_grain": target,
        }
    )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n2d", type=int, default=8308)
    parser.add_argument("--n3d", type=int, default=1229)
    parser.add_argument("--out", type=Path, default=Path("results"))
    args = parser.parse_args()
    seed = {(r["dim"], r["N"]): r["Nc"] / r["N"] for r in SEED_ROWS}
    target_2d = seed[(2, 8308)] if args.n2d <= 20000 else seed[(2, 50772)]
    target_3d = seed[(3, 122932)]

    print(f"2D column of {args.n2d} discs to t = 0.11 s (ipm, 1e-8)")
    s2 = advance(cocd.column_2d(args.n2d), 1e-3, 0.11, "ipm", 1e-8)
    rows = curve(f"2D column, {args.n2d} discs, t = 0.11 s", s2, target_2d)
    print(pd.DataFrame(rows).to_string(index=False), flush=True)
    print(f"3D column of {args.n3d} spheres to t = 1 s (apgd, 1e-6)")
    s3 = cocd.column_collapse(3, n_grains=args.n3d, width=CHANNEL_WIDTH, bed="rough", mu=MU_3D)
    s3 = advance(s3, 1e-2, 1.0, "apgd", 1e-6, fallback=["clarabel-dual"])
    rows += curve(f"3D column, {s3.n_free} spheres, t = 1 s", s3, target_3d)
    table = pd.DataFrame(rows)
    title = "Detection threshold D for the seed's potential contacts per grain"
    intro = (
        "Potential contacts per free grain for fixed thresholds D (mean radii, no margin), "
        "at the start of Table 1's recorded steps. The last row of each case is the D "
        "interpolated to the seed's count (`seed_Nc_per_grain`)."
    )
    files = write_table(args.out, "seed_contacts", table, title=title, intro=intro)
    found = table.dropna(subset=["seed_Nc_per_grain"])
    summary = "; ".join(
        f"{r.case}: D = {r.D_over_r:g} r gives {r.Nc_per_grain:.2f} per grain "
        f"(seed {r.seed_Nc_per_grain:.2f})"
        for r in found.itertuples()
    )
    files.append(write_meta(args.out, "seed_contacts", title=title, files=files, summary=summary))
    print(table.to_markdown(index=False, floatfmt=".3g"))
    print(summary)


if __name__ == "__main__":
    main()
