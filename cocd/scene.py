"""Scenes: discs (2D) or spheres (3D), fixed grains, planar walls, materials, gravity.

A :class:`Scene` is the state of a simulation: the stepper advances it in place.
Everything else in cocd (contact detection, the conic problem, measurements) is a
pure function of a scene.

Units are SI. In 2D a disc's mass is its area times the density (mass per unit
depth), as in 2D contact-dynamics codes.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cocd.checks import (
    broadcast_array,
    float_array,
    friction_coefficient,
    require_finite,
    shaped_array,
)
from cocd.errors import OverlapError, SceneError

__all__ = ["DEFAULT_OVERLAP_TOL", "Scene", "Wall"]

#: Largest overlap allowed between two grains (or a grain and a wall) when a
#: simulation starts, relative to the smaller radius.
DEFAULT_OVERLAP_TOL = 1e-6

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Wall:
    """An infinite fixed plane (a line in 2D).

    Parameters
    ----------
    point : (d,) array
        Any point of the plane.
    normal : (d,) array
        Normal pointing towards the side where grains live; normalised on creation.
    mu : float, optional
        Grain-wall friction coefficient of this wall; ``None`` takes the scene's
        ``mu_wall``.
    """

    point: FloatArray
    normal: FloatArray
    mu: float | None = None

    def __init__(self, point: ArrayLike, normal: ArrayLike, mu: float | None = None) -> None:
        p = float_array(point, "wall point").reshape(-1)
        n = float_array(normal, "wall normal").reshape(-1)
        if p.shape != n.shape or p.size not in (2, 3):
            raise SceneError(
                f"wall point {p.tolist()} and normal {n.tolist()} must both have 2 or 3 coordinates"
            )
        if not (np.all(np.isfinite(p)) and np.all(np.isfinite(n))):
            raise SceneError(f"wall point {p.tolist()} or normal {n.tolist()} is not finite")
        length = float(np.linalg.norm(n))
        if length == 0.0:
            raise SceneError("wall normal is the zero vector")
        if mu is not None:
            mu = friction_coefficient(mu, "wall friction coefficient")
        object.__setattr__(self, "point", p)
        object.__setattr__(self, "normal", n / length)
        object.__setattr__(self, "mu", None if mu is None else float(mu))

    @property
    def dim(self) -> int:
        return int(self.point.size)

    def gaps(self, positions: FloatArray, radii: FloatArray) -> FloatArray:
        """Signed distance of each grain's surface to the plane, shape ``(n,)``."""
        return np.asarray((positions - self.point) @ self.normal - radii, dtype=np.float64)


