"""``cocd bench hard``: every backend on every hard case of :data:`cocd.builders.HARD_CASES`.

Each hard case (a heavy grain on light ones, a tall stack, a jammed crystal,
a wedged grain, a fast impact, a size ratio, zero gaps; see each builder's
docstring for what it stresses) is stepped ``steps`` times by each backend
that handles its dimension (:func:`cocd.bench.select_solvers`), with a
:class:`~cocd.stepper.Stepper` in a child process under a memory cap and a
wall-clock limit, so that a backend that crashes, hangs or runs out of memory
is a row saying so, never a crash of the harness.

Columns (:data:`COLUMNS`)
    ``case``, ``dim``, ``dt``, ``N`` (free grains), ``Nc`` (most contacts in a
    step), ``solver``, ``status``, ``steps_done``, ``iterations`` (mean),
    ``wall_s`` (mean wall time of the backend's solve call, set-up
    included, detection not), ``ccp_residual``, ``coulomb_residual``,
    ``dynamics_residual`` (largest over the steps done, :mod:`cocd.residuals`),
    ``energy_drift`` and ``note``. The matrix and the heatmap judge a
    non-convex backend (``nscd``, ``fp``) by its ``coulomb_residual``.

Time step
    :data:`DEFAULT_DT` (1 ms), unless the case's builder takes a ``dt``
    argument, in which case the value the case was built with is used
    (:func:`case_dt`): ``fast_impact`` throws its projectile at
    ``speed_ratio * radius / dt`` so that it moves ``speed_ratio`` radii per
    step *with that dt*; stepping it with another dt would be another case.

Status
    ``ok`` when every step was ``optimal``. Otherwise, when the stepping
    stopped early, why: the backend's status (``max_iter``, ``time_limit``,
    ``infeasible``, ``error``), ``time_limit`` when the child was killed at
    ``1.5 * steps * time_limit + 30`` s, ``error`` when the backend raised or
    the child died (out of memory, a signal); ``note`` gives the message and
    the step reached. When every step was answered but some only
    ``inaccurate``, the status is ``inaccurate``.

Energy drift
    ``max_k (E_k - E_0) / E_scale`` over the steps taken, with
    ``E = E_kin + E_pot`` (translational and rotational kinetic energy,
    gravitational potential energy of the free grains) and
    ``E_scale = max(E_kin,0, sum_i m_i |g| d_i)``: the initial kinetic energy
    for a case thrown into motion (``fast_impact``), else the work needed to
    lift every grain by its own diameter, for a case starting at rest. The
    scale does not depend on the origin of the potential energy. Positive
    values are energy created; the step's contact model is dissipative, so a
    correct answer gives ``<= 0`` up to the backend's accuracy.
"""

from __future__ import annotations

import inspect
import math
import re
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

import solvers
from cocd.bench import estimate, select_solvers, study
from cocd.bench.report import write_meta, write_table
from cocd.bench.runner import default_memory_gb
from cocd.bench.study import StudySettings, option
from cocd.bench.worker import Worker, short
from cocd.builders import HARD_CASES
from cocd.errors import CocdError

__all__ = ["COLUMNS", "DEFAULT_DT", "case_dt", "energy_scale", "matrix_markdown", "run"]

#: Time step (s) of a hard case whose builder does not fix one.
DEFAULT_DT = 1e-3

#: Columns of ``hard.csv``, in order.
COLUMNS = [
    "case",
    "dim",
    "dt",
    "N",
    "Nc",
    "solver",
    "status",
    "steps_done",
    "iterations",
    "wall_s",
    "ccp_residual",
    "coulomb_residual",
    "dynamics_residual",
    "energy_drift",
    "note",
]

#: Letters marking failed cells in the heatmap.
_LETTERS = {
    "time_limit": "T",
    "error": "E",
    "max_iter": "M",
    "infeasible": "I",
}


