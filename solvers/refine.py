"""Solve to the framework's target: ``ccp_residual <= tol``.

Backends whose own stopping criteria are not the natural map (interior point
and active-set methods) call :func:`solve_to_target` with a function that runs
one native solve at a given native tolerance. It projects the impulses on
their cones (a change at the level of rounding) and solves at ``tol * 1e-2``;
when the answer's ``ccp_residual`` is above ``tol`` it polishes it
(:mod:`solvers.polish`), and if that is not enough, solves again with native
tolerances 100 times tighter, down to a floor. Iterations and times add up.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from cocd.cones import project_coulomb
from cocd.residuals import ccp_residual
from solvers.base import Request, Solution, Status
from solvers.polish import polish_impulses

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from cocd.problem import ConicProblem

__all__ = ["Attempt", "solve_to_target"]

FIRST_TOL_FACTOR = 1e-2
TIGHTEN_FACTOR = 1e-2
SMALLEST_NATIVE_TOL = 1e-13
_ANSWERED = (Status.OPTIMAL, Status.INACCURATE)


@dataclass
class Attempt:
    """One native solve: impulses ``(nc, m)``, velocity (or ``None`` to derive it
    from the impulses), mapped status, native status and iterations."""

    p: NDArray[np.float64]
    u: NDArray[np.float64] | None
    status: Status
    native_status: str
    iterations: int
    extras: dict[str, Any] = field(default_factory=dict)


def solve_to_target(
    problem: ConicProblem,
    request: Request,
    attempt: Callable[[float, float | None], Attempt],
    *,
    solver: str,
    setup_time: float = 0.0,
    polish: bool = True,
    first_factor: float = FIRST_TOL_FACTOR,
    floor: float = SMALLEST_NATIVE_TOL,
) -> Solution:
    """Run ``attempt(native_tol, time_left)`` until ``ccp_residual <= request.tol``,
    within ``request.time_limit``.

    The answer returned is the best (lowest ``ccp_residual``) of the attempts
    that answered; its status is ``optimal`` when it meets the target,
    ``inaccurate`` otherwise. When no attempt answered, the status is the last
    native one mapped (``error``, ``max_iter``, ``time_limit``, ...) and the
    impulses are zero.
    ``extras["attempts"]`` lists ``(native_tol, native_status, iterations,
    polished, ccp_residual)`` per solve.
    """
    tol, time_limit = request.tol, request.time_limit
    solve_time = 0.0
    polish_time = 0.0
    iterations = 0
    native_tol = max(tol * first_factor, floor)
    attempts: list[tuple[float, str, int, bool, float]] = []
    # The best answer so far: a tighter re-solve may fail or come back worse.
    best: tuple[float, NDArray[np.float64], Attempt, bool] | None = None
    status = Status.ERROR
    while True:
        left = None if time_limit is None else max(time_limit - solve_time, 1e-3)
        begin = time.perf_counter()
        result = attempt(native_tol, left)
        solve_time += time.perf_counter() - begin
        iterations += result.iterations
        p = np.asarray(result.p, dtype=np.float64).reshape(problem.nc, problem.contact_dim)
        ok = result.status in _ANSWERED and bool(np.all(np.isfinite(p)))
        ccp = float("inf")
        polished = False
        if ok:
            # Interior-point and splitting answers sit in the cones up to rounding;
            # make them exactly admissible before judging them.
            p = project_coulomb(p, problem.mu)
            ccp = ccp_residual(problem, p)
            if polish and ccp > tol:
                begin = time.perf_counter()
                p, info = polish_impulses(problem, p, target=tol)
                polish_time += time.perf_counter() - begin
                polished = info["accepted"] > 0
                ccp = info["ccp_after"]
            if best is None or ccp < best[0]:
                best = (ccp, p, result, polished)
        attempts.append((native_tol, result.native_status, result.iterations, polished, ccp))
        if best is not None and best[0] <= tol:
            break
        if not ok:
            if (
                result.status == Status.ERROR
                and best is None
                and native_tol < tol
                and len(attempts) == 1
            ):
                # A first solve tighter than the target failed: try once at tol itself.
                native_tol = tol
                continue
            status = result.status
            break
        if native_tol <= floor:
            break
        if time_limit is not None and solve_time >= time_limit:
            status = Status.TIME_LIMIT
            break
        native_tol = max(native_tol * TIGHTEN_FACTOR, floor)

    if best is not None:
        ccp, p, result, polished_best = best
        status = Status.OPTIMAL if ccp <= tol else Status.INACCURATE
        # A polished p no longer matches the native velocity: report the one p implies.
        u = problem.velocity(p) if (result.u is None or polished_best) else result.u
    else:
        p = np.zeros((problem.nc, problem.contact_dim))
        u = problem.U.copy()
    return Solution(
        u=np.asarray(u, dtype=np.float64),
        p=p,
        status=status,
        iterations=iterations,
        setup_time=setup_time,
        solve_time=solve_time + polish_time,
        solver=solver,
        extras={
            "native_status": result.native_status,
            "native_tol": native_tol,
            "solves": len(attempts),
            "attempts": attempts,
            "polish_time": polish_time,
            **result.extras,
        },
    )
