"""A study's table, kept on disk row by row and resumed by key.

Every study that resumes does it here: rows are keyed on ``(problem, solver,
tol)`` or on the key columns the study names, an earlier table is read under
the current names (:func:`cocd.bench.schema.upgrade`), and the file is
rewritten (atomically) after every row, so that a run that is stopped keeps
what it finished and the next ``--resume`` solves only the rest.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from cocd.bench import schema
from cocd.errors import CocdError

__all__ = ["KEY", "Results"]

#: The default key of a row.
KEY = ("problem", "solver", "tol")

Row = dict[str, Any]


class Results:
    """The rows of ``path``, by key.

    Parameters
    ----------
    path
        The CSV file (``OUT/<name>.csv``).
    columns
        The table's columns, in order.
    resume
        Read the rows of an earlier ``path`` (those ``keep`` accepts); otherwise
        start empty (the file is replaced at the first :meth:`add`).
    key
        The columns that name a row.
    keep
        Which earlier rows to reuse (default: all). Columns an earlier table
        lacks, other than the key's, are read as empty.

    Raises
    ------
    CocdError
        When an earlier table cannot be read or lacks a key column.
    """

    def __init__(
        self,
        path: Path,
        columns: Sequence[str],
        *,
        resume: bool = False,
        key: Sequence[str] = KEY,
        keep: Callable[[Row], bool] | None = None,
    ) -> None:
        self.path = Path(path)
        self.columns = list(columns)
        self.key = tuple(key)
        missing = [k for k in self.key if k not in self.columns]
        if missing:
            raise ValueError(f"key columns {missing} are not among the columns")
        self._rows: dict[tuple[Any, ...], Row] = {}
        self.resumed = 0
        if resume:
            for row in self._read():
                if keep is None or keep(row):
                    self._rows[self._key(row)] = row
            self.resumed = len(self._rows)

    # -- lookup ----------------------------------------------------------------
    def has(self, *values: Any, **named: Any) -> bool:
        """Whether a row with this key is kept (values in key order, or by name)."""
        return self._lookup(values, named) in self._rows

    def get(self, *values: Any, **named: Any) -> Row | None:
        """The row with this key, or None."""
        return self._rows.get(self._lookup(values, named))

    def __len__(self) -> int:
        return len(self._rows)

    @property
    def rows(self) -> list[Row]:
        """The rows, in the order they were added (resumed rows first)."""
        return list(self._rows.values())

    def frame(self) -> pd.DataFrame:
        """The rows as a table with :attr:`columns`."""
        return pd.DataFrame(self.rows, columns=self.columns)

    # -- writing ---------------------------------------------------------------
    def add(self, row: Row, *, save: bool = True) -> None:
        """Keep ``row`` (replacing one with the same key), then rewrite the file."""
        row = {c: row.get(c, np.nan) for c in self.columns}
        self._rows[self._key(row)] = row
        if save:
            self.save()

    def save(self) -> Path:
        """Write the table to :attr:`path` (through a temporary file: never half-written)."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_name(f".{self.path.name}.tmp")
        self.frame().to_csv(tmp, index=False)
        os.replace(tmp, self.path)
        return self.path

    # -- helpers ---------------------------------------------------------------
    def _read(self) -> list[Row]:
        if not self.path.is_file():
            return []
        try:
            old = pd.read_csv(self.path, keep_default_na=False, na_values=[""])
        except (OSError, ValueError, pd.errors.ParserError) as exc:
            raise CocdError(f"cannot resume from {self.path}: {exc}") from None
        old = schema.upgrade(old)
        lacking = [k for k in self.key if k not in old.columns]
        if lacking:
            raise CocdError(
                f"cannot resume from {self.path}: it has no {', '.join(lacking)} column "
                "(move it away, or run without --resume to start a new table)"
            )
        for column in self.columns:
            if column not in old.columns:
                old[column] = np.nan
        old = old[self.columns].astype(object)
        old = old.where(pd.notna(old), None)
        rows = old.to_dict("records")
        for row in rows:
            for column, value in row.items():
                if value is None:
                    row[column] = "" if column == "note" else np.nan
        return [{str(k): v for k, v in row.items()} for row in rows]

    def _lookup(self, values: tuple[Any, ...], named: dict[str, Any]) -> tuple[Any, ...]:
        if values and named:
            raise TypeError("give the key by position or by name, not both")
        if named:
            unknown = set(named) - set(self.key)
            if unknown or len(named) != len(self.key):
                raise TypeError(f"the key is {self.key}, got {sorted(named)}")
            return self._key(named)
        if len(values) != len(self.key):
            raise TypeError(f"the key is {self.key}, got {len(values)} values")
        return self._key(dict(zip(self.key, values, strict=True)))

    def _key(self, row: Row) -> tuple[Any, ...]:
        return tuple(_normal(row[k]) for k in self.key)


def _normal(value: Any) -> Any:
    """A key value that compares equal whether it was read from a CSV or computed:
    numbers as floats (rounded to 12 significant digits), everything else as text."""
    if isinstance(value, (bool, np.bool_)):
        return str(bool(value))
    if isinstance(value, (int, float, np.integer, np.floating)):
        v = float(value)
        if not math.isfinite(v):
            return str(v)
        return float(f"{v:.12g}")
    return str(value)
