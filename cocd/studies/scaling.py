"""``cocd bench scaling``: time per step against N, per backend, with fitted exponents.

2D: the Table 1 column collapse (mid-collapse steps from t = 0.11 s, dt = 1e-3,
eps 1e-8), recorded along one trajectory per N exactly as ``cocd bench
table1`` does (the same cache). 3D (dt = 1e-2, eps 1e-5), one of three
packings per row (``packing``):

- ``column``: the seed's 3D column (``column_collapse(3, n_grains=N,
  width=0.2, bed="rough", mu=0.3)``, lattice packing, released at t = 0),
  mid-flow: the steps from t = 0.1 s, recorded along one ``apgd`` trajectory
  at eps 1e-5 (cached as ``cocd bench column3d-solvers`` does), each
  warm-started from the previous step's impulses for the backends that take
  a warm start;
- ``box``: a box at rest, ``static_box(3, n_grains=N, mu=0.3)`` settled by rain
  deposition with ``apgd`` (cached), its first step from rest, cold;
- ``jammed_box``: equal spheres on a simple cubic lattice touching each other
  and the walls, at rest, cold: a lattice with about 3 contacts per sphere,
  not a granular packing (kept for comparison with earlier tables).

Potential contacts of ``column`` and ``box``: gap below 0.98 mean radii, the
threshold that gives the seed's 6.75 per sphere (:data:`~cocd.studies.table1.D_SEED_3D`);
``Nc_per_grain`` is ``Nc`` over the free grains.

Each backend solves ``steps`` problems per N in a :class:`~cocd.bench.runner.Worker`
(time limit, memory cap, one warm-up); the row's time is the mean wall time of
the solves. For each backend, dimension and packing, ``time = c N^k`` is fitted
by least squares on the logarithms of the rows that were solved.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from cocd.bench import estimate, schema, select_solvers, study
from cocd.bench.metrics import finite_max, finite_mean, fit_exponent
from cocd.bench.report import write_meta, write_table
from cocd.bench.results import Results
from cocd.bench.runner import Worker, default_memory_gb, warmup_problem
from cocd.bench.states import record_steps
from cocd.bench.study import StudySettings, option
from cocd.builders import column_2d, column_collapse, jammed_box, static_box
from cocd.contacts import detect_contacts
from cocd.errors import CocdError
from cocd.problem import assemble
from cocd.studies.table1 import CHANNEL_WIDTH, D_SEED_3D, MU_3D

__all__ = ["COLUMNS", "PACKINGS_3D", "run"]

COLUMNS = [
    "dim",
    "packing",
    "N",
    "Nc",
    "Nc_per_grain",
    "solver",
    "start",
    "tol",
    "steps_ok",
    "iterations",
    "wall_s",
    "detect_assemble_s",
    "ccp_residual",
    "peak_rss_gib",
    "note",
]
#: What names a row.
KEY = ("dim", "packing", "N", "solver", "tol")
DT_2D, EPS_2D, T_START_2D = 1e-3, 1e-8, 0.11
DT_3D, EPS_3D = 1e-2, 1e-5
#: The 3D packings, in the order they are run.
PACKINGS_3D = ("column", "box", "jammed_box")
#: Start of the 3D column's timed steps (s): mid-flow.
T_START_3D = 0.1


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
    return seq.problems[:steps], [None] * steps, seq.n_free, float("nan")


def _problems_3d(packing: str, n: int, steps: int, progress: Callable[[str], None]) -> Any:
    """``(problems, warm starts, free grains, detection and assembly seconds)``."""
    if packing == "column":
        make = partial(column_collapse, 3, n_grains=n, width=CHANNEL_WIDTH, bed="rough", mu=MU_3D)
        seq = record_steps(
            f"column3d-solvers-{n}",
            make,
            dt=DT_3D,
            t_start=T_START_3D,
            n_steps=steps,
            solver="apgd",
            tol=EPS_3D,
            d_max=D_SEED_3D * float(make().radii.mean()),
            progress=progress,
        )
        return seq.problems, seq.warm_starts, seq.n_free, float("nan")
    if packing == "box":
        progress(f"scaling: settling a box of {n} spheres by rain deposition (cached)")
        scene = static_box(3, n_grains=n, mu=MU_3D, solver="apgd")
        d_max: float | None = D_SEED_3D * float(scene.radii.mean())
    else:
        scene = jammed_box(n, dim=3, mu=MU_3D)
        d_max = None
    start = time.perf_counter()
    contacts = detect_contacts(scene, d_max)
    problem = assemble(scene, contacts, DT_3D)
    elapsed = time.perf_counter() - start
    return [problem] * steps, [None] * steps, scene.n_free, elapsed


@dataclass(frozen=True)
class Settings(StudySettings):
    """The options of ``cocd bench scaling``."""

    solvers: str | None = study.solvers()
    n2d: tuple[int, ...] = option(
        (1109, 8308, 20488, 50772),
        "2D column sizes (comma-separated; empty for none).",
        kind="ints",
    )
    n3d: tuple[int, ...] = option(
        (2000, 8000, 32000), "3D sizes per packing (comma-separated; empty for none).", kind="ints"
    )
    packings: tuple[str, ...] = option(
        ("column", "box", "jammed_box"),
        "3D packings: column (mid-flow), box (rain-deposited, at rest), jammed_box.",
        kind="names",
    )
    n3d_box: tuple[int, ...] | None = option(
        None, "Sizes of the box packing, if not those of --n3d.", kind="ints"
    )
    resume: bool = study.resume("scaling", "Keep OUT/scaling.csv's 3D rows; run the others.")
    steps: int = option(3, "Problems timed per size.")
    trajectory: str = option("ipm", "Backend that steps the 2D columns.")
    table1: Path | None = option(None, "Take the 2D rows from this table1.csv instead.")
    time_limit: float = study.time_limit(900.0)
    memory_gb: float | None = study.memory_gb()


def run(cfg: Settings, *, out: Path, progress: Callable[[str], None] = print) -> pd.DataFrame:
    """Time every backend at every size; write ``scaling.{csv,md,png}`` and the fits.

    ``table1``: a ``table1.csv`` of ``cocd bench table1`` whose 2D rows (this
    machine's, the same column-collapse steps) join the table instead of
    being solved again. ``packings``: the 3D packings (default all of
    :data:`PACKINGS_3D`). ``n3d_box``: the box's sizes, when they are not
    ``n3d`` (its rain deposition costs hours at 10^5 spheres). ``resume``: keep
    the 3D rows of ``out/scaling.csv`` (same packing, N, backend and eps) and
    solve only the others; the table is rewritten after every row, so an
    interrupted run goes on where it stopped.
    """
    packings = list(PACKINGS_3D) if cfg.packings is None else list(cfg.packings)
    unknown = sorted(set(packings) - set(PACKINGS_3D))
    if unknown or not packings:
        raise CocdError(
            f"unknown 3D packing {', '.join(map(repr, unknown)) or '(none given)'}; "
            f"choose from {', '.join(PACKINGS_3D)}"
        )
    if cfg.n3d_box is not None and "box" not in packings:
        raise CocdError("--n3d-box sizes the box packing, which --packings leaves out")
    if cfg.steps < 1:
        raise CocdError(f"steps must be >= 1, got {cfg.steps}")
    if any(n < 1 for n in [*cfg.n2d, *cfg.n3d, *(cfg.n3d_box or [])]) or not (
        cfg.n2d or cfg.n3d or cfg.table1 is not None
    ):
        raise CocdError(f"sizes must be positive integers, got 2D {cfg.n2d} and 3D {cfg.n3d}")
    memory = default_memory_gb() if cfg.memory_gb is None else float(cfg.memory_gb)
    rows: list[dict[str, Any]] = (
        _table1_rows(cfg.table1, cfg.solvers) if cfg.table1 is not None else []
    )
    done = Results(out / "scaling.csv", COLUMNS, resume=cfg.resume, key=KEY,
                   keep=lambda row: row["dim"] == 3)  # fmt: skip
    rows += done.rows
    cases = [(2, "column", n) for n in sorted(cfg.n2d)]
    box_sizes = cfg.n3d if cfg.n3d_box is None else cfg.n3d_box
    cases += [
        (3, packing, n)
        for packing in packings
        for n in sorted(box_sizes if packing == "box" else cfg.n3d)
    ]
    names = {dim: select_solvers(cfg.solvers, dim) for dim in (2, 3)}

    def prep(dim: int, packing: str) -> int:  # steps that make the problems
        if packing != "column":
            return 0
        return round(T_START_2D / DT_2D) if dim == 2 else round(T_START_3D / DT_3D)

    estimate.announce(
        "scaling",
        [
            (n, prep(dim, packing) + cfg.steps * len(names[dim]))
            for dim, packing, n in cases
            if names[dim]
        ],
        out=Path(out),
        progress=progress,
    )
    # A backend that ran out of time at one size is not tried at larger ones.
    given_up: dict[tuple[int, str, str], str] = {}
    with Worker(memory_gb=memory) as worker:
        for dim, packing, n in cases:
            eps = EPS_2D if dim == 2 else EPS_3D
            todo = [name for name in names[dim] if not done.has(dim, packing, n, name, eps)]
            if not todo:
                continue
            if dim == 2:
                problems, warms, n_free, detect = _problems_2d(
                    n, cfg.steps, cfg.trajectory, progress
                )
            else:
                problems, warms, n_free, detect = _problems_3d(packing, n, cfg.steps, progress)
            nc = float(np.mean([p.nc for p in problems]))
            base = {
                "dim": dim, "packing": packing, "N": int(n), "Nc": nc,
                "Nc_per_grain": nc / max(n_free, 1), "tol": eps,
                "detect_assemble_s": detect,
            }  # fmt: skip
            warm = warmup_problem(dim)
            for name in todo:
                start = "warm" if warms[0] is not None and solvers_warm(name) else "cold"
                key = (dim, packing, name)
                if key in given_up:
                    rows.append(_skipped_row(base, name, start, cfg.steps, given_up[key]))
                    continue
                worker.restart()  # each row's peak memory is its own
                worker.solve_row(warm, name, eps, time_limit=60.0)
                answers = []
                for problem, ws in zip(problems, warms, strict=True):
                    row = worker.solve_row(
                        problem, name, eps, time_limit=cfg.time_limit, warm_start=ws
                    )
                    answers.append(row)
                    if row["status"] in ("error", "time_limit"):
                        break
                if answers[-1]["status"] == "time_limit":
                    given_up[key] = f"skipped: time limit at N = {n}"
                ok = [a for a in answers if a["status"] in ("optimal", "inaccurate")]
                notes = sorted({str(a.get("note") or "") for a in answers} - {""})
                bad = [str(a["status"]) for a in answers if a["status"] != "optimal"]
                rows.append(
                    {
                        **base,
                        "start": start,
                        "solver": name,
                        "steps_ok": f"{sum(a['status'] == 'optimal' for a in answers)}/{cfg.steps}",
                        "iterations": finite_mean(ok, "iterations"),
                        "wall_s": finite_mean(ok, "wall_s"),
                        "ccp_residual": finite_max(answers, "ccp_residual"),
                        "peak_rss_gib": finite_max(answers, "peak_rss_gib"),
                        "note": "; ".join([*bad, *notes])[:200],
                    }
                )
                progress(
                    f"scaling {dim}D {packing} N = {n} Nc = {nc:.0f} {name}: "
                    f"{rows[-1]['wall_s']:.3g} s/step, {rows[-1]['steps_ok']} optimal"
                )
                _write(pd.DataFrame(rows, columns=COLUMNS), out, cfg.steps, cfg.time_limit)
    table = pd.DataFrame(rows, columns=COLUMNS)
    _write(table, out, cfg.steps, cfg.time_limit)
    return table


def solvers_warm(name: str) -> bool:
    """Whether backend ``name`` takes a warm start."""
    import solvers

    return bool(solvers.get(name).warm_start)


def _skipped_row(
    base: dict[str, Any], name: str, start: str, steps: int, note: str
) -> dict[str, Any]:
    nan = float("nan")
    return {
        **base, "start": start, "solver": name, "steps_ok": f"0/{steps}", "iterations": nan,
        "wall_s": nan, "ccp_residual": nan, "peak_rss_gib": nan, "note": note,
    }  # fmt: skip


def _table1_rows(path: Path, solvers: str | list[str] | None) -> list[dict[str, Any]]:
    """This machine's 2D rows of a ``table1.csv`` as scaling rows."""
    try:
        t1 = schema.upgrade(pd.read_csv(path, keep_default_na=False, na_values=[""]))
    except (OSError, ValueError) as exc:
        raise CocdError(f"cannot read Table 1 rows from {path}: {exc}") from None
    needed = {"source", "dim", "N", "Nc", "Nc_per_grain", "solver", "start", "tol", "steps_ok"}
    missing = needed - set(t1.columns)
    if missing:
        raise CocdError(f"{path} is not a table1.csv: columns {sorted(missing)} are missing")
    wanted = select_solvers(solvers, 2)
    t1 = t1[(t1["source"] == "this machine") & (t1["dim"] == 2) & t1["solver"].isin(wanted)]
    return [
        {
            "dim": 2,
            "packing": "column",
            "N": int(r["N"]),
            "Nc": float(r["Nc"]),
            "Nc_per_grain": float(r["Nc_per_grain"]),
            "start": str(r["start"]),
            "solver": str(r["solver"]),
            "tol": float(r["tol"]),
            "steps_ok": str(r["steps_ok"]),
            "iterations": float(r["iterations"]),
            "wall_s": float(r["wall_s"]),
            "detect_assemble_s": float("nan"),
            "ccp_residual": float(r["ccp_residual"]),
            "peak_rss_gib": float("nan"),
            "note": f"from {path.name}" + (f"; {r['note']}" if str(r["note"]) != "nan" else ""),
        }
        for _, r in t1.iterrows()
    ]


def fits(table: pd.DataFrame) -> pd.DataFrame:
    """One row per (dim, packing, solver): the fitted exponent and the sizes it covers."""
    out = []
    for (dim, packing, solver), group in table.groupby(["dim", "packing", "solver"], sort=False):
        k, c = fit_exponent(group["N"], group["wall_s"])
        solved = group[np.isfinite(group["wall_s"])]
        out.append(
            {
                "dim": dim,
                "packing": packing,
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
        f"dt = 1e-3, eps 1e-8). 3D (dt = 1e-2, eps 1e-5), `packing`: `column`, the seed's "
        f"column (lattice, rough bed, 20 cm channel, mu 0.3) mid-flow, {steps} steps from "
        f"t = {T_START_3D:g} s, warm-started from the previous step (`start`); `box`, a "
        "rain-deposited box at rest, its first step, cold; `jammed_box`, equal spheres on a "
        "simple cubic lattice at rest (about 3 contacts per sphere: a lattice, not a "
        "granular packing), cold. N counts the free grains of `box` and `jammed_box` and "
        "the column's grains (its bed is glued); `Nc_per_grain` is Nc over the free grains. "
        f"Mean wall time per solve; time limit {time_limit:g} s; a backend that runs out of "
        "time is not tried at larger sizes of the same packing. `peak_rss_gib`: the solving "
        "process's peak resident memory (problem, backend and warm-up)."
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
    marks = {"column": "o-", "box": "s--", "jammed_box": "^:"}
    for ax, dim in zip(axes, (2, 3), strict=True):
        sub = table[table["dim"] == dim]
        for (packing, solver), group in sub.groupby(["packing", "solver"], sort=False):
            k = fitted[
                (fitted.dim == dim) & (fitted.packing == packing) & (fitted.solver == solver)
            ]["exponent"]
            name = f"{solver}, {packing}" if dim == 3 else str(solver)
            fitted_k = float(k.iloc[0]) if len(k) else float("nan")
            label = f"{name} (k = {fitted_k:.2f})" if math.isfinite(fitted_k) else name
            ax.loglog(group["N"], group["wall_s"], marks.get(packing, "o-"), label=label)
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


STUDY = study.register(
    study.Study(
        "scaling",
        "bench",
        Settings,
        run,
        help="Time per step against N per backend (2D column; 3D column, box, lattice), with fits.",
        outputs=("scaling",),
    )
)
