"""The contact Jacobian by contact blocks: ``H x`` and ``H' p`` reading far less than CSR.

A scene's Jacobian (:func:`cocd.contacts.contact_jacobian`) has a structure CSR
does not use: the rows of contact ``a`` touch at most two grains, each through a
block of its ``per_grain`` unknowns (``d`` translations, then ``r`` rotations),
and the two blocks share their numbers: ``(+T_a, R_a)`` on one grain and
``(-T_a, R_a)`` on the other, with ``T_a`` the ``(m, d)`` contact frame and
``R_a`` its ``(m, r)`` rotational rows. Stored so (``T``, ``R`` and each
contact's two first unknowns), a product reads 18 numbers per 3D contact where
CSR reads 30 values and 30 column indices, and gathers each grain's unknowns
contiguously. The kernels are unrolled for 3D and 2D contacts with friction; what
this gains an APGD iteration is measured by
``benchmarks/test_bench_apgd_operator.py``.

:func:`contact_blocks` reads the blocks off any CSR matrix: the rows of each
contact's first grain give them, and every column of its second grain's rows is
compared with them (stored zeros and duplicates summed, as CSR sums them), so
that the block products equal the CSR ones exactly (to the order of the sums).
A matrix without this structure (an external problem, a layout other than
cocd's) gives None, and the caller keeps CSR. cocd's Jacobians have it because
their rotational unknowns are spin times radius, so the rotational rows,
``-(n x t)``, are the same for both grains. Rows are scaled as the matrix is:
the blocks of ``diag(s) H`` are read from ``diag(s) H``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
import scipy.sparse as sp
from numba import njit, prange

from solvers.base import FloatArray

__all__ = ["ContactBlocks", "contact_blocks"]

#: Most shares of the contacts scattered at once by ``H' p``.
MAX_SHARES = 8


@dataclass(eq=False)
class ContactBlocks:
    """``H`` of shape ``(m nc, ndof)`` as per-contact blocks (see the module).

    ``T``: ``(nc, m, d)``, on the translations of grain ``first[a, 0]`` (plus) and
    of ``first[a, 1]`` (minus); ``R``: ``(nc, m, r)``, on the rotations of both;
    ``first``: ``(nc, 2)``, the first column of each grain's block of ``per_grain``
    unknowns, -1 for none.
    """

    T: FloatArray
    R: FloatArray
    first: np.ndarray
    ndof: int

    def __post_init__(self) -> None:
        # On several threads, H' p scatters into private copies of the result, one per
        # thread (at most MAX_SHARES: their sum is read at every product), then sums them.
        threads = min(numba.get_num_threads(), MAX_SHARES)
        self._buffers = np.zeros((threads, self.ndof)) if threads > 1 else None
        self._scaled = np.empty(self.ndof)

    def matvec_scaled_add(
        self, scale: FloatArray, z: FloatArray, base: FloatArray, out: FloatArray
    ) -> None:
        """``out = base + H (scale * z)`` (flat arrays)."""
        np.multiply(scale, z, out=self._scaled)
        _blocks_matvec_add(self.T, self.R, self.first, self._scaled, base, out)

    def rmatvec(self, p: FloatArray, out: FloatArray) -> None:
        """``out = H' p`` (flat arrays)."""
        if self._buffers is None:
            _blocks_rmatvec_serial(self.T, self.R, self.first, p, out)
        else:
            _blocks_rmatvec(self.T, self.R, self.first, p, self._buffers, out)


def contact_blocks(H: sp.csr_matrix, m: int, d: int, per_grain: int) -> ContactBlocks | None:
    """``H`` (``m`` rows per contact) as :class:`ContactBlocks` with ``d`` translations
    and ``per_grain - d`` rotations per grain, or None when it does not have that
    structure exactly."""
    rows, ndof = H.shape
    if m < 1 or rows % m or not 0 < d <= per_grain or ndof % per_grain:
        return None
    H = sp.csr_matrix(H)
    nc = rows // m
    T = np.zeros((nc, m, d))
    R = np.zeros((nc, m, per_grain - d))
    first = np.full((nc, 2), -1, dtype=np.int64)
    ok = _read_blocks(
        H.indptr.astype(np.int64, copy=False),
        H.indices.astype(np.int64, copy=False),
        H.data.astype(np.float64, copy=False),
        per_grain,
        T,
        R,
        first,
    )
    return ContactBlocks(T, R, first, ndof) if ok else None


