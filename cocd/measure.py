"""Measurements: pure functions of a scene's state or of a recorded run.

These are the quantities read off a granular collapse (Martin et al. 2022,
sections 4-5): energies, the front position ``r_f`` and the runout, the mass
(free-surface) profile ``h(x)``, the volume occupied by the mass and its
relative variation ``a_V``, velocity profiles ``u_x(z)`` at a station, the
static/flowing interface ``h_sf`` and the erodible bed's energy ratio.

Conventions
-----------
- Frame: the flow direction is the coordinate ``axis`` (default 0, x); the last
  coordinate is z, normal to the plane (a slope is a tilted gravity, so z is the
  height above the plane, as in the field's profiles); in 3D the remaining
  coordinate is y, across the channel.
- State: functions take a :class:`~cocd.scene.Scene` or arrays: positions
  ``(n, d)``, radii ``(n,)`` or one number, velocities ``(n, d)``. Given a Scene,
  glued (fixed) grains are left out unless ``mask`` says otherwise: a glued layer
  spans the whole plane and would join every grain into one mass.
- Units: SI. In 2D a "volume" is an area (m^2, i.e. m^3 per metre of depth) and
  energies are per metre of depth.
- Bins are edges, strictly increasing; a grain belongs to the bin holding its
  centre, ``[e_k, e_k+1)`` (the last bin also holds its right edge); grains
  outside every bin are ignored.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import overload

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cocd.errors import SceneError
from cocd.scene import Scene

__all__ = [
    "DEFAULT_GAP_FRACTION",
    "STATIC_VELOCITY",
    "MassProfile",
    "bed_energy_ratio",
    "bed_surface",
    "front_position",
    "granular_volume",
    "kinetic_energy",
    "main_mass",
    "mass_profile",
    "potential_energy",
    "relative_runout",
    "relative_volume_variation",
    "runout",
    "static_flowing_interface",
    "surface_front",
    "velocity_profile",
]

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.intp]

#: Default connection threshold of :func:`main_mass`, as a fraction of the mean
#: grain diameter: two grains whose surfaces are closer belong to the same mass.
DEFAULT_GAP_FRACTION = 0.5

#: Speed below which a layer counts as static (1 cm/s, as in Farin et al. 2014).
STATIC_VELOCITY = 0.01


def kinetic_energy(scene: Scene) -> float:
    """Translational plus rotational kinetic energy of the free grains (J, or J/m in 2D)."""
    free = scene.free
    m = scene.masses[free]
    v2 = np.sum(scene.velocities[free] ** 2, axis=1)
    w = scene.angular_velocities[free]
    w2 = w**2 if scene.dim == 2 else np.sum(w**2, axis=1)
    return float(0.5 * np.sum(m * v2) + 0.5 * np.sum(scene.inertia[free] * w2))


def potential_energy(scene: Scene) -> float:
    """Gravitational potential energy ``-sum m g.c`` of the free grains, zero at the origin."""
    free = scene.free
    return float(-np.sum(scene.masses[free] * (scene.positions[free] @ scene.gravity)))


# -- the main mass and its front ---------------------------------------------
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
    x, r, sel = _grains(scene_or_positions, radii, mask)
    return _main_mass(x, r, sel, _gap(gap, r, sel))


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
    scene_or_positions : Scene or (n, d) array
        A scene, or the grain centres (m).
    radii : (n,) array or float, optional
        Radii (m); required with positions, not allowed with a Scene.
    axis : int
        Flow direction, a horizontal coordinate (0, or 1 in 3D).
    gap : float, optional
        Connection threshold (m), see :func:`main_mass`.
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
    x, r, sel = _grains(scene_or_positions, radii, mask)
    _flow_axis(axis, x.shape[1])
    main = _main_mass(x, r, sel, _gap(gap, r, sel))
    return float(np.max(x[main, axis] + r[main]))


def bed_surface(scene: Scene, x_bins: ArrayLike) -> FloatArray:
    """Height of the bed's surface per bin before a flow (m, absolute z): what it flows over.

    For a scene of :func:`cocd.builders.column_collapse` (groups ``bed``,
    ``layer``, ``column``): the top of the erodible layer where there is one,
    else the top of the glued bed grains, else the floor (0). For :func:`surface_front`.
    """
    edges = _edges(x_bins, "x_bins")
    groups = scene.groups
    r = scene.radii
    bed = groups.get("bed", slice(0, 0))
    x = scene.positions
    base = float(np.max(x[bed, -1] + r[bed])) if bed.stop > bed.start else 0.0
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
    thickest, the front is the upper edge of the last bin reached going
    downstream while crossing at most ``max_gap_bins`` bins in a row that do
    not carry it. On an erodible bed this is the front the eye sees (column
    and entrained layer grains alike), and grains rolling ahead alone (a
    thin, isolated bump) do not move it, which :func:`front_position` cannot
    ensure once the layer joins every grain into one mass.

    Parameters
    ----------
    scene_or_positions, radii, mask : see :func:`front_position`
        Give the grains that can flow (a Scene's free grains by default).
    x_bins : (nx + 1,) array
        Bin edges along the flow direction (m); one mean diameter is a good width.
        The front is known to one bin.
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
    x, r, sel = _grains(scene_or_positions, radii, mask)
    _flow_axis(axis, x.shape[1])
    edges = _edges(x_bins, "x_bins")
    nx = edges.size - 1
    base = _float_array(surface, "surface")
    if base.ndim == 0:
        base = np.full(nx, float(base))
    if base.shape != (nx,):
        raise SceneError(f"surface must be a number or have shape ({nx},), got {base.shape}")
    if threshold is None:
        threshold = float(np.mean(r[sel]))
    threshold = _finite_scalar(threshold, "threshold")
    if threshold < 0.0:
        raise SceneError(f"threshold must be >= 0, got {threshold:g}")
    if int(max_gap_bins) != max_gap_bins or max_gap_bins < 0:
        raise SceneError(f"max_gap_bins must be an integer >= 0, got {max_gap_bins!r}")
    height = _profile(x, r, sel, edges, None, axis).height
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
    return float(edges[last + 1])


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
    r0 = _finite_scalar(initial_front, "initial_front")
    rf = _finite_array(final_front, "final_front")
    return _scalar_or_array(rf - r0)


@overload
def relative_runout(L0: float, Lf: float) -> float: ...
@overload
def relative_runout(L0: float, Lf: Sequence[float] | FloatArray) -> FloatArray: ...
def relative_runout(L0: float, Lf: float | Sequence[float] | FloatArray) -> float | FloatArray:
    """Relative runout ``(L_f - L_0) / L_0`` (dimensionless).

    Parameters
    ----------
    L0 : float
        Initial length of the mass, from the back wall to the front (m), > 0.
    Lf : float or (nt,) array
        Final length (or a series ``L(t)``), measured from the same back wall (m).

    Returns
    -------
    float or (nt,) array
        Same shape as ``Lf``.
    """
    length0 = _finite_scalar(L0, "L0")
    if length0 <= 0.0:
        raise SceneError(f"L0 must be > 0, got {length0:g}")
    lengths = _finite_array(Lf, "Lf")
    return _scalar_or_array((lengths - length0) / length0)


# -- the mass profile and the volume -----------------------------------------
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
    scene_or_positions : Scene or (n, d) array
        A scene, or the grain centres (m).
    radii : (n,) array or float, optional
        Radii (m); required with positions, not allowed with a Scene.
    x_bins : (nx + 1,) array
        Bin edges along the flow direction (m), strictly increasing.
    y_bins : (ny + 1,) array, optional
        Bin edges across the channel (m), 3D only.
    axis : int
        Flow direction, a horizontal coordinate (0, or 1 in 3D).
    connected : bool
        Keep only the main connected mass (default); False keeps every
        selected grain.
    gap : float, optional
        Connection threshold (m), see :func:`main_mass`.
    mask : (n,) bool array, optional
        Grains to consider. Default: every grain, or a Scene's free grains.

    Returns
    -------
    MassProfile
        Heights (m, absolute z: subtract the bed's z for a thickness), solid
        volume and grain count per bin.
    """
    x, r, sel = _grains(scene_or_positions, radii, mask)
    d = x.shape[1]
    _flow_axis(axis, d)
    xe = _edges(x_bins, "x_bins")
    ye = None
    if y_bins is not None:
        if d != 3:
            raise SceneError("y_bins apply to 3D scenes only (the grains are 2D)")
        ye = _edges(y_bins, "y_bins")
    keep = _main_mass(x, r, sel, _gap(gap, r, sel)) if connected else sel
    return _profile(x, r, keep, xe, ye, axis)


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
    scene_or_positions : Scene or (n, d) array
        A scene, or the grain centres (m).
    radii : (n,) array or float, optional
        Radii (m); required with positions, not allowed with a Scene.
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
    axis : int
        Flow direction, a horizontal coordinate (0, or 1 in 3D).
    gap : float, optional
        Connection threshold (m), see :func:`main_mass`.
    mask : (n,) bool array, optional
        Grains to consider. Default: every grain, or a Scene's free grains.

    Returns
    -------
    float
        ``V`` in m^3 (m^2, i.e. m^3 per metre of depth, in 2D).
    """
    x, r, sel = _grains(scene_or_positions, radii, mask)
    d = x.shape[1]
    _flow_axis(axis, d)
    z0 = _finite_scalar(base, "base")
    g = _gap(gap, r, sel)
    main = _main_mass(x, r, sel, g)
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
        xe = _edges(x_bins, "x_bins")
        _covers(xe, x[main, axis], "x_bins")
    ye = None
    if y_bins is not None:
        if d != 3:
            raise SceneError("y_bins apply to 3D scenes only (the grains are 2D)")
        if width is not None:
            raise SceneError("give either y_bins or width, not both")
        ye = _edges(y_bins, "y_bins")
        _covers(ye, x[main, cross], "y_bins")
    elif width is not None and d == 2:
        raise SceneError("width applies to 3D scenes only (a 2D volume is per metre of depth)")

    profile = _profile(x, r, main, xe, ye, axis)
    lx = _overlap(xe, back, front)
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
        ly = _overlap(
            ye, float(np.min(x[main, cross] - r[main])), float(np.max(x[main, cross] + r[main]))
        )
        return float(np.sum(thickness * lx[:, None] * ly[None, :]))
    area = float(np.sum(thickness * lx))
    if d == 2:
        return area
    if width is None:
        w = float(np.max(x[main, cross] + r[main]) - np.min(x[main, cross] - r[main]))
    else:
        w = _finite_scalar(width, "width")
        if w <= 0.0:
            raise SceneError(f"width must be > 0, got {w:g}")
    return area * w


@overload
def relative_volume_variation(V: float, V0: float) -> float: ...
@overload
def relative_volume_variation(V: Sequence[float] | FloatArray, V0: float) -> FloatArray: ...
def relative_volume_variation(
    V: float | Sequence[float] | FloatArray, V0: float
) -> float | FloatArray:
    """Relative volume variation ``a_V = (V - V0) / V0`` (dimensionless).

    Positive when the mass dilates, negative when it compacts.

    Parameters
    ----------
    V : float or (nt,) array
        Volume occupied by the mass (see :func:`granular_volume`), or a series
        ``V(t)``, >= 0.
    V0 : float
        Initial volume, > 0, same units as ``V``.

    Returns
    -------
    float or (nt,) array
        Same shape as ``V``.
    """
    v0 = _finite_scalar(V0, "V0")
    if v0 <= 0.0:
        raise SceneError(f"V0 must be > 0, got {v0:g}")
    v = _finite_array(V, "V")
    if np.any(v < 0.0):
        raise SceneError(f"V must be >= 0, got {float(v.min()):g}")
    return _scalar_or_array((v - v0) / v0)


# -- velocity profiles and the static/flowing interface -----------------------
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
    x, v, sel = _kinematics(scene_or_positions, velocities, mask)
    _flow_axis(axis, x.shape[1])
    ze = _edges(z_bins, "z_bins")
    xs = _finite_scalar(station_x, "station_x")
    hw = _finite_scalar(half_width, "half_width")
    if hw <= 0.0:
        raise SceneError(f"half_width must be > 0, got {hw:g}")
    window = sel & (np.abs(x[:, axis] - xs) < hw)
    k, inside = _bin_index(ze, x[:, -1])
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
    scene_or_positions : Scene or (n, d) array
        A scene, or the grain centres (m).
    velocities : (n, d) array, optional
        Grain velocities (m/s); required with positions, not allowed with a Scene.
    station_x, half_width, z_bins, axis, mask
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
    top = _finite_scalar(bed_top, "bed_top")
    c = _finite_scalar(threshold, "threshold")
    if c <= 0.0:
        raise SceneError(f"threshold must be > 0, got {c:g}")
    u = velocity_profile(
        scene_or_positions,
        velocities,
        station_x=station_x,
        half_width=half_width,
        z_bins=z_bins,
        axis=axis,
        mask=mask,
    )
    ze = _edges(z_bins, "z_bins")
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


def bed_energy_ratio(scene: Scene, bed_mask: ArrayLike, *, reference_height: float = 0.0) -> float:
    """Kinetic-to-potential energy ratio of the erodible bed, ``e_b = E_k / E_p``.

    ``E_k`` is the translational plus rotational kinetic energy of the free
    grains of the bed. ``E_p = sum m_i (-g_z) (c_z,i - reference_height)`` is
    their potential energy in the component of gravity normal to the plane, so
    the height above the plane ``z = reference_height`` (the floor, by default):
    on a slope the along-slope part of the potential has no natural zero, and on
    a horizontal plane this is the usual ``m g h``. Martin et al. (2022, Fig. 13)
    plot ``e_b / max_t e_b``.

    Parameters
    ----------
    scene : Scene
        The state.
    bed_mask : (n,) bool array
        The grains of the initial erodible bed; glued grains are left out.
    reference_height : float
        z of the zero of potential energy (m).

    Returns
    -------
    float
        ``e_b`` (dimensionless).
    """
    if not isinstance(scene, Scene):
        raise SceneError(f"bed_energy_ratio needs a Scene, got {type(scene).__name__}")
    bed = _mask(bed_mask, scene.n_grains, "bed_mask") & scene.free
    if not bed.any():
        raise SceneError("bed_mask selects no free grain")
    z0 = _finite_scalar(reference_height, "reference_height")
    gz = float(scene.gravity[-1])
    if gz >= 0.0:
        raise SceneError(f"gravity must point down the z axis (g_z < 0), got g_z = {gz:g}")
    m = scene.masses[bed]
    v2 = np.sum(scene.velocities[bed] ** 2, axis=1)
    w = scene.angular_velocities[bed]
    w2 = w**2 if scene.dim == 2 else np.sum(w**2, axis=1)
    ek = 0.5 * float(np.sum(m * v2)) + 0.5 * float(np.sum(scene.inertia[bed] * w2))
    ep = -gz * float(np.sum(m * (scene.positions[bed, -1] - z0)))
    if ep <= 0.0:
        raise SceneError(
            f"the bed's potential energy above z = {z0:g} is {ep:g} J: it must be > 0 "
            "(is reference_height below the bed?)"
        )
    return ek / ep


# -- helpers -------------------------------------------------------------------
def _grains(
    scene_or_positions: Scene | ArrayLike, radii: ArrayLike | float | None, mask: ArrayLike | None
) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Positions ``(n, d)``, radii ``(n,)`` and the selected grains ``(n,)``."""
    if isinstance(scene_or_positions, Scene):
        if radii is not None:
            raise SceneError("pass a Scene alone, or positions and radii: not a Scene and radii")
        x, r = scene_or_positions.positions, scene_or_positions.radii
        default = scene_or_positions.free.copy()
    else:
        x = _positions(scene_or_positions)
        if radii is None:
            raise SceneError("radii are required with a positions array")
        r = _float_array(radii, "radii")
        if r.ndim == 0:
            r = np.full(x.shape[0], float(r))
        if r.shape != (x.shape[0],):
            raise SceneError(f"radii must be a number or have shape ({x.shape[0]},), got {r.shape}")
        _require_finite(r, "radii")
        if np.any(r <= 0.0):
            k = int(np.argmax(r <= 0.0))
            raise SceneError(f"radius of grain {k} is {r[k]:g}: radii must be > 0")
        default = np.ones(x.shape[0], dtype=bool)
    sel = default if mask is None else _mask(mask, x.shape[0], "mask")
    if not sel.any():
        raise SceneError("no grain selected (the mask is all False)")
    return x, r, sel


