"""Mosek's interior point on the velocity-based primal (COCD) and on the force-based dual.

Mosek's own Optimizer API (``mosek.Task``), not cvxpy or Fusion; the package
is imported only when a problem is solved (the registry probes for a licence
without importing this module). Mosek takes no quadratic objective together
with conic constraints, so, as in the seed paper, the objective goes into a
rotated quadratic cone ``Q_r = {(a, b, w): 2ab >= |w|^2, a, b >= 0}``:

``mosek``: the primal (:meth:`cocd.problem.ConicProblem.primal_conic_form`),
variables ``(x, t)``::

    min  q'x + t
    s.t. b - A x in K                    (rplus in 2D, one quadratic cone per contact in 3D)
         (t, 1, L x) in Q_r(ndof + 2)    (2t >= |L x|^2 = x'Px, L = P^(1/2), P diagonal)

Mosek's dual of ``min c'x, Fx + g in D`` is ``max -g'y, F'y = c, y in D*``.
The objective cone is active at the optimum with multiplier ``(1, t, -L x)``
(its first entry pays for ``t``), which adds ``-P x`` to ``F'y``; hence
``P x + q + A'y = 0`` and the multipliers ``y`` of the contact rows are the
``z`` of Clarabel's ``A x + s = b``: impulses by :meth:`PrimalConicForm.impulses`.

``mosek-dual``: the force-based dual (:meth:`cocd.problem.ConicProblem.dual_conic_form`,
``P = mass_scale W = G'G`` with ``G = sqrt(mass_scale) M^(-1/2) H'``, never
forming ``W``), variables ``(x, t)``::

    min  q'x + t
    s.t. -A x in K                       (zero, rplus, then quadratic cones of dimension 3)
         (t, 1, G x) in Q_r(ndof + 2)

impulses from ``x`` (:meth:`DualConicForm.impulses`), ``u = U + M^-1 H'p``.

========================  =====================================================
cocd                      Mosek (``dparam`` / ``iparam``)
========================  =====================================================
``tol``                   the target is the framework's ``ccp_residual <= tol``
                          (:mod:`solvers.refine`): ``intpnt_co_tol_rel_gap =
                          intpnt_co_tol_pfeas = intpnt_co_tol_dfeas =
                          intpnt_co_tol_mu_red = tol * 1e-2``; an answer above
                          the target is polished (:mod:`solvers.polish`, off
                          with ``polish=False``), then solved again with
                          tolerances 100 times tighter, down to 1e-12.
``status``                ``optimal`` when ``ccp_residual <= tol``;
                          ``inaccurate`` when Mosek answered (solution status
                          ``optimal``, or ``prim_and_dual_feas`` after a stall)
                          but the target was not reached; otherwise
                          ``SOLSTA_MAP`` / ``TRM_MAP``
``max_iter``              ``intpnt_max_iterations`` per solve (Mosek's default 400)
``time_limit``            ``optimizer_max_time``, shared by the solves (seconds)
``warm_start``            not supported (an interior point method)
``verbose``               Mosek's log stream printed to stdout
``**options``             ``polish`` (bool), ``num_threads`` (``iparam.num_threads``,
                          0 = Mosek's choice)
========================  =====================================================

Not run here (no licence); the model and its dual signs are checked without
one by evaluating Mosek's own primal and dual violations at Clarabel's
solution (``tests/test_conic_backends.py``).
"""

from __future__ import annotations

import functools
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.sparse as sp

from cocd.errors import ProblemError
from cocd.problem import PrimalConicForm
from solvers._conic import answer, no_free_setting, prepare, to_target
from solvers.base import Request, Solution, Status
from solvers.refine import Attempt

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from cocd.problem import ConicProblem, DualConicForm

__all__ = [
    "SOLSTA_MAP",
    "TRM_MAP",
    "build_dual_task",
    "build_primal_task",
    "mosek_dual_solve_problem",
    "mosek_solve_problem",
]

