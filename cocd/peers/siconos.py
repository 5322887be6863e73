"""Siconos's frictional-contact solvers, run on cocd's problems in a child process.

Siconos (``siconos.numerics``) is usually installed for the system's Python
(Debian: ``apt-get install python3-siconos``), not for the one cocd runs in.
Each solve therefore runs ``_siconos_child.py`` under that Python
(``/usr/bin/python3``, or the one ``$COCD_SICONOS_PYTHON`` names), exchanging
files in a temporary folder: cocd writes the problem's numbers (``problem.npz``:
sparse matrices as COO triplets, vectors) and the request (``request.json``);
the child builds the Siconos problem from exactly those numbers, runs the
driver and writes ``r``, ``u`` (and ``v``) with its iteration count, its own
error, its ``info`` code and the driver's time back.

Solver names: ``siconos:NSGS`` runs Siconos's NSGS on the problem as the file
states it (``fc2d_driver`` / ``fc3d_driver`` for a local problem,
``gfc3d_driver`` for a global one); ``siconos:NSGS(condensed)`` runs the local
solver on a global problem's condensed form ``W = H' M^-1 H``,
``q = w + H' M^-1 f``, computed by cocd (:meth:`GlobalProblem.local`), whose
time is then the run's ``setup_s``. Siconos 4.4 has no 2D global driver, so a
2D global problem is solved condensed only.

The answer is judged by cocd (:meth:`natural_map_error` of the problem as read,
the same function as for cocd's backends); Siconos's own error is kept beside it.
Only the driver call is timed (``solve_s``; a call under
:data:`cocd.bench.runner.SHORT_SOLVE_S` is made again from the same start, up to
:data:`~cocd.bench.runner.SHORT_SOLVE_REPEATS` calls, and the median kept, as cocd's
short solves are); ``wall_s`` is the whole child, from the start of its Python to its
answer.
"""

from __future__ import annotations

import functools
import json
import os
import resource
import signal
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp

from cocd.bench.runner import SHORT_SOLVE_REPEATS, SHORT_SOLVE_S
from cocd.errors import CocdError, ProblemError
from cocd.io.problems import GlobalProblem, LocalProblem

__all__ = [
    "CONDENSED",
    "DEFAULTS",
    "ENV",
    "INSTALL",
    "SOLVERS",
    "Condensed",
    "applicable",
    "condense",
    "default_solvers",
    "full_name",
    "judge",
    "parse",
    "peer_unavailable_reason",
    "probe",
    "python",
    "solve",
    "solvers_for",
]

ExternalProblem = LocalProblem | GlobalProblem

#: The environment variable naming the Python that imports ``siconos.numerics``.
ENV = "COCD_SICONOS_PYTHON"
DEFAULT_PYTHON = "/usr/bin/python3"
#: How to get it on Debian and Ubuntu.
INSTALL = "apt-get update && apt-get install python3-siconos"
CHILD = Path(__file__).with_name("_siconos_child.py")
PREFIX = "siconos:"
CONDENSED = "(condensed)"
#: Iterations allowed when none are given: that of cocd's Gauss-Seidel ``nscd``.
DEFAULT_MAX_ITER = 20_000
#: Seconds the child may take besides the driver call (Python, imports, building).
GRACE = 60.0

Form = tuple[str, int]  # ("local" | "global", dimension): what Siconos is handed

#: Siconos's solvers by the form they take, as ``SICONOS_..._<NAME>`` calls them.
#: Left out: GAMS and PATH (not in the Debian build), NSGSV (dense storage only),
#: the fc3d local (one-contact) solvers.
SOLVERS: dict[Form, tuple[str, ...]] = {
    ("local", 2): ("NSGS", "CPG", "LEMKE", "ENUM"),
    ("local", 3): (
        "NSGS",
        "NSN_AC",
        "NSN_AC_TEST",
        "NSN_FB",
        "NSN_NM",
        "PROX",
        "ADMM",
        "VI_FPP",
        "VI_EG",
        "FPP",
        "EG",
        "TFP",
        "DSFP",
        "ACLMFP",
        "PFP",
        "SOCLCP",
        "HP",
        "CONVEXQP_PG_CYLINDER",
        "VI_FPP_Cylinder",
    ),
    ("global", 2): ("NSGS",),
    ("global", 3): (
        "NSGS",
        "NSGS_WR",
        "NSGSV_WR",
        "NSN_AC",
        "NSN_AC_WR",
        "PROX_WR",
        "DSFP_WR",
        "TFP_WR",
        "ADMM",
        "ADMM_WR",
        "IPM",
        "VI_FPP",
        "VI_EG",
        "ACLMFP",
    ),
}
#: Those run when none are named: the usual ones of each family (Gauss-Seidel,
#: semi-smooth Newton, proximal point, ADMM, projection, pivoting, interior point).
DEFAULTS: dict[Form, tuple[str, ...]] = {
    ("local", 2): ("NSGS", "CPG", "LEMKE"),
    ("local", 3): ("NSGS", "NSN_AC", "NSN_FB", "PROX", "ADMM", "VI_FPP", "VI_EG"),
    ("global", 2): ("NSGS",),
    ("global", 3): ("NSGS", "NSN_AC", "PROX_WR", "ADMM", "IPM"),
}
_CONSTANT = {
    ("local", 2): "SICONOS_FRICTION_2D_",
    ("local", 3): "SICONOS_FRICTION_3D_",
    ("global", 2): "SICONOS_GLOBAL_FRICTION_2D_",
    ("global", 3): "SICONOS_GLOBAL_FRICTION_3D_",
}
_DRIVER = {
    ("local", 2): "fc2d_driver",
    ("local", 3): "fc3d_driver",
    ("global", 2): "gfc2d_driver",
    ("global", 3): "gfc3d_driver",
}