def case_dt(name: str) -> float:
    """The time step (s) hard case ``name`` is meant to be stepped with.

    The ``dt`` its builder was made with (bound, or the builder's default)
    when the builder takes one, e.g. ``fast_impact``; else :data:`DEFAULT_DT`.
    """
    try:
        param = inspect.signature(HARD_CASES[name]).parameters.get("dt")
    except (TypeError, ValueError):
        param = None
    if param is None or param.default is inspect.Parameter.empty:
        return DEFAULT_DT
    return float(param.default)


def energy_scale(kinetic0: float, masses: Any, radii: Any, gravity: Any) -> float:
    """``max(E_kin,0, sum m |g| 2r)``: the energy the drift is measured against (see module)."""
    lift = float(np.sum(np.asarray(masses) * float(np.linalg.norm(gravity)) * 2.0 * radii))
    return max(float(kinetic0), lift, 1e-300)


# -- child process -----------------------------------------------------------
def _timed_solve(real: Callable[..., Any], clock: list[float]) -> Callable[..., Any]:
    """Wrap ``solvers.solve`` so that the stepper's solve calls are timed (wall)."""

    def solve(*args: Any, **kwargs: Any) -> Any:
        start = time.perf_counter()
        try:
            return real(*args, **kwargs)
        finally:
            clock.append(time.perf_counter() - start)

    return solve


def _warm_up(solver: str, dim: int, tol: float) -> None:
    """Solve the harness's warm-up problem once: imports the backend, loads compiled kernels."""
    import solvers as backends
    from cocd.bench.runner import warmup_problem

    try:
        backends.solve(warmup_problem(dim, DEFAULT_DT), solver, tol, time_limit=10.0)
    except Exception:
        pass  # the timed run will report whatever is wrong


_WARMED: set[tuple[str, int]] = set()  # (backend, dim) the child has loaded


def _run_job(emit: Callable[[Any], None], job: dict[str, Any]) -> dict[str, Any]:
    """Child process: step one case with one backend; a ``("start", ...)`` event, one
    ``("step", ...)`` event per step, and the end (status, note, steps done)."""
    from cocd.errors import SolverError
    from cocd.measure import kinetic_energy, potential_energy
    from cocd.stepper import Stepper

    step = 0
    try:
        scene = HARD_CASES[job["case"]]()
        free = scene.free
        ek0 = kinetic_energy(scene)
        emit(
            (
                "start",
                {
                    "N": scene.n_free,
                    "dim": scene.dim,
                    "E0": ek0 + potential_energy(scene),
                    "scale": energy_scale(
                        ek0, scene.masses[free], scene.radii[free], scene.gravity
                    ),
                },
            )
        )
        if (job["solver"], scene.dim) not in _WARMED:
            _warm_up(job["solver"], scene.dim, job["tol"])
            _WARMED.add((job["solver"], scene.dim))
        clock: list[float] = []
        real = solvers.solve
        solvers.solve = _timed_solve(real, clock)
        try:
            stepper = Stepper(
                scene,
                job["dt"],
                solver=job["solver"],
                tol=job["tol"],
                time_limit=job["time_limit"],
            )
            for step in range(1, job["steps"] + 1):
                clock.clear()
                record = stepper.step()
                emit(
                    (
                        "step",
                        {
                            "step": step,
                            "nc": record.nc,
                            "status": record.status,
                            "iterations": record.iterations,
                            "wall": clock[-1] if clock else math.nan,
                            "ccp": record.ccp_residual,
                            "coulomb": record.coulomb_residual,
                            "dynamics": record.dynamics_residual,
                            "E": record.kinetic_energy + record.potential_energy,
                        },
                    )
                )
        finally:
            solvers.solve = real
    except SolverError as exc:
        match = re.search(r"returned status (\w+)", str(exc))
        status = match.group(1) if match else "error"
        return {"status": status, "note": short(exc), "step": step}
    except MemoryError:
        return {"status": "error", "note": f"out of memory (cap {job['memory_gb']:g} GiB)",
                "step": step}  # fmt: skip
    except Exception as exc:
        return {"status": "error", "note": f"{type(exc).__name__}: {short(exc)}", "step": step}
    return {"status": None, "note": "", "step": job["steps"]}


