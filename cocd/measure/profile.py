"""The mass (free-surface) profile and the volume the mass occupies."""

from __future__ import annotations

from collections.abc import Sequence
from typing import overload

import numpy as np
from numpy.typing import ArrayLike

from cocd.checks import bin_edges, finite_positive, finite_scalar
from cocd.errors import SceneError
from cocd.measure._common import (
    FloatArray,
    MassProfile,
    bin_profile,
    check_covers,
    check_flow_axis,
    connection_gap,
    grains,
    largest_mass,
    overlap,
    relative_change,
)
from cocd.scene import Scene

__all__ = ["granular_volume", "mass_profile", "relative_volume_variation"]


def mass_profile(
    scene_or_positions: Scene | ArrayLike,
    radii: ArrayLike | float | None = None,
    *,
    x_bins: ArrayLike,
    y_bins: ArrayLike | None = None,
    axis: int = 0,
    connected: bool = True,
    gap: float | None = None,
    mask: ArrayLike | None = None,
) -> MassProfile:
    """Mass profile ``h(x)``: the height of the free surface per bin.

    For each bin, ``h`` is the highest grain top ``c_z + r`` among the grains of
    the main connected mass (:func:`main_mass`, unless ``connected=False``)
    whose centre lies in the bin. In 3D without ``y_bins``, every grain across
    the width counts: the side view of the mass, its highest point per x bin.
    With ``y_bins``, the height per (x, y) cell; ``MassProfile.mean_height``
    averages it across the width.

    Parameters
    ----------
    scene_or_positions, radii, gap, mask : see :func:`main_mass`
    x_bins : (nx + 1,) array
        Bin edges along the flow direction (m), strictly increasing.
    y_bins : (ny + 1,) array, optional
        Bin edges across the channel (m), 3D only.
    axis : int
        Flow direction, a horizontal coordinate (0, or 1 in 3D).
    connected : bool
        Keep only the main connected mass (default); False keeps every
        selected grain.

    Returns
    -------
    MassProfile
        Heights (m, absolute z: subtract the bed's z for a thickness), solid
        volume and grain count per bin.
    """
    x, r, sel = grains(scene_or_positions, radii, mask)
    d = x.shape[1]
    check_flow_axis(axis, d)
    xe = bin_edges(x_bins, "x_bins")
    ye = None
    if y_bins is not None:
        if d != 3:
            raise SceneError("y_bins apply to 3D scenes only (the grains are 2D)")
        ye = bin_edges(y_bins, "y_bins")
    keep = largest_mass(x, r, sel, connection_gap(gap, r, sel)) if connected else sel
    return bin_profile(x, r, keep, xe, ye, axis)


