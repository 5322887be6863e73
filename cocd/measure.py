"""Measurements: pure functions of a scene's state."""

from __future__ import annotations

import numpy as np

from cocd.scene import Scene

__all__ = ["kinetic_energy", "potential_energy"]


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
