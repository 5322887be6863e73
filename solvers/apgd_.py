"""Accelerated projected gradient descent (APGD) on the force-based dual.

Nesterov's method with adaptive step and restart on

    min_p  1/2 p'Wp + b'p    s.t.  p in K = prod K_a,     W = H M^-1 H',

after Mazhar, Heyn, Negrut & Tasora (2015), "Using Nesterov's method to
accelerate multibody dynamics with friction and contact", ACM TOG 34(3).
Per iteration: a projected step from the extrapolated point ``y``,
``x+ = P_K(y - g(y) / L)``; backtracking doubles ``L`` until the step satisfies
the quadratic upper bound ``f(x+) <= f(y) + g(y)'(x+ - y) + L/2 |x+ - y|^2``
(for a quadratic: ``(x+ - y)'W(x+ - y) <= L |x+ - y|^2``), then ``L`` shrinks by
0.9 so that the step follows the local curvature; the momentum follows
Nesterov's ``theta`` sequence and restarts (``theta = 1``, no extrapolation)
whenever the objective goes up, ``f(x+) > f(x)``, or the gradient-mapping test
``g(y)'(x+ - x) > 0`` (O'Donoghue & Candès) fires. The iterate with the smallest
``ccp_residual`` is kept.

The method runs in scaled variables ``q = p / s`` (componentwise), i.e. on
``S W S`` with ``S = diag(s)``, the Jacobi preconditioner of each contact's
Delassus block (``scaling="block"``, the default): ``s`` is one over the square
root of the block's diagonal, with the normal and the (mean) tangential entry
apart, so every diagonal entry of ``S W S`` is 1. For spheres the tangential
entry is 3.5 times the normal one (2.5 r^2 / J of rotation per grain); the map
``p = s q`` takes the cone of friction ``mu`` to that of ``mu s_n / s_t``, so
the projection stays the exact Euclidean one. On a step of the seed's 3D
column (12 293 spheres, tol 1e-5) this takes 1900 iterations against 2886 for
``scaling="contact"``, the per-contact scalar ``s = sqrt(rho_a)`` (every
block's trace ``m``); see ``results/column3d_solvers.md``. The stopping test
reads the framework's natural map of ``p = s q`` from ``q`` and its gradient
``S (W p + b)`` in one pass, so it costs no extra product.

``W`` is never formed: ``W x = H (M^-1 (H'x))``. Each iteration is a few
fused passes of the multi-threaded numba kernels of
:mod:`solvers._apgd_kernels` (projected step and its length, the two sparse
products, the differences with the restart tests' inner products, the
extrapolation, the natural map): about 25 ms per iteration for 374 000 3D
contacts on two cores, against 43 ms for the scipy products and vector
operations they replace. A scene's ``H`` is multiplied through its contact
blocks (:mod:`solvers._blocks`: each contact's frame and rotational rows, read
once instead of 30 CSR entries and indices): on a mid-flow step of the seed's
3D column at its size (112 459 spheres, 1 423 363 contacts, one thread) an
iteration took 0.182 s against 0.362 s with both products in CSR
(``COCD_BENCH_SPHERES=112459 pytest benchmarks/test_bench_apgd_operator.py
--benchmark-enable``). ``H`` without that structure (an external problem) stays
in CSR. The starting ``L`` is a 10-step power iteration on
``S W S`` (20 products).

========================  =====================================================
cocd                      APGD
========================  =====================================================
``tol``                   stop when the framework's ``ccp_residual(problem, p)
                          <= tol``. The natural map is summed every
                          ``check_every`` iterations from the gradient the
                          iteration already has (numba, one pass over the
                          contacts); when it is below ``tol``,
                          ``cocd.residuals.ccp_residual`` itself confirms it
``status``                ``optimal`` when the test above holds; otherwise
                          ``max_iter`` or ``time_limit``, with the checked
                          iterate of smallest residual (never raises);
                          ``error`` if the iterates stop being finite
``max_iter``              iterations (default 10 000), each an accepted step;
                          a backtracking step costs one more ``H'`` product
``time_limit``            seconds, tested at every iteration
``warm_start``            impulses ``(nc, m)``, projected on their cones first
``verbose``               one line per 100 iterations (residual, ``L``, restarts)
``check_every``           iterations between residual checks (default 1)
``scaling``               ``"block"`` (default) or ``"contact"``: the scaling
                          of the impulses described above
``operator``              ``"auto"`` (default): the products through ``H``'s
                          contact blocks when it has them, else CSR;
                          ``"csr"``: always CSR. ``extras["operator"]``
                          says which was used
``polish``                none: the answer is the best checked iterate;
                          ``polish=False`` is accepted, ``polish=True`` warns
========================  =====================================================

Cost per iteration: two sparse products (``H'd`` and ``H (M^-1 H'd)`` for the
step ``d = x+ - y``; gradients and objective differences follow by linearity,
the Delassus shift included), one projection, four passes over the ``m nc``
impulses. The gradient is recomputed from scratch every 100 iterations to stop
rounding drift.

``extras["history"]`` holds ``dp`` (per iteration: the largest change of an
impulse component over the rms of ``rho b``), ``lipschitz`` (``L`` of the
accepted step), ``ccp_iteration`` and ``ccp`` (the residual at each check);
``extras`` also has ``ccp``, ``restarts`` and ``backtracks``.
"""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.sparse as sp

