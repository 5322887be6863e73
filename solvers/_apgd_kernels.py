"""Fused, multi-threaded numba kernels of one APGD iteration (:mod:`solvers.apgd_`).

An APGD iteration is memory-bound: two sparse products and about fifteen
vector operations over ``m nc`` numbers. Here each pass over the data does as
much of that work as it can (the projected step with its squared length, the
step's differences with the inner products the restart tests need, the
extrapolation of both the iterate and its gradient), and every loop runs on
all cores (``prange``; ``NUMBA_NUM_THREADS`` caps them). Sums are reductions
over threads, so their rounding may differ between thread counts; nothing
here depends on the order of the contacts.

Arrays are ``float64``; impulses and gradients are ``(nc, m)`` with the normal
first; sparse matrices are given by their CSR arrays ``(indptr, indices, data)``.
Compiled on first use and cached on disk.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from solvers._contact_kernels import project_coulomb_scalars

__all__ = [
    "csr_matvec",
    "csr_scaled_matvec_add",
    "differences",
    "extrapolate",
    "natural_map_sq_par",
    "step_and_length",
    "weighted_square",
]


@njit(cache=True, inline="always")
def _project3(x0, x1, x2, mu, m):
    """The Coulomb-cone projection of ``(x0, x1, x2)`` (``m`` in {1, 2, 3}; unused parts 0)."""
    if m == 1:
        return max(x0, 0.0), 0.0, 0.0
    return project_coulomb_scalars(x0, x1, x2, mu)


@njit(cache=True, parallel=True)
def step_and_length(y, g, t, mu, out, d):
    """``out = P_K(y - t g)`` and ``d = out - y``; returns ``|d|^2``."""
    nc, m = y.shape
    total = 0.0
    for a in prange(nc):
        x0 = y[a, 0] - t * g[a, 0]
        x1 = y[a, 1] - t * g[a, 1] if m > 1 else 0.0
        x2 = y[a, 2] - t * g[a, 2] if m > 2 else 0.0
        x0, x1, x2 = _project3(x0, x1, x2, mu[a], m)
        out[a, 0] = x0
        d0 = x0 - y[a, 0]
        d[a, 0] = d0
        part = d0 * d0
        if m > 1:
            out[a, 1] = x1
            d1 = x1 - y[a, 1]
            d[a, 1] = d1
            part += d1 * d1
        if m > 2:
            out[a, 2] = x2
            d2 = x2 - y[a, 2]
            d[a, 2] = d2
            part += d2 * d2
        total += part
    return total


@njit(cache=True, parallel=True)
def csr_matvec(indptr, indices, data, v, out):
    """``out = A v`` for ``A`` in CSR form."""
    n = indptr.shape[0] - 1
    for i in prange(n):
        acc = 0.0
        for idx in range(indptr[i], indptr[i + 1]):
            acc += data[idx] * v[indices[idx]]
        out[i] = acc


@njit(cache=True, parallel=True)
def weighted_square(z, w):
    """``sum_i w_i z_i^2``."""
    total = 0.0
    for i in prange(z.shape[0]):
        total += w[i] * z[i] * z[i]
    return total


@njit(cache=True, parallel=True)
def csr_scaled_matvec_add(indptr, indices, data, scale, z, base, out):
    """``out = base + A (scale * z)`` for ``A`` in CSR form (``base, out`` flat)."""
    n = indptr.shape[0] - 1
    for i in prange(n):
        acc = base[i]
        for idx in range(indptr[i], indptr[i + 1]):
            j = indices[idx]
            acc += data[idx] * scale[j] * z[j]
        out[i] = acc


@njit(cache=True, parallel=True)
def differences(x_new, x, g_new, g_x, g_y, s, delta, dg, rho, mu, with_map):
    """``delta = x_new - x``, ``dg = g_new - g_x``.

    Returns ``(g_x'delta + delta'dg / 2, g_y'delta, max_a s_a |delta_a|_inf, map)``:
    the objective's change (exact for a quadratic), the gradient-mapping
    restart test, the largest change of an unscaled impulse component
    (``s`` of shape ``(nc, m)``: impulse ``= s * q`` componentwise), and, when
    ``with_map``, :func:`natural_map_sq_par` of ``(x_new, g_new)`` read in the same
    pass (else 0).
    """
    nc, m = x.shape
    df = 0.0
    gm = 0.0
    nat = 0.0
    biggest = np.zeros(nc)
    for a in prange(nc):
        part_df = 0.0
        part_gm = 0.0
        big = 0.0
        for k in range(m):
            dl = x_new[a, k] - x[a, k]
            dgk = g_new[a, k] - g_x[a, k]
            delta[a, k] = dl
            dg[a, k] = dgk
            part_df += g_x[a, k] * dl + 0.5 * dl * dgk
            part_gm += g_y[a, k] * dl
            if abs(dl) * s[a, k] > big:
                big = abs(dl) * s[a, k]
        df += part_df
        gm += part_gm
        if with_map:
            nat += _natural_map_part(x_new, g_new, s, rho, mu, a, m)
        biggest[a] = big
    return df, gm, biggest.max() if nc else 0.0, nat


@njit(cache=True, parallel=True)
def extrapolate(x_new, delta, g_new, dg, beta, y, g_y):
    """``y = x_new + beta delta`` and ``g_y = g_new + beta dg``."""
    nc, m = x_new.shape
    for a in prange(nc):
        for k in range(m):
            y[a, k] = x_new[a, k] + beta * delta[a, k]
            g_y[a, k] = g_new[a, k] + beta * dg[a, k]


@njit(cache=True, inline="always")
def _natural_map_part(q, g, s, rho, mu, a, m):
    """Contact ``a``'s term of :func:`natural_map_sq_par`."""
    p0 = s[a, 0] * q[a, 0]
    p1 = s[a, 1] * q[a, 1] if m > 1 else 0.0
    p2 = s[a, 2] * q[a, 2] if m > 2 else 0.0
    x0 = p0 - rho[a] * g[a, 0] / s[a, 0]
    x1 = p1 - rho[a] * g[a, 1] / s[a, 1] if m > 1 else 0.0
    x2 = p2 - rho[a] * g[a, 2] / s[a, 2] if m > 2 else 0.0
    x0, x1, x2 = _project3(x0, x1, x2, mu[a], m)
    return (p0 - x0) ** 2 + (p1 - x1) ** 2 + (p2 - x2) ** 2


@njit(cache=True, parallel=True)
def natural_map_sq_par(q, g, s, rho, mu):
    """``sum_a |p_a - P_K(p_a - rho_a u_a)|^2`` with ``p = s q`` and ``u = g / s`` (componentwise).

    The framework's natural map of the impulses ``p`` (``rho`` per contact,
    ``mu`` the true friction coefficients), read from the scaled iterate ``q``
    and its gradient ``g = s u``.
    """
    nc, m = q.shape
    total = 0.0
    for a in prange(nc):
        total += _natural_map_part(q, g, s, rho, mu, a, m)
    return total
