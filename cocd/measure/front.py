"""The main mass, its front and the runout."""

from __future__ import annotations

from collections.abc import Sequence
from typing import overload

import numpy as np
from numpy.typing import ArrayLike

from cocd.checks import (
    bin_edges,
    broadcast_array,
    finite_array,
    finite_nonnegative,
    finite_scalar,
)
from cocd.errors import SceneError
from cocd.measure._common import (
    BoolArray,
    FloatArray,
    bin_profile,
    check_flow_axis,
    connection_gap,
    grains,
    largest_mass,
    relative_change,
    scalar_or_array,
)
from cocd.measure.profile import mass_profile
from cocd.scene import Scene

__all__ = [
    "bed_surface",
    "bed_top",
    "front_position",
    "main_mass",
    "relative_runout",
    "runout",
    "surface_front",
]


def main_mass(
    scene_or_positions: Scene | ArrayLike,
    radii: ArrayLike | float | None = None,
    *,
    gap: float | None = None,
    mask: ArrayLike | None = None,
) -> BoolArray:
    """Mask of the grains of the main connected mass.

    Two selected grains are connected when the gap between their surfaces,
    ``|c_i - c_j| - r_i - r_j``, is at most ``gap``; the main mass is the
    connected component of this network holding the most grains (on a tie, the
    one holding the lowest grain index). Grains thrown ahead of the flow, or
    left behind, are not part of it.

    Parameters
    ----------
    scene_or_positions : Scene or (n, d) array
        A scene, or the grain centres (m).
    radii : (n,) array or float, optional
        Radii (m); required with positions, not allowed with a Scene.
    gap : float, optional
        Connection threshold (m), >= 0. Default ``DEFAULT_GAP_FRACTION`` times
        the mean diameter of the selected grains.
    mask : (n,) bool array, optional
        Grains to consider. Default: every grain, or a Scene's free grains.

    Returns
    -------
    (n,) bool array
        True for the grains of the main mass.
    """
    x, r, sel = grains(scene_or_positions, radii, mask)
    return largest_mass(x, r, sel, connection_gap(gap, r, sel))


def front_position(
    scene_or_positions: Scene | ArrayLike,
    radii: ArrayLike | float | None = None,
    *,
    axis: int = 0,
    gap: float | None = None,
    mask: ArrayLike | None = None,
) -> float:
    """Front position ``r_f``: the foremost grain surface of the main mass.

    ``r_f = max (c_i[axis] + r_i)`` over the grains of :func:`main_mass`: a grain
    detached from the mass (gap above ``gap``) does not move the front.

    Parameters
    ----------
    scene_or_positions, radii, gap : see :func:`main_mass`
    axis : int
        Flow direction, a horizontal coordinate (0, or 1 in 3D).
    mask : (n,) bool array, optional
        Grains to consider. Default: every grain, or a Scene's free grains. On an
        erodible bed, whose grains span the channel, pass the grains of the
        flowing mass (e.g. those that started in the column, or those above the
        initial bed surface).

    Returns
    -------
    float
        ``r_f`` in m, in the scene's frame (subtract the back wall's position to
        get a length from it).
    """
    x, r, sel = grains(scene_or_positions, radii, mask)
    check_flow_axis(axis, x.shape[1])
    main = largest_mass(x, r, sel, connection_gap(gap, r, sel))
    return float(np.max(x[main, axis] + r[main]))


def bed_top(scene: Scene) -> float:
    """Top of the glued bed grains (group ``bed``) of a :func:`cocd.builders.column_collapse`
    scene, else the floor (0): m, absolute z."""
    bed = scene.groups.get("bed", slice(0, 0))
    if bed.stop <= bed.start:
        return 0.0
    return float(np.max(scene.positions[bed, -1] + scene.radii[bed]))


def bed_surface(scene: Scene, x_bins: ArrayLike) -> FloatArray:
    """Height of the bed's surface per bin before a flow (m, absolute z): what it flows over.

    For a scene of :func:`cocd.builders.column_collapse` (groups ``bed``,
    ``layer``, ``column``): the top of the erodible layer where there is one,
    else the top of the glued bed grains, else the floor (0). For :func:`surface_front`.
    """
    edges = bin_edges(x_bins, "x_bins")
    groups = scene.groups
    r = scene.radii
    x = scene.positions
    base = bed_top(scene)
    surface = np.full(edges.size - 1, base)
    layer = groups.get("layer", slice(0, 0))
    if layer.stop > layer.start:
        mask = np.zeros(scene.n_grains, dtype=bool)
        mask[layer] = True
        top = mass_profile(x, r, x_bins=edges, mask=mask, connected=False)
        surface = np.where(np.isfinite(top.height), top.height, base)
    return surface