@njit(cache=True)
def _read_blocks(indptr, indices, data, per_grain, T, R, first):  # pragma: no cover - compiled
    """Fill ``T``, ``R``, ``first`` from the CSR arrays; False as soon as a row does not
    fit: a third grain, or a second grain whose row is not the first's with the
    translations negated (every column compared, stored zeros and duplicates summed
    as CSR sums them)."""
    nc, m, d = T.shape
    lo_v = np.zeros(per_grain)
    hi_v = np.zeros(per_grain)
    for a in range(nc):
        lo = -1
        hi = -1
        for k in range(m):
            row = a * m + k
            for idx in range(indptr[row], indptr[row + 1]):
                g = indices[idx] - indices[idx] % per_grain
                if g == lo or g == hi:
                    continue
                if lo < 0:
                    lo = g
                elif hi < 0:
                    hi = g
                else:
                    return False
        if hi >= 0 and hi < lo:
            lo, hi = hi, lo
        first[a, 0] = lo
        first[a, 1] = hi
        for k in range(m):
            row = a * m + k
            lo_v[:] = 0.0
            hi_v[:] = 0.0
            for idx in range(indptr[row], indptr[row + 1]):
                col = indices[idx]
                if col - col % per_grain == lo:
                    lo_v[col - lo] += data[idx]
                else:
                    hi_v[col - hi] += data[idx]
            for c in range(per_grain):
                if c < d:
                    T[a, k, c] = lo_v[c]
                    if hi >= 0 and hi_v[c] != -lo_v[c]:
                        return False
                else:
                    R[a, k, c - d] = lo_v[c]
                    if hi >= 0 and hi_v[c] != lo_v[c]:
                        return False
    return True


@njit(cache=True, parallel=True)
def _blocks_matvec_add(T, R, first, w, base, out):  # pragma: no cover - compiled
    """``out = base + H w`` from the blocks; unrolled for 3D and 2D contacts with
    friction, the general loops otherwise."""
    nc, m, d = T.shape
    r = R.shape[2]
    if m == 3 and d == 3 and r == 3:
        for a in prange(nc):
            i = first[a, 0]
            j = first[a, 1]
            v0 = v1 = v2 = s0 = s1 = s2 = 0.0
            if i >= 0:
                v0, v1, v2 = w[i], w[i + 1], w[i + 2]
                s0, s1, s2 = w[i + 3], w[i + 4], w[i + 5]
            if j >= 0:
                v0, v1, v2 = v0 - w[j], v1 - w[j + 1], v2 - w[j + 2]
                s0, s1, s2 = s0 + w[j + 3], s1 + w[j + 4], s2 + w[j + 5]
            for k in range(3):
                out[3 * a + k] = (
                    base[3 * a + k]
                    + (T[a, k, 0] * v0 + T[a, k, 1] * v1 + T[a, k, 2] * v2)
                    + (R[a, k, 0] * s0 + R[a, k, 1] * s1 + R[a, k, 2] * s2)
                )
    elif m == 2 and d == 2 and r == 1:
        for a in prange(nc):
            i = first[a, 0]
            j = first[a, 1]
            v0 = v1 = s0 = 0.0
            if i >= 0:
                v0, v1, s0 = w[i], w[i + 1], w[i + 2]
            if j >= 0:
                v0, v1, s0 = v0 - w[j], v1 - w[j + 1], s0 + w[j + 2]
            for k in range(2):
                out[2 * a + k] = (
                    base[2 * a + k] + (T[a, k, 0] * v0 + T[a, k, 1] * v1) + R[a, k, 0] * s0
                )
    else:
        for a in prange(nc):
            i = first[a, 0]
            j = first[a, 1]
            for k in range(m):
                acc = base[a * m + k]
                if i >= 0:
                    for c in range(d):
                        acc += T[a, k, c] * w[i + c]
                    for c in range(r):
                        acc += R[a, k, c] * w[i + d + c]
                if j >= 0:
                    for c in range(d):
                        acc -= T[a, k, c] * w[j + c]
                    for c in range(r):
                        acc += R[a, k, c] * w[j + d + c]
                out[a * m + k] = acc


