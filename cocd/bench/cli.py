"""``cocd bench``: the harness commands.

Each command writes its tables and plots under ``--out`` (default
``results``) with a ``<name>.meta.json`` recording the command and machine,
then rebuilds ``<out>/README.md`` from every such record.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Annotated

import typer

from cocd.errors import CocdError
from cocd.exits import fail

bench_app = typer.Typer(
    rich_markup_mode=None,
    add_completion=False,
    no_args_is_help=True,
    help="Compare backends: Table 1, stability, precision, hard cases, external problems.",
)

Solvers = Annotated[
    str | None,
    typer.Option("--solvers", help="Comma-separated backends (default: the harness's set)."),
]
Out = Annotated[
    Path, typer.Option("--out", help="Output directory (the committed tables: --out results).")
]
#: Where results go unless --out says otherwise: not the committed results/.
DEFAULT_OUT = Path("cocd-results")
TimeLimit = Annotated[
    float, typer.Option("--time-limit", help="Seconds per solve before a backend is stopped.")
]
MemoryGb = Annotated[
    float | None,
    typer.Option("--memory-gb", help="Memory cap per backend process (GiB; default 3/4 of RAM)."),
]


def _floats(text: str, what: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise CocdError(f"{what} must be comma-separated numbers, got {text!r}") from None
    if not values or any(not (v > 0) for v in values):
        raise CocdError(f"{what} must be positive numbers, got {text!r}")
    return values


def _run(job: Callable[[], object], out: Path) -> None:
    """Run one harness command; a CocdError is a one-line error and exit code 2."""
    try:
        job()
    except CocdError as exc:
        fail(exc)
    _finish(out)


def _finish(out: Path) -> None:
    from cocd.bench.report import write_readme

    try:
        typer.echo(f"wrote {write_readme(out)}")
    except CocdError as exc:
        fail(exc)


@bench_app.command()
def table1(
    solvers: Solvers = None,
    scale: Annotated[
        float,
        typer.Option("--scale", help="Multiply the seed's grain counts by this (0 < S <= 1)."),
    ] = 0.1,
    scale_3d: Annotated[
        float | None,
        typer.Option("--scale-3d", help="The 3D case's own scale (default: --scale)."),
    ] = None,
    cases: Annotated[str, typer.Option("--cases", help="Which halves: 2d, 3d or 2d,3d.")] = "2d,3d",
    steps: Annotated[int, typer.Option("--steps", help="Steps averaged per row.")] = 10,
    time_limit: TimeLimit = 600.0,
    memory_gb: MemoryGb = None,
    resume: Annotated[
        bool,
        typer.Option(
            "--resume", help="Keep the rows already in OUT/table1.csv; solve only the others."
        ),
    ] = False,
    row_budget: Annotated[
        float | None,
        typer.Option(
            "--row-budget", help="Seconds of solving after which a row stops (slow backends)."
        ),
    ] = None,
    trajectory: Annotated[
        str | None,
        typer.Option(
            "--trajectory",
            help="Backend that steps each column to the recorded steps (default: clarabel, "
            "clarabel-dual in 3D).",
        ),
    ] = None,
    out: Out = DEFAULT_OUT,
) -> None:
    """The seed's Table 1: iterations and time per step against N, dt and eps."""
    from cocd.bench import table1 as mod

    _run(
        lambda: mod.run(
            solvers=solvers,
            scale=scale,
            scale_3d=scale_3d,
            resume=resume,
            trajectory_solver=trajectory,
            row_budget=row_budget,
            cases=[c.strip() for c in cases.split(",") if c.strip()],
            steps=steps,
            time_limit=time_limit,
            memory_gb=memory_gb,
            out=out,
        ),
        out,
    )


@bench_app.command()
def stability(
    solvers: Solvers = None,
    eps_list: Annotated[
        str, typer.Option("--eps-list", help="Comma-separated tolerances.")
    ] = "1e-1,1e-2,1e-3,1e-4,1e-5,1e-6,1e-7,1e-8",
    n: Annotated[int, typer.Option("--n", help="Spheres in the box.")] = 1000,
    dim: Annotated[int, typer.Option("--dim", help="2 or 3.")] = 3,
    t_end: Annotated[float, typer.Option("--t-end", help="Duration in units of sqrt(H/g).")] = 5.0,
    dt: Annotated[float, typer.Option("--dt", help="Time step (s).")] = 1e-2,
    threshold: Annotated[
        float,
        typer.Option("--threshold", help="At rest while Ek / (Ek + Ep) stays below this."),
    ] = 1e-6,
    time_limit: TimeLimit = 600.0,
    run_budget: Annotated[
        float | None,
        typer.Option(
            "--run-budget",
            help="Wall seconds per (solver, eps) run; a run that spends them stops, not at rest.",
        ),
    ] = None,
    out: Out = DEFAULT_OUT,
) -> None:
    """The seed's Fig. 3: does a box at rest stay at rest, for each solver and eps?"""
    from cocd.bench import stability as mod

    _run(
        lambda: mod.run(
            solvers=solvers,
            eps_list=_floats(eps_list, "--eps-list"),
            n=n,
            dim=dim,
            t_end=t_end,
            dt=dt,
            threshold=threshold,
            time_limit=time_limit,
            out=out,
            run_budget=run_budget,
        ),
        out,
    )


