"""``cocd bench precision``: speed against error (work-precision diagrams and profiles).

Every backend sweeps a list of tolerances on the same step problems, cold and
warm-started, and each run is placed by what it achieved (the framework's
``ccp_residual`` and ``u_error``, :mod:`cocd.residuals`) against what it cost
(wall-clock seconds), never by the tolerance it was asked.

Problems
--------
``column-2d``
    :func:`~cocd.builders.column_2d` with ``n2d`` discs, ``dt = 1e-3`` s, the
    step that starts at ``t = 0.05`` s: the column is collapsing, many contacts
    slide (the degenerate case for interior points).
``box-3d``
    :func:`~cocd.builders.box_3d` with ``n3d`` spheres, ``dt = 1e-2`` s (the
    seed's 3D time step), the step that starts at ``t = 0.1`` s: the lattice
    has fallen onto the floor and is settling; about 3.5 contacts per sphere
    (715 contacts for 200 spheres), most of them sticking.

Each is recorded with :func:`~cocd.bench.states.record_steps` (two steps, so
that the second, the one used, has the first one's impulses as a warm start).
Each problem is an instance twice: ``cold`` and ``warm`` (warm start given to
the backends that use one; the others' cold runs stand for them on the warm
instance, marked ``no warm start`` in the plots).

Reference
---------
Clarabel at ``tol = 1e-10`` in this process (with the refinement and polishing
of :mod:`solvers.refine`). When its own ``ccp_residual`` is above ``1e-9``
(Clarabel's primal stalls near 1e-8 on the 3D box), ``clarabel-dual`` and then
``scs-dual`` are tried at the same tolerance and the most accurate answer is
kept; the outputs name the reference's backend and its ``ccp_residual``, and
say so when even the best is above ``1e-9``. ``u_error`` is measured against
the reference's velocity.

Outputs (under ``out``)
-----------------------
``precision.csv``
    One row per run, timed-out sweeps' skipped tolerances included.
``precision_<problem>.png``
    Work-precision diagrams: wall time against ``ccp_residual`` (top) and
    ``u_error`` (bottom), cold and warm panels, one curve per backend.
``precision_profile.png``
    Dolan-Moré performance profiles for the targets ``ccp_residual <= 1e-4,
    1e-6, 1e-8``.
``precision_sgm.csv``, ``precision_sgm.md``
    Shifted geometric mean (shift :data:`SGM_SHIFT` s) of the time to reach each
    target; an instance not reached within the time limit counts as the time
    limit.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

import solvers as backends
from cocd.bench import estimate, select_solvers, study
from cocd.bench.metrics import (
    SGM_SHIFT,
    costs_to_target,
    performance_profile,
    performance_ratios,
    sgm_table,
    shifted_geometric_mean,
)
from cocd.bench.report import throttled, write_meta, write_table
from cocd.bench.results import Results
from cocd.bench.runner import ROW_COLUMNS, Worker, default_memory_gb, warmup_problem
from cocd.bench.states import StepSequence, record_steps
from cocd.bench.study import StudySettings, option
from cocd.builders import box_3d, column_2d
from cocd.errors import CocdError
from cocd.problem import ConicProblem
from cocd.residuals import ccp_residual
from cocd.scene import Scene
from cocd.studies._plots import STARTS, TARGETS, plot_precision, plot_profiles

__all__ = [
    "COLUMNS",
    "REFERENCE_TOL",
    "SGM_SHIFT",
    "TARGETS",
    "costs_to_target",
    "performance_profile",
    "performance_ratios",
    "run",
    "sgm_table",
    "shifted_geometric_mean",
]

FloatArray = NDArray[np.float64]

#: The reference answer's tolerance, and the accuracy it must reach to be
#: trusted as the zero of ``u_error``.
REFERENCE_TOL = 1e-10
REFERENCE_OK = 1e-9
#: Tried in turn, at ``REFERENCE_TOL``, when Clarabel's answer is not within
#: ``REFERENCE_OK``: on 3D problems Clarabel's primal can stall near 1e-8,
#: where the dual formulations (interior point, then ADMM) still converge.
REFERENCE_FALLBACKS = ("clarabel-dual", "scs-dual")

#: Leading columns of ``precision.csv``; the runner's columns follow.
COLUMNS = ["problem", "dim", "N", "Nc", "dt", "start", "solver", "tol"] + [
    c for c in ROW_COLUMNS if c != "solver"
]

#: What names a row of ``precision.csv``.
KEY = ("problem", "N", "solver", "start", "tol")

#: Runs whose child was killed, i.e. the next job starts in a fresh process.
_KILLED = ("killed", "child exited")


@dataclass(frozen=True)
class _Case:
    """How a benchmark problem is made: scene, time step, start time."""

    label: str
    dim: int
    make: Callable[[], Scene]
    dt: float
    t_start: float


@dataclass
class _Instance:
    """One step problem with its reference answer."""

    label: str
    dim: int
    n_free: int
    dt: float
    problem: ConicProblem
    warm_start: FloatArray | None
    ref_u: FloatArray
    ref_ccp: float
    ref_solver: str
    #: Two copies of ``problem`` with no cached data, alternated between jobs.
    copies: tuple[ConicProblem, ConicProblem]


def with_cold_runs_as_warm(rows: pd.DataFrame, warm_capable: set[str]) -> pd.DataFrame:
    """Add, for backends that ignore a warm start, their cold runs as warm ones.

    Such a backend would do exactly the same work on the warm instance, so its
    cold runs stand for it there (instead of running it twice).
    """
    cold = rows[(rows["start"] == "cold") & ~rows["solver"].isin(warm_capable)].copy()
    cold["start"] = "warm"
    return pd.concat([rows, cold], ignore_index=True)


# -- the command --------------------------------------------------------------
@dataclass(frozen=True)
class Settings(StudySettings):
    """The options of ``cocd bench precision``."""

    solvers: str | None = study.solvers()
    tols: tuple[float, ...] = option(
        (1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9),
        "Comma-separated tolerances swept by each solver.",
        kind="floats",
    )
    n2d: int = option(2000, "Discs in the 2D column.")
    n3d: int = option(1000, "Spheres in the 3D box.")
    time_limit: float = study.time_limit(300.0)
    memory_gb: float | None = study.memory_gb()
    resume: bool = study.resume("precision")


def run(cfg: Settings, *, out: Path, progress: Callable[[str], None] = print) -> pd.DataFrame:
    """Sweep ``tols`` with every backend on the 2D and 3D problems; write tables and plots.

    Returns
    -------
    DataFrame
        The rows of ``precision.csv``.
    """
    tol_list = _check(cfg.tols, cfg.n2d, cfg.n3d)
    cases = _cases(cfg.n2d, cfg.n3d)
    chosen = {case.label: select_solvers(cfg.solvers, case.dim) for case in cases}
    if not any(chosen.values()):
        raise CocdError(
            f"none of the solvers {cfg.solvers!r} handles the requested problems "
            f"(n2d = {cfg.n2d}, n3d = {cfg.n3d})"
        )
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    sizes = {"column-2d": cfg.n2d, "box-3d": cfg.n3d}
    estimate.announce(
        "precision",
        [
            # The trajectory to the problem, then each backend's sweep, cold and warm.
            (sizes[c.label], round(c.t_start / c.dt) + 2 * len(chosen[c.label]) * len(tol_list))
            for c in cases
            if chosen[c.label]
        ],
        out=out,
        progress=progress,
    )

    instances: list[_Instance] = []
    warmups: dict[int, ConicProblem] = {}
    for case in cases:
        if not chosen[case.label]:
            progress(f"{case.label}: no selected solver handles {case.dim}D problems, skipped")
            continue
        instances.append(_instance(case, progress))
        warmups[case.dim] = warmup_problem(case.dim)

    # Every row of an earlier run is kept with --resume; this run's replace theirs.
    kept = Results(out / "precision.csv", COLUMNS, resume=cfg.resume, key=KEY)
    rows: list[dict[str, Any]] = []
    plan = [(i, n, s) for i in instances for n in chosen[i.label] for s in _starts(i, n)]
    total, count = len(plan) * len(tol_list), 0
    memory = default_memory_gb() if cfg.memory_gb is None else cfg.memory_gb
    with Worker(memory_gb=memory) as worker:
        jobs = _Jobs(worker, cfg.time_limit)
        for inst, name, start in plan:
            timed_out_at: float | None = None
            for tol in tol_list:
                count += 1
                base = {
                    "problem": inst.label,
                    "dim": inst.dim,
                    "N": inst.n_free,
                    "Nc": inst.problem.nc,
                    "dt": inst.dt,
                    "start": start,
                    "tol": tol,
                }
                earlier = kept.get(inst.label, inst.n_free, name, start, tol)
                if earlier is not None:
                    row = {k: v for k, v in earlier.items() if k not in base}
                    if _timed_out(row, cfg.time_limit):
                        timed_out_at = tol
                elif timed_out_at is not None:
                    row = _skipped(name, f"timed out at tol {timed_out_at:g}")
                else:
                    jobs.warm_up(name, warmups[inst.dim], tol_list[0])
                    warm = inst.warm_start if start == "warm" else None
                    row = jobs.solve(inst, name, tol, warm)
                    if _timed_out(row, cfg.time_limit):
                        timed_out_at = tol
                rows.append({**base, **row})
                kept.add(rows[-1], save=False)
                said = " (kept from the earlier table)" if earlier is not None else ""
                progress(f"[{count}/{total}] {_describe(rows[-1])}{said}")
            # Written after every sweep: a run of an hour that is stopped keeps its rows.
            kept.save()

    files = [kept.save()]
    # What follows is this run's: the rows of its problems, backends and tolerances.
    table = pd.DataFrame(rows, columns=COLUMNS)

    names = list(dict.fromkeys(n for i in instances for n in chosen[i.label]))
    warm_capable_set = {n for n in names if backends.get(n).warm_start}
    analysed = with_cold_runs_as_warm(table, warm_capable_set)
    keys = [(i.label, s) for i in instances for s in STARTS]
    costs = {
        target: costs_to_target(analysed, target, keys, names, cfg.time_limit) for target in TARGETS
    }
    sgm = _sgm_by_problems(analysed, instances, chosen, names, cfg.time_limit)
    for inst in instances:
        files.append(plot_precision(analysed, inst, names, warm_capable_set, out))
    files.append(plot_profiles(costs, names, len(keys), out))

    intro = _intro(instances, names, cfg.time_limit)
    title = "Speed against error: work-precision, performance profiles, geometric means"
    files += write_table(out, "precision_sgm", sgm, title=title, intro=intro)
    summary = intro + "\n\n" + sgm.to_markdown(index=False, floatfmt=".3g")
    write_meta(out, "precision", title=title, files=files, summary=summary)
    progress(f"precision: {len(table)} rows in {time.perf_counter() - started:.0f} s")
    progress(sgm.to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    return table


# -- pieces of run ------------------------------------------------------------
def _sgm_by_problems(
    rows: pd.DataFrame,
    instances: Sequence[_Instance],
    chosen: dict[str, list[str]],
    names: Sequence[str],
    time_limit: float,
) -> pd.DataFrame:
    """Shifted geometric means over every instance (``problems = "all"``) and, when
    both dimensions are there, over each dimension's instances with only the
    backends that take them (a 2D-only backend is not charged for 3D there)."""
    groups = [("all", list(instances), list(names))]
    dims = sorted({i.dim for i in instances})
    if len(dims) > 1:
        for dim in dims:
            insts = [i for i in instances if i.dim == dim]
            who = [n for n in names if any(n in chosen[i.label] for i in insts)]
            groups.append((f"{dim}D", insts, who))
    tables = []
    for label, insts, who in groups:
        keys = [(i.label, s) for i in insts for s in STARTS]
        costs = {t: costs_to_target(rows, t, keys, who, time_limit) for t in TARGETS}
        tables.append(sgm_table(costs, who, time_limit).assign(problems=label))
    table = pd.concat(tables, ignore_index=True)
    return table[["problems", *[c for c in table.columns if c != "problems"]]]


def _check(tols: Sequence[float], n2d: int, n3d: int) -> list[float]:
    try:
        values = [float(t) for t in tols]
    except (TypeError, ValueError):
        raise CocdError(f"tols must be numbers, got {tols!r}") from None
    if not values:
        raise CocdError("tols is empty: give at least one tolerance, e.g. 1e-4,1e-8")
    bad = [t for t in values if not (math.isfinite(t) and t > 0.0)]
    if bad:
        raise CocdError(f"tolerances must be finite and > 0, got {bad[0]!r} in {list(tols)!r}")
    for name, n in (("n2d", n2d), ("n3d", n3d)):
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
            raise CocdError(f"{name} must be an integer >= 0 (0 skips it), got {n!r}")
    if n2d == 0 and n3d == 0:
        raise CocdError("n2d and n3d are both 0: nothing to run")
    # Loosest first: a sweep stops at the first time-out, and tighter
    # tolerances would only take longer.
    return sorted(set(values), reverse=True)


def _cases(n2d: int, n3d: int) -> list[_Case]:
    cases = []
    if n2d > 0:
        cases.append(_Case("column-2d", 2, partial(column_2d, int(n2d)), 1e-3, 0.05))
    if n3d > 0:
        cases.append(_Case("box-3d", 3, partial(box_3d, int(n3d)), 1e-2, 0.1))
    return cases


def _instance(case: _Case, progress: Callable[[str], None]) -> _Instance:
    """Record the case's steps and solve the second one to the reference accuracy."""
    seq: StepSequence = record_steps(
        f"precision-{case.label}",
        case.make,
        dt=case.dt,
        t_start=case.t_start,
        n_steps=2,
        progress=throttled(progress, 5.0),
    )
    problem = seq.problems[-1]
    progress(
        f"{case.label}: N = {seq.n_free}, Nc = {problem.nc}, t = {seq.t_start + case.dt:.3f} s"
    )
    ref = _reference(problem, case.label, progress)
    return _Instance(
        label=case.label,
        dim=case.dim,
        n_free=seq.n_free,
        dt=case.dt,
        problem=problem,
        warm_start=seq.warm_starts[-1],
        ref_u=ref.u,
        ref_ccp=ref.ccp,
        ref_solver=ref.solver,
        copies=(_pristine(problem), _pristine(problem)),
    )


