"""NumericsMatrix reading for the Siconos text files (:mod:`cocd.io.siconos`).

A NumericsMatrix (``NM_write_in_file`` / ``NM_new_from_file``) is its storage
type, then ``size0`` (rows) and ``size1`` (columns), then by storage:

- **0, dense**: ``size0 size1`` again, then the ``size0 size1`` values in
  column-major order (``A[i, j]`` is value ``i + j size0``);
- **1, sparse-block** (``SBM_write_in_file``): ``nbblocks``; if it is not 0,
  ``blocknumber0``, ``blocknumber1``, the cumulative row block sizes
  ``blocksize0`` (``blocknumber0`` integers, the last is ``size0``), the
  cumulative column block sizes ``blocksize1``, ``filled1``, ``filled2`` (the
  number of blocks), ``index1_data`` (``filled1`` block-row pointers: the
  blocks of block row ``i`` are numbers ``index1_data[i]`` to
  ``index1_data[i+1] - 1``), ``index2_data`` (``filled2`` block-column
  indices), then for each block in order its number and its values in
  column-major order;
- **2, sparse** (``NSM_write_in_file``): the origin (1 triplet, 2 compressed
  column, 3 compressed row), then CSparse's text dump (``cs_print``): a line
  ``CSparse Version ...``, a line ``m-by-n, nzmax: K nnz: L, 1-norm: x``
  followed for each column ``j`` by ``col j : locations a to b`` and the entries
  ``i : x`` (compressed), or a line ``triplet: m-by-n, nzmax: K nnz: L``
  followed by ``L`` entries ``i j : x`` (triplet; duplicates add up, as in
  CSparse). These values are printed with ``%g``: 6 significant digits.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from cocd.errors import ProblemFileError

__all__ = ["Matrix", "Reader", "read_matrix"]

_INT = re.compile(r"[+-]?\d{1,18}\Z")
_FLOAT = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?\Z")
_CS_SIZE = re.compile(
    r"(triplet:\s+)?(\d+)-by-(\d+),\s+nzmax:\s+(\d+)\s+nnz:\s+(\d+)(?:,\s+1-norm:\s+\S+)?\s*\Z"
)
_ORIGIN_NAMES = {1: "triplet", 2: "compressed-column", 3: "compressed-row"}


@dataclass
class Matrix:
    A: sp.csc_matrix
    storage: str


class Reader:
    """The file's tokens, with their line numbers, and a cursor."""

    def __init__(self, path: str, text: str) -> None:
        self.path = path
        self.lines = text.split("\n")
        tokens: list[str] = []
        counts: list[int] = []
        for line in self.lines:
            parts = line.split()
            tokens.extend(parts)
            counts.append(len(parts))
        self.tokens = tokens
        self.line_of = np.repeat(np.arange(1, len(self.lines) + 1), counts)
        self.pos = 0

    # -- messages ---------------------------------------------------------------
    def error(self, message: str, at: int | None = None) -> ProblemFileError:
        if at is None:
            return ProblemFileError(f"{self.path}: {message}")
        return ProblemFileError(f"{self.path}: {self.where(at)}: {message}")

    def where(self, i: int) -> str:
        if i >= len(self.tokens):
            return "end of file"
        return f"line {int(self.line_of[i])}"

    @property
    def left(self) -> int:
        return len(self.tokens) - self.pos

    def need(self, n: int, what: str) -> None:
        if self.left < n:
            raise self.error(f"truncated: expected {n} {what}, found {self.left}")

    # -- scalars ----------------------------------------------------------------
    def peek_int(self, offset: int = 0) -> int | None:
        i = self.pos + offset
        if i < len(self.tokens) and _INT.match(self.tokens[i]):
            return int(self.tokens[i])
        return None

    def integer(self, what: str, *, lo: int | None = None, choices: tuple[int, ...] = ()) -> int:
        """The next token as an integer ``what`` (``>= lo``, one of ``choices``)."""
        if self.left < 1:
            raise self.error(f"truncated: expected the {what}, found the end of the file")
        i = self.pos
        tok = self.tokens[i]
        alts = ", ".join(map(str, choices[:-1])) + f" or {choices[-1]}" if choices else ""
        if not _INT.match(tok):
            kind = f"an integer {alts}" if choices else "an integer"
            raise self.error(f"expected the {what}, {kind}, got {tok!r}", i)
        value = int(tok)
        if choices and value not in choices:
            raise self.error(f"{what} must be {alts}, got {value}", i)
        if lo is not None and value < lo:
            raise self.error(f"{what} must be >= {lo}, got {value}", i)
        self.pos += 1
        return value

    # -- arrays -----------------------------------------------------------------
    def take(self, n: int, what: str) -> tuple[int, list[str]]:
        """The position of the next ``n`` tokens and the tokens; moves past them."""
        self.need(n, what)
        start = self.pos
        self.pos += n
        return start, self.tokens[start : start + n]

    def floats(self, n: int, what: str) -> NDArray[np.float64]:
        """The next ``n`` tokens as finite floats."""
        start, chunk = self.take(n, f"value{'s' if n != 1 else ''} of {what}")
        return self.to_floats(chunk, start, 1, what)

    def to_floats(
        self, chunk: list[str], start: int, stride: int, what: str
    ) -> NDArray[np.float64]:
        """Convert ``chunk`` (token ``k`` at position ``start + k stride``)."""
        matches = list(map(_FLOAT.match, chunk))
        try:
            k = matches.index(None)
        except ValueError:
            k = -1
        if k >= 0:
            tok = chunk[k]
            at = start + k * stride
            low = tok.lower().lstrip("+-")
            if low == "nan":
                raise self.error(f"NaN in {what}", at)
            if low in ("inf", "infinity"):
                raise self.error(f"infinite value {tok!r} in {what}", at)
            raise self.error(f"expected a number in {what}, got {tok!r}", at)
        values = np.array(chunk, dtype=np.float64)
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            at = start + int(bad[0]) * stride
            raise self.error(f"value {chunk[int(bad[0])]!r} in {what} is out of range", at)
        return values

    def to_ints(self, chunk: list[str], start: int, stride: int, what: str) -> NDArray[np.int64]:
        matches = list(map(_INT.match, chunk))
        try:
            k = matches.index(None)
        except ValueError:
            return np.array(chunk, dtype=np.int64)
        raise self.error(f"expected an integer in {what}, got {chunk[k]!r}", start + k * stride)

    def ints(self, n: int, what: str) -> NDArray[np.int64]:
        """The next ``n`` tokens as integers."""
        start, chunk = self.take(n, f"integers of {what}")
        return self.to_ints(chunk, start, 1, what)

    # -- line-based pieces (CSparse header) -------------------------------------
    def line_text(self) -> tuple[int, str]:
        """The text of the current token's line; moves past all its tokens."""
        if self.left < 1:
            raise self.error("truncated: expected a CSparse header line, found the end of the file")
        line = int(self.line_of[self.pos])
        end = int(np.searchsorted(self.line_of, line, side="right"))
        self.pos = end
        return line, self.lines[line - 1].strip()


