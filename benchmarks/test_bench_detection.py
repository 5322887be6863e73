"""pytest-benchmark: contact detection of one step of a collapsing 3D column.

The seed's 3D column (:func:`cocd.builders.column_collapse`, lattice on a rough bed
of fixed grains, 20 cm channel) with a mid-flow velocity field: grains fall and
spread faster the higher they are, with a grain-scale scatter, at the seed's 3D
step ``dt = 1e-2`` s. The margins that follow this motion make the candidate pairs
outnumber the contacts many times over, which is where the cost of detection lies
at scale. ``benchmark.extra_info`` records the grains and the contacts found.

    pytest benchmarks/test_bench_detection.py --benchmark-enable
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from _scenes import falling_column

from cocd.contacts import detect_contacts
from cocd.scene import Scene

#: Spheres in the column.
N = 10000
#: Time step (s), the seed's in 3D.
DT = 1e-2


@pytest.fixture(scope="module", name="falling_column")
def falling_column_fixture() -> tuple[Scene, np.ndarray]:
    return falling_column(N)


@pytest.mark.benchmark(group="detect-3d-column")
def test_detect_falling_column(benchmark: Any, falling_column: tuple[Scene, np.ndarray]):
    scene, v = falling_column
    contacts = benchmark.pedantic(
        detect_contacts,
        args=(scene,),
        kwargs=dict(velocities=v, dt=DT),
        rounds=3,
        iterations=1,
        warmup_rounds=1,
    )
    benchmark.extra_info.update(N=scene.n_free, Nc=contacts.nc)
    assert contacts.nc > 3 * scene.n_free
