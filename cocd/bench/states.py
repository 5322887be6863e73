"""Step problems along a recorded trajectory, cached on disk.

Benchmarks compare backends on *the same* problems: a scene is advanced by one
trajectory backend to a start time, then the next ``n_steps`` step problems are
recorded with that backend's impulses (a warm start for the following step,
matched by contact pair). Every backend is then timed on these problems, so
that no backend's own trajectory changes what the others are asked.

Recorded sequences are pickled in ``$COCD_CACHE/bench`` (default
``~/.cache/cocd/bench``), keyed by a hash of the initial scene and every
parameter; an unreadable or mismatched file is rebuilt, never trusted. A long
recording (a large column advanced to its start time) checkpoints its state
beside it every few minutes, so that an interrupted recording continues from
its last checkpoint, on the trajectory it would have followed.
"""

from __future__ import annotations

import hashlib
import os
import pickle
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cocd.packing import cache_dir
from cocd.problem import ConicProblem
from cocd.scene import Scene
from cocd.stepper import Stepper, match_impulses

__all__ = ["StepSequence", "record_steps"]

FloatArray = NDArray[np.float64]

#: Bump when the recording changes, so that old cache files are not reused
#: (2: the stepper's motion-following detection margin).
_FORMAT = 2
#: Wall seconds between two checkpoints of a recording.
CHECKPOINT_S = 300.0


@dataclass
class StepSequence:
    """Consecutive step problems of one trajectory.

    Attributes
    ----------
    label : str
        Names the case in tables (``column-2d``, ``box-3d``, ...).
    dim, n_free : int
        Dimension and number of free grains.
    dt, t_start : float
        Time step and the time at the start of the first recorded step.
    problems : list of ConicProblem
    impulses : list of (nc, m) arrays
        The trajectory backend's answer to each problem.
    warm_starts : list of (nc, m) arrays or None
        For each problem, the previous step's impulses matched by contact pair
        (None for the first).
    trajectory_solver, trajectory_tol : str, float
    build_time : float
        Seconds taken to record (0 when read from the cache).
    """

    label: str
    dim: int
    n_free: int
    dt: float
    t_start: float
    problems: list[ConicProblem]
    impulses: list[FloatArray]
    warm_starts: list[FloatArray | None]
    trajectory_solver: str
    trajectory_tol: float
    build_time: float = 0.0
    meta: dict[str, float] = field(default_factory=dict)


