"""The coupling hook: external loads per grain, contact impulses per grain.

Analytic answers: a grain falling through a linear drag ``-gamma v`` reaches
the terminal velocity ``m g / gamma``; a grain resting on a floor under a
buoyancy equal to its weight stays at rest with no contact impulse; a torque
spins a free grain at ``tau / I``; a resting stack's grains each receive a net
contact impulse ``m g dt`` upwards.
"""

from __future__ import annotations

import numpy as np
import pytest

from cocd import Scene, Stepper, Wall, stack
from cocd.coupling import Loads
from cocd.errors import ProblemError

G = 9.81
RADIUS = 0.01


def _grain(dim, *, height=RADIUS, floor=True, mu=0.3):
    x = np.zeros((1, dim))
    x[0, -1] = height
    up = np.zeros(dim)
    up[-1] = 1.0
    walls = [Wall(np.zeros(dim), up)] if floor else []
    return Scene(x, RADIUS, walls=walls, mu=mu)


@pytest.mark.parametrize("dim", [2, 3])
def test_linear_drag_gives_the_terminal_velocity(dim):
    scene = _grain(dim, height=1.0, floor=False)
    m = float(scene.masses[0])
    gamma = m / 0.02  # relaxation time m / gamma = 20 ms

    def drag(s, t):
        return -gamma * s.velocities

    stepper = Stepper(scene, 1e-3, external=drag)
    stepper.run(until=0.5)  # 25 relaxation times
    terminal = m * G / gamma
    v = scene.velocities[0]
    assert abs(-v[-1] - terminal) <= 1e-3 * terminal
    assert np.allclose(v[:-1], 0.0, atol=1e-12)
    # Halfway the velocity follows v(t) = v_T (1 - exp(-t gamma / m)) to O(dt).
    half = Stepper(_grain(dim, height=1.0, floor=False), 1e-4, external=drag)
    half.run(until=0.02)
    expected = terminal * (1.0 - np.exp(-1.0))
    assert abs(-half.scene.velocities[0, -1] - expected) <= 5e-3 * expected


@pytest.mark.parametrize("dim", [2, 3])
def test_buoyancy_equal_to_the_weight_keeps_a_grain_at_rest(dim):
    scene = _grain(dim)
    weight = float(scene.masses[0]) * G
    lift = np.zeros((1, dim))
    lift[0, -1] = weight
    stepper = Stepper(scene, 1e-3, external=Loads(forces=lift))
    stepper.run(200)
    assert np.abs(scene.velocities).max() < 1e-12
    assert abs(scene.positions[0, -1] - RADIUS) < 1e-12
    impulse, angular = stepper.contact_impulses()
    assert np.abs(impulse).max() < 1e-12 * weight
    # Without the lift the floor carries the weight: m g dt per step.
    plain = Stepper(_grain(dim), 1e-3)
    plain.run(5)
    impulse, angular = plain.contact_impulses()
    assert impulse[0, -1] == pytest.approx(weight * 1e-3, rel=1e-8)
    assert np.abs(impulse[0, :-1]).max() < 1e-14 and np.abs(angular).max() < 1e-14


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("mu", [0.0, 0.5])
def test_a_torque_spins_a_free_grain(dim, mu):
    scene = _grain(dim, height=1.0, floor=False, mu=mu)
    inertia = float(scene.inertia[0])
    tau = np.zeros(1) if dim == 2 else np.zeros((1, 3))
    if dim == 2:
        tau[0] = 2e-6
    else:
        tau[0, 1] = 2e-6
    stepper = Stepper(scene, 1e-3, external=(None, tau))
    stepper.run(10)
    w = scene.angular_velocities[0]
    spin = w if dim == 2 else w[1]
    assert spin == pytest.approx(10 * 1e-3 * 2e-6 / inertia, rel=1e-10)


@pytest.mark.parametrize("dim", [2, 3])
def test_a_resting_stack_gets_m_g_dt_per_grain(dim):
    scene = stack(4, dim=dim)
    stepper = Stepper(scene, 1e-3)
    stepper.run(20)
    impulse, angular = stepper.contact_impulses()
    m = scene.masses
    free = scene.free
    assert np.allclose(impulse[free, -1], m[free] * G * 1e-3, rtol=1e-6)
    assert np.abs(impulse[free, :-1]).max() < 1e-10
    assert np.abs(angular).max() < 1e-10
    assert np.all(impulse[~free] == 0.0)


def test_bad_loads_are_named():
    scene = _grain(2)
    with pytest.raises(ProblemError, match=r"forces must have shape \(1, 2\)"):
        Stepper(scene, 1e-3, external=np.zeros((2, 2)))
    with pytest.raises(ProblemError, match=r"torques must have shape \(1,\)"):
        Stepper(scene, 1e-3, external=Loads(torques=np.zeros((1, 3))))
    stepper = Stepper(scene, 1e-3, external=lambda s, t: np.full((1, 2), np.nan))
    with pytest.raises(ProblemError, match=r"external loads of step 1 .* not finite \(grain 0"):
        stepper.step()
    stepper = Stepper(scene, 1e-3, external=lambda s, t: 1 / 0)
    with pytest.raises(ProblemError, match="the load callable raised ZeroDivisionError"):
        stepper.step()
    with pytest.raises(ProblemError, match="no step has been taken"):
        Stepper(scene, 1e-3).contact_impulses()