def read_matrix(rd: Reader, name: str) -> Matrix:
    """One NumericsMatrix (``NM_new_from_file``)."""
    storage = rd.integer(f"storage type of {name}", choices=(0, 1, 2))
    at = rd.pos
    size0 = rd.integer(f"row count of {name}", lo=0)
    size1 = rd.integer(f"column count of {name}", lo=0)
    if size0 == 0 or size1 == 0:
        raise rd.error(f"{name} is {size0} x {size1}: a matrix must not be empty", at)
    if storage == 0:
        return _read_dense(rd, name, size0, size1)
    if storage == 1:
        return _read_sparse_block(rd, name, size0, size1)
    return _read_csparse(rd, name, size0, size1)


def _read_dense(rd: Reader, name: str, size0: int, size1: int) -> Matrix:
    at = rd.pos
    s0 = rd.integer(f"repeated row count of {name}", lo=0)
    s1 = rd.integer(f"repeated column count of {name}", lo=0)
    if (s0, s1) != (size0, size1):
        raise rd.error(
            f"dense {name}: the sizes are written twice and differ: "
            f"{size0} x {size1} then {s0} x {s1}",
            at,
        )
    values = rd.floats(size0 * size1, f"the dense {name}")
    A = sp.csc_matrix(values.reshape((size0, size1), order="F"))
    return Matrix(A, "dense")