def granular_volume(
    scene_or_positions: Scene | ArrayLike,
    radii: ArrayLike | float | None = None,
    *,
    x_bins: ArrayLike | None = None,
    y_bins: ArrayLike | None = None,
    width: float | None = None,
    base: float = 0.0,
    axis: int = 0,
    gap: float | None = None,
    mask: ArrayLike | None = None,
) -> float:
    """Volume ``V`` occupied by the mass: the volume under its free surface.

    ``V = sum_k (h_k - base)+ |B_k ∩ E|`` over the bins ``B_k`` of
    :func:`mass_profile` (main connected mass), where ``E`` is the extent of
    the mass, ``[min(c - r), max(c + r)]`` along each binned direction, so a
    bin that reaches past the front or the back counts only up to the mass.
    An empty x bin within the extent takes the height interpolated linearly
    between its non-empty neighbours (the nearest one's at the ends: the surface
    bridges it, as when bins are narrower than the grains); an empty (x, y)
    cell counts zero, so cells should be wider than a grain. It is the volume
    a profilometer sees (grains and the pores between them), so that
    ``(V - V0)/V0`` measures dilatancy as in the experiments. In 3D without
    ``y_bins`` the side-view area is multiplied by ``width``.

    Parameters
    ----------
    scene_or_positions, radii, axis, gap, mask : see :func:`mass_profile`
    x_bins : (nx + 1,) array, optional
        Bin edges along the flow direction (m); they must cover the centres of
        the main mass. Default: bins ``2 r_max + gap`` wide (or a little
        wider), from the back to the front of the mass: none is empty.
    y_bins : (ny + 1,) array, optional
        Bin edges across the channel (3D only); they must cover the mass.
    width : float, optional
        3D without ``y_bins``: the channel width (m). Default: the extent of the
        mass across the channel, ``max(c_y + r) - min(c_y - r)``.
    base : float
        z of the surface the mass rests on (m): the floor, or the top of a glued
        layer.

    Returns
    -------
    float
        ``V`` in m^3 (m^2, i.e. m^3 per metre of depth, in 2D).
    """
    x, r, sel = grains(scene_or_positions, radii, mask)
    d = x.shape[1]
    check_flow_axis(axis, d)
    z0 = finite_scalar(base, "base")
    g = connection_gap(gap, r, sel)
    main = largest_mass(x, r, sel, g)
    cross = 1 - axis if d == 3 else -1  # the horizontal axis that is not the flow's
    back = float(np.min(x[main, axis] - r[main]))
    front = float(np.max(x[main, axis] + r[main]))
    if x_bins is None:
        # Centres of a connected mass are at most 2 r_max + gap apart along x, so
        # bins at least that wide are never empty.
        reach = 2.0 * float(np.max(r[main])) + g
        nbins = max(1, int(np.floor((front - back) / reach * (1.0 + 1e-12))))
        xe = np.linspace(back, front, nbins + 1)
    else:
        xe = bin_edges(x_bins, "x_bins")
        check_covers(xe, x[main, axis], "x_bins")
    ye = None
    if y_bins is not None:
        if d != 3:
            raise SceneError("y_bins apply to 3D scenes only (the grains are 2D)")
        if width is not None:
            raise SceneError("give either y_bins or width, not both")
        ye = bin_edges(y_bins, "y_bins")
        check_covers(ye, x[main, cross], "y_bins")
    elif width is not None and d == 2:
        raise SceneError("width applies to 3D scenes only (a 2D volume is per metre of depth)")

    profile = bin_profile(x, r, main, xe, ye, axis)
    lx = overlap(xe, back, front)
    height = profile.height
    if ye is None:
        # The free surface bridges an empty bin inside the mass (bins narrower
        # than the spacing of the grains).
        filled = np.isfinite(height)
        centres = profile.x_centres
        bridge = ~filled & (lx > 0.0)
        height = height.copy()
        height[bridge] = np.interp(centres[bridge], centres[filled], height[filled])
    thickness = np.clip(np.nan_to_num(height - z0, nan=0.0), 0.0, None)
    if ye is not None:
        ly = overlap(
            ye, float(np.min(x[main, cross] - r[main])), float(np.max(x[main, cross] + r[main]))
        )
        return float(np.sum(thickness * lx[:, None] * ly[None, :]))
    area = float(np.sum(thickness * lx))
    if d == 2:
        return area
    if width is None:
        w = float(np.max(x[main, cross] + r[main]) - np.min(x[main, cross] - r[main]))
    else:
        w = finite_positive(width, "width")
    return area * w


@overload
def relative_volume_variation(V: float, V0: float) -> float: ...


@overload
def relative_volume_variation(V: Sequence[float] | FloatArray, V0: float) -> FloatArray: ...


def relative_volume_variation(
    V: float | Sequence[float] | FloatArray, V0: float
) -> float | FloatArray:
    """Relative volume variation ``a_V = (V - V0) / V0`` (dimensionless), shaped like ``V``.

    Positive when the mass dilates, negative when it compacts. ``V`` is the
    volume occupied by the mass (:func:`granular_volume`) or a series ``V(t)``,
    >= 0; ``V0`` the initial volume, > 0, in the same units.
    """
    return relative_change(V, V0, "V", "V0", nonnegative=True)
