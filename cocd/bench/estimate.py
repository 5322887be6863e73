"""How long a harness command will take, said before it starts its solves.

Each command describes the solves it is about to make as ``(N, count)`` pairs:
``count`` solves of a problem of ``N`` grains. Their *work* is
``sum(count * ((N / 1000) ** EXPONENT + PER_SOLVE))``: the exponent is a middle
value of the fits of time per step against N in ``results/scaling`` (1.1 to
1.5 by backend and packing), and ``PER_SOLVE`` what every solve costs however
small (setting it up, checking its residuals). The time is the work times a
rate in seconds per unit:

- the rate of the last finished run of the same command, when ``OUT`` or
  ``./results`` holds its ``<name>.meta.json`` (every command records its
  ``elapsed_s`` and ``work_units`` there, see :func:`record`);
- otherwise :data:`RATES`, measured on a 2-core machine with the command
  each entry names.

The figure is a guide, not a promise: solver iterations change with the
packing and the tolerance, so it can be off by a factor of a few.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

__all__ = [
    "EXPONENT",
    "PER_SOLVE",
    "RATES",
    "announce",
    "format_seconds",
    "kept",
    "made",
    "record",
    "work",
]

#: Time per solve grows as N ** EXPONENT.
EXPONENT = 1.4
#: Work of a solve besides its size: the cost of a tiny one, in units of a
#: 1000-grain solve (fitted with the rates below on small and large problems).
PER_SOLVE = 0.1

#: Seconds per work unit of each command with its default backends: elapsed_s /
#: work_units of the meta.json of the command after each entry, on a 2-core AMD
#: EPYC that was running a second benchmark at the time (so they lean long).
RATES: dict[str, float] = {
    "table1": 3.0,  # cocd bench table1 --scale 0.02 --scale-3d 0.002 --steps 3
    "stability": 11.3,  # cocd bench stability --n 200 --t-end 1 --eps-list 1e-2,1e-6
    "precision": 1.13,  # cocd bench precision --n2d 300 --n3d 150 --tols 1e-3,1e-6
    "hard": 0.94,  # cocd bench hard --steps 2
    "external": 0.92,  # cocd bench external <shared external problems> --time-limit 20
    # Siconos's solves add a child Python each and some run to the time limit:
    "peers": 16.5,  # cocd bench peers <Capsules-i125, spheres-in-a-box> --solvers nscd --tols 1e-8
    "scaling": 1.47,  # cocd bench scaling --n2d 300 --n3d 300 --packings column,jammed_box
    "timestep": 0.27,  # cocd validate timestep --n 100 --dts 1e-3,5e-4 --times 0.02,0.06
    "nscd": 0.25,  # cocd validate nscd --n 100 --times 1,2
    # Solve seconds per unit of thirteen 4000-step runs of cocd validate erodible --n 2000
    # --slopes 16,19,22 --seeds 3 --workers 2 (0.065 to 0.113 by run), rounded up for
    # their frames and measurement. At 100 discs (--until 0.3) the rate is 0.70: fixed
    # costs dominate there, and the estimate leans low.
    "erodible": 0.08,
    "avalanche": 0.067,  # cocd validate avalanche --n 100 --mus 0.4
    # Per worker, packings read from the cache: cocd validate avalanche3d --mus
    # 0.2,0.28,0.4 --seeds 3 --workers 2, its last two sequences (848 s, 54 962 units).
    "avalanche3d": 0.031,
    # Per step of cocd validate flume --slopes 0 (35 087 free spheres, apgd at tol 1e-5,
    # one run on 2 cores), steps 18 to 90: 33.3 s for 145.7 units.
    "flume": 0.23,
}
#: Rate for a command without an entry (runout_scaling, stability_threshold): 2D
#: collapse runs of 100 discs (cocd validate erodible --n 100 --until 0.3).
DEFAULT_RATE = 0.7

_current: dict[str, Any] = {}


def work(solves: Iterable[tuple[float, float]]) -> float:
    """``sum(count * ((N / 1000) ** EXPONENT + PER_SOLVE))`` over ``(N, count)`` pairs."""
    return float(
        sum(c * ((max(float(n), 1.0) / 1000.0) ** EXPONENT + PER_SOLVE) for n, c in solves)
    )


def format_seconds(seconds: float) -> str:
    """``40 s``, ``12 min``, ``3.5 h``."""
    if not math.isfinite(seconds):
        return "unknown"
    if seconds < 90:
        return f"{max(1, round(seconds))} s"
    if seconds < 90 * 60:
        return f"{round(seconds / 60)} min"
    return f"{seconds / 3600:.1f} h"


def announce(
    name: str,
    solves: Iterable[tuple[float, float]],
    *,
    out: Path,
    progress: Callable[[str], None] = print,
    workers: int = 1,
) -> float:
    """Print the expected run time of command ``name`` and start its clock.

    Parameters
    ----------
    name : str
        The command's record name (``<name>.meta.json``).
    solves : iterable of (N, count)
        The solves to come: ``count`` problems of ``N`` grains each.
    out : Path
        The command's output folder (where an earlier record may be).
    progress : callable
        Receives the line.
    workers : int
        Solves made that many at once (``cocd validate --workers``): the time is
        divided by it, and rates are kept per worker.

    Returns
    -------
    float
        The expected seconds.
    """
    pairs = [(float(n), float(c)) for n, c in solves if c > 0]
    units = work(pairs)
    _current.clear()
    workers = max(1, int(workers))
    _current.update(name=name, start=time.perf_counter(), work=units, workers=workers)
    count = int(sum(c for _, c in pairs))
    largest = int(max((n for n, _ in pairs), default=0))
    rate, source = _rate(name, Path(out))
    seconds = rate * units / workers
    _current["seconds"] = seconds
    line = (
        f"{name}: {count} solve{'' if count == 1 else 's'}, the largest of {largest} grains; "
        "expected "
        f"{format_seconds(seconds)} ({source}; a guide, it can be off by a factor of a few)"
    )
    progress(line)
    return seconds


def kept(
    fraction: float,
    what: str,
    progress: Callable[[str], None] = print,
    *,
    measured: tuple[float, float] | None = None,
    runs: int | None = None,
) -> None:
    """Part of the announced work is already done and kept (runs read back): say how
    long the other ``fraction`` of it should take, after ``what`` (e.g. ``6 of 27 runs
    kept``).

    ``measured``: ``(seconds, work units)`` of the rest, timed at the rate of the kept
    runs made as they will be (same backend, tolerance and dimension), in one worker's
    solve seconds (detection, set-up and solve, steps taken again included; the rest
    of a run, writing frames and measuring them, is left out, so the figure leans low
    on small problems). When given, the rest is timed at that rate, the command's own
    on this problem size, rather than at the announced one. ``runs``: how many runs are
    left; fewer than the workers keep only that many busy.
    """
    if _current.get("seconds") is None:
        return
    rest = min(max(fraction, 0.0), 1.0)
    if rest == 0.0:  # the announced time was for work already done
        progress(f"{_current['name']}: {what}; nothing is left to solve")
        return
    workers = _current["workers"]
    busy = workers if runs is None else max(1, min(workers, int(runs)))
    seconds, units = measured if measured is not None else (0.0, 0.0)
    if seconds > 0 and units > 0 and math.isfinite(seconds / units):
        rest_s = seconds / units * _current["work"] * rest / busy
        source = " (at the kept runs' rate)"
    else:
        rest_s, source = _current["seconds"] * rest * workers / busy, ""
    progress(f"{_current['name']}: {what}; the rest should take {format_seconds(rest_s)}{source}")


def made(n: float, count: float) -> None:
    """``count`` solves of ``N`` grains were made. A command that reports what it made
    (the validation cases, whose runs may be read back from kept results or resumed)
    records that work instead of the work it announced, so that the rate it gives the
    next estimate is that of the solves made (none made: no rate)."""
    if _current:
        _current["made"] = _current.get("made", 0.0) + (work([(n, count)]) if count > 0 else 0.0)


def record() -> dict[str, float]:
    """``elapsed_s`` and ``work_units`` of the command announced last, for its meta.json."""
    if not _current:
        return {}
    return {
        "elapsed_s": round(time.perf_counter() - _current["start"], 1),
        "work_units": round(_current.get("made", _current["work"]), 6),
        "workers": _current.get("workers", 1),
    }


def _rate(name: str, out: Path) -> tuple[float, str]:
    for folder in dict.fromkeys([out, Path("results"), Path("results") / "validation"]):
        path = folder / f"{name}.meta.json"
        try:
            meta = json.loads(path.read_text())
            elapsed, units = float(meta["elapsed_s"]), float(meta["work_units"])
            elapsed *= max(1, int(meta.get("workers", 1)))  # seconds of one worker
        except (OSError, ValueError, KeyError, TypeError):
            continue
        if units > 0 and elapsed > 0 and math.isfinite(elapsed / units):
            return elapsed / units, f"scaled from the run recorded in {path}"
    return RATES.get(name, DEFAULT_RATE), "from timings on a 2-core machine"