from cocd.contacts import unknowns_per_grain
from cocd.errors import ProblemError
from cocd.residuals import ccp_residual
from solvers._apgd_kernels import (
    csr_matvec,
    csr_scaled_matvec_add,
    differences,
    extrapolate,
    natural_map_sq_par,
    step_and_length,
    weighted_square,
)
from solvers._blocks import contact_blocks
from solvers._iterative import Checks, Stop, answer, ratio, residual_scales, start_impulses
from solvers.base import FloatArray, Request, Solution, Status

if TYPE_CHECKING:
    from cocd.problem import ConicProblem

__all__ = ["DEFAULT_MAX_ITER", "apgd_solve_problem"]

DEFAULT_MAX_ITER = 10_000
#: Scalings of the impulses (see :func:`component_scaling`).
SCALINGS = ("block", "contact")
#: How the products with ``H`` are made (see :class:`_ScaledDual`).
OPERATORS = ("auto", "csr")
#: Factor applied to L after every accepted step (Mazhar et al.).
L_SHRINK = 0.9
POWER_ITERATIONS = 10
RESYNC_EVERY = 100
_VERBOSE_EVERY = 100


def apgd_solve_problem(
    problem: ConicProblem,
    request: Request,
    *,
    check_every: int = 1,
    scaling: str = "block",
    operator: str = "auto",
    **options: Any,
) -> Solution:
    """Solve the force-based dual of ``problem`` by APGD (see the module's table)."""
    start = time.perf_counter()
    stop = Stop.of("apgd", start, request, DEFAULT_MAX_ITER, check_every, options)
    tol, cap, check_every, deadline = stop.tol, stop.cap, stop.check_every, stop.deadline

    rho = problem.rho
    s = component_scaling(problem, scaling)
    scaled = _ScaledDual(problem, s, operator)
    rb_norm, impulse_scale = residual_scales(problem)
    x = start_impulses(problem, request.warm_start) / s
    g_x = scaled.gradient(x)
    L = scaled.power_estimate()
    setup_time = time.perf_counter() - start

    solve_start = time.perf_counter()
    mu_true = problem.mu
    # p = s q maps the cone of friction mu onto that of mu s_n / s_t.
    mu = mu_true * s[:, 0] / s[:, 1] if s.shape[1] > 1 else mu_true
    y, g_y = x.copy(), g_x.copy()
    x_new, g_new = np.empty_like(x), np.empty_like(x)
    d, delta, dg = np.empty_like(x), np.empty_like(x), np.empty_like(x)
    zd = np.empty(scaled.ndof)
    theta = 1.0
    dp_history: list[float] = []
    l_history: list[float] = []
    checks = Checks()
    restarts = backtracks = 0

    r = ratio(math.sqrt(natural_map_sq_par(x, g_x, s, rho, mu_true)), rb_norm)
    best_x, best_r = x.copy(), r
    checks.add(0, r)
    status, native = Status.MAX_ITER, "max_iter"
    k = 0
    if r <= tol and ccp_residual(problem, s * x) <= tol:
        status, native = Status.OPTIMAL, "converged"
    while status is not Status.OPTIMAL:
        if k >= cap:
            break
        if deadline is not None and time.perf_counter() >= deadline:
            status, native = Status.TIME_LIMIT, "time_limit"
            break
        k += 1
        # Projected step from y, with backtracking on the Lipschitz estimate L.
        while True:
            dd = step_and_length(y, g_y, 1.0 / L, mu, x_new, d)
            dWd = scaled.curvature(d, zd, dd)
            if dWd <= L * dd or not math.isfinite(dWd):
                break
            L *= 2.0
            backtracks += 1
        scaled.update_gradient(g_y, zd, d, g_new)  # g(x_new) = g(y) + S W S d
        check = k % check_every == 0 or k == cap
        resync = k % RESYNC_EVERY == 0
        # The natural map is summed in the same pass, unless the gradient is resynced.
        df, g_map, biggest, nat = differences(
            x_new, x, g_new, g_x, g_y, s, delta, dg, rho, mu_true, check and not resync
        )
        if resync:
            g_new[:] = scaled.gradient(x_new)
            dg[:] = scaled.product(delta)
            if check:
                nat = natural_map_sq_par(x_new, g_new, s, rho, mu_true)
        dp_history.append(biggest / impulse_scale)
        l_history.append(L)
        if not math.isfinite(df):
            status, native = Status.ERROR, "non-finite iterate"
            break
        if check:
            r = ratio(math.sqrt(nat), rb_norm)
            checks.add(k, r)
            if r < best_r:  # into the same buffer: no fresh pages to fault in
                np.copyto(best_x, x_new)
                best_r = r
            if r <= tol:
                exact = ccp_residual(problem, s * x_new)
                if exact <= tol:
                    np.copyto(best_x, x_new)
                    best_r = exact
                    status, native = Status.OPTIMAL, "converged"
                    break
                # The test may have read a drifted gradient.
                g_new[:] = scaled.gradient(x_new)
                dg[:] = scaled.product(delta)
        if stop.verbose and k % _VERBOSE_EVERY == 0:
            print(f"apgd: iteration {k:6d}  ccp {r:9.3e}  L {L:9.3e}  restarts {restarts}")
        # Momentum, restarted when the objective or the gradient-mapping test goes up.
        if df > 0.0 or g_map > 0.0:
            restarts += 1
            theta, beta = 1.0, 0.0
        else:
            theta_next = 0.5 * (-theta * theta + theta * math.sqrt(theta * theta + 4.0))
            beta = theta * (1.0 - theta) / (theta * theta + theta_next)
            theta = theta_next
        extrapolate(x_new, delta, g_new, dg, beta, y, g_y)
        x, x_new = x_new, x
        g_x, g_new = g_new, g_x
        L *= L_SHRINK
    times = (setup_time, time.perf_counter() - solve_start)
    p = np.ascontiguousarray(s * best_x)
    return answer(
        problem,
        p,
        stop,
        (status, native, k, best_r),
        times,
        checks,
        np.asarray(dp_history),
        "iterations",
        {"lipschitz": np.asarray(l_history)},
        restarts=restarts,
        backtracks=backtracks,
        check_every=check_every,
        scaling=scaling,
        operator=scaled.operator,
    )


