"""The local form of cocd's Gauss-Seidel backends: ``u = W r + q`` on ``W`` itself.

A local problem (FCLib, Siconos) gives the Delassus operator ``W`` and ``q``; Coulomb's
law per contact, normal first, with De Saxcé's ``û = u + (mu |u_T|, 0)`` and ``K* ∋ û
⊥ r ∈ K``. The backends' usual path turns it into a :class:`~cocd.problem.ConicProblem`
through a factor ``H H' = W``, which exists only for a symmetric ``W``. The local form
solves the problem as Siconos's NSGS does, on ``W`` in block-CSR form, symmetric or
not: Gauss-Seidel over the contacts, at contact ``a`` the rest ``q'_a = q_a + sum_{b !=
a} W_ab r_b`` from row ``a`` and then the backend's own step on block ``W_aa``
(:mod:`solvers._local_kernels`, compiled, the stopping test inside the sweep):

- ``nscd``: the exact one-contact solver of Coulomb's law (``local="fb"``: its
  Fischer-Burmeister Newton with the exact solver as fallback), relaxed by ``relax``;
- ``pgs``: the projected step ``P_K(r_a - omega rho_a u_a)`` on the convex problem (the
  cone complementarity problem ``K* ∋ u ⊥ r ∈ K``, a monotone variational inequality
  when ``W + W'`` is positive semi-definite).

``apgd`` has none: its acceleration rests on ``1/2 r'Wr + q'r`` being the objective,
which needs a symmetric ``W``, and a symmetric ``W`` has its factor, so its ConicProblem
path applies; what would remain for a non-symmetric ``W``, the plain projected gradient
``r <- P_K(r - t (W r + q))``, converges only for ``t`` below ``2 lambda_min(W + W') /
|W|^2`` (zero for the singular ``W`` of rigid bodies) and is slower than ``pgs``'s
Gauss-Seidel on the same inequality.

A backend declares its local form in :attr:`solvers.SolverInfo.local_entry`; call it
with :func:`solve_local`. Requests mean what they mean for the ConicProblem path:

========================  =====================================================
cocd                      local form
========================  =====================================================
``tol``                   stop when the criterion's error ``<= tol``: with
                          ``criterion="residual"`` (default) the framework's
                          ``coulomb_residual`` (``nscd``) or ``ccp_residual``
                          (``pgs``) computed on ``W`` (``rho_a = m /
                          trace(W_aa)``, normalised by ``|rho q|``: the numbers
                          of the ConicProblem path when ``W`` is symmetric);
                          with ``criterion="natural_map"`` the file's own
                          ``||r - P_K(r - û)|| / max(1, ||q||)``, as Siconos
                          reports it (``û = u`` for ``pgs``). Tested after
                          every sweep, exactly, inside the sweep
``status``                ``optimal`` when met, else ``max_iter`` or
                          ``time_limit`` with the impulses of least error seen
                          (never raises for a solve that does not converge)
``max_iter``              sweeps (default: the backend's, 20 000 for ``nscd``,
                          10 000 for ``pgs``)
``time_limit``            seconds, tested between runs of sweeps (the first
                          run is 16 sweeps, the others sized from the time a
                          sweep takes, at most a tenth of a second each;
                          without a time limit, runs of 65 536 sweeps)
``warm_start``            impulses ``(nc, m)``, projected on their cones
``verbose``               one line per run of sweeps
``**options``             ``nscd``: ``relax``, ``symmetric``, ``local``,
                          ``newton`` (below); ``pgs``: ``omega``; both accept
                          ``check_every`` (unused: the test is after every
                          sweep) and ``polish=False``
========================  =====================================================

``nscd`` with ``newton=True`` finishes the sweeps by semismooth Newton on the
Alart-Curnier function (:mod:`solvers._local_newton`, the method of Siconos's
``NSN_AC``, regularised for the singular ``W`` of packings): 32 sweeps, then Newton
from their answer; while Newton stops short of ``tol`` (a failed line search, a
stall), sweeps again from its best iterate, twice as many as before, and Newton
again. Gauss-Seidel converges linearly and, on a packing with redundant contacts, can
stall (``1.5e-5`` after 20 000 sweeps on BoxesStack); Newton converges fast once near
(``1e-15`` after 10 steps there). ``iterations`` counts sweeps and Newton steps.

The answer is a :class:`~solvers.base.Solution` whose ``p`` is ``r`` ``(nc, m)`` and
``u`` the local velocity ``W r + q`` ``(m nc,)``. ``extras``: ``criterion``, its
``error`` for the answer, ``history`` (the error at the start of every sweep),
``branches`` (``nscd``), ``local_newton`` and ``local_fallbacks`` (``local="fb"``);
with ``newton=True``, ``sweeps``, ``newton_steps``, ``newton_stops`` (why each Newton
stage ended) and ``newton_shifted``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike

from cocd.errors import ProblemError
from solvers._contact_kernels import project_cones
from solvers._iterative import _inverses, ignore_polish, positive_int, relaxation
from solvers._local_kernels import (
    LOCAL_EXACT,
    LOCAL_FB,
    NSCD,
    PGS,
    branch_counts,
    local_error,
    local_sweeps,
    local_velocity,
)
from solvers.base import FloatArray, IntArray, Request, Solution, Status, entry_function
from solvers.registry import REQUEST_FIELDS, registered, requested

__all__ = ["CRITERIA", "LocalData", "nscd_local", "pgs_local", "solve_local"]

#: Stopping criteria of the local form (module docstring).
CRITERIA = ("residual", "natural_map")
#: Sweeps of the first run when there is a time limit; a later run lasts at most this,
#: and has at most ``_MAX_RUN`` sweeps (the memory of their errors).
_FIRST_RUN = 16
_RUN_SECONDS = 0.1
_MAX_RUN = 1 << 16
_LOCAL = {"exact": LOCAL_EXACT, "fb": LOCAL_FB}


@dataclass(frozen=True, eq=False)
class LocalData:
    """A local problem ``u = W r + q``, Coulomb's law per contact (module docstring).

    Attributes
    ----------
    W : (m nc, m nc) csr
        Any square sparse (or dense) matrix; need not be symmetric.
    q : (m nc,)
    mu : (nc,)
        Friction coefficients, ``>= 0``.
    dim : int
        ``m``, the components per contact (1, 2 or 3), normal first.

    Checked and normalised on construction (one-line :class:`~cocd.errors.ProblemError`);
    the block-CSR arrays the kernels read are built once, on first use.
    """

    W: sp.csr_matrix
    q: FloatArray
    mu: FloatArray
    dim: int

    def __post_init__(self) -> None:
        dim = self.dim
        if isinstance(dim, bool) or not isinstance(dim, (int, np.integer)) or dim not in (1, 2, 3):
            raise ProblemError(f"local problem: dim must be 1, 2 or 3, got {dim!r}")
        shape = getattr(self.W, "shape", None)
        if shape is None or len(shape) != 2 or shape[0] != shape[1]:
            raise ProblemError(f"local problem: W must be a square matrix, got shape {shape}")
        n = int(shape[0])
        if n % dim:
            raise ProblemError(f"local problem: W has {n} rows, not a multiple of dim = {dim}")
        try:
            W = sp.csr_matrix(self.W, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ProblemError(f"local problem: W is not a matrix ({exc})") from None
        if not np.all(np.isfinite(W.data)):
            raise ProblemError("local problem: W has non-finite entries")
        q = _vector("q", self.q, n)
        mu = _vector("mu", self.mu, n // dim)
        bad = np.flatnonzero(mu < 0.0)
        if bad.size:
            raise ProblemError(f"local problem: mu[{bad[0]}] is {mu[bad[0]]:g}: must be >= 0")
        object.__setattr__(self, "W", W)
        object.__setattr__(self, "q", q)
        object.__setattr__(self, "mu", mu)
        object.__setattr__(self, "dim", int(dim))

    @classmethod
    def of(cls, problem: Any) -> LocalData:
        """The data of anything with ``W``, ``q``, ``mu`` and ``dim`` (a
        :class:`cocd.io.problems.LocalProblem`)."""
        return cls(problem.W, problem.q, problem.mu, problem.dim)

    @property
    def nc(self) -> int:
        return int(self.mu.size)

    @cached_property
    def arrays(self) -> _Arrays:
        """The block-CSR arrays of ``W`` and the per-contact data (built once)."""
        return _Arrays.of(self)

    def velocity(self, r: ArrayLike) -> FloatArray:
        """``u = W r + q``, ``(m nc,)``."""
        a = self.arrays
        rr = np.ascontiguousarray(np.asarray(r, dtype=np.float64).reshape(a.q.shape))
        u = np.empty_like(rr)
        local_velocity(a.indptr, a.indices, a.blocks, a.q, rr, u)
        return u.reshape(-1)


def _vector(name: str, x: Any, size: int) -> FloatArray:
    try:
        a = np.asarray(x, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise ProblemError(f"local problem: {name} is not an array of numbers ({exc})") from None
    if a.size != size:
        raise ProblemError(f"local problem: {name} has {a.size} entries, expected {size}")
    if not np.all(np.isfinite(a)):
        raise ProblemError(f"local problem: {name} has non-finite entries")
    return a


@dataclass(frozen=True)
class _Arrays:
    """What the kernels read (:mod:`solvers._local_kernels`)."""

    indptr: IntArray
    indices: IntArray
    blocks: FloatArray
    Wd: FloatArray
    Wdinv: FloatArray
    q: FloatArray
    mu: FloatArray
    rho: FloatArray
    ones: FloatArray
    #: ``|rho q|`` and ``max(1, |q|)``, the denominators of the two criteria.
    rho_q: float
    q_norm: float

    @classmethod
    def of(cls, data: LocalData) -> _Arrays:
        m, nc = data.dim, data.nc
        B = data.W.tobsr(blocksize=(m, m))
        B.sum_duplicates()
        B.sort_indices()
        indptr = B.indptr.astype(np.int64)
        indices = B.indices.astype(np.int64)
        blocks = np.ascontiguousarray(B.data, dtype=np.float64).reshape(-1, m, m)
        rows = np.repeat(np.arange(nc), np.diff(indptr))
        has_diagonal = np.zeros(nc, dtype=bool)
        has_diagonal[rows[indices == rows]] = True
        missing = np.flatnonzero(~has_diagonal)
        if missing.size:  # every diagonal block is stored, zero or not (Newton's pattern)
            rows = np.concatenate([rows, missing])
            indices = np.concatenate([indices, missing])
            blocks = np.concatenate([blocks, np.zeros((missing.size, m, m))])
            order = np.lexsort((indices, rows))
            rows, indices, blocks = rows[order], indices[order], blocks[order]
            indptr = np.searchsorted(rows, np.arange(nc + 1)).astype(np.int64)
        Wd = np.zeros((nc, m, m))
        diagonal = indices == rows
        Wd[rows[diagonal]] = blocks[diagonal]
        trace = np.einsum("aii->a", Wd)
        rho = np.where(trace > 0.0, m / np.where(trace > 0.0, trace, 1.0), 0.0)
        q = np.ascontiguousarray(data.q.reshape(nc, m))
        return cls(
            indptr,
            indices,
            blocks,
            Wd,
            _inverses(Wd),
            q,
            np.ascontiguousarray(data.mu),
            rho,
            np.ones(nc),
            float(np.linalg.norm(rho[:, None] * q)),
            max(1.0, float(np.linalg.norm(q))),
        )


# -- the entry -------------------------------------------------------------------------
def solve_local(
    data: LocalData,
    solver: str,
    tol: float = 1e-8,
    *,
    max_iter: int | None = None,
    time_limit: float | None = None,
    warm_start: ArrayLike | None = None,
    verbose: bool = False,
    criterion: str = "residual",
    **options: Any,
) -> Solution:
    """Solve the local problem ``data`` with the local form of the backend ``solver``.

    ``tol``, ``max_iter``, ``time_limit``, ``warm_start`` and ``verbose`` are those of
    :func:`solvers.solve` (options written in the name win, as there);
    ``criterion`` is ``"residual"`` or ``"natural_map"`` (module docstring). A
    backend without a local form, an unknown option or a bad request raises a one-line
    :class:`~cocd.errors.ProblemError` (an unknown name
    :class:`~cocd.errors.SolverNotFound`).
    """
    info, asked, options = requested(
        solver,
        dict(tol=tol, max_iter=max_iter, time_limit=time_limit, verbose=verbose,
             criterion=criterion),
        options,
        "criterion",
    )  # fmt: skip
    tol, max_iter, time_limit, verbose, criterion = (
        asked[k] for k in (*REQUEST_FIELDS, "criterion")
    )
    if info.local_entry is None:
        raise ProblemError(
            f"solver {info.name!r} has no local form (it solves the ConicProblem of a "
            f"factor H H' = W); backends with one: {', '.join(local_backends()) or 'none'}"
        )
    if not isinstance(data, LocalData):
        raise ProblemError(f"solve_local takes a LocalData, got {type(data).__name__}")
    if criterion not in CRITERIA:
        raise ProblemError(f"criterion must be one of {', '.join(CRITERIA)}, got {criterion!r}")
    request = _request(data, tol, max_iter, time_limit, warm_start, verbose)
    fn: Callable[..., Solution] = entry_function(info.local_entry)
    solution = fn(data, request, criterion=criterion, **options)
    solution.solver = solver
    return solution


def local_backends() -> list[str]:
    """The registered backends that have a local form."""
    return sorted(n for n, info in registered().items() if info.local_entry is not None)


def _request(
    data: LocalData,
    tol: Any,
    max_iter: Any,
    time_limit: Any,
    warm_start: ArrayLike | None,
    verbose: bool,
) -> Request:
    # tol, max_iter and time_limit were checked by solvers.registry.requested.
    p0 = None
    if warm_start is not None:
        p0 = np.asarray(warm_start, dtype=np.float64)
        if p0.size != data.q.size:
            raise ProblemError(f"warm_start has {p0.size} entries, expected {(data.nc, data.dim)}")
        if not np.all(np.isfinite(p0)):
            raise ProblemError("warm_start has non-finite entries")
        p0 = p0.reshape(data.nc, data.dim)
    return Request(tol, p0, max_iter, time_limit, verbose)


# -- the backends' local forms -----------------------------------------------------------
def nscd_local(
    data: LocalData,
    request: Request,
    *,
    criterion: str = "residual",
    relax: float = 1.0,
    symmetric: bool = False,
    local: str = "exact",
    newton: bool = False,
    **options: Any,
) -> Solution:
    """``nscd``'s local form: Gauss-Seidel with the exact one-contact Coulomb solver,
    finished by semismooth Newton when ``newton`` (:func:`_with_newton`)."""
    relax = float(relax)
    if not 0.0 < relax <= 2.0:
        raise ProblemError(f"nscd: relax must be in (0, 2], got {relax}")
    if local not in _LOCAL:
        raise ProblemError(f"nscd: local must be one of {sorted(_LOCAL)}, got {local!r}")
    _other_options("nscd", options)
    from solvers.nscd_ import DEFAULT_MAX_SWEEPS

    method = _Method("nscd", NSCD, True, _LOCAL[local], relax, 1.0, bool(symmetric))
    if newton:
        sol = _with_newton(data, request, criterion, method, DEFAULT_MAX_SWEEPS)
    else:
        sol = _run(data, request, criterion, method, DEFAULT_MAX_SWEEPS)
    separated, stick, slide = branch_counts(sol.p, data.arrays.mu)
    sol.extras["branches"] = {"separated": separated, "stick": stick, "slide": slide}
    sol.extras["local"] = local
    return sol


def pgs_local(
    data: LocalData,
    request: Request,
    *,
    criterion: str = "residual",
    omega: float = 1.0,
    **options: Any,
) -> Solution:
    """``pgs``'s local form: projected Gauss-Seidel on the convex problem."""
    omega = relaxation(omega)
    _other_options("pgs", options)
    from solvers.pgs_ import DEFAULT_MAX_ITER

    method = _Method("pgs", PGS, False, LOCAL_EXACT, 1.0, omega, False)
    return _run(data, request, criterion, method, DEFAULT_MAX_ITER)


