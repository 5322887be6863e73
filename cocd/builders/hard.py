"""The hard cases: small scenes that stress a solver (mass ratios, jamming, impacts, ...)."""

from __future__ import annotations

from collections.abc import Callable
from functools import partial

import numpy as np

from cocd.builders._common import box_walls, check_count, check_dim, floor_wall
from cocd.builders.columns import stack
from cocd.checks import checked, positive_number
from cocd.errors import SceneError
from cocd.scene import Scene, Wall

__all__ = [
    "HARD_CASES",
    "fast_impact",
    "heavy_on_light",
    "jammed_box",
    "size_ratio",
    "tall_stack",
    "wedged_grain",
    "zero_gap",
]


@checked
def heavy_on_light(mass_ratio: float = 1e3, *, dim: int = 2, radius: float = 0.005) -> Scene:
    """A heavy grain resting on light grains of the same size (mass ratio by density).

    Stresses: conditioning. The inverse-mass-weighted Delassus operator ``W``
    mixes entries a ratio ``mass_ratio`` apart; first-order methods (pgs, apgd)
    converge at a rate set by that ratio, interior-point methods lose digits.

    Light grains touch the floor and each other (zero gaps): two in 2D, three
    in a triangle in 3D; the heavy grain sits in their hollow, touching them.
    """
    dim = check_dim(dim)
    ratio = positive_number(mass_ratio, "mass_ratio")
    r = positive_number(radius, "radius")
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
    return Scene(positions, r, density=density, walls=[floor_wall(dim)])


@checked
def tall_stack(n: int = 50, *, dim: int = 2, radius: float = 0.005, mu: float = 0.3) -> Scene:
    """A vertical stack of ``n`` touching grains on the floor.

    Stresses: a long chain of contacts whose forces grow linearly to ``n m g``
    at the bottom; propagating the load through the chain takes first-order
    methods about ``n`` iterations per digit, and the stack is only
    neutrally stable (any tangential error makes it buckle).
    """
    return stack(
        check_count("n", n), radius=positive_number(radius, "radius"), dim=check_dim(dim), mu=mu
    )


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
    dim = check_dim(dim)
    n = check_count("n_grains", n_grains)
    r = positive_number(radius, "radius")
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
    return Scene(positions, r, walls=box_walls(dim, box), mu=mu)


@checked
def wedged_grain(
    half_angle_deg: float = 10.0, *, dim: int = 2, radius: float = 0.005, mu: float = 0.3
) -> Scene:
    """One grain touching both walls of a V (a trough in 3D) whose apex is at the origin.

    Stresses: arching. Each wall pushes with ``m g / (2 sin a)`` (large for a
    narrow V); when ``mu >= tan a`` friction alone can hold the grain, a static
    indeterminate state where the normal forces are not unique.
    """
    dim = check_dim(dim)
    a_deg = float(half_angle_deg)
    if not (np.isfinite(a_deg) and 0.0 < a_deg < 90.0):
        raise SceneError(f"half_angle_deg must be in (0, 90), got {half_angle_deg}")
    r = positive_number(radius, "radius")
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
    dim = check_dim(dim)
    ratio = positive_number(speed_ratio, "speed_ratio")
    dt = positive_number(dt, "dt")
    r = positive_number(radius, "radius")
    m = check_count("n_targets", n_targets)
    positions = np.zeros((m + 1, dim))
    positions[:m, 0] = (np.arange(m) - (m - 1) / 2.0) * 2.0 * r
    positions[:m, -1] = r
    positions[m, 0] = positions[m // 2, 0]
    positions[m, -1] = 3.0 * r + 0.25 * r
    velocities = np.zeros((m + 1, dim))
    velocities[m, -1] = -ratio * r / dt
    return Scene(positions, r, velocities=velocities, walls=[floor_wall(dim)], mu=mu)


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
    dim = check_dim(dim)
    k = positive_number(ratio, "ratio")
    rs = positive_number(small_radius, "small_radius")
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
    return Scene(positions, radii, walls=[floor_wall(dim)], mu=mu)


@checked
def zero_gap(n_side: int = 6, *, dim: int = 2, mu: float = 0.3) -> Scene:
    """A square (cubic) block of equal grains touching each other and the floor, gaps exactly 0.

    The radius is 2^-7 m so that every centre is an exact binary multiple of
    it and every gap is 0.0 in floating point. Stresses: all contacts active
    and degenerate at once (``D = 0``), redundant constraints, and detection
    on the boundary of the threshold test.
    """
    dim = check_dim(dim)
    m = check_count("n_side", n_side)
    r = 2.0**-7
    idx = np.indices((m,) * dim).reshape(dim, -1).T
    positions = (2.0 * idx + 1.0) * r
    return Scene(positions, r, walls=[floor_wall(dim)], mu=mu)


#: Named hard cases for the benchmark harness: name -> builder with no arguments.
HARD_CASES: dict[str, Callable[[], Scene]] = {}


def _register(name: str, case: partial[Scene], *, in_3d: dict[str, object] | None = None) -> None:
    """Add ``case`` as ``name``; with ``in_3d`` (the arguments that change, maybe none),
    add it with ``dim=3`` as ``name_3d`` too."""
    HARD_CASES[name] = case
    if in_3d is not None:
        HARD_CASES[f"{name}_3d"] = partial(case, **{**in_3d, "dim": 3})


_register("heavy_on_light_1e3", partial(heavy_on_light, 1e3))
_register("heavy_on_light_1e6", partial(heavy_on_light, 1e6), in_3d={})
_register("tall_stack_50", partial(tall_stack, 50), in_3d={})
_register("jammed_box", partial(jammed_box, n_grains=200), in_3d={"n_grains": 125})
_register("jammed_box_mu0", partial(jammed_box, n_grains=200, mu=0.0))
_register("jammed_box_mu1.5", partial(jammed_box, n_grains=200, mu=1.5), in_3d={"n_grains": 125})
_register("wedged_grain", partial(wedged_grain, 10.0), in_3d={})
_register("fast_impact", partial(fast_impact, 1.0), in_3d={})
_register("size_ratio_10", partial(size_ratio, 10.0), in_3d={})
_register("small_on_big_10", partial(size_ratio, 10.0, big_on_small=False))
_register("zero_gap", partial(zero_gap, n_side=6), in_3d={"n_side": 4})