#: Mosek solution status (name) of the interior-point solution -> shared status.
SOLSTA_MAP: dict[str, Status] = {
    "optimal": Status.OPTIMAL,
    "prim_infeas_cer": Status.INFEASIBLE,
    "dual_infeas_cer": Status.INFEASIBLE,
    "prim_illposed_cer": Status.INFEASIBLE,
    "dual_illposed_cer": Status.INFEASIBLE,
}
#: Mosek termination code (name) -> shared status, when the solution is not optimal.
TRM_MAP: dict[str, Status] = {
    "trm_max_iterations": Status.MAX_ITER,
    "trm_max_time": Status.TIME_LIMIT,
    "trm_stall": Status.INACCURATE,  # only with a primal-dual feasible solution
}

SMALLEST_TOL = 1e-12


def build_primal_task(task: Any, form: PrimalConicForm) -> int:
    """Put the primal ``form`` into the empty Mosek ``task``; returns the number of contact rows.

    Variables ``(x, t)``; AFEs: the contact rows ``b - A x``, then ``(t, 1, L x)``.
    """
    n = form.P.shape[0]
    diag = form.P.diagonal()
    if sp.triu(form.P, k=1).nnz or np.any(diag <= 0.0):
        raise ProblemError("the Mosek primal needs a diagonal, positive definite P")
    L = np.sqrt(diag)
    rows = form.A.shape[0]
    F = sp.vstack(
        [
            sp.hstack([-form.A, sp.csc_matrix((rows, 1))]),
            sp.csc_matrix(([1.0], ([0], [n])), shape=(2, n + 1)),
            sp.hstack([sp.diags(L), sp.csc_matrix((n, 1))]),
        ]
    )
    g = np.concatenate([form.b, [0.0, 1.0], np.zeros(n)])
    c = np.concatenate([form.q, [1.0]])
    _build(task, c, F, g, form.cones, n + 2)
    return rows


def build_dual_task(task: Any, form: DualConicForm) -> int:
    """Put the dual ``form`` into the empty Mosek ``task``; returns the number of impulse unknowns.

    Variables ``(x, t)``; AFEs: the cone rows ``-A x``, then ``(t, 1, G x)``.
    """
    pr = form.problem
    mass_scale = pr.scales[0]
    nx = form.A.shape[1]
    G = sp.diags(np.sqrt(mass_scale / pr.mass)) @ pr.H.T  # G'G = mass_scale W = P
    rows = form.A.shape[0]
    F = sp.vstack(
        [
            sp.hstack([-form.A, sp.csc_matrix((rows, 1))]),
            sp.csc_matrix(([1.0], ([0], [nx])), shape=(2, nx + 1)),
            sp.hstack([G, sp.csc_matrix((pr.ndof, 1))]),
        ]
    )
    g = np.concatenate([form.b, [0.0, 1.0], np.zeros(pr.ndof)])
    c = np.concatenate([form.q, [1.0]])
    _build(task, c, F, g, form.cones, pr.ndof + 2)
    return nx


def _build(
    task: Any,
    c: NDArray[np.float64],
    F: sp.spmatrix,
    g: NDArray[np.float64],
    cones: Sequence[tuple[str, int]],
    objective_cone: int,
) -> None:
    import mosek

    n = c.size
    task.appendvars(n)
    task.putvarboundsliceconst(0, n, mosek.boundkey.fr, -np.inf, np.inf)
    task.putclist(list(range(n)), c.tolist())
    task.putobjsense(mosek.objsense.minimize)
    coo = sp.coo_matrix(F)
    task.appendafes(F.shape[0])
    task.putafefentrylist(
        coo.row.astype(np.int64).tolist(), coo.col.astype(np.int32).tolist(), coo.data.tolist()
    )
    task.putafegslice(0, F.shape[0], g.tolist())
    domains: list[int] = []
    soc3: int | None = None
    for kind, size in cones:
        if kind == "zero":
            domains.append(task.appendrzerodomain(size))
        elif kind == "nonneg":
            domains.append(task.appendrplusdomain(size))
        else:
            if soc3 is None:
                soc3 = task.appendquadraticconedomain(3)  # one domain, used by every contact
            domains.append(soc3)
    domains.append(task.appendrquadraticconedomain(objective_cone))
    task.appendaccsseq(domains, F.shape[0], 0, None)


