"""``ipm``: a primal-dual interior point for the COCD primal that uses its structure.

The velocity-based primal in standard form (:meth:`cocd.problem.ConicProblem.primal_conic_form`)
``min 1/2 x'Px  s.t.  A x + s = b,  s in K`` has a diagonal ``P`` (the masses)
and tiny cones (one row per half-plane in 2D, one second-order cone of
dimension 3 per contact in 3D). With Nesterov-Todd scaling ``W`` (``W z =
W^-1 s = lambda``), each Newton step of Mehrotra's predictor-corrector
reduces to the symmetric positive definite system

    (P + A' Theta A) dx = r,      Theta = (W'W)^-1  (block diagonal, cone by cone)

on the generalized velocities only: a sparse matrix with the pattern of the
grains' contact graph, whose values a numba kernel writes in one pass over the
cones (:mod:`solvers._ipm_kernels`) and whose fill-reducing ordering and
symbolic factorisation are computed once per solve. ``dz`` and ``ds`` follow
by products with ``A`` and the cone blocks. Predictor and corrector share one
numerical factorisation per iteration.

Linear solvers (option ``linsolve``, :mod:`solvers._ipm_linsolve`): PARDISO (Intel MKL
through ``pypardiso``, a dependency where MKL has wheels), CHOLMOD (through ``cvxopt``),
QDLDL. The default is the first installed of these, the fastest first (their times
per factorisation are in ``results/full/table1.md``).

========================  =====================================================
cocd                      ipm
========================  =====================================================
``tol``                   stops as soon as the framework's ``ccp_residual`` of
                          the impulses ``z`` is ``<= tol`` (checked every
                          iteration: a few sparse products)
``status``                ``optimal`` at the target (after the polish, if
                          needed); ``max_iter``; ``time_limit``;
                          ``inaccurate`` when the best residual has not halved
                          in 6 iterations and the polish
                          (:mod:`solvers.polish`, off with ``polish=False``;
                          given at most as long again as the interior point
                          took) does not reach the target, or when a factorisation
                          fails after an iterate was found
``max_iter``              interior-point iterations (default 100)
``time_limit``            seconds
``warm_start``            not used (an interior point starts from the centre)
``verbose``               one line per iteration
``**options``             ``linsolve`` (``pardiso``, ``cholmod``, ``qdldl``),
                          ``threads`` (PARDISO's; default: the environment's
                          ``MKL_NUM_THREADS``, else 2), ``polish``,
                          ``correctors`` (Gondzio correctors per iteration
                          on the nonnegative rows, default 2; 0 for plain
                          Mehrotra)
========================  =====================================================

``extras``: ``linsolve``, ``threads`` (PARDISO's, else None), ``history``
(iteration, mu, step, ccp_residual), ``times`` (seconds in assembly,
factorisation, solves, residual checks),
``factorisations`` (numerical ones), ``system_size`` and ``system_nnz`` (the
order of ``K`` and the entries of its upper triangle) and ``factor_nnz`` (the
factor's nonzeros as PARDISO reports them; ``None`` for the other solvers).
"""

from __future__ import annotations

import os
import time
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.sparse as sp

from cocd.cones import project_coulomb
from cocd.errors import ProblemError
from cocd.residuals import ccp_residual
from solvers._conic import check_setting
from solvers._ipm_kernels import (
    cone_blocks,
    fill_linear,
    fill_reduced,
    linear_groups,
    max_step_linear,
    max_step_soc,
    pair_positions,
)
from solvers._ipm_linsolve import LINEAR, LINSOLVES, default_linsolve, openblas_single
from solvers.base import Request, Solution, Status
from solvers.polish import polish_impulses

if TYPE_CHECKING:
    from cocd.problem import ConicProblem

__all__ = ["LINSOLVES", "ReducedSystem", "ipm_solve_problem"]

DEFAULT_MAX_ITER = 100
STEP_FRACTION = 0.99
STALL_ITERATIONS = 6
REFINE_STEPS = 6
#: Gondzio's correctors (Gondzio 1996; Colombo and Gondzio 2008): the trial step
#: min(1, STRETCH alpha + ADD), the band [BETA_MIN, BETA_MAX] sigma mu of the target
#: products, and the fraction of the aimed-at gain a corrector must give to be kept.
GONDZIO_STRETCH, GONDZIO_ADD = 1.0, 0.2
BETA_MIN, BETA_MAX = 0.1, 10.0
GONDZIO_ACCEPT = 0.1
DEFAULT_CORRECTORS = 2
#: Most consecutive nonnegative rows on the same unknowns assembled as one group.
LINEAR_GROUP = 4


