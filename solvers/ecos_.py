"""ECOS's interior point on the velocity-based primal (COCD), with an epigraph objective.

ECOS minimises a linear objective over ``G z + s = h, s in K`` (nonnegative
orthant, then second-order cones), so the quadratic objective of the primal
(:meth:`cocd.problem.ConicProblem.primal_conic_form`, ``1/2 x'Px`` with ``P``
diagonal and positive, ``q`` zero) goes into one more cone. With ``L = P^(1/2)``
and a new variable ``t``::

    (t + 1, t - 1, sqrt(2) L x)  in  SOC(ndof + 2)
    <=>  (t + 1)^2 >= (t - 1)^2 + 2 |L x|^2
    <=>  4 t >= 2 x'Px
    <=>  t >= 1/2 x'Px,

(the rotated cone ``2 t . 1 >= |L x|^2`` written as a plain one), and ECOS
solves ``min q'x + t`` over ``(x, t)`` with the contact rows ``A x + s = b``
unchanged. At the optimum ``t = 1/2 x'Px``. The multipliers ``z`` of the
contact rows are those of the quadratic problem: the epigraph cone is active,
so its multiplier is ``1/2 (t + 1, 1 - t, -sqrt(2) L x)`` (its first two
entries add up to the objective's 1 on ``t``), whose contribution to the
stationarity in ``x`` is ``-sqrt(2) L (-sqrt(2)/2 L x) = P x``; hence
``P x + q + A'z = 0`` as for Clarabel, and the impulses follow from
:meth:`PrimalConicForm.impulses` of ``z`` restricted to the contact rows.

========================  =====================================================
cocd                      ECOS
========================  =====================================================
``tol``                   the target is the framework's ``ccp_residual <= tol``
                          (:mod:`solvers.refine`): ECOS runs with
                          ``feastol = abstol = reltol = tol * 1e-2``; an answer
                          above the target is polished (:mod:`solvers.polish`,
                          off with ``polish=False``), then solved again with
                          tolerances 100 times tighter, down to 1e-10 (below
                          it ECOS stalls: its absolute gap stops near 5e-11
                          and it runs to ``max_iters``). Iterations and
                          times add up over the solves.
``status``                ``optimal`` when ``ccp_residual <= tol``,
                          ``inaccurate`` when ECOS answered (exit flag 0, or
                          10, "close to optimal") but the target was not
                          reached; otherwise ``STATUS_MAP`` on ``exitFlag``
``max_iter``              ``max_iters`` per solve (ECOS's default 100)
``time_limit``            ECOS has no time limit: only checked between solves
``warm_start``            not supported by ECOS (an interior point method)
``verbose``               ``verbose``
``**options``             ``polish`` (bool) and the ECOS settings not mapped
                          above: ``nitref, feastol_inacc, abstol_inacc,
                          reltol_inacc``
========================  =====================================================
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

import ecos
import numpy as np
import scipy.sparse as sp

from cocd.errors import ProblemError
from solvers._conic import answer, no_free_setting, to_target
from solvers.base import Request, Solution, Status
from solvers.refine import Attempt

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from cocd.problem import ConicProblem, PrimalConicForm

__all__ = ["STATUS_MAP", "ecos_solve_problem", "epigraph_form"]

#: ECOS ``info["exitFlag"]`` -> shared status.
STATUS_MAP: dict[int, Status] = {
    0: Status.OPTIMAL,  # ECOS_OPTIMAL
    1: Status.INFEASIBLE,  # ECOS_PINF
    2: Status.INFEASIBLE,  # ECOS_DINF
    10: Status.INACCURATE,  # ECOS_OPTIMAL + ECOS_INACC_OFFSET: close to optimal
    11: Status.INFEASIBLE,  # close to primal infeasible
    12: Status.INFEASIBLE,  # close to dual infeasible
    -1: Status.MAX_ITER,  # ECOS_MAXIT
    -2: Status.ERROR,  # ECOS_NUMERICS
    -3: Status.ERROR,  # ECOS_OUTCONE
    -4: Status.ERROR,  # ECOS_SIGINT
    -7: Status.ERROR,  # ECOS_FATAL
}

SMALLEST_TOL = 1e-10
_FREE = {"nitref", "feastol_inacc", "abstol_inacc", "reltol_inacc"}


def epigraph_form(
    form: PrimalConicForm,
) -> tuple[NDArray[np.float64], sp.csc_matrix, NDArray[np.float64], dict[str, Any]]:
    """``(c, G, h, dims)`` of ECOS for the primal ``form`` (see the module docstring).

    Variables ``(x, t)``; rows: the contact rows of ``form`` (nonnegative or
    second-order cones, in that order), then the epigraph cone of dimension
    ``ndof + 2``.
    """
    n = form.P.shape[0]
    diag = form.P.diagonal()
    if sp.triu(form.P, k=1).nnz or np.any(diag <= 0.0):
        raise ProblemError("the ECOS epigraph needs a diagonal, positive definite P")
    rows = form.A.shape[0]
    L = np.sqrt(diag)
    contact = sp.hstack([form.A, sp.csc_matrix((rows, 1))])
    t_col = sp.csc_matrix(([-1.0, -1.0], ([0, 1], [n, n])), shape=(2, n + 1))
    lx = sp.hstack([sp.diags(-np.sqrt(2.0) * L), sp.csc_matrix((n, 1))])
    G = sp.csc_matrix(sp.vstack([contact, t_col, lx]))
    h = np.concatenate([form.b, [1.0, -1.0], np.zeros(n)])
    c = np.concatenate([form.q, [1.0]])
    n_lin = sum(size for kind, size in form.cones if kind == "nonneg")
    soc = [size for kind, size in form.cones if kind == "soc"]
    dims: dict[str, Any] = {"l": n_lin, "q": [*soc, n + 2]}
    return np.asarray(c, dtype=np.float64), G, np.asarray(h, dtype=np.float64), dims


def ecos_solve_problem(problem: ConicProblem, request: Request, **options: Any) -> Solution:
    """Solve the COCD primal of ``problem`` with ECOS (see the module's table)."""
    start = time.perf_counter()
    form = problem.primal_conic_form()
    polish = bool(options.pop("polish", True))
    for key in options:
        if key not in _FREE:
            raise no_free_setting(
                "ecos",
                key,
                "tolerances and max_iters follow tol and max_iter",
                f"free settings: {', '.join(sorted(_FREE))}",
            )
    settings: dict[str, Any] = {**options, "verbose": bool(request.verbose)}
    if request.max_iter is not None:
        settings["max_iters"] = int(request.max_iter)
    c, G, h, dims = epigraph_form(form)
    rows, n = form.A.shape

    def attempt(native_tol: float, time_left: float | None) -> Attempt:
        sol = ecos.solve(
            c, G, h, dims, feastol=native_tol, abstol=native_tol, reltol=native_tol, **settings
        )
        info = sol["info"]
        flag = int(info["exitFlag"])
        x = np.asarray(sol["x"], dtype=np.float64)
        p, u = answer(form, x[:n], np.asarray(sol["z"], dtype=np.float64)[:rows])
        status = STATUS_MAP.get(flag, Status.ERROR)
        native = str(info["infostring"])
        return Attempt(p, u, status, native, int(info["iter"]), _extras(form, info, flag, x))

    return to_target(
        problem,
        "primal",
        request,
        attempt,
        base="ecos",
        start=start,
        polish=polish,
        floor=min(SMALLEST_TOL, request.tol),
    )


def _extras(
    form: PrimalConicForm, info: dict[str, Any], flag: int, x: NDArray[np.float64]
) -> dict[str, Any]:
    n = form.A.shape[1]
    return {
        "exit_flag": flag,
        "objective": float(info["pcost"]),
        "objective_dual": float(info["dcost"]),
        "epigraph_t": float(x[n]),
        "quadratic": 0.5 * float(x[:n] @ (form.P @ x[:n])) + float(form.q @ x[:n]),
        "r_prim": float(info["pres"]),
        "r_dual": float(info["dres"]),
        "gap": float(info["gap"]),
    }
