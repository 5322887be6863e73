"""``cocd bench external``: every backend on every problem file of a folder.

Problems written by other tools (FCLib HDF5, Siconos text) are read
(:func:`cocd.io.read_problem`), turned into cocd's
:class:`~cocd.problem.ConicProblem` once (the conversion time is charged to
every backend alike) and solved by each backend that takes them, in a
:class:`~cocd.bench.runner.Worker` child (same clock, time limit, memory cap),
after one warm-up solve per backend and dimension. A backend with a local form
(``nscd``, ``pgs``: :mod:`solvers.local`) solves a local problem on its ``W``
instead, and a global one on its condensed ``W = H' M^-1 H``, as
:func:`cocd.external.solve_external` does, in a child of its own (same limits); its
conversion (the block CSR of ``W``, and a global problem's condensation) is its own
``setup_s``; a local-form solve under :data:`~cocd.bench.runner.SHORT_SOLVE_S` is run
again, up to :data:`~cocd.bench.runner.SHORT_SOLVE_REPEATS` runs, and its median
times kept. The Capsules files, whose ``W`` is not symmetric, have rows from
those backends only; the others say ``n/a`` and why.

Each answer is judged by the framework: ``ccp_residual`` (the convex problem
every convex backend solves) and ``natural_map_error`` (Coulomb's law in the
file's own terms, :func:`cocd.io.problems.natural_map_error`). Two
Dolan-Moré performance profiles follow, one per criterion: for each backend,
the fraction of problems it solved within a factor ``tau`` of the fastest
backend that solved them.
"""

from __future__ import annotations

import pickle
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from cocd.bench import DEFAULT_SOLVERS, estimate, select_solvers, study
from cocd.bench.metrics import table_profile
from cocd.bench.report import write_meta, write_table
from cocd.bench.runner import (
    SHORT_SOLVE_REPEATS,
    SHORT_SOLVE_S,
    Worker,
    default_memory_gb,
    warmup_problem,
)
from cocd.bench.study import StudySettings, option
from cocd.bench.worker import Worker as ChildWorker
from cocd.errors import CocdError, ProblemError
from cocd.external import RECORD_KEYS, not_applicable
from cocd.io.problems import GlobalProblem, LocalProblem

__all__ = ["COLUMNS", "EXTERNAL_SOLVERS", "SUFFIXES", "FileSolver", "run"]

#: Suffixes of the files taken from the folder.
SUFFIXES = (".hdf5", ".h5", ".dat")
#: The harness's set plus nscd finished by Newton, the non-convex fixed point and ECOS.
EXTERNAL_SOLVERS = [*DEFAULT_SOLVERS, "nscd:newton=True", "ecos", "fp:clarabel-dual"]
COLUMNS = [*RECORD_KEYS[:-1], "wall_s", "note"]


def _files(folder: Path) -> list[Path]:
    if not folder.is_dir():
        raise CocdError(f"{folder} is not a folder of problem files")
    files = sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in SUFFIXES)
    if not files:
        raise CocdError(f"{folder} holds no problem file ({', '.join(SUFFIXES)})")
    return files


def _usable(name: str) -> bool:
    import solvers as registry

    try:
        return registry.resolve(name)[0].unavailable_reason() is None
    except CocdError:
        return False


def _has_local_form(name: str) -> bool:
    import solvers as registry

    try:
        return registry.resolve(name)[0].local_entry is not None
    except CocdError:
        return False


_LOADED: dict[str, Any] = {}  # the local child's last problem, by path


