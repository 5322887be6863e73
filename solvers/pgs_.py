"""Projected Gauss-Seidel (PGS) on the cone complementarity problem, in impulses.

The method of Anitescu & Tasora: sweep over the contacts in order and move
each impulse by a projected step on its own block of the dual,

    p_a  <-  P_Ka(p_a - omega rho_a w_a),      w = W p + b = H v + (D/dt, 0),

with ``rho_a = m / trace(W_aa)`` (the framework's per-contact scale,
DESIGN.md section 2) and an over-relaxation factor ``omega`` in (0, 2).
``W`` is never formed: the generalized velocity ``v = U + M^-1 H'p`` is kept
up to date after every contact's change (a contact touches at most two grains,
so the update costs the nonzeros of its rows), and ``w_a = H_a v + offset_a``.
The sweeps run in a numba kernel (:func:`solvers._pgs_kernels.pgs_sweeps`).

========================  =====================================================
cocd                      PGS
========================  =====================================================
``tol``                   stop when the framework's ``ccp_residual(problem, p)
                          <= tol`` (natural map, DESIGN.md section 2). It is
                          evaluated every ``check_every`` sweeps: ``v`` is
                          recomputed from ``p`` (one sparse product, which also
                          removes the rounding drift of the incremental
                          updates), the natural map is summed by a numba kernel
                          (same formula as ``ccp_residual``, one pass over the
                          contacts) and, when it is below ``tol``,
                          ``cocd.residuals.ccp_residual`` itself confirms it
``status``                ``optimal`` when the test above holds; otherwise
                          ``max_iter`` or ``time_limit``, with the impulses of
                          the check with the smallest residual (never raises);
                          ``error`` if the iterates stop being finite
``max_iter``              sweeps (default 10 000); ``iterations`` counts sweeps
``time_limit``            seconds, tested at every check
``warm_start``            impulses ``(nc, m)``, projected on their cones first
``verbose``               one line per 20 checks (sweeps, residual, largest change)
``omega``                 over-relaxation, in (0, 2) (default 1); outside
                          raises ``ProblemError``. The block step is a
                          projected gradient step of length ``omega rho_a`` on
                          ``W_aa``, a descent step while ``omega rho_a
                          lambda_max(W_aa) < 2``. Frictionless contacts
                          (``m = 1``, ``rho_a W_aa = 1``) converge for every
                          ``omega`` in (0, 2). With friction ``rho_a
                          lambda_max(W_aa)`` is 3/2 for discs (tangential
                          stiffness 3 times the normal one) and 21/16 for
                          spheres (3.5 times), so the sweeps converge for
                          ``omega < 4/3`` in 2D and ``omega < 32/21 ~ 1.52``
                          in 3D, and stall above (status ``max_iter``).
                          ``omega = 1.3`` saves about a third of the sweeps
``check_every``           sweeps between residual checks (default 5; a check
                          costs about one sweep)
``polish``                none: the answer is the last checked iterate;
                          ``polish=False`` is accepted, ``polish=True`` warns
========================  =====================================================

Cost per sweep: two passes over the nonzeros of ``H`` (``w_a``, then the
velocity update), i.e. ``O(nnz(H))``, about ``2 m (2 (d + r))`` multiply-adds
per contact (``r`` rotations per grain), with no factorisation and no memory
beyond ``p`` and ``v``. Convergence is linear, slow on tall stacks and
polydisperse packings (information travels one contact per sweep).

``extras["history"]`` holds ``dp`` (per sweep: the largest change of an
impulse component divided by the rms of ``rho b``, the impulse scale of
:mod:`cocd.residuals`), ``ccp_iteration`` and ``ccp`` (sweeps at each check and
the residual there). ``extras["ccp"]`` is the residual of the returned impulses.
"""

from __future__ import annotations

import math
import time
import warnings
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from cocd.cones import project_coulomb
from cocd.errors import ProblemError
from cocd.residuals import ccp_residual
from solvers._contact_kernels import natural_map_sq
from solvers._pgs_kernels import pgs_sweeps
from solvers.base import Solution, Status

if TYPE_CHECKING:
    from cocd.problem import ConicProblem

__all__ = ["DEFAULT_CHECK_EVERY", "DEFAULT_MAX_ITER", "pgs_solve_problem"]

DEFAULT_MAX_ITER = 10_000
DEFAULT_CHECK_EVERY = 5
_VERBOSE_EVERY = 20

FloatArray = NDArray[np.float64]