def _read_sparse_block(rd: Reader, name: str, size0: int, size1: int) -> Matrix:
    what = f"sparse-block {name}"
    nbblocks = rd.integer(f"block count of {name}", lo=0)
    if nbblocks == 0:
        return Matrix(sp.csc_matrix((size0, size1)), "sparse-block")
    at = rd.pos
    nb0 = rd.integer(f"block-row count of {name}", lo=1)
    nb1 = rd.integer(f"block-column count of {name}", lo=1)
    if nb0 > size0 or nb1 > size1:
        raise rd.error(f"{what} has {nb0} x {nb1} blocks but is only {size0} x {size1}", at)
    rows_at = rd.pos
    cum0 = rd.ints(nb0, f"the row block sizes of {name}")
    cols_at = rd.pos
    cum1 = rd.ints(nb1, f"the column block sizes of {name}")
    for cum, size, which, where in (
        (cum0, size0, "row", rows_at),
        (cum1, size1, "column", cols_at),
    ):
        steps = np.diff(cum, prepend=0)
        if np.any(steps <= 0):
            raise rd.error(
                f"{what}: the cumulative {which} block sizes must increase, got {_preview(cum)}",
                where,
            )
        if cum[-1] != size:
            raise rd.error(
                f"{what}: the {which} blocks end at {int(cum[-1])} but the matrix has "
                f"{size} {which}s",
                where,
            )
    at = rd.pos
    filled1 = rd.integer(f"filled1 (block-row pointer count) of {name}", lo=1)
    filled2 = rd.integer(f"filled2 (stored block count) of {name}", lo=0)
    if filled1 > nb0 + 1:
        raise rd.error(f"{what}: filled1 is {filled1} but there are only {nb0} block rows", at)
    if filled2 != nbblocks:
        raise rd.error(f"{what}: filled2 is {filled2} but the block count is {nbblocks}", at)
    at = rd.pos
    ptr = rd.ints(filled1, f"the block-row pointers (index1_data) of {name}")
    if ptr[0] != 0 or ptr[-1] != nbblocks or np.any(np.diff(ptr) < 0):
        raise rd.error(
            f"{what}: the block-row pointers must rise from 0 to {nbblocks}, got {_preview(ptr)}",
            at,
        )
    at = rd.pos
    bcol = rd.ints(filled2, f"the block-column indices (index2_data) of {name}")
    bad = np.flatnonzero((bcol < 0) | (bcol >= nb1))
    if bad.size:
        raise rd.error(
            f"{what}: block {int(bad[0])} is in block column {int(bcol[bad[0]])}, "
            f"outside 0..{nb1 - 1}",
            at + int(bad[0]),
        )
    brow = np.repeat(np.arange(filled1 - 1), np.diff(ptr))
    key = brow * nb1 + bcol
    order = np.argsort(key, kind="stable")
    ordered = key[order]
    twice = np.flatnonzero(ordered[1:] == ordered[:-1])
    if twice.size:  # (a sort: np.unique hashes, far slower on many distinct keys)
        k = int(order[twice[0]])
        raise rd.error(f"{what}: block ({int(brow[k])}, {int(bcol[k])}) is stored twice", at + k)
    start0 = np.concatenate([[0], cum0[:-1]])
    start1 = np.concatenate([[0], cum1[:-1]])
    nr = (cum0 - start0)[brow]
    ncol = (cum1 - start1)[bcol]
    sizes = nr * ncol
    # For each block: its number, then its values (column-major).
    value_tokens: list[str] = []
    value_pos: list[int] = []
    for b in range(nbblocks):
        got = rd.integer(f"block number of block {b} of {name}", lo=0)
        if got != b:
            raise rd.error(f"{what}: expected block number {b}, got {got}", rd.pos - 1)
        n = int(sizes[b])
        start, chunk = rd.take(n, f"values of block {b} ({int(nr[b])} x {int(ncol[b])}) of {name}")
        value_pos.append(start)
        value_tokens.extend(chunk)
    values = _floats_at(rd, value_tokens, value_pos, sizes, f"the blocks of {name}")
    # Entry (i, j) of block b is value i + j nr[b] of that block.
    offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    k = np.arange(values.size) - np.repeat(offsets, sizes)
    nr_e = np.repeat(nr, sizes)
    rows = np.repeat(start0[brow], sizes) + k % nr_e
    cols = np.repeat(start1[bcol], sizes) + k // nr_e
    A = sp.csc_matrix((values, (rows, cols)), shape=(size0, size1))
    A.eliminate_zeros()
    return Matrix(A, "sparse-block")


