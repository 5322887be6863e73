"""``cocd bench`` and ``cocd validate``: one command per registered study.

The commands are generated from the studies (:mod:`cocd.bench.study`): each
writes its tables and plots under ``--out`` with a ``<name>.meta.json``
recording the command and machine, then rebuilds ``<out>/README.md`` from
every such record.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from cocd.bench.study import DEFAULT_OUT, HEADINGS, add_commands
from cocd.errors import CocdError
from cocd.exits import fail

__all__ = ["bench_app", "validate_app"]

bench_app = typer.Typer(
    rich_markup_mode=None,
    add_completion=False,
    no_args_is_help=True,
    help="Compare backends: Table 1, stability, precision, hard cases, external problems, scaling.",
)
validate_app = typer.Typer(
    rich_markup_mode=None,
    add_completion=False,
    no_args_is_help=True,
    help="Reproduce the seeds' physics: time step, NSCD, erodible beds, runout against the "
    "aspect ratio, avalanche angles.",
)
add_commands(bench_app, "bench")
add_commands(validate_app, "validate")


@bench_app.command()
def readme(
    out: Annotated[Path, typer.Option("--out", help="Output directory.")] = DEFAULT_OUT["bench"],
) -> None:
    """Rebuild OUT/README.md from the result files' records."""
    from cocd.bench.report import write_readme

    try:
        typer.echo(f"wrote {write_readme(out, heading=HEADINGS['bench'])}")
    except CocdError as exc:
        fail(exc)
