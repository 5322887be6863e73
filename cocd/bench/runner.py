"""Run one backend on one step problem and turn the outcome into a table row.

Every harness command goes through :func:`solve_row` (in process) or a
:class:`Worker` (a child process with a wall-clock limit and a memory cap), so
that all backends are timed by the same clock and judged by the same residuals
(:mod:`cocd.residuals`), and a backend that crashes, runs out of memory or
overruns its time is a row saying so, never a crash of the harness.

Row columns (:data:`ROW_COLUMNS`): ``solver``, ``formulation``, ``status``
(the shared vocabulary of :class:`solvers.Status`, plus ``time_limit`` when the
child was killed and ``error`` when the backend raised), ``iterations``,
``setup_s``, ``solve_s`` (the backend's own set-up and solve times),
``wall_s`` (the whole call, set-up and refinement included), ``ccp_residual``,
``coulomb_residual``, ``dynamics_residual``, ``u_error``, ``polished``,
``note``. Rows without an answer carry NaN residuals. Rows from a
:class:`Worker` also carry ``peak_rss_gib``, the child's peak resident memory.

Besides the columns, an answered row holds ``phases``: seconds by phase of the
call, from the backend's own clocks where it keeps them (``ipm``: ``setup``,
``assemble``, ``factor``, ``solve``, ``check``, ``polish``), otherwise only
``setup``; ``other`` is the rest of ``wall_s``. ``factorisations`` and
``linsolve`` are those an interior point reports (NaN and "" otherwise); ``solves``
the native solves made to reach the tolerance (1 without refinement).
"""

from __future__ import annotations

import os
import pickle
import resource
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

import solvers
from cocd.bench import schema
from cocd.bench.worker import Worker as ChildWorker
from cocd.problem import ConicProblem
from cocd.residuals import residuals

__all__ = [
    "ROW_COLUMNS",
    "SHORT_SOLVE_REPEATS",
    "SHORT_SOLVE_S",
    "Worker",
    "solve_row",
    "u_error",
    "warmup_problem",
]

FloatArray = NDArray[np.float64]

#: A solve whose first run takes under ``SHORT_SOLVE_S`` seconds is run again, up to
#: ``SHORT_SOLVE_REPEATS`` runs in all, and its median time is kept: a single run of tens
#: of microseconds is as much the state of the caches as the solver (``cocd bench
#: peers``, both sides alike).
SHORT_SOLVE_S = 0.01
SHORT_SOLVE_REPEATS = 5

ROW_COLUMNS = [
    "solver",
    "formulation",
    *schema.SOLVE_COLUMNS,
    "dynamics_residual",
    "u_error",
    "polished",
    "note",
]


def warmup_problem(dim: int, dt: float = 1e-3) -> ConicProblem:
    """Three grains stacked on the floor: a tiny frictional problem that loads a
    backend's code (imports, compiled kernels) before it is timed."""
    from cocd.builders import stack
    from cocd.contacts import detect_contacts
    from cocd.problem import assemble

    scene = stack(3, dim=dim, mu=0.3)
    return assemble(scene, detect_contacts(scene), dt)


def u_error(problem: ConicProblem, u: FloatArray, ref_u: FloatArray) -> float:
    """``||u - u_ref|| / max(||u_ref||, ||U||)``: a velocity error that stays defined at rest."""
    scale = max(float(np.linalg.norm(ref_u)), float(np.linalg.norm(problem.U)), 1e-300)
    return float(np.linalg.norm(np.asarray(u) - ref_u) / scale)


def _empty_row(solver: str) -> dict[str, Any]:
    """A row of :data:`ROW_COLUMNS` for ``solver`` before its answer (an unknown name is an
    ``error`` row)."""
    row: dict[str, Any] = {c: np.nan for c in ROW_COLUMNS}
    row.update(solver=solver, polished=False, note="")
    try:
        row["formulation"] = solvers.get(solver).formulation
    except Exception as exc:
        row.update(status="error", note=f"{type(exc).__name__}: {exc}")
    return row