# -- cones ---------------------------------------------------------------------------
class _Cones:
    """``l`` nonnegative rows followed by ``k`` second-order cones of dimension 3."""

    def __init__(self, n_lin: int, k: int) -> None:
        self.l, self.k = n_lin, k
        self.degree = n_lin + k

    def split(self, v: Any) -> tuple[Any, Any]:
        return v[: self.l], v[self.l :].reshape(self.k, 3)

    def join(self, a: Any, b: Any) -> Any:
        if not self.k:  # 2D: nonnegative rows only, nothing to copy
            return a
        return np.concatenate([a, b.reshape(-1)])

    def identity(self) -> Any:
        e = np.zeros((self.k, 3))
        e[:, 0] = 1.0
        return self.join(np.ones(self.l), e)

    def interior_shift(self, v: Any) -> Any:
        """``v + (1 + alpha) e`` with ``alpha`` the largest violation, if ``v`` is not interior."""
        a, b = self.split(v)
        viol = []
        if self.l:
            viol.append(float(-a.min()))
        if self.k:
            viol.append(float((np.linalg.norm(b[:, 1:], axis=1) - b[:, 0]).max()))
        alpha = max(viol) if viol else -1.0
        if alpha >= -1e-8:
            return v + (1.0 + alpha) * self.identity()
        return v

    def scaling(self, s: Any, z: Any) -> dict[str, Any]:
        """Nesterov-Todd scaling at ``(s, z)``: ``W z = W^-1 s = lambda``."""
        sl, sq = self.split(s)
        zl, zq = self.split(z)
        out: dict[str, Any] = {}
        out["wl"] = np.sqrt(sl / zl)
        if self.k:
            sJs = sq[:, 0] ** 2 - np.sum(sq[:, 1:] ** 2, axis=1)
            zJz = zq[:, 0] ** 2 - np.sum(zq[:, 1:] ** 2, axis=1)
            sJs = np.maximum(sJs, 1e-300)
            zJz = np.maximum(zJz, 1e-300)
            sb = sq / np.sqrt(sJs)[:, None]
            zb = zq / np.sqrt(zJz)[:, None]
            gamma = np.sqrt(np.maximum((1.0 + np.sum(sb * zb, axis=1)) / 2.0, 1e-300))
            Jz = zb.copy()
            Jz[:, 1:] *= -1.0
            wbar = (sb + Jz) / (2.0 * gamma)[:, None]
            eta = (sJs / zJz) ** 0.25
            out["wbar"], out["eta"] = wbar, eta
        return out

    def apply_w(self, sc: dict[str, Any], v: Any, inverse: bool = False) -> Any:
        """``W v`` (or ``W^-1 v``).

        On a second-order cone, with ``wbar = (a, b)`` (``wbar'J wbar = 1``),
        ``W = eta [[a, b'], [b, I + b b'/(1 + a)]]`` and ``W^-1 = [[a, -b'],
        [-b, I + b b'/(1 + a)]] / eta``.
        """
        va, vb = self.split(v)
        ra = va / sc["wl"] if inverse else va * sc["wl"]
        if not self.k:
            return self.join(ra, np.zeros((0, 3)))
        wbar, eta = sc["wbar"], sc["eta"]
        a, bvec = wbar[:, 0], wbar[:, 1:]
        v0, v1 = vb[:, 0], vb[:, 1:]
        bv = np.sum(bvec * v1, axis=1)
        sign = -1.0 if inverse else 1.0
        r0 = a * v0 + sign * bv
        r1 = sign * v0[:, None] * bvec + v1 + (bv / (1.0 + a))[:, None] * bvec
        scale = 1.0 / eta if inverse else eta
        rb = scale[:, None] * np.concatenate([r0[:, None], r1], axis=1)
        return self.join(ra, rb)

    def theta_blocks(self, sc: dict[str, Any]) -> tuple[Any, Any]:
        """``Theta = W^-2``: ``(l,)`` on the nonnegative rows, ``(k, 3, 3)`` per cone."""
        theta_lin = 1.0 / sc["wl"] ** 2
        theta_soc = np.zeros((self.k, 3, 3))
        if self.k:
            wbar, eta = sc["wbar"], sc["eta"]
            a, bvec = wbar[:, 0], wbar[:, 1:]
            Winv = np.empty((self.k, 3, 3))
            Winv[:, 0, 0] = a
            Winv[:, 0, 1:] = -bvec
            Winv[:, 1:, 0] = -bvec
            Winv[:, 1:, 1:] = (
                np.eye(2)[None] + bvec[:, :, None] * bvec[:, None, :] / (1.0 + a)[:, None, None]
            )
            Winv /= eta[:, None, None]
            theta_soc = np.einsum("kij,kjl->kil", Winv, Winv)
        return theta_lin, theta_soc

    def product(self, u: Any, v: Any) -> Any:
        """Jordan product ``u o v``."""
        ua, ub = self.split(u)
        va, vb = self.split(v)
        ra = ua * va
        rb = np.empty_like(ub)
        rb[:, 0] = np.sum(ub * vb, axis=1)
        rb[:, 1:] = ub[:, :1] * vb[:, 1:] + vb[:, :1] * ub[:, 1:]
        return self.join(ra, rb)

    def divide(self, lam: Any, r: Any) -> Any:
        """``d`` with ``lam o d = r``."""
        la, lb = self.split(lam)
        ra, rb = self.split(r)
        da = ra / la
        det = lb[:, 0] ** 2 - np.sum(lb[:, 1:] ** 2, axis=1)
        d0 = (lb[:, 0] * rb[:, 0] - np.sum(lb[:, 1:] * rb[:, 1:], axis=1)) / det
        d1 = (rb[:, 1:] - lb[:, 1:] * d0[:, None]) / lb[:, :1]
        return self.join(da, np.concatenate([d0[:, None], d1], axis=1))

    def max_step(self, x: Any, d: Any) -> float:
        """Largest ``alpha`` with ``x + alpha d`` in the cone (``x`` interior), capped at 1e30."""
        xa, xb = self.split(x)
        da, db = self.split(d)
        best = float(max_step_linear(xa, da)) if self.l else 1e30
        if self.k:
            best = min(best, float(max_step_soc(xb, db)))
        return best


