"""Scene builders: deterministic for a given seed."""

from __future__ import annotations

import numpy as np

from cocd.errors import SceneError
from cocd.scene import Scene, Wall

__all__ = ["box_3d", "column_2d", "stack"]


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
    if int(n_grains) < 1:
        raise SceneError(f"n_grains must be >= 1, got {n_grains}")
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
    if int(n_grains) < 1:
        raise SceneError(f"n_grains must be >= 1, got {n_grains}")
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
    if int(n_grains) < 1:
        raise SceneError(f"n_grains must be >= 1, got {n_grains}")
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
