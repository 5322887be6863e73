"""Solve external problems (FCLib, Siconos) with any backend and judge the answer.

A local or global problem (:mod:`cocd.io.problems`) is turned into a
:class:`~cocd.problem.ConicProblem` and solved by a registered backend, except when
the backend has a local form (``nscd``, ``pgs``: :mod:`solvers.local`), which solves
``u = W r + q`` on ``W`` itself, as Siconos's NSGS does: no factor ``H H' = W`` is
needed, so a ``W`` that is not symmetric is solved too (the Capsules files), and a
small problem costs no conversion. A global problem goes to a local form through its
condensed problem ``W = H' M^-1 H``, ``q = w + H' M^-1 f`` (:func:`condense`, timed
into ``setup_s``), and its answer is judged in the global terms. The
answer is judged three ways: ``ccp_residual`` and ``coulomb_residual`` (cocd's
scaled measures, DESIGN.md section 2) on the ConicProblem, or for a local problem
on its ``W`` (the same numbers when ``W`` is symmetric: the ConicProblem's Delassus
operator is ``W``), and ``natural_map_error`` in the file's own terms, the number
Siconos users quote.

Convex backends answer the cone complementarity problem (COCD); they reach a
small ``ccp_residual``, while the Coulomb law itself (``natural_map_error``)
holds only for the non-convex backends (``nscd``, ``fp:...``) and for
contacts that stick or separate.
"""

from __future__ import annotations

import time
import weakref
from typing import Any

import numpy as np

import solvers
from cocd.cones import project_coulomb
from cocd.errors import CocdError, ProblemError
from cocd.io.problems import ExternalSolution, GlobalProblem, LocalProblem, natural_map_error
from cocd.problem import ConicProblem
from cocd.residuals import ccp_residual, coulomb_residual
from solvers.local import LocalData, local_backends, solve_local

__all__ = [
    "RECORD_KEYS",
    "condense",
    "conic_of",
    "describe",
    "judge",
    "local_data",
    "local_form_data",
    "local_residuals",
    "not_applicable",
    "solve_external",
]

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
            problem.check_scales()
        except ProblemError as exc:
            out["solvable"] = f"no: {_reason(exc)}"
        else:
            try:
                out["delassus_shift"] = problem.shift
            except ProblemError as exc:
                names = ", ".join(local_backends())
                out["solvable"] = f"local forms only ({names}): {_reason(exc)}"
    if problem.title:
        out["title"] = problem.title
    if problem.description:
        out["description"] = " ".join(problem.description.split())
    return out


def judge(problem: ExternalProblem, r: np.ndarray, u: np.ndarray | None = None) -> dict[str, float]:
    """``ccp_residual``, ``coulomb_residual`` and ``natural_map_error`` of impulses ``r``.

    For a local problem the first two are computed on its ``W`` (:func:`local_residuals`),
    with ``u = W r + q`` when given (else computed), for a global one on its ConicProblem.
    """
    p = np.asarray(r, dtype=np.float64).reshape(problem.nc, problem.dim)
    if isinstance(problem, LocalProblem):
        u = problem.velocity(p) if u is None else np.asarray(u, dtype=np.float64)
        ccp, coulomb = local_residuals(problem, p, u)
        return {
            "ccp_residual": ccp,
            "coulomb_residual": coulomb,
            "natural_map_error": natural_map_error(p, u, problem.mu, problem.dim, problem.q),
        }
    conic = problem.conic
    return {
        "ccp_residual": ccp_residual(conic, p),
        "coulomb_residual": coulomb_residual(conic, p),
        "natural_map_error": problem.natural_map_error(p),
    }


def local_residuals(
    problem: LocalProblem, r: np.ndarray, u: np.ndarray | None = None
) -> tuple[float, float]:
    """``ccp_residual`` and ``coulomb_residual`` (:mod:`cocd.residuals`) of impulses ``r``
    on the local problem's own ``W``: ``w = u = W r + q``, ``rho_a = m / trace(W_aa)``
    (positive: :class:`LocalProblem` refuses a zero block), normalised by ``|rho q|``.

    When ``W`` is symmetric these are the residuals on :attr:`LocalProblem.conic`,
    whose Delassus operator is ``W``; they need no factor of ``W``, so they judge a
    ``W`` that is not symmetric too.
    """
    nc, m = problem.nc, problem.dim
    if nc == 0:
        return 0.0, 0.0
    rho = (m / problem.check_scales())[:, None]
    p = np.asarray(r, dtype=np.float64).reshape(nc, m)
    w = problem.velocity(p) if u is None else np.asarray(u, dtype=np.float64)
    w = w.reshape(nc, m)
    den = float(np.linalg.norm(rho * problem.q.reshape(nc, m)))
    # Both natural maps in one projection: w, then De Saxcé's ŵ = w + (mu |w_T|, 0).
    x = np.concatenate([p - rho * w, p - rho * w])
    x[nc:, 0] -= rho[:, 0] * problem.mu * np.linalg.norm(w[:, 1:], axis=1)
    F = np.tile(p, (2, 1)) - project_coulomb(x, np.concatenate([problem.mu, problem.mu]))
    ccp, coulomb = float(np.linalg.norm(F[:nc])), float(np.linalg.norm(F[nc:]))
    return _ratio(ccp, den), _ratio(coulomb, den)


