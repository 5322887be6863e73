"""Block Gauss-Seidel (BGS) on the cone complementarity problem, with exact local solves.

Sweep over the contacts and give each, the others held, the exact answer of its
own convex problem

    min_{p_a in K_a}  1/2 p_a'W_aa p_a + r_a'p_a,      r_a = (W p + b)_a - W_aa p_a,

where ``W_aa = H_a M^-1 H_a'`` is the contact's ``m x m`` Delassus block
(:func:`solvers._bgs_kernels.local_ccp`: interior, apex or a point of the cone's
boundary, exact to rounding). This is block coordinate descent on the dual: each
local answer lowers the objective, unlike the scalar step of ``pgs`` (which moves
``p_a`` along ``-rho_a w_a`` and needs over-relaxation below 4/3 to converge), and
the normal and tangential impulses are found together, as Siconos' and LMGC90's
non-smooth Gauss-Seidel do for the non-convex law (``nscd`` here). ``W`` is never
formed: ``v = U + M^-1 H'p`` is updated after every contact.

Order and threads. The sweep visits the contacts in the problem's order
(``order="natural"``, the default), or by their graph distance from the supports
(walls and fixed grains): ``"top-down"`` (farthest first) or ``"bottom-up"``.
On a resting stack the three need about as many sweeps (GS on a chain of
contacts is GS on a 1D Laplacian whatever the order: the load moves about one
contact per sweep); on the seed's 3D column neither distance order reaches a
lower residual than the natural one in the same time, whose sweeps read memory in
order and are faster. With ``colour=True`` the order is coloured greedily (no two
contacts of a colour share an unknown) and each colour is swept in parallel on
numba's threads; the colouring depends only on the problem, so the answer does
not depend on the thread count. On two cores the sequential sweep (the default)
is the faster (``results/column3d_solvers.md``, ``cocd bench column3d-solvers``).

========================  =====================================================
cocd                      BGS
========================  =====================================================
``tol``                   stop when the framework's ``ccp_residual(problem, p)
                          <= tol``, evaluated every ``check_every`` sweeps
                          (``v`` recomputed from ``p``, natural map summed in
                          one pass) and confirmed by ``cocd.residuals``
``status``                ``optimal`` when the test holds; otherwise
                          ``max_iter`` or ``time_limit`` with the checked
                          iterate of smallest residual (never raises);
                          ``error`` if the iterates stop being finite
``max_iter``              sweeps (default 10 000)
``time_limit``            seconds, tested at every check
``warm_start``            impulses ``(nc, m)``, projected on their cones first
``verbose``               one line per 20 checks
``order``                 ``"natural"`` (default), ``"top-down"`` or
                          ``"bottom-up"`` (by distance from the supports)
``colour``                sweep colour by colour in parallel (default False)
``check_every``           sweeps between residual checks (default 5)
``polish``                none; ``polish=False`` accepted, ``polish=True`` warns
========================  =====================================================

Cost per sweep: two passes over the nonzeros of ``H`` (as ``pgs``) and one local
solve per contact (a 3 x 3 product for a sticking contact; a one-dimensional
maximisation over the slip angle, a few Newton steps, for a sliding one in 3D).
Set-up: the Delassus blocks and their inverses, the depth order and the colouring,
each one pass over ``H``.

``extras`` has ``ccp``, ``colours`` (number of colours, 1 for a sequential sweep),
``order`` and ``history`` (``dp`` per sweep, ``ccp_iteration`` and ``ccp`` per
check).
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

import numpy as np

from cocd.errors import ProblemError
from solvers._bgs_kernels import bgs_sweep, greedy_colours, support_depth
from solvers._iterative import Contacts, Stop, contact_blocks, gauss_seidel, start_impulses
from solvers.base import FloatArray, IntArray, Request, Solution

if TYPE_CHECKING:
    from cocd.problem import ConicProblem

__all__ = ["DEFAULT_CHECK_EVERY", "DEFAULT_MAX_ITER", "ORDERS", "bgs_solve_problem"]

DEFAULT_MAX_ITER = 10_000
DEFAULT_CHECK_EVERY = 5
ORDERS = ("natural", "top-down", "bottom-up")


def bgs_solve_problem(
    problem: ConicProblem,
    request: Request,
    *,
    order: str = "natural",
    colour: bool = False,
    check_every: int = DEFAULT_CHECK_EVERY,
    **options: Any,
) -> Solution:
    """Solve the CCP of ``problem`` by block Gauss-Seidel (see the module's table)."""
    start = time.perf_counter()
    stop = Stop.of("bgs", start, request, DEFAULT_MAX_ITER, check_every, options)
    if order not in ORDERS:
        raise ProblemError(f"bgs: order must be one of {', '.join(ORDERS)}, got {order!r}")

    nc, m = problem.nc, problem.contact_dim
    c = Contacts.of(problem, sort=True)
    W, Winv = contact_blocks(problem, c.indptr, c.indices, c.data, c.inv_mass)
    sequence = _order(problem.H, c.indptr, c.indices, m, nc, order)
    if colour and nc > 0:
        colours = greedy_colours(sequence, c.indptr, c.indices, m, problem.H.shape[1])
        # Stable: within a colour the contacts keep their order.
        sequence = sequence[np.argsort(colours[sequence], kind="stable")]
        counts = np.bincount(colours, minlength=int(colours.max()) + 1)
        starts = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    else:
        starts = np.array([0, nc], dtype=np.int64)
    p = start_impulses(problem, request.warm_start)
    setup_time = time.perf_counter() - start

    def sweeps(p: FloatArray, v: FloatArray, n: int) -> FloatArray:
        return np.array([
            bgs_sweep(c.indptr, c.indices, c.data, c.inv_mass, c.offset, W, Winv, c.mu, p, v,
                      sequence, starts, c.shift)
            for _ in range(n)
        ])  # fmt: skip

    extras = {"colours": len(starts) - 1, "order": order, "check_every": stop.check_every}
    return gauss_seidel(problem, c, p, sweeps, stop, setup_time, finite_residual=True, **extras)


def _order(H: Any, indptr: IntArray, indices: IntArray, m: int, nc: int, order: str) -> IntArray:
    """The contacts in the order of the sweep."""
    natural = np.arange(nc, dtype=np.int64)
    if order == "natural" or nc == 0:
        return natural
    csc = H.tocsc()
    depth = support_depth(
        indptr, indices, csc.indptr.astype(np.int64), csc.indices.astype(np.int64), m, nc
    )
    ranked = np.argsort(-depth if order == "top-down" else depth, kind="stable")
    return np.ascontiguousarray(ranked, dtype=np.int64)
