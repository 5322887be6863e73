"""Velocity profiles and the static/flowing interface."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from cocd.checks import bin_edges, finite_positive, finite_scalar
from cocd.measure._common import (
    STATIC_VELOCITY,
    FloatArray,
    bin_index,
    check_flow_axis,
    kinematics,
)
from cocd.scene import Scene

__all__ = ["static_flowing_interface", "velocity_profile"]


def velocity_profile(
    scene_or_positions: Scene | ArrayLike,
    velocities: ArrayLike | None = None,
    *,
    station_x: float,
    half_width: float,
    z_bins: ArrayLike,
    axis: int = 0,
    mask: ArrayLike | None = None,
) -> FloatArray:
    """Velocity profile ``u_x(z)`` at a station.

    For each z bin, the arithmetic mean of the flow-direction velocity
    ``v[:, axis]`` over the grains whose centre lies in the bin and within
    ``|c_x - station_x| < half_width`` (every y in 3D).

    Parameters
    ----------
    scene_or_positions : Scene or (n, d) array
        A scene, or the grain centres (m).
    velocities : (n, d) array, optional
        Grain velocities (m/s); required with positions, not allowed with a Scene.
    station_x : float
        Position of the station along the flow direction (m).
    half_width : float
        Half width of the measuring window (m), > 0.
    z_bins : (nz + 1,) array
        Bin edges in z (m), strictly increasing.
    axis : int
        Flow direction, a horizontal coordinate (0, or 1 in 3D).
    mask : (n,) bool array, optional
        Grains to consider. Default: every grain, or a Scene's free grains.

    Returns
    -------
    (nz,) array
        ``u_x`` per bin (m/s); NaN for a bin with no grain.
    """
    x, v, sel = kinematics(scene_or_positions, velocities, mask)
    check_flow_axis(axis, x.shape[1])
    ze = bin_edges(z_bins, "z_bins")
    xs = finite_scalar(station_x, "station_x")
    hw = finite_positive(half_width, "half_width")
    window = sel & (np.abs(x[:, axis] - xs) < hw)
    k, inside = bin_index(ze, x[:, -1])
    use = window & inside
    nz = ze.size - 1
    count = np.bincount(k[use], minlength=nz)
    total = np.bincount(k[use], weights=v[use, axis], minlength=nz)
    u = np.full(nz, np.nan)
    np.divide(total, count, out=u, where=count > 0)
    return u


def static_flowing_interface(
    scene_or_positions: Scene | ArrayLike,
    velocities: ArrayLike | None = None,
    *,
    station_x: float,
    half_width: float,
    z_bins: ArrayLike,
    bed_top: float,
    threshold: float = STATIC_VELOCITY,
    axis: int = 0,
    mask: ArrayLike | None = None,
) -> float:
    """Static/flowing interface ``h_sf`` at a station: the top of the static bed.

    From the profile ``u_x(z)`` of :func:`velocity_profile`, scan the bins
    upwards from the bottom of ``z_bins``, stopping at the first bin that
    starts at or above ``bed_top``: a bin is static when ``|u_x| < threshold``.
    ``h_sf`` is the upper edge of the last bin of the contiguous static run that
    starts at the lowest non-empty bin, capped at ``bed_top``. Empty bins
    neither end nor extend the run. So:

    - the whole initial bed static: ``h_sf = bed_top``;
    - the lowest non-empty bin flowing (the bed eroded to its base):
      ``h_sf = z_bins[0]``;
    - no grain below ``bed_top`` in the window: NaN.

    This is the thickness of the static layer within the initial erodible bed
    (Martin et al. 2022, section 5.2.2, with ``threshold`` = 1 cm/s as in
    Farin et al. 2014) measured in absolute z; subtract the bed's base for a
    thickness. ``|u_x|`` rather than ``u_x`` so that grains moving back up the
    slope do not count as static.

    Parameters
    ----------
    scene_or_positions, velocities, station_x, half_width, z_bins, axis, mask
        As in :func:`velocity_profile`; ``z_bins[0]`` should be the base of the
        erodible bed.
    bed_top : float
        z of the initial bed surface (m), ``h_i`` above the base.
    threshold : float
        Speed below which a bin is static (m/s), > 0; default 0.01.

    Returns
    -------
    float
        ``h_sf`` (m), or NaN.
    """
    top = finite_scalar(bed_top, "bed_top")
    c = finite_positive(threshold, "threshold")
    u = velocity_profile(
        scene_or_positions,
        velocities,
        station_x=station_x,
        half_width=half_width,
        z_bins=z_bins,
        axis=axis,
        mask=mask,
    )
    ze = bin_edges(z_bins, "z_bins")
    h = float("nan")
    for k in range(u.size):
        if ze[k] >= top:
            break
        if np.isnan(u[k]):
            continue
        if abs(u[k]) >= c:
            if np.isnan(h):
                h = float(ze[0])
            break
        h = float(ze[k + 1])
    return h if np.isnan(h) else min(h, top)