def python() -> str:
    """The Python that runs Siconos: ``$COCD_SICONOS_PYTHON``, else ``/usr/bin/python3``."""
    return os.environ.get(ENV) or DEFAULT_PYTHON


@functools.lru_cache(maxsize=8)
def _probe(executable: str) -> dict[str, Any] | str:
    if not Path(executable).is_file():
        return f"{executable} does not exist"
    try:
        done = subprocess.run(
            [executable, str(CHILD), "probe"],
            capture_output=True,
            text=True,
            timeout=60,
            check=False,
        )
    except (OSError, subprocess.TimeoutExpired) as exc:
        return f"{executable} does not run ({type(exc).__name__})"
    if done.returncode != 0:
        lines = [ln for ln in (done.stderr or "").strip().splitlines() if ln.strip()]
        last = lines[-1] if lines else f"exit status {done.returncode}"
        return f"{executable} cannot import siconos.numerics ({last.strip()[:160]})"
    try:
        return dict(json.loads(done.stdout.strip().splitlines()[-1]))
    except (ValueError, IndexError):
        return f"{executable} answered the probe with no JSON"


def probe() -> dict[str, Any]:
    """What the Siconos at hand offers: ``version``, ``python``, ``constants``, ``drivers``.

    Raises
    ------
    CocdError
        When Siconos is not usable (:func:`peer_unavailable_reason` says why).
    """
    got = _probe(python())
    if isinstance(got, str):
        raise CocdError(_unavailable(got))
    return got


def _unavailable(why: str) -> str:
    return (
        f"Siconos is not available: {why} (install it with `{INSTALL}`, or set {ENV} "
        "to a Python that imports siconos.numerics)"
    )


def peer_unavailable_reason() -> str | None:
    """Why Siconos cannot run here, in one line (None when it can)."""
    got = _probe(python())
    return _unavailable(got) if isinstance(got, str) else None


# -- names ------------------------------------------------------------------------
def parse(name: str) -> tuple[str, bool]:
    """``(method, condensed)`` of ``siconos:NSGS(condensed)``, ``NSGS`` (prefix optional).

    Raises
    ------
    CocdError
        For a name no form knows, listing the known ones.
    """
    text = name.strip()
    if text.lower().startswith(PREFIX):
        text = text[len(PREFIX) :]
    condensed = text.endswith(CONDENSED)
    if condensed:
        text = text[: -len(CONDENSED)].strip()
    known = {m.upper(): m for methods in SOLVERS.values() for m in methods}
    method = known.get(text.upper())
    if method is None:
        listed = ", ".join(sorted(known.values()))
        raise CocdError(f"unknown Siconos solver {name.strip()!r}; known: {listed}")
    return method, condensed


def full_name(method: str, condensed: bool = False) -> str:
    """``siconos:METHOD`` or ``siconos:METHOD(condensed)``."""
    return f"{PREFIX}{method}{CONDENSED if condensed else ''}"


def _form(problem: ExternalProblem, condensed: bool) -> Form:
    kind = "local" if condensed else problem.kind
    return (kind, int(problem.dim))


def applicable(problem: ExternalProblem, name: str) -> str | None:
    """Why ``name`` cannot solve ``problem`` (None when it can)."""
    method, condensed = parse(name)
    if condensed and problem.kind != "global":
        return "(condensed) applies to global problems only"
    form = _form(problem, condensed)
    if method not in SOLVERS.get(form, ()):
        return f"not a Siconos solver of {form[1]}D {form[0]} problems"
    offered = probe()
    if _DRIVER[form] not in offered["drivers"]:
        return f"this Siconos ({offered['version']}) has no {_DRIVER[form]}"
    if _CONSTANT[form] + method not in offered["constants"]:
        return f"this Siconos ({offered['version']}) has no {_CONSTANT[form]}{method}"
    return None


