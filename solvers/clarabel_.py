"""Clarabel's interior point on the velocity-based primal (COCD) and on the force-based dual.

``clarabel``: the primal as ``min 1/2 x'Px  s.t.  A x + s = b,  s in K`` in the
velocity correction (:meth:`cocd.problem.ConicProblem.primal_conic_form`):
nonnegative cones in 2D and for frictionless scenes, one second-order cone of
dimension 3 per contact in 3D; impulses from Clarabel's dual variables ``z``.

``clarabel-dual``: the force-based dual ``min 1/2 p'Wp + b'p, p in K``
(:meth:`cocd.problem.ConicProblem.dual_conic_form`, ``W`` sparse); velocities
``u = U + M^-1 H'p``.

One function for both, :func:`clarabel_solve_problem`, taking the form
(:mod:`solvers._conic`); both go through Clarabel's own Python API (not cvxpy).

========================  =====================================================
cocd                      Clarabel
========================  =====================================================
``tol``                   the target is the framework's ``ccp_residual <= tol``
                          (:mod:`solvers.refine`): Clarabel runs with
                          ``tol_gap_abs = tol_gap_rel = tol_feas = tol * 1e-2``
                          and ``tol_ktratio = min(1e-6, that)``; an answer above
                          the target is polished (:mod:`solvers.polish`, off
                          with ``polish=False``), then solved again with
                          tolerances 100 times tighter, down to 1e-13.
                          Iterations and times add up over the solves.
``status``                ``optimal`` when ``ccp_residual <= tol``,
                          ``inaccurate`` when Clarabel answered but the target
                          was not reached; otherwise ``STATUS_MAP``
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

import functools
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import clarabel
import numpy as np
import scipy.sparse as sp

from cocd.errors import ProblemError
from solvers._conic import answer, check_setting, no_free_setting, prepare, to_target
from solvers.base import Request, Solution, Status
from solvers.refine import Attempt

if TYPE_CHECKING:
    from cocd.problem import ConicProblem, DualConicForm, PrimalConicForm

__all__ = ["STATUS_MAP", "clarabel_dual_solve_problem", "clarabel_solve_problem"]

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

_MAPPED = {"tol_gap_abs", "tol_gap_rel", "tol_feas", "tol_ktratio", "time_limit", "max_iter"}


def clarabel_solve_problem(
    problem: ConicProblem, request: Request, *, form: str = "primal", **options: Any
) -> Solution:
    """Solve ``form`` of ``problem`` with Clarabel (see the module's table)."""
    start, model, polish = prepare(problem, form, options)
    settings = _settings(request, options)
    cones = _cones(model.cones)

    def attempt(native_tol: float, time_left: float | None) -> Attempt:
        sol = _run(model, cones, settings, native_tol, time_left)
        native = str(sol.status).split(".")[-1]
        p, u = answer(model, np.asarray(sol.x), np.asarray(sol.z))
        status = STATUS_MAP.get(native, Status.ERROR)
        return Attempt(p, u, status, native, int(sol.iterations), _extras(sol))

    return to_target(problem, form, request, attempt, base="clarabel", start=start, polish=polish)


#: The force-based dual, for direct calls (the registry passes ``form="dual"``).
clarabel_dual_solve_problem = functools.partial(clarabel_solve_problem, form="dual")


def _settings(request: Request, options: dict[str, Any]) -> Any:
    settings = clarabel.DefaultSettings()
    for key, value in options.items():
        if key.startswith("_") or not hasattr(settings, key) or key in _MAPPED:
            raise no_free_setting(
                "clarabel", key, "tolerances follow tol", "see clarabel.DefaultSettings"
            )
        kind = type(getattr(settings, key))
        if kind in (bool, int, float, str):
            check_setting("clarabel", key, value, kind)
        try:
            setattr(settings, key, value)
        except (TypeError, ValueError) as exc:
            raise ProblemError(f"clarabel: setting {key}={value!r}: {exc}") from None
    settings.verbose = request.verbose
    if request.max_iter is not None:
        settings.max_iter = request.max_iter
    return settings


def _cones(spec: Sequence[tuple[str, int]]) -> list[Any]:
    make = {
        "zero": clarabel.ZeroConeT,
        "nonneg": clarabel.NonnegativeConeT,
        "soc": clarabel.SecondOrderConeT,
    }
    return [make[kind](size) for kind, size in spec]


def _run(
    form: PrimalConicForm | DualConicForm,
    cones: list[Any],
    settings: Any,
    native_tol: float,
    time_left: float | None,
) -> Any:
    settings.tol_gap_abs = native_tol
    settings.tol_gap_rel = native_tol
    settings.tol_feas = native_tol
    settings.tol_ktratio = min(1e-6, native_tol)
    if time_left is not None:
        settings.time_limit = time_left
    # Clarabel reads the upper triangle of P.
    P = sp.triu(form.P, format="csc")
    return clarabel.DefaultSolver(P, form.q, form.A, form.b, cones, settings).solve()


def _extras(sol: Any) -> dict[str, Any]:
    return {
        "objective": float(sol.obj_val),
        "objective_dual": float(sol.obj_val_dual),
        "r_prim": float(sol.r_prim),
        "r_dual": float(sol.r_dual),
    }
