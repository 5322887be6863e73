"""The stability study's output: the series, the summary, its verdicts and the largest eps
at rest per backend."""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd

from cocd.bench import report
from cocd.studies._plots import plot_stability

#: How a run stopped by its wall-time budget is noted.
BUDGET_NOTE = "run budget"


def write_stability(
    out: Path,
    table: pd.DataFrame,
    steps: pd.DataFrame,
    threshold: float,
    dim: int,
    n_free: int,
    height: float,
    period: float,
    dt: float,
) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    series_path = out / "stability.csv"
    steps.to_csv(series_path, index=False)
    shape = "discs in a 2D box" if dim == 2 else "spheres in a 3D box"
    intro = (
        f"{n_free} {shape}, settled by rain deposition and released at rest; "
        f"packing height H = {height:.4g} m, T = sqrt(H/g) = {period:.4g} s, dt = {dt:g} s. "
        f"`at_rest`: every asked step was taken and the ratio of kinetic to total energy "
        f"Ek / (Ek + Ep), with Ep measured from the floor, stayed below the threshold "
        f"**{threshold:g}**. Time per step is the backend's own set-up plus solve time; "
        "`ccp_residual` (largest over the steps) is the framework's residual (the same "
        "for every backend). "
        f"The seed (Fig. 3, Mosek, 110 233 spheres) keeps the box at rest for eps <= 1e-3."
    )
    files = report.write_table(
        out,
        "stability_summary",
        table,
        title="Stability: a box at rest stays at rest (Fig. 3)",
        intro=intro,
    )
    png = out / "stability.png"
    plot_stability(png, table, steps, threshold, dim, n_free)
    files = [series_path, *files, png]
    report.write_meta(
        out,
        "stability",
        title="Stability: a box at rest stays at rest (Fig. 3)",
        files=files,
        summary=_verdicts(table, threshold),
    )
    return [*files, out / "stability.meta.json"]


def write_thresholds(
    out: Path, summary: pd.DataFrame, threshold: float, dim: int, t_end: float, dt: float
) -> list[Path]:
    """``stability_threshold``: per backend, the largest tolerance at rest (Fig. 3)."""
    table = stability_thresholds(summary)
    parts = []
    for row in table.itertuples():
        if math.isnan(row.largest_eps_at_rest):
            parts.append(f"`{row.solver}` never")
        else:
            parts.append(f"`{row.solver}` {row.largest_eps_at_rest:g}")
    n = summary.N.iloc[0] if len(summary) else 0
    text = (
        f"Largest tolerance at which a {dim}D box of {n} grains stays at rest "
        f"(Ek/E < {threshold:g} over {t_end:g} sqrt(H/g), dt = {dt:g} s): **{', '.join(parts)}**. "
        "The seed (Fig. 3, Mosek, 110 233 spheres) keeps its box at rest for eps <= 1e-3."
    )
    sensitivity = criterion_sensitivity(summary, CRITERIA)
    moved = []
    for value in CRITERIA:
        if value == threshold:
            continue
        sub = sensitivity[sensitivity.threshold == value]
        cells = ", ".join(f"`{r.solver}` {_eps(r.largest_eps_at_rest)}" for r in sub.itertuples())
        moved.append(f"at {value:g}: {cells}")
    text += (
        " The same runs judged with other criteria (Ek/E below the value given; no run "
        f"again): {'; '.join(moved)}."
    )
    files_s = report.write_table(
        out,
        "stability_criterion",
        sensitivity,
        title="Sensitivity of the stability threshold to the at-rest criterion (Fig. 3)",
        intro="The runs of `stability_summary` judged at rest with several thresholds on "
        "max Ek / (Ek + Ep): per threshold and backend, the largest tolerance at rest and "
        "whether every smaller finished tolerance was at rest too.",
    )
    title = "Stability threshold per backend (Fig. 3)"
    files = files_s + report.write_table(
        out,
        "stability_threshold",
        table,
        title=title,
        intro="`largest_eps_at_rest`: the largest tolerance whose run stayed at rest; "
        "`consistent`: every smaller tolerance that ran to its end was at rest too; "
        "`unfinished`: tolerances stopped by their time budget or a failed step.",
    )
    report.write_meta(out, "stability_threshold", title=title, files=files, summary=text)
    return [*files, out / "stability_threshold.meta.json"]


#: At-rest criteria (thresholds on max Ek / (Ek + Ep)) of the sensitivity table.
CRITERIA = (1e-4, 1e-5, 1e-6, 1e-7, 1e-8)


def criterion_sensitivity(summary: pd.DataFrame, thresholds: tuple[float, ...]) -> pd.DataFrame:
    """:func:`stability_thresholds` of the same runs judged at rest with each threshold on
    ``max_energy_ratio`` (a run stopped early is never at rest)."""
    finished = summary.steps_done == summary.steps_asked
    parts = []
    for value in thresholds:
        judged = summary.assign(at_rest=finished & (summary.max_energy_ratio < value))
        parts.append(stability_thresholds(judged).assign(threshold=value))
    table = pd.concat(parts, ignore_index=True)
    return table[["threshold", "solver", "largest_eps_at_rest", "consistent"]]


def _eps(value: float) -> str:
    return "never" if math.isnan(value) else f"{value:g}"


def stability_thresholds(summary: pd.DataFrame) -> pd.DataFrame:
    """Per backend of a stability summary: the largest tolerance at rest."""
    rows = []
    for solver, sub in summary.groupby("solver", sort=False):
        sub = sub.sort_values("tol", ascending=False)
        done = sub[sub.steps_done == sub.steps_asked]
        rest = done[done.at_rest.astype(bool)]
        largest = float(rest.tol.max()) if len(rest) else math.nan
        below = done[done.tol <= largest] if len(rest) else done.iloc[0:0]
        rows.append(
            {
                "solver": solver,
                "largest_eps_at_rest": largest,
                "consistent": bool(below.at_rest.astype(bool).all()) if len(rest) else False,
                "unfinished": ", ".join(
                    f"{e:g}" for e in sub.tol[sub.steps_done < sub.steps_asked]
                ),
            }
        )
    return pd.DataFrame(rows)


def _verdicts(table: pd.DataFrame, threshold: float) -> str:
    """A Markdown pivot: solver x eps, 'yes' / 'no' (max ratio) or 'failed at step k'."""
    if table.empty:
        return "No run."

    def cell(row: pd.Series) -> str:
        if row["note"] and row["steps_done"] < row["steps_asked"]:
            if str(row["note"]).startswith(BUDGET_NOTE):
                return f"budget spent at step {int(row['steps_done'])}"
            return f"failed at step {int(row['steps_done']) + 1}"
        word = "yes" if row["at_rest"] else "no"
        return f"{word} ({row['max_energy_ratio']:.1e})"

    cells = table.assign(
        verdict=table.apply(cell, axis=1), eps_label=table["tol"].map(lambda e: f"{e:.0e}")
    )
    order = list(dict.fromkeys(cells["eps_label"]))
    pivot = cells.pivot(index="solver", columns="eps_label", values="verdict")
    pivot = pivot.reindex(index=list(dict.fromkeys(cells["solver"])), columns=order)
    pivot.columns.name = None
    text = pivot.reset_index().to_markdown(index=False)
    return (
        f"At rest (max Ek / (Ek + Ep) over the run below {threshold:g}; "
        f"in brackets the max ratio), per solver and eps:\n\n{text}"
    )