def default_solvers(problem: ExternalProblem) -> list[str]:
    """The :data:`DEFAULTS` that apply to ``problem``; a global one is also solved condensed."""
    names = [full_name(m) for m in DEFAULTS.get(_form(problem, False), ())]
    if problem.kind == "global":
        names += [full_name(m, True) for m in DEFAULTS.get(_form(problem, True), ())]
    return [n for n in names if applicable(problem, n) is None]


def solvers_for(problem: ExternalProblem, names: list[str] | None) -> list[str]:
    """``names`` (or the defaults) that apply to ``problem``, as full names.

    A plain name asked of a global problem also runs condensed when the global
    form has no such solver (``CPG`` on a 2D global problem is ``CPG(condensed)``).
    """
    if names is None:
        return default_solvers(problem)
    out: list[str] = []
    for name in names:
        method, condensed = parse(name)
        full = full_name(method, condensed)
        if applicable(problem, full) is None:
            out.append(full)
        elif not condensed and problem.kind == "global":
            alt = full_name(method, True)
            if applicable(problem, alt) is None:
                out.append(alt)
    return list(dict.fromkeys(out))


# -- solving ----------------------------------------------------------------------
@dataclass(frozen=True)
class Condensed:
    """A global problem's condensed (local) form and the seconds cocd took to make it."""

    local: LocalProblem
    seconds: float


def condense(problem: GlobalProblem) -> Condensed:
    """``W = H' M^-1 H``, ``q = w + H' M^-1 f``, timed from the file's M and H
    (:func:`cocd.external.condense`, which cocd's local forms are charged too)."""
    from cocd.external import condense as condensed

    return Condensed(*condensed(problem))


def _coo(prefix: str, A: Any) -> dict[str, np.ndarray]:
    C = sp.coo_matrix(A)
    return {
        f"{prefix}_row": C.row.astype(np.int64),
        f"{prefix}_col": C.col.astype(np.int64),
        f"{prefix}_val": C.data.astype(np.float64),
    }


def _arrays(problem: ExternalProblem) -> dict[str, Any]:
    """The numbers handed to the child (no strings: the child's numpy may be older)."""
    if isinstance(problem, LocalProblem):
        return {
            **_coo("W", problem.W),
            "n": np.int64(problem.W.shape[0]),
            "q": problem.q,
            "mu": problem.mu,
            "dim": np.int64(problem.dim),
        }
    return {
        **_coo("M", problem.M),
        **_coo("H", problem.H),
        "ndof": np.int64(problem.ndof),
        "m": np.int64(problem.H.shape[1]),
        "f": problem.f,
        "w": problem.w,
        "mu": problem.mu,
        "dim": np.int64(problem.dim),
    }


def _limit_memory(memory_gb: float | None) -> Any:
    if memory_gb is None:
        return None
    cap = int(memory_gb * 2**30)

    def apply() -> None:  # in the child, before exec
        resource.setrlimit(resource.RLIMIT_AS, (cap, cap))

    return apply


def _tail(text: str, limit: int = 200) -> str:
    """The last informative line of a child's output."""
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    for line in reversed(lines):
        if "Hopefully more info" not in line and not line.startswith("Traceback"):
            return line[:limit]
    return ""


def _signal_name(number: int) -> str:
    try:
        return f"signal {signal.Signals(number).name}"
    except ValueError:
        return f"signal {number}"


def _status(info: int, iterations: int, max_iter: int, error: float) -> str:
    if info == 0:
        return "optimal"
    if iterations >= max_iter:
        return "max_iter"
    return "inaccurate" if np.isfinite(error) else "error"


