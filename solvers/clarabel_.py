"""The velocity-based primal (COCD) solved by Clarabel's interior point.

The problem goes to Clarabel's own Python API as
``min 1/2 x'Px + q'x  s.t.  A x + s = b,  s in K`` (see
:meth:`cocd.problem.ConicProblem.primal_conic_form`): nonnegative cones in 2D and
for frictionless scenes, one second-order cone of dimension 3 per contact in 3D.
Impulses are recovered from Clarabel's dual variables ``z``.

========================  =====================================================
cocd                      Clarabel
========================  =====================================================
``tol``                   the target is the framework's ``ccp_residual <= tol``.
                          Clarabel runs with ``tol_gap_abs = tol_gap_rel =
                          tol_feas = tol * 1e-2`` (``tol_ktratio = min(1e-6,
                          that)``). An answer above the target is polished
                          (:mod:`solvers.polish`, off with ``polish=False``);
                          if still above, Clarabel solves again with
                          tolerances 100 times tighter, down to 1e-13.
                          Iterations add up over the solves; ``solve_time``
                          includes polishing (``extras["attempts"]`` lists
                          native tol, status, iterations, polished, ccp).
``status``                ``optimal`` when ``ccp_residual <= tol``,
                          ``inaccurate`` when Clarabel answered but the target
                          was not reached; otherwise Clarabel's status mapped
                          by ``STATUS_MAP``
``max_iter``              ``max_iter`` per solve (Clarabel's default 200)
``time_limit``            ``time_limit``, shared by the solves (seconds)
``warm_start``            not supported by Clarabel (an interior point method)
``verbose``               ``verbose``
``**options``             any other ``DefaultSettings`` attribute by name, e.g.
                          ``direct_solve_method="faer"``, ``max_threads=2``
========================  =====================================================

Why the target is our residual and not Clarabel's: in a flow, a contact that
slid during the last step starts the next one with its free relative velocity
exactly on the boundary of the dual cone. Its complementarity is degenerate
and an interior point stops with an impulse of order sqrt(gap) there, which
Clarabel's (objective-relative) criteria accept but the natural map does not.
Polishing fixes the active set such contacts belong to.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

import clarabel
import numpy as np

from cocd.errors import ProblemError
from cocd.residuals import ccp_residual
from solvers.base import Solution, Status
from solvers.polish import polish_impulses

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from cocd.problem import ConicProblem

__all__ = ["STATUS_MAP", "clarabel_solve_problem"]

#: The first solve uses Clarabel tolerances of ``tol * FIRST_TOL_FACTOR``.
FIRST_TOL_FACTOR = 1e-2
#: Each further solve tightens them by this factor ...
TIGHTEN_FACTOR = 1e-2
#: ... down to this floor.
SMALLEST_NATIVE_TOL = 1e-13

STATUS_MAP: dict[str, Status] = {
    "Solved": Status.OPTIMAL,
    "AlmostSolved": Status.INACCURATE,
    "PrimalInfeasible": Status.INFEASIBLE,
    "DualInfeasible": Status.INFEASIBLE,
    "AlmostPrimalInfeasible": Status.INFEASIBLE,
    "AlmostDualInfeasible": Status.INFEASIBLE,
    "MaxIterations": Status.MAX_ITER,
    "MaxTime": Status.TIME_LIMIT,
    "NumericalError": Status.ERROR,
    "InsufficientProgress": Status.ERROR,
    "CallbackTerminated": Status.ERROR,
    "Unsolved": Status.ERROR,
}


def clarabel_solve_problem(
    problem: ConicProblem,
    *,
    tol: float = 1e-8,
    warm_start: NDArray[np.float64] | None = None,
    max_iter: int | None = None,
    time_limit: float | None = None,
    verbose: bool = False,
    **options: Any,
) -> Solution:
    """Solve the COCD primal of ``problem`` with Clarabel (see the module's table)."""
    start = time.perf_counter()
    form = problem.primal_conic_form()
    cones = [
        clarabel.NonnegativeConeT(size) if kind == "nonneg" else clarabel.SecondOrderConeT(size)
        for kind, size in form.cones
    ]
    polish = bool(options.pop("polish", True))
    settings = clarabel.DefaultSettings()
    for key, value in options.items():
        if key.startswith("_") or not hasattr(settings, key) or key in _MAPPED:
            raise ProblemError(
                f"clarabel has no free setting {key!r} (tolerances follow tol); "
                "see clarabel.DefaultSettings"
            )
        setattr(settings, key, value)
    settings.verbose = verbose
    if max_iter is not None:
        settings.max_iter = max_iter
    setup_time = time.perf_counter() - start

    solve_time = 0.0
    polish_time = 0.0
    iterations = 0
    native_tol = max(tol * FIRST_TOL_FACTOR, SMALLEST_NATIVE_TOL)
    attempts = []
    while True:
        _set_tolerances(settings, native_tol)
        if time_limit is not None:
            settings.time_limit = max(time_limit - solve_time, 1e-3)
        begin = time.perf_counter()
        solver = clarabel.DefaultSolver(form.P, form.q, form.A, form.b, cones, settings)
        sol = solver.solve()
        solve_time += time.perf_counter() - begin
        iterations += int(sol.iterations)
        native = str(sol.status).split(".")[-1]
        status = STATUS_MAP.get(native, Status.ERROR)
        p = form.impulses(np.asarray(sol.z))
        ccp = ccp_residual(problem, p) if status in _ANSWERED else float("inf")
        polished = False
        if polish and tol < ccp < float("inf"):
            begin = time.perf_counter()
            p, info = polish_impulses(problem, p, target=tol)
            polish_time += time.perf_counter() - begin
            polished = info["accepted"] > 0
            ccp = info["ccp_after"]
        attempts.append((native_tol, native, int(sol.iterations), polished, ccp))
        if ccp <= tol or status not in _ANSWERED or native_tol <= SMALLEST_NATIVE_TOL:
            break
        if time_limit is not None and solve_time >= time_limit:
            status = Status.TIME_LIMIT
            break
        native_tol = max(native_tol * TIGHTEN_FACTOR, SMALLEST_NATIVE_TOL)

    if status in _ANSWERED:
        status = Status.OPTIMAL if ccp <= tol else Status.INACCURATE
    # A polished p no longer matches Clarabel's x: report the velocity it implies.
    u = problem.velocity(p) if any(a[3] for a in attempts) else form.velocity(np.asarray(sol.x))
    return Solution(
        u=u,
        p=p,
        status=status,
        iterations=iterations,
        setup_time=setup_time,
        solve_time=solve_time + polish_time,
        solver="clarabel",
        extras={
            "native_status": native,
            "native_tol": native_tol,
            "solves": len(attempts),
            "attempts": attempts,
            "polish_time": polish_time,
            "objective": float(sol.obj_val),
            "objective_dual": float(sol.obj_val_dual),
            "r_prim": float(sol.r_prim),
            "r_dual": float(sol.r_dual),
        },
    )


_MAPPED = {
    "tol_gap_abs",
    "tol_gap_rel",
    "tol_feas",
    "tol_ktratio",
    "time_limit",
    "max_iter",
    "verbose",
}
_ANSWERED = (Status.OPTIMAL, Status.INACCURATE)


def _set_tolerances(settings: Any, native_tol: float) -> None:
    settings.tol_gap_abs = native_tol
    settings.tol_gap_rel = native_tol
    settings.tol_feas = native_tol
    settings.tol_ktratio = min(1e-6, native_tol)
