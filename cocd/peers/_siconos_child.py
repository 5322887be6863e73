"""One Siconos solve, run by :mod:`cocd.peers.siconos` in a child process.

Runs under the Python that has Siconos (the system's, 3.11 on Debian 12), so it
imports only the standard library, numpy and ``siconos.numerics``: no cocd, no
scipy. Usage::

    python _siconos_child.py probe          # prints what this Siconos offers, as JSON
    python _siconos_child.py solve WORKDIR

``WORKDIR/request.json`` names the problem's form (``local`` or ``global``),
the solver constant (``SICONOS_FRICTION_3D_NSGS``, ...), the driver
(``fc2d_driver``, ``fc3d_driver``, ``gfc3d_driver``), ``tol``, ``max_iter`` and
``time_limit``. ``WORKDIR/problem.npz`` holds the numbers, sparse matrices as
COO triplets:

- local ``u = W r + q``: ``W_row, W_col, W_val, n, q, mu, dim``;
- global ``M v = H r + f``, ``u = H' v + w``: ``M_*`` (ndof x ndof), ``H_*``
  (ndof x m), ``f``, ``w``, ``mu``, ``dim``.

A local ``W`` becomes a sparse-block matrix (Siconos's storage for contact
problems, the only sparse one its 2D solvers take) read from a text file
written here with every digit (``repr``), so that Siconos solves exactly the
numbers cocd judges; global ``M`` and ``H`` are CSparse triplet matrices.

Only the driver call is timed. It runs under ``SIGALRM`` at ``time_limit``
seconds with the default action, so an overrun ends the process by that
signal, which the parent reports as ``time_limit``. The answer goes to
``WORKDIR/answer.npz`` (``r``, ``u`` and, for a global problem, ``v``) and
``WORKDIR/answer.json`` (``info``, ``iterations``, ``error``: Siconos's own
error, ``solve_s``, ``build_s``, ``import_s``).
"""

from __future__ import annotations

import json
import os
import signal
import sys
import time
from typing import Any

import numpy as np

#: Prefixes of the constants naming solvers, and the drivers, that :func:`probe` reports.
PREFIXES = (
    "SICONOS_FRICTION_2D_",
    "SICONOS_FRICTION_3D_",
    "SICONOS_GLOBAL_FRICTION_2D_",
    "SICONOS_GLOBAL_FRICTION_3D_",
)
DRIVERS = ("fc2d_driver", "fc3d_driver", "gfc2d_driver", "gfc3d_driver")


def _siconos() -> tuple[Any, Any]:
    """``siconos`` and ``siconos.numerics``.

    This file sits beside cocd's ``siconos.py``, and Python puts a script's folder
    first on the path: that folder is taken off it, so that ``import siconos``
    finds Siconos.
    """
    here = os.path.dirname(os.path.abspath(__file__))
    sys.path[:] = [p for p in sys.path if os.path.abspath(p or os.curdir) != here]
    import siconos
    import siconos.numerics as sn

    return siconos, sn


def probe() -> dict[str, Any]:
    """The Siconos version, its solver constants and drivers."""
    siconos, sn = _siconos()
    release = str(getattr(siconos, "version", "") or getattr(siconos, "__version__", ""))
    names = sorted(n for n in dir(sn) if n.startswith(PREFIXES) and not n.endswith("_STR"))
    return {
        "version": release,
        "python": sys.version.split()[0],
        "numpy": np.__version__,
        "constants": names,
        "drivers": [d for d in DRIVERS if hasattr(sn, d)],
    }