@njit(cache=True)
def _scatter(T, R, first, p, out, lo, hi):  # pragma: no cover - compiled
    """``out += H' p`` over contacts ``lo`` to ``hi`` (exclusive); unrolled for 3D and
    2D contacts with friction, the general loops otherwise."""
    _, m, d = T.shape
    r = R.shape[2]
    if m == 3 and d == 3 and r == 3:
        for a in range(lo, hi):
            i = first[a, 0]
            j = first[a, 1]
            p0, p1, p2 = p[3 * a], p[3 * a + 1], p[3 * a + 2]
            f0 = T[a, 0, 0] * p0 + T[a, 1, 0] * p1 + T[a, 2, 0] * p2
            f1 = T[a, 0, 1] * p0 + T[a, 1, 1] * p1 + T[a, 2, 1] * p2
            f2 = T[a, 0, 2] * p0 + T[a, 1, 2] * p1 + T[a, 2, 2] * p2
            g0 = R[a, 0, 0] * p0 + R[a, 1, 0] * p1 + R[a, 2, 0] * p2
            g1 = R[a, 0, 1] * p0 + R[a, 1, 1] * p1 + R[a, 2, 1] * p2
            g2 = R[a, 0, 2] * p0 + R[a, 1, 2] * p1 + R[a, 2, 2] * p2
            if i >= 0:
                out[i] += f0
                out[i + 1] += f1
                out[i + 2] += f2
                out[i + 3] += g0
                out[i + 4] += g1
                out[i + 5] += g2
            if j >= 0:
                out[j] -= f0
                out[j + 1] -= f1
                out[j + 2] -= f2
                out[j + 3] += g0
                out[j + 4] += g1
                out[j + 5] += g2
    elif m == 2 and d == 2 and r == 1:
        for a in range(lo, hi):
            i = first[a, 0]
            j = first[a, 1]
            p0, p1 = p[2 * a], p[2 * a + 1]
            f0 = T[a, 0, 0] * p0 + T[a, 1, 0] * p1
            f1 = T[a, 0, 1] * p0 + T[a, 1, 1] * p1
            g0 = R[a, 0, 0] * p0 + R[a, 1, 0] * p1
            if i >= 0:
                out[i] += f0
                out[i + 1] += f1
                out[i + 2] += g0
            if j >= 0:
                out[j] -= f0
                out[j + 1] -= f1
                out[j + 2] += g0
    else:
        for a in range(lo, hi):
            i = first[a, 0]
            j = first[a, 1]
            for c in range(d):
                f = 0.0
                for k in range(m):
                    f += T[a, k, c] * p[a * m + k]
                if i >= 0:
                    out[i + c] += f
                if j >= 0:
                    out[j + c] -= f
            for c in range(r):
                g = 0.0
                for k in range(m):
                    g += R[a, k, c] * p[a * m + k]
                if i >= 0:
                    out[i + d + c] += g
                if j >= 0:
                    out[j + d + c] += g


@njit(cache=True)
def _blocks_rmatvec_serial(T, R, first, p, out):  # pragma: no cover - compiled
    """``out = H' p`` from the blocks, on one thread."""
    out[:] = 0.0
    _scatter(T, R, first, p, out, 0, T.shape[0])


@njit(cache=True, parallel=True)
def _blocks_rmatvec(T, R, first, p, buffers, out):  # pragma: no cover - compiled
    """``out = H' p`` from the blocks: each thread scatters a share of the contacts
    into its own buffer, then the buffers are summed."""
    nc = T.shape[0]
    chunks, ndof = buffers.shape
    for t in prange(chunks):
        buffers[t, :] = 0.0
        _scatter(T, R, first, p, buffers[t], t * nc // chunks, (t + 1) * nc // chunks)
    for q in prange(ndof):
        total = 0.0
        for t in range(chunks):
            total += buffers[t, q]
        out[q] = total
