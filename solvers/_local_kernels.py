"""Numba kernels of the local form (:mod:`solvers.local`): Gauss-Seidel on ``u = W r + q``
with ``W`` itself, symmetric or not, in block-CSR form.

``W`` is given by its block rows: ``indptr`` (``nc + 1``), ``indices`` (block columns)
and ``blocks`` (``(nnzb, m, m)``), contact ``a``'s row holding the blocks ``W_ab``;
``Wd`` (``(nc, m, m)``) are the diagonal blocks ``W_aa`` and ``Wdinv`` their inverses
(zero for a singular block). Impulses ``r`` and ``q`` are ``(nc, m)``, normal first,
``m`` in {1, 2, 3}.

A sweep visits the contacts in order (backward on odd sweeps when ``symmetric``); at
contact ``a`` it sums ``q'_a = q_a + sum_{b != a} W_ab r_b`` over row ``a`` with the
current impulses and replaces ``r_a`` by

- ``NSCD``: the exact solution of the one-contact Coulomb law on ``W_aa`` with the
  rest ``q'_a`` (:func:`solvers._nscd_local_kernels.local_solve`, or its
  Fischer-Burmeister Newton with the exact solver as fallback), relaxed by ``relax``;
- ``PGS``: the projected step ``P_K(r_a - omega rho_a (q'_a + W_aa r_a))``,
  ``rho_a = m / trace(W_aa)``.

The stopping test rides on the sweep. Over the same row it also sums the velocity
``u_a = (W r^k + q)_a`` of the impulses ``r^k`` the sweep started from (for the
contacts already visited, from a copy of their earlier impulses; for the others the
two sums coincide), so the error of ``r^k`` is exact and costs no second pass over
``W``: ``sqrt(sum_a |r_a - P_K(r_a - s_a û_a)|^2) / den`` with ``û = u + (mu |u_T|,
0)`` for ``NSCD`` (De Saxcé's velocity, Coulomb's law) and ``û = u`` for ``PGS`` (the
convex problem), ``s_a`` and ``den`` the criterion's scales (:mod:`solvers.local`).
The sweep after which it is ``<= tol`` is the last, and its starting impulses are the
answer; otherwise the impulses of least error seen are kept.

Compiled on first use and cached on disk (``cache=True``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from solvers._apgd_kernels import _project3
from solvers._nscd_local_kernels import fb_workspace, local_solve, local_solve_fb

__all__ = [
    "LOCAL_EXACT",
    "LOCAL_FB",
    "NSCD",
    "PGS",
    "branch_counts",
    "local_error",
    "local_sweeps",
    "local_velocity",
]

#: Methods of :func:`local_sweeps`.
NSCD = 0
PGS = 1
#: Local solvers of the NSCD method (as :mod:`solvers._nscd_kernels`).
LOCAL_EXACT = 0
LOCAL_FB = 1


@njit(cache=True, inline="always")
def _block_times(blocks, j, x, c, m):
    """``W_j x_c`` for block ``j`` (components beyond ``m`` are 0), written out per ``m``."""
    if m == 3:
        x0, x1, x2 = x[c, 0], x[c, 1], x[c, 2]
        return (
            blocks[j, 0, 0] * x0 + blocks[j, 0, 1] * x1 + blocks[j, 0, 2] * x2,
            blocks[j, 1, 0] * x0 + blocks[j, 1, 1] * x1 + blocks[j, 1, 2] * x2,
            blocks[j, 2, 0] * x0 + blocks[j, 2, 1] * x1 + blocks[j, 2, 2] * x2,
        )
    if m == 2:
        x0, x1 = x[c, 0], x[c, 1]
        return (
            blocks[j, 0, 0] * x0 + blocks[j, 0, 1] * x1,
            blocks[j, 1, 0] * x0 + blocks[j, 1, 1] * x1,
            0.0,
        )
    return blocks[j, 0, 0] * x[c, 0], 0.0, 0.0


@njit(cache=True, inline="always")
def _contact_error(r, a, u0, u1, u2, mu, s, desaxce, m):
    """``|r_a - P_K(r_a - s û)|^2`` of one contact (``û`` De Saxcé's ``u`` when ``desaxce``)."""
    r0 = r[a, 0]
    r1 = r[a, 1] if m > 1 else 0.0
    r2 = r[a, 2] if m > 2 else 0.0
    x0 = r0 - s * u0
    if desaxce and m > 1:
        x0 -= s * mu * np.sqrt(u1 * u1 + u2 * u2)
    x0, x1, x2 = _project3(x0, r1 - s * u1, r2 - s * u2, mu, m)
    d0, d1, d2 = r0 - x0, r1 - x1, r2 - x2
    return d0 * d0 + d1 * d1 + d2 * d2


@njit(cache=True, inline="always")
def _pgs_step(r, a, w0, w1, w2, step, mu, m):
    """``r_a <- P_K(r_a - step w)``."""
    x0 = r[a, 0] - step * w0
    if m == 1:
        r[a, 0] = max(x0, 0.0)
        return
    x1 = r[a, 1] - step * w1
    x2 = r[a, 2] - step * w2 if m > 2 else 0.0
    x0, x1, x2 = _project3(x0, x1, x2, mu, m)
    r[a, 0] = x0
    r[a, 1] = x1
    if m > 2:
        r[a, 2] = x2


@njit(cache=True)
def _ratio(num, den):
    """``num / den`` with ``0 / x = 0`` and ``x / 0 = inf`` (as :func:`cocd.residuals`)."""
    if num == 0.0:
        return 0.0
    if den > 0.0:
        return num / den
    return np.inf


@njit(cache=True)
def local_velocity(indptr, indices, blocks, q, r, u):
    """``u = W r + q`` (all ``(nc, m)``)."""
    nc, m = r.shape
    for a in range(nc):
        for k in range(m):
            u[a, k] = q[a, k]
        for j in range(indptr[a], indptr[a + 1]):
            w0, w1, w2 = _block_times(blocks, j, r, indices[j], m)
            u[a, 0] += w0
            if m > 1:
                u[a, 1] += w1
            if m > 2:
                u[a, 2] += w2


@njit(cache=True)
def local_error(indptr, indices, blocks, q, mu, scale, desaxce, den, r):
    """The error of ``r`` (module docstring), one pass over ``W``."""
    nc, m = r.shape
    total = 0.0
    for a in range(nc):
        u0 = q[a, 0]
        u1 = q[a, 1] if m > 1 else 0.0
        u2 = q[a, 2] if m > 2 else 0.0
        for j in range(indptr[a], indptr[a + 1]):
            w0, w1, w2 = _block_times(blocks, j, r, indices[j], m)
            u0 += w0
            u1 += w1
            u2 += w2
        total += _contact_error(r, a, u0, u1, u2, mu[a], scale[a], desaxce, m)
    return _ratio(np.sqrt(total), den)


@njit(cache=True)
def local_sweeps(
    indptr,
    indices,
    blocks,
    Wd,
    Wdinv,
    q,
    mu,
    rho,
    r,
    best,
    state,
    history,
    method,
    local,
    relax,
    omega,
    symmetric,
    first_sweep,
    n_sweeps,
    tol,
    scale,
    desaxce,
    den,
    counts,
):
    """Up to ``n_sweeps`` Gauss-Seidel sweeps on ``u = W r + q``, in place (module docstring).

    Parameters
    ----------
    indptr, indices, blocks, Wd, Wdinv, q, mu
        The problem (module docstring).
    rho : (nc,)
        ``m / trace(W_aa)`` (0 for a block without a positive trace): ``PGS``'s step.
    r : (nc, m)
        Impulses, updated: after the call, those of the last sweep.
    best : (nc, m)
        Receives the impulses of least error seen when they improve on ``state[0]``
        (the caller starts it with the starting impulses: an error that is never
        finite keeps them).
    state : (1,)
        ``state[0]``: the least error seen so far (``inf`` at first), updated; a NaN
        error never improves on it.
    history : (>= n_sweeps,)
        Receives the error of the impulses each sweep started from.
    method : int
        ``NSCD`` or ``PGS``.
    local : int
        ``NSCD``'s local solver: ``LOCAL_EXACT`` or ``LOCAL_FB``.
    relax, omega : float
        ``NSCD``'s relaxation, ``PGS``'s over-relaxation.
    symmetric : bool
        Alternate forward and backward sweeps (counted from ``first_sweep``).
    first_sweep, n_sweeps : int
        Sweeps done before this call, and the most to do in it.
    tol : float
        Stop after the sweep that finds its starting impulses' error ``<= tol``.
    scale : (nc,), desaxce : bool, den : float
        The criterion (module docstring).
    counts : (2,) int64
        Local solves ended by Newton, and by the exact solver after Newton failed
        (``LOCAL_FB``), incremented.

    Returns
    -------
    (int, bool)
        Sweeps done, and whether the impulses in ``best`` meet ``tol``.
    """
    nc, m = r.shape
    prev = np.empty_like(r)
    keep = np.empty_like(r)
    kept = False
    rest = np.zeros(m)
    out = np.empty(m)
    work = fb_workspace(m)
    best_err = state[0]
    done = 0
    converged = False
    for sweep in range(n_sweeps):
        backward = symmetric and ((first_sweep + sweep) % 2 == 1)
        for a in range(nc):
            for k in range(m):
                prev[a, k] = r[a, k]
        total = 0.0
        for step in range(nc):
            a = nc - 1 - step if backward else step
            # rest: q'_a with the current impulses; old: (W r^k + q)_a.
            rest0 = q[a, 0]
            rest1 = q[a, 1] if m > 1 else 0.0
            rest2 = q[a, 2] if m > 2 else 0.0
            old0, old1, old2 = rest0, rest1, rest2
            for j in range(indptr[a], indptr[a + 1]):
                c = indices[j]
                if c == a:
                    continue
                w0, w1, w2 = _block_times(blocks, j, r, c, m)
                rest0 += w0
                rest1 += w1
                rest2 += w2
                if (c > a) if backward else (c < a):  # visited: r^k_c is in prev
                    w0, w1, w2 = _block_times(blocks, j, prev, c, m)
                old0 += w0
                old1 += w1
                old2 += w2
            # Contact a has not moved yet this sweep: r_a is still r^k_a.
            own0, own1, own2 = _block_times(Wd, a, r, a, m)
            old0 += own0
            old1 += own1
            old2 += own2
            total += _contact_error(r, a, old0, old1, old2, mu[a], scale[a], desaxce, m)
            if method == NSCD:
                rest[0] = rest0
                if m > 1:
                    rest[1] = rest1
                if m > 2:
                    rest[2] = rest2
                if local == LOCAL_FB:
                    if local_solve_fb(Wd[a], Wdinv[a], rest, mu[a], r[a], out, work):
                        counts[0] += 1
                    else:
                        counts[1] += 1
                else:
                    local_solve(Wd[a], Wdinv[a], rest, mu[a], out)
                for k in range(m):
                    if relax != 1.0:
                        r[a, k] = relax * out[k] + (1.0 - relax) * r[a, k]
                    else:
                        r[a, k] = out[k]
            else:
                step_a = omega * rho[a]
                _pgs_step(r, a, rest0 + own0, rest1 + own1, rest2 + own2, step_a, mu[a], m)
        err = _ratio(np.sqrt(total), den)
        history[sweep] = err
        done += 1
        if err < best_err:
            best_err = err
            prev, keep = keep, prev
            kept = True
        if best_err <= tol:
            converged = True
            break
    if kept:
        for a in range(nc):
            for k in range(m):
                best[a, k] = keep[a, k]
    if not converged and done > 0:
        # The impulses of the last sweep, not yet judged.
        err = local_error(indptr, indices, blocks, q, mu, scale, desaxce, den, r)
        if err < best_err:
            best_err = err
            for a in range(nc):
                for k in range(m):
                    best[a, k] = r[a, k]
            converged = best_err <= tol
    state[0] = best_err
    return done, converged


@njit(cache=True)
def branch_counts(r, mu):
    """How many contacts are separated (``r_N <= 0``), sticking (inside the cone) and
    sliding (on its boundary, ``r_N > 0``), as ``nscd``'s ``branches``."""
    nc, m = r.shape
    separated = 0
    slide = 0
    for a in range(nc):
        rn = r[a, 0]
        if rn <= 0.0:
            separated += 1
            continue
        if m > 1:
            nt = 0.0
            for k in range(1, m):
                nt += r[a, k] * r[a, k]
            if np.sqrt(nt) >= mu[a] * rn * (1.0 - 1e-9):
                slide += 1
    return separated, nc - separated - slide, slide
