"""Numba kernels of block Gauss-Seidel on the cone complementarity problem (:mod:`solvers.bgs_`).

One contact ``a`` with its Delassus block ``W`` (``m x m``, symmetric positive
definite) and the rest ``r = (W p + b)_a - W p_a`` (what the other contacts and the
free motion give) has the convex local problem

    min_p  1/2 p'W p + r'p    s.t.  p in K = {|p_T| <= mu p_N},

whose answer is ``K ∋ p ⊥ W p + r ∈ K*``, the contact's part of the CCP. It is
solved exactly, branch by branch:

- interior (stick): ``p = -W^-1 r`` when it lies in ``K``;
- apex (separation): ``p = 0`` when ``r`` lies in the dual cone ``K* = {mu |r_T| <= r_N}``;
- boundary (slide): ``p = t e`` with ``e = (1, mu cos th, mu sin th)`` and ``t > 0``.
  For a fixed direction the best ``t`` is ``-r.e / e'W e``, which leaves the
  maximisation of ``phi(th) = (r.e)^2 / e'W e`` over the angles with ``r.e < 0``. In
  2D the two directions ``e = (1, +-mu)`` are compared; in 3D a safeguarded Newton
  iteration on ``phi' = 0`` (analytic derivatives; a long step is kept only when
  ``phi`` does not drop) starts from the previous impulse's angle, else the stick
  trial's; when the maximum it ends on has a multiplier of the wrong sign (``phi``
  may have spurious maxima), it starts again from the best of a ring of 32 angles.

Each local answer lowers the dual objective (an exact block minimisation), so the
sweeps are block coordinate descent on a convex quadratic over a product of cones.

The sweep visits the contacts in a given order. For several threads the order is
cut into *colours*: runs of contacts of which no two share a grain, swept in
parallel (``prange``) one colour after the other, so that every thread reads and
writes grains no other thread touches. Arrays are ``float64``; impulses ``(nc, m)``,
normal first, ``m`` in {1, 2, 3}; ``H`` by its CSR arrays with the ``m`` rows of
contact ``a`` at ``a m .. a m + m - 1``. Compiled on first use and cached on disk.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from solvers._contact_kernels import contact_rest, move_contact

__all__ = ["bgs_sweep", "greedy_colours", "local_ccp", "support_depth"]

_NEWTON_ITER = 30
_RING = 31
_TINY = 1e-300


@njit(cache=True, inline="always")
def _ewe(W, e1, e2):
    """``e'W e`` for ``e = (1, e1, e2)``."""
    return (
        W[0, 0]
        + 2.0 * (W[0, 1] * e1 + W[0, 2] * e2)
        + W[1, 1] * e1 * e1
        + 2.0 * W[1, 2] * e1 * e2
        + W[2, 2] * e2 * e2
    )


@njit(cache=True, inline="always")
def _phi(W, r, mu, theta):
    """``(r.e)^2 / e'W e`` when ``r.e < 0`` (else 0) for ``e = (1, mu cos, mu sin)``."""
    c, s = np.cos(theta), np.sin(theta)
    e1, e2 = mu * c, mu * s
    alpha = r[0] + r[1] * e1 + r[2] * e2
    if alpha >= 0.0:
        return 0.0
    beta = _ewe(W, e1, e2)
    if beta <= 0.0:
        return 0.0
    return alpha * alpha / beta


