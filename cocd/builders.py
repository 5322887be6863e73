"""Scene builders: deterministic for a given seed."""

from __future__ import annotations

from collections.abc import Callable
from functools import partial

import numpy as np
from numpy.typing import NDArray

from cocd.checks import checked
from cocd.errors import SceneError
from cocd.packing import rain_deposition
from cocd.resources import BYTES_PER_GRAIN, check_fits
from cocd.scene import Scene, Wall

__all__ = [
    "HARD_CASES",
    "box_3d",
    "column_2d",
    "column_collapse",
    "fast_impact",
    "grain_groups",
    "heavy_on_light",
    "jammed_box",
    "size_ratio",
    "stack",
    "static_box",
    "tall_stack",
    "wedged_grain",
    "zero_gap",
]

FloatArray = NDArray[np.float64]
G = 9.81
#: Solid fractions used to size a packing from its grain count (or the reverse):
#: frictionless rain deposition of 10 %-polydisperse grains.
RAIN_FRACTION = {2: 0.84, 3: 0.63}


@checked
def column_2d(
    n_grains: int = 300,
    *,
    width: float = 0.2,
    aspect: float = 0.7,
    polydispersity: float = 0.1,
    density: float = 2500.0,
    mu: float = 0.3,
    mu_wall: float | None = None,
    seed: int = 0,
) -> Scene:
    """A 2D granular column released at t = 0 (its gate removed), on a smooth floor.

    Discs sit on a loose hexagonal lattice (gaps of 2 % of the largest
    diameter) filling a ``width x aspect*width`` column against a left wall
    at ``x = 0``, on a floor at ``y = 0``; the right side is open.

    Parameters
    ----------
    n_grains : int
        Number of discs.
    width : float
        Column width R0 (m); the grain size follows from ``n_grains``.
    aspect : float
        Height over width, H0 / R0.
    polydispersity : float
        Radii uniform in ``r (1 -+ polydispersity / 2)``.
    density, mu, mu_wall : float
        Material; ``mu_wall`` defaults to ``mu``.
    seed : int
        Seed of the radii.
    """
    n_grains = _count("n_grains", n_grains)
    if not (width > 0 and aspect > 0):
        raise SceneError(f"width and aspect must be > 0, got {width} and {aspect}")
    if not 0 <= polydispersity < 1:
        raise SceneError(f"polydispersity must be in [0, 1), got {polydispersity}")
    n = int(n_grains)
    spacing = width * np.sqrt(2.0 * aspect / (np.sqrt(3.0) * n))
    cols = max(1, int(np.floor(width / spacing)))
    r_max = spacing / (2.0 * 1.02)
    r_mean = r_max / (1.0 + polydispersity / 2.0)
    rng = np.random.default_rng(seed)
    radii = r_mean * (1.0 + polydispersity * (rng.random(n) - 0.5))

    k = np.arange(n)
    row, col = k // cols, k % cols
    x = spacing / 2.0 + col * spacing + np.where(row % 2 == 1, spacing / 2.0, 0.0)
    y = spacing / 2.0 + row * spacing * np.sqrt(3.0) / 2.0
    walls = [Wall((0.0, 0.0), (0.0, 1.0)), Wall((0.0, 0.0), (1.0, 0.0))]
    return Scene(
        np.stack([x, y], axis=1),
        radii,
        density=density,
        walls=walls,
        gravity=(0.0, -9.81),
        mu=mu,
        mu_wall=mu_wall,
    )


@checked
def stack(
    n_grains: int,
    *,
    radius: float = 0.005,
    dim: int = 3,
    density: float = 2500.0,
    mu: float = 0.3,
    gap: float = 0.0,
) -> Scene:
    """A vertical stack of equal grains resting on a horizontal wall at height 0.

    ``gap`` separates consecutive grains (and the lowest from the wall).
    """
    n_grains = _count("n_grains", n_grains)
    if dim not in (2, 3):
        raise SceneError(f"dim must be 2 or 3, got {dim}")
    heights = radius + gap + np.arange(int(n_grains)) * (2.0 * radius + gap)
    positions = np.zeros((int(n_grains), dim))
    positions[:, -1] = heights
    up = np.zeros(dim)
    up[-1] = 1.0
    return Scene(
        positions,
        radius,
        density=density,
        walls=[Wall(np.zeros(dim), up)],
        mu=mu,
    )