def surface_front(
    scene_or_positions: Scene | ArrayLike,
    radii: ArrayLike | float | None = None,
    *,
    x_bins: ArrayLike,
    surface: ArrayLike | float = 0.0,
    threshold: float | None = None,
    max_gap_bins: int = 2,
    axis: int = 0,
    mask: ArrayLike | None = None,
) -> float:
    """Front of a flow over a bed: where its free surface stands above the bed's surface.

    The free surface ``h`` of the selected grains (every grain, not only the
    main mass: :func:`mass_profile` with ``connected=False``) is compared per
    bin with the bed's surface ``surface`` (e.g. the top of an erodible layer
    before the flow, or of the glued grains). A bin *carries the flow* when
    ``h - surface > threshold``. Starting at the bin where the flow is
    thickest, the last bin reached going downstream while crossing at most
    ``max_gap_bins`` bins in a row that do not carry it is the front's bin;
    the front is the farthest reach ``x + r`` of the grains centred in it (so
    it moves continuously, not by whole bins). On an erodible bed this is the
    front the eye sees (column and entrained layer grains alike), and grains
    rolling ahead alone (a
    thin, isolated bump) do not move it, which :func:`front_position` cannot
    ensure once the layer joins every grain into one mass.

    Parameters
    ----------
    scene_or_positions, radii, mask : see :func:`front_position`
        Give the grains that can flow (a Scene's free grains by default).
    x_bins : (nx + 1,) array
        Bin edges along the flow direction (m); one mean diameter is a good width.
        They decide which bin is the front's; the front itself is a grain's reach.
    surface : float or (nx,) array
        Height of the bed's surface per bin (m, absolute z), NaN for none (the
        bin then never carries the flow).
    threshold : float, optional
        Thickness above the surface that counts as flow (m), >= 0; default half
        the mean diameter of the selected grains.
    max_gap_bins : int
        Longest run of bins without flow that is crossed, >= 0.
    axis : int
        Flow direction, a horizontal coordinate (0, or 1 in 3D).

    Returns
    -------
    float
        The front (m), in the scene's frame; NaN when no bin carries the flow.
    """
    x, r, sel = grains(scene_or_positions, radii, mask)
    check_flow_axis(axis, x.shape[1])
    edges = bin_edges(x_bins, "x_bins")
    nx = edges.size - 1
    base = broadcast_array(surface, nx, "surface")
    if threshold is None:
        threshold = float(np.mean(r[sel]))
    threshold = finite_nonnegative(threshold, "threshold")
    if int(max_gap_bins) != max_gap_bins or max_gap_bins < 0:
        raise SceneError(f"max_gap_bins must be an integer >= 0, got {max_gap_bins!r}")
    height = bin_profile(x, r, sel, edges, None, axis).height
    excess = np.where(np.isfinite(height) & np.isfinite(base), height - base, -np.inf)
    flowing = excess > threshold
    if not flowing.any():
        return float("nan")
    k = int(np.argmax(excess))
    last, gap = k, 0
    for j in range(k + 1, nx):
        if flowing[j]:
            last, gap = j, 0
        else:
            gap += 1
            if gap > max_gap_bins:
                break
    # Not the bin's edge: the farthest reach of the grains centred in that bin, so
    # that the front moves continuously and not by whole bins.
    xs, rs = x[sel, axis], r[sel]
    inside = (xs >= edges[last]) & (xs < edges[last + 1])
    return float(np.max(xs[inside] + rs[inside])) if inside.any() else float(edges[last + 1])


@overload
def runout(initial_front: float, final_front: float) -> float: ...


@overload
def runout(initial_front: float, final_front: Sequence[float] | FloatArray) -> FloatArray: ...


def runout(
    initial_front: float, final_front: float | Sequence[float] | FloatArray
) -> float | FloatArray:
    """Runout distance ``r_f(final) - r_f(initial)`` (m).

    Parameters
    ----------
    initial_front : float
        Front position at release (m), e.g. ``front_position`` of the first state.
    final_front : float or (nt,) array
        Front position of the deposit, or a series ``r_f(t)`` (m).

    Returns
    -------
    float or (nt,) array
        The distance travelled by the front (m), same shape as ``final_front``.
    """
    r0 = finite_scalar(initial_front, "initial_front")
    rf = finite_array(final_front, "final_front")
    return scalar_or_array(rf - r0)


@overload
def relative_runout(L0: float, Lf: float) -> float: ...


@overload
def relative_runout(L0: float, Lf: Sequence[float] | FloatArray) -> FloatArray: ...


def relative_runout(L0: float, Lf: float | Sequence[float] | FloatArray) -> float | FloatArray:
    """Relative runout ``(L_f - L_0) / L_0`` (dimensionless), shaped like ``Lf``.

    ``L0`` is the initial length of the mass, from the back wall to the front
    (m, > 0); ``Lf`` the final length, or a series ``L(t)``, from the same wall.
    """
    return relative_change(Lf, L0, "Lf", "L0")
