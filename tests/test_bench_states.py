"""Recorded step sequences (``cocd.bench.states``): tolerances, warm starts and the cache."""

from __future__ import annotations

from functools import partial

import numpy as np
import pytest

import solvers
from cocd.bench.states import record_steps
from cocd.builders import stack


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("COCD_CACHE", str(tmp_path / "cache"))
    return tmp_path / "cache"


def test_prep_tol_solves_only_the_steps_before_t_start(cache, monkeypatch):
    asked: list[float] = []
    real = solvers.solve

    def spy(problem, solver="clarabel", tol=1e-8, *args, **kwargs):
        asked.append(tol)
        return real(problem, solver, tol, *args, **kwargs)

    monkeypatch.setattr(solvers, "solve", spy)
    make = partial(stack, 3, dim=2)
    seq = record_steps("st", make, dt=1e-3, t_start=3e-3, n_steps=2, tol=1e-8, prep_tol=1e-4)
    assert asked == [1e-4] * 3 + [1e-8] * 2
    assert seq.trajectory_tol == 1e-8 and len(seq.problems) == 2
    assert seq.t_start == pytest.approx(3e-3)
    # The second recorded step is warm-started from the first one's impulses.
    assert seq.warm_starts[1] is not None
    np.testing.assert_allclose(seq.warm_starts[1], seq.impulses[0])
    # Read back from the cache; another prep_tol is another sequence.
    asked.clear()
    again = record_steps("st", make, dt=1e-3, t_start=3e-3, n_steps=2, tol=1e-8, prep_tol=1e-4)
    assert asked == [] and again.build_time == 0.0
    record_steps("st", make, dt=1e-3, t_start=3e-3, n_steps=2, tol=1e-8)
    assert asked == [1e-8] * 5
    assert len(list((cache / "bench").glob("st-*.pkl"))) == 2
