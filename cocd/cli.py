"""The ``cocd`` command.

``cocd run`` (also ``python -m cocd``) runs a small 2D column collapse and
prints per-step statistics; ``cocd solvers`` lists the backends; ``cocd problem``
reads and solves external problem files (FCLib HDF5, Siconos text);
``cocd bench`` runs the benchmark harness (:mod:`cocd.bench`).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

import solvers
from cocd.bench.cli import bench_app
from cocd.builders import column_2d
from cocd.errors import CocdError
from cocd.stepper import Stepper, StepRecord

app = typer.Typer(
    add_completion=False,
    no_args_is_help=False,
    help="Granular media with hard Coulomb contact, one convex conic problem per step.",
)
app.add_typer(bench_app, name="bench")
problem_app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help="Single-step problems from other tools: FCLib HDF5 and Siconos text files.",
)
app.add_typer(problem_app, name="problem")
console = Console(soft_wrap=True)


def _fail(exc: Exception) -> None:
    typer.echo(f"error: {exc}", err=True)
    raise typer.Exit(code=2)


@app.callback(invoke_without_command=True)
def main(ctx: typer.Context) -> None:
    """With no command, run the default scene (same as ``cocd run``)."""
    if ctx.invoked_subcommand is None:
        ctx.invoke(run)


@app.command()
def run(
    n: Annotated[int, typer.Option("--n", help="Number of discs in the column.")] = 300,
    steps: Annotated[int, typer.Option("--steps", help="Number of time steps.")] = 100,
    dt: Annotated[float, typer.Option("--dt", help="Time step (s).")] = 1e-3,
    solver: Annotated[str, typer.Option("--solver", help="Backend (see `cocd solvers`).")] = (
        "clarabel"
    ),
    tol: Annotated[float, typer.Option("--tol", help="Backend tolerance.")] = 1e-8,
    mu: Annotated[float, typer.Option("--mu", help="Friction coefficient.")] = 0.3,
    every: Annotated[int, typer.Option("--every", help="Print one step in EVERY.")] = 1,
    out: Annotated[
        Path | None, typer.Option("--out", help="Write the per-step table (CSV).")
    ] = None,
) -> None:
    """Collapse of a 2D column of discs (aspect 0.7, 20 cm wide) released at t = 0."""
    try:
        if n < 1 or steps < 0 or every < 1:
            raise CocdError(
                f"need --n >= 1, --steps >= 0, --every >= 1 (got {n}, {steps}, {every})"
            )
        scene = column_2d(n, mu=mu)
        stepper = Stepper(scene, dt, solver=solver, tol=tol)
    except CocdError as exc:
        _fail(exc)
        return
    console.print(
        f"2D column: {scene.n_grains} discs, mean radius {scene.radii.mean() * 1e3:.2f} mm, "
        f"mu = {mu:g}; dt = {dt:g} s, solver {solver}, tol {tol:g}"
    )
    console.print(
        f"{'step':>5} {'t (s)':>7} {'Nc':>6} {'iter':>5} {'solve (s)':>9} "
        f"{'ccp':>9} {'coulomb':>9} {'Ek (J/m)':>10} {'status':>10}"
    )

    def show(r: StepRecord) -> None:
        if r.step % every == 0 or r.step == steps:
            console.print(
                f"{r.step:5d} {r.t:7.4f} {r.nc:6d} {r.iterations:5d} {r.solve_time:9.4f} "
                f"{r.ccp_residual:9.2e} {r.coulomb_residual:9.2e} {r.kinetic_energy:10.3e} "
                f"{r.status:>10}",
                highlight=False,
            )

    try:
        stepper.run(steps, callback=show)
    except CocdError as exc:
        _fail(exc)
    stats = stepper.stats()
    if len(stats):
        console.print(
            f"mean over {len(stats)} steps: Nc {stats.nc.mean():.0f}, iterations "
            f"{stats.iterations.mean():.1f}, solve {stats.solve_time.mean():.4f} s/step, "
            f"max ccp_residual {stats.ccp_residual.max():.2e}",
            highlight=False,
        )
    if out is not None:
        stats.to_csv(out, index=False)
        console.print(f"wrote {out}")


@app.command("solvers")
def list_solvers() -> None:
    """List the registered backends, their capabilities and availability."""
    table = Table("name", "formulation", "dims", "convex", "warm start", "available")
    missing = solvers.unavailable()
    for name, info in sorted(solvers.registered().items()):
        table.add_row(
            name,
            info.formulation,
            ",".join(map(str, info.dims)),
            "yes" if info.convex else "no",
            "yes" if info.warm_start else "no",
            "yes" if name not in missing else f"no: {missing[name]}",
        )
    console.print(table)


def _jsonable(d: dict[str, Any]) -> dict[str, Any]:
    """NaN and infinity as ``null`` (JSON has neither)."""
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in d.items()}


@problem_app.command("info")
def problem_info(
    file: Annotated[Path, typer.Argument(help="FCLib .hdf5 or Siconos .dat file.")],
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """Kind (local or global), sizes, friction and the Delassus operator's symmetry."""
    from cocd.external import describe
    from cocd.io import read_problem

    try:
        info = describe(read_problem(file))
    except CocdError as exc:
        _fail(exc)
        return
    if as_json:
        typer.echo(json.dumps(_jsonable(info)))
        return
    for key, value in info.items():
        shown = f"{value:.6g}" if isinstance(value, float) else str(value)
        console.print(f"{key:>18}: {shown}", highlight=False)


@problem_app.command("solve")
def problem_solve(
    file: Annotated[Path, typer.Argument(help="FCLib .hdf5 or Siconos .dat file.")],
    solver: Annotated[str, typer.Option("--solver", help="Backend (see `cocd solvers`).")] = (
        "clarabel"
    ),
    tol: Annotated[float, typer.Option("--tol", help="Backend tolerance.")] = 1e-8,
    time_limit: Annotated[
        float | None, typer.Option("--time-limit", help="Seconds for the backend.")
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    save_solution: Annotated[
        Path | None,
        typer.Option(
            "--save-solution",
            help="Write the answer as .npz: r (impulses, normal first), u (local "
            "velocities), v (generalized velocities, global problems).",
        ),
    ] = None,
) -> None:
    """Solve one problem with one backend; report cocd's residuals and the natural map error."""
    from cocd.external import solve_external
    from cocd.io import read_problem

    try:
        problem = read_problem(file)
        record, answer = solve_external(problem, solver, tol, time_limit=time_limit)
    except CocdError as exc:
        _fail(exc)
        return
    if save_solution is not None:
        if answer is None:
            _fail(CocdError(f"solver {solver!r} returned no usable impulses: nothing to save"))
        else:
            import numpy as np

            arrays: dict[str, Any] = answer.arrays()
            np.savez(save_solution, **arrays)
    if as_json:
        typer.echo(json.dumps(_jsonable(record)))
        return
    for key, value in record.items():
        shown = f"{value:.3e}" if isinstance(value, float) else str(value)
        console.print(f"{key:>18}: {shown}", highlight=False)
    if save_solution is not None:
        console.print(f"wrote {save_solution}")
