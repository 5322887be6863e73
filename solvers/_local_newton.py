"""Semismooth Newton on the Alart-Curnier function of a local problem ``u = W r + q``.

The finishing stage of ``nscd``'s local form with ``newton=True``
(:mod:`solvers.local`), the method of Siconos's ``NSN_AC`` (Alart and Curnier 1991;
Christensen, Klarbring, Pang and Strömberg 1998). Per contact, with ``rho_a = m /
trace(W_aa)``, ``xi_N = r_N - rho u_N`` and ``xi_T = r_T - rho u_T``::

    Phi_N = r_N - max(xi_N, 0)
    Phi_T = r_T - P_D(mu max(xi_N, 0))(xi_T)        (D(s): the disc of radius s)

``Phi(r) = 0`` exactly when ``r`` and ``u = W r + q`` satisfy Coulomb's law, the
zeros of the natural map with De Saxcé's velocity. ``Phi`` is piecewise smooth;
a generalised Jacobian is ``J = A + B W`` with block-diagonal ``A = dPhi/dr`` and
``B = dPhi/du`` (written out in :func:`alart_curnier`), dimensionless since ``B``
carries ``rho``.

``J`` is singular wherever redundant contacts of rigid bodies stick or press (their
rows of ``W`` are dependent), which is the usual case in a packing. Each step
therefore solves the regularised system ``(J + lambda I) d = -Phi`` by sparse LU
(:func:`scipy.sparse.linalg.splu`, minimum-degree order on ``J + J'``: ``J`` has
``W``'s pattern, nearly symmetric) with ``lambda = kappa |Phi| / max(|r|, |rho q|)``,
which vanishes at a solution and keeps the fast local convergence of Newton under an
error bound (Yamashita and Fukushima 2001, for Levenberg-Marquardt); ``kappa`` starts
at 1, halves after a full step and grows fourfold after a step cut below a quarter
(the model is poor away from ``r``). It takes the longest
of ``1, 1/2, ...`` that decreases ``|Phi|^2`` below the largest of its last
``_MEMORY`` values by Armijo's rule (the non-monotone rule of Grippo, Lampariello and
Lucidi 1986; a monotone rule stalls on the kinks of ``Phi``). A ``J + lambda I``
that is still singular is shifted by a small multiple of its largest entry. The
stage stops at the criterion's tolerance, when the line search fails, when ``|Phi|``
has not halved in ``_STALL`` steps, or at the step or time budget; the caller goes
back to Gauss-Seidel sweeps from the best iterate.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numba import njit
from scipy.sparse.linalg import MatrixRankWarning, splu

from solvers._local_kernels import local_velocity
from solvers.base import FloatArray, IntArray

__all__ = ["NewtonResult", "alart_curnier", "newton"]

#: Armijo's constant and the least step tried.
_ARMIJO = 1e-4
_MIN_STEP = 2.0**-30
#: The shift of a singular Jacobian, relative to its largest entry.
_SHIFT = 1e-10
#: Merits remembered by the non-monotone line search; steps without halving ``|Phi|``
#: after which a stage stops.
_MEMORY = 10
_KAPPA = 1.0
_KAPPA_RANGE = (1e-2, 1e4)
_STALL = 50


@njit(cache=True)
def alart_curnier(r, u, mu, rho, phi, A, B, jacobian):
    """``Phi`` into ``phi`` ``(nc, m)`` and, when ``jacobian``, the blocks ``A``, ``B``
    ``(nc, m, m)`` of its generalised Jacobian ``A + B W`` (module docstring); returns
    ``|Phi|^2``."""
    nc, m = r.shape
    total = 0.0
    for a in range(nc):
        rh = rho[a]
        xn = r[a, 0] - rh * u[a, 0]
        active = xn > 0.0
        pn = xn if active else 0.0
        phi[a, 0] = r[a, 0] - pn
        total += phi[a, 0] * phi[a, 0]
        if jacobian:
            for i in range(m):
                for k in range(m):
                    A[a, i, k] = 0.0
                    B[a, i, k] = 0.0
            if active:
                B[a, 0, 0] = rh
            else:
                A[a, 0, 0] = 1.0
        if m == 1:
            continue
        x1 = r[a, 1] - rh * u[a, 1]
        x2 = r[a, 2] - rh * u[a, 2] if m == 3 else 0.0
        size = np.sqrt(x1 * x1 + x2 * x2)
        s = mu[a] * pn
        if size <= s:
            phi[a, 1] = r[a, 1] - x1
            if m == 3:
                phi[a, 2] = r[a, 2] - x2
            if jacobian:
                for i in range(1, m):
                    B[a, i, i] = rh
        else:
            n1 = x1 / size
            n2 = x2 / size
            phi[a, 1] = r[a, 1] - s * n1
            if m == 3:
                phi[a, 2] = r[a, 2] - s * n2
            if jacobian:
                # P = s nhat: dP = s G dxi_T + nhat ds, G = (I - nhat nhat') / |xi_T|,
                # dxi_T = dr_T - rho du_T, ds = mu [xi_N > 0] (dr_N - rho du_N).
                nh = (n1, n2)
                for i in range(1, m):
                    for k in range(1, m):
                        g = ((1.0 if i == k else 0.0) - nh[i - 1] * nh[k - 1]) * s / size
                        A[a, i, k] = (1.0 if i == k else 0.0) - g
                        B[a, i, k] = rh * g
                    if active:
                        A[a, i, 0] = -mu[a] * nh[i - 1]
                        B[a, i, 0] = rh * mu[a] * nh[i - 1]
        for i in range(1, m):
            total += phi[a, i] * phi[a, i]
    return total


@njit(cache=True)
def _jacobian_data(indptr, indices, blocks, A, B, shift, data):
    """The entries of ``A + B W + shift I`` in the CSR order of :func:`_pattern`."""
    nc = indptr.size - 1
    m = A.shape[1]
    pos = 0
    for a in range(nc):
        for i in range(m):
            for j in range(indptr[a], indptr[a + 1]):
                b = indices[j]
                for k in range(m):
                    v = 0.0
                    for c in range(m):
                        v += B[a, i, c] * blocks[j, c, k]
                    if b == a:
                        v += A[a, i, k]
                        if i == k:
                            v += shift
                    data[pos] = v
                    pos += 1


def _pattern(indptr: IntArray, indices: IntArray, m: int) -> tuple[IntArray, IntArray]:
    """The scalar CSR ``(indptr, indices)`` of a matrix with ``W``'s block pattern (every
    diagonal block included): row ``(a, i)`` holds columns ``(b, k)`` for the blocks
    ``b`` of block row ``a``, in order."""
    nc = indptr.size - 1
    per_block_row = np.diff(indptr) * m
    row_lengths = np.repeat(per_block_row, m)
    rows = np.zeros(nc * m + 1, dtype=np.int64)
    np.cumsum(row_lengths, out=rows[1:])
    cols = np.empty(int(rows[-1]), dtype=np.int64)
    pos = 0
    for a in range(nc):
        block_cols = (indices[indptr[a] : indptr[a + 1], None] * m + np.arange(m)).reshape(-1)
        for _ in range(m):
            cols[pos : pos + block_cols.size] = block_cols
            pos += block_cols.size
    return rows, cols


@dataclass
class NewtonResult:
    """The best iterate (by the criterion), its error, the iterations taken and why it
    stopped: ``converged``, ``line search``, ``stalled``, ``singular``, ``budget`` or
    ``time``; ``shifted`` counts the steps whose system needed the extra shift."""

    r: FloatArray
    error: float
    iterations: int
    reason: str
    shifted: int


def newton(
    indptr: IntArray,
    indices: IntArray,
    blocks: FloatArray,
    q: FloatArray,
    mu: FloatArray,
    rho: FloatArray,
    r0: FloatArray,
    error_of: Callable[[FloatArray], float],
    tol: float,
    *,
    max_iter: int = 50,
    deadline: float | None = None,
) -> NewtonResult:
    """Semismooth Newton from ``r0`` ``(nc, m)`` until ``error_of(r) <= tol``.

    ``W`` is given by its block rows (``indptr``, ``indices``, ``blocks``, as
    :mod:`solvers._local_kernels` reads it, every diagonal block present), ``q`` is
    ``(nc, m)``; ``error_of`` is the caller's criterion. The answer is the iterate of
    least error seen, ``r0`` included.
    """
    nc, m = r0.shape
    n = nc * m
    r = np.ascontiguousarray(r0, dtype=np.float64).copy()
    u = np.empty_like(r)
    local_velocity(indptr, indices, blocks, q, r, u)
    best, best_error = r.copy(), float(error_of(r))
    if best_error <= tol:
        return NewtonResult(best, best_error, 0, "converged", 0)
    phi, A, B = np.empty_like(r), np.empty((nc, m, m)), np.empty((nc, m, m))
    merit = alart_curnier(r, u, mu, rho, phi, A, B, True)
    # J is assembled in CSR, which is the CSC of J': SuperLU factors J' and solves with
    # trans="T".
    rows, cols = _pattern(indptr, indices, m)
    data = np.empty(cols.size)
    scale = max(float(np.linalg.norm(rho[:, None] * q)), 1e-300)
    trial, trial_u, trial_phi = np.empty_like(r), np.empty_like(r), np.empty_like(r)
    merits = [merit]
    kappa = _KAPPA
    least, least_at = merit, 0
    shifted = 0
    reason = "budget"
    k = 0
    while k < max_iter:
        if deadline is not None and time.perf_counter() >= deadline:
            reason = "time"
            break
        k += 1
        lam = kappa * math.sqrt(merit) / max(float(np.linalg.norm(r)), scale)
        _jacobian_data(indptr, indices, blocks, A, B, lam, data)
        d = _solve(data, cols, rows, -phi.reshape(-1), n)
        if d is None:
            shifted += 1
            _jacobian_data(indptr, indices, blocks, A, B, lam + _SHIFT * max(
                float(np.abs(data).max()), 1.0), data)  # fmt: skip
            d = _solve(data, cols, rows, -phi.reshape(-1), n)
            if d is None:
                reason = "singular"
                break
        reference = max(merits[-_MEMORY:])
        t = 1.0
        step = d.reshape(nc, m)
        while t >= _MIN_STEP:
            np.add(r, t * step, out=trial)
            local_velocity(indptr, indices, blocks, q, trial, trial_u)  # not u + t W d
            trial_merit = alart_curnier(trial, trial_u, mu, rho, trial_phi, A, B, False)
            if trial_merit <= (1.0 - 2.0 * _ARMIJO * t) * reference:
                break
            t *= 0.5
        else:
            reason = "line search"
            break
        r, trial = trial, r
        u, trial_u = trial_u, u
        merit = trial_merit
        # A short step says the model is poor away from r: weigh the shift more.
        if t == 1.0:
            kappa = max(kappa * 0.5, _KAPPA_RANGE[0])
        elif t < 0.25:
            kappa = min(kappa * 4.0, _KAPPA_RANGE[1])
        merits.append(merit)
        error = float(error_of(r))
        if error < best_error:
            best, best_error = r.copy(), error
        if error <= tol:
            reason = "converged"
            break
        if merit <= 0.25 * least:
            least, least_at = merit, k
        elif k - least_at >= _STALL:
            reason = "stalled"
            break
        alart_curnier(r, u, mu, rho, phi, A, B, True)
    return NewtonResult(best, best_error, k, reason, shifted)


def _solve(
    data: FloatArray, cols: IntArray, rows: IntArray, b: FloatArray, n: int
) -> FloatArray | None:
    """``J^-1 b`` for ``J`` in CSR ``(data, cols, rows)`` by sparse LU, or None when ``J``
    is singular or the answer is not finite."""
    Jt = sp.csc_matrix((data, cols, rows), shape=(n, n))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", MatrixRankWarning)
            d = splu(Jt, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.1).solve(b, trans="T")
    except RuntimeError:  # "Factor is exactly singular"
        return None
    if d.shape != (n,) or not np.all(np.isfinite(d)):
        return None
    return np.asarray(d, dtype=np.float64)