def _kinematics(
    scene_or_positions: Scene | ArrayLike, velocities: ArrayLike | None, mask: ArrayLike | None
) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Positions ``(n, d)``, velocities ``(n, d)`` and the selected grains ``(n,)``."""
    if isinstance(scene_or_positions, Scene):
        if velocities is not None:
            raise SceneError("pass a Scene alone, or positions and velocities: not both")
        x, v = scene_or_positions.positions, scene_or_positions.velocities
        default = scene_or_positions.free.copy()
    else:
        x = _positions(scene_or_positions)
        if velocities is None:
            raise SceneError("velocities are required with a positions array")
        v = _float_array(velocities, "velocities")
        if v.shape != x.shape:
            raise SceneError(f"velocities must have shape {x.shape} like positions, got {v.shape}")
        _require_finite(v, "velocities")
        default = np.ones(x.shape[0], dtype=bool)
    sel = default if mask is None else _mask(mask, x.shape[0], "mask")
    if not sel.any():
        raise SceneError("no grain selected (the mask is all False)")
    return x, v, sel


def _positions(value: ArrayLike) -> FloatArray:
    x = _float_array(value, "positions")
    if x.ndim != 2 or x.shape[1] not in (2, 3) or x.shape[0] == 0:
        raise SceneError(f"positions must have shape (n, 2) or (n, 3) with n >= 1, got {x.shape}")
    _require_finite(x, "positions")
    return x


def _main_mass(x: FloatArray, r: FloatArray, sel: BoolArray, gap: float) -> BoolArray:
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


def _profile(
    x: FloatArray,
    r: FloatArray,
    keep: BoolArray,
    xe: FloatArray,
    ye: FloatArray | None,
    axis: int,
) -> MassProfile:
    d = x.shape[1]
    kx, inside = _bin_index(xe, x[:, axis])
    shape: tuple[int, ...] = (xe.size - 1,)
    flat = kx
    if ye is not None:
        ky, inside_y = _bin_index(ye, x[:, 1 - axis])
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


def _bin_index(edges: FloatArray, values: FloatArray) -> tuple[IntArray, BoolArray]:
    """Bin of each value, ``[e_k, e_k+1)`` with the last edge included, and whether inside."""
    k = np.searchsorted(edges, values, side="right") - 1
    k[values == edges[-1]] = edges.size - 2
    inside = (k >= 0) & (k < edges.size - 1)
    return np.where(inside, k, 0), inside


def _overlap(edges: FloatArray, lo: float, hi: float) -> FloatArray:
    """Length of each bin inside ``[lo, hi]``, shape ``(nbins,)``."""
    return np.asarray(np.clip(np.minimum(edges[1:], hi) - np.maximum(edges[:-1], lo), 0.0, None))


def _covers(edges: FloatArray, centres: FloatArray, name: str) -> None:
    lo, hi = float(centres.min()), float(centres.max())
    if lo < edges[0] or hi > edges[-1]:
        raise SceneError(
            f"{name} [{edges[0]:g}, {edges[-1]:g}] do not cover the centres of the mass "
            f"[{lo:g}, {hi:g}]"
        )


def _gap(gap: float | None, r: FloatArray, sel: BoolArray) -> float:
    if gap is None:
        return DEFAULT_GAP_FRACTION * 2.0 * float(np.mean(r[sel]))
    g = _finite_scalar(gap, "gap")
    if g < 0.0:
        raise SceneError(f"gap must be >= 0, got {g:g}")
    return g


def _flow_axis(axis: int, d: int) -> None:
    if not isinstance(axis, (int, np.integer)) or not 0 <= axis < d - 1:
        raise SceneError(
            f"axis must be a horizontal coordinate (0{', 1' if d == 3 else ''}) in {d}D, "
            f"got {axis!r}: the last coordinate is z"
        )


def _edges(value: ArrayLike, name: str) -> FloatArray:
    e = _float_array(value, name)
    if e.ndim != 1 or e.size < 2:
        raise SceneError(f"{name} must be a 1-D array of at least 2 edges, got shape {e.shape}")
    _require_finite(e, name)
    if np.any(np.diff(e) <= 0.0):
        raise SceneError(f"{name} must be strictly increasing")
    return e


def _mask(value: ArrayLike, n: int, name: str) -> BoolArray:
    m = np.asarray(value)
    if m.shape != (n,) or m.dtype != bool:
        raise SceneError(f"{name} must be a boolean array of shape ({n},), got {m.dtype} {m.shape}")
    return m.copy()


def _float_array(value: object, name: str) -> FloatArray:
    try:
        return np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise SceneError(f"{name} must be numeric: {exc}") from None


def _require_finite(a: FloatArray, name: str) -> None:
    bad = ~np.isfinite(a)
    if bad.any():
        where = tuple(int(k) for k in np.argwhere(bad)[0])
        subject = f"{name}[{', '.join(map(str, where))}]" if a.ndim else name
        raise SceneError(f"{subject} is {a[where]}: {name} must be finite")


def _finite_scalar(value: object, name: str) -> float:
    a = _float_array(value, name)
    if a.ndim != 0:
        raise SceneError(f"{name} must be a number, got shape {a.shape}")
    _require_finite(a, name)
    return float(a)


def _finite_array(value: object, name: str) -> FloatArray:
    a = _float_array(value, name)
    if a.ndim > 1:
        raise SceneError(f"{name} must be a number or a 1-D series, got shape {a.shape}")
    _require_finite(a, name)
    return a


def _scalar_or_array(a: FloatArray) -> float | FloatArray:
    return float(a) if a.ndim == 0 else a
