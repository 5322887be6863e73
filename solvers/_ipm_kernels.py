"""numba kernels of the ``ipm`` backend: the reduced matrix ``K = P + A' Theta A``.

Each group ``g`` of rows of ``A`` (consecutive nonnegative rows on the same
unknowns, such as the two half-planes of a 2D contact, or the three rows of a
second-order cone) touches a few unknowns (at most 6 in 2D, 12 in 3D). Its
rows are stored densely on those unknowns, in increasing order (``local``),
with the positions in ``K``'s upper-triangular CSR data of every pair of them
(``pos``), so that each interior-point iteration writes ``K``'s values in one
pass over the groups, on a pattern (and a symbolic factorisation) fixed for
the whole solve.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = [
    "cone_blocks",
    "fill_linear",
    "fill_reduced",
    "linear_groups",
    "max_step_linear",
    "max_step_soc",
    "pair_positions",
]


@njit(cache=True)
def max_step_linear(x, d):  # pragma: no cover
    """Largest ``alpha`` with ``x + alpha d >= 0`` (``x > 0``), capped at 1e30."""
    best = 1e30
    for i in range(x.size):
        if d[i] < 0.0:
            a = -x[i] / d[i]
            if a < best:
                best = a
    return best


@njit(cache=True)
def max_step_soc(x, d):  # pragma: no cover
    """Largest ``alpha`` with every ``x[c] + alpha d[c]`` in the second-order cone
    (``x (k, 3)`` interior), capped at 1e30."""
    best = 1e30
    for c in range(x.shape[0]):
        x0, x1, x2 = x[c, 0], x[c, 1], x[c, 2]
        d0, d1, d2 = d[c, 0], d[c, 1], d[c, 2]
        cc = x0 * x0 - x1 * x1 - x2 * x2
        bq = x0 * d0 - x1 * d1 - x2 * d2
        a = d0 * d0 - d1 * d1 - d2 * d2
        disc = bq * bq - a * cc
        alpha = np.inf
        if a < 0.0 or (bq < 0.0 and disc >= 0.0):
            den = -bq + np.sqrt(max(disc, 0.0))
            if den > 0.0:
                alpha = max(cc, 0.0) / den
        if d0 < 0.0:
            alpha = min(alpha, -x0 / d0)
        if alpha >= 0.0 and alpha < best:
            best = alpha
    return best


@njit(cache=True)
def fill_linear(dofs, nq, local, group_start, group_size, theta, pos, out):  # pragma: no cover
    """``out += sum_g A_g' diag(theta_g) A_g`` over groups of nonnegative rows;
    ``theta`` is indexed by row (group ``g`` holds rows ``group_start[g] + k``)."""
    for g in range(group_start.size):
        ng = group_size[g]
        n = nq[g]
        r0 = group_start[g]
        for a in range(n):
            for b in range(a, n):
                s = 0.0
                for k in range(ng):
                    s += theta[r0 + k] * local[g, k, a] * local[g, k, b]
                out[pos[g, a, b]] += s


@njit(cache=True)
def linear_groups(indptr, indices, n_lin, largest):  # pragma: no cover
    """Runs of at most ``largest`` consecutive rows among the first ``n_lin`` with
    the same unknowns (sorted CSR indices): their starts and sizes."""
    starts = np.empty(n_lin, dtype=np.int64)
    sizes = np.empty(n_lin, dtype=np.int64)
    g = 0
    r = 0
    while r < n_lin:
        size = 1
        while size < largest and r + size < n_lin:
            a, b = r, r + size
            same = indptr[a + 1] - indptr[a] == indptr[b + 1] - indptr[b]
            if same:
                for t in range(indptr[a + 1] - indptr[a]):
                    if indices[indptr[a] + t] != indices[indptr[b] + t]:
                        same = False
                        break
            if not same:
                break
            size += 1
        starts[g] = r
        sizes[g] = size
        g += 1
        r += size
    return starts[:g], sizes[:g]


def cone_blocks(A_csr, group_start, group_size):
    """Dense local rows of ``A`` per cone.

    Returns ``dofs (G, q)`` (global unknowns, -1 padded), ``nq (G,)`` and
    ``local (G, gmax, q)`` (the cone's rows on its unknowns).
    """
    indptr = A_csr.indptr.astype(np.int64)
    indices = A_csr.indices.astype(np.int64)
    data = A_csr.data.astype(np.float64)
    G = group_start.size
    gmax = int(group_size.max()) if G else 1
    # At most the nonzeros of the cone's rows; trimmed to the largest actual count.
    ends = group_start + group_size
    q = max(int((indptr[ends] - indptr[group_start]).max()) if G else 1, 1)
    dofs, nq, local = _cone_blocks(indptr, indices, data, group_start, group_size, gmax, q)
    q = max(int(nq.max()) if G else 1, 1)
    dofs, local = dofs[:, :q], local[:, :, :q]
    # Unknowns in increasing order (padding last): pair (a, b) is upper iff a <= b.
    order = np.argsort(np.where(dofs < 0, np.iinfo(np.int64).max, dofs), axis=1, kind="stable")
    dofs = np.take_along_axis(dofs, order, axis=1)
    local = np.take_along_axis(local, order[:, None, :], axis=2)
    return np.ascontiguousarray(dofs), nq, np.ascontiguousarray(local)


@njit(cache=True)
def _cone_blocks(indptr, indices, data, group_start, group_size, gmax, q):  # pragma: no cover
    G = group_start.size
    dofs = -np.ones((G, q), dtype=np.int64)
    nq = np.zeros(G, dtype=np.int64)
    local = np.zeros((G, gmax, q))
    for g in range(G):
        n = 0
        for k in range(group_size[g]):
            r = group_start[g] + k
            for idx in range(indptr[r], indptr[r + 1]):
                j = indices[idx]
                slot = -1
                for t in range(n):
                    if dofs[g, t] == j:
                        slot = t
                        break
                if slot < 0:
                    slot = n
                    dofs[g, n] = j
                    n += 1
                local[g, k, slot] += data[idx]
        nq[g] = n
    return dofs, nq, local


@njit(cache=True)
def pair_positions(dofs, nq, indptr, indices):  # pragma: no cover
    """Position in the upper CSR data of ``K`` of each pair ``(dofs[a], dofs[b])``.

    ``pos[g, a, b]`` for ``a <= b`` (the group's unknowns are in increasing order);
    -1 elsewhere.
    """
    G, q = dofs.shape
    pos = -np.ones((G, q, q), dtype=np.int32)
    for g in range(G):
        for a in range(nq[g]):
            for b in range(a, nq[g]):
                i, j = dofs[g, a], dofs[g, b]
                lo, hi = indptr[i], indptr[i + 1]
                while lo < hi:  # binary search of column j in row i
                    mid = (lo + hi) // 2
                    if indices[mid] < j:
                        lo = mid + 1
                    else:
                        hi = mid
                pos[g, a, b] = lo
    return pos


@njit(cache=True)
def fill_reduced(dofs, nq, local, group_size, theta, pos, out):  # pragma: no cover
    """``out += sum_g A_g' Theta_g A_g`` on the upper-triangular pattern.

    ``theta (G, gmax, gmax)``: each group's block of ``Theta = (W'W)^-1``.
    """
    G, q = dofs.shape
    gmax = local.shape[1]
    tmp = np.empty((gmax, q))
    for g in range(G):
        ng = group_size[g]
        n = nq[g]
        for k in range(ng):
            for b in range(n):
                s = 0.0
                for ll in range(ng):
                    s += theta[g, k, ll] * local[g, ll, b]
                tmp[k, b] = s
        for a in range(n):
            for b in range(a, n):
                p = pos[g, a, b]
                s = 0.0
                for k in range(ng):
                    s += local[g, k, a] * tmp[k, b]
                out[p] += s