def component_scaling(problem: ConicProblem, scaling: str) -> FloatArray:
    """The scale ``s`` of each impulse component, shape ``(nc, m)``: ``p = s q``.

    ``"contact"``: ``sqrt(rho_a)`` on every component (each block's trace
    becomes ``m``). ``"block"``: one over the square root of the diagonal of
    the contact's Delassus block, the normal and the tangential mean apart
    (one tangential scale, so that the cone stays round): every diagonal entry
    becomes 1. A contact whose diagonal is not positive keeps ``"contact"``.
    """
    if scaling not in SCALINGS:
        raise ProblemError(f"apgd: scaling must be one of {', '.join(SCALINGS)}, got {scaling!r}")
    nc, m = problem.nc, problem.contact_dim
    s = np.repeat(np.sqrt(problem.rho)[:, None], m, axis=1)
    if scaling == "contact" or m == 1:
        return s
    diag = np.asarray(problem.H.multiply(problem.H) @ (1.0 / problem.mass)).reshape(nc, m)
    diag = diag - problem.delassus_shift
    normal, tangential = diag[:, 0], diag[:, 1:].mean(axis=1)
    ok = (normal > 0.0) & (tangential > 0.0) & np.isfinite(normal) & np.isfinite(tangential)
    s[ok, 0] = 1.0 / np.sqrt(normal[ok])
    s[ok, 1:] = (1.0 / np.sqrt(tangential[ok]))[:, None]
    return s


