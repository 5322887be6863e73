"""Kinetic and potential energy, and the erodible bed's energy ratio."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from cocd.checks import bool_mask, finite_scalar
from cocd.errors import SceneError
from cocd.scene import Scene

__all__ = ["bed_energy_ratio", "kinetic_energy", "potential_energy"]


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
    bed = bool_mask(bed_mask, scene.n_grains, "bed_mask") & scene.free
    if not bed.any():
        raise SceneError("bed_mask selects no free grain")
    z0 = finite_scalar(reference_height, "reference_height")
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
