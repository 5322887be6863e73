"""What the measurements share: constants, the grains selected, bins."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cocd.checks import (
    bool_mask,
    broadcast_array,
    finite_array,
    finite_nonnegative,
    finite_positive,
    float_array,
    require_finite,
)
from cocd.errors import SceneError
from cocd.scene import Scene

__all__ = ["DEFAULT_GAP_FRACTION", "STATIC_VELOCITY", "MassProfile"]


FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.intp]

#: Default connection threshold of :func:`main_mass`, as a fraction of the mean
#: grain diameter: two grains whose surfaces are closer belong to the same mass.
DEFAULT_GAP_FRACTION = 0.5

#: Speed below which a layer counts as static (1 cm/s, as in Farin et al. 2014).
STATIC_VELOCITY = 0.01


def grains(
    scene_or_positions: Scene | ArrayLike, radii: ArrayLike | float | None, mask: ArrayLike | None
) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Positions ``(n, d)``, radii ``(n,)`` and the selected grains ``(n,)``."""
    not_both = "pass a Scene alone, or positions and radii: not a Scene and radii"
    return _state(scene_or_positions, radii, mask, "radii", _radii, not_both)


def kinematics(
    scene_or_positions: Scene | ArrayLike, velocities: ArrayLike | None, mask: ArrayLike | None
) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Positions ``(n, d)``, velocities ``(n, d)`` and the selected grains ``(n,)``."""
    not_both = "pass a Scene alone, or positions and velocities: not both"
    return _state(scene_or_positions, velocities, mask, "velocities", _velocities, not_both)


def _state(
    scene_or_positions: Scene | ArrayLike,
    given: object,
    mask: ArrayLike | None,
    name: str,
    convert: Callable[[object, FloatArray], FloatArray],
    not_both: str,
) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Positions, the per-grain array ``name`` (a Scene's, or ``given`` converted)
    and the grains ``mask`` selects: by default every grain, or a Scene's free grains."""
    if isinstance(scene_or_positions, Scene):
        if given is not None:
            raise SceneError(not_both)
        x, values = scene_or_positions.positions, getattr(scene_or_positions, name)
        default = scene_or_positions.free.copy()
    else:
        x = _positions(scene_or_positions)
        if given is None:
            raise SceneError(f"{name} are required with a positions array")
        values = convert(given, x)
        default = np.ones(x.shape[0], dtype=bool)
    sel = default if mask is None else bool_mask(mask, x.shape[0], "mask")
    if not sel.any():
        raise SceneError("no grain selected (the mask is all False)")
    return x, values, sel


def _radii(value: object, x: FloatArray) -> FloatArray:
    r = broadcast_array(value, x.shape[0], "radii")
    require_finite(r, "radii")
    if np.any(r <= 0.0):
        k = int(np.argmax(r <= 0.0))
        raise SceneError(f"radius of grain {k} is {r[k]:g}: radii must be > 0")
    return r


def _velocities(value: object, x: FloatArray) -> FloatArray:
    v = float_array(value, "velocities")
    if v.shape != x.shape:
        raise SceneError(f"velocities must have shape {x.shape} like positions, got {v.shape}")
    require_finite(v, "velocities")
    return v


def _positions(value: ArrayLike) -> FloatArray:
    x = float_array(value, "positions")
    if x.ndim != 2 or x.shape[1] not in (2, 3) or x.shape[0] == 0:
        raise SceneError(f"positions must have shape (n, 2) or (n, 3) with n >= 1, got {x.shape}")
    require_finite(x, "positions")
    return x