@dataclass
class _Reference:
    u: FloatArray
    ccp: float
    solver: str


def _reference(problem: ConicProblem, label: str, progress: Callable[[str], None]) -> _Reference:
    """Clarabel at ``REFERENCE_TOL``; if not within ``REFERENCE_OK``, the best of the fallbacks."""
    available = set(backends.available())
    best: _Reference | None = None
    for name in ("clarabel", *REFERENCE_FALLBACKS):
        if name not in available:
            continue
        start = time.perf_counter()
        try:
            sol = backends.solve(problem, name, tol=REFERENCE_TOL)
        except CocdError as exc:
            progress(f"{label}: reference {name} failed: {exc}")
            continue
        elapsed = time.perf_counter() - start
        if not sol.found:
            progress(f"{label}: reference {name}: {sol.status.value}, {elapsed:.2f} s")
            continue
        ccp = ccp_residual(problem, sol.p)
        progress(
            f"{label}: reference {name} at tol {REFERENCE_TOL:g}: {sol.status.value}, "
            f"ccp_residual {ccp:.2g}, {elapsed:.2f} s"
        )
        if best is None or ccp < best.ccp:
            best = _Reference(np.asarray(sol.u, dtype=np.float64), ccp, name)
        if best.ccp <= REFERENCE_OK:
            break
    if best is None:
        raise CocdError(f"{label}: no reference answer (clarabel and its fallbacks failed)")
    if best.ccp > REFERENCE_OK:
        progress(
            f"{label}: WARNING: the best reference ({best.solver}) has ccp_residual "
            f"{best.ccp:.2g} > {REFERENCE_OK:g}; u_error below about that is not meaningful"
        )
    return best