def _sbm_text(n: int, dim: int, row: Any, col: Any, val: Any) -> str:
    """``W`` (COO) as a Siconos matrix file in sparse-block storage (type 1).

    Blocks are ``dim x dim``, one per pair of contacts that ``W`` couples plus
    every diagonal one; within a row of blocks they are sorted by column, and
    each is written column-major, as ``SBM_new_from_file`` reads them.
    """
    nb = n // dim
    diag = np.arange(nb, dtype=np.int64) * dim
    row = np.concatenate([np.asarray(row, dtype=np.int64), diag])
    col = np.concatenate([np.asarray(col, dtype=np.int64), diag])
    val = np.concatenate([np.asarray(val, dtype=np.float64), np.zeros(nb)])
    keys = (row // dim) * nb + col // dim
    blocks, where = np.unique(keys, return_inverse=True)
    data = np.zeros((blocks.size, dim, dim))
    np.add.at(data, (where, row % dim, col % dim), val)
    block_row, block_col = blocks // nb, blocks % nb
    starts = np.concatenate([[0], np.cumsum(np.bincount(block_row, minlength=nb))])
    sizes = " ".join(str(dim * (k + 1)) for k in range(nb))
    lines = [
        "1",
        str(n),
        str(n),
        str(blocks.size),
        str(nb),
        str(nb),
        sizes,
        sizes,
        str(nb + 1),
        str(blocks.size),
        " ".join(map(str, starts.tolist())),
        " ".join(map(str, block_col.tolist())),
    ]
    for k in range(blocks.size):
        lines.append(str(k))
        lines.extend(repr(float(x)) for x in data[k].T.reshape(-1))
    return "\n".join(lines) + "\n"


def _triplet(sn: Any, row: Any, col: Any, val: Any, shape: tuple[int, int]) -> Any:
    """A CSparse triplet NumericsMatrix from COO arrays."""
    A = sn.NM_create(sn.NM_SPARSE, int(shape[0]), int(shape[1]))
    sn.NM_triplet_alloc(A, max(1, len(val)))
    for i, j, x in zip(row.tolist(), col.tolist(), val.tolist(), strict=True):
        sn.NM_entry(A, int(i), int(j), float(x))
    return A


def _vector(data: Any, name: str) -> Any:
    return np.ascontiguousarray(data[name], dtype=np.float64).reshape(-1)


def solve(workdir: str) -> dict[str, Any]:
    """Build the problem of ``workdir``, run the driver under the time limit, write the answer."""
    with open(os.path.join(workdir, "request.json")) as f:
        request = json.load(f)
    start = time.perf_counter()
    _, sn = _siconos()
    import_s = time.perf_counter() - start
    start = time.perf_counter()
    data = np.load(os.path.join(workdir, "problem.npz"))
    dim = int(data["dim"])
    mu = _vector(data, "mu")
    # The problem structures point into the arrays handed to Siconos: they stay
    # bound to local names until the driver has returned.
    if request["form"] == "local":
        n = int(data["n"])
        path = os.path.join(workdir, "W.txt")
        with open(path, "w") as f:
            f.write(_sbm_text(n, dim, data["W_row"], data["W_col"], data["W_val"]))
        W = sn.NM_new_from_filename(path)
        q = _vector(data, "q")
        problem = sn.FrictionContactProblem(dim, W, q, mu)
        m = n
        ndof = 0
    else:
        ndof, m = int(data["ndof"]), int(data["m"])
        M = _triplet(sn, data["M_row"], data["M_col"], data["M_val"], (ndof, ndof))
        H = _triplet(sn, data["H_row"], data["H_col"], data["H_val"], (ndof, m))
        f_vec, w_vec = _vector(data, "f"), _vector(data, "w")
        # The Python constructor takes no (M, H, f, w, mu): the fields are set one by one.
        problem = sn.GlobalFrictionContactProblem()
        problem.dimension = dim
        problem.numberOfContacts = m // dim
        problem.M, problem.H = M, H
        problem.q, problem.b, problem.mu = f_vec, w_vec, mu
    driver = getattr(sn, request["driver"])

    def call() -> tuple[Any, ...]:
        """One driver call from r = u = v = 0 with fresh options: its time and answer."""
        options = sn.SolverOptions(getattr(sn, request["constant"]))
        options.dparam[sn.SICONOS_DPARAM_TOL] = float(request["tol"])
        options.iparam[sn.SICONOS_IPARAM_MAX_ITER] = int(request["max_iter"])
        r, u, v = np.zeros(m), np.zeros(m), np.zeros(ndof)
        begin = time.perf_counter()
        if request["form"] == "local":
            info = driver(problem, r, u, options)
        else:
            info = driver(problem, r, u, v, options)
        return time.perf_counter() - begin, info, options, r, u, v

    build_s = time.perf_counter() - start
    limit = request.get("time_limit")
    if limit:
        # Default action: an overrun ends this process with SIGALRM, in C code too.
        signal.signal(signal.SIGALRM, signal.SIG_DFL)
        signal.setitimer(signal.ITIMER_REAL, float(limit))
    solve_s, info, options, r, u, v = call()
    signal.setitimer(signal.ITIMER_REAL, 0.0)
    # A short call is made again (cocd's short solves are too) and the median kept.
    times = [solve_s]
    while solve_s < float(request.get("repeat_below", 0.0)) and len(times) < int(
        request.get("repeats", 1)
    ):
        times.append(call()[0])
    solve_s = float(np.median(times))
    arrays: dict[str, Any] = {"r": r, "u": u}
    if request["form"] == "global":
        arrays["v"] = v
    np.savez(os.path.join(workdir, "answer.npz"), **arrays)
    answer = {
        "info": int(info),
        "iterations": int(options.iparam[sn.SICONOS_IPARAM_ITER_DONE]),
        "error": float(options.dparam[sn.SICONOS_DPARAM_RESIDU]),
        "solve_s": solve_s,
        "runs": len(times),
        "build_s": build_s,
        "import_s": import_s,
    }
    with open(os.path.join(workdir, "answer.json"), "w") as f:
        json.dump(answer, f)
    return answer


def main(argv: list[str]) -> int:
    if len(argv) == 2 and argv[1] == "probe":
        print(json.dumps(probe()))
        return 0
    if len(argv) == 3 and argv[1] == "solve":
        solve(argv[2])
        # The answer is written: leave without running Siconos's destructors, which
        # may free arrays twice when the problem's fields were set from Python.
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(0)
    print("usage: _siconos_child.py probe | solve WORKDIR", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv))
