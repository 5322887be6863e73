"""Numba kernels on single contacts, shared by the contact solvers (:mod:`solvers.pgs_`,
:mod:`solvers.bgs_`, :mod:`solvers.nscd_`).

The exact projection on one Coulomb cone, the natural map summed over contacts,
the diagonal Delassus blocks, and the two halves of every Gauss-Seidel visit: a
contact's relative velocity read from ``v``, and the update of ``v`` when its
impulse changes. Arrays are ``float64``; impulses are ``(nc, m)`` with the
normal first, ``m`` in {1, 2, 3}; ``H`` is given by its CSR arrays ``(indptr,
indices, data)`` with the ``m`` rows of contact ``a`` at ``a m .. a m + m - 1``.

Compiled on first use and cached on disk (``cache=True``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = [
    "contact_rest",
    "delassus_blocks",
    "move_contact",
    "natural_map_sq",
    "project_cones",
    "project_contact",
    "project_coulomb_scalars",
    "restart_velocity",
    "row_velocity",
]


@njit(cache=True, inline="always")
def project_coulomb_scalars(xn, t1, t2, mu):
    """``(xn, t1, t2)`` projected on ``{|(t1, t2)| <= mu xn}``, as three scalars.

    ``t2 = 0`` for a contact in 2D. Same closed form as
    :func:`cocd.cones.project_coulomb`; with ``mu = 0`` a point ``(xn < 0, 0)`` is
    outside the cone (``|0| <= 0 * xn`` holds, ``xn >= 0`` does not) and goes to 0.
    Written in scalars so that hot loops (the local residual of :mod:`solvers.nscd_`)
    use it without an array.
    """
    nt = np.sqrt(t1 * t1 + t2 * t2)
    if nt <= mu * xn and xn >= 0.0:
        return xn, t1, t2
    if mu * nt <= -xn:
        return 0.0, 0.0, 0.0
    # Here nt > 0 (nt = 0 is either inside or polar).
    s = (xn + mu * nt) / (1.0 + mu * mu)
    f = mu * s / nt
    return s, t1 * f, t2 * f


@njit(cache=True)
def project_contact(x, mu):
    """Project ``x`` (one contact, normal first, ``m`` in {1, 2, 3} components, as
    :class:`cocd.problem.Problem` allows) on ``{|x_T| <= mu x_N}`` in place.

    ``m = 1`` is the half-line ``x_N >= 0``; otherwise :func:`project_coulomb_scalars`.
    """
    m = x.shape[0]
    if m == 1:
        if x[0] < 0.0:
            x[0] = 0.0
        return
    x0, x1, x2 = project_coulomb_scalars(x[0], x[1], x[2] if m > 2 else 0.0, mu)
    x[0] = x0
    x[1] = x1
    if m > 2:
        x[2] = x2


@njit(cache=True)
def project_cones(x, mu, out):
    """``out = P_K(x)`` contact by contact; ``x, out`` of shape ``(nc, m)`` (may alias)."""
    nc, m = x.shape
    for a in range(nc):
        for k in range(m):
            out[a, k] = x[a, k]
        project_contact(out[a], mu[a])


@njit(cache=True, inline="always")
def row_velocity(row, indptr, indices, data, v, offset):
    """``offset[row] + H[row] v``: one row of the relative velocity ``w = H v + offset``."""
    w = offset[row]
    for idx in range(indptr[row], indptr[row + 1]):
        w += data[idx] * v[indices[idx]]
    return w


@njit(cache=True, inline="always")
def contact_rest(a, indptr, indices, data, v, offset, W, p, shift, r):
    """``r = (W p + b)_a - W_aa p_a``: what the other contacts and the free motion give
    contact ``a`` (``shift`` the problem's ``delassus_shift``, ``W`` its blocks)."""
    m = p.shape[1]
    for k in range(m):
        s = row_velocity(a * m + k, indptr, indices, data, v, offset)
        for ll in range(m):
            s -= W[a, k, ll] * p[a, ll]
        r[k] = s - shift * p[a, k]


@njit(cache=True, inline="always")
def move_contact(a, new, indptr, indices, data, inv_mass, p, v):
    """``p_a <- new`` and ``v += M^-1 H_a' (change of p_a)``, so that ``v = U + M^-1 H'p``
    still holds; returns the largest change of an impulse component."""
    m = p.shape[1]
    biggest = 0.0
    for k in range(m):
        d = new[k] - p[a, k]
        if d != 0.0:
            row = a * m + k
            for idx in range(indptr[row], indptr[row + 1]):
                j = indices[idx]
                v[j] += data[idx] * d * inv_mass[j]
            p[a, k] = new[k]
            if abs(d) > biggest:
                biggest = abs(d)
    return biggest


@njit(cache=True)
def natural_map_sq(indptr, indices, data, v, offset, rho, mu, p, shift, desaxce=False):
    """``sum_a |p_a - P_K(p_a - rho_a w_a)|^2`` with ``w = H v + offset - shift p``
    (``v = U + M^-1 H'p``; ``shift`` is the problem's ``delassus_shift``).

    The numerator of :func:`cocd.residuals.ccp_residual`, squared, in one pass; with
    ``desaxce=True``, De Saxcé's ``w_N + mu |w_T|`` in place of ``w_N``: that of
    :func:`cocd.residuals.coulomb_residual`.
    """
    nc, m = p.shape
    x = np.empty(m)
    total = 0.0
    for a in range(nc):
        for k in range(m):
            x[k] = row_velocity(a * m + k, indptr, indices, data, v, offset) - shift * p[a, k]
        if desaxce and m > 1:
            wt2 = 0.0
            for k in range(1, m):
                wt2 += x[k] * x[k]
            x[0] += mu[a] * np.sqrt(wt2)
        for k in range(m):
            x[k] = p[a, k] - rho[a] * x[k]
        project_contact(x, mu[a])
        for k in range(m):
            d = p[a, k] - x[k]
            total += d * d
    return total


@njit(cache=True)
def restart_velocity(indptr, indices, data, inv_mass, U, p, v):
    """``v = U + M^-1 H'p`` in place, from the CSR arrays of ``H`` (``p`` of shape
    ``(nc, m)``): the velocity the sweeps keep up to date, recomputed from scratch so
    that rounding does not accumulate in it."""
    m = p.shape[1]
    for j in range(v.shape[0]):
        v[j] = 0.0
    for row in range(indptr.shape[0] - 1):
        pk = p[row // m, row % m]
        if pk != 0.0:
            for idx in range(indptr[row], indptr[row + 1]):
                v[indices[idx]] += data[idx] * pk
    for j in range(v.shape[0]):
        v[j] = U[j] + v[j] * inv_mass[j]


@njit(cache=True)
def delassus_blocks(indptr, indices, data, inv_mass, nc, m):
    """Diagonal blocks ``W_aa = H_a M^-1 H_a'`` of the Delassus operator, shape ``(nc, m, m)``.

    Computed from the rows of ``H`` with a dense scratch row (no ``W`` is formed).
    """
    ndof = inv_mass.shape[0]
    scratch = np.zeros(ndof)
    blocks = np.zeros((nc, m, m))
    for a in range(nc):
        for k in range(m):
            row = a * m + k
            for idx in range(indptr[row], indptr[row + 1]):
                scratch[indices[idx]] += data[idx] * inv_mass[indices[idx]]
            for ll in range(k, m):
                other = a * m + ll
                s = 0.0
                for idx in range(indptr[other], indptr[other + 1]):
                    s += data[idx] * scratch[indices[idx]]
                blocks[a, k, ll] = s
                blocks[a, ll, k] = s
            for idx in range(indptr[row], indptr[row + 1]):
                scratch[indices[idx]] = 0.0
    return blocks
