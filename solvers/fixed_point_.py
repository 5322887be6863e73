"""The non-convex Coulomb law as a sequence of convex problems (``fp:<backend>``).

Cadoux's fixed point (Acary, Cadoux, Lemaréchal, Malick 2011, "A formulation of the
linear discrete Coulomb friction problem via convex optimization", ZAMM 91(2)):
the Coulomb law ``K ∋ p ⊥ W p + b + (mu |w_T|, 0) ∈ K*`` is the cone complementarity
problem of a convex problem whose linear term is shifted by ``s = (mu |w_T|, 0)``,
evaluated at its own solution. With ``s`` frozen the problem is the convex step
problem (:class:`~cocd.problem.ConicProblem`) with the gaps
``D_k = D + dt mu |w_T^k|``: at outer iteration ``k``

1. ``s_k = mu |w_T^k|`` from the relative velocity ``w^k = W p^k + b`` of the
   previous iterate (``s_0 = 0`` without a warm start, i.e. the first iterate is
   the COCD answer);
2. ``p^{k+1}`` solves ``ConicProblem(dim, m, M, H, D + dt s_k, mu, dt, U)`` with
   the convex backend ``inner`` through :func:`solvers.solve`, warm-started from
   ``p^k`` when that backend takes a warm start;
3. stop when ``coulomb_residual`` of the ORIGINAL problem at ``p^{k+1}`` is
   ``<= tol``.

A fixed point is a solution of the Coulomb law. Convergence is not guaranteed (the
map contracts for small ``mu``); the best iterate is returned.

========================  =====================================================
cocd                      fixed point
========================  =====================================================
``tol``                   stop when ``coulomb_residual(problem, p) <= tol``;
                          each inner solve targets ``ccp_residual <=
                          inner_tol * tol`` on its shifted problem
                          (``inner_tol`` default 0.1)
``status``                ``optimal`` when the target is met; ``max_iter``
                          after ``max_outer`` outer iterations (default 100) or
                          when the inner iterations reach ``max_iter``;
                          ``time_limit``; ``inaccurate`` when an inner solve
                          fails after an answer was found (that answer is
                          returned), the inner status when the first one fails
``max_iter``              cap on the sum of the inner iterations (each inner
                          solve gets what is left)
``time_limit``            seconds, shared by the inner solves
``warm_start``            impulses: give the first shift ``s_0`` and start the
                          first inner solve when ``inner`` takes a warm start
``verbose``               prints the outer iterations (not the inner logs)
``**options``             ``inner`` (a convex backend name, default
                          ``clarabel-dual``; ``fp:<backend>`` sets it),
                          ``inner_tol`` (fraction of ``tol``), ``max_outer``,
                          ``inner_options`` (dict passed to the inner backend);
                          an unknown, unusable or non-convex ``inner`` raises
                          ``ProblemError`` (naming the available backends)
========================  =====================================================

``iterations`` is the sum of the inner iterations; ``extras["outer"]`` the number
of outer iterations, ``extras["history"]`` ``(outer, inner status, inner
iterations, coulomb_residual)`` per outer iteration.
"""

from __future__ import annotations

import dataclasses
import time
from typing import TYPE_CHECKING, Any

import numpy as np

import solvers
from cocd.errors import ProblemError, SolverNotFound
from cocd.problem import ConicProblem
from cocd.residuals import coulomb_residual
from solvers.base import Request, Solution, Status

if TYPE_CHECKING:
    from numpy.typing import NDArray

__all__ = ["DEFAULT_INNER", "DEFAULT_MAX_OUTER", "fp_solve_problem"]

DEFAULT_INNER = "clarabel-dual"
DEFAULT_MAX_OUTER = 100
DEFAULT_INNER_TOL = 0.1