def _other_options(name: str, options: dict[str, Any]) -> None:
    """``check_every`` (checked, unused) and ``polish`` (as the ConicProblem path)."""
    if "check_every" in options:
        positive_int(options.pop("check_every"), "check_every")
    ignore_polish(name, options)
    options.pop("polish", None)
    if options:
        raise ProblemError(f"{name}'s local form has no option {sorted(options)[0]!r}")


#: Sweeps before the first Newton stage of ``newton=True``; doubled after each stage
#: that stops short of the tolerance. Newton steps per stage.
_NEWTON_AFTER = 32
_NEWTON_STEPS = 200


def _with_newton(
    data: LocalData, request: Request, criterion: str, method: _Method, default_cap: int
) -> Solution:
    """Gauss-Seidel sweeps, then semismooth Newton on the Alart-Curnier function
    (:mod:`solvers._local_newton`) from their answer; while Newton stops short of the
    tolerance (a failed line search, its step budget), sweeps again from its best
    iterate, twice as many as the time before, and Newton again. Sweeps and Newton
    steps share ``max_iter`` and ``time_limit``; ``iterations`` counts both."""
    from solvers._local_newton import newton

    start = time.perf_counter()
    a = data.arrays
    scale, den = (a.rho, a.rho_q) if criterion == "residual" else (a.ones, a.q_norm)

    def error_of(r: FloatArray) -> float:
        rr = np.ascontiguousarray(r)
        return float(local_error(a.indptr, a.indices, a.blocks, a.q, a.mu, scale, True, den, rr))

    cap = default_cap if request.max_iter is None else int(request.max_iter)
    deadline = None if request.time_limit is None else start + float(request.time_limit)
    r = request.warm_start
    sweeps = steps = shifted = 0
    chunk = _NEWTON_AFTER
    histories: list[FloatArray] = []
    stops: list[str] = []
    sol: Solution | None = None
    status = Status.MAX_ITER
    while True:
        left = None if deadline is None else max(deadline - time.perf_counter(), 1e-6)
        part = Request(request.tol, r, max(1, min(chunk, cap - sweeps - steps)), left,
                       request.verbose)  # fmt: skip
        sol = _run(data, part, criterion, method, default_cap)
        sweeps += sol.iterations
        histories.append(sol.extras["history"])
        r, error = sol.p, float(sol.extras["error"])
        if sol.status in (Status.OPTIMAL, Status.ERROR) or sweeps + steps >= cap:
            status = sol.status
            break
        if deadline is not None and time.perf_counter() >= deadline:
            status = Status.TIME_LIMIT
            break
        got = newton(
            a.indptr, a.indices, a.blocks, a.q, a.mu, a.rho, r, error_of, request.tol,
            max_iter=min(_NEWTON_STEPS, cap - sweeps - steps), deadline=deadline,
        )  # fmt: skip
        steps += got.iterations
        shifted += got.shifted
        stops.append(got.reason)
        if request.verbose:
            print(f"{method.name} (local): Newton, {got.iterations} steps ({got.reason}), "
                  f"{criterion} {got.error:.3e}")  # fmt: skip
        if got.error < error:
            r, error = got.r, got.error
        if got.reason == "converged":
            status = Status.OPTIMAL
            break
        if got.reason == "time" or sweeps + steps >= cap:
            status = Status.TIME_LIMIT if got.reason == "time" else Status.MAX_ITER
            break
        chunk *= 2
    extras = dict(sol.extras)
    extras.update(
        native_status=status.value,
        error=error,
        history=np.concatenate(histories),
        sweeps=sweeps,
        newton_steps=steps,
        newton_stops=stops,
        newton_shifted=shifted,
    )
    total = time.perf_counter() - start
    return Solution(
        u=sol.u if r is sol.p else data.velocity(r),  # the last sweeps' answer has its u
        p=np.asarray(r).reshape(a.q.shape),
        status=status,
        iterations=sweeps + steps,
        setup_time=sol.setup_time,
        solve_time=total - sol.setup_time,
        solver=method.name,
        extras=extras,
    )


