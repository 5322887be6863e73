"""``cocd problem``: single-step problems from other tools (FCLib HDF5, Siconos text),
described, and solved by one backend and judged by cocd's residuals."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console

from cocd.errors import CocdError
from cocd.exits import EXIT_ERROR, EXIT_NOT_SOLVED, fail
from cocd.outputs import writable_file

problem_app = typer.Typer(
    rich_markup_mode=None,
    add_completion=False,
    no_args_is_help=True,
    help="Single-step problems from other tools: FCLib HDF5 and Siconos text files.",
)
console = Console(soft_wrap=True)


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
        fail(exc)
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
    force: Annotated[
        bool, typer.Option("--force", help="Replace the file named with --save-solution.")
    ] = False,
) -> None:
    """Solve one problem with one backend; report cocd's residuals and the natural map error.

    Exit status: 0 when the backend reports ``optimal``, 3 when it answered but
    not to the tolerance (``max_iter``, ``inaccurate``, ``time_limit``), 2 on an
    error (a bad file or option, a failed backend).
    """
    from cocd.external import solve_external
    from cocd.io import read_problem

    try:
        if save_solution is not None:
            if save_solution.is_dir():
                raise CocdError(f"--save-solution {save_solution} is a folder, not a file")
            if not save_solution.suffix:  # the path said is the path written
                save_solution = save_solution.with_name(save_solution.name + ".npz")
            if save_solution.suffix != ".npz":
                raise CocdError(f"--save-solution writes .npz, not {save_solution.name!r}")
            writable_file(save_solution, "--save-solution", replace=force)
        problem = read_problem(file)
        record, answer = solve_external(problem, solver, tol, time_limit=time_limit)
    except CocdError as exc:
        fail(exc)
        return
    if save_solution is not None:
        if answer is None:
            fail(CocdError(f"solver {solver!r} returned no usable impulses: nothing to save"))
        else:
            import numpy as np

            arrays: dict[str, Any] = answer.arrays()
            np.savez(save_solution, **arrays)
    if as_json:
        typer.echo(json.dumps(_jsonable(record)))
    else:
        for key, value in record.items():
            shown = f"{value:.3e}" if isinstance(value, float) else str(value)
            console.print(f"{key:>18}: {shown}", highlight=False)
        if save_solution is not None:
            console.print(f"wrote {save_solution}")
    status = str(record.get("status", ""))
    if status != "optimal":
        typer.echo(f"not solved to tol {tol:g}: status {status}", err=True)
        raise typer.Exit(code=EXIT_NOT_SOLVED if answer is not None else EXIT_ERROR)
