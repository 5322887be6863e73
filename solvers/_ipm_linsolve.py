"""The linear solvers of :mod:`solvers.ipm_`: PARDISO, CHOLMOD and QDLDL on ``K``.

Each factors the reduced matrix ``K`` given by its upper triangle in CSR form
(its pattern fixed, its values new at every iteration) and solves with it:
``factor(data)`` for new values, ``solve(rhs)``, ``close()``; ``factor_nnz`` is
the factor's size where the library reports it.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
from typing import Any

import numpy as np
import scipy.sparse as sp

from solvers.base import installed

__all__ = ["LINEAR", "LINSOLVES", "default_linsolve", "openblas_single"]

_PARDISO: list[Any] = []  # one PyPardisoSolver per process: creating one searches for MKL


class _Pardiso:
    """PARDISO through pypardiso's MKL binding, with the 1-based CSR arrays kept."""

    def __init__(self, K: sp.csr_matrix, threads: int) -> None:
        import pypardiso

        if not _PARDISO:
            solver = pypardiso.PyPardisoSolver(mtype=2)  # real SPD
            # Explicit parameters (iparm[0] = 1): with the defaults (iparm[0] = 0) MKL
            # runs iterative refinement in every solve, which made each solve several
            # times slower for no accuracy gained: ipm refines against K itself when it
            # has to.
            ip = solver.iparm
            ip[:] = 0
            ip[0] = 1  # parameters given below
            ip[1] = 2  # METIS nested dissection
            ip[7] = 0  # no iterative refinement in the solve phase
            ip[9] = 13  # pivot perturbation 1e-13 (indefinite types only)
            ip[17] = -1  # report the factor's nonzeros
            _PARDISO.append(solver)
        self.solver = _PARDISO[0]
        # An input (< 0: report) that PARDISO overwrites with the count: ask again for
        # every matrix, or the handle shared between solves reports the first one's.
        self.solver.iparm[17] = -1
        setter = getattr(self.solver.libmkl, "MKL_Set_Num_Threads", None)
        if setter is not None:
            setter(ctypes.c_int(threads))
        self.n = K.shape[0]
        self.data = np.ascontiguousarray(K.data, dtype=np.float64)
        self.ia = (K.indptr + 1).astype(np.int32)
        self.ja = (K.indices + 1).astype(np.int32)
        self.call(11, np.zeros(self.n))

    def call(self, phase: int, b: Any) -> Any:
        s = self.solver
        b = np.ascontiguousarray(b, dtype=np.float64)
        x = np.zeros_like(b)
        error = ctypes.c_int32(0)
        i32 = ctypes.POINTER(ctypes.c_int32)
        f64 = ctypes.POINTER(ctypes.c_double)
        s._mkl_pardiso(
            s.pt.ctypes.data_as(ctypes.POINTER(s._pt_type[0])),
            ctypes.byref(ctypes.c_int32(1)),
            ctypes.byref(ctypes.c_int32(1)),
            ctypes.byref(ctypes.c_int32(s.mtype)),
            ctypes.byref(ctypes.c_int32(phase)),
            ctypes.byref(ctypes.c_int32(self.n)),
            self.data.ctypes.data_as(f64),
            self.ia.ctypes.data_as(i32),
            self.ja.ctypes.data_as(i32),
            s.perm.ctypes.data_as(i32),
            ctypes.byref(ctypes.c_int32(1)),
            s.iparm.ctypes.data_as(i32),
            ctypes.byref(ctypes.c_int32(0)),
            b.ctypes.data_as(f64),
            x.ctypes.data_as(f64),
            ctypes.byref(error),
        )
        if error.value != 0:
            raise np.linalg.LinAlgError(f"PARDISO phase {phase} failed with error {error.value}")
        return x

    def factor(self, data: Any) -> None:
        self.data[:] = data
        self.call(22, np.zeros(self.n))

    @property
    def factor_nnz(self) -> int | None:
        """Nonzeros of the Cholesky factor (PARDISO's report)."""
        return int(self.solver.iparm[17])

    def solve(self, rhs: Any) -> Any:
        return self.call(33, rhs)

    def close(self) -> None:
        self.call(-1, np.zeros(self.n))


