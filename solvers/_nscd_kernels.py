"""Numba kernel of the NSCD solver (:mod:`solvers.nscd_`): the non-linear Gauss-Seidel
sweep over the contacts, each solved by a local solver of
:mod:`solvers._nscd_local_kernels`.

Arrays are ``float64``; impulses are ``(nc, m)`` with the normal first, ``m`` in
{1, 2, 3}; ``H`` is given by its CSR arrays ``(indptr, indices, data)`` with the
``m`` rows of contact ``a`` at ``a m .. a m + m - 1``. Compiled on first use and
cached on disk (``cache=True``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from solvers._contact_kernels import contact_rest, move_contact
from solvers._nscd_local_kernels import (
    SEPARATED,
    fb_workspace,
    local_2d,
    local_solve,
    local_solve_fb,
)

__all__ = ["LOCAL_EXACT", "LOCAL_FB", "nscd_sweeps"]

#: Local solvers of :func:`nscd_sweeps`.
LOCAL_EXACT = 0
LOCAL_FB = 1


@njit(cache=True)
def nscd_sweeps(
    indptr,
    indices,
    data,
    inv_mass,
    offset,
    W,
    Winv,
    mu,
    p,
    v,
    n_sweeps,
    symmetric,
    relax,
    shift,
    local,
    counts,
):
    """Run ``n_sweeps`` non-linear Gauss-Seidel sweeps over the contacts, in place.

    Contact by contact: ``r_a = H_a v + offset_a - W_aa p_a``, ``p_a`` <- the exact local
    solution (:func:`local_solve`), relaxed by ``relax``, then ``v += M^-1 H_a' (change
    of p_a)`` so that ``v = U + M^-1 H'p`` holds after every contact.

    Parameters
    ----------
    indptr, indices, data, inv_mass, offset, mu, p, v, n_sweeps
        As in :func:`solvers._pgs_kernels.pgs_sweeps`.
    W, Winv : (nc, m, m)
        Diagonal blocks of the Delassus operator and their inverses.
    shift : float
        The problem's ``delassus_shift``: ``H_a M^-1 H_a' = W_aa + shift I``, so
        the contact's own part of ``H_a v`` is ``(W_aa + shift I) p_a``.
    symmetric : bool
        Alternate forward and backward sweeps (symmetric Gauss-Seidel).
    relax : float
        ``p_a <- relax p_local + (1 - relax) p_a`` (stays in the convex cone ``K``).
    local : int
        The local solver: ``LOCAL_EXACT`` (:func:`local_solve`) or ``LOCAL_FB``
        (:func:`local_solve_fb`: Newton on the modified Fischer-Burmeister function from
        the current ``p_a``, the exact solver when Newton fails).
    counts : (2,) int64
        Incremented in place: local solves ended by Newton, and by the exact solver
        after Newton failed (``LOCAL_FB`` only).

    Returns
    -------
    float
        The largest change of an impulse component in the last sweep.
    """
    nc, m = p.shape
    r = np.empty(m)
    out = np.empty(m)
    work = fb_workspace(m)
    biggest = 0.0
    for sweep in range(n_sweeps):
        backward = symmetric and (sweep % 2 == 1)
        biggest = 0.0
        for step in range(nc):
            a = nc - 1 - step if backward else step
            contact_rest(a, indptr, indices, data, v, offset, W, p, shift, r)
            # The 2D law from the block's scalars, read in place: a view of the block
            # per contact (W[a], as local_solve takes it) doubles the sweep's cost,
            # inlined or not. Branch -1: not taken, or at a branch boundary.
            branch = -1
            if local == LOCAL_EXACT and m == 2:
                if r[0] >= 0.0 or W[a, 0, 0] <= 0.0:
                    out[0], out[1], branch = 0.0, 0.0, SEPARATED
                elif mu[a] > 0.0:
                    out[0], out[1], branch = local_2d(
                        W[a, 0, 0], W[a, 0, 1], W[a, 1, 0], W[a, 1, 1],
                        Winv[a, 0, 0], Winv[a, 0, 1], Winv[a, 1, 0], Winv[a, 1, 1],
                        r[0], r[1], mu[a],
                    )  # fmt: skip
            if branch < 0:
                if local == LOCAL_FB:
                    if local_solve_fb(W[a], Winv[a], r, mu[a], p[a], out, work):
                        counts[0] += 1
                    else:
                        counts[1] += 1
                else:  # 3D, frictionless, or a 2D contact at a branch boundary
                    local_solve(W[a], Winv[a], r, mu[a], out)
            if relax != 1.0:
                for k in range(m):
                    out[k] = relax * out[k] + (1.0 - relax) * p[a, k]
            biggest = max(biggest, move_contact(a, out, indptr, indices, data, inv_mass, p, v))
    return biggest
