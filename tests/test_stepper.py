"""The stepper: integration, records, warm-start matching, whole scenes."""

from __future__ import annotations

import numpy as np
import pytest
from test_conic_backends import heap

from cocd import ProblemError, Scene, Stepper, Wall, column_2d, stack
from cocd.stepper import StepRecord, match_impulses

G = 9.81


def test_free_fall_is_symplectic_euler():
    dt, k = 1e-3, 50
    scene = Scene([[0.0, 1.0]], 0.01, velocities=[[0.2, 0.0]])
    stepper = Stepper(scene, dt)
    stepper.run(k)
    # v_k = -g k dt;  y_k = y_0 - g dt^2 k (k + 1) / 2
    assert scene.velocities[0, 1] == pytest.approx(-G * k * dt, rel=1e-12)
    assert scene.positions[0, 1] == pytest.approx(1.0 - G * dt**2 * k * (k + 1) / 2, rel=1e-12)
    assert scene.positions[0, 0] == pytest.approx(0.2 * k * dt, rel=1e-12)
    assert scene.time == pytest.approx(k * dt)
    assert all(r.nc == 0 and r.iterations == 0 for r in stepper.records)


def test_run_until_and_stats_table():
    stepper = Stepper(stack(3, dim=2), 1e-3)
    taken = stepper.run(until=0.0105)
    assert len(taken) == 11
    df = stepper.stats()
    assert list(df.columns) == list(StepRecord.__dataclass_fields__)
    assert len(df) == 11
    assert (df.nc == 3).all()
    assert (df.status == "optimal").all()
    assert df.t.iloc[-1] == pytest.approx(0.011)
    with pytest.raises(ProblemError, match="exactly one of n_steps and until"):
        stepper.run()


def test_match_impulses_by_pair_key():
    prev_keys = np.array([3, 7, 11, 20])
    prev_p = np.arange(8.0).reshape(4, 2)
    keys = np.array([1, 7, 20, 21])
    out = match_impulses(prev_keys, prev_p, keys)
    np.testing.assert_array_equal(out, [[0, 0], [2, 3], [6, 7], [0, 0]])
    assert match_impulses(np.zeros(0, np.int64), np.zeros((0, 2)), keys).shape == (4, 2)


def test_frictionless_stack_drops_rotations_and_tangents():
    n, dt = 5, 1e-3
    scene = stack(n, dim=3, mu=0.0)
    stepper = Stepper(scene, dt)
    stepper.run(5)
    problem = stepper.problem
    assert problem.contact_dim == 1
    assert problem.ndof == 3 * n
    pn = np.sort(stepper.solution.p[:, 0])
    np.testing.assert_allclose(pn, np.arange(1, n + 1) * scene.masses[0] * G * dt, rtol=1e-6)
    assert np.abs(scene.velocities).max() < 1e-8


def test_fixed_grains_carry_no_unknowns_and_do_not_move():
    r = 0.01
    bed = np.array([[2 * r * k, r] for k in range(5)])
    top = np.array([[3 * r, r + np.sqrt(3.0) * r * (1 + 1e-9)]])  # in the hollow of 1 and 2
    fixed = np.array([True] * 5 + [False])
    scene = Scene(np.vstack([bed, top]), r, fixed=fixed, walls=[Wall((0, 0), (0, 1))], mu=0.5)
    stepper = Stepper(scene, 1e-3)
    stepper.run(100)
    assert stepper.problem.ndof == 3
    np.testing.assert_array_equal(scene.positions[:5], bed)
    # A disc resting in the hollow of two glued discs stays there (mu = 0.5 > tan 30 deg).
    assert np.abs(scene.velocities[5]).max() < 1e-8


def test_column_collapse_flows_and_stays_valid():
    scene = column_2d(120)
    front0 = scene.positions[:, 0].max()
    stepper = Stepper(scene, 1e-3)
    stepper.run(80)
    df = stepper.stats()
    assert (df.status != "error").all()
    assert df.kinetic_energy.iloc[-1] > 0.0
    # Energy is dissipated, never created: Ek + Ep decreases (inelastic contacts, friction).
    total = df.kinetic_energy + df.potential_energy
    assert total.iloc[-1] < total.iloc[0]
    # The column spreads to the right (by several millimetres after 80 ms).
    assert scene.positions[:, 0].max() > front0 + 0.003
    assert scene.positions[:, 1].min() > 0.0


def test_3d_heap_in_a_box():
    scene = heap(4, 6)  # 96 spheres in a box open at the top
    side = 4 * 2.2 * 0.005
    stepper = Stepper(scene, 1e-3)
    stepper.run(30)
    assert stepper.problem.nc > 200
    lo = scene.positions - scene.radii[:, None]
    hi = scene.positions + scene.radii[:, None]
    assert lo.min() > -1e-9 and hi[:, :2].max() < side + 1e-9