def _ratio(num: float, den: float) -> float:
    """``num / den`` with ``0 / x = 0`` and ``x / 0 = inf`` (as :mod:`cocd.residuals`)."""
    if num == 0.0:
        return 0.0
    return num / den if den > 0.0 else float("inf")


#: The local form's data of each local problem, built once (block CSR of ``W``).
_LOCAL_DATA: weakref.WeakKeyDictionary[LocalProblem, tuple[tuple[int, ...], LocalData]] = (
    weakref.WeakKeyDictionary()
)


def local_data(problem: LocalProblem) -> LocalData:
    """The :class:`solvers.local.LocalData` of ``problem``, kept while the problem lives
    (rebuilt when its ``W``, ``q`` or ``mu`` is replaced)."""
    key = (id(problem.W), id(problem.q), id(problem.mu), problem.dim)
    held = _LOCAL_DATA.get(problem)
    if held is not None and held[0] == key:
        return held[1]
    problem.check_scales()
    data = LocalData.of(problem)
    _ = data.arrays  # the block CSR of W, built here: set-up, not solve
    _LOCAL_DATA[problem] = (key, data)
    return data


def condense(problem: GlobalProblem) -> tuple[LocalProblem, float]:
    """The condensed problem ``W = H' M^-1 H``, ``q = w + H' M^-1 f`` of ``problem`` and
    the seconds it took, from the file's ``M`` and ``H`` (the mass factorisation
    included, whatever ``problem`` has cached): the cost charged to every solve on the
    condensed form, cocd's local forms and a peer's condensed solvers alike."""
    start = time.perf_counter()
    fresh = GlobalProblem(
        M=problem.M,
        H=problem.H,
        f=problem.f,
        w=problem.w,
        mu=problem.mu,
        dim=problem.dim,
        title=problem.title,
        source=problem.source,
    )
    local = fresh.local()
    return local, time.perf_counter() - start


def local_form_data(problem: ExternalProblem) -> tuple[LocalData, str]:
    """What a backend's local form solves for ``problem``, and the record's note: a local
    problem's own ``W`` (``local form``), a global problem's condensed one, condensed
    afresh (``local form (condensed)``)."""
    if isinstance(problem, GlobalProblem):
        return local_data(condense(problem)[0]), "local form (condensed)"
    return local_data(problem), "local form"


def conic_of(problem: ExternalProblem, solver: str) -> ConicProblem:
    """``problem.conic`` for the backend ``solver``; a local problem without a factor
    ``H H' = W`` (``W`` not symmetric) raises a one-line
    :class:`~cocd.errors.ProblemError` that names the backend."""
    if isinstance(problem, LocalProblem):
        problem.check_scales()  # no backend solves it: said as it is
    try:
        return problem.conic
    except ProblemError as exc:
        if not isinstance(problem, LocalProblem):
            raise
        local = " and ".join(local_backends()) or "no backend"
        raise ProblemError(
            f"{problem.name}: {solver} needs a factor H H' = W of a symmetric W, and "
            f"{_reason(exc).split(', so ')[0]}; {local} solve it on W itself (their local form)"
        ) from None


def _reason(exc: ProblemError) -> str:
    """The message of a problem's error without its leading ``where: ``."""
    return " ".join(str(exc).split(": ", 1)[-1].split())


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

    A problem goes to the backend's local form when it has one
    (:attr:`solvers.SolverInfo.local_entry`; ``options`` may then hold ``criterion``
    and the form's own options, :func:`solvers.local.solve_local`), a global problem
    through :func:`condense`; every other case to the backend on
    :attr:`~cocd.io.problems.LocalProblem.conic`. ``setup_s`` is cocd's conversion
    (the factorisation of ``M`` or ``W``, or the block CSR of ``W`` for a local form,
    each done once per problem; a global problem's condensation, every time) plus
    the backend's own set-up; ``solve_s`` the
    backend's solve time. An unknown solver, a problem the backend does not take
    (dimension, cones) or a local problem whose ``W`` is not symmetric given to a
    backend without a local form raise a one-line :class:`~cocd.errors.CocdError`.
    """
    info = solvers.get(solver)  # unknown names fail here, before the conversion
    start = time.perf_counter()
    if info.local_entry is not None:
        data, note = local_form_data(problem)
        convert = time.perf_counter() - start
        sol = solve_local(data, solver, tol, time_limit=time_limit, max_iter=max_iter, **options)
    else:
        conic = conic_of(problem, solver)
        convert = time.perf_counter() - start
        sol = solvers.solve(
            conic, solver, tol=tol, time_limit=time_limit, max_iter=max_iter, **options
        )
        note = str(sol.extras.get("approximation", ""))
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
        "note": note,
    }
    answer = None
    if sol.p is not None and np.all(np.isfinite(sol.p)):
        if isinstance(problem, LocalProblem):
            # Judged on u = W r + q computed here, not the backend's u.
            r = np.asarray(sol.p, dtype=np.float64).reshape(-1).copy()
            answer = ExternalSolution(r=r, u=problem.velocity(r))
            record.update(judge(problem, r, answer.u))
        else:
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
    if info.local_entry is not None:
        return None  # its local form takes any W, and a global problem condensed
    try:
        _ = conic_of(problem, info.name)
    except ProblemError as exc:
        return _reason(exc)
    return None
