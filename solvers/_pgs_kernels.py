"""Numba kernel of projected Gauss-Seidel (:mod:`solvers.pgs_`): its sweeps over the contacts.

Arrays are ``float64``; impulses are ``(nc, m)`` with the normal first, ``m`` in
{1, 2, 3}; ``H`` is given by its CSR arrays ``(indptr, indices, data)`` with the
``m`` rows of contact ``a`` at ``a m .. a m + m - 1``. Compiled on first use and
cached on disk (``cache=True``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from solvers._contact_kernels import move_contact, project_contact, row_velocity

__all__ = ["pgs_sweeps"]


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
                w = row_velocity(a * m + k, indptr, indices, data, v, offset)
                x[k] = p[a, k] - step * (w - shift * p[a, k])
            project_contact(x, mu[a])
            biggest = max(biggest, move_contact(a, x, indptr, indices, data, inv_mass, p, v))
        dp_max[sweep] = biggest