def pgs_solve_problem(
    problem: ConicProblem,
    *,
    tol: float = 1e-8,
    warm_start: NDArray[np.float64] | None = None,
    max_iter: int | None = None,
    time_limit: float | None = None,
    verbose: bool = False,
    omega: float = 1.0,
    check_every: int = DEFAULT_CHECK_EVERY,
    **options: Any,
) -> Solution:
    """Solve the CCP of ``problem`` by projected Gauss-Seidel (see the module's table).

    Returns
    -------
    Solution
        ``p`` the impulses ``(nc, m)``, ``u = problem.velocity(p)``,
        ``iterations`` the sweeps made.
    """
    start = time.perf_counter()
    ignore_polish("pgs", options)
    omega = relaxation(omega)
    check_every = positive_int(check_every, "check_every")
    sweeps_cap = DEFAULT_MAX_ITER if max_iter is None else int(max_iter)

    nc, m = problem.nc, problem.contact_dim
    H = problem.H
    indptr = H.indptr.astype(np.int64)
    indices = H.indices.astype(np.int64)
    data = np.ascontiguousarray(H.data, dtype=np.float64)
    inv_mass = 1.0 / problem.mass
    offset = np.ascontiguousarray(problem.offset, dtype=np.float64)
    shift = problem.delassus_shift
    rho = np.ascontiguousarray(problem.rho, dtype=np.float64)
    mu = np.ascontiguousarray(problem.mu, dtype=np.float64)
    rb = rho[:, None] * problem.b.reshape(nc, m)
    rb_norm = float(np.linalg.norm(rb))
    impulse_scale = impulse_rms(rb)
    p = start_impulses(problem, warm_start)
    setup_time = time.perf_counter() - start

    solve_start = time.perf_counter()
    deadline = None if time_limit is None else start + float(time_limit)
    dp_buffer = np.empty(check_every)
    dp_history: list[FloatArray] = []
    check_sweeps: list[int] = []
    check_ccp: list[float] = []
    best_p, best_r = p.copy(), math.inf
    sweeps = 0
    status = Status.MAX_ITER
    native = "max_iter"
    while True:
        v = problem.velocity(p)  # resynchronise: the sweeps update v incrementally
        r = ratio(
            math.sqrt(natural_map_sq(indptr, indices, data, v, offset, rho, mu, p, shift)), rb_norm
        )
        check_sweeps.append(sweeps)
        check_ccp.append(r)
        if not np.all(np.isfinite(v)):
            status, native = Status.ERROR, "non-finite iterate"
            break
        if r < best_r:
            best_p, best_r = p.copy(), r
        if verbose and (len(check_ccp) % _VERBOSE_EVERY == 1):
            last = dp_history[-1][-1] if dp_history else math.nan
            print(f"pgs: sweep {sweeps:6d}  ccp {r:9.3e}  max|dp| {last:9.3e}")
        if r <= tol:
            exact = ccp_residual(problem, p)
            if exact <= tol:
                best_p, best_r = p.copy(), exact
                status, native = Status.OPTIMAL, "converged"
                break
        if sweeps >= sweeps_cap:
            break
        if deadline is not None and time.perf_counter() >= deadline:
            status, native = Status.TIME_LIMIT, "time_limit"
            break
        n = min(check_every, sweeps_cap - sweeps)
        pgs_sweeps(
            indptr, indices, data, inv_mass, offset, rho, mu, omega, p, v, n, dp_buffer, shift
        )
        dp_history.append(dp_buffer[:n] / impulse_scale)
        sweeps += n
    solve_time = time.perf_counter() - solve_start

    if verbose:
        print(f"pgs: {native} after {sweeps} sweeps, ccp {best_r:.3e}, {solve_time:.3g} s")
    history = {
        "dp": np.concatenate(dp_history) if dp_history else np.zeros(0),
        "ccp_iteration": np.asarray(check_sweeps, dtype=np.int64),
        "ccp": np.asarray(check_ccp),
    }
    return Solution(
        u=problem.velocity(best_p),
        p=best_p,
        status=status,
        iterations=sweeps,
        setup_time=setup_time,
        solve_time=solve_time,
        solver="pgs",
        extras={
            "native_status": native,
            "ccp": best_r,
            "omega": omega,
            "check_every": check_every,
            "history": history,
        },
    )


# -- helpers shared with solvers.apgd_ ---------------------------------------
def start_impulses(problem: ConicProblem, warm_start: NDArray[np.float64] | None) -> FloatArray:
    """The starting impulses ``(nc, m)``: the warm start projected on the cones, or zero."""
    shape = (problem.nc, problem.contact_dim)
    if warm_start is None:
        return np.zeros(shape)
    p0 = np.asarray(warm_start, dtype=np.float64).reshape(shape)
    if not np.all(np.isfinite(p0)):
        raise ProblemError("warm_start has non-finite entries")
    return np.ascontiguousarray(project_coulomb(p0, problem.mu))


def ignore_polish(solver: str, options: dict[str, Any]) -> None:
    """Warn when ``polish=True`` is asked of an iterative method (its other options
    are checked by :func:`solvers.solve` against its ``SolverInfo.accepts``).

    The iterative methods answer with their own iterates and never polish:
    ``polish=False`` (which the conformance suite passes to every backend) is
    what they do anyway, ``polish=True`` warns that it is ignored.
    """
    if options.get("polish", False):
        warnings.warn(
            f"{solver} does not polish its answer; polish=True is ignored",
            UserWarning,
            stacklevel=3,
        )


def relaxation(omega: Any) -> float:
    """``omega`` as a float in (0, 2), else :class:`ProblemError`."""
    try:
        value = float(omega)
    except (TypeError, ValueError):
        raise ProblemError(f"omega must be a number in (0, 2), got {omega!r}") from None
    if not (0.0 < value < 2.0):
        raise ProblemError(f"omega must be in (0, 2) (over-relaxation factor), got {omega!r}")
    return value


def positive_int(value: Any, name: str) -> int:
    """``value`` as a positive int, else :class:`ProblemError`."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ProblemError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def impulse_rms(rb: FloatArray) -> float:
    """Root mean square over contacts of ``rho_a b_a``, 1 when zero (as in cocd.residuals)."""
    s = float(np.linalg.norm(rb)) / math.sqrt(max(rb.shape[0], 1))
    return s if s > 0.0 else 1.0


def ratio(num: float, den: float) -> float:
    """``num / den`` with ``0 / x = 0`` and ``x / 0 = inf`` (as in cocd.residuals)."""
    if num == 0.0:
        return 0.0
    return num / den if den > 0.0 else math.inf