def solve(
    problem: ExternalProblem,
    solver: str,
    tol: float,
    *,
    time_limit: float | None = None,
    max_iter: int | None = None,
    memory_gb: float | None = None,
    condensed: Condensed | None = None,
) -> dict[str, Any]:
    """Run Siconos's ``solver`` on ``problem`` in a child process; its record.

    The record holds ``solver`` (the full name), ``status`` (``optimal`` when
    Siconos reports success, ``max_iter``, ``inaccurate``, ``time_limit`` when
    the driver overran ``time_limit`` and was stopped, ``error`` when it failed
    or the child died), ``iterations``, ``setup_s`` (cocd's condensation for a
    ``(condensed)`` solver, else 0), ``solve_s`` (the driver call), ``wall_s``
    (the whole child), ``natural_map_error`` and ``coulomb_residual`` of its
    ``r`` judged by cocd, ``peer_error`` and ``peer_info`` (Siconos's own error
    and code), ``note``, and ``r`` and ``u`` (None without an answer).

    Raises
    ------
    CocdError
        When Siconos is unavailable, or ``solver`` is unknown or does not apply.
    """
    if not (np.isfinite(tol) and tol > 0):
        raise CocdError(f"tol must be a finite number > 0, got {tol!r}")
    method, is_condensed = parse(solver)
    name = full_name(method, is_condensed)
    reason = applicable(problem, name)
    if reason is not None:
        raise CocdError(f"{name} cannot solve {problem.name}: {reason}")
    cap = DEFAULT_MAX_ITER if max_iter is None else int(max_iter)
    form = _form(problem, is_condensed)
    setup = 0.0
    handed: ExternalProblem = problem
    if is_condensed:
        assert isinstance(problem, GlobalProblem)
        condensed = condensed or condense(problem)
        handed, setup = condensed.local, condensed.seconds
    record: dict[str, Any] = {
        "solver": name,
        "status": "error",
        "iterations": np.nan,
        "setup_s": setup,
        "solve_s": np.nan,
        "wall_s": np.nan,
        "natural_map_error": np.nan,
        "coulomb_residual": np.nan,
        "peer_error": np.nan,
        "peer_info": np.nan,
        "note": "",
        "r": None,
        "u": None,
    }
    request = {
        "form": form[0],
        "constant": _CONSTANT[form] + method,
        "driver": _DRIVER[form],
        "tol": float(tol),
        "max_iter": cap,
        "time_limit": None if time_limit is None else float(time_limit),
        "repeat_below": SHORT_SOLVE_S,
        "repeats": SHORT_SOLVE_REPEATS,
    }
    with tempfile.TemporaryDirectory(prefix="cocd-siconos-") as work:
        np.savez(Path(work) / "problem.npz", **_arrays(handed))
        (Path(work) / "request.json").write_text(json.dumps(request))
        record.update(_run_child(work, time_limit, memory_gb))
        if record["status"] != "done":
            return record
        answer = json.loads((Path(work) / "answer.json").read_text())
        with np.load(Path(work) / "answer.npz") as got:
            r, u = np.array(got["r"]), np.array(got["u"])
    info, iterations, error = int(answer["info"]), int(answer["iterations"]), answer["error"]
    record.update(
        status=_status(info, iterations, cap, float(error)),
        iterations=iterations,
        solve_s=float(answer["solve_s"]),
        peer_error=float(error),
        peer_info=info,
        note=f"Siconos info {info}, its error {float(error):.3g}",
        r=r,
        u=u,
    )
    record.update(judge(problem, r))
    return record


def judge(problem: ExternalProblem, r: np.ndarray) -> dict[str, float]:
    """``natural_map_error`` of ``r`` on the problem as read and, when cocd can build its
    conic form, ``coulomb_residual``; NaN for a non-finite ``r``."""
    out = {"natural_map_error": np.nan, "coulomb_residual": np.nan}
    r = np.asarray(r, dtype=np.float64).reshape(-1)
    if r.size != problem.nc * problem.dim or not np.all(np.isfinite(r)):
        return out
    from cocd.residuals import coulomb_residual

    try:
        out["natural_map_error"] = problem.natural_map_error(r)
        out["coulomb_residual"] = coulomb_residual(problem.conic, r.reshape(-1, problem.dim))
    except ProblemError:  # e.g. a non-symmetric W: no conic form, the natural map stands
        pass
    return out


def _run_child(work: str, time_limit: float | None, memory_gb: float | None) -> dict[str, Any]:
    """Run the child on ``work``; ``status`` ``done``, ``time_limit`` or ``error``."""
    backstop = None if time_limit is None else float(time_limit) + GRACE
    start = time.perf_counter()
    proc = subprocess.Popen(
        [python(), str(CHILD), "solve", work],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        errors="replace",
        start_new_session=True,
        preexec_fn=_limit_memory(memory_gb),
    )
    try:
        out, err = proc.communicate(timeout=backstop)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        wall = time.perf_counter() - start
        return {
            "status": "time_limit",
            "wall_s": wall,
            "note": f"the child overran {backstop:g} s and was killed",
        }
    wall = time.perf_counter() - start
    code = proc.returncode
    if code == -signal.SIGALRM:
        return {
            "status": "time_limit",
            "wall_s": wall,
            "note": f"stopped at the time limit ({time_limit:g} s)",
        }
    if code != 0:
        how = _signal_name(-code) if code < 0 else f"exit status {code}"
        detail = _tail(err) or _tail(out)
        return {
            "status": "error",
            "wall_s": wall,
            "note": f"Siconos failed ({how}): {detail}" if detail else f"Siconos failed ({how})",
        }
    return {"status": "done", "wall_s": wall}
