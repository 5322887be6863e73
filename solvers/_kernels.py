"""Numba kernels of the iterative contact solvers (:mod:`solvers.pgs_`, :mod:`solvers.apgd_`).

Everything here loops over contacts, which Python cannot do fast: the exact
projection on one Coulomb cone, the projected Gauss-Seidel sweep, and the
per-contact reductions (projected steps, natural maps) of the gradient method.
Arrays are ``float64``; impulses are ``(nc, m)`` with the normal first,
``m`` in {1, 2, 3}; ``H`` is given by its CSR arrays ``(indptr, indices, data)``
with the ``m`` rows of contact ``a`` at ``a m .. a m + m - 1``.

Compiled on first use and cached on disk (``cache=True``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = [
    "natural_map_sq",
    "pgs_sweeps",
    "project_cones",
    "project_contact",
    "projected_step",
    "scaled_natural_map_sq",
]


@njit(cache=True)
def project_contact(x, mu):
    """Project ``x`` (one contact, length ``m``, normal first) on ``{|x_T| <= mu x_N}`` in place.

    ``m = 1`` is the half-line ``x_N >= 0``. Same closed form as
    :func:`cocd.cones.project_coulomb`; with ``mu = 0`` a point ``(x_N < 0, 0)``
    is outside the cone (``|0| <= 0 * x_N`` holds, ``x_N >= 0`` does not) and
    goes to 0.
    """
    m = x.shape[0]
    xn = x[0]
    if m == 1:
        if xn < 0.0:
            x[0] = 0.0
        return
    nt2 = 0.0
    for k in range(1, m):
        nt2 += x[k] * x[k]
    nt = np.sqrt(nt2)
    if nt <= mu * xn and xn >= 0.0:
        return
    if mu * nt <= -xn:
        for k in range(m):
            x[k] = 0.0
        return
    # Here nt > 0 (nt = 0 is either inside or polar).
    s = (xn + mu * nt) / (1.0 + mu * mu)
    x[0] = s
    f = mu * s / nt
    for k in range(1, m):
        x[k] *= f


@njit(cache=True)
def project_cones(x, mu, out):
    """``out = P_K(x)`` contact by contact; ``x, out`` of shape ``(nc, m)`` (may alias)."""
    nc, m = x.shape
    for a in range(nc):
        for k in range(m):
            out[a, k] = x[a, k]
        project_contact(out[a], mu[a])


@njit(cache=True)
def projected_step(y, g, t, mu, out):
    """``out = P_K(y - t g)``, shapes ``(nc, m)``; returns ``max_a |out_a - y_a|_inf``."""
    nc, m = y.shape
    biggest = 0.0
    for a in range(nc):
        for k in range(m):
            out[a, k] = y[a, k] - t * g[a, k]
        project_contact(out[a], mu[a])
        for k in range(m):
            d = abs(out[a, k] - y[a, k])
            if d > biggest:
                biggest = d
    return biggest


@njit(cache=True)
def scaled_natural_map_sq(q, g, s, mu):
    """``sum_a s_a^2 |q_a - P_K(q_a - g_a)|^2``: the squared natural map in scaled variables.

    With ``p_a = s_a q_a`` and ``g_a = s_a w_a`` (``s_a = sqrt(rho_a)``),
    ``s_a (q_a - P_K(q_a - g_a)) = p_a - P_K(p_a - rho_a w_a)``, the ``F_a`` of
    :func:`cocd.residuals.ccp_residual`.
    """
    nc, m = q.shape
    x = np.empty(m)
    total = 0.0
    for a in range(nc):
        for k in range(m):
            x[k] = q[a, k] - g[a, k]
        project_contact(x, mu[a])
        part = 0.0
        for k in range(m):
            d = q[a, k] - x[k]
            part += d * d
        total += s[a] * s[a] * part
    return total


@njit(cache=True)
def natural_map_sq(indptr, indices, data, v, offset, rho, mu, p, shift):
    """``sum_a |p_a - P_K(p_a - rho_a w_a)|^2`` with ``w = H v + offset - shift p``
    (``v = U + M^-1 H'p``; ``shift`` is the problem's ``delassus_shift``).

    The numerator of :func:`cocd.residuals.ccp_residual`, squared, in one pass.
    """
    nc, m = p.shape
    x = np.empty(m)
    total = 0.0
    for a in range(nc):
        for k in range(m):
            row = a * m + k
            w = offset[row]
            for idx in range(indptr[row], indptr[row + 1]):
                w += data[idx] * v[indices[idx]]
            x[k] = p[a, k] - rho[a] * (w - shift * p[a, k])
        project_contact(x, mu[a])
        for k in range(m):
            d = p[a, k] - x[k]
            total += d * d
    return total


@njit(cache=True)
def pgs_sweeps(
    indptr, indices, data, inv_mass, offset, rho, mu, omega, p, v, n_sweeps, dp_max, shift
):
    """Run ``n_sweeps`` projected Gauss-Seidel sweeps over the contacts, in place.

    Contact by contact, in order: ``w_a = H_a v + offset_a - shift p_a`` (``shift``
    the problem's ``delassus_shift``),
    ``p_a <- P_K(p_a - omega rho_a w_a)``, then ``v += M^-1 H_a' (change of p_a)``
    so that ``v = U + M^-1 H'p`` holds after every contact (``H_a`` touches at
    most two grains: the update costs the nonzeros of its rows).

    Parameters
    ----------
    indptr, indices, data : CSR arrays of ``H``, shape ``(m nc, ndof)``
    inv_mass : (ndof,)
    offset : (m nc,)
        ``(D/dt, 0..)`` per contact.
    rho : (nc,)
        Per-contact step ``m / trace(W_aa)``.
    mu : (nc,)
    omega : float
        Over-relaxation factor.
    p : (nc, m)
        Impulses, updated.
    v : (ndof,)
        Generalized velocity ``U + M^-1 H'p``, updated with ``p``.
    n_sweeps : int
    dp_max : (>= n_sweeps,)
        Receives, per sweep, the largest change of an impulse component.
    """
    nc, m = p.shape
    x = np.empty(m)
    for sweep in range(n_sweeps):
        biggest = 0.0
        for a in range(nc):
            step = omega * rho[a]
            for k in range(m):
                row = a * m + k
                w = offset[row]
                for idx in range(indptr[row], indptr[row + 1]):
                    w += data[idx] * v[indices[idx]]
                x[k] = p[a, k] - step * (w - shift * p[a, k])
            project_contact(x, mu[a])
            for k in range(m):
                d = x[k] - p[a, k]
                if d != 0.0:
                    row = a * m + k
                    for idx in range(indptr[row], indptr[row + 1]):
                        j = indices[idx]
                        v[j] += data[idx] * d * inv_mass[j]
                    p[a, k] = x[k]
                    if abs(d) > biggest:
                        biggest = abs(d)
        dp_max[sweep] = biggest
