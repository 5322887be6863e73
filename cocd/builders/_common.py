"""What the builders share: sizes, radii, lattices, walls, and the checks of their arguments."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from cocd.checks import positive_number
from cocd.errors import SceneError
from cocd.packing import rain_deposition
from cocd.resources import BYTES_PER_GRAIN, check_fits
from cocd.scene import Scene, Wall

FloatArray = NDArray[np.float64]
G = 9.81
#: Solid fractions used to size a packing from its grain count (or the reverse):
#: frictionless rain deposition of 10 %-polydisperse grains.
RAIN_FRACTION = {2: 0.84, 3: 0.63}


def check_dim(dim: int) -> int:
    if dim not in (2, 3):
        raise SceneError(f"dim must be 2 or 3, got {dim!r}")
    return int(dim)


def check_count(name: str, value: int | None) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise SceneError(f"{name} must be an integer >= 1, got {value!r}")
    check_fits(int(value) * BYTES_PER_GRAIN, f"a scene of {int(value)} grains ({name})")
    return int(value)


def _derived_count(count: float, diameter: float) -> int:
    """The grain count a diameter implies, checked like a given one."""
    if not np.isfinite(count) or count > 1e15:
        raise SceneError(f"diameter {diameter:g} m gives {count:.3g} grains: far too many")
    return check_count(f"grains for diameter {diameter:g} m", max(1, round(count)))


def check_polydispersity(value: float) -> float:
    if not (np.isfinite(value) and 0.0 <= value < 1.0):
        raise SceneError(f"polydispersity must be in [0, 1), got {value}")
    return float(value)


def uniform_radii(n: int, d_mean: float, poly: float, rng: np.random.Generator) -> FloatArray:
    """Radii uniform in ``r (1 -+ poly / 2)``, rescaled so their mean is exactly ``d_mean / 2``."""
    u = 1.0 + poly * (rng.random(n) - 0.5)
    return np.asarray(0.5 * d_mean * u / u.mean(), dtype=np.float64)


def radii_up_to(r_max: float, poly: float, n: int, rng: np.random.Generator) -> FloatArray:
    """Radii uniform in ``r (1 -+ poly / 2)`` with ``r (1 + poly / 2) = r_max``."""
    return np.asarray(r_max / (1.0 + poly / 2.0) * (1.0 + poly * (rng.random(n) - 0.5)))


def mean_grain_volume(dim: int, d_mean: float, poly: float) -> float:
    """Mean grain area (2D) or volume (3D) for radii uniform in ``r (1 -+ poly / 2)``."""
    r = d_mean / 2.0
    if dim == 2:
        return float(np.pi * r**2 * (1.0 + poly**2 / 12.0))
    return float(4.0 / 3.0 * np.pi * r**3 * (1.0 + poly**2 / 4.0))


def _one_of(n_grains: int | None, diameter: float | None) -> None:
    if (n_grains is None) == (diameter is None):
        raise SceneError(
            f"give exactly one of n_grains and diameter, got n_grains={n_grains!r}, "
            f"diameter={diameter!r}"
        )


def lattice_size(
    dim: int, n_grains: int | None, diameter: float | None, volume: float, poly: float
) -> tuple[int, float]:
    """Grain count and mean diameter of a loose lattice filling ``volume``."""
    _one_of(n_grains, diameter)
    cell = np.sqrt(3.0) / 2.0 if dim == 2 else 1.0  # site volume / spacing^d
    ratio = 1.02 * (1.0 + poly / 2.0)  # spacing / mean diameter
    if n_grains is not None:
        n = check_count("n_grains", n_grains)
        spacing = (volume / (n * cell)) ** (1.0 / dim)
        return n, float(spacing / ratio)
    d = positive_number(diameter, "diameter")
    with np.errstate(divide="ignore", over="ignore"):
        n = _derived_count(volume / (cell * (ratio * d) ** dim), d)
    return n, d


def rain_size(
    dim: int, n_grains: int | None, diameter: float | None, volume: float, poly: float
) -> tuple[int, float]:
    """Grain count and mean diameter of a settled rain packing filling ``volume``."""
    _one_of(n_grains, diameter)
    unit = mean_grain_volume(dim, 1.0, poly)  # grain volume for a unit mean diameter
    if n_grains is not None:
        n = check_count("n_grains", n_grains)
        return n, float((RAIN_FRACTION[dim] * volume / (n * unit)) ** (1.0 / dim))
    d = positive_number(diameter, "diameter")
    with np.errstate(divide="ignore", over="ignore"):
        return _derived_count(RAIN_FRACTION[dim] * volume / (unit * d**dim), d), d


def lattice_sites(
    dim: int,
    n: int | None,
    horizontal: FloatArray,
    base: float,
    spacing: float,
    thickness: float | None,
    rng: np.random.Generator,
) -> FloatArray:
    """Sites of a lattice over ``[0, horizontal]`` from height ``base``, shape ``(n, dim)``.

    Hexagonal rows in 2D, cubic in 3D. Either ``n`` sites (rows filled in
    turn) or every site whose grain lies within ``thickness`` of ``base``.
    """
    del rng  # the lattice is regular; kept for a uniform signature
    row_h = spacing * (np.sqrt(3.0) / 2.0 if dim == 2 else 1.0)
    counts = [max(1, int(np.floor(h / spacing))) for h in horizontal]
    if dim == 2:
        counts[0] = max(1, int(np.floor(horizontal[0] / spacing - 0.5)))
    per_row = int(np.prod(counts))
    if n is None:
        assert thickness is not None
        rows = max(1, int(np.floor((thickness - spacing) / row_h)) + 1)
        n = rows * per_row
    k = np.arange(n)
    row = k // per_row
    within = k % per_row
    coords = []
    for c in counts:
        coords.append((within % c + 0.5) * spacing)
        within = within // c
    if dim == 2:
        coords[0] = coords[0] + np.where(row % 2 == 1, spacing / 2.0, 0.0)
    coords.append(base + spacing / 2.0 + row * row_h)
    return np.stack(coords, axis=1)


def loose_lattice(
    dim: int, n: int, horizontal: FloatArray, base: float, r_max: float, rng: np.random.Generator
) -> FloatArray:
    """``n`` sites of a square/cubic lattice 10 % looser than the largest grain, jittered.

    The jitter is small enough that no two grains (or grain and wall) can
    touch; it breaks the lattice's symmetry so that the rain packs randomly.
    """
    spacing = 2.2 * r_max
    counts = [max(1, int(np.floor(h / spacing))) for h in horizontal]
    per_layer = int(np.prod(counts))
    k = np.arange(n)
    layer, within = k // per_layer, k % per_layer
    coords = []
    for c in counts:
        coords.append((within % c + 0.5) * spacing)
        within = within // c
    coords.append(base + (layer + 0.5) * spacing)
    x = np.stack(coords, axis=1)
    amplitude = 0.45 * (spacing - 2.0 * r_max) / (2.0 * np.sqrt(dim))
    return np.asarray(x + rng.uniform(-amplitude, amplitude, x.shape), dtype=np.float64)


def bed_grains(dim: int, d: float, bed_len: float, chan: float) -> FloatArray:
    """Centres of touching grains of diameter ``d`` on the floor over the bed."""
    xs = (np.arange(max(1, int(np.floor(bed_len / d)))) + 0.5) * d
    if dim == 2:
        return np.stack([xs, np.full(xs.size, d / 2.0)], axis=1)
    ys = (np.arange(max(1, int(np.floor(chan / d)))) + 0.5) * d
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    return np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, d / 2.0)], axis=1)


def deposit(
    parts_x: list[FloatArray],
    parts_r: list[FloatArray],
    n_fixed: int,
    walls: list[Wall],
    scene_kw: dict[str, float | None],
    mu_prep: float,
    solver: str | None,
    cache: bool,
) -> FloatArray:
    """Settle the grains (the first ``n_fixed`` glued) under vertical gravity; new positions."""
    x = np.concatenate(parts_x)
    r = np.concatenate(parts_r)
    fixed = np.zeros(len(r), dtype=bool)
    fixed[:n_fixed] = True
    scene = Scene(x, r, fixed=fixed, walls=walls, **scene_kw)  # type: ignore[arg-type]
    if solver is None:
        solver = "clarabel" if scene.dim == 2 else "scs-dual"
    result = rain_deposition(scene, mu_prep=mu_prep, solver=solver, cache=cache)
    return result.scene.positions


def box_walls(dim: int, box: float | FloatArray) -> list[Wall]:
    """A floor and side walls at 0 and ``box`` along every horizontal axis (``box``: one
    size for all, or one per horizontal axis)."""
    sizes = np.broadcast_to(np.asarray(box, dtype=float), (dim - 1,))
    walls = [floor_wall(dim)]
    for axis in range(dim - 1):
        e = np.eye(dim)[axis]
        walls += [Wall(np.zeros(dim), e), Wall(sizes[axis] * e, -e)]
    return walls


def floor_wall(dim: int) -> Wall:
    up = np.zeros(dim)
    up[-1] = 1.0
    return Wall(np.zeros(dim), up)


def set_groups(scene: Scene, groups: dict[str, slice]) -> None:
    scene.groups = dict(groups)