def record_steps(
    label: str,
    make_scene: Callable[[], Scene],
    *,
    dt: float,
    t_start: float,
    n_steps: int,
    solver: str = "clarabel",
    tol: float = 1e-8,
    cache: bool = True,
    progress: Callable[[str], None] | None = None,
    prep_tol: float | None = None,
    d_max: float | None = None,
    checkpoint_s: float = CHECKPOINT_S,
) -> StepSequence:
    """Advance ``make_scene()`` with ``solver`` to ``t_start``, then record ``n_steps`` steps.

    Parameters
    ----------
    label : str
        Case name (also part of the cache file name).
    make_scene : callable
        Builds the initial scene (deterministic: its content is part of the key).
    dt, t_start : float
        Time step (s) and start time of the recorded steps (s).
    n_steps : int
        Number of recorded step problems.
    solver, tol : str, float
        Trajectory backend and its tolerance.
    prep_tol : float, optional
        Tolerance of the steps before ``t_start`` (default ``tol``): they only
        need to bring the scene to a physical state, the recorded steps are
        solved at ``tol``.
    cache : bool
        Read and write ``$COCD_CACHE/bench`` (and checkpoints there).
    progress : callable, optional
        Called with a line of text every step while recording.
    d_max : float, optional
        Detection threshold (m) of every step: a fixed threshold, no margin
        (:class:`~cocd.stepper.Stepper`); default the stepper's.
    checkpoint_s : float
        Wall seconds between two checkpoints.
    """
    scene = make_scene()
    path, key = cache_path(label, scene, dt, t_start, n_steps, solver, tol, prep_tol, d_max)
    partial = path.with_suffix(".partial.pkl")
    if cache:
        seq = _read(path, key)
        if seq is not None:
            return seq
    start = time.perf_counter()
    stepper = Stepper(
        scene, dt, solver=solver, tol=tol if prep_tol is None else prep_tol, d_max=d_max
    )
    n_before = max(0, round(t_start / dt) - round(scene.time / dt))
    say = progress or (lambda _line: None)
    problems: list[ConicProblem] = []
    impulses: list[FloatArray] = []
    warm: list[FloatArray | None] = []
    prev_keys: NDArray[np.int64] | None = None
    prev_p: FloatArray | None = None
    state = _read_checkpoint(partial, key) if cache else None
    if state is not None:
        scene, records, previous, problems, impulses, warm, prev_keys, prev_p = state
        stepper.scene = scene
        stepper.restore(records, previous)
        say(f"{label}: continuing from the checkpoint at step {stepper.step_count}")
    last = time.perf_counter()

    def checkpoint() -> None:
        nonlocal last
        if cache and time.perf_counter() - last >= checkpoint_s:
            _write(partial, key, (scene, stepper.records, stepper.previous, problems, impulses,
                                  warm, prev_keys, prev_p))  # fmt: skip
            last = time.perf_counter()

    while stepper.step_count < n_before:
        r = stepper.step()
        say(f"{label}: preparing, step {r.step}/{n_before}, t = {r.t:.4f} s, Nc = {r.nc}")
        checkpoint()
    stepper.tol = float(tol)
    t0 = scene.time - len(problems) * dt
    if not problems and stepper.previous is not None:
        prev_keys, prev_p = stepper.previous
    while len(problems) < n_steps:
        r = stepper.step()
        assert stepper.problem is not None and stepper.solution is not None
        assert stepper.contacts is not None
        problem, p = stepper.problem, np.asarray(stepper.solution.p)
        if prev_keys is not None and prev_p is not None:
            w = match_impulses(prev_keys, prev_p, stepper.contacts.keys)
            warm.append(w if w.shape == p.shape else None)
        else:
            warm.append(None)
        problems.append(problem)
        impulses.append(p)
        prev_keys, prev_p = stepper.contacts.keys, p
        say(f"{label}: recording, step {len(problems)}/{n_steps}, t = {r.t:.4f} s, Nc = {r.nc}")
        checkpoint()
    seq = StepSequence(
        label=label,
        dim=scene.dim,
        n_free=scene.n_free,
        dt=dt,
        t_start=t0,
        problems=problems,
        impulses=impulses,
        warm_starts=warm,
        trajectory_solver=solver,
        trajectory_tol=tol,
        build_time=time.perf_counter() - start,
        meta={
            # The trajectory's own end-of-step check (Stepper): what it let through.
            "penetration_max": max((float(r.penetration) for r in stepper.records), default=0.0),
            "redos": float(sum(r.redos for r in stepper.records)),
        },
    )
    if cache:
        _write(path, key, seq)
        partial.unlink(missing_ok=True)
    return seq


def cache_path(
    label: str,
    scene: Scene,
    dt: float,
    t_start: float,
    n_steps: int,
    solver: str,
    tol: float,
    prep_tol: float | None = None,
    d_max: float | None = None,
) -> tuple[Path, str]:
    """The cache file of :func:`record_steps` for these arguments, and its key."""
    key = _key(label, scene, dt, t_start, n_steps, solver, tol)
    if prep_tol is not None:
        key = hashlib.sha256(f"{key}|prep_tol={float(prep_tol)!r}".encode()).hexdigest()
    if d_max is not None:
        key = hashlib.sha256(f"{key}|d_max={float(d_max)!r}".encode()).hexdigest()
    return cache_dir() / "bench" / f"{label}-{key[:16]}.pkl", key


def _key(
    label: str, scene: Scene, dt: float, t_start: float, n: int, solver: str, tol: float
) -> str:
    h = hashlib.sha256()
    h.update(f"{_FORMAT}|{label}|{dt!r}|{t_start!r}|{n}|{solver}|{tol!r}".encode())
    for a in (scene.positions, scene.radii, scene.velocities, scene.fixed, scene.gravity):
        h.update(np.ascontiguousarray(a).tobytes())
    h.update(f"{scene.mu!r}|{scene.mu_wall!r}|{scene.time!r}".encode())
    for w in scene.walls:
        h.update(np.concatenate([w.point, w.normal]).tobytes() + repr(w.mu).encode())
    h.update(np.ascontiguousarray(scene.density).tobytes())
    return h.hexdigest()


def _read(path: Path, key: str) -> StepSequence | None:
    if not path.exists():
        return None
    try:
        with open(path, "rb") as f:
            stored_key, seq = pickle.load(f)
    except Exception:
        return None
    if stored_key != key or not isinstance(seq, StepSequence):
        return None
    seq.build_time = 0.0
    return seq


def _read_checkpoint(path: Path, key: str) -> tuple[Any, ...] | None:
    """The state a recording saved, if ``path`` holds one of this key."""
    if not path.exists():
        return None
    try:
        with open(path, "rb") as f:
            stored_key, state = pickle.load(f)
    except Exception:
        return None
    if stored_key != key or not isinstance(state, tuple) or len(state) != 8:
        return None
    return state


def _write(path: Path, key: str, seq: object) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            pickle.dump((key, seq), f, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
