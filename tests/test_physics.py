"""Analytic physics: resting grains, rolling and sliding on slopes, a launched
sphere, a resting stack's impulses, a head-on collision."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import normal_impulses_from_top

from cocd import Scene, Stepper, Wall, stack

G = 9.81
RADIUS = 0.01


def on_floor(dim, *, velocity=None, gravity=None, mu=0.3, gap=0.0):
    """One grain touching (or ``gap`` above) a horizontal wall at height 0."""
    x = np.zeros((1, dim))
    x[0, -1] = RADIUS + gap
    up = np.zeros(dim)
    up[-1] = 1.0
    v = None if velocity is None else np.asarray(velocity, dtype=float).reshape(1, dim)
    return Scene(x, RADIUS, velocities=v, walls=[Wall(np.zeros(dim), up)], gravity=gravity, mu=mu)


@pytest.mark.parametrize("dim", [2, 3])
def test_grain_on_wall_stays_at_rest(dim):
    scene = on_floor(dim)
    stepper = Stepper(scene, 1e-3)
    stepper.run(200)
    assert np.abs(scene.velocities).max() < 1e-8
    assert np.abs(scene.angular_velocities).max() < 1e-8
    assert abs(scene.positions[0, -1] - RADIUS) < 1e-10
    assert stepper.problem.nc == 1


def slope_acceleration(dim, theta, mu=0.3, dt=1e-3, steps=200):
    """Acceleration down a slope (tilted gravity) measured after 50 steps."""
    g = np.zeros(dim)
    g[0] = G * np.sin(theta)
    g[-1] = -G * np.cos(theta)
    scene = on_floor(dim, gravity=g, mu=mu)
    stepper = Stepper(scene, dt)
    stepper.run(50)
    v50 = scene.velocities[0, 0]
    stepper.run(steps - 50)
    return (scene.velocities[0, 0] - v50) / ((steps - 50) * dt), scene


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("degrees", [20.0, 35.0])
def test_rolls_without_slipping_below_the_limit(dim, degrees):
    theta = np.radians(degrees)
    mu = 0.3
    limit = (3.0 if dim == 2 else 3.5) * mu
    assert np.tan(theta) < limit
    a, scene = slope_acceleration(dim, theta, mu)
    expected = (2.0 / 3.0 if dim == 2 else 5.0 / 7.0) * G * np.sin(theta)
    assert abs(a - expected) <= 1e-3 * expected
    # Rolling: the contact point does not slip (v = R w), the grain stays on the plane.
    spin = scene.angular_velocities[0] if dim == 2 else scene.angular_velocities[0, 1]
    v = scene.velocities[0, 0]
    assert abs(v - (-spin if dim == 2 else spin) * RADIUS) < 1e-6 * v
    assert abs(scene.positions[0, -1] - RADIUS) < 1e-9


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("degrees", [50.0, 60.0])
def test_slides_above_the_limit(dim, degrees):
    theta = np.radians(degrees)
    mu = 0.3
    assert np.tan(theta) > (3.0 if dim == 2 else 3.5) * mu
    a, scene = slope_acceleration(dim, theta, mu)
    expected = G * (np.sin(theta) - mu * np.cos(theta))
    assert abs(a - expected) <= 1e-3 * expected
    # The convexified law lifts a sliding grain by dt mu |slip|: a small gap, not a jump.
    assert 0.0 < scene.positions[0, -1] - RADIUS < 1e-3 * 0.3 * 2.0


def launch(dim, dt, v0=0.5, mu=0.3):
    """Launch a grain without spin; return (time it starts rolling, its speed then)."""
    # Start from the gap the scheme keeps under a contact sliding at v0
    # (dt mu v0, DESIGN.md section 1), so that the launch is not an impact.
    scene = on_floor(dim, velocity=np.eye(dim)[0] * v0, mu=mu, gap=dt * mu * v0)
    stepper = Stepper(scene, dt)
    while scene.time < 2 * v0 / (mu * G):
        stepper.step()
        w = stepper.problem.relative_velocity(stepper.problem.velocity(stepper.solution.p))
        if np.linalg.norm(w[0, 1:]) < 1e-9:
            return scene.time, scene.velocities[0, 0]
    raise AssertionError("the grain never stopped slipping")


@pytest.mark.parametrize("dim", [2, 3])
def test_launched_grain_starts_rolling(dim):
    v0, mu = 0.5, 0.3
    t_star = v0 / (3 * mu * G) if dim == 2 else 2 * v0 / (7 * mu * G)
    v_roll = (2.0 / 3.0 if dim == 2 else 5.0 / 7.0) * v0
    errors = []
    for dt in (1e-3, 2.5e-4):
        t, v = launch(dim, dt, v0, mu)
        # Rolling starts during the first step whose end finds no slip.
        assert t - dt < t_star <= t + 1e-12
        assert abs(v - v_roll) < 1e-9 * v_roll
        errors.append(t - t_star)
    # The bound on the time error shrinks with dt: the smaller step is 4x finer.
    assert errors[1] < 2.5e-4


@pytest.mark.parametrize("dim", [2, 3])
def test_sliding_launch_from_contact_lifts_off_by_mu_slip(dim):
    """COCD's convexified law: a grain sliding on touching ground leaves it with a
    normal velocity mu |slip| (the non-convex law would keep it on the ground)."""
    mu = 0.3
    scene = on_floor(dim, velocity=np.eye(dim)[0] * 0.5, mu=mu)
    stepper = Stepper(scene, 1e-3)
    stepper.step()
    w = stepper.problem.relative_velocity(stepper.problem.velocity(stepper.solution.p))[0]
    slip = np.linalg.norm(w[1:])
    assert slip > 0.1
    assert w[0] == pytest.approx(mu * slip, rel=1e-6)
    assert scene.velocities[0, -1] == pytest.approx(mu * slip, rel=1e-6)


@pytest.mark.parametrize("dim", [2, 3])
def test_resting_stack_impulses(dim):
    n, dt = 10, 1e-3
    scene = stack(n, radius=RADIUS, dim=dim)
    stepper = Stepper(scene, dt)
    stepper.run(20)
    assert np.abs(scene.velocities).max() < 1e-8
    p = stepper.solution.p
    m = scene.masses[0]
    # Contact k from the top carries the weight of the k grains above it.
    pn = normal_impulses_from_top(scene, stepper.contacts, p)
    assert pn.size == n
    expected = np.arange(1, n + 1) * m * G * dt
    np.testing.assert_allclose(pn, expected, rtol=1e-6)
    np.testing.assert_allclose(p[:, 1:], 0.0, atol=1e-9 * m * G * dt)


def test_head_on_collision():
    r, v = 0.01, 1.0
    scene = Scene(
        [[-r, 0.0], [r, 0.0]],
        r,
        velocities=[[v, 0.0], [-v, 0.0]],
        gravity=(0.0, 0.0),
        density=[2500.0, 2500.0],
    )
    momentum0 = scene.masses @ scene.velocities
    stepper = Stepper(scene, 1e-3)
    stepper.step()
    momentum = scene.masses @ scene.velocities
    scale = scene.masses.sum() * v  # total momentum is zero: compare with |m v|
    assert np.abs(momentum - momentum0).max() <= 1e-12 * scale
    normal = np.array([-1.0, 0.0])  # from grain 1 to grain 0
    approach = (scene.velocities[0] - scene.velocities[1]) @ normal
    assert approach >= -1e-9
    # A perfectly inelastic head-on impact of equal discs stops both.
    np.testing.assert_allclose(scene.velocities, 0.0, atol=1e-8)


def test_head_on_collision_unequal_masses_3d():
    r = 0.01
    scene = Scene(
        [[-r, 0.0, 0.0], [2 * r, 0.0, 0.0]],
        [r, 2 * r],
        velocities=[[2.0, 0.3, 0.0], [-0.5, 0.0, 0.1]],
        gravity=(0.0, 0.0, 0.0),
        mu=0.4,
    )
    m = scene.masses
    momentum0 = m @ scene.velocities
    Stepper(scene, 1e-3).step()
    momentum = m @ scene.velocities
    assert np.abs(momentum - momentum0).max() <= 1e-12 * np.abs(momentum0).max()
    # Inelastic: the normal velocities become equal.
    assert scene.velocities[0, 0] - scene.velocities[1, 0] <= 1e-9