def _run(worker: Worker, job: dict[str, Any], grace: float) -> tuple[dict, list[dict], dict]:
    """Run ``job`` in ``worker``: the start message, the step messages and the end."""
    job = {**job, "memory_gb": worker.memory_gb or math.inf}
    limit = 1.5 * job["steps"] * job["time_limit"] + grace
    outcome = worker.run(_run_job, job, limit=limit)
    head: dict[str, Any] = {}
    steps: list[dict[str, Any]] = []
    for kind, body in outcome.events:
        if kind == "start":
            head = body
        else:
            steps.append(body)
    if outcome.status == "done":
        return head, steps, outcome.result
    return head, steps, {"status": outcome.status, "note": outcome.note, "step": len(steps)}


# -- rows, matrix, plot ------------------------------------------------------
def _row(
    job: dict[str, Any], dim: int, head: dict, steps: list[dict[str, Any]], end: dict
) -> dict[str, Any]:
    row: dict[str, Any] = {c: np.nan for c in COLUMNS}
    row.update(
        case=job["case"],
        dim=dim,
        dt=job["dt"],
        N=head.get("N", np.nan),
        solver=job["solver"],
        steps_done=len(steps),
        note="",
    )
    if steps:
        df = pd.DataFrame(steps)
        drift = (df["E"] - head["E0"]) / head["scale"]
        row.update(
            Nc=int(df["nc"].max()),
            iterations=float(df["iterations"].mean()),
            wall_s=float(df["wall"].mean()),
            ccp_residual=float(df["ccp"].max()),
            coulomb_residual=float(df["coulomb"].max()),
            dynamics_residual=float(df["dynamics"].max()),
            energy_drift=float(drift.max()),
        )
    if end.get("status"):
        row["status"] = end["status"]
        note = str(end["note"])
        if not note.startswith("step "):  # the stepper's messages name the step already
            note = f"step {len(steps) + 1} of {job['steps']}: {note}"
        row["note"] = note
    else:
        bad = [s for s in steps if s["status"] != "optimal"]
        row["status"] = "ok" if not bad else bad[0]["status"]
        if bad:
            row["note"] = f"first at step {bad[0]['step']}"
    return row


def _measure(solver: str) -> str:
    """The residual a backend is judged by: the CCP's, or the Coulomb law's if non-convex."""
    try:
        return "ccp_residual" if solvers.get(solver).convex else "coulomb_residual"
    except CocdError:
        return "ccp_residual"


def _order(table: pd.DataFrame) -> tuple[list[str], list[str]]:
    cases = list(dict.fromkeys(table["case"]))
    names = list(dict.fromkeys(table["solver"]))
    return cases, names


def matrix_markdown(table: pd.DataFrame) -> str:
    """Cases x solvers: ``status residual`` (e.g. ``ok 3e-09``), ``-`` where not run.

    A backend that stopped the stepping shows its status and the step it
    failed on (``max_iter at step 3``).
    """
    cases, names = _order(table)
    lines = [
        "| case | " + " | ".join(names) + " |",
        "|---|" + "---|" * len(names),
    ]
    for case in cases:
        cells = []
        for name in names:
            hit = table[(table["case"] == case) & (table["solver"] == name)]
            if hit.empty:
                cells.append("-")
                continue
            r = hit.iloc[0]
            value = r[_measure(name)]
            if r["status"] not in ("ok", "inaccurate"):  # the stepping stopped there
                cells.append(f"{r['status']} at step {int(r['steps_done']) + 1}")
            elif np.isfinite(value):
                cells.append(f"{r['status']} {value:.0e}")
            else:
                cells.append(str(r["status"]))
        lines.append(f"| {case} | " + " | ".join(cells) + " |")
    nonconvex = [n for n in names if _measure(n) == "coulomb_residual"]
    lines.append("")
    lines.append(
        "Cell: status and the largest `ccp_residual` over the steps"
        + (f" (`coulomb_residual` for the non-convex {', '.join(nonconvex)})" if nonconvex else "")
        + "; a failure shows the step it stopped the stepping at"
        + "; `-`: the backend does not handle the case's dimension."
    )
    return "\n".join(lines)


