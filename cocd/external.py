"""Solve external problems (FCLib, Siconos) with any backend and judge the answer.

A local or global problem (:mod:`cocd.io.problems`) is turned into a
:class:`~cocd.problem.ConicProblem`, solved by a registered backend, and the
answer is judged three ways: ``ccp_residual`` and ``coulomb_residual``
(cocd's scaled measures, DESIGN.md section 2) on the ConicProblem, and
``natural_map_error`` in the file's own terms, the number Siconos users quote.

Convex backends answer the cone complementarity problem (COCD); they reach a
small ``ccp_residual``, while the Coulomb law itself (``natural_map_error``)
holds only for the non-convex backends (``nscd``, ``fp:...``) and for
contacts that stick or separate.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

import solvers
from cocd.errors import CocdError, ProblemError
from cocd.io.problems import ExternalSolution, GlobalProblem, LocalProblem
from cocd.residuals import ccp_residual, coulomb_residual

__all__ = ["RECORD_KEYS", "describe", "judge", "not_applicable", "solve_external"]

ExternalProblem = LocalProblem | GlobalProblem

#: Keys of the record :func:`solve_external` returns (``cocd problem solve --json``).
RECORD_KEYS = [
    "problem",
    "kind",
    "dim",
    "nc",
    "ndof",
    "solver",
    "status",
    "iterations",
    "setup_s",
    "solve_s",
    "ccp_residual",
    "coulomb_residual",
    "natural_map_error",
    "note",
]


def describe(problem: ExternalProblem) -> dict[str, Any]:
    """Sizes and properties of a problem (``cocd problem info``)."""
    out: dict[str, Any] = {
        "problem": problem.name,
        "source": problem.source,
        "kind": problem.kind,
        "dim": problem.dim,
        "nc": problem.nc,
        "ndof": problem.ndof,
        "mu_min": float(problem.mu.min()) if problem.nc else None,
        "mu_max": float(problem.mu.max()) if problem.nc else None,
        "norm_q": float(np.linalg.norm(problem.q)),
    }
    if isinstance(problem, GlobalProblem):
        out["M_nnz"] = int(problem.M.nnz)
        out["H_nnz"] = int(problem.H.nnz)
        out["M_diagonal"] = problem.mass_is_diagonal
    local = problem.local()
    out["W_nnz"] = int(local.W.nnz)
    out["W_symmetry_error"] = local.symmetry_error()
    if isinstance(problem, LocalProblem):
        try:
            out["delassus_shift"] = problem.shift
        except ProblemError as exc:
            out["solvable"] = f"no: {str(exc).split(': ', 1)[-1]}"
    if problem.title:
        out["title"] = problem.title
    if problem.description:
        out["description"] = " ".join(problem.description.split())
    return out


def judge(problem: ExternalProblem, r: np.ndarray) -> dict[str, float]:
    """``ccp_residual``, ``coulomb_residual`` and ``natural_map_error`` of impulses ``r``."""
    conic = problem.conic
    p = np.asarray(r, dtype=np.float64).reshape(problem.nc, problem.dim)
    return {
        "ccp_residual": ccp_residual(conic, p),
        "coulomb_residual": coulomb_residual(conic, p),
        "natural_map_error": problem.natural_map_error(p),
    }


def solve_external(
    problem: ExternalProblem,
    solver: str,
    tol: float,
    *,
    time_limit: float | None = None,
    max_iter: int | None = None,
    **options: Any,
) -> tuple[dict[str, Any], ExternalSolution | None]:
    """Solve ``problem`` with ``solver``; return its record and the answer in the file's terms.

    ``setup_s`` is cocd's conversion (the factorisation of ``M`` or ``W``) plus
    the backend's own set-up; ``solve_s`` the backend's solve time. An unknown
    solver, a problem the backend does not take (dimension, cones) or a local
    problem whose ``W`` is not symmetric raise a :class:`~cocd.errors.CocdError`.
    """
    solvers.get(solver)  # unknown names fail here, before the conversion
    start = time.perf_counter()
    conic = problem.conic  # may raise ProblemError (e.g. a non-symmetric W)
    convert = time.perf_counter() - start
    sol = solvers.solve(conic, solver, tol=tol, time_limit=time_limit, max_iter=max_iter, **options)
    record: dict[str, Any] = {
        "problem": problem.name,
        "kind": problem.kind,
        "dim": problem.dim,
        "nc": problem.nc,
        "ndof": problem.ndof,
        "solver": solver,
        "status": sol.status.value,
        "iterations": int(sol.iterations),
        "setup_s": float(convert + sol.setup_time),
        "solve_s": float(sol.solve_time),
        "ccp_residual": float("nan"),
        "coulomb_residual": float("nan"),
        "natural_map_error": float("nan"),
        "note": str(sol.extras.get("approximation", "")),
    }
    answer = None
    if sol.p is not None and np.all(np.isfinite(sol.p)):
        record.update(judge(problem, sol.p))
        answer = problem.solution(sol.p)
    return record, answer


def not_applicable(problem: ExternalProblem, solver: str) -> str | None:
    """Why ``solver`` cannot answer ``problem`` (``None`` if it can)."""
    try:
        info, options = solvers.resolve(solver)
    except CocdError as exc:
        return str(exc)
    reason = info.unavailable_reason()
    if reason:
        return reason
    if problem.dim not in info.dims:
        return f"handles dimensions {info.dims} only"
    if info.linear_cones_only and problem.dim == 3 and "facets" not in options:
        return "linear cones only (use :facets=K for 3D)"
    try:
        _ = problem.conic
    except ProblemError as exc:
        return str(exc).split(": ", 1)[-1]
    return None