def solve_row(
    problem: ConicProblem,
    solver: str,
    tol: float,
    *,
    warm_start: FloatArray | None = None,
    time_limit: float | None = None,
    max_iter: int | None = None,
    ref_u: FloatArray | None = None,
    keep_solution: bool = False,
) -> dict[str, Any]:
    """Solve ``problem`` with ``solver`` in this process; one row of :data:`ROW_COLUMNS`.

    Exceptions raised by the backend become ``status = "error"`` rows. With
    ``keep_solution`` the row also holds ``u`` and ``p`` (not table columns).
    """
    row = _empty_row(solver)
    if row["status"] == "error":
        return row
    start = time.perf_counter()
    try:
        sol = solvers.solve(
            problem,
            solver,
            tol=tol,
            warm_start=warm_start if solvers.get(solver).warm_start else None,
            time_limit=time_limit,
            max_iter=max_iter,
        )
    except MemoryError:
        row.update(status="error", note="out of memory", wall_s=time.perf_counter() - start)
        return row
    except Exception as exc:  # a backend failure is a row, not a crash
        row.update(
            status="error",
            note=f"{type(exc).__name__}: {str(exc)[:300]}",
            wall_s=time.perf_counter() - start,
        )
        return row
    wall = time.perf_counter() - start
    attempts = sol.extras.get("attempts", [])
    phases = {"setup": float(sol.setup_time)}
    phases.update({str(k): float(v) for k, v in (sol.extras.get("times") or {}).items()})
    phases["other"] = max(0.0, wall - sum(phases.values()))
    row.update(
        phases=phases,
        factorisations=float(sol.extras.get("factorisations", np.nan)),
        linsolve=str(sol.extras.get("linsolve", "")),
        status=sol.status.value,
        iterations=sol.iterations,
        setup_s=sol.setup_time,
        solve_s=sol.solve_time,
        wall_s=wall,
        polished=bool(any(a[3] for a in attempts)) if attempts else False,
        solves=len(attempts) if attempts else 1,
        note=str(sol.extras.get("approximation", "")),
    )
    # max_iter and time_limit answers carry impulses too: their residuals say how
    # far the backend got.
    if _usable(problem, sol.u, sol.p):
        res = residuals(problem, sol.u, sol.p)
        row.update(
            ccp_residual=res.ccp,
            coulomb_residual=res.coulomb,
            dynamics_residual=res.dynamics,
        )
        if ref_u is not None:
            row["u_error"] = u_error(problem, sol.u, ref_u)
    if keep_solution:
        row["u"], row["p"] = sol.u, sol.p
    return row


def _usable(problem: ConicProblem, u: Any, p: Any) -> bool:
    if u is None or p is None:
        return False
    u, p = np.asarray(u), np.asarray(p)
    return (
        u.size == problem.ndof
        and p.size == problem.nc * problem.contact_dim
        and bool(np.all(np.isfinite(u)))
        and bool(np.all(np.isfinite(p)))
    )


_LOADED: dict[str, Any] = {}  # the child's last problem, by path


def _solve_job(emit: Any, path: str, kwargs: dict[str, Any]) -> dict[str, Any]:
    """Child process: one row for the problem pickled at ``path`` (kept loaded)."""
    if _LOADED.get("path") != path:
        _LOADED.clear()  # free the previous problem before loading the next
        with open(path, "rb") as f:
            _LOADED.update(path=path, problem=pickle.load(f))
    row = solve_row(_LOADED["problem"], **kwargs)
    # The child's peak resident memory so far (Linux reports KiB).
    row["peak_rss_gib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    return row


class Worker:
    """Solves step problems in a child process (:class:`cocd.bench.worker.Worker`).

    A job that overruns ``1.5 * time_limit + grace`` seconds kills the child,
    which is restarted for the next job; the row says ``time_limit``. Problems
    are handed over as pickles on disk (written once per problem by
    :meth:`solve_row`) and the child keeps the last one loaded.

    Use as a context manager::

        with Worker(memory_gb=12) as worker:
            row = worker.solve_row(problem, "clarabel", 1e-8, time_limit=60)
    """

    def __init__(self, memory_gb: float | None = None, grace: float = 30.0) -> None:
        self.memory_gb = memory_gb
        self.grace = grace
        self._child = ChildWorker(memory_gb)
        self._dir = tempfile.TemporaryDirectory(prefix="cocd-bench-")
        self._paths: dict[int, str] = {}
        self._problems: list[ConicProblem] = []

    def __enter__(self) -> Worker:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Stop the child and delete the problem files."""
        self.restart()
        self._dir.cleanup()

    def restart(self) -> None:
        """Stop the child (a new one starts with the next job): its peak memory starts afresh."""
        self._child.close()

    def _path(self, problem: ConicProblem) -> str:
        key = id(problem)
        if key not in self._paths:
            path = Path(self._dir.name) / f"problem-{len(self._paths)}.pkl"
            with open(path, "wb") as f:
                pickle.dump(problem, f, protocol=pickle.HIGHEST_PROTOCOL)
            self._paths[key] = str(path)
            # Held so that its id is not reused by another problem while this worker lives.
            self._problems.append(problem)
        return self._paths[key]

    def solve_row(
        self, problem: ConicProblem, solver: str, tol: float, **options: Any
    ) -> dict[str, Any]:
        """As :func:`solve_row` (``options``: its keywords), in the child process; never
        raises for a backend failure.

        Each problem is written to disk once per worker (keyed by identity) and
        kept alive by the worker until :meth:`close`.
        """
        time_limit = options.get("time_limit")
        limit = None if time_limit is None else 1.5 * time_limit + self.grace
        job = dict(solver=solver, tol=tol, **options)
        outcome = self._child.run(_solve_job, self._path(problem), job, limit=limit)
        row = _empty_row(solver)
        if outcome.status == "done":
            row.update(outcome.result)
        else:
            row.update(status=outcome.status, note=outcome.note, wall_s=outcome.elapsed)
        return row


def default_memory_gb() -> float:
    """Three quarters of the machine's memory, for a child's cap."""
    try:
        pages = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        return 0.75 * pages / 2**30
    except (ValueError, OSError):
        return 12.0
