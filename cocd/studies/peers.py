"""``cocd bench peers DIR --peer siconos``: another project's solvers beside cocd's backends.

Every problem file of a folder (FCLib HDF5, Siconos text) is solved by cocd's
backends (as ``cocd bench external`` does, :class:`~cocd.studies.external.FileSolver`:
the backends with a local form on ``W`` itself, a global problem's condensed, and
stopping on the natural-map error, as the peer's solvers stop on theirs; the others
on the problem converted once; each in a child after a warm-up) and
by the peer's solvers (:mod:`cocd.peers`: Siconos in a child process under its
own Python), each at every tolerance of ``--tols``, with the same time limit.
Every answer is judged by cocd with the same function,
:meth:`natural_map_error` of the problem as read (Coulomb's law in the file's
own terms), whoever computed it.

Per file, the *target* is the best natural-map error any peer solver reaches
(raised to ``--target-floor``, below which errors are the rounding of the
data), and each side's *time to target* the least ``setup_s + solve_s`` over
its runs that reach it: for cocd, its conversion of the file (the factorisation
of ``W`` or ``M``) plus the backend's set-up and solve; for the peer, the
driver call plus, for a global problem solved in condensed form, cocd's
condensation. ``peers_summary`` gives per file the target and both sides' best
solver and time, their ratio, and the geometric mean of the ratios;
``peers_profile.png`` the Dolan-Moré performance profile of every solver of
both sides in time to target. Rows are kept in ``peers.csv`` as they finish and
``--resume`` solves only the (problem, solver, tol) it lacks.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pandas as pd

from cocd import peers
from cocd.bench import estimate, select_solvers, solver_names, study
from cocd.bench.results import Results
from cocd.bench.runner import default_memory_gb
from cocd.bench.study import StudySettings, option
from cocd.errors import CocdError
from cocd.studies._peers_report import write_report
from cocd.studies.external import FileSolver, _files, _usable

__all__ = ["COCD_SOLVERS", "COLUMNS", "STUDY", "Settings", "run"]

COLUMNS = [
    "problem",
    "kind",
    "dim",
    "nc",
    "side",
    "solver",
    "tol",
    "status",
    "iterations",
    "setup_s",
    "solve_s",
    "wall_s",
    "natural_map_error",
    "coulomb_residual",
    "note",
]
#: cocd's backends when none are named (those installed): the non-convex ones,
#: which solve Coulomb's law, and the fast convex ones, which solve it where
#: contacts stick or separate.
COCD_SOLVERS = [
    "nscd",
    "nscd:newton=True",
    "pgs",
    "apgd",
    "ipm",
    "clarabel",
    "clarabel-dual",
    "scs-dual",
    "fp:clarabel-dual",
]
NO_SOLVERS = ("none", "-")
#: A local form stops on the error both sides are judged by, as the peer's solvers do.
LOCAL_OPTIONS = {"criterion": "natural_map"}


@dataclass(frozen=True)
class Settings(StudySettings):
    """The options of ``cocd bench peers``."""

    folder: Path = study.problem_folder()
    peer: str = option("siconos", "The project whose solvers run beside cocd's (siconos).")
    solvers: str | None = study.solvers(
        help="cocd backends, comma-separated, or `none` (default: "
        + ",".join(COCD_SOLVERS)
        + ", those installed)."
    )
    peer_solvers: str | None = option(
        None,
        "Peer solvers, comma-separated: NSGS,NSN_AC,... (the `siconos:` prefix optional; "
        "NAME(condensed) runs a local solver on a global problem's condensed form; "
        "default: the usual ones of each family).",
    )
    tols: tuple[float, ...] = option(
        (1e-4, 1e-6, 1e-8, 1e-10, 1e-12),
        "Tolerances asked of every solver, both sides.",
        kind="floats",
    )
    time_limit: float = study.time_limit(60.0)
    peer_max_iter: int = option(20_000, "Iterations allowed to a peer solver.")
    target_floor: float = option(
        1e-12, "Natural-map errors at or below this reach any target (0: none)."
    )
    memory_gb: float | None = study.memory_gb()
    resume: bool = study.resume("peers")


def _check(cfg: Settings) -> list[float]:
    tols = [float(t) for t in cfg.tols]
    if not tols or not all(math.isfinite(t) and t > 0 for t in tols):
        raise CocdError(f"--tols must be finite numbers > 0, got {list(cfg.tols)!r}")
    if cfg.peer_max_iter < 1:
        raise CocdError(f"--peer-max-iter must be >= 1, got {cfg.peer_max_iter}")
    if not (math.isfinite(cfg.target_floor) and cfg.target_floor >= 0):
        raise CocdError(f"--target-floor must be a number >= 0, got {cfg.target_floor!r}")
    return list(dict.fromkeys(tols))


def _cocd_names(text: str | None) -> list[str]:
    if text is None:
        return [n for n in COCD_SOLVERS if _usable(n)]
    if text.strip().lower() in (*NO_SOLVERS, ""):
        return []
    return solver_names(text)  # unknown names fail here


def _peer_names(peer: ModuleType, text: str | None) -> list[str] | None:
    if text is None:
        return None
    names = [w.strip() for w in text.split(",") if w.strip()]
    if not names:
        raise CocdError("--peer-solvers is empty: name at least one, e.g. NSGS")
    for name in names:
        peer.parse(name)  # unknown names fail here
    return names


@dataclass
class _File:
    """One problem file and what is left to solve on it."""

    path: Path
    problem: Any
    cocd: list[str]
    peer: list[str]
    todo: int = 0


def run(cfg: Settings, *, out: Path, progress: Callable[[str], None] = print) -> pd.DataFrame:
    """Solve every file of ``folder`` with cocd's backends and the peer's solvers at every
    tolerance; write ``peers.csv``, ``peers_summary`` and ``peers_profile.png``."""
    tols = _check(cfg)
    peer = peers.get(cfg.peer)
    side = cfg.peer.strip().lower()
    names = _cocd_names(cfg.solvers)
    paths = _files(Path(cfg.folder))
    out = Path(out)
    # An unreadable file is said again by every run, not resumed.
    table = Results(
        out / "peers.csv", COLUMNS, resume=cfg.resume, keep=lambda r: r["status"] != "unreadable"
    )
    reason = peer.peer_unavailable_reason()
    peer_names: list[str] | None = None
    if reason is not None:
        if not names:
            raise CocdError(f"{reason}; and no cocd backend is asked (--solvers none)")
        progress(f"{reason}; running cocd's side only.")
    else:
        peer_names = _peer_names(peer, cfg.peer_solvers)
    from cocd.io import read_problem

    files: list[_File] = []
    for path in paths:
        try:
            problem: Any = read_problem(path)
        except CocdError as exc:
            problem = exc
        cocd_names: list[str] = []
        peer_list: list[str] = []
        if not isinstance(problem, CocdError):
            cocd_names = select_solvers(names, problem.dim) if names else []
            if reason is None:
                peer_list = peer.solvers_for(problem, peer_names)
        entry = _File(path, problem, cocd_names, peer_list)
        entry.todo = sum(
            not table.has(path.name, s, t) for s in [*cocd_names, *peer_list] for t in tols
        )
        files.append(entry)
    if table.resumed:
        progress(f"{table.resumed} rows kept from {table.path}")
    estimate.announce(
        "peers",
        [
            (f.problem.nc / 2, f.todo)  # about two contacts per grain in these files
            for f in files
            if not isinstance(f.problem, CocdError)
        ],
        out=out,
        progress=progress,
    )
    memory = default_memory_gb() if cfg.memory_gb is None else float(cfg.memory_gb)
    unreadable: list[dict[str, Any]] = []
    with FileSolver(memory) as solver:
        for f in files:
            if isinstance(f.problem, CocdError):
                row = {"problem": f.path.name, "status": "unreadable", "note": str(f.problem)}
                unreadable.append({c: row.get(c, np.nan) for c in COLUMNS})
                progress(f"{f.path.name}: unreadable: {f.problem}")
                continue
            if f.todo == 0:
                continue
            base = {
                "problem": f.path.name,
                "kind": f.problem.kind,
                "dim": f.problem.dim,
                "nc": f.problem.nc,
                "note": "",
            }
            _cocd_side(f, base, tols, cfg, table, solver, progress)
            _peer_side(f, base, tols, cfg, table, peer, side, memory, progress)
    frame = table.frame()
    if unreadable:
        frame = pd.concat([frame, pd.DataFrame(unreadable, columns=COLUMNS)], ignore_index=True)
    write_report(
        out,
        frame,
        peer=side,
        tols=tols,
        time_limit=cfg.time_limit,
        floor=cfg.target_floor,
        peer_note=reason,
    )
    return frame


def _say(progress: Callable[[str], None], row: dict[str, Any]) -> None:
    seconds = row["setup_s"] + row["solve_s"]
    progress(
        f"{row['problem']:42s} {row['side']:8s} {row['solver']:26s} tol {row['tol']:.0e} "
        f"{row['status']:10s} natural map {row['natural_map_error']:.1e}  {seconds:.3g} s"
    )


def _cocd_side(
    f: _File,
    base: dict[str, Any],
    tols: list[float],
    cfg: Settings,
    table: Results,
    solver: FileSolver,
    progress: Callable[[str], None],
) -> None:
    """cocd's backends on the file, as ``cocd bench external`` runs them (local forms on
    ``W`` itself, the others on the ConicProblem); each answer judged in the file's terms."""
    for name, tol in [(s, t) for s in f.cocd for t in tols if not table.has(f.path.name, s, t)]:
        got = solver.row(f.problem, name, tol, cfg.time_limit, LOCAL_OPTIONS)
        row = {**base, "side": "cocd", "solver": name, "tol": tol, **got}
        table.add(row)
        if row["status"] != "n/a":
            _say(progress, {c: row.get(c, np.nan) for c in COLUMNS})


def _peer_side(
    f: _File,
    base: dict[str, Any],
    tols: list[float],
    cfg: Settings,
    table: Results,
    peer: ModuleType,
    side: str,
    memory: float,
    progress: Callable[[str], None],
) -> None:
    todo = [(s, t) for s in f.peer for t in tols if not table.has(f.path.name, s, t)]
    condensed = None
    for solver, tol in todo:
        if solver.endswith(peer.CONDENSED) and condensed is None:
            condensed = peer.condense(f.problem)  # once per file: the same cost for every run
        rec = peer.solve(
            f.problem,
            solver,
            tol,
            time_limit=cfg.time_limit,
            max_iter=cfg.peer_max_iter,
            memory_gb=memory,
            condensed=condensed,
        )
        row = {**base, **{k: rec[k] for k in COLUMNS if k in rec}, "side": side, "tol": tol}
        table.add(row)
        _say(progress, row)


STUDY = study.register(
    study.Study(
        "peers",
        "bench",
        Settings,
        run,
        help="cocd's backends beside another project's solvers (Siconos) on every problem "
        "file of FOLDER, judged by cocd's natural-map error: time to the peer's best error.",
        outputs=("peers", "peers_summary"),
    )
)
