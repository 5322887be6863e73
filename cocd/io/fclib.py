"""FCLib HDF5 problem files: read and write, local and global.

Layout (the FCLib library's own, as written by Siconos and LMGC90)::

    /fclib_local   W (matrix), vectors/q, vectors/mu, spacedim, info/{title,description,math_info}
    /fclib_global  M, H (matrices), vectors/f, vectors/w, vectors/mu, spacedim, info/...
    /solution      optional: r, u (and v for a global problem)
    /guesses       optional: number_of_guesses, 1/r, 1/u, ...

A matrix group holds ``m, n, nz, nzmax, p, i, x``: ``nz >= 0`` is a triplet
list (``i`` rows, ``p`` columns, ``nz`` entries), ``nz == -1`` compressed
columns (``p`` the ``n + 1`` column pointers, ``i`` row indices) and
``nz == -2`` compressed rows (``p`` the ``m + 1`` row pointers, ``i`` column
indices), as in CSparse. Matrices are written compressed by columns; reading
a written file gives back the same arrays bit for bit.

FCLib's optional equality constraints of a global problem (``G``, ``b``) are
not part of cocd's model: a file that has them is refused with a clear error.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from cocd.errors import ProblemError, ProblemFileError
from cocd.io.problems import ExternalSolution, GlobalProblem, LocalProblem

__all__ = ["HDF5_SIGNATURE", "is_hdf5", "read_fclib", "read_fclib_solution", "write_fclib"]

FloatArray = NDArray[np.float64]
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def is_hdf5(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` starts with the HDF5 signature."""
    try:
        with open(path, "rb") as fh:
            return fh.read(8) == HDF5_SIGNATURE
    except OSError:
        return False


def read_fclib(path: str | os.PathLike[str]) -> LocalProblem | GlobalProblem:
    """Read the problem of an FCLib HDF5 file (local or global).

    Raises :class:`~cocd.errors.ProblemFileError` naming the file and what is
    wrong (missing group or dataset, inconsistent sizes, indices out of range,
    non-finite values).
    """
    import h5py

    path = Path(path)
    if not path.is_file():
        raise ProblemFileError(f"{path}: no such file")
    try:
        fh = h5py.File(path, "r")
    except OSError as exc:
        raise ProblemFileError(f"{path}: not a readable HDF5 file ({exc})") from None
    try:
        with fh:
            return _read(fh, path)
    except ProblemFileError:
        raise
    except ProblemError as exc:
        raise ProblemFileError(f"{path}: {exc}") from None
    except (OSError, KeyError, ValueError, TypeError, IndexError, RuntimeError) as exc:
        reason = f"{type(exc).__name__}: {exc}"
        raise ProblemFileError(f"{path}: unreadable FCLib data ({reason})") from None


def _read(fh: Any, path: Path) -> LocalProblem | GlobalProblem:
    groups = [k for k in ("fclib_local", "fclib_global") if k in fh]
    if len(groups) != 1:
        found = ", ".join(sorted(fh.keys())) or "nothing"
        raise ProblemFileError(
            f"{path}: an FCLib file holds exactly one of the groups /fclib_local and "
            f"/fclib_global; found {found}"
        )
    kind = groups[0]
    g = fh[kind]
    where = f"{path}: /{kind}"
    dim = _int(g, "spacedim", where)
    info = _info(g)
    if kind == "fclib_local":
        W = _read_matrix(g, "W", where)
        q = _vec(g, "vectors/q", where)
        mu = _vec(g, "vectors/mu", where)
        ndof = None
        if "info" in g and "numberOfDegreeOfFreedom" in g["info"].attrs:
            ndof = int(np.asarray(g["info"].attrs["numberOfDegreeOfFreedom"]).reshape(-1)[0])
        try:
            return LocalProblem(W=W, q=q, mu=mu, dim=dim, source=str(path), ndof=ndof, **info)
        except ProblemError as exc:
            raise ProblemFileError(str(exc).replace(str(path), where, 1)) from None
    for extra in ("G", "vectors/b"):
        if extra in g and _size(g[extra]) > 0:
            raise ProblemFileError(
                f"{where}: has equality constraints ({extra}); cocd's global form is "
                "M v = H r + f, u = H'v + w without them"
            )
    M = _read_matrix(g, "M", where)
    H = _read_matrix(g, "H", where)
    f = _vec(g, "vectors/f", where)
    w = _vec(g, "vectors/w", where)
    mu = _vec(g, "vectors/mu", where)
    try:
        return GlobalProblem(M=M, H=H, f=f, w=w, mu=mu, dim=dim, source=str(path), **info)
    except ProblemError as exc:
        raise ProblemFileError(str(exc).replace(str(path), where, 1)) from None