def _floats_at(
    rd: Reader,
    tokens: list[str],
    starts: list[int],
    sizes: NDArray[np.int64],
    what: str,
) -> NDArray[np.float64]:
    """Floats of token runs ``tokens`` gathered from the positions ``starts``."""
    try:
        return rd.to_floats(tokens, 0, 1, what)
    except ProblemFileError:
        pass
    # Find the run holding the bad token to report its line.
    for start, n in zip(starts, sizes.tolist(), strict=True):
        rd.to_floats(rd.tokens[start : start + n], start, 1, what)
    raise AssertionError("unreachable")  # pragma: no cover


def _read_csparse(rd: Reader, name: str, size0: int, size1: int) -> Matrix:
    origin_at = rd.pos
    origin = rd.integer(f"sparse origin of {name}", choices=(1, 2, 3))
    if rd.left < 1 or rd.tokens[rd.pos] != "CSparse":
        got = "the end of the file" if rd.left < 1 else repr(rd.tokens[rd.pos])
        if rd.left < 1:
            raise rd.error(f"truncated: expected the 'CSparse Version' line of {name}, found {got}")
        raise rd.error(f"expected the 'CSparse Version' line of {name}, got {got}", rd.pos)
    rd.line_text()
    line, text = rd.line_text()
    match = _CS_SIZE.match(text)
    if match is None:
        raise rd.error(
            f"line {line}: expected the CSparse size line of {name} "
            f"('m-by-n, nzmax: k nnz: l' or 'triplet: m-by-n, ...'), got {text[:80]!r}"
        )
    triplet = match.group(1) is not None
    m, n, nzmax, nnz = (int(match.group(g)) for g in (2, 3, 4, 5))
    if (m, n) != (size0, size1):
        raise rd.error(
            f"line {line}: the CSparse dump of {name} is {m}-by-{n} but its header says "
            f"{size0} x {size1}"
        )
    if nnz > nzmax:
        raise rd.error(f"line {line}: {name} has nnz {nnz} > nzmax {nzmax}")
    if triplet != (origin == 1):
        layout = "triplet" if triplet else "compressed"
        raise rd.error(
            f"{name}: the sparse origin is {origin} ({_ORIGIN_NAMES[origin]}) but the CSparse "
            f"dump is {layout}",
            origin_at,
        )
    if triplet:
        A = _read_cs_triplet(rd, name, m, n, nnz)
        storage = "sparse (CSparse triplet)"
    else:
        if origin == 3 and m != n:
            raise rd.error(
                f"{name}: a compressed-row dump of a non-square matrix ({m} x {n}) is "
                "ambiguous (CSparse prints it by columns)",
                origin_at,
            )
        A = _read_cs_compressed(rd, name, m, n, nnz)
        if origin == 3:
            A = sp.csc_matrix(A.T)
            storage = "sparse (CSparse compressed-row)"
        else:
            storage = "sparse (CSparse compressed-column)"
    A.eliminate_zeros()
    return Matrix(A, storage)


def _read_cs_triplet(rd: Reader, name: str, m: int, n: int, nz: int) -> sp.csc_matrix:
    what = f"the triplet entries of {name}"
    start, chunk = rd.take(4 * nz, f"tokens of {what} ({nz} entries 'i j : x')")
    colons = chunk[2::4]
    if colons.count(":") != nz:
        k = next(k for k, t in enumerate(colons) if t != ":")
        raise rd.error(f"expected ':' in {what}, got {colons[k]!r}", start + 4 * k + 2)
    rows = rd.to_ints(chunk[0::4], start, 4, f"the row indices of {name}")
    cols = rd.to_ints(chunk[1::4], start + 1, 4, f"the column indices of {name}")
    vals = rd.to_floats(chunk[3::4], start + 3, 4, f"the values of {name}")
    _check_range(rd, rows, m, start, 4, f"row index of {name}")
    _check_range(rd, cols, n, start + 1, 4, f"column index of {name}")
    return sp.csc_matrix((vals, (rows, cols)), shape=(m, n))


