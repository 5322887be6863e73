"""Table 1's output: the table with the seed's rows, its Markdown, the fastest backend
per size and the time by phase."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from cocd.bench.metrics import finite
from cocd.bench.report import write_meta, write_table
from cocd.studies._table1_setup import (
    CASE_2D,
    CASE_3D,
    DT_2D,
    DT_3D,
    MIN_GRAINS,
    MU_3D,
    PHASES,
    PREP_TOL_3D,
    SEED,
    SEED_N_3D,
    SEED_ROWS,
    THIS_MACHINE,
    TRAJECTORY_TOL,
)


def seed_rows() -> list[dict[str, Any]]:
    return [
        {
            "source": SEED,
            "case": r["case"],
            "dim": r["dim"],
            "N": r["N"],
            "Nc": float(r["Nc"]),
            "Nc_per_grain": float(r["Nc"]) / r["N"],
            "d_max_r": np.nan,  # not given in the seed's text
            "dt": r["dt"],
            "tol": r["tol"],
            "solver": "mosek",
            "start": "cold",
            "steps_ok": "",
            "iterations": float(r["iterations"]),
            "wall_s": r["time"],
            "ccp_residual": np.nan,
            "coulomb_residual": np.nan,
            "scale": 1.0,
            "note": "seed Table 1 (Mosek interior point; Nc: potential contacts)",
        }
        for r in SEED_ROWS
    ]


# -- output -------------------------------------------------------------------
def write_table1(
    out: Path,
    table: pd.DataFrame,
    scales: tuple[float, float],
    steps: int,
    wanted: list[str],
    trajectory: dict[int, str],
    t_start_2d: float,
    t_start_3d: float,
    time_limit: float,
) -> None:
    title = "Table 1: iterations and time per step against N, dt and eps"
    scale, scale_3d = scales
    halves = []
    if "2d" in wanted:
        halves.append(
            f"2D *{CASE_2D}*: columns of N discs (the seed's 1109, 8308, 20488, 50772 times "
            f"{scale:g}, at least {MIN_GRAINS}; 20 cm wide, aspect 0.7), dt = {DT_2D:g} s, "
            f"{steps} steps from t = {t_start_2d:g} s, trajectory by {trajectory[2]}."
        )
    if "3d" in wanted:
        halves.append(
            f"3D *{CASE_3D}*: a column of {SEED_N_3D} x {scale_3d:g} spheres (20 x 14 cm, "
            "20 cm wide channel, rough bed) collapsing, "
            f"mu = {MU_3D:g}, dt = {DT_3D:g} s, {steps} steps from t = {t_start_3d:g} s, "
            f"trajectory by {trajectory[3]} (tol {PREP_TOL_3D:g} before t = {t_start_3d:g} s)."
        )
    intro = "\n".join(
        [
            f"N scaled by {_scales_text(scales, wanted)} for this 2-core machine "
            "(the seed ran Mosek on 2 x 8 cores "
            "at full size; its rows are at the bottom). Every backend solves the same "
            f"recorded step problems (trajectory backends at tol {TRAJECTORY_TOL:g}); "
            "`tol` (the seed's eps) is handed to each backend, the residuals are the framework's "
            "(`cocd.residuals`), max over the steps with an answer (optimal, inaccurate, "
            "or the last iterate of a max_iter stop; failed steps have none), and "
            "`steps_ok` counts the optimal ones. Contacts are detected with a fixed "
            "threshold `d_max_r` (mean radii) that gives the seed's potential contacts per "
            "grain (`Nc_per_grain`; the seed does not state its threshold). "
            "Interior points start cold; backends "
            "that take a warm start get the previous step's impulses (column `start`). "
            f"Time limit {time_limit:g} s per solve; `wall_s` (time per step) is the wall time "
            "of the whole call (set-up included), averaged over the solves that returned.",
            "",
            *[f"- {h}" for h in halves],
        ]
    )
    files = write_table(out, "table1", table, title=title, intro=intro)
    key = [
        "source",
        "case",
        "N",
        "Nc",
        "Nc_per_grain",
        "tol",
        "solver",
        "steps_ok",
        "iterations",
        "wall_s",
        "ccp_residual",
    ]
    summary = f"N scaled by {_scales_text(scales, wanted)}.\n\n" + table[key].to_markdown(
        index=False, floatfmt=".3g"
    )
    counts = _contact_counts(table)
    if counts:
        summary += "\n\nPotential contacts per grain:\n\n" + "\n".join(counts)
    best = fastest(table)
    if best:
        summary += "\n\nFastest backend with every step optimal:\n\n" + "\n".join(best)
    breakdown = _breakdown(table)
    if breakdown:
        summary += "\n\n" + breakdown
    write_meta(out, "table1", title=title, files=files, summary=summary)


def fastest(table: pd.DataFrame, reference: str = "clarabel") -> list[str]:
    """One line per (dim, N, eps) of this machine: the fastest backend whose every step
    was solved to ``optimal``, beside ``reference`` in the same run."""
    mine = table[table["source"] == THIS_MACHINE]
    lines = []
    for (dim, n, eps), rows in mine.groupby(["dim", "N", "tol"], sort=True):
        kind = "discs" if dim == 2 else "spheres"
        head = f"- {n} {kind}, eps {eps:g}: "
        done = rows[rows["steps_ok"].map(_all_optimal) & rows["wall_s"].notna()]
        if done.empty:
            lines.append(head + "no backend solved every step to optimal")
            continue
        best = done.loc[done["wall_s"].idxmin()]
        line = head + f"{best['solver']}, {best['wall_s']:.3g} s per step"
        ref = rows[rows["solver"] == reference]
        if best["solver"] != reference and not ref.empty:
            r = ref.iloc[0]
            t = r["wall_s"]
            if _all_optimal(r["steps_ok"]) and finite(t):
                ratio = float(t) / float(best["wall_s"])
                line += f"; {reference} {float(t):.3g} s ({ratio:.3g} times as long)"
            else:
                line += f"; {reference} {r['steps_ok']} optimal" + (
                    f" at {float(t):.3g} s per step solved" if finite(t) else ""
                )
        lines.append(line)
    return lines


def _all_optimal(steps_ok: object) -> bool:
    """True for ``"k/k"`` with ``k > 0``."""
    ok, _, total = str(steps_ok).partition("/")
    return ok.isdigit() and ok == total and int(ok) > 0


def _breakdown(table: pd.DataFrame) -> str:
    """Where a step's time goes, for the rows whose backend times its phases (ipm)."""
    phases = [f"t_{phase}_s" for phase in PHASES]
    mine = table[(table["source"] == THIS_MACHINE) & table["t_factor_s"].notna()]
    if mine.empty:
        return ""
    cols = ["N", "tol", "solver", "iterations", "factorisations", "wall_s", *phases]
    return "Time per step by phase (s; `t_other_s`: the rest of the wall time):\n\n" + mine[
        cols
    ].to_markdown(index=False, floatfmt=".3g")