def _size(obj: Any) -> int:
    if hasattr(obj, "size"):
        return int(obj.size)
    return len(obj)


def _dataset(g: Any, name: str, where: str) -> NDArray[Any]:
    if name not in g:
        raise ProblemFileError(f"{where}: missing dataset {name!r}")
    obj = g[name]
    if not hasattr(obj, "shape"):
        raise ProblemFileError(f"{where}: {name!r} is a group, expected a dataset")
    return np.asarray(obj[()])


def _vec(g: Any, name: str, where: str) -> FloatArray:
    a = _dataset(g, name, where)
    if not np.issubdtype(a.dtype, np.number):
        raise ProblemFileError(f"{where}: {name} holds {a.dtype}, expected numbers")
    a = a.astype(np.float64).reshape(-1)
    bad = np.flatnonzero(~np.isfinite(a))
    if bad.size:
        raise ProblemFileError(
            f"{where}: {name}[{bad[0]}] is {a[bad[0]]} ({bad.size} non-finite entries)"
        )
    return a


def _int(g: Any, name: str, where: str) -> int:
    a = _dataset(g, name, where).reshape(-1)
    if a.size != 1 or not np.issubdtype(a.dtype, np.integer):
        raise ProblemFileError(f"{where}: {name} must be one integer, got {a!r}")
    return int(a[0])


def _index(g: Any, name: str, where: str) -> NDArray[np.int64]:
    a = _dataset(g, name, where).reshape(-1)
    if a.size and not np.issubdtype(a.dtype, np.integer):
        raise ProblemFileError(f"{where}: {name} holds {a.dtype}, expected integers")
    return a.astype(np.int64)


def _info(g: Any) -> dict[str, str]:
    out: dict[str, str] = {}
    if "info" not in g or hasattr(g["info"], "shape"):
        return out
    for key in ("title", "description", "math_info"):
        if key in g["info"]:
            value = g["info"][key][()]
            if isinstance(value, bytes):
                value = value.decode("utf-8", errors="replace")
            out[key] = str(value).strip()
    return out


def _read_matrix(g: Any, name: str, where: str) -> sp.csc_matrix:
    if name not in g or hasattr(g[name], "shape"):
        raise ProblemFileError(f"{where}: missing matrix group {name!r}")
    mg = g[name]
    here = f"{where}/{name}"
    m, n, nz = (_int(mg, k, here) for k in ("m", "n", "nz"))
    if m < 0 or n < 0:
        raise ProblemFileError(f"{here}: negative size {m} x {n}")
    p = _index(mg, "p", here)
    i = _index(mg, "i", here)
    x = _vec(mg, "x", here)
    if nz >= 0:  # triplet: i rows, p columns
        if min(p.size, i.size, x.size) < nz:
            raise ProblemFileError(
                f"{here}: triplet of {nz} entries but p, i, x hold {p.size}, {i.size}, {x.size}"
            )
        rows, cols, vals = i[:nz], p[:nz], x[:nz]
        _check_range(rows, m, "row", here)
        _check_range(cols, n, "column", here)
        return sp.csc_matrix((vals, (rows, cols)), shape=(m, n))
    if nz not in (-1, -2):
        raise ProblemFileError(f"{here}: nz = {nz}; expected >= 0 (triplet), -1 (CSC) or -2 (CSR)")
    outer, inner = (n, m) if nz == -1 else (m, n)
    if p.size != outer + 1:
        raise ProblemFileError(
            f"{here}: {'column' if nz == -1 else 'row'} pointers p have {p.size} entries, "
            f"expected {outer + 1}"
        )
    if p[0] != 0 or np.any(np.diff(p) < 0):
        raise ProblemFileError(f"{here}: pointers p must start at 0 and never decrease")
    count = int(p[-1])
    if i.size < count or x.size < count:
        raise ProblemFileError(
            f"{here}: pointers announce {count} entries but i, x hold {i.size}, {x.size}"
        )
    _check_range(i[:count], inner, "column" if nz == -2 else "row", here)
    cls = sp.csc_matrix if nz == -1 else sp.csr_matrix
    return sp.csc_matrix(cls((x[:count], i[:count], p), shape=(m, n)))