def _local_job(
    emit: Any, path: str, solver: str, tol: float, time_limit: float, options: dict[str, Any]
) -> dict[str, Any]:
    """Local child: one row of the local form of ``solver`` (with ``options``, e.g.
    ``criterion``) on the problem pickled at ``path`` (kept loaded; a global problem
    condensed at every solve), judged as :func:`cocd.external.solve_external` judges."""
    from cocd.external import judge, local_form_data
    from solvers.local import solve_local

    if _LOADED.get("path") != path:
        _LOADED.clear()
        with open(path, "rb") as f:
            _LOADED.update(path=path, problem=pickle.load(f))
    problem = _LOADED["problem"]

    def once() -> tuple[Any, str, float, float, float]:
        start = time.perf_counter()
        data, note = local_form_data(problem)
        convert = time.perf_counter() - start
        sol = solve_local(data, solver, tol, time_limit=time_limit, **options)
        return sol, note, convert + sol.setup_time, sol.solve_time, time.perf_counter() - start

    sol, note, setup, solve, wall = once()
    runs = [(setup, solve, wall)]
    while wall < SHORT_SOLVE_S and len(runs) < SHORT_SOLVE_REPEATS:  # median of a short one
        runs.append(once()[2:])
    setup, solve, wall = (float(x) for x in np.median(np.array(runs), axis=0))
    row: dict[str, Any] = {
        "status": sol.status.value,
        "iterations": sol.iterations,
        "setup_s": setup,
        "solve_s": solve,
        "wall_s": wall,
        "note": note,
    }
    if np.all(np.isfinite(sol.p)):
        row.update(judge(problem, sol.p))
    return row


class _LocalForms:
    """Local forms run in a child of their own (:func:`_local_job`): each problem is
    pickled once, and each backend warmed up once per dimension on a tiny problem."""

    def __init__(self, memory_gb: float, folder: str) -> None:
        self.child = ChildWorker(memory_gb)
        self.folder = Path(folder)
        self.paths: dict[int, str] = {}
        self.held: list[LocalProblem | GlobalProblem] = []
        self.warmed: set[tuple[str, int]] = set()

    def _path(self, problem: LocalProblem | GlobalProblem) -> str:
        if id(problem) not in self.paths:
            path = self.folder / f"local-{len(self.paths)}.pkl"
            with open(path, "wb") as f:
                pickle.dump(problem, f, protocol=pickle.HIGHEST_PROTOCOL)
            self.paths[id(problem)] = str(path)
            self.held.append(problem)  # its id is not reused while it is held
        return self.paths[id(problem)]

    def solve_row(
        self,
        problem: LocalProblem | GlobalProblem,
        solver: str,
        tol: float,
        time_limit: float,
        options: dict[str, Any],
    ) -> dict[str, Any]:
        if (solver, problem.dim) not in self.warmed:
            tiny = GlobalProblem.from_conic(warmup_problem(problem.dim))
            for form in (tiny, tiny.local()):  # both paths compiled and imported
                self.child.run(
                    _local_job, self._path(form), solver, tol, 60.0, options, limit=300.0
                )
            self.warmed.add((solver, problem.dim))
        limit = 1.5 * time_limit + 30.0
        outcome = self.child.run(
            _local_job, self._path(problem), solver, tol, time_limit, options, limit=limit
        )
        if outcome.status == "done":
            return dict(outcome.result)
        return {"status": outcome.status, "note": outcome.note, "wall_s": outcome.elapsed}

    def close(self) -> None:
        self.child.close()


@dataclass(frozen=True)
class Settings(StudySettings):
    """The options of ``cocd bench external``."""

    folder: Path = study.problem_folder()
    solvers: str | None = study.solvers()
    tol: float = option(1e-8, "Tolerance asked of every solver.", positive=True)
    coulomb_target: float = option(
        1e-6, "natural_map_error counted as solving Coulomb.", positive=True
    )
    time_limit: float = study.time_limit(60.0)
    memory_gb: float | None = study.memory_gb()


def run(cfg: Settings, *, out: Path, progress: Callable[[str], None] = print) -> pd.DataFrame:
    """Solve every problem of ``folder`` with every backend; write the table and profiles."""
    from cocd.io import read_problem

    files = _files(Path(cfg.folder))
    names = cfg.solvers if cfg.solvers is not None else [n for n in EXTERNAL_SOLVERS if _usable(n)]
    memory = default_memory_gb() if cfg.memory_gb is None else float(cfg.memory_gb)
    problems: dict[Path, Any] = {}
    for path in files:
        try:
            problems[path] = read_problem(path)
        except CocdError as exc:
            problems[path] = exc
    estimate.announce(
        "external",
        # Size in grains: about two contacts per grain in these files.
        [
            (p.nc / 2, len(select_solvers(names, p.dim)))
            for p in problems.values()
            if not isinstance(p, CocdError)
        ],
        out=Path(out),
        progress=progress,
    )
    rows: list[dict[str, Any]] = []
    with FileSolver(memory) as solver:
        for path in files:
            rows += _file_rows(path, problems[path], cfg, names, solver, progress)
    table = pd.DataFrame(rows, columns=COLUMNS)
    _write(table, out, tol=cfg.tol, time_limit=cfg.time_limit, coulomb_target=cfg.coulomb_target)
    return table