def fp_solve_problem(
    problem: ConicProblem, request: Request, *, inner: str = DEFAULT_INNER, **options: Any
) -> Solution:
    """Solve the non-convex Coulomb law of ``problem`` by Cadoux's fixed point on
    convex problems solved by ``inner`` (see the module's table)."""
    tol, max_iter, time_limit = request.tol, request.max_iter, request.time_limit
    info = _inner_backend(inner)
    inner_tol = float(options.pop("inner_tol", DEFAULT_INNER_TOL))
    if not 0.0 < inner_tol <= 1.0:
        raise ProblemError(f"fp: inner_tol is a fraction of tol in (0, 1], got {inner_tol}")
    max_outer = options.pop("max_outer", DEFAULT_MAX_OUTER)
    if not isinstance(max_outer, int) or max_outer < 1:
        raise ProblemError(f"fp: max_outer must be a positive integer, got {max_outer!r}")
    inner_options = dict(options.pop("inner_options", None) or {})
    if options:
        raise ProblemError(
            f"fp has no option {sorted(options)[0]!r}; its options are inner, inner_tol, "
            "max_outer and inner_options (options of the inner backend go in inner_options)"
        )

    start = time.perf_counter()
    nc, m = problem.nc, problem.contact_dim
    warm_start = request.warm_start
    p = None if warm_start is None else np.asarray(warm_start, dtype=np.float64).reshape(nc, m)
    shift = np.zeros(nc) if p is None else _slip_shift(problem, p)

    best: tuple[float, NDArray[np.float64], NDArray[np.float64]] | None = None
    history: list[tuple[int, str, int, float]] = []
    approximation: str | None = None
    iterations = 0
    setup_time = 0.0
    status = Status.MAX_ITER
    outer = 0
    while outer < max_outer:
        elapsed = time.perf_counter() - start
        if time_limit is not None and elapsed >= time_limit:
            status = Status.TIME_LIMIT
            break
        if max_iter is not None and iterations >= max_iter:
            status = Status.MAX_ITER
            break
        outer += 1
        shifted = dataclasses.replace(problem, D=problem.D + problem.dt * shift)
        sol = solvers.solve(
            shifted,
            solver=inner,
            tol=inner_tol * tol,
            warm_start=p if info.warm_start else None,
            max_iter=None if max_iter is None else max_iter - iterations,
            time_limit=None if time_limit is None else max(time_limit - elapsed, 1e-3),
            verbose=False,
            **inner_options,
        )
        iterations += sol.iterations
        setup_time += sol.setup_time
        if not sol.found:
            status = Status.INACCURATE if best is not None else sol.status
            history.append((outer, sol.status.value, sol.iterations, float("nan")))
            break
        p = sol.p
        approximation = sol.extras.get("approximation", approximation)
        res = coulomb_residual(problem, p)
        history.append((outer, sol.status.value, sol.iterations, res))
        if request.verbose:
            print(
                f"fp:{inner}: outer {outer:3d}  inner {sol.status.value} "
                f"({sol.iterations} it)  coulomb_residual {res:.3e}"
            )
        if best is None or res < best[0]:
            best = (res, p.copy(), sol.u)
        if res <= tol:
            status = Status.OPTIMAL
            break
        shift = _slip_shift(problem, p)
    total = time.perf_counter() - start

    if best is None:
        p_out = np.zeros((nc, m))
        res_out = coulomb_residual(problem, p_out)
    else:
        res_out, p_out, _ = best
    return Solution.from_impulses(
        problem,
        p_out,
        status,
        iterations,
        (setup_time, total - setup_time),
        f"fp:{inner}",
        status.value,
        inner=inner,
        outer=outer,
        coulomb_residual=res_out,
        history=history,
        **({"approximation": approximation} if approximation else {}),
    )


def _inner_backend(inner: Any) -> solvers.SolverInfo:
    """The convex backend ``inner``; a ProblemError (naming the available backends, from
    the registry's SolverNotFound) when it is unknown, unusable or not convex."""
    if not isinstance(inner, str) or not inner:
        raise ProblemError(
            f"fp needs the name of a convex backend as inner, got {inner!r}: "
            "use 'fp:<backend>', e.g. 'fp:clarabel-dual'"
        )
    try:
        info = solvers.get(inner)
    except SolverNotFound as exc:
        # solvers.solve wraps any other exception of a backend in a SolverError:
        # say it as a problem with the name given.
        raise ProblemError(f"fp:{inner}: no inner backend {inner!r}: {exc}") from exc
    if not info.convex:
        raise ProblemError(
            f"fp:{inner}: the inner backend of the fixed point must solve a convex problem, "
            f"and {info.name!r} solves the non-convex Coulomb law itself; use a convex "
            "backend such as 'fp:clarabel-dual', 'fp:clarabel' or 'fp:scs-dual'"
        )
    return info


def _slip_shift(problem: ConicProblem, p: NDArray[np.float64]) -> NDArray[np.float64]:
    """``mu |w_T|`` per contact for the relative velocity ``w = W p + b``, shape ``(nc,)``."""
    if problem.contact_dim == 1:
        return np.zeros(problem.nc)
    w = problem.contact_velocity(p)
    return np.asarray(problem.mu * np.linalg.norm(w[:, 1:], axis=1))