@checked
def box_3d(
    n_grains: int = 2000,
    *,
    diameter: float = 0.005,
    width: float | None = None,
    polydispersity: float = 0.1,
    density: float = 2500.0,
    mu: float = 0.3,
    mu_wall: float | None = None,
    seed: int = 0,
) -> Scene:
    """Spheres on a loose cubic lattice inside a square box (floor and four side walls).

    Parameters
    ----------
    n_grains : int
        Number of spheres.
    diameter : float
        Largest diameter is ``diameter``; radii uniform in
        ``r (1 -+ polydispersity / 2)`` with ``r (1 + polydispersity / 2) = diameter / 2``.
    width : float, optional
        Inner side of the box; default fits a square base of about
        ``n_grains ** (1/3)`` sites per side.
    """
    n_grains = _count("n_grains", n_grains)
    if not diameter > 0:
        raise SceneError(f"diameter must be > 0, got {diameter}")
    if not 0 <= polydispersity < 1:
        raise SceneError(f"polydispersity must be in [0, 1), got {polydispersity}")
    n = int(n_grains)
    spacing = 1.02 * diameter
    side = max(1, int(np.ceil(n ** (1.0 / 3.0))))
    if width is not None:
        if not width >= spacing:
            raise SceneError(f"width {width} is smaller than one grain site {spacing}")
        side = int(np.floor(width / spacing))
    box = side * spacing if width is None else float(width)
    k = np.arange(n)
    ix, iy, iz = k % side, (k // side) % side, k // (side * side)
    positions = (np.stack([ix, iy, iz], axis=1) + 0.5) * spacing
    rng = np.random.default_rng(seed)
    r_max = diameter / 2.0
    radii = r_max / (1 + polydispersity / 2) * (1.0 + polydispersity * (rng.random(n) - 0.5))
    walls = [
        Wall((0.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
        Wall((0.0, 0.0, 0.0), (1.0, 0.0, 0.0)),
        Wall((0.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
        Wall((box, 0.0, 0.0), (-1.0, 0.0, 0.0)),
        Wall((0.0, box, 0.0), (0.0, -1.0, 0.0)),
    ]
    return Scene(positions, radii, density=density, walls=walls, mu=mu, mu_wall=mu_wall)


# -- column collapse, static box ---------------------------------------------
@checked
def column_collapse(
    dim: int = 2,
    *,
    n_grains: int | None = None,
    diameter: float | None = None,
    length: float = 0.20,
    height: float = 0.14,
    width: float | None = None,
    slope_deg: float = 0.0,
    polydispersity: float = 0.1,
    density: float = 2500.0,
    mu: float = 0.3,
    mu_wall: float | None = None,
    bed: str = "smooth",
    erodible_thickness: float = 0.0,
    bed_length: float | None = None,
    packing: str = "lattice",
    mu_prep: float = 0.0,
    seed: int = 0,
    solver: str | None = None,
    cache: bool = True,
) -> Scene:
    """A granular column R0 x H0 (x W) released at t = 0, the paper's collapse set-up.

    The column stands against a back wall at ``x = 0`` on a bed along ``x``
    (the floor is the plane ``z = 0``, ``y = 0`` in 2D); its gate at ``x = R0`` is
    removed at t = 0, so there is no front wall. In 3D the channel is bounded
    by lateral walls at ``y = 0`` and ``y = W``. A slope is a tilted gravity:
    ``g (sin a, -cos a)`` in 2D, ``g (sin a, 0, -cos a)`` in 3D, with ``x``
    down the slope.

    Grains are ordered bed (fixed), erodible layer, column; see
    :func:`grain_groups`.

    Parameters
    ----------
    dim : {2, 3}
    n_grains : int, optional
        Number of column grains. Give exactly one of ``n_grains`` and
        ``diameter``: the other follows from the column's size and the packing
        fraction (lattice: its own; rain: ``RAIN_FRACTION``).
    diameter : float, optional
        Mean grain diameter (m).
    length, height : float
        Column length R0 and height H0 (m); default 20 x 14 cm (aspect 0.7).
        With rain packing the settled height is H0 to within a few diameters.
    width : float, optional
        3D channel width W between the lateral walls; default 0.20 m. Not
        allowed in 2D.
    slope_deg : float
        Bed inclination in degrees, in (-90, 90).
    polydispersity : float
        Radii uniform in ``r (1 -+ polydispersity / 2)``, scaled so that the
        mean diameter is exact.
    density, mu, mu_wall : float
        Material; ``mu_wall`` defaults to ``mu``.
    bed : {"smooth", "rough"}
        Rough: a layer of glued (fixed) grains of the mean diameter covers the
        floor over ``bed_length``.
    erodible_thickness : float
        Thickness (m) of a layer of free grains over the whole bed length, in
        front of and under the column; 0 for none. With a layer, an end wall
        at ``x = bed_length`` holds it.
    bed_length : float, optional
        Length of the rough bed and of the erodible layer; default ``4 R0``.
    packing : {"lattice", "rain"}
        Lattice: a loose lattice (hexagonal in 2D, cubic in 3D, gaps of 2 % of
        the largest diameter), not settled. Rain: grains dropped in the
        container (gate closed) and settled with :func:`~cocd.packing.rain_deposition`
        (cached on disk).
    mu_prep : float
        Friction during rain deposition (0: compact, > 0: loose).
    seed : int
        Seed of the radii and of the initial jitter.
    solver : str, optional
        Backend used for rain deposition; default ``clarabel`` in 2D and
        ``scs-dual`` in 3D (measured 2.5 times faster than clarabel there).
    cache : bool
        Use the packing cache for rain deposition.

    Returns
    -------
    Scene
    """
    dim = _dim(dim)
    length = _positive("length", length)
    height = _positive("height", height)
    if dim == 2 and width is not None:
        raise SceneError("width is the 3D channel width; leave it None in 2D")
    chan = _positive("width", 0.20 if width is None else width)
    if not (np.isfinite(slope_deg) and -90.0 < slope_deg < 90.0):
        raise SceneError(f"slope_deg must be in (-90, 90), got {slope_deg}")
    poly = _polydispersity(polydispersity)
    density = _positive("density", density)
    if bed not in ("smooth", "rough"):
        raise SceneError(f"bed must be 'smooth' or 'rough', got {bed!r}")
    if packing not in ("lattice", "rain"):
        raise SceneError(f"packing must be 'lattice' or 'rain', got {packing!r}")
    if not (np.isfinite(erodible_thickness) and erodible_thickness >= 0.0):
        raise SceneError(f"erodible_thickness must be finite and >= 0, got {erodible_thickness}")
    bed_len = 4.0 * length if bed_length is None else _positive("bed_length", bed_length)
    if bed_len < length:
        raise SceneError(f"bed_length {bed_len} is shorter than the column length {length}")

    cross = np.array([length, chan]) if dim == 3 else np.array([length])
    volume = float(np.prod(cross)) * height
    if packing == "lattice":
        n, d_mean = _lattice_size(dim, n_grains, diameter, volume, poly)
    else:
        n, d_mean = _rain_size(dim, n_grains, diameter, volume, poly)
    rng = np.random.default_rng(seed)
    radii = _radii(n, d_mean, poly, rng)
    r_max = float(radii.max())

    # Bed: fixed grains of the mean diameter, touching, on the floor.
    parts_x: list[FloatArray] = []
    parts_r: list[FloatArray] = []
    groups: dict[str, slice] = {}
    base = 0.0
    if bed == "rough":
        bed_x = _bed_grains(dim, d_mean, bed_len, chan)
        parts_x.append(bed_x)
        parts_r.append(np.full(len(bed_x), d_mean / 2.0))
        base = d_mean
    n_bed = sum(len(p) for p in parts_x)
    groups["bed"] = slice(0, n_bed)

    up = np.zeros(dim)
    up[-1] = 1.0
    walls = [Wall(np.zeros(dim), up), Wall(np.zeros(dim), np.eye(dim)[0])]
    if dim == 3:
        walls += [Wall(np.zeros(3), (0.0, 1.0, 0.0)), Wall((0.0, chan, 0.0), (0.0, -1.0, 0.0))]
    if erodible_thickness > 0.0:
        walls.append(Wall(bed_len * np.eye(dim)[0], -np.eye(dim)[0]))
    gate = Wall(length * np.eye(dim)[0], -np.eye(dim)[0])
    horizontal = np.array([bed_len, chan]) if dim == 3 else np.array([bed_len])
    layer_n = 0
    scene_kw = dict(density=density, mu=mu, mu_wall=mu_wall)

    if erodible_thickness > 0.0:
        layer_volume = float(np.prod(horizontal)) * erodible_thickness
        if packing == "lattice":
            spacing = 1.02 * 2.0 * r_max
            layer_x = _lattice(dim, None, horizontal, base, spacing, erodible_thickness, rng)
            layer_r = _radii(len(layer_x), d_mean, poly, rng)
        else:
            layer_n = max(
                1, round(RAIN_FRACTION[dim] * layer_volume / _grain_volume(dim, d_mean, poly))
            )
            layer_r = _radii(layer_n, d_mean, poly, rng)
            layer_x = _loose_lattice(dim, layer_n, horizontal, base, float(layer_r.max()), rng)
            settled = _deposit(
                [*parts_x, layer_x],
                [*parts_r, layer_r],
                n_bed,
                walls,
                scene_kw,
                mu_prep,
                solver,
                cache,
            )
            layer_x = settled[n_bed:]
        parts_x.append(layer_x)
        parts_r.append(layer_r)
        # The column stands on the layer's surface (its highest point under the column).
        under = layer_x[:, 0] < length + 2.0 * r_max
        base = float(np.max(layer_x[under, -1] + layer_r[under])) + 0.02 * r_max
    n_below = sum(len(p) for p in parts_x)
    groups["layer"] = slice(n_bed, n_below)

    if packing == "lattice":
        spacing = 1.02 * 2.0 * r_max
        column_x = _lattice(dim, n, cross, base, spacing, None, rng)
        parts_x.append(column_x)
        parts_r.append(radii)
    else:
        column_x = _loose_lattice(dim, n, cross, base, r_max, rng)
        parts_x.append(column_x)
        parts_r.append(radii)
        # The layer is held still while the column rains onto it: the gate plane
        # would cut through the layer in front of the column.
        settled = _deposit(
            parts_x, parts_r, n_below, [*walls, gate], scene_kw, mu_prep, solver, cache
        )
        parts_x = [settled]
        parts_r = [np.concatenate(parts_r)]
    groups["column"] = slice(n_below, n_below + n)

    positions = np.concatenate(parts_x)
    all_r = np.concatenate(parts_r)
    fixed = np.zeros(len(all_r), dtype=bool)
    fixed[groups["bed"]] = True
    a = np.radians(slope_deg)
    gravity = np.zeros(dim)
    gravity[0], gravity[-1] = G * np.sin(a), -G * np.cos(a)
    scene = Scene(
        positions,
        all_r,
        fixed=fixed,
        walls=walls,
        gravity=gravity,
        **scene_kw,  # type: ignore[arg-type]
    )
    _set_groups(scene, groups)
    return scene


@checked
def static_box(
    dim: int = 3,
    *,
    n_grains: int,
    diameter: float = 0.005,
    width: float | None = None,
    polydispersity: float = 0.1,
    density: float = 2500.0,
    mu: float = 0.3,
    mu_wall: float | None = None,
    mu_prep: float = 0.0,
    seed: int = 0,
    solver: str | None = None,
    cache: bool = True,
) -> Scene:
    """Grains at rest in a box, prepared by rain deposition (the paper's Fig. 3 case).

    Parameters
    ----------
    dim : {2, 3}
    n_grains : int
        Number of grains.
    diameter : float
        Mean diameter (m).
    width : float, optional
        Inner side of the (square) box; default about ``n_grains ** (1/d)``
        diameters, so that the settled packing is roughly as tall as wide.
    polydispersity, density, mu, mu_wall : float
        As in :func:`column_collapse`.
    mu_prep : float
        Friction during deposition (0: compact, > 0: loose); ``mu`` is set after.
    seed : int
    solver : str, optional
        Backend of the deposition; default as in :func:`column_collapse`.
    cache : bool
        Use the packing cache.

    Returns
    -------
    Scene
        Velocities zero, floor at the last coordinate 0, side walls at 0 and
        ``width``; no lid.
    """
    dim = _dim(dim)
    n = _count("n_grains", n_grains)
    d_mean = _positive("diameter", diameter)
    poly = _polydispersity(polydispersity)
    if width is None:
        side = max(4.0, np.ceil((n / RAIN_FRACTION[dim]) ** (1.0 / dim)))
        width = float(side * d_mean * (np.pi / 6.0 if dim == 3 else np.pi / 4.0) ** (1.0 / dim))
        width = max(width, 4.0 * d_mean)
    box = _positive("width", width)
    rng = np.random.default_rng(seed)
    radii = _radii(n, d_mean, poly, rng)
    if box < 2.2 * float(radii.max()):
        raise SceneError(f"width {box} is too small for grains of diameter {2 * radii.max():.3g}")
    horizontal = np.full(dim - 1, box)
    positions = _loose_lattice(dim, n, horizontal, 0.0, float(radii.max()), rng)
    walls = _box_walls(dim, box)
    scene_kw = dict(density=density, mu=mu, mu_wall=mu_wall)
    settled = _deposit([positions], [radii], 0, walls, scene_kw, mu_prep, solver, cache)
    return Scene(settled, radii, walls=walls, **scene_kw)  # type: ignore[arg-type]


def grain_groups(scene: Scene) -> dict[str, slice]:
    """Index ranges of the grain groups a builder made (e.g. bed, layer, column).

    Scenes not made by :func:`column_collapse` have one group, ``"all"``.
    """
    return dict(scene.groups)


# -- hard cases --------------------------------------------------------------
@checked
def heavy_on_light(mass_ratio: float = 1e3, *, dim: int = 2, radius: float = 0.005) -> Scene:
    """A heavy grain resting on light grains of the same size (mass ratio by density).

    Stresses: conditioning. The inverse-mass-weighted Delassus operator ``W``
    mixes entries a ratio ``mass_ratio`` apart; first-order methods (pgs, apgd)
    converge at a rate set by that ratio, interior-point methods lose digits.

    Light grains touch the floor and each other (zero gaps): two in 2D, three
    in a triangle in 3D; the heavy grain sits in their hollow, touching them.
    """
    dim = _dim(dim)
    ratio = _positive("mass_ratio", mass_ratio)
    r = _positive("radius", radius)
    if dim == 2:
        light = np.array([[-r, r], [r, r]])
        heavy = np.array([[0.0, r + np.sqrt(3.0) * r]])
    else:
        ang = np.radians([90.0, 210.0, 330.0])
        ring = 2.0 * r / np.sqrt(3.0)  # centres 2r apart
        light = np.stack([ring * np.cos(ang), ring * np.sin(ang), np.full(3, r)], axis=1)
        heavy = np.array([[0.0, 0.0, r + np.sqrt(4.0 * r * r - ring * ring)]])
    positions = np.concatenate([light, heavy])
    density = np.full(len(positions), 2500.0)
    density[-1] *= ratio
    return Scene(positions, r, density=density, walls=[_floor(dim)])


@checked
def tall_stack(n: int = 50, *, dim: int = 2, radius: float = 0.005, mu: float = 0.3) -> Scene:
    """A vertical stack of ``n`` touching grains on the floor.

    Stresses: a long chain of contacts whose forces grow linearly to ``n m g``
    at the bottom; propagating the load through the chain takes first-order
    methods about ``n`` iterations per digit, and the stack is only
    neutrally stable (any tangential error makes it buckle).
    """
    return stack(_count("n", n), radius=_positive("radius", radius), dim=_dim(dim), mu=mu)


@checked
def jammed_box(
    n_grains: int = 200, *, dim: int = 2, radius: float = 0.005, mu: float = 0.3
) -> Scene:
    """A dense crystal of equal grains touching each other and the walls (zero gaps).

    2D: hexagonal (6 neighbours, 3 contacts per disc: 6 contact unknowns
    against 3 degrees of freedom per disc). 3D: simple cubic (3 contacts per
    sphere: 9 unknowns against 6). Stresses: many more contact unknowns than
    degrees of freedom, so the impulses are not unique (``W`` singular);
    interior-point methods see a degenerate problem and first-order methods
    a flat valley. ``mu=0`` and ``mu=1.5`` give the friction extremes.
    """
    dim = _dim(dim)
    n = _count("n_grains", n_grains)
    r = _positive("radius", radius)
    d = 2.0 * r
    if dim == 2:
        cols = max(2, int(np.round(np.sqrt(n))))
        k = np.arange(n)
        row, col = k // cols, k % cols
        x = r + col * d + np.where(row % 2 == 1, r, 0.0)
        y = r + row * d * np.sqrt(3.0) / 2.0
        positions = np.stack([x, y], axis=1)
        box = (cols + 0.5) * d
    else:
        side = max(2, int(np.ceil(n ** (1.0 / 3.0))))
        k = np.arange(n)
        positions = (np.stack([k % side, (k // side) % side, k // side**2], axis=1) + 0.5) * d
        box = side * d
    return Scene(positions, r, walls=_box_walls(dim, box), mu=mu)


@checked
def wedged_grain(
    half_angle_deg: float = 10.0, *, dim: int = 2, radius: float = 0.005, mu: float = 0.3
) -> Scene:
    """One grain touching both walls of a V (a trough in 3D) whose apex is at the origin.

    Stresses: arching. Each wall pushes with ``m g / (2 sin a)`` (large for a
    narrow V); when ``mu >= tan a`` friction alone can hold the grain, a static
    indeterminate state where the normal forces are not unique.
    """
    dim = _dim(dim)
    a_deg = float(half_angle_deg)
    if not (np.isfinite(a_deg) and 0.0 < a_deg < 90.0):
        raise SceneError(f"half_angle_deg must be in (0, 90), got {half_angle_deg}")
    r = _positive("radius", radius)
    a = np.radians(a_deg)
    height = r / np.sin(a)
    normals = np.zeros((2, dim))
    normals[:, 0] = np.cos(a), -np.cos(a)
    normals[:, -1] = np.sin(a)
    centre = np.zeros((1, dim))
    centre[0, -1] = height
    walls = [Wall(np.zeros(dim), nrm) for nrm in normals]
    return Scene(centre, r, walls=walls, mu=mu)


@checked
def fast_impact(
    speed_ratio: float = 1.0,
    *,
    dt: float = 1e-3,
    dim: int = 2,
    radius: float = 0.005,
    n_targets: int = 5,
    mu: float = 0.3,
) -> Scene:
    """A grain thrown down onto a row of grains resting on the floor.

    The projectile's speed is ``speed_ratio * radius / dt``: with the same
    ``dt`` in the stepper it moves ``speed_ratio`` radii per step. It starts a
    quarter radius above its target (inside the default detection range).
    Stresses: a large, one-step velocity jump (a big ``D/dt``-free right-hand
    side) and, above ``speed_ratio`` ~ 0.5, the contact detection threshold.
    """
    dim = _dim(dim)
    ratio = _positive("speed_ratio", speed_ratio)
    dt = _positive("dt", dt)
    r = _positive("radius", radius)
    m = _count("n_targets", n_targets)
    positions = np.zeros((m + 1, dim))
    positions[:m, 0] = (np.arange(m) - (m - 1) / 2.0) * 2.0 * r
    positions[:m, -1] = r
    positions[m, 0] = positions[m // 2, 0]
    positions[m, -1] = 3.0 * r + 0.25 * r
    velocities = np.zeros((m + 1, dim))
    velocities[m, -1] = -ratio * r / dt
    return Scene(positions, r, velocities=velocities, walls=[_floor(dim)], mu=mu)


@checked
def size_ratio(
    ratio: float = 10.0,
    *,
    dim: int = 2,
    small_radius: float = 0.002,
    big_on_small: bool = True,
    mu: float = 0.3,
) -> Scene:
    """A big grain on a bed of small ones, or small grains on a big one.

    ``big_on_small``: a row (2D) or square layer (3D) of small grains touching
    on the floor and the big grain, ``ratio`` times their radius, resting on
    the central ones. Otherwise: the big grain on the floor with small grains
    touching its upper half. Stresses: contact stiffness and mass ratios of
    ``ratio ** d``; detection with a neighbour search sized by the largest
    radius; the default ``d_max`` (half the mean radius) is dominated by one size.
    """
    dim = _dim(dim)
    k = _positive("ratio", ratio)
    rs = _positive("small_radius", small_radius)
    big = k * rs
    if big_on_small:
        m = int(np.ceil(2.0 * big / (2.0 * rs))) + 1  # small grains per side of the centre
        offs = (np.arange(-m, m) + 0.5) * 2.0 * rs
        if dim == 2:
            small = np.stack([offs, np.full(offs.size, rs)], axis=1)
            lift = np.sqrt((big + rs) ** 2 - rs**2)
        else:
            gx, gy = np.meshgrid(offs, offs, indexing="ij")
            small = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, rs)], axis=1)
            lift = np.sqrt((big + rs) ** 2 - 2.0 * rs**2)
        centre = np.zeros((1, dim))
        centre[0, -1] = rs + lift
        positions = np.concatenate([small, centre])
    else:
        centre = np.zeros((1, dim))
        centre[0, -1] = big
        # Small grains on the upper cap, spaced along arcs so they do not touch.
        angles = np.radians(np.arange(-60.0, 61.0, 20.0))
        if dim == 2:
            dirs = np.stack([np.sin(angles), np.cos(angles)], axis=1)
        else:
            dirs = np.stack([np.sin(angles), np.zeros(angles.size), np.cos(angles)], axis=1)
        small = centre + (big + rs) * dirs
        step = 2.0 * (big + rs) * np.sin(np.radians(10.0))
        if step < 2.0 * rs:
            raise SceneError(f"ratio {ratio} is too small for small grains on a big one (>= 6)")
        positions = np.concatenate([centre, small])
    radii = np.full(len(positions), rs)
    radii[-1 if big_on_small else 0] = big
    return Scene(positions, radii, walls=[_floor(dim)], mu=mu)


@checked
def zero_gap(n_side: int = 6, *, dim: int = 2, mu: float = 0.3) -> Scene:
    """A square (cubic) block of equal grains touching each other and the floor, gaps exactly 0.

    The radius is 2^-7 m so that every centre is an exact binary multiple of
    it and every gap is 0.0 in floating point. Stresses: all contacts active
    and degenerate at once (``D = 0``), redundant constraints, and detection
    on the boundary of the threshold test.
    """
    dim = _dim(dim)
    m = _count("n_side", n_side)
    r = 2.0**-7
    idx = np.indices((m,) * dim).reshape(dim, -1).T
    positions = (2.0 * idx + 1.0) * r
    return Scene(positions, r, walls=[_floor(dim)], mu=mu)


#: Named hard cases for the benchmark harness: name -> builder with no arguments.
HARD_CASES: dict[str, Callable[[], Scene]] = {
    "heavy_on_light_1e3": partial(heavy_on_light, 1e3),
    "heavy_on_light_1e6": partial(heavy_on_light, 1e6),
    "heavy_on_light_1e6_3d": partial(heavy_on_light, 1e6, dim=3),
    "tall_stack_50": partial(tall_stack, 50),
    "tall_stack_50_3d": partial(tall_stack, 50, dim=3),
    "jammed_box": partial(jammed_box, 200),
    "jammed_box_3d": partial(jammed_box, 125, dim=3),
    "jammed_box_mu0": partial(jammed_box, 200, mu=0.0),
    "jammed_box_mu1.5": partial(jammed_box, 200, mu=1.5),
    "jammed_box_mu1.5_3d": partial(jammed_box, 125, dim=3, mu=1.5),
    "wedged_grain": partial(wedged_grain, 10.0),
    "wedged_grain_3d": partial(wedged_grain, 10.0, dim=3),
    "fast_impact": partial(fast_impact, 1.0),
    "fast_impact_3d": partial(fast_impact, 1.0, dim=3),
    "size_ratio_10": partial(size_ratio, 10.0),
    "size_ratio_10_3d": partial(size_ratio, 10.0, dim=3),
    "small_on_big_10": partial(size_ratio, 10.0, big_on_small=False),
    "zero_gap": partial(zero_gap, 6),
    "zero_gap_3d": partial(zero_gap, 4, dim=3),
}


# -- helpers -------------------------------------------------------------------
def _dim(dim: int) -> int:
    if dim not in (2, 3):
        raise SceneError(f"dim must be 2 or 3, got {dim!r}")
    return int(dim)


def _positive(name: str, value: float) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise SceneError(f"{name} must be a number, got {value!r}") from None
    if not (np.isfinite(v) and v > 0.0):
        raise SceneError(f"{name} must be finite and > 0, got {value}")
    return v


def _count(name: str, value: int | None) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise SceneError(f"{name} must be an integer >= 1, got {value!r}")
    check_fits(int(value) * BYTES_PER_GRAIN, f"a scene of {int(value)} grains ({name})")
    return int(value)


def _derived_count(count: float, diameter: float) -> int:
    """The grain count a diameter implies, checked like a given one."""
    if not np.isfinite(count) or count > 1e15:
        raise SceneError(f"diameter {diameter:g} m gives {count:.3g} grains: far too many")
    return _count(f"grains for diameter {diameter:g} m", max(1, round(count)))


def _polydispersity(value: float) -> float:
    if not (np.isfinite(value) and 0.0 <= value < 1.0):
        raise SceneError(f"polydispersity must be in [0, 1), got {value}")
    return float(value)


def _radii(n: int, d_mean: float, poly: float, rng: np.random.Generator) -> FloatArray:
    """Radii uniform in ``r (1 -+ poly / 2)``, rescaled so their mean is exactly ``d_mean / 2``."""
    u = 1.0 + poly * (rng.random(n) - 0.5)
    return np.asarray(0.5 * d_mean * u / u.mean(), dtype=np.float64)


def _grain_volume(dim: int, d_mean: float, poly: float) -> float:
    """Mean grain area (2D) or volume (3D) for radii uniform in ``r (1 -+ poly / 2)``."""
    r = d_mean / 2.0
    if dim == 2:
        return float(np.pi * r**2 * (1.0 + poly**2 / 12.0))
    return float(4.0 / 3.0 * np.pi * r**3 * (1.0 + poly**2 / 4.0))


def _one_of(n_grains: int | None, diameter: float | None) -> None:
    if (n_grains is None) == (diameter is None):
        raise SceneError(
            f"give exactly one of n_grains and diameter, got n_grains={n_grains!r}, "
            f"diameter={diameter!r}"
        )


def _lattice_size(
    dim: int, n_grains: int | None, diameter: float | None, volume: float, poly: float
) -> tuple[int, float]:
    """Grain count and mean diameter of a loose lattice filling ``volume``."""
    _one_of(n_grains, diameter)
    cell = np.sqrt(3.0) / 2.0 if dim == 2 else 1.0  # site volume / spacing^d
    ratio = 1.02 * (1.0 + poly / 2.0)  # spacing / mean diameter
    if n_grains is not None:
        n = _count("n_grains", n_grains)
        spacing = (volume / (n * cell)) ** (1.0 / dim)
        return n, float(spacing / ratio)
    d = _positive("diameter", diameter)  # type: ignore[arg-type]
    with np.errstate(divide="ignore", over="ignore"):
        n = _derived_count(volume / (cell * (ratio * d) ** dim), d)
    return n, d


def _rain_size(
    dim: int, n_grains: int | None, diameter: float | None, volume: float, poly: float
) -> tuple[int, float]:
    """Grain count and mean diameter of a settled rain packing filling ``volume``."""
    _one_of(n_grains, diameter)
    unit = _grain_volume(dim, 1.0, poly)  # grain volume for a unit mean diameter
    if n_grains is not None:
        n = _count("n_grains", n_grains)
        return n, float((RAIN_FRACTION[dim] * volume / (n * unit)) ** (1.0 / dim))
    d = _positive("diameter", diameter)  # type: ignore[arg-type]
    with np.errstate(divide="ignore", over="ignore"):
        return _derived_count(RAIN_FRACTION[dim] * volume / (unit * d**dim), d), d


def _lattice(
    dim: int,
    n: int | None,
    horizontal: FloatArray,
    base: float,
    spacing: float,
    thickness: float | None,
    rng: np.random.Generator,
) -> FloatArray:
    """Sites of a lattice over ``[0, horizontal]`` from height ``base``, shape ``(n, dim)``.

    Hexagonal rows in 2D, cubic in 3D. Either ``n`` sites (rows filled in
    turn) or every site whose grain lies within ``thickness`` of ``base``.
    """
    del rng  # the lattice is regular; kept for a uniform signature
    row_h = spacing * (np.sqrt(3.0) / 2.0 if dim == 2 else 1.0)
    counts = [max(1, int(np.floor(h / spacing))) for h in horizontal]
    if dim == 2:
        counts[0] = max(1, int(np.floor(horizontal[0] / spacing - 0.5)))
    per_row = int(np.prod(counts))
    if n is None:
        assert thickness is not None
        rows = max(1, int(np.floor((thickness - spacing) / row_h)) + 1)
        n = rows * per_row
    k = np.arange(n)
    row = k // per_row
    within = k % per_row
    coords = []
    for c in counts:
        coords.append((within % c + 0.5) * spacing)
        within = within // c
    if dim == 2:
        coords[0] = coords[0] + np.where(row % 2 == 1, spacing / 2.0, 0.0)
    coords.append(base + spacing / 2.0 + row * row_h)
    return np.stack(coords, axis=1)


def _loose_lattice(
    dim: int, n: int, horizontal: FloatArray, base: float, r_max: float, rng: np.random.Generator
) -> FloatArray:
    """``n`` sites of a square/cubic lattice 10 % looser than the largest grain, jittered.

    The jitter is small enough that no two grains (or grain and wall) can
    touch; it breaks the lattice's symmetry so that the rain packs randomly.
    """
    spacing = 2.2 * r_max
    counts = [max(1, int(np.floor(h / spacing))) for h in horizontal]
    per_layer = int(np.prod(counts))
    k = np.arange(n)
    layer, within = k // per_layer, k % per_layer
    coords = []
    for c in counts:
        coords.append((within % c + 0.5) * spacing)
        within = within // c
    coords.append(base + (layer + 0.5) * spacing)
    x = np.stack(coords, axis=1)
    amplitude = 0.45 * (spacing - 2.0 * r_max) / (2.0 * np.sqrt(dim))
    return np.asarray(x + rng.uniform(-amplitude, amplitude, x.shape), dtype=np.float64)


def _bed_grains(dim: int, d: float, bed_len: float, chan: float) -> FloatArray:
    """Centres of touching grains of diameter ``d`` on the floor over the bed."""
    xs = (np.arange(max(1, int(np.floor(bed_len / d)))) + 0.5) * d
    if dim == 2:
        return np.stack([xs, np.full(xs.size, d / 2.0)], axis=1)
    ys = (np.arange(max(1, int(np.floor(chan / d)))) + 0.5) * d
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    return np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, d / 2.0)], axis=1)


def _deposit(
    parts_x: list[FloatArray],
    parts_r: list[FloatArray],
    n_fixed: int,
    walls: list[Wall],
    scene_kw: dict[str, float | None],
    mu_prep: float,
    solver: str | None,
    cache: bool,
) -> FloatArray:
    """Settle the grains (the first ``n_fixed`` glued) under vertical gravity; new positions."""
    x = np.concatenate(parts_x)
    r = np.concatenate(parts_r)
    fixed = np.zeros(len(r), dtype=bool)
    fixed[:n_fixed] = True
    scene = Scene(x, r, fixed=fixed, walls=walls, **scene_kw)  # type: ignore[arg-type]
    if solver is None:
        solver = "clarabel" if scene.dim == 2 else "scs-dual"
    result = rain_deposition(scene, mu_prep=mu_prep, solver=solver, cache=cache)
    return result.scene.positions


def _box_walls(dim: int, box: float) -> list[Wall]:
    """A floor and side walls at 0 and ``box`` along every horizontal axis."""
    walls = [_floor(dim)]
    for axis in range(dim - 1):
        e = np.eye(dim)[axis]
        walls += [Wall(np.zeros(dim), e), Wall(box * e, -e)]
    return walls


def _floor(dim: int) -> Wall:
    up = np.zeros(dim)
    up[-1] = 1.0
    return Wall(np.zeros(dim), up)


def _set_groups(scene: Scene, groups: dict[str, slice]) -> None:
    scene.groups = dict(groups)
