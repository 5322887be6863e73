"""``cocd bench margin``: the detection margin's cost against the penetration it avoids.

Two column collapses from rest, each stepped with several detection thresholds:

- 3D: ``column_collapse(3, n_grains=n3d, bed="rough")`` (lattice packing, a
  20 cm channel), ``apgd`` at tol 1e-5, dt = 1e-2 s (the seed's 3D step);
- 2D: ``column_2d(n2d)``, ``clarabel`` at tol 1e-8, dt = 1e-3 s.

Thresholds: fixed ``d_max`` of 0.5, 1 and 2 mean radii, and the motion-following
margin (``d_max = 0.5 r`` plus ``skin`` times the distance a pair's free relative
velocity closes in one step) with skin 1 and 2. These rows only record the
overlaps (``on_penetration="record"``); the last row is the stepper's default
(skin 2 and ``on_penetration="redo"``), whose redos are counted.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import pandas as pd

import cocd
from cocd.bench import report, study
from cocd.bench.study import StudySettings, option
from cocd.errors import CocdError

__all__ = ["COLUMNS", "DEFAULT", "STUDY", "Settings", "rows_for", "run", "summary_lines"]

#: The table's columns.
COLUMNS = [
    "scene",
    "threshold",
    "policy",
    "steps",
    "contacts_per_grain",
    "penetration_max_r",
    "steps_with_missed",
    "missed_pairs",
    "redos",
    "detect_s_per_step",
    "solve_s_per_step",
    "wall_s",
]
#: The threshold of the stepper's default row.
DEFAULT = "default (0.5 r + skin 2, redo)"


@dataclass(frozen=True)
class Settings(StudySettings):
    """The options of ``cocd bench margin``."""

    n3d: int = option(600, "Spheres in the 3D column.")
    steps3d: int = option(40, "Steps of the 3D collapse (dt = 1e-2 s).")
    n2d: int = option(300, "Discs in the 2D column.")
    steps2d: int = option(150, "Steps of the 2D collapse (dt = 1e-3 s).")


def rows_for(
    label: str,
    make: Callable[[], cocd.Scene],
    dt: float,
    steps: int,
    solver: str,
    tol: float,
    progress: Callable[[str], Any] = print,
) -> list[dict[str, Any]]:
    """One row per threshold for the scene ``make()`` builds."""
    r_mean = float(make().radii.mean())
    settings: list[tuple[str, dict[str, Any]]] = [
        ("d_max 0.5 r (fixed)", dict(d_max=0.5 * r_mean, on_penetration="record")),
        ("d_max 1 r (fixed)", dict(d_max=1.0 * r_mean, on_penetration="record")),
        ("d_max 2 r (fixed)", dict(d_max=2.0 * r_mean, on_penetration="record")),
        ("0.5 r + skin 1", dict(skin=1.0, on_penetration="record")),
        ("0.5 r + skin 2", dict(skin=2.0, on_penetration="record")),
        (DEFAULT, dict()),
    ]
    rows: list[dict[str, Any]] = []
    for name, options in settings:
        scene = make()
        stepper = cocd.Stepper(scene, dt, solver=solver, tol=tol, **options)
        start = time.perf_counter()
        stepper.run(steps)
        wall = time.perf_counter() - start
        st = stepper.stats()
        rows.append(
            {
                "scene": label,
                "threshold": name,
                "policy": options.get("on_penetration", "redo"),
                "steps": len(st),
                "contacts_per_grain": float((st.nc / st.n).mean()),
                "penetration_max_r": float(st.penetration.max()),
                "steps_with_missed": int((st.missed_contacts > 0).sum()),
                "missed_pairs": int(st.missed_contacts.sum()),
                "redos": int(st.redos.sum()),
                "detect_s_per_step": float(st.detect_time.mean()),
                "solve_s_per_step": float((st.setup_time + st.solve_time).mean()),
                "wall_s": wall,
            }
        )
        progress(pd.DataFrame(rows[-1:]).to_string(index=False, header=len(rows) == 1))
    return rows


def summary_lines(table: pd.DataFrame) -> list[str]:
    """One sentence per scene: the narrow and wide fixed thresholds against the default."""
    lines = []
    for dim in ("3D", "2D"):
        t = table[table.scene.str.startswith(dim)].set_index("threshold")
        old, wide = t.loc["d_max 0.5 r (fixed)"], t.loc["d_max 2 r (fixed)"]
        new = t.loc[DEFAULT]
        lines.append(
            f"{t.scene.iloc[0]}: a fixed d_max of 0.5 r lets grains overlap by "
            f"{old.penetration_max_r:.3g} r ({old.missed_pairs} missed pairs) with "
            f"{old.contacts_per_grain:.2f} potential contacts per grain; 2 r: "
            f"{wide.penetration_max_r:.2g} r with {wide.contacts_per_grain:.2f} "
            f"({wide.contacts_per_grain / old.contacts_per_grain:.2f} times as many); the "
            f"default margin: {new.penetration_max_r:.2g} r with {new.contacts_per_grain:.2f} "
            f"({new.contacts_per_grain / old.contacts_per_grain:.2f} times), {new.redos} redos, "
            f"solve {new.solve_s_per_step:.3g} s per step against {old.solve_s_per_step:.3g} s."
        )
    return lines


def run(cfg: Settings, *, out: Path, progress: Any = print) -> pd.DataFrame:
    """Each threshold on a 3D and a 2D collapse; writes ``margin.csv`` and ``.md``."""
    for name, value, least in (
        ("n3d", cfg.n3d, 2),
        ("n2d", cfg.n2d, 2),
        ("steps3d", cfg.steps3d, 1),
        ("steps2d", cfg.steps2d, 1),
    ):
        if int(value) != value or value < least:
            raise CocdError(f"--{name} must be an integer >= {least}, got {value!r}")
    n3d, n2d = int(cfg.n3d), int(cfg.n2d)
    steps3d, steps2d = int(cfg.steps3d), int(cfg.steps2d)
    rows = rows_for(
        f"3D collapse, {n3d} spheres, rough bed; apgd 1e-5, dt 1e-2, {steps3d} steps",
        partial(cocd.column_collapse, 3, n_grains=n3d, bed="rough"),
        1e-2,
        steps3d,
        "apgd",
        1e-5,
        progress,
    )
    rows += rows_for(
        f"2D collapse, {n2d} discs; clarabel 1e-8, dt 1e-3, {steps2d} steps",
        partial(cocd.column_2d, n2d),
        1e-3,
        steps2d,
        "clarabel",
        1e-8,
        progress,
    )
    table = pd.DataFrame(rows, columns=COLUMNS)
    title = "Detection margin: potential contacts against penetration"
    intro = (
        "Each column collapse starts from rest. `penetration_max_r`: the largest overlap at "
        "the end of a step, relative to the smaller radius of the pair. `steps_with_missed`, "
        "`missed_pairs`: overlaps of pairs that were not potential contacts. Rows with policy "
        "`record` only measure; the default redoes a step whose grains went through, with "
        "the margin of those grains widened (`redos`)."
    )
    summary = "\n\n".join(summary_lines(table))
    report.publish(out, "margin", table, title=title, intro=intro, summary=summary)
    progress(table.to_markdown(index=False, floatfmt=".3g"))
    progress(summary)
    return table


STUDY = study.register(
    study.Study(
        "margin",
        "bench",
        Settings,
        run,
        outputs=("margin",),
        help="The detection margin's cost (potential contacts, time per step) against the "
        "penetration it avoids, on a 3D and a 2D column collapse.",
    )
)
