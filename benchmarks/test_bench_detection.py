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

from cocd.builders import column_collapse
from cocd.contacts import detect_contacts
from cocd.scene import Scene

#: Spheres in the column.
N = 10000
#: Time step (s), the seed's in 3D.
DT = 1e-2


@pytest.fixture(scope="module")
def falling_column() -> tuple[Scene, np.ndarray]:
    scene = column_collapse(3, n_grains=N, width=0.2, bed="rough", mu=0.3)
    x = scene.positions
    height = (x[:, 2] - x[:, 2].min()) / np.ptp(x[:, 2])
    rng = np.random.default_rng(0)
    v = np.zeros_like(x)
    v[:, 0] = 0.8 * height  # spreading away from the back wall
    v[:, 2] = -1.2 * height  # falling
    v += rng.normal(scale=0.05, size=v.shape)
    v[scene.fixed] = 0.0
    return scene, v


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
