"""Sweeps: grids of short runs (scene x size x solver x tolerance x time step) on Dask.

A sweep file (TOML) declares the scenes and the axes of the grid::

    name = "solvers-vs-tol"
    steps = 20                     # steps per cell (or: until = 0.05)

    [scenes.column]                # one table per scene: a builder and its arguments
    builder = "column_2d"
    params = { n_grains = 100 }

    [scenes.box]
    builder = "box_3d"
    params = { n_grains = 200 }

    [grid]                         # every combination is one cell
    scene = ["column", "box"]
    solver = ["clarabel", "ipm"]
    tol = [1e-6, 1e-8]
    dt = [1e-3]
    "params.mu" = [0.3, 0.5]       # any builder argument, e.g. the size

Each cell runs its scene for ``steps`` steps and writes one Parquet file,
``cells/<id>.parquet`` (a single row: the cell's coordinates, then what the run
measured: contacts, iterations, solve times, residuals, final energy, and a
checksum of the final positions); ``<id>`` is a hash of the cell's resolved
specification, so a cell's file names what was run. A file is written under a
temporary name and renamed when complete: a cell is either there whole or not
at all, and a rerun of the sweep skips the cells whose file exists (a finished
sweep does no work). A cell whose run fails is a row with ``status = "error"``
and the message.

Cells run as tasks of a ``dask.distributed`` cluster: by default a local
cluster of worker processes (``workers``), else an existing cluster
(``scheduler`` address). A worker that dies has its task run again elsewhere
(Dask's own retry); since a cell's file is written atomically and named by the
cell, each cell is present exactly once whatever happens.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
import re
import time
import uuid
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd
import pydantic
import tomllib
from pydantic import BaseModel, ConfigDict, Field, field_validator

from cocd.checks import first_repeat
from cocd.config import ConfigError, known_builder, parse_config
from cocd.errors import CocdError

__all__ = [
    "Cell",
    "SweepSpec",
    "SweepSummary",
    "aggregate",
    "cells_of",
    "load_sweep",
    "run_cell",
    "run_sweep",
]

#: Grid axes besides ``params.<argument>``.
AXES = ("scene", "solver", "tol", "dt")


class SceneEntry(BaseModel):
    model_config = ConfigDict(extra="forbid")

    builder: str
    params: dict[str, Any] = Field(default_factory=dict)

    _known = field_validator("builder")(classmethod(lambda cls, v: known_builder(v)))


class SweepSpec(BaseModel):
    """A sweep file: scenes, grid axes and the length of each run."""

    model_config = ConfigDict(extra="forbid")

    name: str = "sweep"
    steps: int | None = Field(None, ge=1)
    until: float | None = Field(None, gt=0.0)
    warm_start: bool = True
    max_iter: int | None = Field(None, ge=1)
    scenes: dict[str, SceneEntry]
    grid: dict[str, list[Any]]

    @field_validator("name")
    @classmethod
    def _plain(cls, name: str) -> str:  # the tables are written as <out>/<name>.csv
        if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9._-]*", name):
            raise ValueError(f"must be a plain file name (letters, digits, . _ -), not {name!r}")
        return name

    @field_validator("grid")
    @classmethod
    def _axes(cls, grid: dict[str, list[Any]]) -> dict[str, list[Any]]:
        for key, values in grid.items():
            if key not in AXES and not key.startswith("params."):
                raise ValueError(f"unknown axis {key!r}; use {', '.join(AXES)} or params.<name>")
            if not values:
                raise ValueError(f"axis {key!r} has no values")
            again = first_repeat(values, key=lambda v: json.dumps(v, sort_keys=True, default=str))
            if again is not None:
                raise ValueError(
                    f"axis {key!r} repeats {values[again]!r}: its cells would run twice"
                )
        if "scene" not in grid:
            raise ValueError("the grid needs a 'scene' axis")
        return grid


@dataclass(frozen=True)
class Cell:
    """One run of the grid: its coordinates and the scene file content it runs."""

    id: str
    coords: dict[str, Any]
    config: dict[str, Any]


@dataclass(frozen=True)
class SweepSummary:
    cells: int
    ran: int
    skipped: int
    failed: int
    table: pd.DataFrame
    wall_time: float
    #: Cell files that could not be read, renamed ``*.unreadable`` (their cells ran again).
    set_aside: tuple[str, ...] = ()


def load_sweep(path: str | Path) -> SweepSpec:
    """Read and validate a sweep file (errors name the file and the key)."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"sweep file {path} does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read sweep file {path}: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    return parse_sweep(data, str(path))