class ReducedSystem:
    """The pattern and the assembly of ``K = P + A' Theta A`` (upper triangle, CSR).

    The rows of ``A`` are assembled in groups: runs of consecutive nonnegative
    rows on the same unknowns (the two half-planes of a 2D contact: one pass
    over the pair instead of two), then the ``k`` second-order cones of three
    rows. Each group keeps its rows densely on the unknowns it touches. The
    pattern holds every pair of unknowns a group touches (a second-order cone's
    block of ``Theta`` couples all of them), built from the group-unknown
    incidence ``C`` as ``C'C`` so that no entry vanishes by cancellation (in 2D
    the rows ``N + mu T`` and ``N - mu T`` of a contact cancel in ``A'A``).
    """

    def __init__(self, A: sp.csr_matrix, n_lin: int, k: int, pdiag: Any) -> None:
        n = A.shape[1]
        lin_start, lin_size = linear_groups(
            A.indptr.astype(np.int64), A.indices.astype(np.int64), n_lin, LINEAR_GROUP
        )
        self.k, self.n_lin_groups = k, int(lin_start.size)
        self.group_start = np.concatenate([lin_start, n_lin + 3 * np.arange(k)]).astype(np.int64)
        self.group_size = np.concatenate([lin_size, 3 * np.ones(k)]).astype(np.int64)
        self.dofs, self.nq, self.local = cone_blocks(A, self.group_start, self.group_size)
        touched = self.dofs >= 0
        C = sp.csr_matrix(
            (np.ones(int(touched.sum())), (np.nonzero(touched)[0], self.dofs[touched])),
            shape=(self.group_start.size, n),
        )
        pattern = sp.csr_matrix(sp.triu(sp.identity(n) + C.T @ C, format="csr"))
        pattern.sort_indices()
        pattern.data[:] = 0.0
        self.pattern = pattern
        indptr = pattern.indptr.astype(np.int64)
        self.pos = pair_positions(self.dofs, self.nq, indptr, pattern.indices.astype(np.int64))
        self.diag_pos = indptr[:-1].copy()  # the diagonal is each row's first upper entry
        self.base = np.zeros(pattern.nnz)
        self.base[self.diag_pos] = pdiag

    def fill(self, theta_lin: Any, theta_soc: Any, out: Any = None) -> Any:
        """The values of ``K`` on :attr:`pattern` for ``Theta``: ``theta_lin (n_lin,)`` on
        the nonnegative rows, ``theta_soc (k, 3, 3)`` the second-order cones' blocks."""
        if out is None:
            out = np.empty(self.pattern.nnz)
        out[:] = self.base
        m = self.n_lin_groups
        if m:
            fill_linear(
                self.dofs[:m],
                self.nq[:m],
                self.local[:m],
                self.group_start[:m],
                self.group_size[:m],
                np.ascontiguousarray(theta_lin, dtype=np.float64),
                self.pos[:m],
                out,
            )
        if self.k:
            fill_reduced(
                self.dofs[m:],
                self.nq[m:],
                self.local[m:],
                self.group_size[m:],
                np.ascontiguousarray(theta_soc, dtype=np.float64),
                self.pos[m:],
                out,
            )
        return out


