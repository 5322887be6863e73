"""Contact detection, contact frames and the contact Jacobian.

A potential contact is a pair (grain-grain, grain-fixed grain, grain-wall)
whose gap ``D = |c_i - c_j| - r_i - r_j`` (or distance to a wall minus the
radius) is below ``d_max`` (seed paper, section 3.3). Its frame is the normal
``n`` pointing from j to i followed by the tangents (1 in 2D, 2 in 3D).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numba import njit
from numpy.typing import NDArray
from scipy.spatial import KDTree

from cocd.errors import SceneError
from cocd.scene import Scene

__all__ = ["ContactSet", "contact_jacobian", "detect_contacts", "dof_layout"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass(frozen=True)
class ContactSet:
    """Potential contacts of one configuration.

    Attributes
    ----------
    i : (nc,) int
        First grain (the normal points towards it).
    j : (nc,) int
        Second grain, or ``-1 - k`` for wall ``k``.
    gap : (nc,) float
        Signed gap ``D`` (m); negative means overlap.
    normal : (nc, d) float
        Unit normal from j to i.
    tangents : (nc, d - 1, d) float
        Unit tangents; with the normal, a right-handed orthonormal frame.
    mu : (nc,) float
        Friction coefficient of each contact.
    radius_i, radius_j : (nc,) float
        Radii of the two grains (``radius_j`` is 0 for walls).
    keys : (nc,) int64
        Identifier of the pair, the same at every step; contacts are sorted by it.
    d_max : float
        Detection threshold used.
    """

    i: IntArray
    j: IntArray
    gap: FloatArray
    normal: FloatArray
    tangents: FloatArray
    mu: FloatArray
    radius_i: FloatArray
    radius_j: FloatArray
    keys: IntArray
    d_max: float

    @property
    def nc(self) -> int:
        return int(self.i.size)

    @property
    def dim(self) -> int:
        return int(self.normal.shape[1])

    @property
    def is_wall(self) -> NDArray[np.bool_]:
        return np.asarray(self.j < 0)


def detect_contacts(scene: Scene, d_max: float | None = None) -> ContactSet:
    """Find every potential contact with gap below ``d_max``.

    Parameters
    ----------
    scene : Scene
    d_max : float, optional
        Gap threshold in metres; default half the mean radius.

    Returns
    -------
    ContactSet
        Sorted by pair key; pairs of two fixed grains are left out.
    """
    x, r = scene.positions, scene.radii
    n, d = x.shape
    if d_max is None:
        d_max = 0.5 * float(r.mean())
    if not (np.isfinite(d_max) and d_max >= 0.0):
        raise SceneError(f"d_max must be finite and >= 0, got {d_max}")

    i_parts: list[IntArray] = []
    j_parts: list[IntArray] = []
    gap_parts: list[FloatArray] = []
    normal_parts: list[FloatArray] = []
    mu_parts: list[FloatArray] = []

    if n > 1:
        pairs = KDTree(x).query_pairs(2.0 * float(r.max()) + d_max, output_type="ndarray")
        if pairs.size:
            i, j = pairs[:, 0].astype(np.int64), pairs[:, 1].astype(np.int64)
            keep = ~(scene.fixed[i] & scene.fixed[j])
            i, j = i[keep], j[keep]
            delta = x[i] - x[j]
            dist = np.linalg.norm(delta, axis=1)
            gap = dist - r[i] - r[j]
            close = gap < d_max
            i, j, delta, dist, gap = i[close], j[close], delta[close], dist[close], gap[close]
            if np.any(dist == 0.0):
                a = int(np.flatnonzero(dist == 0.0)[0])
                raise SceneError(f"grains {i[a]} and {j[a]} have the same centre")
            i_parts.append(i)
            j_parts.append(j)
            gap_parts.append(gap)
            normal_parts.append(delta / dist[:, None])
            mu_parts.append(np.full(i.size, scene.mu))

    free = np.flatnonzero(scene.free).astype(np.int64)
    for k, wall in enumerate(scene.walls):
        gap = wall.gaps(x[free], r[free])
        close = gap < d_max
        m = int(close.sum())
        i_parts.append(free[close])
        j_parts.append(np.full(m, -1 - k, dtype=np.int64))
        gap_parts.append(gap[close])
        normal_parts.append(np.broadcast_to(wall.normal, (m, d)).copy())
        mu_parts.append(np.full(m, scene.wall_friction(k)))

    i = np.concatenate(i_parts) if i_parts else np.zeros(0, np.int64)
    j = np.concatenate(j_parts) if j_parts else np.zeros(0, np.int64)
    gap = np.concatenate(gap_parts) if gap_parts else np.zeros(0)
    normal = np.concatenate(normal_parts) if normal_parts else np.zeros((0, d))
    mu = np.concatenate(mu_parts) if mu_parts else np.zeros(0)

    keys = _pair_keys(i, j, n, len(scene.walls))
    order = np.argsort(keys, kind="stable")
    i, j, gap, normal, mu, keys = (
        i[order],
        j[order],
        gap[order],
        normal[order],
        mu[order],
        keys[order],
    )
    radius_j = np.where(j >= 0, r[np.maximum(j, 0)], 0.0)
    return ContactSet(
        i=i,
        j=j,
        gap=gap,
        normal=normal,
        tangents=_tangents(normal),
        mu=mu,
        radius_i=r[i],
        radius_j=radius_j,
        keys=keys,
        d_max=float(d_max),
    )


def dof_layout(scene: Scene, frictionless: bool) -> tuple[IntArray, int]:
    """Map each grain to the first of its unknowns.

    Returns
    -------
    first : (n,) int
        Index of the grain's first unknown, -1 for fixed grains.
    per_grain : int
        Unknowns per free grain: d translations, then the rotations (1 in 2D,
        3 in 3D) unless the scene is frictionless.
    """
    d = scene.dim
    per_grain = d if frictionless else (3 if d == 2 else 6)
    first = np.full(scene.n_grains, -1, dtype=np.int64)
    free = scene.free
    first[free] = np.arange(int(free.sum()), dtype=np.int64) * per_grain
    return first, per_grain


def contact_jacobian(
    contacts: ContactSet, first: IntArray, per_grain: int, ndof: int
) -> sp.csr_matrix:
    """The contact Jacobian ``H``, shape ``(m nc, ndof)``.

    Row block ``a`` maps the generalized velocity to the relative velocity at
    contact ``a`` in its frame, normal first: ``v_i + w_i x r_i - v_j - w_j x r_j``
    with ``r_i = -R_i n`` and ``r_j = R_j n``. ``m`` is 1 when rotations are not
    unknowns (frictionless) and ``d`` otherwise.

    Rotational unknowns are ``R w`` (the spin times the radius, a velocity), so
    the rotational columns are ``-(n x t)`` for both grains, free of the radius.
    """
    nc, d = contacts.nc, contacts.dim
    frictionless = per_grain == d
    m = 1 if frictionless else d
    frame = contacts.normal[:, None, :] if frictionless else _frames(contacts)  # (nc, m, d)

    if frictionless:
        rot = np.zeros((nc, 1, 0))
    elif d == 2:
        rot = np.zeros((nc, 2, 1))
        rot[:, 1, 0] = -1.0
    else:
        rot = np.zeros((nc, 3, 3))
        rot[:, 1:, :] = -np.cross(contacts.normal[:, None, :], contacts.tangents)

    # Each row holds grain i's block then grain j's (when they move): a numba kernel
    # writes the CSR arrays row by row, without a COO sort.
    first_i = np.where(contacts.i >= 0, first[np.maximum(contacts.i, 0)], -1).astype(np.int64)
    first_j = np.where(contacts.j >= 0, first[np.maximum(contacts.j, 0)], -1).astype(np.int64)
    block = np.ascontiguousarray(np.concatenate([frame, rot], axis=2), dtype=np.float64)
    indptr, indices, data = _jacobian_csr(block, first_i, first_j, d)
    H = sp.csr_matrix((data, indices, indptr), shape=(m * nc, ndof))
    H.sort_indices()
    return H


@njit(cache=True)
def _jacobian_csr(block, first_i, first_j, d):  # pragma: no cover - compiled
    """CSR arrays of ``H`` from each contact's ``(m, per_grain)`` block for grain i
    (``-block`` on grain j's translations, ``+block`` on its rotations), zeros
    dropped; ``first_*`` is -1 for a grain that is not an unknown."""
    nc, m, per_grain = block.shape
    nnz = 0
    for a in range(nc):
        for k in range(m):
            for side in range(2):
                if (first_i[a] if side == 0 else first_j[a]) >= 0:
                    for c in range(per_grain):
                        if block[a, k, c] != 0.0:
                            nnz += 1
    indptr = np.zeros(nc * m + 1, dtype=np.int64)
    indices = np.empty(nnz, dtype=np.int64)
    data = np.empty(nnz)
    pos = 0
    for a in range(nc):
        lo, hi = (first_i[a], first_j[a]) if first_i[a] <= first_j[a] else (first_j[a], first_i[a])
        for k in range(m):
            row = a * m + k
            for start in (lo, hi):  # ascending columns
                if start < 0:
                    continue
                sign = 1.0 if start == first_i[a] else -1.0
                for c in range(per_grain):
                    v = block[a, k, c]
                    if v != 0.0:
                        indices[pos] = start + c
                        data[pos] = sign * v if c < d else v
                        pos += 1
            indptr[row + 1] = pos
    return indptr, indices, data


def _frames(contacts: ContactSet) -> FloatArray:
    """Normal then tangents, shape ``(nc, d, d)``."""
    return np.concatenate([contacts.normal[:, None, :], contacts.tangents], axis=1)


def _tangents(normal: FloatArray) -> FloatArray:
    """Deterministic unit tangents, shape ``(nc, d - 1, d)``.

    2D: ``t = e_z x n``. 3D: the branchless orthonormal basis of Duff et al.
    (2017), continuous in ``n`` except across ``n_z = 0``'s sign change.
    """
    d = normal.shape[1]
    if d == 2:
        return np.stack([-normal[:, 1], normal[:, 0]], axis=1)[:, None, :]
    nx, ny, nz = normal[:, 0], normal[:, 1], normal[:, 2]
    sign = np.where(nz >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    t1 = np.stack([1.0 + sign * nx * nx * a, sign * b, -sign * nx], axis=1)
    t2 = np.stack([b, sign + ny * ny * a, -ny], axis=1)
    return np.stack([t1, t2], axis=1)


def _pair_keys(i: IntArray, j: IntArray, n: int, n_walls: int) -> IntArray:
    """A key per pair, the same at every step; walls numbered after the grains."""
    other = np.where(j >= 0, j, n - 1 - j)
    return np.asarray(i * np.int64(n + n_walls) + other)