def parse_sweep(data: Any, source: str = "sweep file") -> SweepSpec:
    try:
        spec = SweepSpec.model_validate(data)
    except pydantic.ValidationError as exc:
        first = exc.errors()[0]
        loc = ".".join(str(p) for p in first["loc"]) or "(top level)"
        message = str(first["msg"]).removeprefix("Value error, ")
        if first["type"] == "extra_forbidden":
            message = "unknown key"
        raise ConfigError(f"{source}: {loc}: {message}") from None
    if (spec.steps is None) == (spec.until is None):
        raise ConfigError(f"{source}: give exactly one of steps and until")
    unknown = set(spec.grid["scene"]) - set(spec.scenes)
    if unknown:
        raise ConfigError(f"{source}: grid.scene: {sorted(unknown)} not among the [scenes] tables")
    import solvers

    for cell in cells_of(spec):  # every cell is a valid scene file, with known backends
        config = parse_config(cell.config, f"{source}: cell {cell.coords}")
        for backend in (config.run.solver, *config.run.fallback):
            try:
                solvers.get(backend)
            except CocdError as exc:
                raise ConfigError(f"{source}: cell {cell.coords}: {exc}") from None
    return spec


def cells_of(spec: SweepSpec) -> list[Cell]:
    """Every combination of the grid's axes, in a fixed order."""
    keys = list(spec.grid)
    cells = []
    for values in itertools.product(*(spec.grid[k] for k in keys)):
        coords = dict(zip(keys, values, strict=True))
        entry = spec.scenes[coords["scene"]]
        params = dict(entry.params)
        run: dict[str, Any] = {
            "warm_start": spec.warm_start,
            "max_iter": spec.max_iter,
        }
        if spec.steps is not None:
            run["steps"] = spec.steps
        else:
            run["until"] = spec.until
        for key, value in coords.items():
            if key.startswith("params."):
                params[key.removeprefix("params.")] = value
            elif key != "scene":
                run[key] = value
        config = {"builder": entry.builder, "params": params, "run": run}
        key = json.dumps({"coords": coords, "config": config}, sort_keys=True, default=str)
        cells.append(Cell(hashlib.sha256(key.encode()).hexdigest()[:16], coords, config))
    return cells


# -- one cell -----------------------------------------------------------------------------
def run_cell(cell: Cell, folder: str) -> str:
    """Run one cell and write its row to ``folder/<id>.parquet``; returns the path.

    Runs in a worker process. The row is written to a temporary file, then
    renamed: the cell's file is complete or absent.
    """
    from cocd.config import build_scene

    start = time.perf_counter()
    row: dict[str, Any] = {"cell": cell.id, **{_column(k): v for k, v in cell.coords.items()}}
    try:
        config = parse_config(cell.config, f"cell {cell.id}")
        scene = build_scene(config)
        stepper = config.stepper(scene)
        stepper.run(config.n_steps())
        stats = stepper.stats()
        row.update(
            status="ok",
            error="",
            n_grains=scene.n_free,
            steps=len(stats),
            nc_mean=float(stats.nc.mean()),
            iterations_mean=float(stats.iterations.mean()),
            iterations_max=int(stats.iterations.max()),
            solve_time_mean=float(stats.solve_time.mean()),
            solve_time_total=float(stats.solve_time.sum()),
            ccp_max=float(stats.ccp_residual.max()),
            coulomb_max=float(stats.coulomb_residual.max()),
            kinetic_energy_final=float(stats.kinetic_energy.iloc[-1]),
            positions_checksum=hashlib.sha256(scene.positions.tobytes()).hexdigest()[:16],
        )
    except CocdError as exc:
        row.update(status="error", error=f"{type(exc).__name__}: {exc}"[:500])
    row["wall_time"] = time.perf_counter() - start
    row["host"] = os.uname().nodename
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    final = out / f"{cell.id}.parquet"
    tmp = out / f".{cell.id}.{uuid.uuid4().hex}.tmp"
    pd.DataFrame([row]).to_parquet(tmp, index=False)
    os.replace(tmp, final)
    return str(final)


def _column(axis: str) -> str:
    return axis.replace("params.", "param_")


# -- the sweep -----------------------------------------------------------------------------
def done_cells(folder: Path, ids: Iterable[str]) -> tuple[set[str], list[Path]]:
    """Of the cells ``ids``, those whose file in ``folder`` is complete (readable); and
    the files that could not be read, each renamed ``<id>.parquet.unreadable`` (never
    deleted) so that its cell runs again. Other files in ``folder`` are not touched."""
    done: set[str] = set()
    aside: list[Path] = []
    for cell_id in ids:
        path = folder / f"{cell_id}.parquet"
        if not path.exists():
            continue
        try:
            pd.read_parquet(path)
        except Exception:  # damaged, or someone else's: kept aside, the cell runs again
            target = path.with_name(path.name + ".unreadable")
            k = 1
            while target.exists():
                k += 1
                target = path.with_name(f"{path.name}.unreadable{k}")
            path.rename(target)
            aside.append(target)
            continue
        done.add(cell_id)
    return done, aside