# -- the solver ------------------------------------------------------------------------
def ipm_solve_problem(problem: ConicProblem, request: Request, **options: Any) -> Solution:
    """Solve the COCD primal of ``problem`` (see the module's table)."""
    linsolve = str(options.get("linsolve") or default_linsolve())
    if linsolve not in LINEAR:
        raise ProblemError(f"ipm: linsolve must be one of {LINSOLVES}, got {linsolve!r}")
    with openblas_single(linsolve):
        return _solve(problem, request, linsolve, options)


def _threads(options: Any) -> int:
    """PARDISO's threads: the option, else ``MKL_NUM_THREADS`` (which Dask's workers and
    ``cocd validate --workers`` set to 1), else 2."""
    given = options.get("threads")
    where = "the option threads"
    if given is None:
        given, where = os.environ.get("MKL_NUM_THREADS", "").strip() or 2, "MKL_NUM_THREADS"
    try:
        threads = int(given)
    except (TypeError, ValueError):
        threads = 0
    if threads < 1:
        raise ProblemError(f"ipm: {where} must be a positive integer, got {given!r}")
    return threads


def _solve(problem: ConicProblem, request: Request, linsolve: str, options: Any) -> Solution:
    tol, time_limit, verbose = request.tol, request.time_limit, request.verbose
    threads = _threads(options) if linsolve == "pardiso" else None  # PARDISO's alone
    polish = bool(options.get("polish", True))
    correctors = options.get("correctors", DEFAULT_CORRECTORS)
    check_setting("ipm", "correctors", correctors, int)
    if correctors < 0:
        raise ProblemError(f"ipm: setting correctors must be an integer >= 0, got {correctors!r}")
    cap = DEFAULT_MAX_ITER if request.max_iter is None else int(request.max_iter)
    start = time.perf_counter()
    times = {
        "setup": 0.0,
        "assemble": 0.0,
        "factor": 0.0,
        "solve": 0.0,
        "check": 0.0,
        "polish": 0.0,
    }
    factorisations = [0]

    form = problem.primal_conic_form()
    n_lin = sum(size for kind, size in form.cones if kind == "nonneg")
    k = sum(1 for kind, _ in form.cones if kind == "soc")
    if any(kind not in ("nonneg", "soc") for kind, _ in form.cones):
        raise ProblemError("ipm takes nonnegative and second-order cones only")
    cones = _Cones(n_lin, k)
    A = sp.csr_matrix(form.A)
    A.sort_indices()
    b = np.asarray(form.b, dtype=np.float64)
    pdiag = np.asarray(form.P.diagonal(), dtype=np.float64)

    At = sp.csr_matrix(A.T)  # A' is applied several times per iteration
    red = ReducedSystem(A, n_lin, k, pdiag)
    diag_pos = red.diag_pos
    K = red.pattern.copy()
    data = np.empty(red.pattern.nnz)
    lin: Any = None
    reg = [0.0]  # the diagonal shift of the last factorisation (relative)
    times["setup"] = time.perf_counter() - start

    def factor(theta: tuple[Any, Any]) -> None:
        t0 = time.perf_counter()
        red.fill(*theta, data)
        t1 = time.perf_counter()
        times["assemble"] += t1 - t0
        nonlocal lin
        if lin is None:
            K.data[:] = data
            lin = LINEAR[linsolve](K, threads or 1)
        # K is positive definite (P is), but Theta spans many orders of magnitude near
        # the end (sliding contacts sit on the cone's boundary): when the factorisation
        # meets a non-positive pivot, scale the diagonal up by a tiny relative amount
        # and let iterative refinement (against the unshifted K) recover the accuracy.
        failure: Exception | None = None
        for shift in (0.0, 1e-13, 1e-11, 1e-9, 1e-7, 1e-5, 1e-3):
            trial = data
            if shift:  # relative to each diagonal entry: K's rows span many scales
                trial = data.copy()
                trial[diag_pos] *= 1.0 + shift
            try:
                lin.factor(trial)
                reg[0] = shift
                break
            except Exception as exc:  # each library has its own error type
                failure = exc
        else:
            raise np.linalg.LinAlgError(f"ipm: factorisation failed ({failure})")
        times["factor"] += time.perf_counter() - t1
        factorisations[0] += 1

    def kmul(v: Any) -> Any:
        return pdiag * v + At @ (theta_mul(A @ v))

    theta_cur: list[tuple[Any, Any]] = []

    def theta_mul(v: Any) -> Any:
        theta_lin, theta_soc = theta_cur[0]
        va, vb = cones.split(v)
        ra = theta_lin * va
        rb = np.einsum("kij,kj->ki", theta_soc, vb) if k else vb
        return cones.join(ra, rb)

    def solve_k(rhs: Any) -> Any:
        t0 = time.perf_counter()
        x = lin.solve(rhs)
        if reg[0]:  # the factor is of a shifted K: refine against the exact one
            target = 1e-13 * float(np.linalg.norm(rhs))
            for _ in range(REFINE_STEPS):
                r = rhs - kmul(x)
                if float(np.linalg.norm(r)) <= target:
                    break
                x = x + lin.solve(r)
        times["solve"] += time.perf_counter() - t0
        return x

    solve_start = time.perf_counter()
    history: list[tuple[int, float, float, float]] = []
    status = Status.MAX_ITER
    best: tuple[float, Any, Any] | None = None
    try:
        # Initial point: Theta = I, x = (P + A'A)^-1 A'b, s = b - A x, z = -s, shifted inside.
        theta_cur.append((np.ones(n_lin), np.broadcast_to(np.eye(3), (k, 3, 3))))
        factor(theta_cur[0])
        x = solve_k(At @ b)
        r = b - A @ x
        s = cones.interior_shift(r.copy())
        z = cones.interior_shift(-r)
        stalls = 0
        it = 0
        progress: list[float] = []
        while True:
            t0 = time.perf_counter()
            p = form.impulses(z)
            res = ccp_residual(problem, p)
            times["check"] += time.perf_counter() - t0
            mu = float(s @ z) / cones.degree
            if best is None or res < best[0]:
                best = (res, x.copy(), z.copy())
            if verbose:
                print(f"ipm: {it:3d}  mu {mu:.3e}  ccp_residual {res:.3e}")
            if res <= tol:
                status = Status.OPTIMAL
                break
            progress.append(best[0])
            if len(progress) > STALL_ITERATIONS and best[0] > 0.5 * progress[-STALL_ITERATIONS - 1]:
                # No halving of the best residual in STALL_ITERATIONS iterations.
                status = Status.INACCURATE
                break
            if it >= cap:
                status = Status.MAX_ITER
                break
            if time_limit is not None and time.perf_counter() - start >= time_limit:
                status = Status.TIME_LIMIT
                break
            it += 1
            rx = pdiag * x + At @ z
            rz = A @ x + s - b
            sc = cones.scaling(s, z)
            lam = cones.apply_w(sc, z)
            theta = cones.theta_blocks(sc)
            theta_cur[0] = theta
            factor(theta)

            def direction(d: Any, sc: Any = sc, rx: Any = rx, rz: Any = rz) -> tuple[Any, Any, Any]:
                # A dx + ds = -rz;  W dz + W^-1 ds = d;  P dx + A'dz = -rx
                wd = cones.apply_w(sc, d)
                rhs = -rx - At @ theta_mul(rz + wd)
                dx = solve_k(rhs)
                dz = theta_mul(A @ dx + rz + wd)
                ds = cones.apply_w(sc, d - cones.apply_w(sc, dz))
                return dx, ds, dz

            # Predictor (affine scaling): d = lambda \ (-lambda o lambda) = -lambda.
            _, ds_a, dz_a = direction(-lam)
            alpha_a = min(1.0, cones.max_step(s, ds_a), cones.max_step(z, dz_a))
            mu_a = float((s + alpha_a * ds_a) @ (z + alpha_a * dz_a)) / cones.degree
            sigma = min(1.0, max(0.0, mu_a / mu)) ** 3 if mu > 0 else 0.0
            # Corrector: lambda o (W dz + W^-1 ds)
            #            = -lambda o lambda - (W^-1 ds_a) o (W dz_a) + sigma mu e
            rc = (
                -cones.product(lam, lam)
                - cones.product(cones.apply_w(sc, ds_a, inverse=True), cones.apply_w(sc, dz_a))
                + sigma * mu * cones.identity()
            )
            dx, ds, dz = direction(cones.divide(lam, rc))
            step = min(cones.max_step(s, ds), cones.max_step(z, dz))
            # Gondzio's centrality correctors on the nonnegative rows: aim at a longer
            # step, push the products s_i z_i that the trial point leaves outside
            # [BETA_MIN, BETA_MAX] sigma mu back in, and keep the correction while it
            # lengthens the step. Each costs one solve with the same factor.
            zero_x, zero_z = np.zeros_like(rx), np.zeros_like(rz)  # pure correctors
            for _ in range(correctors if n_lin else 0):
                if step >= 1.0:
                    break
                target = min(1.0, GONDZIO_STRETCH * step + GONDZIO_ADD)
                v = (s[:n_lin] + target * ds[:n_lin]) * (z[:n_lin] + target * dz[:n_lin])
                smu = sigma * mu
                dv = np.maximum(np.clip(v, BETA_MIN * smu, BETA_MAX * smu) - v, -BETA_MAX * smu)
                cx, cs, cz = direction(
                    cones.divide(lam, np.concatenate([dv, np.zeros(3 * k)])), rx=zero_x, rz=zero_z
                )
                trial = min(cones.max_step(s, ds + cs), cones.max_step(z, dz + cz))
                if trial < step + GONDZIO_ACCEPT * (target - step):
                    break
                dx, ds, dz, step = dx + cx, ds + cs, dz + cz, trial
            alpha = min(1.0, STEP_FRACTION * step)
            history.append((it, mu, alpha, res))
            x = x + alpha * dx
            s = s + alpha * ds
            z = z + alpha * dz
            stalls = stalls + 1 if alpha < 1e-8 else 0
            if stalls >= 10 or not (np.all(np.isfinite(x)) and np.all(np.isfinite(z))):
                status = Status.INACCURATE
                break
    except (np.linalg.LinAlgError, RuntimeError, ValueError, ArithmeticError) as exc:
        if best is None:
            raise
        status = Status.INACCURATE
        history.append((len(history) + 1, float("nan"), 0.0, float("nan")))
        if verbose:
            print(f"ipm: stopped: {type(exc).__name__}: {exc}")
    finally:
        if lin is not None:
            lin.close()
    assert best is not None
    res_best, _, z_best = best
    p_out = form.impulses(z if status == Status.OPTIMAL else z_best)
    polished = False
    if status != Status.OPTIMAL and polish and np.all(np.isfinite(p_out)):
        # Degenerate contacts (sliding on the cone's boundary) stall an interior
        # point short of the target: finish with the active-set Newton polish.
        # At most as long again as the interior point took.
        t0 = time.perf_counter()
        candidate, info = polish_impulses(
            problem,
            project_coulomb(p_out, problem.mu),
            target=tol,
            time_budget=max(1.0, t0 - solve_start),
        )
        times["polish"] = time.perf_counter() - t0
        if info["ccp_after"] < res_best:
            p_out, res_best, polished = candidate, info["ccp_after"], info["accepted"] > 0
            if res_best <= tol:
                status = Status.OPTIMAL
    solve_time = time.perf_counter() - solve_start
    return Solution.from_impulses(
        problem,
        p_out,
        status,
        len(history),
        (times["setup"], solve_time),
        "ipm",
        status.value,
        linsolve=linsolve,
        threads=threads,
        history=history,
        times=times,
        ccp_residual=ccp_residual(problem, p_out),
        polished=polished,
        factorisations=factorisations[0],
        system_size=int(K.shape[0]),
        system_nnz=int(K.nnz),
        factor_nnz=None if lin is None else lin.factor_nnz,
    )
