"""One step's problem solved: the warm start, the fallback chain, the checks of an answer.

:class:`~cocd.stepper.Stepper` calls these for every step; they know backends
and problems, not scenes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

import solvers
from cocd.errors import ProblemError, SolverError
from cocd.problem import ConicProblem
from cocd.residuals import Residuals, residuals

__all__ = ["Acceptance", "judge", "match_impulses", "solve_chain", "warm_start"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Acceptance:
    """When a backend's answer is accepted (see :class:`~cocd.stepper.Stepper`)."""

    tol: float
    residual_factor: float | None
    energy_factor: float | None


def match_impulses(
    prev_keys: NDArray[np.int64], prev_p: FloatArray, keys: NDArray[np.int64]
) -> FloatArray:
    """Impulses of the previous step for the contacts of this one, matched by pair key.

    Contacts that are new get zero. ``prev_keys`` must be sorted (as
    :func:`~cocd.contacts.detect_contacts` returns them).
    """
    out = np.zeros((keys.size, prev_p.shape[1]))
    if prev_keys.size == 0 or keys.size == 0:
        return out
    pos = np.searchsorted(prev_keys, keys)
    pos = np.minimum(pos, prev_keys.size - 1)
    hit = prev_keys[pos] == keys
    out[hit] = prev_p[pos[hit]]
    return out


def warm_start(
    previous: tuple[NDArray[np.int64], FloatArray] | None,
    keys: NDArray[np.int64],
    contact_dim: int,
) -> FloatArray | None:
    """The previous step's impulses matched to ``keys``; None without a usable one."""
    if previous is None:
        return None
    p0 = match_impulses(*previous, keys)
    return p0 if p0.shape[1] == contact_dim else None


def solve_chain(
    problem: ConicProblem,
    names: Sequence[str],
    accept: Acceptance,
    energy_before: float,
    where: str,
    *,
    p0: FloatArray | None,
    options: dict[str, Any],
    **limits: Any,
) -> tuple[solvers.Solution, str, list[str], Residuals]:
    """Try the backends ``names`` in turn until one's answer is accepted.

    ``options`` go to the first backend only, ``limits`` (``max_iter``,
    ``time_limit``) to all. Returns the answer, the backend that gave it, the
    failures before it and its residuals; raises :class:`SolverError`, prefixed
    with ``where``, when every backend fails.
    """
    failures: list[str] = []
    for position, name in enumerate(names):
        info = solvers.get(name)
        try:
            solution = solvers.solve(
                problem,
                solver=name,
                tol=accept.tol,
                warm_start=p0 if info.warm_start else None,
                **limits,
                **(options if position == 0 else {}),  # a fallback of the same name too
            )
        except ProblemError:
            raise  # the problem or the options are wrong, not the backend
        except SolverError as exc:  # the backend raised (solvers.solve says what)
            failures.append(f"{name}: {exc}")
            continue
        reason, res = judge(problem, solution, info.convex, energy_before, accept)
        if reason is None:
            assert res is not None
            return solution, name, failures, res
        failures.append(f"{name}: {reason}")
    raise SolverError(f"{where}: " + "; ".join(failures))


def judge(
    problem: ConicProblem,
    solution: solvers.Solution,
    convex: bool,
    energy_before: float,
    accept: Acceptance,
) -> tuple[str | None, Residuals | None]:
    """Why a backend's answer is not accepted (``None``: it is), and its residuals."""
    status = solution.status.value
    if not solution.found:
        native = solution.extras.get("native_status", "no native status")
        return (
            f"returned status {status} ({native}) after {solution.iterations} iterations",
            None,
        )
    u, p = np.asarray(solution.u), np.asarray(solution.p)
    if not (np.all(np.isfinite(u)) and np.all(np.isfinite(p))):
        return "returned non-finite velocities or impulses", None
    res = residuals(problem, u, p)
    measured = res.ccp if convex else res.coulomb
    label = "ccp_residual" if convex else "coulomb_residual"
    # An approximate model (faceted cones) answers another problem: its residual
    # against the exact cone measures the model's error, not a failure.
    approximate = bool(solution.extras.get("approximation"))
    factor = accept.residual_factor
    if factor is not None and not approximate and not measured <= factor * accept.tol:
        return (
            f"{label} {measured:.3g} is above {factor:g} x tol "
            f"({factor * accept.tol:.3g}; status {status})",
            res,
        )
    if accept.energy_factor is not None:
        v = problem.velocity(p)
        after = 0.5 * float(np.sum(problem.mass * v * v))
        free = 0.5 * float(np.sum(problem.mass * problem.U * problem.U))
        bound = accept.energy_factor * max(energy_before, free)
        if after > bound and after > 0.0:
            return (
                f"kinetic energy blew up: {after:.3g} after the step against "
                f"{max(energy_before, free):.3g} before (limit x{accept.energy_factor:g})",
                res,
            )
    return None, res