class FileSolver:
    """cocd's backends on external problems, each row judged in the file's terms.

    A problem goes to a backend's local form when it has one (in a child of its own,
    :class:`_LocalForms`; a global problem condensed); otherwise its ConicProblem is built
    once (its conversion charged to every backend's ``setup_s``) and solved in a
    :class:`~cocd.bench.runner.Worker`. Each backend is warmed up once per
    dimension. Used by ``cocd bench external`` and ``cocd bench peers``.
    """

    def __init__(self, memory_gb: float) -> None:
        self._scratch = tempfile.TemporaryDirectory(prefix="cocd-external-")
        self.worker = Worker(memory_gb=memory_gb)
        self.local_forms = _LocalForms(memory_gb, self._scratch.name)
        self.warmed: set[tuple[str, int]] = set()
        self._conic: tuple[int, Any, float, str] | None = None  # id, conic, seconds, refusal

    def __enter__(self) -> FileSolver:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        try:
            self.local_forms.close()
            self.worker.close()
        finally:
            self._scratch.cleanup()

    def _conic_of(self, problem: Any) -> tuple[Any, float, str]:
        """The problem's ConicProblem (None when it has none), its conversion seconds and
        why not; kept for the last problem asked."""
        if self._conic is None or self._conic[0] != id(problem):
            start = time.perf_counter()
            try:
                conic, why = problem.conic, ""
            except ProblemError as exc:
                conic, why = None, str(exc).split(": ", 1)[-1]
            self._conic = (id(problem), conic, time.perf_counter() - start, why)
        return self._conic[1], self._conic[2], self._conic[3]

    def row(
        self,
        problem: Any,
        solver: str,
        tol: float,
        time_limit: float,
        local_options: dict[str, Any] | None = None,
    ) -> dict[str, Any]:
        """One backend on one problem: status, iterations, setup_s, solve_s, wall_s,
        ccp_residual, coulomb_residual, natural_map_error, note. ``local_options`` go
        to a local form (e.g. ``criterion``)."""
        if _has_local_form(solver):
            got = self.local_forms.solve_row(
                problem, solver, tol, time_limit, dict(local_options or {})
            )
            return {**got, "status": got.get("status", "error")}
        conic, convert, why = self._conic_of(problem)
        if conic is None:
            return {"status": "n/a", "note": not_applicable(problem, solver) or why}
        if (solver, problem.dim) not in self.warmed:
            self.worker.solve_row(warmup_problem(problem.dim), solver, tol, time_limit=60.0)
            self.warmed.add((solver, problem.dim))
        got = self.worker.solve_row(conic, solver, tol, time_limit=time_limit, keep_solution=True)
        row = {
            "status": got.get("status", "error"),
            "iterations": got.get("iterations", np.nan),
            "solve_s": got.get("solve_s", np.nan),
            "setup_s": convert + float(got.get("setup_s", np.nan)),
            "wall_s": convert + float(got.get("wall_s", np.nan)),
            "ccp_residual": got.get("ccp_residual", np.nan),
            "coulomb_residual": got.get("coulomb_residual", np.nan),
            "natural_map_error": np.nan,
            "note": got.get("note", "") or "",
        }
        p = got.get("p")
        if p is not None and np.all(np.isfinite(p)):
            row["natural_map_error"] = problem.natural_map_error(p)
        return row


