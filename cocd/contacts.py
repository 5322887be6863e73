"""Contact detection, contact frames, the contact Jacobian and the end-of-step check.

A potential contact is a pair (grain-grain, grain-fixed grain, grain-wall)
whose gap ``D = |c_i - c_j| - r_i - r_j`` (or distance to a wall minus the
radius) is below a threshold (seed paper, section 3.3): a floor ``d_max``
plus a margin that follows the motion, as a Verlet skin does. A pair left out
can close its gap within the step, unconstrained; :func:`penetration` measures,
after the step, whether that happened. A contact's frame is the normal ``n``
pointing from j to i followed by the tangents (1 in 2D, 2 in 3D).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numba import njit
from numpy.typing import NDArray
from scipy.spatial import KDTree

from cocd.checks import nonnegative_number
from cocd.errors import SceneError
from cocd.scene import Scene

__all__ = [
    "D_MAX_FACTOR",
    "SKIN_FACTOR",
    "ContactSet",
    "Penetration",
    "contact_jacobian",
    "default_d_max",
    "detect_contacts",
    "dof_layout",
    "penetration",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Default floor of the detection threshold, relative to the mean radius.
D_MAX_FACTOR = 0.5
#: Default skin factor: a pair's margin is this many times the distance its
#: free relative velocity closes in one step. Contacts change the velocities
#: within the step, so the free motion alone would under-estimate the approach.
SKIN_FACTOR = 2.0


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


def default_d_max(scene: Scene) -> float:
    """The default floor of the detection threshold: half the mean radius (m)."""
    return D_MAX_FACTOR * float(scene.radii.mean())


def detect_contacts(
    scene: Scene,
    d_max: float | None = None,
    *,
    velocities: FloatArray | None = None,
    dt: float = 0.0,
    skin: float = SKIN_FACTOR,
    reach: FloatArray | None = None,
) -> ContactSet:
    """Find every potential contact: gap below ``d_max`` plus the pair's margin.

    The margin follows the motion, as a Verlet skin does: with the step's free
    velocities ``v`` (those of fixed grains are 0) it is ``skin * dt * |v_i - v_j|``
    for a pair of grains (the most their gap can close if the pair kept its free
    relative velocity, times ``skin``) and ``skin * dt * max(0, -v_i . n)`` for a
    grain and a wall (its approach speed). ``reach`` adds a distance per grain
    (a pair gets ``reach_i + reach_j``), e.g. to redo a step whose grains went
    further than their margin.

    Parameters
    ----------
    scene : Scene
    d_max : float, optional
        Floor of the gap threshold in metres; default :func:`default_d_max`.
    velocities : (n, d) array, optional
        Free translational velocities; without them there is no margin.
    dt : float
        Time step (s).
    skin : float
        Margin factor (:data:`SKIN_FACTOR`); 0 for a fixed threshold.
    reach : (n,) array, optional
        Extra margin per grain (m).

    Returns
    -------
    ContactSet
        Sorted by pair key; pairs of two fixed grains are left out.
    """
    x, r = scene.positions, scene.radii
    n, d = x.shape
    if d_max is None:
        d_max = default_d_max(scene)
    nonnegative_number(d_max, "d_max")
    if not (np.isfinite(skin) and skin >= 0.0 and np.isfinite(dt) and dt >= 0.0):
        raise SceneError(f"skin and dt must be finite and >= 0, got {skin} and {dt}")
    v = None
    if velocities is not None and skin * dt > 0.0:
        v = np.where(scene.fixed[:, None], 0.0, np.asarray(velocities, dtype=np.float64))
        if v.shape != (n, d) or not np.all(np.isfinite(v)):
            raise SceneError(f"velocities must be finite with shape {(n, d)}, got {v.shape}")
    extra = np.zeros(n) if reach is None else np.asarray(reach, dtype=np.float64)
    if extra.shape != (n,) or not (np.all(np.isfinite(extra)) and np.all(extra >= 0.0)):
        raise SceneError(f"reach must be finite, >= 0 and of shape ({n},)")

    i_parts: list[IntArray] = []
    j_parts: list[IntArray] = []
    gap_parts: list[FloatArray] = []
    normal_parts: list[FloatArray] = []
    mu_parts: list[FloatArray] = []

    if n > 1:
        i, j = _candidate_pairs(scene, float(d_max), v, skin * dt, extra)
        keep = ~(scene.fixed[i] & scene.fixed[j])
        i, j = i[keep], j[keep]
        delta = x[i] - x[j]
        dist = np.linalg.norm(delta, axis=1)
        gap = dist - r[i] - r[j]
        threshold = d_max + extra[i] + extra[j]
        if v is not None:
            threshold = threshold + skin * dt * np.linalg.norm(v[i] - v[j], axis=1)
        close = gap < threshold
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
        threshold = d_max + extra[free]
        if v is not None:
            threshold = threshold + skin * dt * np.maximum(0.0, -(v[free] @ wall.normal))
        close = gap < threshold
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


def _candidate_pairs(
    scene: Scene, d_max: float, v: FloatArray | None, skin_dt: float, extra: FloatArray
) -> tuple[IntArray, IntArray]:
    """Grain pairs ``i < j`` that may be closer than their threshold (a superset).

    Among free grains, a pair's margin is at most ``b_i + b_j`` with
    ``b = skin dt |v - v_ref| + reach`` (``v_ref``: the median free velocity), so one
    search with the common bound of most grains finds their pairs, and the few
    grains faster than that are searched around one by one, each within its own
    bound. A fixed grain does not move: its pairs with free grains are searched
    apart, each free grain within its own margin ``skin dt |v| + reach``, so that a
    bed of fixed grains under a falling column (whose speeds differ from the
    median by the whole fall) does not widen every search. Pairs of two fixed
    grains are not searched.
    """
    x, r = scene.positions, scene.radii
    n = x.shape[0]
    free = np.flatnonzero(~scene.fixed).astype(np.int64)
    still = np.flatnonzero(scene.fixed).astype(np.int64)
    keys = [np.zeros(0, np.int64)]
    if free.size > 1:
        b = extra[free].copy()
        if v is not None:
            ref = np.median(v[free], axis=0)
            b += skin_dt * np.linalg.norm(v[free] - ref, axis=1)
        keys.append(_pairs_among(x[free], r[free], b, d_max, free, n))
    if free.size and still.size:
        margin = extra[free] + (0.0 if v is None else skin_dt * np.linalg.norm(v[free], axis=1))
        reach = r[free] + float(r[still].max()) + d_max + margin + float(extra[still].max())
        found = KDTree(x[still]).query_ball_point(x[free], reach)
        counts = np.fromiter((len(f) for f in found), dtype=np.int64, count=free.size)
        if counts.sum():
            others = still[np.concatenate([np.asarray(f, dtype=np.int64) for f in found])]
            mine = np.repeat(free, counts)
            lo, hi = np.minimum(mine, others), np.maximum(mine, others)
            keys.append(lo * np.int64(n) + hi)
    merged = unique_ints(np.concatenate(keys))
    return merged // n, merged % n


def _pairs_among(
    x: FloatArray, r: FloatArray, b: FloatArray, d_max: float, index: IntArray, n: int
) -> IntArray:
    """Keys ``i n + j`` (``i < j``, global indices ``index``) of the pairs of these grains
    closer than ``r_i + r_j + d_max + b_i + b_j``, or a few more."""
    r_max = float(r.max())
    common = float(np.quantile(b, 0.95)) if b.any() else 0.0
    tree = KDTree(x)
    pairs = tree.query_pairs(2.0 * r_max + d_max + 2.0 * common, output_type="ndarray")
    lo, hi = index[pairs[:, 0]], index[pairs[:, 1]]
    parts = [np.minimum(lo, hi) * np.int64(n) + np.maximum(lo, hi)]
    fast = np.flatnonzero(b > common)
    if fast.size:
        found = tree.query_ball_point(x[fast], r[fast] + r_max + d_max + 2.0 * b[fast])
        counts = np.fromiter((len(f) for f in found), dtype=np.int64, count=fast.size)
        if counts.sum():
            others = index[np.concatenate([np.asarray(f, dtype=np.int64) for f in found])]
            centre = np.repeat(index[fast], counts)
            keep = centre != others
            low, high = np.minimum(centre, others)[keep], np.maximum(centre, others)[keep]
            parts.append(low * np.int64(n) + high)
    return np.concatenate(parts)


@dataclass(frozen=True)
class Penetration:
    """How far grains overlap at the end of a step (:func:`penetration`).

    Attributes
    ----------
    depth : float
        Largest overlap, relative to the smaller radius of the pair (a grain's
        own radius against a wall); 0 when nothing overlaps.
    depth_m : float
        That overlap in metres.
    i, j : int
        The deepest pair (``j = -1 - k`` for wall ``k``); -1, -1 when none.
    potential : bool
        Whether that pair was a potential contact of the step (then the
        backend's answer let it overlap, not the margin).
    missed : int
        Number of pairs that overlap without having been potential contacts.
    missed_depth : float
        Largest relative overlap among those (0 when none).
    missed_i, missed_j : (m,) int arrays
        Those pairs.
    missed_gap : (m,) float array
        Their gaps at the start of the step (m): how far they had to close.
    """

    depth: float
    depth_m: float
    i: int
    j: int
    potential: bool
    missed: int
    missed_depth: float
    missed_i: IntArray
    missed_j: IntArray
    missed_gap: FloatArray

    def describe(self, scene: Scene) -> str:
        """The deepest pair in words: ``grains 3 and 7 overlap by 1.2e-4 m (0.12 r)``."""
        if self.depth <= 0.0:
            return "no grains overlap"
        if self.j >= 0:
            who = f"grains {self.i} and {self.j} overlap"
        else:
            who = f"grain {self.i} penetrates wall {-1 - self.j}"
        kind = "a potential contact" if self.potential else "not a potential contact"
        return f"{who} by {self.depth_m:.3g} m ({self.depth:.3g} of the smaller radius; {kind})"


def penetration(scene: Scene, contacts: ContactSet, start: FloatArray) -> Penetration:
    """Overlaps at the end of a step, and pairs that went through each other in it.

    Parameters
    ----------
    scene : Scene
        At the end of the step.
    contacts : ContactSet
        The step's potential contacts (detected at the start).
    start : (n, d) array
        Grain centres at the start of the step.

    Notes
    -----
    Potential contacts, and grains against walls (planes: a grain that went
    through one is behind it), are checked at the end of the step. A pair that
    was not a potential contact had a gap of at least ``contacts.d_max`` at the
    start, so it can have touched only if the two grains' displacements differ
    by more than that: only the neighbourhoods of grains displaced by more than
    ``d_max / 2`` from the median displacement are searched. Centres move in a
    straight line within a step, so for those pairs the depth is the deepest
    overlap along the way: a grain that passed through another is found even
    if they are apart again at the end.
    """
    x, r = scene.positions, scene.radii
    n = x.shape[0]
    n_walls = len(scene.walls)
    free = scene.free

    # (i, j, gap) of every pair checked: grain pairs and walls alike.
    ci, cj = contacts.i, contacts.j
    grain = cj >= 0
    i_parts = [ci[grain]]
    j_parts = [cj[grain]]
    gap_parts = [np.linalg.norm(x[ci[grain]] - x[cj[grain]], axis=1) - r[ci[grain]] - r[cj[grain]]]
    idx = np.flatnonzero(free).astype(np.int64)
    for k, wall in enumerate(scene.walls):
        i_parts.append(idx)
        j_parts.append(np.full(idx.size, -1 - k, dtype=np.int64))
        gap_parts.append(wall.gaps(x[idx], r[idx]))
    if n > 1:
        pi, pj = _passing_pairs(scene, start, contacts.d_max)
        # Potential contacts are judged at the end of the step only (above).
        other = ~_is_member(_pair_keys(pi, pj, n, n_walls), contacts.keys)
        pi, pj = pi[other], pj[other]
        i_parts.append(pi)
        j_parts.append(pj)
        gap_parts.append(_swept_gap(start[pi] - start[pj], x[pi] - x[pj]) - r[pi] - r[pj])
    i = np.concatenate(i_parts)
    j = np.concatenate(j_parts)
    gap = np.concatenate(gap_parts)
    over = gap < 0.0
    i, j, gap = i[over], j[over], gap[over]
    potential = _is_member(_pair_keys(i, j, n, n_walls), contacts.keys)
    smaller = np.where(j >= 0, np.minimum(r[i], r[np.maximum(j, 0)]), r[i])
    rel = -gap / smaller
    missed = ~potential
    mi, mj = i[missed], j[missed]
    start_gap = np.empty(mi.size)
    walls = mj < 0
    pair = ~walls
    start_gap[pair] = (
        np.linalg.norm(start[mi[pair]] - start[mj[pair]], axis=1) - r[mi[pair]] - r[mj[pair]]
    )
    for w in np.flatnonzero(walls):
        wall = scene.walls[-1 - int(mj[w])]
        start_gap[w] = float(wall.gaps(start[mi[w]][None, :], r[mi[w]][None])[0])
    if rel.size == 0:
        return Penetration(0.0, 0.0, -1, -1, False, 0, 0.0, mi, mj, start_gap)
    a = int(np.argmax(rel))
    return Penetration(
        depth=float(rel[a]),
        depth_m=float(-gap[a]),
        i=int(i[a]),
        j=int(j[a]),
        potential=bool(potential[a]),
        missed=int(missed.sum()),
        missed_depth=float(rel[missed].max()) if missed.any() else 0.0,
        missed_i=mi,
        missed_j=mj,
        missed_gap=start_gap,
    )


def _passing_pairs(scene: Scene, start: FloatArray, d_max: float) -> tuple[IntArray, IntArray]:
    """Grain pairs ``i < j`` whose relative displacement in the step may have brought
    them closer than contact although their gap was at least ``d_max`` (a superset).

    With ``b`` the distance of each grain's displacement from the median one,
    a pair's relative displacement is at most ``b_i + b_j``: only grains with
    ``b > d_max / 2`` can be in such a pair, and each is searched around within
    ``r_i + r_max + 2 b_i`` (the pairs whose other grain moved more are found
    from that one).
    """
    x, r = scene.positions, scene.radii
    free = scene.free
    disp = x - start
    ref = np.median(disp[free], axis=0) if free.any() else np.zeros(x.shape[1])
    b = np.linalg.norm(np.where(free[:, None], disp, 0.0) - ref, axis=1)
    fast = np.flatnonzero(b > 0.5 * d_max)
    if fast.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    tree = KDTree(start)
    found = tree.query_ball_point(start[fast], r[fast] + float(r.max()) + 2.0 * b[fast])
    counts = np.fromiter((len(f) for f in found), dtype=np.int64, count=fast.size)
    if counts.sum() == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    others = np.concatenate([np.asarray(f, dtype=np.int64) for f in found])
    centre = np.repeat(fast, counts)
    lo, hi = np.minimum(centre, others), np.maximum(centre, others)
    keep = (lo != hi) & ~(scene.fixed[lo] & scene.fixed[hi])
    n = np.int64(x.shape[0])
    keys = unique_ints(lo[keep] * n + hi[keep])
    return keys // n, keys % n


def _swept_gap(before: FloatArray, after: FloatArray) -> FloatArray:
    """Smallest distance between two centres moving in straight lines, shape ``(m,)``.

    ``before`` and ``after`` are the relative positions ``c_i - c_j`` at the start
    and the end of the step, shape ``(m, d)``.
    """
    e = after - before
    ee = np.einsum("ij,ij->i", e, e)
    t = np.where(ee > 0.0, -np.einsum("ij,ij->i", before, e) / np.where(ee > 0.0, ee, 1.0), 0.0)
    t = np.clip(t, 0.0, 1.0)
    return np.asarray(np.linalg.norm(before + t[:, None] * e, axis=1))


def unique_ints(a: IntArray) -> IntArray:
    """The distinct values of an integer array, ascending: ``np.unique(a)`` by a sort.

    numpy 2.3 and later answer ``np.unique`` on integers with a hash table, which on
    millions of distinct 64-bit keys (the candidate pairs of a large step) takes fifty to
    a hundred times as long as sorting them.
    """
    s = np.sort(np.asarray(a).ravel())
    if s.size < 2:
        return s
    keep = np.empty(s.size, dtype=bool)
    keep[0] = True
    np.not_equal(s[1:], s[:-1], out=keep[1:])
    return s[keep]


def _is_member(keys: IntArray, sorted_keys: IntArray) -> NDArray[np.bool_]:
    """Whether each key is in ``sorted_keys`` (ascending)."""
    if sorted_keys.size == 0:
        return np.zeros(keys.size, dtype=bool)
    pos = np.minimum(np.searchsorted(sorted_keys, keys), sorted_keys.size - 1)
    return np.asarray(sorted_keys[pos] == keys)


def unknowns_per_grain(dim: int, frictionless: bool) -> int:
    """Unknowns per free grain: ``dim`` translations, then the rotations (1 in 2D, 3 in
    3D) unless the scene is frictionless."""
    return dim if frictionless else (3 if dim == 2 else 6)


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
    per_grain = unknowns_per_grain(scene.dim, frictionless)
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
