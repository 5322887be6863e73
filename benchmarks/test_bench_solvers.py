"""pytest-benchmark suites: one step solve by every available backend.

Two step problems, built once per session by stepping with ``clarabel``:

* 2D: ``column_2d(300)`` after :data:`WARMUP_STEPS` steps of collapse (a QP:
  2D friction cones are linear, so every 2D backend applies);
* 3D: ``box_3d(200)`` after :data:`WARMUP_STEPS` steps of settling
  (second-order cones: backends that take linear cones only are left out).

Each backend is parametrised by registry name and timed on one cold solve at
:data:`TOL` (``benchmark.pedantic``: one warm-up round, then :data:`ROUNDS`
rounds of one call). ``benchmark.extra_info`` records ``N``, ``Nc``,
``iterations``, ``status``, ``ccp_residual`` and ``coulomb_residual`` (the
framework's residuals, :mod:`cocd.residuals`). Benchmarks measure, they do not
judge: a backend that answers ``max_iter`` or ``error`` is timed and recorded
as such (the accuracy assertions live in ``tests/``).

With ``--benchmark-disable`` (the default in ``pyproject.toml``) every
benchmark runs once, as a smoke test. To time them::

    pytest benchmarks --benchmark-enable
    pytest benchmarks --benchmark-enable --benchmark-autosave
    pytest-benchmark compare --group-by=group --columns=min,mean,stddev,rounds
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import solvers
from cocd.builders import box_3d, column_2d
from cocd.contacts import detect_contacts
from cocd.problem import ConicProblem, assemble
from cocd.residuals import residuals
from cocd.scene import Scene
from cocd.stepper import Stepper

#: Tolerance asked of every backend.
TOL = 1e-6
#: Time step (s) of both problems.
DT = 1e-3
#: Steps taken (with clarabel) before the benchmarked step.
WARMUP_STEPS = 5
#: Timed rounds per backend when benchmarking is enabled.
ROUNDS = 5


def _names(dim: int) -> list[str]:
    """Available backends that can solve this module's ``dim``-D problem."""
    out = []
    for name in solvers.available():
        info = solvers.get(name)
        if dim not in info.dims:
            continue
        if dim == 3 and info.linear_cones_only:  # box_3d has friction: second-order cones
            continue
        out.append(name)
    return out


def _problem(scene: Scene) -> ConicProblem:
    Stepper(scene, DT, solver="clarabel", tol=1e-8).run(WARMUP_STEPS)
    return assemble(scene, detect_contacts(scene), DT)


@pytest.fixture(scope="module")
def problem_2d() -> tuple[Scene, ConicProblem]:
    scene = column_2d(300)
    return scene, _problem(scene)


@pytest.fixture(scope="module")
def problem_3d() -> tuple[Scene, ConicProblem]:
    scene = box_3d(200)
    return scene, _problem(scene)


def _bench(benchmark: Any, scene: Scene, problem: ConicProblem, solver: str) -> None:
    def solve() -> solvers.Solution:
        return solvers.solve(problem, solver, TOL)

    solution = benchmark.pedantic(solve, rounds=ROUNDS, iterations=1, warmup_rounds=1)
    benchmark.extra_info.update(
        N=scene.n_free,
        Nc=problem.nc,
        iterations=int(solution.iterations),
        status=solution.status.value,
        ccp_residual=float("nan"),
        coulomb_residual=float("nan"),
    )
    assert solution.p.shape == (problem.nc, problem.contact_dim)
    if solution.found:
        assert np.all(np.isfinite(solution.p)) and np.all(np.isfinite(solution.u))
        res = residuals(problem, solution.u, solution.p)
        benchmark.extra_info.update(ccp_residual=res.ccp, coulomb_residual=res.coulomb)


@pytest.mark.benchmark(group="step-2d-column300")
@pytest.mark.parametrize("solver", _names(2))
def test_step_2d_column(benchmark: Any, problem_2d: tuple[Scene, ConicProblem], solver: str):
    scene, problem = problem_2d
    assert problem.dim == 2 and problem.is_qp and problem.nc > 0
    _bench(benchmark, scene, problem, solver)


@pytest.mark.benchmark(group="step-3d-box200")
@pytest.mark.parametrize("solver", _names(3))
def test_step_3d_box(benchmark: Any, problem_3d: tuple[Scene, ConicProblem], solver: str):
    scene, problem = problem_3d
    assert problem.dim == 3 and not problem.is_qp and problem.nc > 0
    _bench(benchmark, scene, problem, solver)