class _ScaledDual:
    """The dual in the scaled variables ``q = p / s``: ``S W S`` and ``S b``, matrix-free.

    ``s`` has shape ``(nc, m)``: ``S = diag(s)`` scales each impulse component.
    ``operator``: ``"auto"`` multiplies by ``S H`` through its contact blocks
    (:mod:`solvers._blocks`) when it has their structure, as every scene's
    problem does, else in CSR; ``"csr"`` always in CSR.
    """

    def __init__(self, problem: ConicProblem, s: FloatArray, operator: str = "auto") -> None:
        if operator not in OPERATORS:
            raise ProblemError(
                f"apgd: operator must be one of {', '.join(OPERATORS)}, got {operator!r}"
            )
        nc, m = problem.nc, problem.contact_dim
        rows = s.reshape(-1)
        self.shape = (nc, m)
        H = sp.csr_matrix(sp.diags(rows) @ problem.H)
        self.ndof = H.shape[1]
        self.blocks = (
            contact_blocks(H, m, problem.dim, unknowns_per_grain(problem.dim, m == 1))
            if operator == "auto"
            else None
        )
        self.operator = "blocks" if self.blocks is not None else "csr"
        # S H and its transpose in CSR, when the blocks do not stand for them.
        self.H: sp.csr_matrix | None = None
        self.HT: sp.csr_matrix | None = None
        if self.blocks is None:
            self.H = H
            self.HT = sp.csr_matrix(H.T)
        self.inv_mass = np.ascontiguousarray(1.0 / problem.mass, dtype=np.float64)
        self.b = (rows * problem.b).reshape(nc, m)
        # W = H M^-1 H' - delassus_shift I: S (-shift I) S q = -shift s^2 q.
        self.diagonal = problem.delassus_shift * s**2
        self.shifted = bool(self.diagonal.any())

    def product(self, q: FloatArray) -> FloatArray:
        """``S W S q`` for ``q`` of shape ``(nc, m)``."""
        z = np.empty(self.ndof)
        self._apply_ht(q, z)
        out = np.empty(self.shape)
        zero = np.zeros(out.size)
        self._apply_h(z, zero, out)
        return out - self.diagonal * q if self.shifted else out

    def curvature(self, d: FloatArray, z: FloatArray, dd: float) -> float:
        """``d' S W S d`` (``dd = |d|^2``); leaves ``z = H'S d`` for :meth:`update_gradient`."""
        self._apply_ht(d, z)
        value = weighted_square(z, self.inv_mass)
        if self.shifted:
            value -= float(np.sum(self.diagonal * d * d))
        return value

    def update_gradient(self, g: FloatArray, z: FloatArray, d: FloatArray, out: FloatArray) -> None:
        """``out = g + S W S d`` from ``z = H'S d`` (:meth:`curvature`)."""
        self._apply_h(z, g.reshape(-1), out)
        if self.shifted:
            out -= self.diagonal * d

    def _apply_ht(self, q: FloatArray, z: FloatArray) -> None:
        """``z = H'S q``."""
        if self.blocks is not None:
            self.blocks.rmatvec(q.reshape(-1), z)
        else:
            assert self.HT is not None
            csr_matvec(self.HT.indptr, self.HT.indices, self.HT.data, q.reshape(-1), z)

    def _apply_h(self, z: FloatArray, base: FloatArray, out: FloatArray) -> None:
        """``out = base + S H M^-1 z`` (``out`` of shape ``(nc, m)``)."""
        if self.blocks is not None:
            self.blocks.matvec_scaled_add(self.inv_mass, z, base, out.reshape(-1))
        else:
            H = self.H
            assert H is not None
            csr_scaled_matvec_add(
                H.indptr, H.indices, H.data, self.inv_mass, z, base, out.reshape(-1)
            )

    def gradient(self, q: FloatArray) -> FloatArray:
        """``S W S q + S b``."""
        return self.product(q) + self.b

    def power_estimate(self) -> float:
        """Largest eigenvalue of ``S W S`` by a few power iterations (a lower bound).

        Backtracking raises it where it is too small; a positive floor keeps
        the step finite when ``W`` is zero (no moving grain in contact).
        """
        v = np.random.default_rng(0).standard_normal(self.shape)
        estimate = 0.0
        for _ in range(POWER_ITERATIONS):
            v /= np.linalg.norm(v)
            w = self.product(v)
            estimate = float(np.linalg.norm(w))
            if estimate == 0.0:
                break
            v = w
        return estimate if estimate > 0.0 else 1.0