@njit(cache=True, inline="always")
def _newton_step(W, r, mu, theta):
    """Newton's step on ``F = 2 alpha' beta - alpha beta'`` (``phi' = alpha F / beta^2``)."""
    c, s = np.cos(theta), np.sin(theta)
    e1, e2 = mu * c, mu * s  # e = (1, e1, e2)
    d1, d2 = -mu * s, mu * c  # e' = (0, d1, d2)
    f1, f2 = -mu * c, -mu * s  # e'' = (0, f1, f2)
    alpha = r[0] + r[1] * e1 + r[2] * e2
    a1 = r[1] * d1 + r[2] * d2
    a2 = r[1] * f1 + r[2] * f2
    # W e, W e', W e''
    we0 = W[0, 0] + W[0, 1] * e1 + W[0, 2] * e2
    we1 = W[1, 0] + W[1, 1] * e1 + W[1, 2] * e2
    we2 = W[2, 0] + W[2, 1] * e1 + W[2, 2] * e2
    beta = we0 + we1 * e1 + we2 * e2
    b1 = 2.0 * (we1 * d1 + we2 * d2)
    wd1 = W[1, 1] * d1 + W[1, 2] * d2
    wd2 = W[2, 1] * d1 + W[2, 2] * d2
    b2 = 2.0 * (d1 * wd1 + d2 * wd2 + we1 * f1 + we2 * f2)
    F = 2.0 * a1 * beta - alpha * b1
    dF = 2.0 * a2 * beta + a1 * b1 - alpha * b2
    # At a maximum of phi (alpha < 0) F' > 0; elsewhere step uphill by a fixed angle.
    if dF > 0.0:
        step = -F / dF
    else:
        step = -0.25 if F > 0.0 else 0.25
    if step > 0.5:
        step = 0.5
    elif step < -0.5:
        step = -0.5
    return step


@njit(cache=True, inline="always")
def _normal_velocity(W, r, mu, theta):
    """``(W p + r)_N`` at the best ``p = t e`` of the direction ``theta``, relative to ``|r|``."""
    c, s = np.cos(theta), np.sin(theta)
    e1, e2 = mu * c, mu * s
    alpha = r[0] + r[1] * e1 + r[2] * e2
    we0 = W[0, 0] + W[0, 1] * e1 + W[0, 2] * e2
    beta = (
        we0
        + (W[1, 0] + W[1, 1] * e1 + W[1, 2] * e2) * e1
        + (W[2, 0] + W[2, 1] * e1 + W[2, 2] * e2) * e2
    )
    t = -alpha / beta
    scale = abs(r[0]) + abs(r[1]) + abs(r[2])
    return (t * we0 + r[0]) / scale + 1e-9


@njit(cache=True)
def _maximise(W, r, mu, theta, best):
    """Safeguarded Newton ascent of ``phi`` from ``theta`` (``best = phi(theta)``)."""
    for _ in range(_NEWTON_ITER):
        step = _newton_step(W, r, mu, theta)
        if abs(step) < 1e-4:
            # Close to the root: phi is flat to rounding there, Newton on F is not.
            theta += step
            if abs(step) < 1e-11:
                break
            continue
        moved = False
        for _half in range(40):
            val = _phi(W, r, mu, theta + step)
            if val >= best:
                moved = True
                theta += step
                break
            step *= 0.5
        if not moved:
            break
        best = val
    return theta, _phi(W, r, mu, theta)