def _read_cs_compressed(rd: Reader, name: str, m: int, n: int, nnz: int) -> sp.csc_matrix:
    toks = rd.tokens
    row_tokens: list[str] = []
    val_tokens: list[str] = []
    counts: list[int] = []
    starts: list[int] = []
    ptr = 0
    for j in range(n):
        p, head = rd.take(7, f"tokens of the column header 'col {j} : locations a to b' of {name}")
        for k, word in ((0, "col"), (2, ":"), (3, "locations"), (5, "to")):
            if head[k] != word:
                raise rd.error(
                    f"expected {word!r} in the header of column {j} of {name}, got {head[k]!r}",
                    p + k,
                )
        for k in (1, 4, 6):
            if not _INT.match(head[k]):
                raise rd.error(
                    f"expected an integer in the header of column {j} of {name}, got {head[k]!r}",
                    p + k,
                )
        if int(head[1]) != j:
            raise rd.error(f"expected column {j} of {name}, got column {head[1]}", p + 1)
        a, b = int(head[4]), int(head[6])
        if a != ptr:
            raise rd.error(f"column {j} of {name} starts at location {a}, expected {ptr}", p + 4)
        count = b - a + 1
        if count < 0 or b + 1 > nnz:
            raise rd.error(
                f"column {j} of {name} has locations {a} to {b}, outside 0..{nnz - 1}", p + 6
            )
        q, ent = rd.take(
            3 * count, f"tokens of the {count} entries 'i : x' of column {j} of {name}"
        )
        colons = ent[1::3]
        if colons.count(":") != count:
            k = next(k for k, t in enumerate(colons) if t != ":")
            raise rd.error(
                f"expected ':' in column {j} of {name}, got {colons[k]!r}", q + 3 * k + 1
            )
        row_tokens.extend(ent[0::3])
        val_tokens.extend(ent[2::3])
        counts.append(count)
        starts.append(q)
        ptr = b + 1
    if ptr != nnz:
        raise rd.error(f"{name}: the columns hold {ptr} entries but the header says nnz {nnz}")
    sizes = np.asarray(counts, dtype=np.int64)
    try:
        rows = rd.to_ints(row_tokens, 0, 1, "")
        vals = rd.to_floats(val_tokens, 0, 1, "")
    except ProblemFileError:
        for q, c in zip(starts, counts, strict=True):
            chunk = toks[q : q + 3 * c]
            rd.to_ints(chunk[0::3], q, 3, f"the row indices of {name}")
            rd.to_floats(chunk[2::3], q + 2, 3, f"the values of {name}")
        raise AssertionError("unreachable") from None  # pragma: no cover
    bad = np.flatnonzero((rows < 0) | (rows >= m))
    if bad.size:
        k = int(bad[0])
        col = int(np.searchsorted(np.cumsum(sizes), k, side="right"))
        q = starts[col] + 3 * (k - int(np.sum(sizes[:col])))
        raise rd.error(f"row index {int(rows[k])} of {name} is outside 0..{m - 1}", q)
    cols = np.repeat(np.arange(n), sizes)
    return sp.csc_matrix((vals, (rows, cols)), shape=(m, n))


def _check_range(
    rd: Reader, idx: NDArray[np.int64], size: int, start: int, stride: int, what: str
) -> None:
    bad = np.flatnonzero((idx < 0) | (idx >= size))
    if bad.size:
        k = int(bad[0])
        raise rd.error(f"{what} {int(idx[k])} is outside 0..{size - 1}", start + stride * k)


def _preview(a: NDArray[np.int64], n: int = 6) -> str:
    items = ", ".join(str(int(x)) for x in a[:n])
    return f"[{items}{', ...' if a.size > n else ''}]"