@bench_app.command()
def precision(
    solvers: Solvers = None,
    tols: Annotated[
        str, typer.Option("--tols", help="Comma-separated tolerances swept by each solver.")
    ] = "1e-2,1e-3,1e-4,1e-5,1e-6,1e-7,1e-8,1e-9",
    n2d: Annotated[int, typer.Option("--n2d", help="Discs in the 2D column.")] = 2000,
    n3d: Annotated[int, typer.Option("--n3d", help="Spheres in the 3D box.")] = 1000,
    time_limit: TimeLimit = 300.0,
    memory_gb: MemoryGb = None,
    out: Out = DEFAULT_OUT,
) -> None:
    """Speed against error: work-precision plots, performance profiles, geometric means."""
    from cocd.bench import precision as mod

    _run(
        lambda: mod.run(
            solvers=solvers,
            tols=_floats(tols, "--tols"),
            n2d=n2d,
            n3d=n3d,
            time_limit=time_limit,
            memory_gb=memory_gb,
            out=out,
        ),
        out,
    )


@bench_app.command()
def hard(
    solvers: Solvers = None,
    cases: Annotated[
        str | None, typer.Option("--cases", help="Comma-separated hard cases (default: all).")
    ] = None,
    steps: Annotated[int, typer.Option("--steps", help="Steps per case.")] = 5,
    tol: Annotated[float, typer.Option("--tol", help="Tolerance asked of every solver.")] = 1e-6,
    time_limit: TimeLimit = 120.0,
    memory_gb: MemoryGb = None,
    out: Out = DEFAULT_OUT,
) -> None:
    """Every solver on every hard case: status, iterations, time, residuals, energy drift."""
    from cocd.bench import hard as mod

    _run(
        lambda: mod.run(
            solvers=solvers,
            cases=None if cases is None else [c.strip() for c in cases.split(",") if c.strip()],
            steps=steps,
            tol=tol,
            time_limit=time_limit,
            memory_gb=memory_gb,
            out=out,
        ),
        out,
    )


@bench_app.command()
def external(
    folder: Annotated[
        Path, typer.Argument(help="Folder of FCLib .hdf5 / Siconos .dat problem files.")
    ],
    solvers: Solvers = None,
    tol: Annotated[float, typer.Option("--tol", help="Tolerance asked of every solver.")] = 1e-8,
    coulomb_target: Annotated[
        float,
        typer.Option("--coulomb-target", help="natural_map_error counted as solving Coulomb."),
    ] = 1e-6,
    time_limit: TimeLimit = 60.0,
    memory_gb: MemoryGb = None,
    out: Out = DEFAULT_OUT,
) -> None:
    """Every backend on every problem file of FOLDER: table and performance profiles."""
    from cocd.bench import external as mod

    _run(
        lambda: mod.run(
            folder=folder,
            solvers=solvers,
            tol=tol,
            time_limit=time_limit,
            memory_gb=memory_gb,
            out=out,
            coulomb_target=coulomb_target,
        ),
        out,
    )


def _ints(text: str, what: str) -> list[int]:
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise CocdError(f"{what} must be comma-separated integers, got {text!r}") from None
    if any(v < 1 for v in values):
        raise CocdError(f"{what} must be positive integers, got {text!r}")
    return values


@bench_app.command()
def scaling(
    solvers: Solvers = None,
    n2d: Annotated[
        str, typer.Option("--n2d", help="2D column sizes (comma-separated; empty for none).")
    ] = "1109,8308,20488,50772",
    n3d: Annotated[
        str,
        typer.Option("--n3d", help="3D sizes per packing (comma-separated; empty for none)."),
    ] = "2000,8000,32000",
    packings: Annotated[
        str,
        typer.Option(
            "--packings",
            help="3D packings: column (mid-flow), box (rain-deposited, at rest), jammed_box.",
        ),
    ] = "column,box,jammed_box",
    n3d_box: Annotated[
        str | None,
        typer.Option("--n3d-box", help="Sizes of the box packing, if not those of --n3d."),
    ] = None,
    resume: Annotated[
        bool, typer.Option("--resume", help="Keep OUT/scaling.csv's 3D rows; run the others.")
    ] = False,
    steps: Annotated[int, typer.Option("--steps", help="Problems timed per size.")] = 3,
    trajectory: Annotated[
        str, typer.Option("--trajectory", help="Backend that steps the 2D columns.")
    ] = "ipm",
    table1: Annotated[
        Path | None,
        typer.Option("--table1", help="Take the 2D rows from this table1.csv instead."),
    ] = None,
    time_limit: TimeLimit = 900.0,
    memory_gb: MemoryGb = None,
    out: Out = DEFAULT_OUT,
) -> None:
    """Time per step against N per backend (2D column; 3D column, box, lattice), with fits."""
    from cocd.bench import scaling as mod

    _run(
        lambda: mod.run(
            solvers=solvers,
            n2d=_ints(n2d, "--n2d"),
            n3d=_ints(n3d, "--n3d"),
            steps=steps,
            time_limit=time_limit,
            memory_gb=memory_gb,
            out=out,
            trajectory=trajectory,
            table1=table1,
            packings=[p.strip() for p in packings.split(",") if p.strip()],
            n3d_box=None if n3d_box is None else _ints(n3d_box, "--n3d-box"),
            resume=resume,
        ),
        out,
    )


@bench_app.command()
def readme(out: Out = DEFAULT_OUT) -> None:
    """Rebuild OUT/README.md from the result files' records."""
    _finish(out)