def _pristine(problem: ConicProblem) -> ConicProblem:
    """A copy without the lazily cached data (``W``, scales, ...) a solve leaves behind.

    Every timed run must build its own data, so that the order in which
    backends run does not decide which of them pays for ``W``.
    """
    return ConicProblem(
        dim=problem.dim,
        contact_dim=problem.contact_dim,
        mass=problem.mass.copy(),
        H=problem.H.copy(),
        D=problem.D.copy(),
        mu=problem.mu.copy(),
        dt=problem.dt,
        U=problem.U.copy(),
        slip_offset=None if problem.slip_offset is None else problem.slip_offset.copy(),
        delassus_shift=problem.delassus_shift,
    )


class _Jobs:
    """Timed runs in one :class:`Worker`, each on a freshly loaded problem.

    The worker keeps the last problem it loaded, with whatever a backend
    cached in it. Alternating two pristine copies makes it load every job's
    problem afresh. A backend is first run once, untimed, on a tiny problem in
    the current child process, so that its timed runs do not include importing
    modules or loading compiled kernels.
    """

    def __init__(self, worker: Worker, time_limit: float) -> None:
        self.worker = worker
        self.time_limit = time_limit
        self.warmed: set[str] = set()
        self.last: int | None = None

    def warm_up(self, name: str, problem: ConicProblem, tol: float) -> None:
        if name in self.warmed:
            return
        row = self.worker.solve_row(problem, name, tol, time_limit=self.time_limit)
        self.last = id(problem)
        self._note(row)
        self.warmed.add(name)

    def solve(
        self, inst: _Instance, name: str, tol: float, warm_start: FloatArray | None
    ) -> dict[str, Any]:
        copy = inst.copies[0] if id(inst.copies[0]) != self.last else inst.copies[1]
        row = self.worker.solve_row(
            copy,
            name,
            tol,
            warm_start=warm_start,
            time_limit=self.time_limit,
            ref_u=inst.ref_u,
        )
        self.last = id(copy)
        self._note(row)
        return row

    def _note(self, row: dict[str, Any]) -> None:
        # A killed child is replaced by a fresh one: nothing is loaded there.
        if str(row.get("note", "")).startswith(_KILLED):
            self.warmed.clear()
            self.last = None


