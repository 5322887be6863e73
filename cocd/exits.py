"""Exit statuses of the command line, and the one-line error a failed command ends with."""

from __future__ import annotations

from typing import NoReturn

import typer

__all__ = ["EXIT_ERROR", "EXIT_INTERRUPTED", "EXIT_NOT_SOLVED", "fail"]

#: Exit status of a command whose input was wrong or whose work failed.
EXIT_ERROR = 2
#: Exit status after Ctrl-C (128 + SIGINT, as shells report it).
EXIT_INTERRUPTED = 130
#: Exit status of ``cocd problem solve`` when the backend answered but not to the
#: tolerance (status ``max_iter``, ``inaccurate`` or ``time_limit``), and of a sweep
#: with failed cells.
EXIT_NOT_SOLVED = 3


def fail(exc: Exception) -> NoReturn:
    """Print ``error: <exc>`` on stderr and exit with :data:`EXIT_ERROR`."""
    typer.echo(f"error: {exc}", err=True)
    raise typer.Exit(code=EXIT_ERROR)
