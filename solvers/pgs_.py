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

import time
from typing import TYPE_CHECKING, Any

import numpy as np

from solvers._iterative import Contacts, Stop, gauss_seidel, relaxation, start_impulses
from solvers._pgs_kernels import pgs_sweeps
from solvers.base import FloatArray, Request, Solution

if TYPE_CHECKING:
    from cocd.problem import ConicProblem

__all__ = ["DEFAULT_CHECK_EVERY", "DEFAULT_MAX_ITER", "pgs_solve_problem"]

DEFAULT_MAX_ITER = 10_000
DEFAULT_CHECK_EVERY = 5


def pgs_solve_problem(
    problem: ConicProblem,
    request: Request,
    *,
    omega: float = 1.0,
    check_every: int = DEFAULT_CHECK_EVERY,
    **options: Any,
) -> Solution:
    """Solve the CCP of ``problem`` by projected Gauss-Seidel (see the module's table)."""
    start = time.perf_counter()
    stop = Stop.of("pgs", start, request, DEFAULT_MAX_ITER, check_every, options)
    omega = relaxation(omega)
    c = Contacts.of(problem)
    p = start_impulses(problem, request.warm_start)
    setup_time = time.perf_counter() - start
    dp_buffer = np.empty(stop.check_every)

    def sweeps(p: FloatArray, v: FloatArray, n: int) -> FloatArray:
        pgs_sweeps(
            c.indptr, c.indices, c.data, c.inv_mass, c.offset, c.rho, c.mu, omega, p, v, n,
            dp_buffer, c.shift,
        )  # fmt: skip
        return dp_buffer[:n]

    return gauss_seidel(
        problem, c, p, sweeps, stop, setup_time, omega=omega, check_every=stop.check_every
    )