@njit(cache=True, inline="always")
def local_ccp(W, Winv, r, mu, previous, out):
    """Exact answer ``out`` (length ``m``) of one contact's convex local problem.

    ``W``, ``Winv``: the ``m x m`` block and its inverse; ``r``: the rest;
    ``previous``: the contact's current impulse (a starting angle in 3D).
    Returns 0 for the apex, 1 for the interior, 2 for the boundary.
    """
    m = r.shape[0]
    for k in range(m):
        out[k] = 0.0
    if W[0, 0] <= 0.0:
        return 0
    if m == 1 or mu == 0.0:
        pn = -r[0] / W[0, 0]
        if pn > 0.0:
            out[0] = pn
            return 1
        return 0
    # Interior: the unconstrained minimiser.
    q0 = 0.0
    q1 = 0.0
    q2 = 0.0
    for k in range(m):
        q0 -= Winv[0, k] * r[k]
        q1 -= Winv[1, k] * r[k]
        if m == 3:
            q2 -= Winv[2, k] * r[k]
    qt = np.sqrt(q1 * q1 + q2 * q2)
    if q0 >= 0.0 and qt <= mu * q0:
        out[0] = q0
        out[1] = q1
        if m == 3:
            out[2] = q2
        return 1
    # Apex: r in the dual cone.
    rt = abs(r[1]) if m == 2 else np.sqrt(r[1] * r[1] + r[2] * r[2])
    if mu * rt <= r[0]:
        return 0
    if m == 2:
        best = 0.0
        for sgn in (1.0, -1.0):
            e1 = sgn * mu
            alpha = r[0] + r[1] * e1
            beta = W[0, 0] + 2.0 * W[0, 1] * e1 + W[1, 1] * e1 * e1
            if alpha < 0.0 and beta > 0.0 and alpha * alpha / beta > best:
                best = alpha * alpha / beta
                t = -alpha / beta
                out[0] = t
                out[1] = t * e1
        return 2 if best > 0.0 else 0
    # 3D boundary: maximise phi over the angle, by Newton from the previous impulse's
    # angle (the answer of the last sweep: usually a few steps away), else from the
    # stick trial's (about three steps in the 3D column).
    theta_q = np.arctan2(q2, q1) if qt > 0.0 else np.arctan2(-r[2], -r[1])
    pt = np.sqrt(previous[1] * previous[1] + previous[2] * previous[2])
    theta = np.arctan2(previous[2], previous[1]) if pt > 0.0 else theta_q
    best = _phi(W, r, mu, theta)
    theta, best = _maximise(W, r, mu, theta, best)
    # A maximum of phi is the answer when its multiplier has the right sign, i.e.
    # w = W p + r = lambda (mu, -cos, -sin) with lambda >= 0 (w_N >= 0); phi may have
    # other, spurious maxima: then search a ring of starts for the highest.
    if best <= 0.0 or _normal_velocity(W, r, mu, theta) < 0.0:
        start_theta = theta_q
        start_best = _phi(W, r, mu, theta_q)
        for k in range(_RING):
            cand = theta_q + 2.0 * np.pi * (k + 1) / (_RING + 1)
            val = _phi(W, r, mu, cand)
            if val > start_best:
                start_best, start_theta = val, cand
        cand_theta, cand_best = _maximise(W, r, mu, start_theta, start_best)
        if cand_best > best:
            theta, best = cand_theta, cand_best
    if best <= 0.0:
        return 0
    c, s = np.cos(theta), np.sin(theta)
    e1, e2 = mu * c, mu * s
    alpha = r[0] + r[1] * e1 + r[2] * e2
    beta = _ewe(W, e1, e2)
    t = -alpha / max(beta, _TINY)
    out[0] = t
    out[1] = t * e1
    out[2] = t * e2
    return 2


@njit(cache=True, inline="always")
def _visit(a, indptr, indices, data, inv_mass, offset, W, Winv, mu, p, v, shift, r, out):
    """Solve contact ``a`` with the others fixed; update ``p[a]`` and ``v``; return the
    largest change of an impulse component."""
    contact_rest(a, indptr, indices, data, v, offset, W, p, shift, r)
    local_ccp(W[a], Winv[a], r, mu[a], p[a], out)
    return move_contact(a, out, indptr, indices, data, inv_mass, p, v)


