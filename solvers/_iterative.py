"""What cocd's iterative methods (:mod:`solvers.pgs_`, :mod:`solvers.bgs_`,
:mod:`solvers.apgd_`, :mod:`solvers.nscd_`) share.

The contact data their kernels read, the checks of their options, the starting
impulses, the scale of the residual, the checked loop of the Gauss-Seidel sweeps
(``pgs`` and ``bgs``) and when they stop.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from cocd.cones import project_coulomb
from cocd.errors import ProblemError
from cocd.residuals import ccp_residual
from solvers._contact_kernels import delassus_blocks, natural_map_sq, restart_velocity
from solvers.base import FloatArray, IntArray, Request, Solution, Status

if TYPE_CHECKING:
    from cocd.problem import ConicProblem

__all__ = [
    "Checks",
    "Contacts",
    "Stop",
    "answer",
    "contact_blocks",
    "gauss_seidel",
    "ignore_polish",
    "impulse_rms",
    "positive_int",
    "ratio",
    "relaxation",
    "residual_scales",
    "start_impulses",
]

_VERBOSE_EVERY = 20


@dataclass(frozen=True)
class Contacts:
    """``H`` by its CSR arrays and the per-contact data the kernels read."""

    indptr: IntArray
    indices: IntArray
    data: FloatArray
    inv_mass: FloatArray
    offset: FloatArray
    rho: FloatArray
    mu: FloatArray
    shift: float
    #: ``|rho b|``, the denominator of ``ccp_residual``, and :func:`impulse_rms` of ``rho b``.
    rb_norm: float
    impulse_scale: float

    @classmethod
    def of(cls, problem: ConicProblem, sort: bool = False) -> Contacts:
        """The arrays of ``problem``; ``sort=True`` sorts the column indices of ``H``."""
        H = problem.H
        if sort and not H.has_sorted_indices:
            H = H.sorted_indices()
        rho = np.ascontiguousarray(problem.rho, dtype=np.float64)
        return cls(
            H.indptr.astype(np.int64),
            H.indices.astype(np.int64),
            np.ascontiguousarray(H.data, dtype=np.float64),
            1.0 / problem.mass,
            np.ascontiguousarray(problem.offset, dtype=np.float64),
            rho,
            np.ascontiguousarray(problem.mu, dtype=np.float64),
            problem.delassus_shift,
            *residual_scales(problem),
        )

    def natural_map(self, p: FloatArray, v: FloatArray, coulomb: bool = False) -> float:
        """The framework's ``ccp_residual`` of ``p`` with ``v = U + M^-1 H'p``, in one pass
        (``coulomb=True``: its ``coulomb_residual``)."""
        total = natural_map_sq(
            self.indptr, self.indices, self.data, v, self.offset, self.rho, self.mu, p,
            self.shift, coulomb,
        )  # fmt: skip
        return ratio(math.sqrt(total), self.rb_norm)


def contact_blocks(
    problem: ConicProblem,
    indptr: IntArray,
    indices: IntArray,
    data: FloatArray,
    inv_mass: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """The problem's diagonal Delassus blocks ``W_aa`` (``(nc, m, m)``, the Delassus shift
    taken off) and their inverses, from the CSR arrays of ``H`` (``bgs`` and ``nscd``)."""
    nc, m = problem.nc, problem.contact_dim
    W = delassus_blocks(indptr, indices, data, inv_mass, nc, m)  # of H M^-1 H'
    if problem.delassus_shift:  # the problem's own blocks: W = H M^-1 H' - shift I
        W = W - problem.delassus_shift * np.eye(m)[None, :, :]
    return W, _inverses(W)


def _inverses(W: FloatArray) -> FloatArray:
    """Inverses of the blocks ``(nc, m, m)``; a singular block (a contact between
    bodies without unknowns) gets zeros, and its contact stays separated."""
    det = np.linalg.det(W)
    scale = np.einsum("aii->a", W) ** W.shape[1]
    ok = det > 1e-14 * scale
    out = np.zeros_like(W)
    if np.any(ok):
        out[ok] = np.linalg.inv(W[ok])
    return out


@dataclass(frozen=True)
class Stop:
    """When the iterative method ``name`` stops: at ``tol``, after ``cap`` iterations
    or at ``deadline`` (``time.perf_counter()``), checking every ``check_every``."""

    name: str
    tol: float
    cap: int
    check_every: int
    deadline: float | None
    verbose: bool

    @classmethod
    def of(
        cls,
        name: str,
        start: float,
        request: Request,
        default_cap: int,
        check_every: Any,
        options: dict[str, Any],
    ) -> Stop:
        """From ``request``, its time limit counted from ``start``; warns when ``options``
        ask for a polish (:func:`ignore_polish`)."""
        ignore_polish(name, options)
        max_iter, time_limit = request.max_iter, request.time_limit
        cap = default_cap if max_iter is None else int(max_iter)
        deadline = None if time_limit is None else start + float(time_limit)
        check = positive_int(check_every, "check_every")
        return cls(name, request.tol, cap, check, deadline, request.verbose)


def gauss_seidel(
    problem: ConicProblem,
    contacts: Contacts,
    p: FloatArray,
    sweeps: Callable[[FloatArray, FloatArray, int], FloatArray],
    stop: Stop,
    setup_time: float,
    finite_residual: bool = False,
    **extras: Any,
) -> Solution:
    """Run ``sweeps(p, v, n)`` (``n`` sweeps in place; the largest change of an impulse
    component per sweep) until the framework's ``ccp_residual`` is ``<= stop.tol``.

    It is checked every ``stop.check_every`` sweeps (``v`` recomputed from ``p``, the
    natural map summed in one pass, confirmed by :func:`cocd.residuals.ccp_residual`);
    with ``finite_residual`` a residual that is not finite is an error too. The answer
    is the checked iterate of smallest residual; ``extras`` go after its ``ccp``.
    """
    begin = time.perf_counter()
    dp_history: list[FloatArray] = []
    checks = Checks()
    best_p, best_r = p.copy(), math.inf
    done = 0
    status, native = Status.MAX_ITER, "max_iter"
    c = contacts
    U = np.ascontiguousarray(problem.U, dtype=np.float64)
    v = np.empty_like(U)
    while True:
        # Resynchronise: the sweeps update v incrementally, and rounding accumulates.
        restart_velocity(c.indptr, c.indices, c.data, c.inv_mass, U, p, v)
        r = contacts.natural_map(p, v)
        checks.add(done, r)
        bad_residual = finite_residual and not (math.isfinite(r) or contacts.rb_norm == 0.0)
        if bad_residual or not np.all(np.isfinite(v)):
            status, native = Status.ERROR, "non-finite iterate"
            break
        if r < best_r:
            best_p, best_r = p.copy(), r
        if stop.verbose and (len(checks.ccp) % _VERBOSE_EVERY == 1):
            last = dp_history[-1][-1] if dp_history else math.nan
            print(f"{stop.name}: sweep {done:6d}  ccp {r:9.3e}  max|dp| {last:9.3e}")
        if r <= stop.tol:
            exact = ccp_residual(problem, p)
            if exact <= stop.tol:
                best_p, best_r = p.copy(), exact
                status, native = Status.OPTIMAL, "converged"
                break
        if done >= stop.cap:
            break
        if stop.deadline is not None and time.perf_counter() >= stop.deadline:
            status, native = Status.TIME_LIMIT, "time_limit"
            break
        n = min(stop.check_every, stop.cap - done)
        dp_history.append(sweeps(p, v, n) / contacts.impulse_scale)
        done += n
    times = (setup_time, time.perf_counter() - begin)
    dp = np.concatenate(dp_history) if dp_history else np.zeros(0)
    outcome = (status, native, done, best_r)
    return answer(problem, best_p, stop, outcome, times, checks, dp, "sweeps", **extras)


@dataclass
class Checks:
    """The residual checks of an iterative method: the iteration of each and its ``ccp``."""

    iteration: list[int] = field(default_factory=list)
    ccp: list[float] = field(default_factory=list)

    def add(self, iteration: int, ccp: float) -> None:
        self.iteration.append(iteration)
        self.ccp.append(ccp)


def answer(
    problem: ConicProblem,
    p: FloatArray,
    stop: Stop,
    outcome: tuple[Status, str, int, float],
    times: tuple[float, float],
    checks: Checks,
    dp: FloatArray,
    unit: str,
    series: dict[str, FloatArray] | None = None,
    **extras: Any,
) -> Solution:
    """The answer ``p`` of the iterative method ``stop.name``, whose last line it prints
    when verbose.

    ``outcome`` is ``(status, native status, iterations, ccp of p)`` and ``unit`` what
    an iteration is. ``extras["history"]`` holds ``dp`` (per iteration), the other
    ``series`` and the ``checks`` (``ccp_iteration``, ``ccp``); ``extras`` go after
    the ``ccp`` of ``p``.
    """
    status, native, iterations, ccp = outcome
    if stop.verbose:
        print(f"{stop.name}: {native} after {iterations} {unit}, ccp {ccp:.3e}, {times[1]:.3g} s")
    history = {
        "dp": dp,
        **(series or {}),
        "ccp_iteration": np.asarray(checks.iteration, dtype=np.int64),
        "ccp": np.asarray(checks.ccp),
    }
    return Solution.from_impulses(
        problem, p, status, iterations, times, stop.name, native, ccp=ccp, **extras, history=history
    )


def start_impulses(problem: ConicProblem, warm_start: FloatArray | None) -> FloatArray:
    """The starting impulses ``(nc, m)``: the warm start projected on the cones, or zero."""
    shape = (problem.nc, problem.contact_dim)
    if warm_start is None:
        return np.zeros(shape)
    p0 = np.asarray(warm_start, dtype=np.float64).reshape(shape)
    if not np.all(np.isfinite(p0)):
        raise ProblemError("warm_start has non-finite entries")
    return np.ascontiguousarray(project_coulomb(p0, problem.mu))


def ignore_polish(solver: str, options: dict[str, Any]) -> None:
    """Warn when ``polish=True`` is asked of an iterative method (its other options
    are checked by :func:`solvers.solve` against its ``SolverInfo.accepts``); called
    by :meth:`Stop.of`.

    The iterative methods answer with their own iterates and never polish:
    ``polish=False`` (which the conformance suite passes to every backend) is
    what they do anyway, ``polish=True`` warns that it is ignored.
    """
    if options.get("polish", False):
        warnings.warn(
            f"{solver} does not polish its answer; polish=True is ignored",
            UserWarning,
            stacklevel=4,
        )


def relaxation(omega: Any) -> float:
    """``omega`` as a float in (0, 2), else :class:`ProblemError`."""
    try:
        value = float(omega)
    except (TypeError, ValueError):
        raise ProblemError(f"omega must be a number in (0, 2), got {omega!r}") from None
    if not (0.0 < value < 2.0):
        raise ProblemError(f"omega must be in (0, 2) (over-relaxation factor), got {omega!r}")
    return value


def positive_int(value: Any, name: str) -> int:
    """``value`` as a positive int, else :class:`ProblemError`."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ProblemError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def residual_scales(problem: ConicProblem) -> tuple[float, float]:
    """``|rho b|`` (the denominator of ``ccp_residual``) and :func:`impulse_rms` of ``rho b``."""
    rb = problem.rho[:, None] * problem.b.reshape(problem.nc, problem.contact_dim)
    return float(np.linalg.norm(rb)), impulse_rms(rb)


def impulse_rms(rb: FloatArray) -> float:
    """Root mean square over contacts of ``rho_a b_a``, 1 when zero (as in cocd.residuals)."""
    s = float(np.linalg.norm(rb)) / math.sqrt(max(rb.shape[0], 1))
    return s if s > 0.0 else 1.0


def ratio(num: float, den: float) -> float:
    """``num / den`` with ``0 / x = 0`` and ``x / 0 = inf`` (as in cocd.residuals)."""
    if num == 0.0:
        return 0.0
    return num / den if den > 0.0 else math.inf