def _starts(inst: _Instance, name: str) -> list[str]:
    """Cold always; warm only for a backend that uses a warm start, when there is one."""
    if backends.get(name).warm_start and inst.warm_start is not None:
        return list(STARTS)
    return ["cold"]


def _timed_out(row: dict[str, Any], time_limit: float) -> bool:
    wall = row.get("wall_s", np.nan)
    return row.get("status") == "time_limit" or bool(np.isfinite(wall) and wall >= time_limit)


def _skipped(name: str, why: str) -> dict[str, Any]:
    row: dict[str, Any] = {c: np.nan for c in ROW_COLUMNS}
    try:
        formulation = backends.get(name).formulation
    except CocdError:
        formulation = ""
    row.update(solver=name, formulation=formulation, status="skipped", polished=False, note=why)
    return row


def _describe(row: dict[str, Any]) -> str:
    text = f"{row['problem']} {row['start']} {row['solver']} tol {row['tol']:g}: {row['status']}"
    if np.isfinite(row.get("wall_s", np.nan)):
        text += f", {row['wall_s']:.3g} s"
    if np.isfinite(row.get("ccp_residual", np.nan)):
        text += f", ccp {row['ccp_residual']:.2g}, u_error {row['u_error']:.2g}"
    if row.get("note"):
        text += f" ({row['note']})"
    return text


