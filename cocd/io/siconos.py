"""Siconos numerics text files (``.dat``) of frictional contact problems.

Siconos writes one problem per file with ``frictionContact_printInFile`` (local)
and ``globalFrictionContact_printInFile`` (global); the numbers are separated by
blanks and newlines, which the readers (``fscanf``) do not distinguish except
in the CSparse header lines. The layout read here:

local file::

    dim                     2 or 3
    nc                      number of contacts
    <matrix W>              a NumericsMatrix, (dim nc) x (dim nc)
    q                       dim nc values
    mu                      nc values
    [isComplete]            one integer, written by old (3.x) Siconos only

global file (``M v = H r + q``, ``u = H' v + b``; FCLib's ``f`` and ``w``)::

    dim
    nc
    <matrix M>              ndof x ndof
    <matrix H>              ndof x (dim nc)
    q                       ndof values (FCLib f)
    b                       dim nc values (FCLib w)
    mu                      nc values
    [isComplete]

Each matrix is a NumericsMatrix, dense, sparse-block or sparse (CSparse),
as :mod:`cocd.io.siconos_matrix` describes.

:func:`read_siconos` returns a :class:`~cocd.io.problems.LocalProblem` or
:class:`~cocd.io.problems.GlobalProblem`; every defect of the file raises
:class:`~cocd.errors.ProblemFileError` naming the file and the line.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from cocd.errors import ProblemError, ProblemFileError
from cocd.io.problems import GlobalProblem, LocalProblem
from cocd.io.siconos_matrix import Reader, read_matrix

__all__ = ["read_siconos"]

Kind = Literal["local", "global"]


def _looks_like_matrix(rd: Reader, rows: int) -> bool:
    """Whether the next tokens start a NumericsMatrix with ``rows`` rows (H after M)."""
    storage, size0, size1 = rd.peek_int(0), rd.peek_int(1), rd.peek_int(2)
    return storage is not None and size0 == rows and size1 is not None


def _trailing(rd: Reader) -> str:
    """A note on what follows mu, if anything."""
    extra = rd.tokens[rd.pos :]
    if not extra:
        return ""
    if len(extra) == 1 and extra[0] in ("0", "1"):
        return f"; trailing isComplete flag {extra[0]} (old Siconos format) ignored"
    return f"; {len(extra)} trailing tokens after mu ignored (from {rd.where(rd.pos)})"


def _read_text(path: Path) -> str:
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise ProblemFileError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise ProblemFileError(f"{path}: is a directory, not a Siconos file") from None
    except PermissionError:
        raise ProblemFileError(f"{path}: cannot be read (permission denied)") from None
    except OSError as exc:
        raise ProblemFileError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if not data.strip():
        raise ProblemFileError(f"{path}: empty file")
    nul = data.find(b"\x00")
    if nul >= 0:
        raise ProblemFileError(
            f"{path}: not a Siconos text file (binary data: NUL byte at offset {nul})"
        )
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ProblemFileError(
            f"{path}: not a Siconos text file (byte 0x{data[exc.start]:02x} at offset "
            f"{exc.start} is not text)"
        ) from None


def read_siconos(
    path: str | os.PathLike[str], kind: Kind | None = None
) -> LocalProblem | GlobalProblem:
    """Read a Siconos numerics text file of a frictional contact problem.

    ``kind`` forces ``"local"`` (``W``, ``q``, ``mu``) or ``"global"`` (``M``,
    ``H``, ``q``, ``b``, ``mu``); by default it is detected: after the first
    matrix, a local file holds exactly its ``q`` and ``mu`` (and possibly the
    old ``isComplete`` flag) while a global file continues with the header of
    ``H`` (a storage type and ``ndof`` rows).

    Matrices are returned as float64 ``csc_matrix``; ``title`` is the file stem,
    ``source`` the path. Raises :class:`~cocd.errors.ProblemFileError`.
    """
    if kind not in (None, "local", "global"):
        raise ProblemError(f"kind must be 'local', 'global' or None, got {kind!r}")
    p, source = Path(path), str(path)
    rd = Reader(source, _read_text(p))
    dim = rd.integer("dimension", choices=(2, 3))
    nc = rd.integer("number of contacts", lo=1)
    m_nc = dim * nc
    first = read_matrix(rd, {"local": "W", "global": "M", None: "W (or M)"}[kind])
    rows, cols = first.A.shape
    detected = kind is None
    if kind is None:
        square_local = (rows, cols) == (m_nc, m_nc)
        if square_local and rd.left in (m_nc + nc, m_nc + nc + 1):
            kind = "local"
        elif _looks_like_matrix(rd, cols):
            kind = "global"
        else:
            kind = "local"
    try:
        if kind == "local":
            if (rows, cols) != (m_nc, m_nc):
                also = (
                    f", and no matrix H with {cols} rows follows it as in a global file"
                    if detected
                    else ""
                )
                raise rd.error(
                    f"W is {rows} x {cols} but {nc} contacts of dimension {dim} need "
                    f"{m_nc} x {m_nc}{also}",
                )
            q = rd.floats(m_nc, "q")
            mu, note = _mu_and_note(rd, nc)
            about = f"Siconos local {dim}D problem, W {first.storage}{note}"
            return LocalProblem(first.A, q, mu, dim, title=p.stem, description=about, source=source)
        if rows != cols:
            raise rd.error(f"M is {rows} x {cols}: a global problem's M must be square")
        H = read_matrix(rd, "H")
        if H.A.shape != (rows, m_nc):
            raise rd.error(
                f"H is {H.A.shape[0]} x {H.A.shape[1]} but M is {rows} x {cols} and {nc} "
                f"contacts of dimension {dim} need H {rows} x {m_nc}"
            )
        f = rd.floats(rows, "q (the global f)")
        w = rd.floats(m_nc, "b (the global w)")
        mu, note = _mu_and_note(rd, nc)
        about = f"Siconos global {dim}D problem, M {first.storage}, H {H.storage}{note}"
        return GlobalProblem(
            first.A, H.A, f, w, mu, dim, title=p.stem, description=about, source=source
        )
    except ProblemFileError:
        raise
    except ProblemError as exc:
        message = str(exc)
        if not message.startswith(f"{path}: "):
            message = f"{path}: {message}"
        raise ProblemFileError(message) from None


def _mu_and_note(rd: Reader, nc: int) -> tuple[NDArray[np.float64], str]:
    """The ``nc`` friction coefficients, checked, and a note on what follows them."""
    mu = rd.floats(nc, "mu")
    bad = np.flatnonzero(mu < 0.0)
    if bad.size:
        at = rd.pos - mu.size + int(bad[0])
        raise rd.error(f"mu[{int(bad[0])}] is {mu[bad[0]]:g}: friction must be >= 0", at)
    return mu, _trailing(rd)