@njit(cache=True, parallel=True)
def bgs_sweep(indptr, indices, data, inv_mass, offset, W, Winv, mu, p, v, order, starts, shift):
    """One block Gauss-Seidel sweep over ``order``, in place; returns the largest change
    of an impulse component.

    ``starts`` cuts ``order`` into colours (``order[starts[c]:starts[c + 1]]``); the
    contacts of one colour share no grain and are visited in parallel, the colours one
    after the other. One colour holding every contact (``starts = [0, nc]``) must be
    visited in order: pass ``starts`` of length 2 with ``order`` for a sequential sweep.
    """
    m = p.shape[1]
    n_colours = starts.shape[0] - 1
    biggest = 0.0
    if n_colours == 1:
        r = np.empty(m)
        out = np.empty(m)
        for step in range(starts[0], starts[1]):
            d = _visit(order[step], indptr, indices, data, inv_mass, offset, W, Winv, mu, p, v,
                       shift, r, out)  # fmt: skip
            if d > biggest:
                biggest = d
        return biggest
    for c in range(n_colours):
        lo, hi = starts[c], starts[c + 1]
        chunk = 256
        n_chunks = (hi - lo + chunk - 1) // chunk
        local_max = np.zeros(n_chunks)
        for b in prange(n_chunks):
            r = np.empty(m)
            out = np.empty(m)
            top = min(hi, lo + (b + 1) * chunk)
            mx = 0.0
            for step in range(lo + b * chunk, top):
                d = _visit(order[step], indptr, indices, data, inv_mass, offset, W, Winv, mu,
                           p, v, shift, r, out)  # fmt: skip
                if d > mx:
                    mx = d
            local_max[b] = mx
        for b in range(n_chunks):
            if local_max[b] > biggest:
                biggest = local_max[b]
    return biggest


@njit(cache=True)
def greedy_colours(order, indptr, indices, m, ndof):
    """Colour the contacts greedily, in ``order``, so that no two of one colour share an
    unknown (a column of ``H``): each contact takes the smallest colour free at every
    unknown it touches. Returns the colour of every contact, ``(nc,)``."""
    nc = order.shape[0]
    colour = np.full(nc, -1, dtype=np.int64)
    words = 2
    used = np.zeros((ndof, words), dtype=np.uint64)
    for step in range(nc):
        a = order[step]
        lo, hi = indptr[a * m], indptr[a * m + m]
        c = 0
        while True:
            w = c // 64
            if w >= words:
                grown = np.zeros((ndof, 2 * words), dtype=np.uint64)
                grown[:, :words] = used
                used = grown
                words *= 2
            bit = np.uint64(1) << np.uint64(c % 64)
            taken = False
            for idx in range(lo, hi):
                if (used[indices[idx], w] & bit) != 0:
                    taken = True
                    break
            if not taken:
                break
            c += 1
        colour[a] = c
        w = c // 64
        bit = np.uint64(1) << np.uint64(c % 64)
        for idx in range(lo, hi):
            used[indices[idx], w] |= bit
    return colour


@njit(cache=True)
def support_depth(indptr, indices, col_ptr, col_rows, m, nc):
    """Graph distance of every contact from the supports, ``(nc,)``.

    Supports are the contacts that touch at most half as many unknowns as the
    most connected one (a grain on a wall or on a fixed grain touches one grain's
    unknowns, a grain pair two); two contacts are neighbours when they share an
    unknown. ``col_ptr, col_rows``: ``H`` in CSC form (column to rows). Contacts
    no support reaches get the largest depth plus one.
    """
    touched = np.zeros(nc, dtype=np.int64)
    widest = 0
    for a in range(nc):
        touched[a] = indptr[a * m + 1] - indptr[a * m]
        for k in range(1, m):
            n_k = indptr[a * m + k + 1] - indptr[a * m + k]
            if n_k > touched[a]:
                touched[a] = n_k
        if touched[a] > widest:
            widest = touched[a]
    depth = np.full(nc, -1, dtype=np.int64)
    queue = np.empty(nc, dtype=np.int64)
    head = 0
    tail = 0
    for a in range(nc):
        if 2 * touched[a] <= widest:
            depth[a] = 0
            queue[tail] = a
            tail += 1
    while head < tail:
        a = queue[head]
        head += 1
        for k in range(m):
            row = a * m + k
            for idx in range(indptr[row], indptr[row + 1]):
                col = indices[idx]
                for jdx in range(col_ptr[col], col_ptr[col + 1]):
                    b = col_rows[jdx] // m
                    if depth[b] < 0:
                        depth[b] = depth[a] + 1
                        queue[tail] = b
                        tail += 1
    deepest = 0
    for a in range(nc):
        if depth[a] > deepest:
            deepest = depth[a]
    for a in range(nc):
        if depth[a] < 0:
            depth[a] = deepest + 1
    return depth
