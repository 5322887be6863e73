"""The stepper's failure policy: fallback chains, and what counts as a failed step."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

import solvers
from cocd import ProblemError, SolverError, Stepper, stack
from cocd.cli import app
from cocd.config import parse_config
from cocd.io.runfile import RunFile
from cocd.runs import run
from solvers import Solution, SolverInfo, Status, registry

# The test doubles return wrong answers on purpose: the suite's answer check is off here.
pytestmark = pytest.mark.unchecked_solutions
runner = CliRunner()
CALLS = {"n": 0}


@pytest.fixture
def doubles(monkeypatch):
    """Test backends, registered for one test: each fails in its own way from its 3rd call."""
    monkeypatch.setattr(registry, "_registry", dict(registry.registered()))
    CALLS["n"] = 0
    for name in ("raises", "nan", "lazy", "kicks", "gives_up", "picky"):
        solvers.register(SolverInfo(name=name, entry=f"{__name__}:_{name}", warm_start=True))
    yield


def _answer(problem, p, status=Status.OPTIMAL):
    return Solution(
        u=problem.velocity(p),
        p=p,
        status=status,
        iterations=1,
        setup_time=0.0,
        solve_time=0.0,
        solver="double",
    )


def _good_until_third_call(problem, **kwargs):
    CALLS["n"] += 1
    if CALLS["n"] < 3:
        return solvers.solve(problem, "clarabel", tol=kwargs["tol"])
    return None


def _raises(problem, **kwargs):
    answer = _good_until_third_call(problem, **kwargs)
    if answer is None:
        raise RuntimeError("the factorisation broke")
    return answer


def _nan(problem, **kwargs):
    answer = _good_until_third_call(problem, **kwargs)
    if answer is None:
        return _answer(problem, np.full((problem.nc, problem.contact_dim), np.nan))
    return answer


def _lazy(problem, **kwargs):
    """Claims an optimal answer without solving anything: zero impulses."""
    answer = _good_until_third_call(problem, **kwargs)
    if answer is None:
        return _answer(problem, np.zeros((problem.nc, problem.contact_dim)))
    return answer


def _kicks(problem, **kwargs):
    """Impulses inside the cones but a thousand times too large."""
    answer = _good_until_third_call(problem, **kwargs)
    if answer is None:
        return _answer(problem, 1e3 * np.asarray(solvers.solve(problem, "clarabel").p))
    return answer


def _picky(problem, **kwargs):
    """Gives up when asked to ``stall``, solves otherwise."""
    if kwargs.get("stall"):
        return _answer(problem, np.zeros((problem.nc, problem.contact_dim)), Status.MAX_ITER)
    return solvers.solve(problem, "clarabel", tol=kwargs["tol"])


def _gives_up(problem, **kwargs):
    answer = _good_until_third_call(problem, **kwargs)
    if answer is None:
        return _answer(problem, np.zeros((problem.nc, problem.contact_dim)), Status.MAX_ITER)
    return answer


@pytest.mark.parametrize(
    ("double", "reason"),
    [
        ("raises", "raises: solver 'raises' failed after"),
        ("nan", "nan: returned non-finite velocities or impulses"),
        ("lazy", "lazy: ccp_residual"),
        ("gives_up", "gives_up: returned status max_iter"),
    ],
)
def test_failed_step_falls_back_and_the_statistics_say_so(doubles, double, reason):
    stepper = Stepper(stack(3, dim=2), 1e-3, solver=double, fallback=["clarabel"], tol=1e-9)
    stepper.run(4)
    stats = stepper.stats()
    assert list(stats.solver) == [double, double, "clarabel", "clarabel"]
    assert stats.failures.iloc[0] == "" and stats.failures.iloc[1] == ""
    assert stats.failures.iloc[2].startswith(reason), stats.failures.iloc[2]
    # The fallback's answer is the physical one: the stack stays at rest.
    assert np.allclose(stepper.scene.velocities, 0.0, atol=1e-9)
    assert (stats.ccp_residual <= 1e-9).all()


def test_a_fallback_of_the_same_backend_runs_without_the_first_ones_options(doubles):
    """``solver_options`` go to the first backend of the chain only, even when a
    fallback is the same backend (nscd's symmetric sweeps, then its forward ones)."""
    stepper = Stepper(
        stack(3, dim=2), 1e-3, solver="picky", solver_options={"stall": True},
        fallback=["picky"], tol=1e-9,
    )  # fmt: skip
    stepper.run(2)
    stats = stepper.stats()
    assert list(stats.solver) == ["picky", "picky"]
    assert all(f.startswith("picky: returned status max_iter") for f in stats.failures)
    assert np.allclose(stepper.scene.velocities, 0.0, atol=1e-9)


def test_without_fallback_the_error_names_the_step_and_the_backend(doubles):
    stepper = Stepper(stack(3, dim=2), 1e-3, solver="raises")
    stepper.run(2)
    with pytest.raises(SolverError) as err:
        stepper.step()
    message = str(err.value)
    assert message.startswith("step 3 (t = 0.003 s, 3 contacts): raises: solver 'raises' failed")
    assert message.endswith("RuntimeError: the factorisation broke")
    assert stepper.step_count == 2  # the failed step changed nothing
    # Every backend of the chain failing: all are named.
    chain = Stepper(stack(3, dim=2), 1e-3, solver="nan", fallback=["lazy"])
    CALLS["n"] = 5
    with pytest.raises(SolverError, match=r"step 1 .*nan: returned non-finite.*; lazy: ccp_resid"):
        chain.step()


def test_kinetic_energy_blow_up_is_a_failure(doubles):
    stepper = Stepper(stack(3, dim=2), 1e-3, solver="kicks", residual_factor=None)
    stepper.run(2)
    with pytest.raises(SolverError, match=r"step 3 .*kicks: kinetic energy blew up"):
        stepper.step()


def test_policy_options_are_checked(doubles):
    with pytest.raises(ProblemError, match="residual_factor must be a finite number >= 1"):
        Stepper(stack(2, dim=2), 1e-3, residual_factor=0.5)
    with pytest.raises(ProblemError, match="energy_factor must be"):
        Stepper(stack(2, dim=2), 1e-3, energy_factor=float("nan"))
    solvers.register(SolverInfo(name="flat", entry=f"{__name__}:_lazy", dims=(2,)))
    with pytest.raises(ProblemError, match=r"solver 'flat' handles dimensions \(2,\), not a 3D"):
        Stepper(stack(2, dim=3), 1e-3, fallback=["flat"])


def test_a_run_that_fails_keeps_what_it_wrote(doubles, tmp_path):
    config = parse_config(
        {
            "builder": "stack",
            "params": {"n_grains": 3, "dim": 2},
            "run": {"solver": "raises", "steps": 10, "frame_every": 1},
        }
    )
    with pytest.raises(SolverError, match="step 3 .*raises"):
        run(config, tmp_path)
    with RunFile(tmp_path / "run.h5") as rf:
        assert list(rf.steps) == [0, 1, 2]
        assert list(rf.stats().step) == [1, 2]
    # The command line: one line, status 2, and the run file still there.
    CALLS["n"] = 0
    scene = tmp_path / "scene.toml"
    scene.write_text(
        'builder = "stack"\n[params]\nn_grains = 3\ndim = 2\n'
        '[run]\nsolver = "raises"\nsteps = 10\nframe_every = 1\n'
    )
    out = tmp_path / "cli"
    result = runner.invoke(app, ["run", str(scene), "--out", str(out)])
    assert result.exit_code == 2
    assert result.output.strip().splitlines()[-1].startswith("error: step 3 (t = 0.003 s")
    with RunFile(out / "run.h5") as rf:
        assert list(rf.steps) == [0, 1, 2]
    # With a fallback on the command line the same run completes and says so.
    CALLS["n"] = 0
    args = ["run", str(scene), "--out", str(out), "--fallback", "clarabel", "--force"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "8 of 10 steps answered by a fallback backend (8 by clarabel)" in result.output
    with RunFile(out / "run.h5") as rf:
        stats = rf.stats()
    assert list(stats.solver[:2]) == ["raises"] * 2 and set(stats.solver[2:]) == {"clarabel"}
    assert stats.failures.iloc[2].startswith("raises: solver 'raises' failed")