class _Cholmod:
    def __init__(self, K: sp.csr_matrix, threads: int) -> None:
        from cvxopt import cholmod, matrix, spmatrix

        self.cholmod, self.matrix, self.spmatrix = cholmod, matrix, spmatrix
        # Upper CSR of K is the lower CSC of K: hand CHOLMOD the lower triangle.
        n = K.shape[0]
        self.n = n
        self.I = matrix(K.indices, tc="i")
        cols = np.repeat(np.arange(n), np.diff(K.indptr))
        self.J = matrix(cols, tc="i")
        self.K = K
        self.F = cholmod.symbolic(self._matrix(K.data), uplo="L")

    def _matrix(self, data: Any) -> Any:
        return self.spmatrix(
            self.matrix(np.ascontiguousarray(data)), self.I, self.J, (self.n, self.n)
        )

    factor_nnz = None

    def factor(self, data: Any) -> None:
        self.cholmod.numeric(self._matrix(data), self.F)

    def solve(self, rhs: Any) -> Any:
        B = self.matrix(np.ascontiguousarray(rhs, dtype=np.float64))
        self.cholmod.solve(self.F, B)
        return np.array(B).reshape(-1)

    def close(self) -> None:
        pass


class _Qdldl:
    def __init__(self, K: sp.csr_matrix, threads: int) -> None:
        # The upper CSR of K read column by column: QDLDL takes the upper CSC.
        marker = sp.csr_matrix((np.arange(1.0, K.nnz + 1.0), K.indices, K.indptr), K.shape)
        self.upper_csc = sp.csc_matrix(marker)
        self.upper_csc.sort_indices()
        self._perm = (self.upper_csc.data - 1.0).astype(np.int64)
        self.F: Any = None
        self.factor_nnz: int | None = None

    def factor(self, data: Any) -> None:
        import qdldl

        self.upper_csc.data[:] = np.asarray(data)[self._perm]
        if self.F is None:
            self.F = qdldl.Solver(self.upper_csc)
        else:
            self.F.update(self.upper_csc)

    def solve(self, rhs: Any) -> Any:
        return np.asarray(self.F.solve(np.asarray(rhs, dtype=np.float64))).reshape(-1)

    def close(self) -> None:
        pass


#: The linear solvers by name, the fastest first (``results/full/table1.md``).
LINEAR: dict[str, Any] = {"pardiso": _Pardiso, "cholmod": _Cholmod, "qdldl": _Qdldl}
LINSOLVES = tuple(LINEAR)


def default_linsolve() -> str:
    """The first installed of :data:`LINSOLVES`."""
    if installed("pypardiso"):
        return "pardiso"
    if installed("cvxopt"):
        return "cholmod"
    return "qdldl"


@functools.cache
def _openblas() -> Any:
    """threadpoolctl's controller of the OpenBLAS libraries loaded now (None: none)."""
    try:
        from threadpoolctl import ThreadpoolController
    except ImportError:  # pragma: no cover - a dependency
        return None
    controller = ThreadpoolController().select(internal_api="openblas")
    return controller if controller.lib_controllers else None


def openblas_single(linsolve: str) -> contextlib.AbstractContextManager[Any]:
    """OpenBLAS on one thread while PARDISO works, for one solve.

    MKL's OpenMP threads keep spinning after each PARDISO call, and OpenBLAS's own
    threads (numpy's vector products between the factorisations) then fight them
    for the cores: on 2 cores a step of a 2000-disc collapse took 0.82 s with both
    pools at 2 threads and 0.29 s with OpenBLAS at 1. The ipm's vector work is too
    small to gain from threads. Other linear solvers are left alone.
    """
    controller = _openblas() if linsolve == "pardiso" else None
    return controller.limit(limits=1) if controller is not None else contextlib.nullcontext()