def _heatmap(table: pd.DataFrame, path: Path, tol: float) -> Path:
    """log10 of each cell's residual; failed cells grey, hatched, with a letter."""
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle

    cases, names = _order(table)
    logs = np.full((len(cases), len(names)), np.nan)
    zero = np.zeros(logs.shape, dtype=bool)
    status: dict[tuple[int, int], str] = {}
    for i, case in enumerate(cases):
        for j, name in enumerate(names):
            hit = table[(table["case"] == case) & (table["solver"] == name)]
            if hit.empty:
                continue
            r = hit.iloc[0]
            status[i, j] = str(r["status"])
            value = float(r[_measure(name)])
            if status[i, j] not in ("ok", "inaccurate") or not np.isfinite(value):
                continue
            if value > 0:
                logs[i, j] = np.log10(value)
            else:
                zero[i, j] = True  # no contact, or an exact answer: shown at the floor
    finite = logs[np.isfinite(logs)]
    lo = min(float(finite.min()) if finite.size else -12.0, np.log10(tol) - 2.0)
    hi = max(float(finite.max()) if finite.size else 0.0, np.log10(tol) + 1.0)
    logs[zero] = lo

    fig = Figure(
        figsize=(max(6.0, 3.2 + 0.9 * len(names)), 1.8 + 0.36 * len(cases)), layout="constrained"
    )
    ax = fig.subplots()
    im = ax.imshow(logs, cmap="viridis", vmin=lo, vmax=hi, aspect="auto")
    for (i, j), st in status.items():
        if np.isfinite(logs[i, j]):
            rgba = im.cmap(im.norm(logs[i, j]))
            light = 0.299 * rgba[0] + 0.587 * rgba[1] + 0.114 * rgba[2] > 0.5
            text = "0" if zero[i, j] else f"{logs[i, j]:.1f}"
            text += "~" if st == "inaccurate" else ""
            ax.text(j, i, text, ha="center", va="center", fontsize=7, color="k" if light else "w")
            continue
        ax.add_patch(
            Rectangle(
                (j - 0.5, i - 0.5), 1, 1, facecolor="0.85", edgecolor="0.55", hatch="///", lw=0
            )
        )
        letter = _LETTERS.get(st, "?")
        ax.text(j, i, letter, ha="center", va="center", fontsize=9, weight="bold")
    labels = [n + (" (Coulomb)" if _measure(n) == "coulomb_residual" else "") for n in names]
    ax.set_xticks(range(len(names)), labels, rotation=35, ha="right", fontsize=8)
    ax.set_yticks(range(len(cases)), cases, fontsize=8)
    ax.set_xticks(np.arange(-0.5, len(names)), minor=True)
    ax.set_yticks(np.arange(-0.5, len(cases)), minor=True)
    ax.grid(which="minor", color="w", lw=1.5)
    ax.tick_params(which="minor", length=0)
    fig.colorbar(im, ax=ax, shrink=0.8).set_label("log10 residual")
    ax.set_title(
        f"Hard cases: largest residual over the steps, tol {tol:g}\n"
        "grey: failed (T time limit, E error, M max_iter, I infeasible); "
        "~ inaccurate; blank: not applicable",
        fontsize=9,
    )
    fig.savefig(path, dpi=130)
    return path


# -- the command ---------------------------------------------------------------
@dataclass(frozen=True)
class Settings(StudySettings):
    """The options of ``cocd bench hard``."""

    solvers: str | None = study.solvers()
    cases: tuple[str, ...] | None = option(
        None, "Comma-separated hard cases (default: all).", kind="names"
    )
    steps: int = option(5, "Steps per case.")
    tol: float = option(1e-6, "Tolerance asked of every solver.", positive=True)
    time_limit: float = study.time_limit(120.0)
    memory_gb: float | None = study.memory_gb()