def _check_range(idx: NDArray[np.int64], size: int, what: str, where: str) -> None:
    if idx.size and (idx.min() < 0 or idx.max() >= size):
        bad = idx[(idx < 0) | (idx >= size)][0]
        raise ProblemFileError(f"{where}: {what} index {bad} outside 0..{size - 1}")


def read_fclib_solution(path: str | os.PathLike[str]) -> ExternalSolution | None:
    """The ``/solution`` group of an FCLib file, or ``None`` when there is none.

    Many published files carry placeholder zeros there: never take it as a
    reference answer without checking its residual.
    """
    import h5py

    with h5py.File(path, "r") as fh:
        if "solution" not in fh:
            return None
        g = fh["solution"]
        where = f"{path}: /solution"
        r = _vec(g, "r", where)
        u = _vec(g, "u", where)
        v = _vec(g, "v", where) if "v" in g else None
        return ExternalSolution(r=r, u=u, v=v)


def write_fclib(
    path: str | os.PathLike[str],
    problem: LocalProblem | GlobalProblem,
    *,
    solution: ExternalSolution | None = None,
) -> Path:
    """Write ``problem`` (and an optional solution) as an FCLib HDF5 file.

    The file is written under a temporary name and renamed when complete, so a
    crash never leaves a half-written problem under ``path``.
    """
    import h5py

    path = Path(path)
    tmp = path.with_name(path.name + ".part")
    with h5py.File(tmp, "w") as fh:
        if isinstance(problem, LocalProblem):
            g = fh.create_group("fclib_local")
            _write_matrix(g, "W", problem.W)
            g["vectors/q"] = problem.q
            if problem.ndof is not None:
                g.create_group("info").attrs["numberOfDegreeOfFreedom"] = np.array(
                    [problem.ndof], dtype=np.int32
                )
        else:
            g = fh.create_group("fclib_global")
            _write_matrix(g, "M", problem.M)
            _write_matrix(g, "H", problem.H)
            g["vectors/f"] = problem.f
            g["vectors/w"] = problem.w
        g["vectors/mu"] = problem.mu
        g["spacedim"] = np.array([problem.dim], dtype=np.int32)
        info = g.require_group("info")
        for key in ("title", "description", "math_info"):
            info[key] = np.bytes_(getattr(problem, key).encode("utf-8"))
        if solution is not None:
            s = fh.create_group("solution")
            for key, value in solution.arrays().items():
                s[key] = value
    os.replace(tmp, path)
    return path


def _write_matrix(g: Any, name: str, A: sp.spmatrix) -> None:
    A = sp.csc_matrix(A)
    mg = g.create_group(name)
    mg["m"] = np.array([A.shape[0]], dtype=np.int32)
    mg["n"] = np.array([A.shape[1]], dtype=np.int32)
    mg["nz"] = np.array([-1], dtype=np.int32)
    mg["nzmax"] = np.array([A.nnz], dtype=np.int32)
    mg["p"] = A.indptr.astype(np.int32)
    mg["i"] = A.indices.astype(np.int32)
    mg["x"] = A.data.astype(np.float64)
