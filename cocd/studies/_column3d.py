"""The seed's 3D column and its cached step, shared by ``cocd bench column3d-ipm`` and
``cocd bench column3d-solvers``.

``column_collapse(3, n_grains=N, width=0.2, bed="rough", mu=0.3)`` (lattice
packing, released at t = 0), dt = 1e-2 s, potential contacts below 0.98 mean
radii (:data:`cocd.studies.table1.D_SEED_3D`), advanced by ``apgd`` at ``tol``
to ``t_start`` and recorded with :func:`cocd.bench.states.record_steps` under
the label ``column3d-solvers-N`` (the cache ``cocd bench scaling`` shares).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import partial

from cocd.bench import report
from cocd.bench.states import StepSequence, record_steps
from cocd.builders import column_collapse
from cocd.errors import CocdError
from cocd.studies.table1 import CHANNEL_WIDTH, D_SEED_3D, DT_3D, MU_3D

__all__ = ["check", "column_step"]


def check(flag: str, value: float, *, minimum: float = 0.0, strict: bool = True) -> None:
    """A one-line :class:`CocdError` unless ``value`` is a finite number above ``minimum``
    (at least ``minimum`` when not ``strict``)."""
    ok = math.isfinite(value) and (value > minimum if strict else value >= minimum)
    if not ok:
        sign = ">" if strict else ">="
        raise CocdError(f"{flag} must be a finite number {sign} {minimum:g}, got {value!r}")


def column_step(
    n: int, *, tol: float, t_start: float, progress: Callable[[str], object]
) -> StepSequence:
    """The step from ``t_start`` of the seed's column of ``n`` spheres (cached)."""
    make = partial(column_collapse, 3, n_grains=n, width=CHANNEL_WIDTH, bed="rough", mu=MU_3D)
    d_max = D_SEED_3D * float(make().radii.mean())
    return record_steps(
        f"column3d-solvers-{n}",
        make,
        dt=DT_3D,
        t_start=t_start,
        n_steps=1,
        solver="apgd",
        tol=tol,
        d_max=d_max,
        progress=report.throttled(progress, 10.0),
    )