def largest_mass(x: FloatArray, r: FloatArray, sel: BoolArray, gap: float) -> BoolArray:
    """The largest connected mass of the selected grains (see :func:`main_mass`)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import KDTree

    idx = np.flatnonzero(sel)
    if idx.size == 1:
        return sel.copy()
    xs, rs = x[idx], r[idx]
    pairs = KDTree(xs).query_pairs(2.0 * float(rs.max()) + gap, output_type="ndarray")
    i, j = pairs[:, 0], pairs[:, 1]
    near = np.linalg.norm(xs[i] - xs[j], axis=1) - rs[i] - rs[j] <= gap
    k = idx.size
    graph = coo_matrix((np.ones(int(near.sum())), (i[near], j[near])), shape=(k, k))
    _, labels = connected_components(graph, directed=False)
    main = np.zeros(sel.shape, dtype=bool)
    main[idx[labels == np.argmax(np.bincount(labels))]] = True
    return main


def bin_index(edges: FloatArray, values: FloatArray) -> tuple[IntArray, BoolArray]:
    """Bin of each value, ``[e_k, e_k+1)`` with the last edge included, and whether inside."""
    k = np.searchsorted(edges, values, side="right") - 1
    k[values == edges[-1]] = edges.size - 2
    inside = (k >= 0) & (k < edges.size - 1)
    return np.where(inside, k, 0), inside


def overlap(edges: FloatArray, lo: float, hi: float) -> FloatArray:
    """Length of each bin inside ``[lo, hi]``, shape ``(nbins,)``."""
    return np.asarray(np.clip(np.minimum(edges[1:], hi) - np.maximum(edges[:-1], lo), 0.0, None))


def check_covers(edges: FloatArray, centres: FloatArray, name: str) -> None:
    """Raise unless the bins ``edges`` span every centre."""
    lo, hi = float(centres.min()), float(centres.max())
    if lo < edges[0] or hi > edges[-1]:
        raise SceneError(
            f"{name} [{edges[0]:g}, {edges[-1]:g}] do not cover the centres of the mass "
            f"[{lo:g}, {hi:g}]"
        )


def connection_gap(gap: float | None, r: FloatArray, sel: BoolArray) -> float:
    """``gap`` checked, or its default for the selected grains."""
    if gap is None:
        return DEFAULT_GAP_FRACTION * 2.0 * float(np.mean(r[sel]))
    return finite_nonnegative(gap, "gap")


def check_flow_axis(axis: int, d: int) -> None:
    """Raise unless ``axis`` is a horizontal coordinate in ``d`` dimensions."""
    if not isinstance(axis, (int, np.integer)) or not 0 <= axis < d - 1:
        raise SceneError(
            f"axis must be a horizontal coordinate (0{', 1' if d == 3 else ''}) in {d}D, "
            f"got {axis!r}: the last coordinate is z"
        )


def relative_change(
    value: object, reference: object, name: str, reference_name: str, *, nonnegative: bool = False
) -> float | FloatArray:
    """``(value - reference) / reference`` for a number or a series, ``reference > 0``."""
    ref = finite_positive(reference, reference_name)
    a = finite_array(value, name)
    if nonnegative and np.any(a < 0.0):
        raise SceneError(f"{name} must be >= 0, got {float(a.min()):g}")
    return scalar_or_array((a - ref) / ref)


def scalar_or_array(a: FloatArray) -> float | FloatArray:
    """A float for a 0-d array, else the array."""
    return float(a) if a.ndim == 0 else a


@dataclass(frozen=True)
class MassProfile:
    """Free-surface profile of the mass on a grid of bins.

    Attributes
    ----------
    x_edges : (nx + 1,) array
        Bin edges along the flow direction (m).
    y_edges : (ny + 1,) array or None
        Bin edges across the channel (3D with ``y_bins`` only).
    height : (nx,) or (nx, ny) array
        z of the free surface (m): the highest grain top ``c_z + r`` among the
        grains whose centre lies in the bin; NaN for an empty bin.
    solid_volume : (nx,) or (nx, ny) array
        Volume of grain material whose centre lies in the bin (m^3; m^2 in 2D,
        per metre of depth). Times the density, the mass per bin.
    n_grains : (nx,) or (nx, ny) int array
        Number of grains per bin.
    """

    x_edges: FloatArray
    y_edges: FloatArray | None
    height: FloatArray
    solid_volume: FloatArray
    n_grains: IntArray

    @property
    def x_centres(self) -> FloatArray:
        """Bin centres along the flow direction, shape ``(nx,)``."""
        return np.asarray(0.5 * (self.x_edges[:-1] + self.x_edges[1:]))

    @property
    def mean_height(self) -> FloatArray:
        """Height averaged across the width, shape ``(nx,)``.

        The mean over the non-empty y cells of each x bin (NaN if all are
        empty); ``height`` itself when there are no y bins.
        """
        if self.height.ndim == 1:
            return self.height
        filled = np.isfinite(self.height)
        total = np.where(filled, self.height, 0.0).sum(axis=1)
        count = filled.sum(axis=1)
        out = np.full(self.height.shape[0], np.nan)
        np.divide(total, count, out=out, where=count > 0)
        return out


def bin_profile(
    x: FloatArray,
    r: FloatArray,
    keep: BoolArray,
    xe: FloatArray,
    ye: FloatArray | None,
    axis: int,
) -> MassProfile:
    """The profile of the grains ``keep`` on the bins ``xe`` (and ``ye``)."""
    d = x.shape[1]
    kx, inside = bin_index(xe, x[:, axis])
    shape: tuple[int, ...] = (xe.size - 1,)
    flat = kx
    if ye is not None:
        ky, inside_y = bin_index(ye, x[:, 1 - axis])
        inside &= inside_y
        shape = (xe.size - 1, ye.size - 1)
        flat = kx * shape[1] + ky
    use = keep & inside
    cells = int(np.prod(shape))
    top = np.full(cells, -np.inf)
    np.maximum.at(top, flat[use], x[use, -1] + r[use])
    grain_volume = np.pi * r**2 if d == 2 else (4.0 / 3.0) * np.pi * r**3
    solid = np.asarray(
        np.bincount(flat[use], weights=grain_volume[use], minlength=cells), dtype=np.float64
    )
    count = np.bincount(flat[use], minlength=cells)
    height = np.where(count > 0, top, np.nan)
    return MassProfile(
        x_edges=xe,
        y_edges=ye,
        height=height.reshape(shape),
        solid_volume=solid.reshape(shape),
        n_grains=count.reshape(shape),
    )
