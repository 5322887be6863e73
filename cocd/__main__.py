"""``python -m cocd``: the ``cocd`` command (runs the default scene with no arguments)."""

from cocd.cli import app

app(prog_name="cocd")