def run_sweep(
    spec: SweepSpec,
    out: str | Path,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    client: Any = None,
    progress: Callable[[int, int, str], None] | None = None,
    notice: Callable[[str], None] | None = None,
) -> SweepSummary:
    """Run the cells of ``spec`` not already in ``out/cells``; aggregate every cell.

    ``notice`` is told at once of each cell file that could not be read and was kept
    aside (also in :attr:`SweepSummary.set_aside`).

    ``client``: an existing ``distributed.Client`` (tests); else ``scheduler`` (an
    address) or a local cluster of ``workers`` processes (default: the cores).
    """
    start = time.perf_counter()
    out = Path(out)
    folder = out / "cells"
    folder.mkdir(parents=True, exist_ok=True)
    cells = cells_of(spec)
    done, aside = done_cells(folder, [c.id for c in cells])
    for path in aside:
        (notice or print)(
            f"{path}: a cell file that could not be read, kept aside; its cell runs again"
        )
    todo = [c for c in cells if c.id not in done]
    say = progress or (lambda _k, _n, _line: None)
    if todo:
        _submit_all(
            todo, folder, workers, scheduler, client, say, len(cells) - len(todo), len(cells)
        )
    table = aggregate(spec, out)
    failed = int((table["status"] != "ok").sum()) if len(table) else 0
    return SweepSummary(
        len(cells),
        len(todo),
        len(cells) - len(todo),
        failed,
        table,
        time.perf_counter() - start,
        tuple(str(p) for p in aside),
    )


def _submit_all(
    todo: list[Cell],
    folder: Path,
    workers: int | None,
    scheduler: str | None,
    client: Any,
    say: Callable[[int, int, str], None],
    already: int,
    total: int,
) -> None:
    from distributed import Client, LocalCluster, as_completed

    own_cluster = own_client = None
    try:
        if client is None:
            if scheduler is not None:
                try:
                    own_client = client = Client(scheduler, timeout="20s")
                except (OSError, TimeoutError, ValueError) as exc:
                    raise CocdError(
                        f"cannot reach the Dask scheduler {scheduler!r}: {exc}"
                    ) from None
            else:
                n = workers or os.cpu_count() or 1
                own_cluster = LocalCluster(
                    n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None
                )
                own_client = client = Client(own_cluster)
        futures = [
            client.submit(run_cell, cell, str(folder), key=f"cocd-cell-{cell.id}", pure=False)
            for cell in todo
        ]
        count = already
        for future in as_completed(futures):
            path = future.result()
            count += 1
            say(count, total, Path(path).stem)
    finally:
        if own_client is not None:
            own_client.close()
        if own_cluster is not None:
            own_cluster.close()


def aggregate(spec: SweepSpec, out: str | Path) -> pd.DataFrame:
    """Every finished cell of the sweep, one row each, in grid order; written to
    ``out/<name>.parquet``, ``.csv`` and ``.md`` (a summary)."""
    out = Path(out)
    cells = cells_of(spec)
    rows = []
    for cell in cells:
        path = out / "cells" / f"{cell.id}.parquet"
        if path.exists():
            rows.append(pd.read_parquet(path))
    table = pd.concat(rows, ignore_index=True) if rows else pd.DataFrame()
    if len(table):
        table.to_parquet(out / f"{spec.name}.parquet", index=False)
        table.to_csv(out / f"{spec.name}.csv", index=False)
        _summary(spec, table, out)
    return table


def _summary(spec: SweepSpec, table: pd.DataFrame, out: Path) -> None:
    coords = [_column(k) for k in spec.grid]
    measured = ["status", "steps", "nc_mean", "iterations_mean", "solve_time_mean", "ccp_max"]
    measured += ["coulomb_max", "kinetic_energy_final"]
    shown = [c for c in [*coords, *measured] if c in table.columns]
    length = f"{spec.steps} steps" if spec.steps is not None else f"until t = {spec.until:g} s"
    text = [
        f"# Sweep `{spec.name}`",
        "",
        f"{len(table)} cells ({' x '.join(f'{len(v)} {k}' for k, v in spec.grid.items())}), "
        f"{length} each; `solve_time_mean` is the backend's solve time per step (s), "
        "`ccp_max` the largest `ccp_residual` over the steps.",
        "",
        table[shown].to_markdown(index=False, floatfmt=".3g"),
        "",
    ]
    errors = table[table["status"] != "ok"]
    for _, row in errors.iterrows():
        text.append(f"- cell `{row['cell']}` failed: {row['error']}")
    (out / f"{spec.name}.md").write_text("\n".join(text) + "\n")