def run(
    cfg: Settings, *, out: Path, progress: Callable[[str], None] = print, grace: float = 30.0
) -> pd.DataFrame:
    """Step every hard case with every backend; write ``hard.{csv,md,png}`` and the matrix.

    ``grace``: seconds added to the wall-clock limit (start-up of the child, detection).

    Returns
    -------
    pandas.DataFrame
        One row per case and backend, columns :data:`COLUMNS`.
    """
    names = list(HARD_CASES) if cfg.cases is None else list(cfg.cases)
    unknown = [c for c in names if c not in HARD_CASES]
    if unknown or not names:
        raise CocdError(
            f"unknown hard case(s) {', '.join(map(repr, unknown)) or '(none given)'}; "
            f"known: {', '.join(HARD_CASES)}"
        )
    if isinstance(cfg.steps, bool) or not isinstance(cfg.steps, int) or cfg.steps < 1:
        raise CocdError(f"steps must be an integer >= 1, got {cfg.steps!r}")
    memory = default_memory_gb() if cfg.memory_gb is None else float(cfg.memory_gb)

    scenes = {name: HARD_CASES[name]() for name in names}
    dims = {name: scene.dim for name, scene in scenes.items()}
    chosen = {d: select_solvers(cfg.solvers, d) for d in sorted(set(dims.values()))}
    if not any(chosen.values()):
        raise CocdError(
            f"none of the solvers {cfg.solvers!r} handles the {'/'.join(map(str, chosen))}D "
            "hard cases chosen"
        )
    estimate.announce(
        "hard",
        [(scene.n_free, cfg.steps * len(chosen[scene.dim])) for scene in scenes.values()],
        out=Path(out),
        progress=progress,
    )

    rows = []
    with Worker(memory) as worker:
        for case in names:
            dim = dims[case]
            for solver in chosen[dim]:
                job = dict(
                    case=case,
                    solver=solver,
                    steps=int(cfg.steps),
                    dt=case_dt(case),
                    tol=float(cfg.tol),
                    time_limit=float(cfg.time_limit),
                )
                start = time.perf_counter()
                head, records, end = _run(worker, job, grace)
                row = _row(job, dim, head, records, end)
                rows.append(row)
                progress(
                    f"{case:22s} {solver:14s} {row['status']:10s} "
                    f"{_measure(solver)[:-9]} {row[_measure(solver)]:.1e}  "
                    f"drift {row['energy_drift']:+.1e}  "
                    f"({time.perf_counter() - start:.1f} s)"
                )
    table = pd.DataFrame(rows, columns=COLUMNS)

    title = "Hard cases: every backend on every stress case"
    intro = (
        f"{cfg.steps} steps per case, tol {cfg.tol:g}, time limit {cfg.time_limit:g} s per solve. "
        "status: `ok` when every step was optimal; `N`: free grains; `Nc`: most contacts; "
        "residuals: largest over the steps; `wall_s`: mean solve wall time; "
        "`energy_drift`: largest (E - E0) / max(Ek0, sum m g d), positive = energy created."
    )
    files = write_table(out, "hard", table, title=title, intro=intro)
    matrix = matrix_markdown(table)
    matrix_path = out / "hard_matrix.md"
    matrix_path.write_text(f"# {title}: status and residual\n\n{matrix}\n")
    files.append(matrix_path)
    files.append(_heatmap(table, out / "hard.png", float(cfg.tol)))
    write_meta(out, "hard", title=title, files=files, summary=matrix)
    return table


STUDY = study.register(
    study.Study(
        "hard",
        "bench",
        Settings,
        run,
        help="Every solver on every hard case: status, iterations, time, residuals, energy drift.",
        outputs=("hard",),
    )
)