def _file_rows(
    path: Path, problem: Any, cfg: Settings, names: Any, solver: FileSolver, progress: Any
) -> list[dict[str, Any]]:
    """The rows of one file: one per backend chosen for its dimension."""
    base: dict[str, Any] = {c: np.nan for c in COLUMNS}
    base.update(problem=path.name, note="")
    if isinstance(problem, CocdError):
        progress(f"{path.name}: unreadable: {problem}")
        return [{**base, "status": "unreadable", "note": str(problem)}]
    base.update(kind=problem.kind, dim=problem.dim, nc=problem.nc, ndof=problem.ndof)
    rows = []
    for name in select_solvers(names, problem.dim):
        row = {**base, "solver": name, **solver.row(problem, name, cfg.tol, cfg.time_limit)}
        rows.append(row)
        if row["status"] == "n/a":
            progress(f"{path.name:44s} {name:14s} n/a: {row['note']}")
            continue
        progress(
            f"{path.name:44s} {name:14s} {row['status']:10s} "
            f"ccp {row['ccp_residual']:.1e}  natural map "
            f"{row['natural_map_error']:.1e}  {row['wall_s']:.3f} s"
        )
    return rows


def _write(
    table: pd.DataFrame, out: Path, *, tol: float, time_limit: float, coulomb_target: float
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    title = "External problems (FCLib, Siconos): every backend on every file"
    intro = (
        f"tol {tol:g} asked of every backend, time limit {time_limit:g} s per solve. "
        "`setup_s` and `wall_s` include cocd's conversion of the file's problem "
        "(factorisation of M or W), the same for every backend on a problem. "
        "`ccp_residual`: the convex problem (DESIGN.md section 2); `natural_map_error`: "
        "Coulomb's law, unscaled natural map / max(1, ||q||). `n/a`: the backend does not "
        "take the problem (the note says why). `local form` (note): the backend solved the "
        "local problem on its W itself (solvers.local), its conversion in its own setup_s."
    )
    files = write_table(out, "external", table, title=title, intro=intro)

    answered = table["solver"].notna() & ~table["status"].isin(["n/a", "unreadable"])
    tab = table[answered]
    criteria = {
        f"convex problem: ccp_residual <= {tol:g}": tab["ccp_residual"] <= tol,
        f"Coulomb's law: natural_map_error <= {coulomb_target:g}": (
            tab["natural_map_error"] <= coulomb_target
        ),
    }
    taus = np.logspace(0, 4, 200)
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8), sharey=True)
    summary_rows = []
    for ax, (label, solved) in zip(axes, criteria.items(), strict=True):
        prof = table_profile(tab, solved, taus) if len(tab) else {}
        for solver, frac in sorted(prof.items()):
            ax.step(taus, frac, where="post", label=solver)
        ax.set_xscale("log")
        ax.set_xlabel("tau (time / fastest time on the problem)")
        ax.set_title(label, fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
        ax.set_ylim(-0.02, 1.02)
        for solver in sorted(prof):
            summary_rows.append(
                {
                    "criterion": label.split(":")[0],
                    "solver": solver,
                    "solved": int(solved[tab["solver"] == solver].sum()),
                    "fastest": float(prof[solver][0]),
                }
            )
    axes[0].set_ylabel("fraction of problems")
    axes[1].legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    png = out / "external_profiles.png"
    fig.savefig(png, dpi=120)
    plt.close(fig)
    files.append(png)
    n_problems = table["problem"].nunique()
    summary = pd.DataFrame(summary_rows)
    text = f"{n_problems} problem files. Problems solved and fraction fastest, per criterion:\n\n"
    if len(summary):
        text += summary.to_markdown(index=False, floatfmt=".2f")
    refused = table["status"].isin(["n/a", "unreadable"])
    taken = set(table.loc[~refused, "problem"])
    skipped = table[refused & ~table["problem"].isin(taken)].drop_duplicates("problem")
    if len(skipped):
        text += "\n\nNot solved by any backend: " + "; ".join(
            f"`{r.problem}` ({r.status}: {r.note})" for r in skipped.itertuples()
        )
    write_meta(out, "external", title=title, files=files, summary=text)


STUDY = study.register(
    study.Study(
        "external",
        "bench",
        Settings,
        run,
        help="Every backend on every problem file of FOLDER: table and performance profiles.",
        outputs=("external",),
    )
)
