"""Columns, stacks and boxes: the scenes of the seed papers' collapses and packings."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from cocd.builders._common import (
    RAIN_FRACTION,
    FloatArray,
    G,
    bed_grains,
    box_walls,
    check_count,
    check_dim,
    check_polydispersity,
    deposit,
    lattice_sites,
    lattice_size,
    loose_lattice,
    mean_grain_volume,
    radii_up_to,
    rain_size,
    set_groups,
    uniform_radii,
)
from cocd.checks import checked, friction_coefficient, nonnegative_number, positive_number
from cocd.errors import SceneError
from cocd.scene import Scene, Wall

__all__ = [
    "box_3d",
    "column_2d",
    "column_collapse",
    "grain_groups",
    "stack",
    "static_box",
]


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
    n_grains = check_count("n_grains", n_grains)
    if not (width > 0 and aspect > 0):
        raise SceneError(f"width and aspect must be > 0, got {width} and {aspect}")
    polydispersity = check_polydispersity(polydispersity)
    n = int(n_grains)
    spacing = width * np.sqrt(2.0 * aspect / (np.sqrt(3.0) * n))
    cols = max(1, int(np.floor(width / spacing)))
    r_max = spacing / (2.0 * 1.02)
    radii = radii_up_to(r_max, polydispersity, n, np.random.default_rng(seed))

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
    n_grains = check_count("n_grains", n_grains)
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
    n_grains = check_count("n_grains", n_grains)
    if not diameter > 0:
        raise SceneError(f"diameter must be > 0, got {diameter}")
    polydispersity = check_polydispersity(polydispersity)
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
    radii = radii_up_to(diameter / 2.0, polydispersity, n, np.random.default_rng(seed))
    walls = [
        Wall((0.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
        Wall((0.0, 0.0, 0.0), (1.0, 0.0, 0.0)),
        Wall((0.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
        Wall((box, 0.0, 0.0), (-1.0, 0.0, 0.0)),
        Wall((0.0, box, 0.0), (0.0, -1.0, 0.0)),
    ]
    return Scene(positions, radii, density=density, walls=walls, mu=mu, mu_wall=mu_wall)


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
    mu_side: float | None = None,
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
    mu_side : float, optional
        3D only: friction of the two lateral walls, e.g. 0 for a wide channel
        (frictionless sidewalls) or a measured grain-wall coefficient for a
        narrow one; default ``mu_wall``.
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
        ``scs-dual`` in 3D.
    cache : bool
        Use the packing cache for rain deposition.

    Returns
    -------
    Scene
    """
    dim = check_dim(dim)
    length = positive_number(length, "length")
    height = positive_number(height, "height")
    if dim == 2 and width is not None:
        raise SceneError("width is the 3D channel width; leave it None in 2D")
    mu_side = _check_mu_side(dim, mu_side)
    chan = positive_number(0.20 if width is None else width, "width")
    if not (np.isfinite(slope_deg) and -90.0 < slope_deg < 90.0):
        raise SceneError(f"slope_deg must be in (-90, 90), got {slope_deg}")
    poly = check_polydispersity(polydispersity)
    density = positive_number(density, "density")
    if bed not in ("smooth", "rough"):
        raise SceneError(f"bed must be 'smooth' or 'rough', got {bed!r}")
    if packing not in ("lattice", "rain"):
        raise SceneError(f"packing must be 'lattice' or 'rain', got {packing!r}")
    nonnegative_number(erodible_thickness, "erodible_thickness")
    bed_len = 4.0 * length if bed_length is None else positive_number(bed_length, "bed_length")
    if bed_len < length:
        raise SceneError(f"bed_length {bed_len} is shorter than the column length {length}")

    cross = np.array([length, chan]) if dim == 3 else np.array([length])
    volume = float(np.prod(cross)) * height
    if packing == "lattice":
        n, d_mean = lattice_size(dim, n_grains, diameter, volume, poly)
    else:
        n, d_mean = rain_size(dim, n_grains, diameter, volume, poly)
    sides = {"length": length, "height": height, **({"width": chan} if dim == 3 else {})}
    for what, size in sides.items():
        if size < d_mean:
            raise SceneError(
                f"{what} {size:g} m is less than a grain of the column ({d_mean:.3g} m)"
            )
    rng = np.random.default_rng(seed)
    radii = uniform_radii(n, d_mean, poly, rng)
    r_max = float(radii.max())

    # Bed: fixed grains of the mean diameter, touching, on the floor.
    parts_x: list[FloatArray] = []
    parts_r: list[FloatArray] = []
    groups: dict[str, slice] = {}
    base = 0.0
    if bed == "rough":
        bed_x = bed_grains(dim, d_mean, bed_len, chan)
        parts_x.append(bed_x)
        parts_r.append(np.full(len(bed_x), d_mean / 2.0))
        base = d_mean
    n_bed = sum(len(p) for p in parts_x)
    groups["bed"] = slice(0, n_bed)

    up = np.zeros(dim)
    up[-1] = 1.0
    walls = [Wall(np.zeros(dim), up), Wall(np.zeros(dim), np.eye(dim)[0])]
    if dim == 3:
        # Frictionless sidewalls or not, rain packings are deposited alike (mu_prep):
        # mu_side is set on the finished scene's walls.
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
            layer_x = lattice_sites(dim, None, horizontal, base, spacing, erodible_thickness, rng)
            layer_r = uniform_radii(len(layer_x), d_mean, poly, rng)
        else:
            layer_n = max(
                1, round(RAIN_FRACTION[dim] * layer_volume / mean_grain_volume(dim, d_mean, poly))
            )
            layer_r = uniform_radii(layer_n, d_mean, poly, rng)
            layer_x = loose_lattice(dim, layer_n, horizontal, base, float(layer_r.max()), rng)
            settled = deposit(
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
        column_x = lattice_sites(dim, n, cross, base, spacing, None, rng)
        parts_x.append(column_x)
        parts_r.append(radii)
    else:
        column_x = loose_lattice(dim, n, cross, base, r_max, rng)
        parts_x.append(column_x)
        parts_r.append(radii)
        # The layer is held still while the column rains onto it: the gate plane
        # would cut through the layer in front of the column.
        settled = deposit(
            parts_x, parts_r, n_below, [*walls, gate], scene_kw, mu_prep, solver, cache
        )
        parts_x = [settled]
        parts_r = [np.concatenate(parts_r)]
    groups["column"] = slice(n_below, n_below + n)

    positions = np.concatenate(parts_x)
    all_r = np.concatenate(parts_r)
    fixed = np.zeros(len(all_r), dtype=bool)
    fixed[groups["bed"]] = True
    walls = _side_friction(walls, mu_side)
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
    set_groups(scene, groups)
    return scene


@checked
def static_box(
    dim: int = 3,
    *,
    n_grains: int,
    diameter: float = 0.005,
    width: float | None = None,
    length: float | None = None,
    polydispersity: float = 0.1,
    density: float = 2500.0,
    mu: float = 0.3,
    mu_wall: float | None = None,
    mu_prep: float = 0.0,
    mu_side: float | None = None,
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
    length : float, optional
        3D only: the box's inner length along x, ``width`` being along y; default
        ``width`` (a square box).
    polydispersity, density, mu, mu_wall : float
        As in :func:`column_collapse`.
    mu_prep : float
        Friction during deposition (0: compact, > 0: loose); ``mu`` is set after.
    mu_side : float, optional
        3D only: the friction of the two walls normal to y (a channel's sidewalls),
        set after deposition as in :func:`column_collapse`; default ``mu_wall``.
    seed : int
    solver : str, optional
        Backend of the deposition; default as in :func:`column_collapse`.
    cache : bool
        Use the packing cache.

    Returns
    -------
    Scene
        Velocities zero, floor at the last coordinate 0, side walls at 0 and
        ``length`` (x) and ``width`` (y); no lid.
    """
    dim = check_dim(dim)
    n = check_count("n_grains", n_grains)
    d_mean = positive_number(diameter, "diameter")
    poly = check_polydispersity(polydispersity)
    if width is None:
        side = max(4.0, np.ceil((n / RAIN_FRACTION[dim]) ** (1.0 / dim)))
        width = float(side * d_mean * (np.pi / 6.0 if dim == 3 else np.pi / 4.0) ** (1.0 / dim))
        width = max(width, 4.0 * d_mean)
    box = positive_number(width, "width")
    if length is not None and dim == 2:
        raise SceneError("length is for a 3D box (in 2D the box is width long)")
    horizontal = np.array([box] if dim == 2 else [box if length is None else length, box])
    horizontal[0] = positive_number(float(horizontal[0]), "length")
    mu_side = _check_mu_side(dim, mu_side)
    rng = np.random.default_rng(seed)
    radii = uniform_radii(n, d_mean, poly, rng)
    if horizontal.min() < 2.2 * float(radii.max()):
        raise SceneError(
            f"the box ({' x '.join(f'{b:g}' for b in horizontal)}) is too small for grains "
            f"of diameter {2 * radii.max():.3g}"
        )
    positions = loose_lattice(dim, n, horizontal, 0.0, float(radii.max()), rng)
    walls = box_walls(dim, horizontal)
    scene_kw = dict(density=density, mu=mu, mu_wall=mu_wall)
    settled = deposit([positions], [radii], 0, walls, scene_kw, mu_prep, solver, cache)
    walls = _side_friction(walls, mu_side)
    return Scene(settled, radii, walls=walls, **scene_kw)  # type: ignore[arg-type]


def _check_mu_side(dim: int, mu_side: float | None) -> float | None:
    if mu_side is None:
        return None
    if dim != 3:
        raise SceneError("mu_side is the 3D sidewalls' friction; leave it None in 2D")
    return friction_coefficient(mu_side, "mu_side")


def _side_friction(walls: Sequence[Wall], mu_side: float | None) -> list[Wall]:
    """``walls`` with friction ``mu_side`` on those whose normal is along y.

    In 3D these are a channel's two sidewalls (callers check the dimension: in 2D the
    floor's normal is along y); ``None`` leaves every wall as it is.
    """
    if mu_side is None:
        return list(walls)
    return [Wall(w.point, w.normal, mu=mu_side) if abs(w.normal[1]) > 0.5 else w for w in walls]


def grain_groups(scene: Scene) -> dict[str, slice]:
    """Index ranges of the grain groups a builder made (e.g. bed, layer, column).

    Scenes not made by :func:`column_collapse` have one group, ``"all"``.
    """
    return dict(scene.groups)
