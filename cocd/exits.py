"""Exit statuses of the command line, and the one-line error a failed command ends with."""

from __future__ import annotations

from typing import Any, NoReturn

import typer
from typer.core import TyperGroup

__all__ = ["EXIT_ERROR", "EXIT_INTERRUPTED", "EXIT_NOT_SOLVED", "OneLineErrors", "fail"]

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


def os_message(exc: OSError) -> str:
    """``Permission denied: '/a/b'`` (the system's words and the path, no errno)."""
    paths = [repr(str(p)) for p in (exc.filename, exc.filename2) if p is not None]
    words = " ".join((exc.strerror or str(exc) or type(exc).__name__).split())
    return f"{words}: {' -> '.join(paths)}" if paths else words


class OneLineErrors(TyperGroup):
    """The root command group. A file the system will not read or write (a read-only
    folder, a file where a folder is needed: an ``OSError`` with an errno or a path),
    or a setting a configuration model refuses, met anywhere under any command, ends
    the command with one line on stderr and :data:`EXIT_ERROR`, as a
    :class:`~cocd.errors.CocdError` does, not with a traceback."""

    def invoke(self, ctx: Any) -> Any:
        from pydantic import ValidationError

        try:
            return super().invoke(ctx)
        except OSError as exc:
            if exc.errno is None and exc.filename is None:
                raise  # not the system refusing a file: a fault to be seen whole
            fail(Exception(os_message(exc)))
        except ValidationError as exc:
            wrong = "; ".join(
                f"{'.'.join(str(part) for part in err['loc'])}: "
                + str(err["msg"]).removeprefix("Value error, ")
                for err in exc.errors()
            )
            fail(Exception(f"invalid setting {wrong}"))
