"""``cocd bench scaling``: time per step against N, per backend, with fitted exponents.

2D: the Table 1 column collapse (mid-collapse steps from t = 0.11 s, dt = 1e-3,
eps 1e-8), recorded along one trajectory per N exactly as ``cocd bench
table1`` does (the same cache). 3D: a static box, ``jammed_box(N, dim=3)``
(equal spheres on a simple cubic lattice touching each other and the walls,
gravity on, dt = 1e-2, eps 1e-5): the stress test of the seed's Fig. 3 box
without the hours a deposition of 10^5 spheres would take; it has about 3
contacts per sphere where a random packing has 6 to 7.

Each backend solves ``steps`` problems per N in a :class:`~cocd.bench.runner.Worker`
(time limit, memory cap, one warm-up); the row's time is the mean wall time of
the solves. For each backend and dimension, ``time = c N^k`` is fitted by
least squares on the logarithms of the rows that were solved.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from cocd.bench import select_solvers
from cocd.bench.report import write_meta, write_table
from cocd.bench.runner import Worker, default_memory_gb, warmup_problem
from cocd.bench.states import record_steps
from cocd.builders import column_2d, jammed_box
from cocd.contacts import detect_contacts
from cocd.errors import CocdError
from cocd.problem import assemble

__all__ = ["COLUMNS", "fit_exponent", "run"]

COLUMNS = [
    "dim",
    "N",
    "Nc",
    "solver",
    "eps",
    "steps_ok",
    "iterations",
    "time_per_step_s",
    "detect_assemble_s",
    "ccp_residual",
    "peak_rss_gib",
    "note",
]
DT_2D, EPS_2D, T_START_2D = 1e-3, 1e-8, 0.11
DT_3D, EPS_3D = 1e-2, 1e-5


def fit_exponent(n: Any, t: Any) -> tuple[float, float]:
    """``(k, c)`` of ``t = c n^k`` by least squares on logarithms (NaN with < 2 points)."""
    n = np.asarray(n, dtype=float)
    t = np.asarray(t, dtype=float)
    ok = np.isfinite(t) & (t > 0) & (n > 0)
    if ok.sum() < 2:
        return float("nan"), float("nan")
    k, logc = np.polyfit(np.log(n[ok]), np.log(t[ok]), 1)
    return float(k), float(math.exp(logc))


def _problems_2d(n: int, steps: int, trajectory: str, progress: Callable[[str], None]) -> Any:
    seq = record_steps(
        f"table1-column-2d-{n}",
        partial(column_2d, n),
        dt=DT_2D,
        t_start=T_START_2D,
        n_steps=max(steps, 10),
        solver=trajectory,
        tol=EPS_2D,
        progress=progress,
    )
    return seq.problems[:steps], float("nan")


def _problems_3d(n: int, steps: int) -> Any:
    scene = jammed_box(n, dim=3, mu=0.3)
    start = time.perf_counter()
    contacts = detect_contacts(scene)
    problem = assemble(scene, contacts, DT_3D)
    elapsed = time.perf_counter() - start
    return [problem] * steps, elapsed


def run(
    *,
    solvers: str | list[str] | None,
    n2d: list[int],
    n3d: list[int],
    steps: int,
    time_limit: float,
    memory_gb: float | None,
    out: Path,
    trajectory: str = "ipm",
    progress: Callable[[str], None] = print,
    table1: Path | None = None,
) -> pd.DataFrame:
    """Time every backend at every size; write ``scaling.{csv,md,png}`` and the fits.

    ``table1``: a ``table1.csv`` of ``cocd bench table1`` whose 2D rows (this
    machine's, the same column-collapse steps) join the table instead of
    being solved again.
    """
    if steps < 1:
        raise CocdError(f"steps must be >= 1, got {steps}")
    if not (math.isfinite(time_limit) and time_limit > 0):
        raise CocdError(f"time limit must be > 0 seconds, got {time_limit!r}")
    if any(n < 1 for n in [*n2d, *n3d]) or not (n2d or n3d or table1 is not None):
        raise CocdError(f"sizes must be positive integers, got 2D {n2d} and 3D {n3d}")
    memory = default_memory_gb() if memory_gb is None else float(memory_gb)
    rows: list[dict[str, Any]] = _table1_rows(table1, solvers) if table1 is not None else []
    with Worker(memory_gb=memory) as worker:
        for dim, sizes in ((2, n2d), (3, n3d)):
            names = select_solvers(solvers, dim)
            # A backend that ran out of time at one size is not tried at larger ones.
            given_up: dict[str, str] = {}
            eps = EPS_2D if dim == 2 else EPS_3D
            for n in sorted(sizes):
                if dim == 2:
                    problems, detect = _problems_2d(n, steps, trajectory, progress)
                else:
                    problems, detect = _problems_3d(n, steps)
                nc = float(np.mean([p.nc for p in problems]))
                warm = warmup_problem(dim)
                for name in names:
                    if name in given_up:
                        rows.append(_skipped_row(dim, n, nc, name, eps, steps, detect,
                                                 given_up[name]))  # fmt: skip
                        continue
                    worker.restart()  # each row's peak memory is its own
                    worker.solve_row(warm, name, eps, time_limit=60.0)
                    answers = []
                    for problem in problems:
                        row = worker.solve_row(problem, name, eps, time_limit=time_limit)
                        answers.append(row)
                        if row["status"] in ("error", "time_limit"):
                            break
                    if answers[-1]["status"] == "time_limit":
                        given_up[name] = f"skipped: time limit at N = {n}"
                    ok = [a for a in answers if a["status"] in ("optimal", "inaccurate")]
                    notes = sorted({str(a.get("note") or "") for a in answers} - {""})
                    bad = [str(a["status"]) for a in answers if a["status"] != "optimal"]
                    rows.append(
                        {
                            "dim": dim,
                            "N": int(n),
                            "Nc": nc,
                            "solver": name,
                            "eps": eps,
                            "steps_ok": f"{sum(a['status'] == 'optimal' for a in answers)}/{steps}",
                            "iterations": _mean(ok, "iterations"),
                            "time_per_step_s": _mean(ok, "wall_s"),
                            "detect_assemble_s": detect,
                            "ccp_residual": _max(answers, "ccp_residual"),
                            "peak_rss_gib": _max(answers, "peak_rss_gib"),
                            "note": "; ".join([*bad, *notes])[:200],
                        }
                    )
                    progress(
                        f"scaling {dim}D N = {n} Nc = {nc:.0f} {name}: "
                        f"{rows[-1]['time_per_step_s']:.3g} s/step, {rows[-1]['steps_ok']} optimal"
                    )
                    _write(pd.DataFrame(rows, columns=COLUMNS), out, steps, time_limit)
    table = pd.DataFrame(rows, columns=COLUMNS)
    _write(table, out, steps, time_limit)
    return table


def _skipped_row(
    dim: int, n: int, nc: float, name: str, eps: float, steps: int, detect: float, note: str
) -> dict[str, Any]:
    nan = float("nan")
    return {
        "dim": dim, "N": int(n), "Nc": nc, "solver": name, "eps": eps,
        "steps_ok": f"0/{steps}", "iterations": nan, "time_per_step_s": nan,
        "detect_assemble_s": detect, "ccp_residual": nan, "peak_rss_gib": nan, "note": note,
    }  # fmt: skip


def _table1_rows(path: Path, solvers: str | list[str] | None) -> list[dict[str, Any]]:
    """This machine's 2D rows of a ``table1.csv`` as scaling rows."""
    try:
        t1 = pd.read_csv(path, keep_default_na=False, na_values=[""])
    except (OSError, ValueError) as exc:
        raise CocdError(f"cannot read Table 1 rows from {path}: {exc}") from None
    missing = {"source", "dim", "N", "Nc", "solver", "eps", "steps_ok"} - set(t1.columns)
    if missing:
        raise CocdError(f"{path} is not a table1.csv: columns {sorted(missing)} are missing")
    wanted = select_solvers(solvers, 2)
    t1 = t1[(t1["source"] == "this machine") & (t1["dim"] == 2) & t1["solver"].isin(wanted)]
    return [
        {
            "dim": 2,
            "N": int(r["N"]),
            "Nc": float(r["Nc"]),
            "solver": str(r["solver"]),
            "eps": float(r["eps"]),
            "steps_ok": str(r["steps_ok"]),
            "iterations": float(r["iterations"]),
            "time_per_step_s": float(r["time_per_step_s"]),
            "detect_assemble_s": float("nan"),
            "ccp_residual": float(r["ccp_residual"]),
            "peak_rss_gib": float("nan"),
            "note": f"from {path.name}" + (f"; {r['note']}" if str(r["note"]) != "nan" else ""),
        }
        for _, r in t1.iterrows()
    ]


def _mean(rows: list[dict[str, Any]], key: str) -> float:
    values = [float(r[key]) for r in rows if r.get(key) is not None and np.isfinite(r[key])]
    return float(np.mean(values)) if values else float("nan")


def _max(rows: list[dict[str, Any]], key: str) -> float:
    values = [float(r[key]) for r in rows if r.get(key) is not None and np.isfinite(r[key])]
    return float(np.max(values)) if values else float("nan")


def fits(table: pd.DataFrame) -> pd.DataFrame:
    """One row per (dim, solver): the fitted exponent and the sizes it covers."""
    out = []
    for (dim, solver), group in table.groupby(["dim", "solver"], sort=True):
        k, c = fit_exponent(group["N"], group["time_per_step_s"])
        solved = group[np.isfinite(group["time_per_step_s"])]
        out.append(
            {
                "dim": dim,
                "solver": solver,
                "exponent": k,
                "coefficient": c,
                "N_min": int(solved["N"].min()) if len(solved) else None,
                "N_max": int(solved["N"].max()) if len(solved) else None,
                "points": len(solved),
            }
        )
    return pd.DataFrame(out)


def _write(table: pd.DataFrame, out: Path, steps: int, time_limit: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    title = "Scaling: time per step against N"
    intro = (
        f"2D: Table 1's column collapse, {steps} mid-collapse steps per N (t = 0.11 s, "
        f"dt = 1e-3, eps 1e-8). 3D: `jammed_box(N, dim=3)` at rest (dt = 1e-2, eps 1e-5). "
        f"Mean wall time per solve, cold start (no warm start); time limit {time_limit:g} s; "
        "a backend that runs out of time is not tried at larger sizes. `peak_rss_gib`: "
        "the solving process's peak resident memory (problem, backend and warm-up)."
    )
    files = write_table(out, "scaling", table, title=title, intro=intro)
    fitted = fits(table)
    fit_md = out / "scaling_fit.md"
    fit_md.write_text(
        "# Scaling: fitted exponents, time = c N^k\n\n"
        + (fitted.to_markdown(index=False, floatfmt=".3g") if len(fitted) else "(none)")
        + "\n"
    )
    files.append(fit_md)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    for ax, dim in zip(axes, (2, 3), strict=True):
        sub = table[table["dim"] == dim]
        for solver, group in sub.groupby("solver"):
            k = fitted[(fitted.dim == dim) & (fitted.solver == solver)]["exponent"]
            label = f"{solver} (k = {float(k.iloc[0]):.2f})" if len(k) else str(solver)
            ax.loglog(group["N"], group["time_per_step_s"], "o-", label=label)
        ax.set_title(f"{dim}D")
        ax.set_xlabel("N (grains)")
        ax.set_ylabel("time per step (s)")
        ax.grid(True, which="both", alpha=0.3)
        if len(sub):
            ax.legend(fontsize=8)
    fig.tight_layout()
    png = out / "scaling.png"
    fig.savefig(png, dpi=120)
    plt.close(fig)
    files.append(png)
    summary = fitted.to_markdown(index=False, floatfmt=".3g") if len(fitted) else ""
    write_meta(out, "scaling", title=title, files=files, summary=summary)