class Scene:
    """Grains, walls, materials and gravity; the state the stepper advances.

    Parameters
    ----------
    positions : (n, d) array
        Centres, d = 2 (discs) or 3 (spheres).
    radii : (n,) array or float
        Radii, all > 0.
    density : float or (n,) array
        Density in kg/m^3 (default 2500, glass). In 2D, mass = density x area.
    velocities : (n, d) array, optional
        Translational velocities (default 0).
    angular_velocities : (n,) array in 2D, (n, 3) in 3D, optional
        Rotational velocities (default 0).
    fixed : (n,) bool array, optional
        Glued grains: they never move and carry no unknowns.
    walls : iterable of Wall
        Fixed planes.
    gravity : (d,) array, optional
        Gravity vector; default ``-9.81`` along the last axis. A slope is a
        tilted gravity.
    mu : float
        Grain-grain (and grain-fixed-grain) friction coefficient.
    mu_wall : float, optional
        Grain-wall friction coefficient of walls that do not set their own;
        default ``mu``.
    """

    def __init__(
        self,
        positions: ArrayLike,
        radii: ArrayLike | float,
        *,
        density: ArrayLike | float = 2500.0,
        velocities: ArrayLike | None = None,
        angular_velocities: ArrayLike | None = None,
        fixed: ArrayLike | None = None,
        walls: Iterable[Wall] = (),
        gravity: ArrayLike | None = None,
        mu: float = 0.3,
        mu_wall: float | None = None,
    ) -> None:
        x = float_array(positions, "positions")
        if x.ndim != 2 or x.shape[1] not in (2, 3):
            raise SceneError(
                f"positions must have shape (n, 2) or (n, 3), got {np.shape(positions)}"
            )
        n, d = x.shape
        if n == 0:
            raise SceneError("a scene needs at least one grain")
        require_finite(x, "positions")
        self.positions: FloatArray = x

        r = broadcast_array(radii, n, "radii")
        require_finite(r, "radii")
        bad = np.flatnonzero(r <= 0.0)
        if bad.size:
            raise SceneError(
                f"radius of grain {bad[0]} is {r[bad[0]]:g}: radii must be > 0 "
                f"({bad.size} non-positive)"
            )
        self.radii: FloatArray = r

        rho = broadcast_array(density, n, "density")
        require_finite(rho, "density")
        bad = np.flatnonzero(rho <= 0.0)
        if bad.size:
            raise SceneError(f"density of grain {bad[0]} is {rho[bad[0]]:g}: must be > 0")
        self.density: FloatArray = rho

        self.velocities: FloatArray = (
            np.zeros((n, d))
            if velocities is None
            else shaped_array(velocities, (n, d), "velocities")
        )
        rot_shape: tuple[int, ...] = (n,) if d == 2 else (n, 3)
        self.angular_velocities: FloatArray = (
            np.zeros(rot_shape)
            if angular_velocities is None
            else shaped_array(angular_velocities, rot_shape, "angular_velocities")
        )

        if fixed is None:
            self.fixed = np.zeros(n, dtype=bool)
        else:
            f = np.asarray(fixed)
            if f.shape != (n,) or f.dtype != bool:
                raise SceneError(f"fixed must be a boolean array of shape ({n},), got {f.shape}")
            self.fixed = f.copy()
        # Glued grains never move.
        self.velocities[self.fixed] = 0.0
        self.angular_velocities[self.fixed] = 0.0

        self.walls: tuple[Wall, ...] = tuple(walls)
        for k, wall in enumerate(self.walls):
            if not isinstance(wall, Wall):
                raise SceneError(f"walls[{k}] is a {type(wall).__name__}, not a Wall")
            if wall.dim != d:
                raise SceneError(f"walls[{k}] is {wall.dim}D but the grains are {d}D")

        g = np.zeros(d) if gravity is None else float_array(gravity, "gravity").reshape(-1)
        if gravity is None:
            g[-1] = -9.81
        if g.shape != (d,):
            raise SceneError(f"gravity must have {d} components, got {g.size}")
        require_finite(g, "gravity")
        self.gravity: FloatArray = g

        self.mu = friction_coefficient(mu, "mu")
        self.mu_wall = self.mu if mu_wall is None else friction_coefficient(mu_wall, "mu_wall")
        self.time = 0.0
        #: Named index ranges of grains set by builders (e.g. bed, layer, column).
        self.groups: dict[str, slice] = {"all": slice(0, n)}

    # -- derived quantities -------------------------------------------------
    @property
    def dim(self) -> int:
        return int(self.positions.shape[1])

    @property
    def n_grains(self) -> int:
        return int(self.positions.shape[0])

    @property
    def free(self) -> NDArray[np.bool_]:
        """Mask of the grains that move."""
        return ~self.fixed

    @property
    def n_free(self) -> int:
        return int(np.count_nonzero(~self.fixed))

    @property
    def masses(self) -> FloatArray:
        """Masses, shape ``(n,)`` (kg, or kg/m in 2D)."""
        if self.dim == 2:
            return np.asarray(self.density * np.pi * self.radii**2)
        return np.asarray(self.density * (4.0 / 3.0) * np.pi * self.radii**3)

    @property
    def inertia(self) -> FloatArray:
        """Moments of inertia about the centre: disc m r^2 / 2, sphere 2 m r^2 / 5."""
        factor = 0.5 if self.dim == 2 else 0.4
        return np.asarray(factor * self.masses * self.radii**2)

    def wall_friction(self, k: int) -> float:
        """Friction coefficient between grains and wall ``k``."""
        mu = self.walls[k].mu
        return self.mu_wall if mu is None else mu

    @property
    def frictionless(self) -> bool:
        """True when no contact can carry a tangential force."""
        return self.mu == 0.0 and all(self.wall_friction(k) == 0.0 for k in range(len(self.walls)))

    def copy(self) -> Scene:
        """An independent copy (arrays copied, walls shared: they are immutable)."""
        other = Scene.__new__(Scene)
        other.__dict__.update(
            {
                k: (v.copy() if isinstance(v, np.ndarray | dict) else v)
                for k, v in self.__dict__.items()
            }
        )
        return other

    def check_overlaps(self, tol: float = DEFAULT_OVERLAP_TOL) -> None:
        """Raise :class:`OverlapError` if grains overlap by more than ``tol`` x radius.

        Grain pairs are compared with the smaller of their radii; a grain and a
        wall with the grain's radius. Pairs of fixed grains are not checked.
        """
        from scipy.spatial import KDTree

        x, r = self.positions, self.radii
        if self.n_grains > 1:
            pairs = KDTree(x).query_pairs(2.0 * float(r.max()), output_type="ndarray")
            if pairs.size:
                i, j = pairs[:, 0], pairs[:, 1]
                keep = ~(self.fixed[i] & self.fixed[j])
                i, j = i[keep], j[keep]
                depth = r[i] + r[j] - np.linalg.norm(x[i] - x[j], axis=1)
                rel = depth / np.minimum(r[i], r[j])
                if rel.size and rel.max() > tol:
                    a = int(np.argmax(rel))
                    raise OverlapError(
                        f"grains {i[a]} and {j[a]} overlap by {depth[a]:.3g} m "
                        f"({rel[a]:.3g} of the smaller radius; allowed {tol:g}); "
                        f"{int(np.count_nonzero(rel > tol))} pairs overlap"
                    )
        for k, wall in enumerate(self.walls):
            rel = -wall.gaps(x, r) / r
            rel[self.fixed] = -np.inf
            if rel.max() > tol:
                a = int(np.argmax(rel))
                raise OverlapError(
                    f"grain {a} penetrates wall {k} by {rel[a] * r[a]:.3g} m "
                    f"({rel[a]:.3g} of its radius; allowed {tol:g})"
                )

    def __repr__(self) -> str:
        return (
            f"Scene(dim={self.dim}, n_grains={self.n_grains}, n_fixed="
            f"{int(self.fixed.sum())}, walls={len(self.walls)}, mu={self.mu:g}, "
            f"mu_wall={self.mu_wall:g}, t={self.time:g})"
        )
