"""numba kernels of the ``ipm`` backend: the reduced matrix ``K = P + A' Theta A``.

Each cone ``g`` (a row of a nonnegative cone, or the three rows of a
second-order cone) touches a few unknowns (at most 6 in 2D, 12 in 3D). Its
rows of ``A`` are stored densely on those unknowns (``local``), with the
positions in ``K``'s upper-triangular CSR data of every pair of them
(``pos``), so that each interior-point iteration writes ``K``'s values in one
pass over the cones, on a pattern (and a symbolic factorisation) fixed for the
whole solve.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["cone_blocks", "fill_reduced", "pair_positions"]


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
    return np.ascontiguousarray(dofs[:, :q]), nq, np.ascontiguousarray(local[:, :, :q])


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

    ``pos[g, a, b]`` for the pair ordered so that row <= column; -1 where unused.
    """
    G, q = dofs.shape
    pos = -np.ones((G, q, q), dtype=np.int64)
    for g in range(G):
        for a in range(nq[g]):
            for b in range(nq[g]):
                i, j = dofs[g, a], dofs[g, b]
                if i > j:
                    continue
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
def fill_reduced(base, dofs, nq, local, group_size, theta, pos, out):  # pragma: no cover
    """``out = base + sum_g A_g' Theta_g A_g`` on the upper-triangular pattern.

    ``theta (G, gmax, gmax)``: each cone's block of ``Theta = (W'W)^-1``.
    """
    out[:] = base
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
            for b in range(n):
                p = pos[g, a, b]
                if p < 0:
                    continue
                s = 0.0
                for k in range(ng):
                    s += local[g, k, a] * tmp[k, b]
                out[p] += s
