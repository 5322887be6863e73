"""NSCD: the non-convex Signorini-Coulomb law by non-linear Gauss-Seidel (as in LMGC90).

The problem is the step problem of :class:`~cocd.problem.ConicProblem` with the
unconvexified law (DESIGN.md section 1): ``w = W p + b``, De Saxcé's
``ŵ = w + (mu |w_T|, 0)``, ``K ∋ p ⊥ ŵ ∈ K*``. It differs from the convex problem
(COCD, the CCP) only at sliding contacts, where it keeps ``w_N = 0`` instead of
``w_N = mu |w_T|``.

Method (Jean and Moreau's non-smooth contact dynamics): sweep over the contacts; at
contact ``a`` freeze the others, ``r_a = (W p + b)_a - W_aa p_a``, and replace ``p_a``
by the exact solution of the one-contact law with block ``W_aa``
(:func:`solvers._nscd_local_kernels.local_solve`: separation, stick and sliding branches
in closed form in 2D; in 3D the sliding branch solves for the slip angle by Newton,
falling back on the roots of a quartic that gives every candidate angle at once).
The velocity ``v = U + M^-1 H'p`` is kept up to date after every contact,
matrix-free: each update touches the nonzeros of ``H_a``.
Only the diagonal blocks ``W_aa`` are formed (from ``H`` and ``M``, once). Sweeps
go forward over the contacts (``symmetric=True`` alternates forward and backward:
about twice as many sweeps on columns, heaps and stacks).

The law is not monotone: Gauss-Seidel is not guaranteed to converge, and the
solution need not be unique (velocities usually are for a single contact or a
chain). The best answer seen (least ``coulomb_residual``) is returned. On
hyperstatic 3D packings Gauss-Seidel can sit on a plateau (``coulomb_residual``
about 1e-7 for tens of thousands of sweeps) while the impulses drift towards a
different set of sliding contacts: ask for ``tol`` around 1e-6 there, or give a
``time_limit``.

========================  =====================================================
cocd                      NSCD
========================  =====================================================
``tol``                   stop when ``coulomb_residual(problem, p) <= tol``
                          (:func:`cocd.residuals.coulomb_residual`), tested
                          after the first sweep and then every
                          ``check_every`` sweeps (default: 4, or a sixteenth
                          of the sweeps made so far once that is more, so
                          that a long solve spends little on its tests and
                          runs at most about 6 % past its target)
``status``                ``optimal`` when the target is met, ``max_iter`` or
                          ``time_limit`` otherwise (never an exception); the
                          impulses are then the best seen
``max_iter``              sweeps (default 20000)
``time_limit``            wall-clock seconds, tested between sweeps
``warm_start``            impulses ``(nc, m)``, projected on their cones
``verbose``               prints the residual at every test
``**options``             ``relax`` (default 1.0: ``p_a <- relax p_local +
                          (1 - relax) p_a``), ``symmetric`` (default False),
                          ``check_every`` (an int; default as above), ``local``: ``"exact"``
                          (default) or ``"fb"`` (see below); ``newton``
                          (default False): the sweeps finished by semismooth
                          Newton, on ``W = H M^-1 H'`` formed once
                          (:func:`solvers.local.nscd_local`; ``check_every``
                          does not apply)
========================  =====================================================

``local="fb"`` is the hybrid local solver of Gauss-Seidel codes: Newton on the
modified Fischer-Burmeister function of the contact, started from its current
impulse, with the exact solver when Newton does not reach the local law to 1e-12
(:func:`solvers._nscd_local_kernels.local_solve_fb`). Where the law has several local
solutions (large ``mu``), the two may pick different ones.

``iterations`` counts sweeps. ``extras``: ``history`` (``(sweep,
coulomb_residual)`` at every test), ``coulomb_residual`` of the answer, ``dp_max``
(largest impulse change in the last sweep), ``branches`` (how many contacts
ended separated, sticking and sliding), ``local`` and, with ``local="fb"``,
``local_newton`` and ``local_fallbacks`` (local solves ended by Newton, and by
the exact solver).
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

import numpy as np

from cocd.cones import project_coulomb
from cocd.errors import ProblemError
from cocd.residuals import coulomb_residual
from solvers._contact_kernels import restart_velocity
from solvers._iterative import Contacts, contact_blocks
from solvers._nscd_kernels import LOCAL_EXACT, LOCAL_FB, nscd_sweeps
from solvers.base import Request, Solution, Status

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from cocd.problem import ConicProblem

__all__ = ["DEFAULT_MAX_SWEEPS", "contact_blocks", "nscd_solve_problem"]

DEFAULT_MAX_SWEEPS = 20000
#: Sweeps between two residual tests by default: ``_CHECK_EVERY``, or the sweeps made
#: so far over ``_CHECK_FRACTION`` once that is more. On a 2000-disc Fig. 4 column a
#: test costs about as much as two sweeps.
_CHECK_EVERY = 4
_CHECK_FRACTION = 16
_LOCAL = {"exact": LOCAL_EXACT, "fb": LOCAL_FB}


def nscd_solve_problem(problem: ConicProblem, request: Request, **options: Any) -> Solution:
    """Solve the non-convex Coulomb law of ``problem`` by NSCD (see the module's table)."""
    tol, time_limit = request.tol, request.time_limit
    relax = float(options.get("relax", 1.0))
    if not 0.0 < relax <= 2.0:
        raise ProblemError(f"nscd: relax must be in (0, 2], got {relax}")
    symmetric = bool(options.get("symmetric", False))
    check_every = options.get("check_every")
    if check_every is not None and (not isinstance(check_every, int) or check_every < 1):
        raise ProblemError(f"nscd: check_every must be a positive integer, got {check_every!r}")
    newton = options.get("newton", False)  # True or False: solvers.registry.FLAGS
    if newton:
        return _with_newton(problem, request, symmetric, relax, options)
    local_name = options.get("local", "exact")
    if local_name not in _LOCAL:
        raise ProblemError(f"nscd: local must be one of {sorted(_LOCAL)}, got {local_name!r}")
    local = _LOCAL[local_name]
    counts = np.zeros(2, dtype=np.int64)
    max_sweeps = DEFAULT_MAX_SWEEPS if request.max_iter is None else int(request.max_iter)

    start = time.perf_counter()
    nc, m = problem.nc, problem.contact_dim
    c = Contacts.of(problem, sort=True)
    W, Winv = contact_blocks(problem, c.indptr, c.indices, c.data, c.inv_mass)
    if request.warm_start is None:
        p = np.zeros((nc, m))
    else:
        p = project_coulomb(np.asarray(request.warm_start, dtype=np.float64).reshape(nc, m), c.mu)
    p = np.ascontiguousarray(p)
    U = np.ascontiguousarray(problem.U, dtype=np.float64)
    v = np.ascontiguousarray(problem.velocity(p), dtype=np.float64)
    setup_time = time.perf_counter() - start

    start = time.perf_counter()
    history: list[tuple[int, float]] = []
    best_res = coulomb_residual(problem, p)
    best_p = p.copy()
    history.append((0, best_res))
    sweeps = 0
    dp_max = 0.0
    status = Status.OPTIMAL if best_res <= tol else Status.MAX_ITER
    while status != Status.OPTIMAL and sweeps < max_sweeps:
        # The first test after one sweep: a single contact, or a warm start that
        # was nearly right, needs no more.
        every = check_every or max(_CHECK_EVERY, sweeps // _CHECK_FRACTION)
        chunk = 1 if sweeps == 0 else min(every, max_sweeps - sweeps)
        dp_max = nscd_sweeps(
            c.indptr, c.indices, c.data, c.inv_mass, c.offset, W, Winv, c.mu, p, v,
            chunk, symmetric, relax, c.shift, local, counts,
        )  # fmt: skip
        sweeps += chunk
        # Rounding accumulates in v over many updates: restart it from p.
        restart_velocity(c.indptr, c.indices, c.data, c.inv_mass, U, p, v)
        res = c.natural_map(p, v, coulomb=True)
        history.append((sweeps, res))
        if request.verbose:
            print(f"nscd: sweep {sweeps:6d}  coulomb_residual {res:.3e}  dp_max {dp_max:.3e}")
        if res < best_res or not np.isfinite(best_res):
            best_res, best_p = res, p.copy()
        if best_res <= tol:
            status = Status.OPTIMAL
        elif time_limit is not None and time.perf_counter() - start >= time_limit:
            status = Status.TIME_LIMIT
            break
    solve_time = time.perf_counter() - start

    return Solution.from_impulses(
        problem,
        best_p,
        status,
        sweeps,
        (setup_time, solve_time),
        "nscd",
        status.value,
        coulomb_residual=best_res,
        history=history,
        dp_max=dp_max,
        branches=_branches(problem, best_p),
        local=local_name,
        local_newton=int(counts[0]),
        local_fallbacks=int(counts[1]),
    )


def _with_newton(
    problem: ConicProblem, request: Request, symmetric: bool, relax: float, options: Any
) -> Solution:
    """``newton=True``: the local form's hybrid (sweeps, then semismooth Newton on the
    Alart-Curnier function, :func:`solvers.local.nscd_local`) on ``W = H M^-1 H'`` and
    ``b``, stopped on the local form's residual, which is ``coulomb_residual`` here (``W``
    is symmetric)."""
    from solvers.local import LocalData, nscd_local

    start = time.perf_counter()
    data = LocalData(problem.W, problem.b, problem.mu, problem.contact_dim)
    setup = time.perf_counter() - start
    local = {k: v for k, v in options.items() if k in ("local",)}
    sol = nscd_local(
        data, request, criterion="residual", relax=relax, symmetric=symmetric, newton=True,
        **local,
    )  # fmt: skip
    p = np.asarray(sol.p, dtype=np.float64).reshape(problem.nc, problem.contact_dim)
    extras = {k: v for k, v in sol.extras.items() if k != "native_status"}
    return Solution.from_impulses(
        problem,
        p,
        sol.status,
        sol.iterations,
        (setup + sol.setup_time, sol.solve_time),
        "nscd",
        sol.status.value,
        **{**extras, "coulomb_residual": coulomb_residual(problem, p), "newton": True},
    )


def _branches(problem: ConicProblem, p: NDArray[np.float64]) -> dict[str, int]:
    """How many contacts are separated (``p = 0``), sticking (inside the cone) and
    sliding (on its boundary, ``p_N > 0``)."""
    pn = p[:, 0]
    pt = np.linalg.norm(p[:, 1:], axis=1) if p.shape[1] > 1 else np.zeros_like(pn)
    separated = pn <= 0.0
    slide = ~separated & (pt >= problem.mu * pn * (1.0 - 1e-9)) & (p.shape[1] > 1)
    return {
        "separated": int(separated.sum()),
        "stick": int((~separated & ~slide).sum()),
        "slide": int(slide.sum()),
    }