@dataclass(frozen=True)
class _Method:
    name: str
    code: int
    coulomb: bool
    local: int
    relax: float
    omega: float
    symmetric: bool


def _run(
    data: LocalData, request: Request, criterion: str, method: _Method, default_cap: int
) -> Solution:
    start = time.perf_counter()
    a = data.arrays
    nc, m = a.q.shape
    if request.warm_start is None:
        r = np.zeros((nc, m))
    else:
        r = np.empty((nc, m))
        project_cones(np.ascontiguousarray(request.warm_start), a.mu, r)
    best = r.copy()
    if criterion == "residual":
        scale, den = a.rho, a.rho_q
    else:
        scale, den = a.ones, a.q_norm
    cap = default_cap if request.max_iter is None else int(request.max_iter)
    deadline = None if request.time_limit is None else start + float(request.time_limit)
    history: list[FloatArray] = []
    state = np.array([math.inf])
    counts = np.zeros(2, dtype=np.int64)
    setup_time = time.perf_counter() - start

    begin = time.perf_counter()
    done = 0
    converged = False
    status = Status.MAX_ITER
    run = min(cap, _MAX_RUN if deadline is None else _FIRST_RUN)
    while nc and done < cap:
        errors = np.empty(run)
        n, converged = local_sweeps(
            a.indptr, a.indices, a.blocks, a.Wd, a.Wdinv, a.q, a.mu, a.rho, r, best, state,
            errors, method.code, method.local, method.relax, method.omega,
            method.symmetric, done, run, request.tol, scale, method.coulomb, den, counts,
        )  # fmt: skip
        history.append(errors[:n])
        done += n
        if request.verbose:
            print(f"{method.name} (local): sweep {done:6d}  {criterion} {state[0]:.3e}")
        if converged or done >= cap:
            break
        now = time.perf_counter()
        if deadline is not None and now >= deadline:
            status = Status.TIME_LIMIT
            break
        if deadline is None:
            run = min(cap - done, _MAX_RUN)
        else:
            per_sweep = (now - begin) / done
            seconds = min(deadline - now, _RUN_SECONDS)
            run = max(1, min(cap - done, _MAX_RUN, int(seconds / max(per_sweep, 1e-9))))
    if converged or nc == 0:
        status = Status.OPTIMAL
    elif not np.all(np.isfinite(r)):
        status = Status.ERROR  # the sweeps blew up; the answer is the best finite iterate
    error = float(state[0]) if nc else 0.0
    solve_time = time.perf_counter() - begin
    extras: dict[str, Any] = {
        "native_status": "non-finite iterate" if status == Status.ERROR else status.value,
        "criterion": criterion,
        "error": error,
        "history": np.concatenate(history) if history else np.zeros(0),
    }
    if method.local == LOCAL_FB:
        extras["local_newton"] = int(counts[0])
        extras["local_fallbacks"] = int(counts[1])
    if request.verbose:
        print(f"{method.name} (local): {status.value} after {done} sweeps, {criterion} {error:.3e}")
    return Solution(
        u=data.velocity(best),
        p=best,
        status=status,
        iterations=done,
        setup_time=setup_time,
        solve_time=solve_time,
        solver=method.name,
        extras=extras,
    )
