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


@bench_app.command()
def upgrade(
    folder: Annotated[Path, typer.Argument(help="A folder of results (searched recursively).")],
    dry_run: Annotated[
        bool, typer.Option("--dry-run", help="Say what would be renamed; write nothing.")
    ] = False,
) -> None:
    """Rename old result columns to the current names.

    For results written by earlier versions. Values are unchanged (warm's yes/no become
    start's warm/cold); each record notes what was renamed, and the README is rebuilt.
    """
    from cocd.bench.report import write_readme
    from cocd.bench.upgrade import upgrade_folder

    try:
        done = upgrade_folder(folder, dry_run=dry_run)
        for path, names in done.items():
            pairs = ", ".join(f"{o} -> {n}" for o, n in names.items())
            typer.echo(f"{'would rename' if dry_run else 'renamed'} in {path}: {pairs}")
        if not done:
            typer.echo(f"{folder}: every table already uses the current names")
        elif not dry_run:
            for readme in sorted({p.parent for p in done if (p.parent / "README.md").exists()}):
                if any(readme.glob("*.meta.json")):
                    typer.echo(f"wrote {write_readme(readme)}")
    except CocdError as exc:
        fail(exc)
