"""``cocd bench seed-contacts``: the detection threshold that gives the seed's
potential contacts per grain.

The seed's Table 1 counts Nc potential contacts (pairs closer than its threshold
D, section 3.3) without giving D. This advances Table 1's two columns to the
start of their recorded steps, as ``cocd bench table1`` does (2D:
``column_2d(N)``, ``ipm`` at 1e-8 to t = 0.11 s; 3D: the rough-bed column in a
20 cm channel, ``apgd`` at 1e-6 with ``clarabel-dual`` as fallback, to t = 1 s),
counts the potential contacts per free grain for fixed thresholds D = 0.25 to
2.5 mean radii, and interpolates the D at which the count is the seed's
(:data:`~cocd.studies.table1.D_SEED_2D`, :data:`~cocd.studies.table1.D_SEED_3D`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

import cocd
from cocd.bench import report, study
from cocd.bench.study import StudySettings, option
from cocd.errors import CocdError
from cocd.studies.table1 import CHANNEL_WIDTH, MU_3D, SEED_ROWS

__all__ = ["FACTORS", "STUDY", "Settings", "advance", "curve", "run"]

#: The fixed thresholds D counted, in mean radii.
FACTORS = [0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0, 2.5]


@dataclass(frozen=True)
class Settings(StudySettings):
    """The options of ``cocd bench seed-contacts``."""

    n2d: int = option(8308, "Discs in the 2D column.")
    n3d: int = option(1229, "Spheres in the 3D column.")


def advance(
    scene: cocd.Scene,
    dt: float,
    until: float,
    solver: str,
    tol: float,
    fallback: Sequence[str] = (),
    progress: Callable[[str], Any] = print,
) -> cocd.Scene:
    """Step ``scene`` to time ``until``, reporting every tenth step."""
    stepper = cocd.Stepper(scene, dt, solver=solver, tol=tol, fallback=fallback)
    start = time.perf_counter()
    while scene.time < until - 1e-9:
        r = stepper.step()
        if r.step % 10 == 0:
            wall = time.perf_counter() - start
            progress(f"  t = {r.t:.3f} s, Nc = {r.nc}, {wall:.0f} s")
    return scene


def curve(label: str, scene: cocd.Scene, target: float) -> list[dict[str, Any]]:
    """Potential contacts per free grain for each of :data:`FACTORS`, then for the
    threshold interpolated to ``target`` per grain."""
    r_mean = float(scene.radii.mean())
    rows: list[dict[str, Any]] = []
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


def run(cfg: Settings, *, out: Path, progress: Any = print) -> pd.DataFrame:
    """Potential contacts per grain against D; writes ``seed_contacts.csv`` and ``.md``."""
    for name, value in (("n2d", cfg.n2d), ("n3d", cfg.n3d)):
        if int(value) != value or value < 2:
            raise CocdError(f"--{name} must be an integer >= 2, got {value!r}")
    n2d, n3d = int(cfg.n2d), int(cfg.n3d)
    seed = {(r["dim"], r["N"]): r["Nc"] / r["N"] for r in SEED_ROWS}
    target_2d = seed[(2, 8308)] if n2d <= 20000 else seed[(2, 50772)]
    target_3d = seed[(3, 122932)]

    progress(f"2D column of {n2d} discs to t = 0.11 s (ipm, 1e-8)")
    s2 = advance(cocd.column_2d(n2d), 1e-3, 0.11, "ipm", 1e-8, progress=progress)
    rows = curve(f"2D column, {n2d} discs, t = 0.11 s", s2, target_2d)
    progress(pd.DataFrame(rows).to_string(index=False))
    progress(f"3D column of {n3d} spheres to t = 1 s (apgd, 1e-6)")
    s3 = cocd.column_collapse(3, n_grains=n3d, width=CHANNEL_WIDTH, bed="rough", mu=MU_3D)
    s3 = advance(s3, 1e-2, 1.0, "apgd", 1e-6, fallback=["clarabel-dual"], progress=progress)
    rows += curve(f"3D column, {s3.n_free} spheres, t = 1 s", s3, target_3d)
    table = pd.DataFrame(rows)
    title = "Detection threshold D for the seed's potential contacts per grain"
    intro = (
        "Potential contacts per free grain for fixed thresholds D (mean radii, no margin), "
        "at the start of Table 1's recorded steps. The last row of each case is the D "
        "interpolated to the seed's count (`seed_Nc_per_grain`)."
    )
    found = table.dropna(subset=["seed_Nc_per_grain"])
    summary = "; ".join(
        f"{r.case}: D = {r.D_over_r:g} r gives {r.Nc_per_grain:.2f} per grain "
        f"(seed {r.seed_Nc_per_grain:.2f})"
        for r in found.itertuples()
    )
    report.publish(out, "seed_contacts", table, title=title, intro=intro, summary=summary)
    progress(table.to_markdown(index=False, floatfmt=".3g"))
    progress(summary)
    return table


STUDY = study.register(
    study.Study(
        "seed-contacts",
        "bench",
        Settings,
        run,
        outputs=("seed_contacts",),
        help="The detection threshold D that gives the seed's potential contacts per grain "
        "on Table 1's two columns.",
    )
)
