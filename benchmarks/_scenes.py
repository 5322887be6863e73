"""Scenes the benchmarks share."""

from __future__ import annotations

import numpy as np

from cocd.builders import column_collapse
from cocd.scene import Scene


def falling_column(n: int) -> tuple[Scene, np.ndarray]:
    """The seed's 3D column of ``n`` spheres (lattice on a rough bed of fixed grains,
    20 cm channel, mu = 0.3) and a mid-flow velocity field: grains fall and spread
    faster the higher they are, with a grain-scale scatter."""
    scene = column_collapse(3, n_grains=n, width=0.2, bed="rough", mu=0.3)
    x = scene.positions
    height = (x[:, 2] - x[:, 2].min()) / np.ptp(x[:, 2])
    rng = np.random.default_rng(0)
    v = np.zeros_like(x)
    v[:, 0] = 0.8 * height  # spreading away from the back wall
    v[:, 2] = -1.2 * height  # falling
    v += rng.normal(scale=0.05, size=v.shape)
    v[scene.fixed] = 0.0
    return scene, v
