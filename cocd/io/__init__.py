"""Reading and writing problems and runs.

:mod:`cocd.io.problems` holds the external problem forms (local and global),
:mod:`cocd.io.fclib` reads and writes FCLib HDF5 files and
:mod:`cocd.io.siconos` reads Siconos text files; :func:`read_problem` picks
the reader from the file.
"""

from __future__ import annotations

import os
from pathlib import Path

from cocd.errors import ProblemFileError
from cocd.io.problems import ExternalSolution, GlobalProblem, LocalProblem, natural_map_error

__all__ = [
    "ExternalSolution",
    "GlobalProblem",
    "LocalProblem",
    "natural_map_error",
    "read_problem",
    "write_problem",
]


def read_problem(path: str | os.PathLike[str]) -> LocalProblem | GlobalProblem:
    """Read a single-step problem: FCLib HDF5 (by its signature) or Siconos text."""
    from cocd.io.fclib import is_hdf5, read_fclib

    path = Path(path)
    if not path.exists():
        raise ProblemFileError(f"{path}: no such file")
    if path.is_dir():
        raise ProblemFileError(f"{path}: is a folder, expected a problem file")
    if is_hdf5(path):
        return read_fclib(path)
    from cocd.io.siconos import read_siconos

    return read_siconos(path)


def write_problem(
    path: str | os.PathLike[str],
    problem: LocalProblem | GlobalProblem,
    solution: ExternalSolution | None = None,
) -> Path:
    """Write a problem as an FCLib HDF5 file (the field's exchange format)."""
    from cocd.io.fclib import write_fclib

    return write_fclib(path, problem, solution=solution)