def _intro(instances: Sequence[_Instance], names: Sequence[str], time_limit: float) -> str:
    lines = []
    for inst in instances:
        flag = (
            ""
            if inst.ref_ccp <= REFERENCE_OK
            else f" (**worse than {REFERENCE_OK:g}**: u_error below about that is not meaningful)"
        )
        lines.append(
            f"- `{inst.label}`: {inst.dim}D, N = {inst.n_free}, Nc = {inst.problem.nc}, "
            f"dt = {inst.dt:g} s; reference {inst.ref_solver} at tol {REFERENCE_TOL:g}, "
            f"ccp_residual {inst.ref_ccp:.2g}{flag}"
        )
    return (
        "Time to reach `ccp_residual <= target` on each (problem, cold/warm start) instance: "
        "the fastest run of the tolerance sweep that reached it. `sgm_s` is the shifted "
        f"geometric mean over instances, shift {SGM_SHIFT:g} s; an instance not reached within "
        f"the time limit ({time_limit:g} s) counts as the time limit, as does one a backend "
        "cannot take in the `all` rows; the `2D` and `3D` rows compare, on each dimension's "
        "instances, the backends that take them. "
        "`sgm_rel` is over the best solver's (1.0). Backends without a warm start "
        "count their cold runs on the warm instance. Each time is one run (not the best of "
        "several), runs made one at a time."
        + _nonconvex_note(names)
        + " Problems:\n\n"
        + "\n".join(lines)
    )


def _nonconvex_note(names: Sequence[str]) -> str:
    other = [n for n in names if not backends.get(n).convex]
    if not other:
        return ""
    return (
        f" {', '.join(other)} solve{'s' if len(other) == 1 else ''} the non-convex Coulomb law, "
        "another problem: their `ccp_residual` stops at the distance between the two answers "
        "(their `coulomb_residual` is in `precision.csv`)."
    )


STUDY = study.register(
    study.Study(
        "precision",
        "bench",
        Settings,
        run,
        help="Speed against error: work-precision plots, performance profiles, geometric means.",
        outputs=("precision",),
    )
)
