"""Coupling with other solvers: external loads per grain, contact impulses per grain.

A fluid solver (or any other model) coupled to cocd, as a DEM is coupled to a
particle finite-element fluid, exchanges two things with it each step:

- it supplies **external loads**: a force on each grain (drag, buoyancy,
  pressure gradient, ...) and, optionally, a torque. The
  :class:`~cocd.stepper.Stepper` takes them as ``external=``: a fixed
  :class:`Loads` (or a force array), or a callable ``f(scene, t)`` called at
  the start of every step with the scene as it is then and the time at the
  step's start, returning a :class:`Loads`, a force array or a
  ``(forces, torques)`` pair. The loads enter the free velocity of the step,
  ``U = v + dt M^-1 (m g + F)`` (and ``I^-1 tau`` for the rotations): an
  explicit (forward Euler) treatment, as in the contact dynamics codes that
  are coupled this way. A load that depends on the velocity, such as a drag
  ``-gamma v``, is then stable for ``dt gamma / m < 2``.
- it reads the **contact impulses per grain** of the last step:
  :meth:`~cocd.stepper.Stepper.contact_impulses` sums each grain's contact
  impulses (N s; divide by ``dt`` for a mean force) and their moments about its
  centre.

Forces are in N (N/m in 2D, per metre of depth, as the masses are), torques in
N m; arrays cover every grain of the scene, fixed grains included (their loads
are ignored). In 2D a torque is a scalar per grain, in 3D a vector.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeAlias

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cocd.errors import ProblemError

if TYPE_CHECKING:
    from cocd.problem import ConicProblem
    from cocd.scene import Scene

__all__ = ["Loads", "grain_impulses", "resolve_loads"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Loads:
    """External force and torque on every grain for one step.

    ``forces``: shape ``(n, d)``; ``torques``: ``(n,)`` in 2D, ``(n, 3)`` in
    3D. Either may be None (no load).
    """

    forces: ArrayLike | None = None
    torques: ArrayLike | None = None


if TYPE_CHECKING:
    #: What ``Stepper(external=...)`` accepts.
    ExternalLoads: TypeAlias = (
        Loads
        | ArrayLike
        | tuple[ArrayLike | None, ArrayLike | None]
        | Callable[[Scene, float], Any]
    )


def resolve_loads(
    value: Any, scene: Scene, where: str = "external loads"
) -> tuple[FloatArray | None, FloatArray | None]:
    """Checked ``(forces, torques)`` arrays of ``value`` for ``scene`` (None: no load).

    ``value``: a :class:`Loads`, a force array, or a ``(forces, torques)`` pair.
    Raises :class:`ProblemError` naming ``where`` for a wrong shape, a
    non-numeric or a non-finite entry.
    """
    if value is None:
        return None, None
    if isinstance(value, Loads):
        forces, torques = value.forces, value.torques
    elif isinstance(value, tuple) and len(value) == 2:
        forces, torques = value
    else:
        forces, torques = value, None
    n, d = scene.n_grains, scene.dim
    rot = (n,) if d == 2 else (n, 3)
    return (
        _array(forces, (n, d), f"{where}: forces"),
        _array(torques, rot, f"{where}: torques"),
    )


def _array(value: Any, shape: tuple[int, ...], what: str) -> FloatArray | None:
    if value is None:
        return None
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ProblemError(f"{what} must be numbers, got {type(value).__name__}") from None
    if a.shape != shape:
        if len(shape) == 1 and a.shape == (shape[0], 1):
            a = a[:, 0]
        else:
            raise ProblemError(f"{what} must have shape {shape} (one row per grain), got {a.shape}")
    if not np.all(np.isfinite(a)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(a.reshape(shape[0], -1)), axis=1))[0])
        raise ProblemError(f"{what} are not finite (grain {bad} first)")
    return a


def grain_impulses(
    scene: Scene, problem: ConicProblem, p: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """Net contact impulse and angular impulse on each grain, from a step's impulses.

    Returns ``(impulse, angular)``: shapes ``(n, d)`` (N s) and ``(n,)`` in 2D or
    ``(n, 3)`` in 3D (N m s, about the grain's centre). Fixed grains get zeros.
    """
    n, d = scene.n_grains, scene.dim
    impulse = np.zeros((n, d))
    angular = np.zeros(n) if d == 2 else np.zeros((n, 3))
    if problem.nc == 0:
        return impulse, angular
    q = np.asarray(problem.H.T @ np.asarray(p, dtype=np.float64).reshape(-1))
    free = scene.free
    per_grain = q.size // scene.n_free
    blocks = q.reshape(scene.n_free, per_grain)
    impulse[free] = blocks[:, :d]
    if per_grain > d:
        # The problem's rotational unknown is r * omega, with mass I / r^2: its
        # generalized impulse q gives I d(omega) = r q.
        r = scene.radii[free]
        if d == 2:
            angular[free] = r * blocks[:, 2]
        else:
            angular[free] = r[:, None] * blocks[:, 3:]
    return impulse, angular
