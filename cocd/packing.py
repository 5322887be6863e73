"""Packing preparation: rain deposition under gravity, cached on disk.

Grains placed without overlap above (or inside) a container are let fall
under gravity with the stepper until they are at rest: the kinetic energy per
grain, relative to ``m g d`` (mean mass, gravity, mean diameter), falls below
``ke_threshold``, or a step cap is reached. Packings are built with a
preparation friction ``mu_prep`` (0: compact, > 0: loose); the scene's own
``mu`` is restored afterwards.

Prepared packings are cached as ``.npz`` files in ``$COCD_CACHE`` (default
``~/.cache/cocd``), keyed by a hash of everything that determines them (the
initial scene and every preparation parameter). A cached file that cannot be
read, or whose content does not match its key, is rebuilt, never trusted.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from cocd.errors import SceneError
from cocd.measure import kinetic_energy
from cocd.scene import Scene

__all__ = ["Deposition", "cache_dir", "packing_fraction", "rain_deposition"]

FloatArray = NDArray[np.float64]

#: Bump when the deposition algorithm changes, so that old cache files are not reused.
_FORMAT = 1


@dataclass(frozen=True)
class Deposition:
    """A settled packing and how it was obtained.

    Attributes
    ----------
    scene : Scene
        The settled scene: velocities zero, time zero, the input scene's ``mu``.
    steps : int
        Steps taken (0 when read from the cache).
    ke_ratio : float
        ``Ek / (N m g d)`` at the last step (0 when read from the cache).
    settled : bool
        True when ``ke_ratio`` fell below the threshold before the step cap.
    from_cache : bool
        True when the packing was read from the cache.
    seconds : float
        Wall-clock time of the preparation (or of the cache read).
    """

    scene: Scene
    steps: int
    ke_ratio: float
    settled: bool
    from_cache: bool
    seconds: float


def cache_dir() -> Path:
    """The packing cache directory: ``$COCD_CACHE`` or ``~/.cache/cocd``."""
    env = os.environ.get("COCD_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "cocd"


def rain_deposition(
    scene: Scene,
    *,
    mu_prep: float = 0.0,
    dt: float | None = None,
    solver: str = "clarabel",
    tol: float = 1e-6,
    ke_threshold: float = 1e-6,
    max_steps: int = 3000,
    cache: bool = True,
) -> Deposition:
    """Let the grains of ``scene`` fall under gravity until they are at rest.

    Parameters
    ----------
    scene : Scene
        Initial placement (no overlaps), e.g. grains on a loose lattice above
        the container's floor. Not modified.
    mu_prep : float
        Friction coefficient (grain-grain and grain-wall) during deposition:
        0 gives a compact packing, > 0 a looser one.
    dt : float, optional
        Time step; default ``0.1 sqrt(d / g)`` with ``d`` the mean diameter.
    solver, tol : str, float
        Backend and tolerance of the deposition steps.
    ke_threshold : float
        Stop when ``Ek / (N m g d) < ke_threshold`` (N free grains, m their
        mean mass, d their mean diameter).
    max_steps : int
        Step cap; the result says whether the packing settled before it.
    cache : bool
        Read and write the on-disk cache (see :func:`cache_dir`).

    Returns
    -------
    Deposition
    """
    from cocd.stepper import Stepper

    if not (np.isfinite(mu_prep) and mu_prep >= 0.0):
        raise SceneError(f"mu_prep must be finite and >= 0, got {mu_prep}")
    if not (np.isfinite(ke_threshold) and ke_threshold > 0.0):
        raise SceneError(f"ke_threshold must be finite and > 0, got {ke_threshold}")
    if int(max_steps) < 1:
        raise SceneError(f"max_steps must be >= 1, got {max_steps}")
    g = float(np.linalg.norm(scene.gravity))
    if g == 0.0:
        raise SceneError("rain_deposition needs a non-zero gravity")
    free = scene.free
    if not free.any():
        raise SceneError("rain_deposition needs at least one free grain")
    d_mean = 2.0 * float(scene.radii[free].mean())
    if dt is None:
        dt = 0.1 * float(np.sqrt(d_mean / g))
    if not (np.isfinite(dt) and dt > 0.0):
        raise SceneError(f"dt must be finite and > 0, got {dt}")

    start = time.perf_counter()
    key = _cache_key(scene, mu_prep, dt, solver, tol, ke_threshold, int(max_steps))
    path = cache_dir() / f"packing-{key}.npz"
    if cache:
        cached = _read(path, key, scene)
        if cached is not None:
            settled_scene = _with_positions(scene, cached)
            return Deposition(settled_scene, 0, 0.0, True, True, time.perf_counter() - start)

    work = scene.copy()
    work.mu = float(mu_prep)
    work.mu_wall = float(mu_prep)
    # Walls that set their own friction keep it; deposition is about geometry.
    stepper = Stepper(work, dt, solver=solver, tol=tol, d_max=0.5 * d_mean, warm_start=True)
    scale = len(np.flatnonzero(free)) * float(work.masses[free].mean()) * g * d_mean
    ke_ratio = np.inf
    steps = 0
    while steps < int(max_steps):
        stepper.step()
        steps += 1
        ke_ratio = kinetic_energy(work) / scale
        if ke_ratio < ke_threshold:
            break
    settled = bool(ke_ratio < ke_threshold)
    positions = work.positions.copy()
    if cache:
        _write(path, key, positions, scene.radii)
    return Deposition(
        _with_positions(scene, positions),
        steps,
        float(ke_ratio),
        settled,
        False,
        time.perf_counter() - start,
    )


def packing_fraction(
    scene: Scene,
    lower: NDArray[np.float64] | tuple[float, ...],
    upper: NDArray[np.float64] | tuple[float, ...],
    *,
    samples: int = 200_000,
    seed: int = 0,
) -> float:
    """Solid fraction of the axis-aligned box ``[lower, upper]`` (area in 2D, volume in 3D).

    Estimated by Monte Carlo: the fraction of ``samples`` uniform points of the
    box that fall inside a grain (standard error about ``0.5 / sqrt(samples)``).

    Parameters
    ----------
    scene : Scene
    lower, upper : (d,) arrays
        Corners of the measuring box; keep it a few diameters away from walls
        and free surfaces to measure the bulk.
    """
    from scipy.spatial import KDTree

    lo = np.asarray(lower, dtype=np.float64)
    hi = np.asarray(upper, dtype=np.float64)
    if lo.shape != (scene.dim,) or hi.shape != (scene.dim,) or not np.all(hi > lo):
        raise SceneError(f"measuring box {lo.tolist()} to {hi.tolist()} is not a {scene.dim}D box")
    rng = np.random.default_rng(seed)
    points = lo + (hi - lo) * rng.random((int(samples), scene.dim))
    r_max = float(scene.radii.max())
    tree = KDTree(scene.positions)
    inside = np.zeros(len(points), dtype=bool)
    for k, near in enumerate(tree.query_ball_point(points, r_max)):
        if near:
            near_idx = np.asarray(near)
            dist = np.linalg.norm(scene.positions[near_idx] - points[k], axis=1)
            inside[k] = bool(np.any(dist <= scene.radii[near_idx]))
    return float(inside.mean())


# -- cache ------------------------------------------------------------------
def _cache_key(
    scene: Scene,
    mu_prep: float,
    dt: float,
    solver: str,
    tol: float,
    ke_threshold: float,
    max_steps: int,
) -> str:
    h = hashlib.sha256()
    h.update(f"format={_FORMAT}".encode())
    for a in (scene.positions, scene.radii, scene.density, scene.gravity):
        h.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
    h.update(scene.fixed.tobytes())
    for wall in scene.walls:
        h.update(wall.point.tobytes() + wall.normal.tobytes() + repr(wall.mu).encode())
    h.update(repr((mu_prep, dt, solver, tol, ke_threshold, max_steps)).encode())
    return h.hexdigest()[:32]


def _checksum(positions: FloatArray, radii: FloatArray) -> str:
    return hashlib.sha256(positions.tobytes() + radii.tobytes()).hexdigest()


def _read(path: Path, key: str, scene: Scene) -> FloatArray | None:
    """Positions stored under ``key``, or None if absent, unreadable or inconsistent."""
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            positions = np.array(data["positions"], dtype=np.float64)
            radii = np.array(data["radii"], dtype=np.float64)
            stored_key = str(data["key"])
            checksum = str(data["checksum"])
    except Exception:  # any unreadable file is rebuilt
        return None
    ok = (
        stored_key == key
        and positions.shape == scene.positions.shape
        and np.array_equal(radii, scene.radii)
        and bool(np.all(np.isfinite(positions)))
        and checksum == _checksum(positions, radii)
    )
    return positions if ok else None


def _write(path: Path, key: str, positions: FloatArray, radii: FloatArray) -> None:
    """Write atomically (temporary file then rename) so readers never see half a file."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".npz.tmp")
        with os.fdopen(fd, "wb") as f:
            np.savez(
                f,
                positions=positions,
                radii=radii,
                key=np.array(key),
                checksum=np.array(_checksum(positions, radii)),
            )
        os.replace(tmp, path)
    except OSError:  # a read-only cache only costs a rebuild next time
        pass


def _with_positions(scene: Scene, positions: FloatArray) -> Scene:
    out = scene.copy()
    out.positions = np.array(positions, dtype=np.float64)
    out.velocities[:] = 0.0
    out.angular_velocities[:] = 0.0
    out.time = 0.0
    return out
