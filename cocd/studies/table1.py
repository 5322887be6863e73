"""``cocd bench table1``: the seed's Table 1 (iterations and time per step), for every backend.

Two cases, as in the seed (section 3.4, Table 1):

- *variation of N* (2D): a column of ``N`` discs (20 cm wide, aspect 0.7,
  :func:`~cocd.builders.column_2d`) collapsing; ``dt = 1e-3`` s, ``eps = 1e-8``,
  statistics over the steps from ``t = 0.11`` s, for the seed's four
  ``N = 1109, 8308, 20488, 50772`` times ``scale``;
- *variation of mu* (3D): a column of ``122932 * scale`` spheres (R0 x H0 =
  20 x 14 cm in a 20 cm wide channel, on a rough bed of glued grains,
  :func:`~cocd.builders.column_collapse`, ``mu = 0.3``) collapsing, as in the
  seed (its box at rest is this collapse's initial state); ``dt = 1e-2`` s,
  ``eps = 1e-8`` and ``1e-5``, statistics over the steps from ``t = 1`` s.

The seed counts Nc potential contacts (pairs closer than its threshold D,
section 3.3) but does not give D: both cases detect contacts with the fixed
threshold that gives the seed's Nc per grain at the start of the recorded
steps (:data:`D_SEED_2D`, :data:`D_SEED_3D`, in mean radii, found by
``python benchmarks/seed_contacts.py``), so that the problems are the size of
the seed's. Every step of the trajectory is checked for overlaps at its end
(:class:`~cocd.stepper.Stepper`).

Each case's step problems are recorded once along one accurate trajectory
(:func:`~cocd.bench.states.record_steps`, cached), then every backend solves
the same problems in a :class:`~cocd.bench.runner.Worker` (time limit, memory
cap). ``eps`` is the ``tol`` handed to each backend; what the rows compare are
the framework's residuals (:mod:`cocd.residuals`). The seed's own rows (Mosek,
2 x 8 cores) are added for reference.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

import solvers
from cocd.bench import estimate, select_solvers, study
from cocd.bench.report import previous_table, write_meta, write_table
from cocd.bench.runner import Worker, default_memory_gb, warmup_problem
from cocd.bench.states import StepSequence, cache_path, record_steps
from cocd.bench.study import option
from cocd.builders import column_2d, column_collapse
from cocd.errors import CocdError
from cocd.scene import Scene

__all__ = ["COLUMNS", "SEED_ROWS", "run"]

#: Phases of a step's solve in the time breakdown (``t_<phase>_s``): the backend's
#: set-up, and for ``ipm`` the assembly of the reduced system, its numerical
#: factorisations, the triangular solves, the residual checks and the polish;
#: ``other`` is the rest of the wall time (for most backends: all their iterations).
PHASES = ("setup", "assemble", "factor", "solve", "check", "polish", "other")
#: Columns an older table1.csv may lack; they are read as empty.
_LATER_COLUMNS = frozenset({"factorisations", *(f"t_{phase}_s" for phase in PHASES)})

#: Columns of ``table1.csv``, in order.
COLUMNS = [
    "source",
    "case",
    "dim",
    "N",
    "Nc",
    "Nc_per_grain",
    "d_max_r",
    "dt",
    "eps",
    "solver",
    "warm",
    "steps_ok",
    "iterations",
    "time_per_step_s",
    "ccp_residual",
    "coulomb_residual",
    "factorisations",
    *(f"t_{phase}_s" for phase in PHASES),
    "scale",
    "note",
]

THIS_MACHINE = "this machine"
SEED = "seed (Mosek, 2x8 cores)"
CASE_2D = "variation of N"
CASE_3D = "variation of mu"

#: Disc counts of the seed's "variation of N" (its Fig. 5 and Table 1).
SEED_N_2D = [1109, 8308, 20488, 50772]
#: Sphere count of the seed's "variation of mu".
SEED_N_3D = 122932
#: Below this the column is too small to flow like a granular column.
MIN_GRAINS = 20
DT_2D, DT_3D = 1e-3, 1e-2
EPS_2D = [1e-8]
EPS_3D = [1e-8, 1e-5]
MU_3D = 0.3
CHANNEL_WIDTH = 0.2
TRAJECTORY_TOL = 1e-8
#: Tolerance of the 3D trajectory's steps before the first recorded one (the 2D
#: ones use TRAJECTORY_TOL): 100 steps of a flowing column at 1e-8 take longer
#: than every backend's solves together.
PREP_TOL_3D = 1e-6

#: Detection thresholds D of the two cases, in mean radii: the fixed thresholds at
#: which the columns have the seed's potential contacts per grain at the start of
#: the recorded steps (4.49 per disc for 8308 discs, 6.75 per sphere), measured on
#: the 8308-disc column and the 1229-sphere one (1 % of the seed's)
#: (``python benchmarks/seed_contacts.py``, ``results/seed_contacts.md``).
D_SEED_2D = 1.63
D_SEED_3D = 0.98

#: Table 1 of the seed (DESIGN.md section 5): Mosek's interior point, cold, ten steps.
SEED_ROWS: list[dict[str, Any]] = [
    dict(case=CASE_2D, dim=2, N=8308, Nc=37331, dt=DT_2D, eps=1e-8, iterations=47, time=8.85),
    dict(case=CASE_2D, dim=2, N=50772, Nc=238659, dt=DT_2D, eps=1e-8, iterations=61, time=51.9),
    dict(case=CASE_3D, dim=3, N=122932, Nc=829505, dt=DT_3D, eps=1e-8, iterations=21, time=475.8),
    dict(case=CASE_3D, dim=3, N=122932, Nc=829505, dt=DT_3D, eps=1e-5, iterations=11, time=269.9),
]

#: Statuses for which the backend returned within its limits (timed and counted).
_RETURNED = ("optimal", "inaccurate", "max_iter")
#: Statuses after which the rest of a case is not worth the time.
_FAILED = ("error", "time_limit", "infeasible")


@dataclass(frozen=True)
class Settings:
    """The options of ``cocd bench table1``."""

    solvers: str | None = study.solvers()
    scale: float = option(0.1, "Multiply the seed's grain counts by this (0 < S <= 1).")
    scale_3d: float | None = option(None, "The 3D case's own scale (default: --scale).")
    cases: tuple[str, ...] = option(("2d", "3d"), "Which halves: 2d, 3d or 2d,3d.", kind="names")
    steps: int = option(10, "Steps averaged per row.")
    time_limit: float = study.time_limit(600.0)
    memory_gb: float | None = study.memory_gb()
    resume: bool = option(False, "Keep the rows already in OUT/table1.csv; solve only the others.")
    row_budget: float | None = option(
        None, "Seconds of solving after which a row stops (slow backends)."
    )
    trajectory_solver: str | None = option(
        None,
        "Backend that steps each column to the recorded steps (default: clarabel, "
        "clarabel-dual in 3D).",
        flag="--trajectory",
    )


def run(
    *,
    solvers: str | list[str] | None,
    scale: float,
    cases: list[str],
    steps: int,
    time_limit: float,
    memory_gb: float | None,
    out: Path,
    t_start_2d: float = 0.11,
    t_start_3d: float = 1.0,
    trajectory_solver: str | None = None,
    progress: Callable[[str], None] = print,
    scale_3d: float | None = None,
    resume: bool = False,
    row_budget: float | None = None,
) -> pd.DataFrame:
    """Run the Table 1 cases with every selected backend; write ``table1.csv/.md/.meta.json``.

    Parameters
    ----------
    solvers : str, list of str or None
        Backends (comma-separated names or a list); None for the harness's
        default set (:func:`cocd.bench.select_solvers`). Backends that cannot
        handle a case's dimension are left out of that case.
    scale : float
        Grain counts are the seed's times ``scale``, in (0, 1]; at least
        20 discs in 2D.
    scale_3d : float, optional
        The 3D case's own scale, in (0, 1]; default ``scale``.
    cases : list of {"2d", "3d"}
        Which halves of the table.
    steps : int
        Step problems averaged per row (the seed: 10).
    time_limit : float
        Seconds per solve; a backend that overruns it on a case's first
        problem is not run on the rest of that case.
    memory_gb : float or None
        Memory cap of the backends' process (GiB); default 3/4 of the machine's.
    out : Path
        Output directory.
    t_start_2d, t_start_3d : float
        Time (s) of the first recorded step, 2D and 3D.
    trajectory_solver : str, optional
        Backend that advances the scenes and records the problems (at
        ``tol = 1e-8``); default ``clarabel`` in 2D and ``clarabel-dual`` in
        3D, the faster accurate one for each while the column flows (measured
        on this machine: clarabel 1.7 times faster than scs-dual for 831
        discs; for 1229 spheres clarabel-dual takes 3 s per step, scs-dual
        about a minute once the column moves).
    progress : callable
        Receives progress lines.
    resume : bool
        Keep the rows of this machine already in ``out/table1.csv`` (same
        case, N, eps and backend) instead of solving them again. The table is
        rewritten after every row, so an interrupted run resumes where it
        stopped.
    row_budget : float, optional
        Seconds of solving after which a row stops (a slow backend on a large
        case); its means are over the steps solved and its note says so.

    Returns
    -------
    pandas.DataFrame
        One row per case, ``N``, ``eps`` and backend (:data:`COLUMNS`), then
        the seed's rows.

    Raises
    ------
    CocdError
        For an unknown case, ``scale`` outside (0, 1], ``steps < 1``, a bad
        time limit or memory cap, or an unknown backend.
    """
    scale, steps, wanted = _check(scale, cases, steps, time_limit, memory_gb)
    if row_budget is not None and not (math.isfinite(row_budget) and row_budget > 0):
        raise CocdError(f"row budget must be > 0 seconds, got {row_budget!r}")
    scale_3d, _, _ = _check(scale if scale_3d is None else scale_3d, cases, steps, time_limit, None)
    cap = default_memory_gb() if memory_gb is None else float(memory_gb)
    done = _previous_rows(Path(out) / "table1.csv") if resume else {}
    trajectory = {dim: _trajectory_solver(trajectory_solver, dim) for dim in (2, 3)}
    # Both lists first, so that a bad name fails before any work.
    names = {dim: select_solvers(solvers, dim) for dim in (2, 3) if f"{dim}d" in wanted}
    for dim, chosen in names.items():
        if not chosen:
            progress(f"table1: no selected backend solves {dim}D problems; {dim}D skipped")
    rows: list[dict[str, Any]] = []
    start = time.perf_counter()

    def write() -> pd.DataFrame:
        table = pd.DataFrame(_ordered(rows) + _seed_rows(), columns=COLUMNS)
        _write(
            out,
            table,
            (scale, scale_3d),
            steps,
            wanted,
            trajectory,
            t_start_2d,
            t_start_3d,
            time_limit,
        )
        return table

    def emit(row: dict[str, Any]) -> None:
        rows.append(row)
        write()

    # (case, label, builder, dt, t_start, eps list, dim, scale, tolerance before t_start,
    #  detection threshold in mean radii)
    plan: list[tuple[str, str, Callable[[], Scene], float, float, list[float], int, float,
                     float | None, float]] = []  # fmt: skip
    if names.get(2):
        for n in sorted({max(MIN_GRAINS, round(scale * n)) for n in SEED_N_2D}):
            make: Callable[[], Scene] = partial(column_2d, n)
            plan.append((CASE_2D, f"table1-column-2d-{n}", make, DT_2D, t_start_2d, EPS_2D, 2,
                         scale, None, D_SEED_2D))  # fmt: skip
    if names.get(3):
        n = max(1, round(scale_3d * SEED_N_3D))
        make = partial(column_collapse, 3, n_grains=n, width=CHANNEL_WIDTH, bed="rough", mu=MU_3D)
        plan.append((CASE_3D, f"table1-column-3d-{n}", make, DT_3D, t_start_3d, EPS_3D, 3,
                     scale_3d, PREP_TOL_3D, D_SEED_3D))  # fmt: skip

    def prep_steps(label: str, make: Callable[[], Scene], dt: float, t0: float,
                   prep_tol: float | None, d_r: float, dim: int) -> int:  # fmt: skip
        """Steps of the trajectory to the recorded ones: none when they are cached."""
        scene = make()
        d_max = d_r * float(scene.radii.mean())
        path, _ = cache_path(label, scene, dt, t0, steps, trajectory[dim], TRAJECTORY_TOL,
                             prep_tol, d_max)  # fmt: skip
        return 0 if path.is_file() else round(t0 / dt) + steps

    estimate.announce(
        "table1",
        [
            (
                int(label.rsplit("-", 1)[1]),
                prep_steps(label, make, dt, t0, prep_tol, d_r, dim)
                + steps * len(eps_list) * len(names[dim]),
            )
            for _, label, make, dt, t0, eps_list, dim, _, prep_tol, d_r in plan
        ],
        out=Path(out),
        progress=progress,
    )
    for case, label, make, dt, t0, eps_list, dim, case_scale, prep_tol, d_r in plan:
        _case(
            case,
            label,
            make,
            dt,
            t0,
            eps_list,
            names=names[dim],
            trajectory=trajectory[dim],
            steps=steps,
            time_limit=time_limit,
            memory_gb=cap,
            scale=case_scale,
            progress=progress,
            done=done,
            emit=emit,
            prep_tol=prep_tol,
            row_budget=row_budget,
            d_max_r=d_r,
        )
    table = write()
    progress(f"table1: done in {time.perf_counter() - start:.0f} s")
    return table


# -- one case -----------------------------------------------------------------
def _case(
    case: str,
    label: str,
    make: Callable[[], Scene],
    dt: float,
    t_start: float,
    eps_list: list[float],
    *,
    names: list[str],
    trajectory: str,
    steps: int,
    time_limit: float,
    memory_gb: float,
    scale: float,
    progress: Callable[[str], None],
    done: dict[tuple[int, int, float, str, float], dict[str, Any]],
    emit: Callable[[dict[str, Any]], None],
    prep_tol: float | None = None,
    row_budget: float | None = None,
    d_max_r: float = D_SEED_2D,
) -> None:
    """Record one case's step problems, then run every backend on them at every eps.

    Contacts are detected with the fixed threshold ``d_max_r`` mean radii. Each
    finished row goes to ``emit``; rows found in ``done`` are emitted as they are.
    """
    scene = make()
    dim, n = scene.dim, scene.n_free
    d_max = d_max_r * float(scene.radii.mean())
    todo = []
    for name in names:
        for eps in sorted(eps_list, reverse=True):
            key = (dim, n, float(eps), name, float(d_max_r))
            if key in done:
                emit(done[key])
            else:
                todo.append((name, eps))
    if not todo:
        progress(f"{label}: every row read from the previous table")
        return
    base = dict(
        source=THIS_MACHINE, case=case, dim=dim, N=n, dt=dt, scale=scale, steps_ok=f"0/{steps}",
        d_max_r=d_max_r,
    )  # fmt: skip
    progress(
        f"{label}: {n} grains, recording {steps} steps from t = {t_start:g} s "
        f"with {trajectory} (tol {TRAJECTORY_TOL:g})"
    )
    try:
        seq = record_steps(
            label,
            make,
            dt=dt,
            t_start=t_start,
            n_steps=steps,
            solver=trajectory,
            tol=TRAJECTORY_TOL,
            prep_tol=prep_tol,
            progress=_throttled(progress),
            d_max=d_max,
        )
    except CocdError as exc:
        # No problems to compare on: every backend gets a row saying why.
        note = f"no step problems: trajectory ({trajectory}) failed: {str(exc)[:200]}"
        progress(f"{label}: {note}")
        for name, eps in todo:
            emit({**base, "Nc": np.nan, "Nc_per_grain": np.nan, "eps": eps, "solver": name,
                  "warm": "no", "note": note})  # fmt: skip
        return
    nc = float(np.mean([p.nc for p in seq.problems]))
    built = "read from the cache" if seq.build_time == 0.0 else f"{seq.build_time:.0f} s"
    progress(f"{label}: {len(seq.problems)} problems, mean Nc = {nc:.0f} ({built})")
    base["Nc"] = nc
    base["Nc_per_grain"] = nc / n
    # Kept alive while the worker uses it (the worker keys problems by identity).
    warmup = warmup_problem(dim, dt)
    # Loosest eps first: a backend out of time there would be at a tighter eps too.
    timed_out_at: dict[str, float] = {}
    with Worker(memory_gb=memory_gb) as worker:
        for name, eps in todo:
            if name in timed_out_at:
                row = {
                    **base,
                    "eps": eps,
                    "solver": name,
                    "warm": "yes" if _takes_warm_start(name, seq) else "no",
                    "note": "not run: time limit on the first problem at eps "
                    f"{timed_out_at[name]:g}",
                }
            else:
                # Imports and JIT compilation in the worker would otherwise be timed
                # as part of the first step.
                worker.solve_row(warmup, name, eps, time_limit=time_limit)
                stats = _solver_rows(
                    worker, seq, name, eps, time_limit, label, progress, row_budget
                )
                row = {**base, "eps": eps, "solver": name, **stats}
                if stats["first_status"] == "time_limit":
                    timed_out_at[name] = eps
            emit({k: v for k, v in row.items() if k in COLUMNS})


def _solver_rows(
    worker: Worker,
    seq: StepSequence,
    name: str,
    eps: float,
    time_limit: float,
    label: str,
    progress: Callable[[str], None],
    row_budget: float | None = None,
) -> dict[str, Any]:
    """Solve every problem of ``seq`` with ``name``; the statistics of one table row.

    With ``row_budget``, the row stops once its solves have taken that many
    seconds; its means are over the steps solved, and its note says so.
    """
    warm = _takes_warm_start(name, seq)
    answers: list[dict[str, Any]] = []
    total = len(seq.problems)
    spent = 0.0
    stopped = ""
    for k, problem in enumerate(seq.problems):
        ws = seq.warm_starts[k] if warm else None
        row = worker.solve_row(problem, name, eps, warm_start=ws, time_limit=time_limit)
        answers.append(row)
        progress(
            f"{label}: {name} eps {eps:g} step {k + 1}/{total}: {row['status']}, "
            f"{_fmt(row.get('iterations'))} it, {_fmt(row.get('wall_s'), '.3g')} s, "
            f"ccp {_fmt(row.get('ccp_residual'), '.2g')}"
        )
        if k == 0 and row["status"] in _FAILED:
            # The first problem is like the others: the rest would fail the same way.
            break
        spent += float(row.get("wall_s") or 0.0)
        if row_budget is not None and spent >= row_budget and k + 1 < total:
            stopped = f"row budget of {row_budget:g} s spent after {k + 1} steps"
            break
    return _summarise(answers, total, warm, stopped)


def _ordered(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """This machine's rows as the seed lists them: by dimension, N, tighter eps first;
    backends in the order they were run."""
    first: dict[str, int] = {}
    for k, r in enumerate(rows):
        first.setdefault(r["solver"], k)
    return sorted(rows, key=lambda r: (r["dim"], r["N"], r["eps"], first[r["solver"]]))


def _previous_rows(path: Path) -> dict[tuple[int, int, float, str, float], dict[str, Any]]:
    """Rows of this machine in an earlier ``table1.csv``, keyed by (dim, N, eps, solver,
    detection threshold); a table written before the threshold was a column has none
    to reuse (its problems were detected with another threshold)."""
    old = previous_table(
        path, COLUMNS, optional=frozenset({"Nc_per_grain", "d_max_r"}), filled=_LATER_COLUMNS
    )
    if old is None:
        return {}
    old = old[old["source"] == THIS_MACHINE].astype(object)
    old = old.where(pd.notna(old), None)
    rows: dict[tuple[int, int, float, str, float], dict[str, Any]] = {}
    numbers = ("Nc", "Nc_per_grain", "d_max_r", "iterations", "time_per_step_s",
               "ccp_residual", "coulomb_residual", *_LATER_COLUMNS)  # fmt: skip
    for rec in old[COLUMNS].to_dict("records"):
        rec["note"] = rec["note"] or ""
        rec["steps_ok"] = rec["steps_ok"] or ""
        for key in numbers:
            rec[key] = np.nan if rec[key] is None else float(rec[key])
        where = (int(rec["dim"]), int(rec["N"]), float(rec["eps"]), str(rec["solver"]))
        rows[(*where, float(rec["d_max_r"]))] = rec
    return rows


def _takes_warm_start(name: str, seq: StepSequence) -> bool:
    return bool(solvers.get(name).warm_start) and any(w is not None for w in seq.warm_starts)


def _summarise(
    answers: list[dict[str, Any]], total: int, warm: bool, stopped: str = ""
) -> dict[str, Any]:
    """Means (iterations, wall time) over returned solves, max residuals, and what went wrong."""
    statuses = [str(a.get("status")) for a in answers]
    returned = [a for a, s in zip(answers, statuses, strict=True) if s in _RETURNED]
    ok = sum(s == "optimal" for s in statuses)
    notes = []
    bad = Counter(s for s in statuses if s != "optimal")
    if bad:
        notes.append(", ".join(f"{s} on {c} step{'s' * (c > 1)}" for s, c in bad.items()))
    details = {str(a.get("note") or "") for a in answers} - {""}
    notes += sorted(details)
    if stopped:
        notes.append(stopped)
    elif len(answers) < total:
        notes.append(f"stopped after the first problem ({total - len(answers)} not run)")
    return {
        "warm": "yes" if warm else "no",
        "steps_ok": f"{ok}/{total}",
        "iterations": _mean(returned, "iterations"),
        "time_per_step_s": _mean(returned, "wall_s"),
        "ccp_residual": _max(answers, "ccp_residual"),
        "coulomb_residual": _max(answers, "coulomb_residual"),
        "factorisations": _mean(returned, "factorisations"),
        **{
            f"t_{phase}_s": _mean([a.get("phases") or {} for a in returned], phase)
            for phase in PHASES
        },
        "note": "; ".join(notes)[:300],
        "first_status": statuses[0] if statuses else "",
    }


def _seed_rows() -> list[dict[str, Any]]:
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
            "eps": r["eps"],
            "solver": "mosek",
            "warm": "no",
            "steps_ok": "",
            "iterations": float(r["iterations"]),
            "time_per_step_s": r["time"],
            "ccp_residual": np.nan,
            "coulomb_residual": np.nan,
            "scale": 1.0,
            "note": "seed Table 1 (Mosek interior point; Nc: potential contacts)",
        }
        for r in SEED_ROWS
    ]


# -- output -------------------------------------------------------------------
def _write(
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
            "eps is the tol handed to each backend, the residuals are the framework's "
            "(`cocd.residuals`), max over the steps with an answer (optimal, inaccurate, "
            "or the last iterate of a max_iter stop; failed steps have none), and "
            "`steps_ok` counts the optimal ones. Contacts are detected with a fixed "
            "threshold `d_max_r` (mean radii) that gives the seed's potential contacts per "
            "grain (`Nc_per_grain`; the seed does not state its threshold). "
            "Interior points start cold; backends "
            "that take a warm start get the previous step's impulses (column `warm`). "
            f"Time limit {time_limit:g} s per solve; time per step is the wall time of the "
            "whole call (set-up included), averaged over the solves that returned.",
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
        "eps",
        "solver",
        "steps_ok",
        "iterations",
        "time_per_step_s",
        "ccp_residual",
    ]
    summary = f"N scaled by {_scales_text(scales, wanted)}.\n\n" + table[key].to_markdown(
        index=False, floatfmt=".3g"
    )
    counts = _contact_counts(table)
    if counts:
        summary += "\n\nPotential contacts per grain:\n\n" + "\n".join(counts)
    fastest = _fastest(table)
    if fastest:
        summary += "\n\nFastest backend with every step optimal:\n\n" + "\n".join(fastest)
    breakdown = _breakdown(table)
    if breakdown:
        summary += "\n\n" + breakdown
    write_meta(out, "table1", title=title, files=files, summary=summary)


def _fastest(table: pd.DataFrame, reference: str = "clarabel") -> list[str]:
    """One line per (dim, N, eps) of this machine: the fastest backend whose every step
    was solved to ``optimal``, beside ``reference`` in the same run."""
    mine = table[table["source"] == THIS_MACHINE]
    lines = []
    for (dim, n, eps), rows in mine.groupby(["dim", "N", "eps"], sort=True):
        kind = "discs" if dim == 2 else "spheres"
        head = f"- {n} {kind}, eps {eps:g}: "
        done = rows[rows["steps_ok"].map(_all_optimal) & rows["time_per_step_s"].notna()]
        if done.empty:
            lines.append(head + "no backend solved every step to optimal")
            continue
        best = done.loc[done["time_per_step_s"].idxmin()]
        line = head + f"{best['solver']}, {best['time_per_step_s']:.3g} s per step"
        ref = rows[rows["solver"] == reference]
        if best["solver"] != reference and not ref.empty:
            r = ref.iloc[0]
            t = r["time_per_step_s"]
            if _all_optimal(r["steps_ok"]) and _finite(t):
                ratio = float(t) / float(best["time_per_step_s"])
                line += f"; {reference} {float(t):.3g} s ({ratio:.3g} times as long)"
            else:
                line += f"; {reference} {r['steps_ok']} optimal" + (
                    f" at {float(t):.3g} s per step solved" if _finite(t) else ""
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
    cols = ["N", "eps", "solver", "iterations", "factorisations", "time_per_step_s", *phases]
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


# -- helpers ------------------------------------------------------------------
def _check(
    scale: float, cases: list[str], steps: int, time_limit: float, memory_gb: float | None
) -> tuple[float, int, list[str]]:
    """Validated ``scale``, ``steps`` and cases (lower case, each once, in order)."""
    try:
        s = float(scale)
    except (TypeError, ValueError):
        raise CocdError(f"scale must be a number in (0, 1], got {scale!r}") from None
    if not (math.isfinite(s) and 0.0 < s <= 1.0):
        raise CocdError(f"scale must be in (0, 1], got {scale!r}")
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 1:
        raise CocdError(f"steps must be an integer >= 1, got {steps!r}")
    if isinstance(cases, str):
        cases = [cases]
    wanted = list(dict.fromkeys(str(c).strip().lower() for c in cases))
    unknown = [c for c in wanted if c not in ("2d", "3d")]
    if unknown or not wanted:
        raise CocdError(f"cases must be among '2d' and '3d', got {list(cases)!r}")
    if not (math.isfinite(time_limit) and time_limit > 0):
        raise CocdError(f"time_limit must be > 0 seconds, got {time_limit!r}")
    if memory_gb is not None and not (math.isfinite(memory_gb) and memory_gb > 0):
        raise CocdError(f"memory_gb must be > 0, got {memory_gb!r}")
    return s, int(steps), wanted


def _trajectory_solver(name: str | None, dim: int) -> str:
    if name is not None:
        solvers.get(name)  # an unknown name fails here, before any work
        return name
    if dim == 3 and "clarabel-dual" in solvers.available():
        return "clarabel-dual"
    return "clarabel"


def _throttled(progress: Callable[[str], None], every: float = 10.0) -> Callable[[str], None]:
    """Pass recording lines on, and a preparation line at most every ``every`` seconds."""
    last = -math.inf

    def say(line: str) -> None:
        nonlocal last
        now = time.perf_counter()
        if "recording" in line or now - last >= every:
            last = now
            progress(line)

    return say


def _mean(rows: list[dict[str, Any]], key: str) -> float:
    values = [float(r[key]) for r in rows if _finite(r.get(key))]
    return float(np.mean(values)) if values else math.nan


def _max(rows: list[dict[str, Any]], key: str) -> float:
    values = [float(r[key]) for r in rows if _finite(r.get(key))]
    return max(values) if values else math.nan


def _finite(value: object) -> bool:
    try:
        return math.isfinite(float(value))  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return False


def _fmt(value: object, spec: str = ".0f") -> str:
    return format(float(value), spec) if _finite(value) else "-"  # type: ignore[arg-type]


STUDY = study.register(
    study.Study(
        "table1",
        "bench",
        Settings,
        run,
        help="The seed's Table 1: iterations and time per step against N, dt and eps.",
        outputs=("table1", "table1_summary"),
    )
)