def mosek_solve_problem(
    problem: ConicProblem, request: Request, *, form: str = "primal", **options: Any
) -> Solution:
    """Solve ``form`` of ``problem`` with Mosek (see the module's table)."""
    import mosek

    start, model, polish = prepare(problem, form, options)
    threads = _threads(options)
    primal = isinstance(model, PrimalConicForm)
    with mosek.Task() as task:
        if isinstance(model, PrimalConicForm):
            build_primal_task(task, model)
        else:
            build_dual_task(task, model)
        _configure(task, request, threads)
        rows, n = model.A.shape

        def attempt(native_tol: float, time_left: float | None) -> Attempt:
            status, native, iters = _optimize(task, native_tol, time_left)
            xx = np.asarray(task.getxx(mosek.soltype.itr), dtype=np.float64)
            # The multipliers of the contact rows, read for the primal only.
            doty = task.getaccdotys(mosek.soltype.itr) if primal else None
            z = None if doty is None else np.asarray(doty, dtype=np.float64)[:rows]
            p, u = answer(model, xx[:n], z)
            return Attempt(p, u, status, native, iters, _extras(task))

        return to_target(
            problem,
            form,
            request,
            attempt,
            base="mosek",
            start=start,
            polish=polish,
            floor=min(SMALLEST_TOL, request.tol),
        )


#: The force-based dual, for direct calls (the registry passes ``form="dual"``).
mosek_dual_solve_problem = functools.partial(mosek_solve_problem, form="dual")


def _threads(options: dict[str, Any]) -> int | None:
    threads = options.pop("num_threads", None)
    if options:
        raise no_free_setting(
            "mosek",
            next(iter(options)),
            "tolerances, iterations and time follow tol, max_iter and time_limit",
            "free settings: num_threads, polish",
        )
    return None if threads is None else int(threads)


def _configure(task: Any, request: Request, threads: int | None) -> None:
    import mosek

    task.putintparam(mosek.iparam.optimizer, mosek.optimizertype.conic)
    if request.verbose:
        task.set_Stream(mosek.streamtype.log, sys.stdout.write)
    if request.max_iter is not None:
        task.putintparam(mosek.iparam.intpnt_max_iterations, int(request.max_iter))
    if threads is not None:
        task.putintparam(mosek.iparam.num_threads, threads)


def _optimize(task: Any, native_tol: float, time_left: float | None) -> tuple[Status, str, int]:
    """One interior-point solve at ``native_tol``: (status, native status, iterations)."""
    import mosek

    for name in ("intpnt_co_tol_rel_gap", "intpnt_co_tol_pfeas", "intpnt_co_tol_dfeas"):
        task.putdouparam(getattr(mosek.dparam, name), native_tol)
    task.putdouparam(mosek.dparam.intpnt_co_tol_mu_red, native_tol)
    if time_left is not None:
        task.putdouparam(mosek.dparam.optimizer_max_time, time_left)
    trm = _name(task.optimize())
    solsta = _name(task.getsolsta(mosek.soltype.itr))
    iterations = int(task.getintinf(mosek.iinfitem.intpnt_iter))
    status = SOLSTA_MAP.get(solsta)
    if status is None:
        status = TRM_MAP.get(trm, Status.ERROR)
        if status is Status.INACCURATE and solsta != "prim_and_dual_feas":
            status = Status.ERROR
    return status, f"{solsta} ({trm})", iterations


def _name(code: Any) -> str:
    """``solsta.optimal`` -> ``"optimal"``, ``rescode.trm_stall`` -> ``"trm_stall"``."""
    return str(code).split(".")[-1]


def _extras(task: Any) -> dict[str, Any]:
    import mosek

    return {
        "objective": float(task.getprimalobj(mosek.soltype.itr)),
        "objective_dual": float(task.getdualobj(mosek.soltype.itr)),
    }
