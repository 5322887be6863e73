"""Bad input gets a specific error whose message names what is wrong."""

from __future__ import annotations

import numpy as np
import pytest

import solvers
from cocd import (
    OverlapError,
    ProblemError,
    Scene,
    SceneError,
    SolverNotFound,
    Stepper,
    Wall,
    stack,
)


def test_non_positive_radius():
    with pytest.raises(SceneError, match=r"radius of grain 1 is -0\.01: radii must be > 0"):
        Scene([[0.0, 0.0], [1.0, 0.0]], [0.01, -0.01])
    with pytest.raises(SceneError, match=r"radius of grain 0 is 0"):
        Scene([[0.0, 0.0]], 0.0)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_coordinates(bad):
    x = np.zeros((3, 3))
    x[:, 2] = [0.0, 0.1, 0.2]
    x[2, 1] = bad
    with pytest.raises(SceneError, match=r"positions\[2, 1\] is .*: positions must be finite"):
        Scene(x, 0.01)


def test_non_finite_velocity_and_gravity():
    with pytest.raises(SceneError, match=r"velocities\[0, 0\] is nan"):
        Scene([[0.0, 0.0]], 0.01, velocities=[[np.nan, 0.0]])
    with pytest.raises(SceneError, match=r"gravity"):
        Scene([[0.0, 0.0]], 0.01, gravity=(0.0, np.inf))


@pytest.mark.parametrize("name", ["mu", "mu_wall"])
def test_negative_friction(name):
    with pytest.raises(SceneError, match=rf"friction coefficient {name} must be finite and >= 0"):
        Scene([[0.0, 0.0]], 0.01, **{name: -0.1})
    with pytest.raises(SceneError, match="wall friction coefficient must be finite and >= 0"):
        Wall((0.0, 0.0), (0.0, 1.0), mu=-1.0)


@pytest.mark.parametrize("dt", [0.0, -1e-3, np.nan, np.inf])
def test_non_positive_dt(dt):
    with pytest.raises(ProblemError, match="time step dt must be finite and > 0"):
        Stepper(stack(1, dim=2), dt)


def test_bad_tolerance():
    with pytest.raises(ProblemError, match="tol must be finite and > 0"):
        Stepper(stack(1, dim=2), 1e-3, tol=0.0)


def test_overlapping_grains_at_start():
    r = 0.01
    scene = Scene([[0.0, r], [1.9 * r, r]], r, walls=[Wall((0.0, 0.0), (0.0, 1.0))])
    with pytest.raises(OverlapError, match=r"grains 0 and 1 overlap by 0\.001 m .*allowed 1e-06"):
        Stepper(scene, 1e-3)
    # Within the stated tolerance, or with a looser one, the run starts.
    Stepper(scene, 1e-3, overlap_tol=0.2)
    touching = Scene([[0.0, r], [2 * r * (1 - 1e-9), r]], r, walls=[Wall((0.0, 0.0), (0.0, 1.0))])
    Stepper(touching, 1e-3)


def test_grain_through_a_wall():
    scene = Scene([[0.0, 0.005]], 0.01, walls=[Wall((0.0, 0.0), (0.0, 1.0))])
    with pytest.raises(OverlapError, match=r"grain 0 penetrates wall 0 by 0\.005 m"):
        Stepper(scene, 1e-3)


def test_unknown_solver_lists_available_names():
    with pytest.raises(
        SolverNotFound, match=r"unknown solver 'mosekk'; available solvers: .*clarabel"
    ):
        Stepper(stack(1, dim=2), 1e-3, solver="mosekk")
    with pytest.raises(SolverNotFound, match="unknown solver 'nope'"):
        solvers.get("nope")


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"positions": [[0.0, 0.0, 0.0, 0.0]], "radii": 0.01}, r"shape \(n, 2\) or \(n, 3\)"),
        ({"positions": np.zeros((0, 2)), "radii": 0.01}, "at least one grain"),
        (
            {"positions": [[0.0, 0.0]], "radii": [0.01, 0.02]},
            r"radii must be a number or have shape \(1,\)",
        ),
        ({"positions": [["a", 0.0]], "radii": 0.01}, "positions must be numeric"),
        ({"positions": [[0.0, 0.0]], "radii": 0.01, "density": -1.0}, "density of grain 0"),
        (
            {"positions": [[0.0, 0.0]], "radii": 0.01, "gravity": (0.0, 0.0, 1.0)},
            "gravity must have 2",
        ),
        (
            {"positions": [[0.0, 0.0]], "radii": 0.01, "walls": [Wall((0, 0, 0), (0, 0, 1))]},
            "walls.0. is 3D but the grains are 2D",
        ),
        ({"positions": [[0.0, 0.0]], "radii": 0.01, "fixed": [1]}, "fixed must be a boolean array"),
        (
            {"positions": [[0.0, 0.0]], "radii": 0.01, "angular_velocities": [[0.0, 0.0, 0.0]]},
            r"angular_velocities must have shape \(1,\)",
        ),
    ],
)
def test_malformed_scene(kwargs, message):
    with pytest.raises(SceneError, match=message):
        Scene(**kwargs)


def test_malformed_wall():
    with pytest.raises(SceneError, match="wall normal is the zero vector"):
        Wall((0.0, 0.0), (0.0, 0.0))
    with pytest.raises(SceneError, match="must both have 2 or 3 coordinates"):
        Wall((0.0, 0.0), (0.0, 1.0, 0.0))


def test_solve_arguments_are_checked():
    scene = stack(2, dim=3)
    stepper = Stepper(scene, 1e-3)
    stepper.step()
    problem = stepper.problem
    with pytest.raises(ProblemError, match="tol must be a finite number > 0"):
        solvers.solve(problem, tol=-1.0)
    with pytest.raises(ProblemError, match="max_iter must be a positive integer"):
        solvers.solve(problem, max_iter=0)
    with pytest.raises(ProblemError, match="time_limit must be > 0"):
        solvers.solve(problem, time_limit=0.0)
    with pytest.raises(ProblemError, match="clarabel has no free setting 'bogus'"):
        solvers.solve(problem, bogus=1)
