"""pytest-benchmark: one APGD solve on a step of a collapsing 3D column, with the
products through the Jacobian's contact blocks (``operator="auto"``) and in CSR.

The step is that of ``test_bench_detection.py``: the seed's 3D column (lattice on a
rough bed of fixed grains, 20 cm channel, mu = 0.3) with a mid-flow velocity field
at the seed's ``dt = 1e-2`` s, whose contacts, margins included, number about seven
per sphere. Each solve makes ``ITERATIONS`` iterations (the time per iteration does
not depend on how far the answer is; the iterations to a tolerance do not depend
on the operator). ``benchmark.extra_info`` records the grains, the contacts and the
seconds per iteration. ``COCD_BENCH_SPHERES`` sets the column's size (default
10 000; the seed's is 112 459).

    pytest benchmarks/test_bench_apgd_operator.py --benchmark-enable
"""

from __future__ import annotations

import os
from typing import Any

import pytest
from _scenes import falling_column

import solvers
from cocd.contacts import detect_contacts
from cocd.problem import ConicProblem, assemble

#: Spheres in the column.
N = int(os.environ.get("COCD_BENCH_SPHERES", "10000"))
#: Time step (s), the seed's in 3D.
DT = 1e-2
#: Iterations per solve.
ITERATIONS = 50

pytestmark = pytest.mark.skipif("apgd" not in solvers.available(), reason="apgd needs numba")


@pytest.fixture(scope="module")
def falling_step() -> ConicProblem:
    scene, v = falling_column(N)
    scene.velocities[:] = v
    return assemble(scene, detect_contacts(scene, velocities=v, dt=DT), DT)


@pytest.mark.benchmark(group="apgd-3d-column")
@pytest.mark.parametrize("operator", ["auto", "csr"])
def test_apgd_iterations_on_a_falling_column(
    benchmark: Any, falling_step: ConicProblem, operator: str
):
    problem = falling_step
    solvers.solve(problem, "apgd", tol=1e-12, max_iter=2, operator=operator)  # compiled
    solution = benchmark.pedantic(
        solvers.solve,
        args=(problem, "apgd"),
        kwargs=dict(tol=1e-12, max_iter=ITERATIONS, operator=operator),
        rounds=3,
        iterations=1,
    )
    assert solution.iterations == ITERATIONS
    assert solution.extras["operator"] == ("blocks" if operator == "auto" else "csr")
    benchmark.extra_info.update(
        N=problem.mass.size // 6,
        Nc=problem.nc,
        s_per_iteration=solution.solve_time / solution.iterations,
    )
