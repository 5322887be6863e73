"""The velocity-based primal as a QP, solved by any backend of qpsolvers (``qp:<name>``).

The registry declares one entry ``qp:<name>`` per qpsolvers backend, with the
fixed option ``qp_solver=<name>``; all of them run :func:`qp_solve_problem`.
The QP is the dimensionless primal of :meth:`cocd.problem.ConicProblem.primal_conic_form`::

    min 1/2 x'Px   s.t.   A x <= b            (qpsolvers: G = A, h = b)

with ``u = U + velocity_scale x``; the duals ``z >= 0`` of ``G`` are mapped to
impulses by :meth:`~cocd.problem.PrimalConicForm.impulses`. Linear cones only:
2D problems (two half-planes per contact), frictionless problems (one row per
contact) and, as an approximation, 3D friction through a pyramid of ``facets``
faces (``qp:osqp:facets=8``; see *Faceted cones* below). A ``z`` entry a
first-order method leaves at ``-1e-16`` is clipped to 0 (the projection on the
nonnegative duals), so the impulses lie in their cones.

Target
------
As for every backend, ``optimal`` means the framework's ``ccp_residual <= tol``
(:func:`solvers.refine.solve_to_target`): the native tolerance starts at
``tol * 1e-2``; an answer above the target is polished (:mod:`solvers.polish`,
off with ``polish=False``), then solved again with native tolerances 100 times
tighter, down to the backend's floor below. ``single`` means the native
tolerance has (almost) no effect on the answer (active-set methods), so there is
one solve plus polishing. Iterations and times add up over the solves; each
solve after the first starts from the previous one's answer when the backend
takes a starting point. ``max_iter`` and ``time_limit`` apply per solve; the
time limit is shared by the solves (a backend without one stops between solves).

========  ===================================================  =======================  ======
backend   ``tol`` -> native settings (``t``)                   max_iter, time_limit     floor
========  ===================================================  =======================  ======
osqp      ``eps_abs = eps_rel = t``; ``polishing=True`` [1]_   ``max_iter``,            1e-10
                                                               ``time_limit``
proxqp    ``eps_abs = eps_rel = t``                            ``max_iter``             1e-12
piqp      ``eps_abs = eps_rel = t``,                           ``max_iter``             1e-12
          ``eps_duality_gap_abs = eps_duality_gap_rel = t``
clarabel  ``tol_gap_abs = tol_gap_rel = tol_feas = t``,        ``max_iter``,            1e-12
          ``tol_ktratio = min(1e-6, t)``                       ``time_limit``
daqp      ``primal_tol = t``,                                  ``iter_limit``,          single
          ``dual_tol = min(t, 1e-12)`` [2]_                    ``time_limit``
highs     ``primal_feasibility_tolerance = max(t, 1e-10)``,    ``qp_iteration_limit``,  single
          ``dual_feasibility_tolerance = max(t, 1e-10)`` [3]_  ``time_limit``
quadprog  none: dual active set (Goldfarb-Idnani), exact       --                       single
          up to rounding
scs       ``eps_abs = eps_rel = t``                            ``max_iters``,           1e-10
                                                               ``time_limit_secs``
ecos      ``abstol = reltol = feastol = t`` [4]_               ``max_iters``            1e-11
cvxopt    ``abstol = reltol = feastol = t``                    ``maxiters``             1e-10
qpalm     ``eps_abs = eps_rel = t``                            ``max_iter``             1e-10
gurobi    ``OptimalityTol = FeasibilityTol = max(t, 1e-9)``,   ``TimeLimit``            1e-9
          ``BarConvTol = t``
mosek     native defaults (qpsolvers' cvxopt wrapper)          --                       single
========  ===================================================  =======================  ======

.. [1] OSQP's own active-set solution polishing: on these problems it returns
   the exact answer (``ccp_residual`` ~1e-18); ``polishing=False`` turns it off.
   OSQP 1.1 prints "Polishing not needed - no active set detected" when no
   constraint is active, even when not verbose.
.. [2] An active-set method: the answer is exact up to rounding whatever ``t``;
   ``dual_tol`` (default 1e-12) is never loosened.
.. [3] HiGHS refuses tolerances below 1e-10; its QP solver is an active-set method.
.. [4] On the epigraph SOCP qpsolvers builds from the QP (dense Cholesky of ``P``).

The names were checked against the installed packages (OSQP 1.1, ProxSuite 0.8,
PIQP 0.7, Clarabel 0.11, DAQP 0.11, HiGHS 1.15, quadprog 0.1, SCS 3.3, ECOS 2.0);
cvxopt, qpalm, gurobi and mosek were not installed where this was written: their
names come from qpsolvers' wrappers.

Other arguments
---------------
``warm_start``
    Impulses ``p0`` give the primal point ``x0 = (u(p0) - U) / velocity_scale``,
    passed as qpsolvers' ``initvals`` to the backends that use one: osqp (primal
    only: qpsolvers cannot pass OSQP's duals), proxqp (also the duals ``z0`` of
    ``p0``, exact in 2D and frictionless problems: a warm start at the answer
    takes 0 iterations), scs (``x`` only), daqp (``primal_start``), qpalm and
    cvxopt. piqp, clarabel, highs, quadprog, ecos, gurobi and mosek take none
    (interior point methods, or qpsolvers drops it); ``extras["warm_start"]``
    says what was done.
``verbose``
    qpsolvers' ``verbose``.
``facets``
    Number of facets of the pyramid replacing each 3D friction cone; ignored
    (nothing approximated) for 2D and frictionless problems.
``polish``
    ``False`` turns the framework's polishing off (not OSQP's: ``polishing``).
``**options``
    Native settings of the backend, passed through qpsolvers. A name the
    backend does not have (read from the installed package: its settings
    object or signature; a fixed list for scs and ecos), or one that ``tol``,
    ``max_iter`` or ``time_limit`` set (table above), raises
    :class:`cocd.errors.ProblemError` naming it. For cvxopt and mosek names are
    not checked: qpsolvers hands them to the package as they are.

Iterations and status
---------------------
``iterations`` is the native count where qpsolvers returns it (osqp, proxqp,
piqp, scs, ecos, quadprog, qpalm, cvxopt); clarabel, daqp and highs report
none through qpsolvers: 0, with ``extras["iterations_reported"] = False``.
Native statuses are mapped on :class:`solvers.Status` (``extras["native_status"]``);
daqp, highs and quadprog expose only qpsolvers' ``found``, so an answer is
``found`` and a failure is ``error``. Warnings qpsolvers raises during a solve
are collected in ``extras["warnings"]`` instead of being printed.
daqp, quadprog and ecos densify ``G`` (qpsolvers' conversion); a problem
whose dense ``G`` would have more than 5e7 entries (400 MB) raises ProblemError.

Faceted cones
-------------
With ``facets=k`` a 3D circular cone ``|p_T| <= mu p_N`` is replaced by the
inscribed pyramid with edges ``mu (cos 2 pi j / k, sin 2 pi j / k)``; friction
reaches ``mu p_N`` along those ``k`` directions and ``mu cos(pi / k) p_N``
half-way between them. So with ``c = cos(pi / k)``::

    K(mu c)  ⊂  K_k  ⊂  K(mu)

and the faceted impulses lie in the true cone. This is another problem, so there
is a single native solve at ``t = tol`` (the faceting error is far larger), no
polishing, the status is the native one (``optimal`` when the backend says
solved), and ``extras["approximation"] = "facets=k"``.
Its error: with ``f(p) = 1/2 p'Wp + b'p`` minimised over ``K`` by ``p*``
(velocity ``u*``) and over ``K_k`` by ``p_k`` (velocity ``u_k``), and
``q = (p*_N, c p*_T)`` in ``K(mu c) ⊂ K_k``:
``1/2 ||u_k - u*||_M^2 <= f(p_k) - f(p*) <= f(q) - f(p*)`` (``p_k`` is feasible
for the exact problem, ``f`` is quadratic with Hessian ``W = H M^-1 H'`` and
``u - u* = M^-1 H'(p - p*)``; ``q`` is feasible for the faceted one). Expanding
``f(q) - f(p*)`` at ``p*``, with ``w* = W p* + b``::

    ||u_k - u*||_M^2  <=  2 (1 - c) S*  +  (1 - c)^2 ||H_T' p*_T||_{M^-1}^2,
    S* = -sum_a w*_T,a . p*_T,a  >= 0   (mu p_N |slip| summed over sliding contacts)

:func:`facet_error_bound` evaluates it from an exact answer. ``1 - cos(pi/k)
<= pi^2 / (2 k^2)``: 0.29, 0.076, 0.019, 0.0048 for k = 4, 8, 16, 32, so the
velocity error is ``O(1/k)`` where contacts slide and ``O(1/k^2)`` where they
all stick. A single sliding sphere whose slip points half-way between two
facets decelerates at ``mu cos(pi / k) g`` instead of ``mu g``.

``tests/test_qp.py`` checks: every ``qp:*`` backend agrees with ``clarabel`` on a
2D packing (1e-6 relative in ``u``, 1e-4 for first-order ones) with
``ccp_residual <= 10 tol``; a frictionless 3D stack; the ProblemError for 3D
friction without facets; faceted impulses inside the circular cones,
``extras["approximation"]``, the bound above, errors that fall with k = 4, 8, 32,
the sliding sphere's ``mu cos(pi / k) g``; and that a warm start changes
neither the answer nor (for osqp, proxqp) raises the iteration count.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable
from functools import cache
from typing import TYPE_CHECKING, Any

import numpy as np
import qpsolvers

from cocd.errors import ProblemError, SolverError
from solvers._qp_backends import BACKENDS, GENERIC, Backend
from solvers.base import Request, Solution, Status
from solvers.refine import FIRST_TOL_FACTOR, Attempt, solve_to_target
from solvers.registry import QP_SOLVERS

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from cocd.problem import ConicProblem, PrimalConicForm

__all__ = ["BACKENDS", "DENSE_ENTRIES_LIMIT", "facet_error_bound", "qp_solve_problem"]

#: Largest dense ``G`` (entries) the densifying backends are given.
DENSE_ENTRIES_LIMIT = 50_000_000


@cache
def _native_names(qp_solver: str) -> frozenset[str] | None:
    backend = BACKENDS.get(qp_solver, GENERIC)
    if backend.names is None:
        return None
    try:
        return frozenset(backend.names())
    except Exception:  # introspection failed: do not block the user
        return None


#: Arguments qpsolvers or this module set: never native options.
_RESERVED = frozenset({"verbose", "initvals", "solver", "problem", "x", "z", "primal_start"})


def _check_options(qp_solver: str, backend: Backend, options: dict[str, Any]) -> None:
    names = _native_names(qp_solver)
    for key in options:
        if key in _RESERVED:
            raise ProblemError(
                f"qp:{qp_solver}: {key!r} is set by cocd (verbose, warm_start), not an option"
            )
        if key in backend.mapped:
            raise ProblemError(
                f"qp:{qp_solver}: setting {key!r} follows tol, max_iter or time_limit "
                "(see solvers.qpsolvers_); it cannot be given as an option"
            )
        if names is not None and key not in names:
            raise ProblemError(
                f"qp:{qp_solver} has no setting {key!r}; its settings: {', '.join(sorted(names))}"
            )


def qp_solve_problem(
    problem: ConicProblem,
    request: Request,
    *,
    qp_solver: str,
    facets: int | None = None,
    **options: Any,
) -> Solution:
    """Solve the COCD primal of ``problem`` as a QP with ``qp_solver`` (see the module)."""
    tol, warm_start = request.tol, request.warm_start
    start = time.perf_counter()
    if qp_solver not in qpsolvers.available_solvers:
        raise SolverError(
            f"qpsolvers cannot run {qp_solver!r} here; it has: "
            f"{', '.join(qpsolvers.available_solvers)}"
        )
    backend = BACKENDS.get(qp_solver, GENERIC)
    takes_start = qp_solver in QP_SOLVERS and QP_SOLVERS[qp_solver][2]
    polish = bool(options.pop("polish", True))
    _check_options(qp_solver, backend, options)
    native = {**backend.defaults, **options}
    name = f"qp:{qp_solver}"

    if facets is not None:
        _check_facets(facets)
    faceted = facets is not None and problem.contact_dim == 3
    form = problem.primal_conic_form(facets if faceted else None)
    P, G = form.P, form.A
    if backend.dense:
        entries = G.shape[0] * G.shape[1]
        if entries > DENSE_ENTRIES_LIMIT:
            raise ProblemError(
                f"{name} works on a dense G: {G.shape[0]} x {G.shape[1]} = {entries:.3g} "
                f"entries ({8 * entries / 1e9:.2g} GB) is above {DENSE_ENTRIES_LIMIT:.3g}; "
                "use a sparse backend (qp:osqp, qp:proxqp, qp:piqp, qp:clarabel)"
            )
        if qp_solver == "quadprog":  # qpsolvers' quadprog refuses sparse matrices
            P, G = P.toarray(), G.toarray()
    qp = qpsolvers.Problem(P, form.q, G=G, h=form.b)

    x_start: NDArray[np.float64] | None = None
    z_start: NDArray[np.float64] | None = None
    warm_note = "none given"
    if warm_start is not None:
        if takes_start:
            p0 = np.asarray(warm_start, dtype=np.float64).reshape(problem.nc, problem.contact_dim)
            x_start = (problem.velocity(p0) - problem.U) / form.velocity_scale
            warm_note = "primal"
            if backend.dual_start and not faceted:
                z_start = _duals(problem, form, p0)
                warm_note = "primal and dual"
        else:
            warm_note = f"ignored: {qp_solver} takes no starting point through qpsolvers"
    setup_time = time.perf_counter() - start
    state = {"x": x_start, "z": z_start}

    def attempt(native_tol: float, time_left: float | None) -> Attempt:
        kwargs = {**backend.settings(native_tol, request.max_iter, time_left), **native}
        if state["z"] is not None:
            kwargs["z"] = state["z"]
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            sol = qpsolvers.solve_problem(
                qp, solver=qp_solver, initvals=state["x"], verbose=request.verbose, **kwargs
            )
        native_status, status = backend.status(sol)
        if not sol.found and status == Status.OPTIMAL:
            status = Status.ERROR
        iterations = backend.iterations(sol)
        extras: dict[str, Any] = {
            "qp_solver": qp_solver,
            "warm_start": warm_note,
            "iterations_reported": iterations is not None,
        }
        if caught:
            extras["warnings"] = [str(w.message) for w in caught]
        x, z = sol.x, sol.z
        n_rows = G.shape[0]
        usable = (
            x is not None
            and z is not None
            and np.shape(x) == (problem.ndof,)
            and np.shape(z) == (n_rows,)
            and bool(np.all(np.isfinite(x)) and np.all(np.isfinite(z)))
        )
        if not usable:
            if status in (Status.OPTIMAL, Status.INACCURATE):
                status = Status.ERROR
            return Attempt(
                p=np.zeros((problem.nc, problem.contact_dim)),
                u=problem.U.copy(),
                status=status,
                native_status=native_status,
                iterations=iterations or 0,
                extras=extras,
            )
        x = np.asarray(x, dtype=np.float64)
        z = np.maximum(np.asarray(z, dtype=np.float64), 0.0)
        if takes_start:  # a tighter solve starts from this answer
            state["x"] = x
        if backend.dual_start:
            state["z"] = z
        return Attempt(
            p=form.impulses(z),
            u=form.velocity(x),
            status=status,
            native_status=native_status,
            iterations=iterations or 0,
            extras=extras,
        )

    if form.facets is not None:
        # Another problem: solved once at tol, whose error is far below the faceting's.
        native_tol = max(tol, backend.floor or 0.0)
        return _single(problem, attempt, native_tol, request, name, setup_time, form.facets)
    first_tol = max(tol * FIRST_TOL_FACTOR, backend.floor or 0.0)
    return solve_to_target(
        problem,
        request,
        attempt,
        solver=name,
        setup_time=setup_time,
        polish=polish,
        floor=first_tol if backend.floor is None else backend.floor,
    )


def _check_facets(facets: Any) -> int:
    try:
        k = int(facets)
        ok = not isinstance(facets, bool) and k == facets and k >= 3
    except (TypeError, ValueError, OverflowError):
        ok = False
    if not ok:
        raise ProblemError(f"facets must be an integer >= 3, got {facets!r}")
    return k


def _single(
    problem: ConicProblem,
    attempt: Callable[[float, float | None], Attempt],
    native_tol: float,
    request: Request,
    name: str,
    setup_time: float,
    facets: int,
) -> Solution:
    """One native solve of the faceted problem; its status is the native one."""
    begin = time.perf_counter()
    result = attempt(native_tol, request.time_limit)
    solve_time = time.perf_counter() - begin
    u = result.u if result.u is not None else problem.velocity(result.p)
    return Solution(
        u=np.asarray(u, dtype=np.float64),
        p=np.asarray(result.p, dtype=np.float64).reshape(problem.nc, problem.contact_dim),
        status=result.status,
        iterations=result.iterations,
        setup_time=setup_time,
        solve_time=solve_time,
        solver=name,
        extras={
            "native_status": result.native_status,
            "native_tol": native_tol,
            "solves": 1,
            "approximation": f"facets={facets}",
            **result.extras,
        },
    )


def _duals(
    problem: ConicProblem, form: PrimalConicForm, p: NDArray[np.float64]
) -> NDArray[np.float64]:
    """The duals of ``G`` that :meth:`PrimalConicForm.impulses` maps to ``p`` (linear cones).

    Frictionless: ``z = p_N``; 2D: ``p_N = z0 + z1``, ``p_T = mu (z0 - z1)``.
    Clipped at 0 (an impulse outside its cone has no exact preimage).
    """
    scale = form.mass_scale * form.velocity_scale
    if problem.contact_dim == 1:
        z = p[:, 0]
    else:
        mu = problem.mu
        ratio = np.divide(p[:, 1], mu, out=np.zeros_like(mu), where=mu > 0.0)
        z = np.stack([p[:, 0] + ratio, p[:, 0] - ratio], axis=1).reshape(-1) / 2.0
    return np.maximum(z, 0.0) / scale


def facet_error_bound(problem: ConicProblem, p_exact: NDArray[np.float64], facets: int) -> float:
    """Bound on ``||u_k - u*||_M`` for a ``facets``-sided pyramid (see the module).

    ``p_exact`` are the exact (circular-cone) impulses, shape ``(nc, 3)``;
    ``u_k`` is the velocity of the faceted problem's answer and ``||v||_M^2 =
    v' M v``. ``sqrt(2 (1 - c) S* + (1 - c)^2 ||H_T' p*_T||^2_{M^-1})`` with
    ``c = cos(pi / facets)`` and ``S* = -sum w*_T . p*_T``.
    """
    k = _check_facets(facets)
    if problem.contact_dim != 3:
        return 0.0
    p = np.asarray(p_exact, dtype=np.float64).reshape(problem.nc, 3)
    c = math.cos(math.pi / k)
    w = problem.contact_velocity(p)
    slide = max(0.0, -float(np.sum(w[:, 1:] * p[:, 1:])))
    pt = p.copy()
    pt[:, 0] = 0.0
    force = problem.H.T @ pt.reshape(-1)
    tangential = float(np.sum(force**2 / problem.mass))
    return math.sqrt(2.0 * (1.0 - c) * slide + (1.0 - c) ** 2 * tangential)