def _contact_counts(table: pd.DataFrame) -> list[str]:
    """One line per size of this machine: Nc per grain and its threshold, beside the
    seed's count where the seed has that size."""
    seed = {(r["dim"], r["N"]): r["Nc"] / r["N"] for r in SEED_ROWS}
    ours = table[(table.source == THIS_MACHINE) & table.Nc_per_grain.notna()]
    lines = []
    for (dim, n), rows in ours.groupby(["dim", "N"], sort=True):
        kind = "discs" if dim == 2 else "spheres"
        line = (
            f"- {n} {kind}: {rows.Nc_per_grain.iloc[0]:.2f} "
            f"(D = {rows.d_max_r.iloc[0]:g} mean radii)"
        )
        if (dim, n) in seed:
            line += f"; the seed: {seed[dim, n]:.2f}"
        lines.append(line)
    return lines


def _scales_text(scales: tuple[float, float], wanted: list[str]) -> str:
    scale, scale_3d = scales
    if scale == scale_3d or "3d" not in wanted:
        return f"{scale:g}"
    if "2d" not in wanted:
        return f"{scale_3d:g}"
    return f"{scale:g} (2D) and {scale_3d:g} (3D)"


def fmt(value: object, spec: str = ".0f") -> str:
    return format(float(value), spec) if finite(value) else "-"  # type: ignore[arg-type]
