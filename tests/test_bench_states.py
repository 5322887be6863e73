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
    # The trajectory's own end-of-step check is kept with it.
    assert seq.meta["penetration_max"] <= 1e-2 and seq.meta["redos"] == 0
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


@pytest.mark.parametrize("stop_at", ["preparing, step 4/", "recording, step 1/"])
def test_an_interrupted_recording_continues_from_its_checkpoint(cache, stop_at):
    """Killed while preparing or recording, the next call continues from the last
    checkpoint and records the problems an uninterrupted recording does."""
    make = partial(stack, 4, dim=2)
    kwargs = dict(dt=1e-3, t_start=6e-3, n_steps=3, solver="pgs", tol=1e-10)
    whole = record_steps("whole", make, cache=False, **kwargs)

    lines: list[str] = []

    def interrupt(line: str) -> None:
        lines.append(line)
        if stop_at in line:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        record_steps("cut", make, progress=interrupt, checkpoint_s=0.0, **kwargs)
    assert list((cache / "bench").glob("cut-*.partial.pkl"))
    lines.clear()
    seq = record_steps("cut", make, progress=lines.append, checkpoint_s=0.0, **kwargs)
    assert "continuing from the checkpoint" in lines[0]
    assert not any("preparing, step 1/" in line for line in lines)
    assert seq.t_start == pytest.approx(whole.t_start)
    assert len(seq.problems) == 3
    for a, b in zip(seq.impulses, whole.impulses, strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
    for a, b in zip(seq.warm_starts[1:], whole.warm_starts[1:], strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
    assert not list((cache / "bench").glob("cut-*.partial.pkl"))  # removed when done
