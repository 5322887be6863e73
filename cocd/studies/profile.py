"""``cocd bench profile``: cProfile of one backend on one recorded Table 1 step.

The 2D column of N discs is stepped as ``cocd bench table1 --scale 1`` does
(from t = 0.11 s, its contact threshold, the same cache); step ``--step`` of
the :data:`STEPS` recorded is solved once to load the backend, then once under
:mod:`cProfile`. ``OUT/profile_<solver>.txt`` holds the backend's phase times
when it keeps them and the pstats listings by cumulative and own time; the
functions with the largest own time are printed. ``--detect`` also profiles
contact detection and assembly of the column as built (t = 0).
"""

from __future__ import annotations

import cProfile
import io
import pstats
import re
import time
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import pandas as pd

import solvers as backends
from cocd.bench import report, solver_names, study
from cocd.bench.states import record_steps
from cocd.bench.study import StudySettings, option
from cocd.builders import column_2d
from cocd.contacts import detect_contacts
from cocd.errors import CocdError
from cocd.problem import assemble
from cocd.residuals import ccp_residual
from cocd.studies import table1

__all__ = ["STEPS", "STUDY", "Settings", "run"]

#: Step problems recorded (``--step`` picks one).
STEPS = 10
#: Time (s) of the first recorded step: the Table 1 case's.
T_START = 0.11
#: Functions in the printed headline.
HEADLINE = 10
#: The backend's extras written beside its profile, when it has them.
EXTRAS = ("times", "factorisations", "linsolve", "system_nnz", "factor_nnz")


@dataclass(frozen=True)
class Settings(StudySettings):
    """The options of ``cocd bench profile``."""

    n: int = option(8308, "Discs in the 2D column.")
    solver: str = option("ipm", "Backend profiled.")
    tol: float = option(1e-8, "Tolerance asked of the backend.", positive=True)
    step: int = option(0, f"Which recorded step (0 to {STEPS - 1}).")
    top: int = option(25, "Functions listed per ordering.")
    trajectory: str = option("ipm", "Backend that steps the column.")
    detect: bool = option(False, "Also profile contact detection and assembly (t = 0).")


def _check(cfg: Settings) -> None:
    solver_names([cfg.solver, cfg.trajectory])  # unknown names fail here
    if int(cfg.n) != cfg.n or cfg.n < 2:
        raise CocdError(f"--n must be an integer >= 2, got {cfg.n!r}")
    if not 0 <= cfg.step < STEPS:
        raise CocdError(f"--step must be 0 to {STEPS - 1}, got {cfg.step}")
    if cfg.top < 1:
        raise CocdError(f"--top must be >= 1, got {cfg.top}")


def _listing(profiler: cProfile.Profile, top: int) -> str:
    """The pstats listings of ``profiler`` by cumulative and by own time."""
    parts = []
    for order in ("cumulative", "tottime"):
        text = io.StringIO()
        pstats.Stats(profiler, stream=text).sort_stats(order).print_stats(top)
        lines = [line for line in text.getvalue().splitlines() if line.strip()]
        parts.append(f"--- by {order} ---\n" + "\n".join(lines))
    return "\n".join(parts)


def _top(profiler: cProfile.Profile, top: int) -> pd.DataFrame:
    """The ``top`` functions by own time: function, calls, own and cumulative seconds."""
    stats: dict[Any, Any] = pstats.Stats(profiler).stats  # type: ignore[attr-defined]
    rows = [
        {
            "function": f"{Path(file).name}:{line}({name})",
            "calls": calls,
            "tottime_s": own,
            "cumtime_s": cumulative,
        }
        for (file, line, name), (_, calls, own, cumulative, _) in stats.items()
    ]
    table = pd.DataFrame(rows, columns=["function", "calls", "tottime_s", "cumtime_s"])
    return table.sort_values("tottime_s", ascending=False).head(top).reset_index(drop=True)


def _detect(make: Any, d_max: float, top: int) -> tuple[str, str]:
    """Detection and assembly of the column as built, timed then profiled."""
    scene = make()
    start = time.perf_counter()
    problem = assemble(scene, detect_contacts(scene, d_max), table1.DT_2D)
    wall = time.perf_counter() - start
    profiler = cProfile.Profile()
    profiler.enable()
    assemble(scene, detect_contacts(scene, d_max), table1.DT_2D)
    profiler.disable()
    line = f"detect+assemble at t = 0: Nc = {problem.nc}, wall {wall:.3f} s"
    return line, f"{line}\n{_listing(profiler, top)}"


def run(cfg: Settings, *, out: Path, progress: Any = print) -> pd.DataFrame:
    """Profile one solve; writes ``profile_<solver>.txt`` and returns its top functions."""
    _check(cfg)
    n = int(cfg.n)
    make = partial(column_2d, n)
    d_max = table1.D_SEED_2D * float(make().radii.mean())
    seq = record_steps(
        f"table1-column-2d-{n}",
        make,
        dt=table1.DT_2D,
        t_start=T_START,
        n_steps=STEPS,
        solver=cfg.trajectory,
        tol=table1.TRAJECTORY_TOL,
        d_max=d_max,
        progress=report.throttled(progress, 10.0),
    )
    problem = seq.problems[cfg.step]
    head: list[str] = []

    def say(line: str) -> None:
        head.append(line)
        progress(line)

    say(f"N = {seq.n_free}, Nc = {problem.nc}, unknowns {problem.ndof}, step {cfg.step}")
    backends.solve(problem, cfg.solver, tol=cfg.tol)  # load and compile
    start = time.perf_counter()
    sol = backends.solve(problem, cfg.solver, tol=cfg.tol)
    wall = time.perf_counter() - start
    say(
        f"{cfg.solver}: {sol.status.value}, {sol.iterations} iterations, wall {wall:.3f} s, "
        f"ccp_residual {ccp_residual(problem, sol.p):.2e}"
    )
    for key in EXTRAS:
        if key in sol.extras:
            value = sol.extras[key]
            if isinstance(value, dict):
                value = ", ".join(f"{k} {v:.3f}" for k, v in value.items())
            say(f"  {key}: {value}")
    profiler = cProfile.Profile()
    profiler.enable()
    backends.solve(problem, cfg.solver, tol=cfg.tol)
    profiler.disable()
    text = "\n".join(head) + "\n" + _listing(profiler, cfg.top) + "\n"
    if cfg.detect:
        summary, listing = _detect(make, d_max, cfg.top)
        say(summary)
        text += "\n" + listing + "\n"
    table = _top(profiler, cfg.top)
    shown = table.head(HEADLINE)
    total = pstats.Stats(profiler).total_tt  # type: ignore[attr-defined]
    progress(f"by own time (of {total:.3f} s profiled):")
    for r in shown.itertuples():
        progress(f"  {r.tottime_s:8.3f} s own {r.cumtime_s:8.3f} s cum  {r.function}")
    name = "profile_" + re.sub(r"[^\w.-]", "_", cfg.solver)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{name}.txt"
    path.write_text(text)
    title = f"cProfile of {cfg.solver} on one step of a {seq.n_free}-disc column"
    summary = "\n".join(
        ["```text", *head, "```", "", shown.to_markdown(index=False, floatfmt=".3g")]
    )
    report.write_meta(out, name, title=title, files=[path], summary=summary)
    return table


STUDY = study.register(
    study.Study(
        "profile",
        "bench",
        Settings,
        run,
        outputs=("profile_<solver>",),
        help="cProfile of one backend on one recorded Table 1 step of the 2D column.",
    )
)
