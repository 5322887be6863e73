"""SCS (operator splitting) on the velocity-based primal (COCD) and on the force-based dual.

``scs``: the primal ``min 1/2 x'Px  s.t.  A x + s = b,  s in K``
(:meth:`cocd.problem.ConicProblem.primal_conic_form`, velocity correction);
impulses from SCS's dual variables ``y`` of the contact rows.

``scs-dual``: the force-based dual ``min 1/2 x'Px + q'x, x in K``
(:meth:`cocd.problem.ConicProblem.dual_conic_form`, ``P = mass_scale W``
sparse); impulses from ``x``, velocities ``u = U + M^-1 H'p``.

One function for both, :func:`scs_solve_problem`, taking the form
(:mod:`solvers._conic`), through SCS's own Python API (``scs.SCS``, not cvxpy). The forms already
order their rows as SCS wants them (zero, nonnegative, second-order cones);
SCS is given the upper triangle of ``P``. The impulses are projected on their
Coulomb cones (SCS's ``y`` lies in the dual cone and its ``s`` in the cone, but
its ``x`` only up to the primal residual).

========================  =====================================================
cocd                      SCS
========================  =====================================================
``tol``                   the target is the framework's ``ccp_residual <= tol``
                          (:mod:`solvers.refine`): SCS runs with
                          ``eps_abs = eps_rel = tol`` (SCS's residuals are
                          already far below ``tol`` in natural-map terms on
                          contact problems); an answer above the target is
                          polished (:mod:`solvers.polish`, off with
                          ``polish=False``), then solved again, warm-started
                          from the previous attempt, with ``eps`` 100 times
                          tighter, down to ``1e-12`` (reached in 125 to 250
                          iterations on 2D and 3D steps; 1e-14 can take
                          thousands). Iterations and times add up.
``status``                ``optimal`` when ``ccp_residual <= tol``;
                          ``inaccurate`` when SCS answered (``solved``, or its
                          best guess at the iteration cap or time limit,
                          ``status_val`` 2, which is polished and judged like
                          any answer) but the target was not reached;
                          otherwise ``STATUS_MAP`` on SCS's ``status_val``
                          (``extras["native_status"]`` keeps SCS's string)
``max_iter``              ``max_iters`` per solve (default here 20 000). SCS
                          tests convergence every 25 iterations, so counts
                          are multiples of 25 (0 when the start is optimal)
``time_limit``            ``time_limit_secs``, shared by the solves (seconds)
``warm_start``            impulses ``p0`` (projected on their cones):
                          ``scs-dual`` starts from ``x = p0 / impulse_scale``,
                          ``s = -A x`` and the ``y`` solving the stationarity
                          condition ``P x + q + A'y = 0`` (``A`` is square),
                          projected on ``K*``; ``scs`` starts from the
                          velocity correction ``p0`` implies,
                          ``x = M^-1 H'p0 / velocity_scale``, the multipliers
                          ``y`` whose impulses are ``p0`` (3D: ``(p_N,
                          p_T / mu)``; 2D: ``(p_N +- p_T / mu) / 2`` clipped
                          at 0; ``mu = 0``: ``p_N`` split evenly), scaled by
                          ``1 / (mass_scale velocity_scale)``, and
                          ``s = P_K(b - A x)``. Re-solves inside one call
                          always start from the previous attempt.
``verbose``               ``verbose``
``**options``             ``polish`` (bool) and SCS settings not mapped above:
                          ``normalize, scale, adaptive_scale, rho_x, alpha,
                          acceleration_lookback, acceleration_interval,
                          eps_infeas, linear_solver`` (default ``auto``: MKL
                          Pardiso when SCS ships it, ``qdldl`` otherwise)
========================  =====================================================

SCS's own stopping test is on its primal and dual residuals and duality gap,
not on the natural map of the contact law. When its answer misses the target,
polishing reads the contacts' active set from it and solves for that set
exactly, which turns an approximate answer into one at rounding level
whenever the active set read is right.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import scs
from numpy.typing import NDArray

from cocd.cones import project_coulomb
from solvers._conic import answer, check_setting, no_free_setting, prepare, to_target
from solvers.base import FloatArray, Request, Solution, Status
from solvers.refine import Attempt

if TYPE_CHECKING:
    from cocd.problem import ConicProblem, DualConicForm, PrimalConicForm

__all__ = ["STATUS_MAP", "scs_dual_solve_problem", "scs_solve_problem"]

#: SCS ``info["status_val"]`` (documented exit flags) -> shared status.
STATUS_MAP: dict[int, Status] = {
    1: Status.OPTIMAL,  # solved
    2: Status.INACCURATE,  # solved (inaccurate - reached max_iters / time_limit_secs)
    0: Status.ERROR,  # unfinished (never returned)
    -1: Status.INFEASIBLE,  # unbounded
    -2: Status.INFEASIBLE,  # infeasible
    -3: Status.ERROR,  # indeterminate
    -4: Status.ERROR,  # failed
    -5: Status.ERROR,  # interrupted (SIGINT)
    -6: Status.INFEASIBLE,  # unbounded (inaccurate)
    -7: Status.INFEASIBLE,  # infeasible (inaccurate)
}

#: First native eps relative to ``tol``, and the tightest eps tried.
FIRST_EPS_FACTOR = 1.0
SMALLEST_EPS = 1e-12
DEFAULT_MAX_ITERS = 20_000

#: SCS's settings left to the user, with the type each takes.
_FREE: dict[str, type] = {
    "normalize": bool,
    "scale": float,
    "adaptive_scale": bool,
    "rho_x": float,
    "alpha": float,
    "acceleration_lookback": int,
    "acceleration_interval": int,
    "eps_infeas": float,
    "linear_solver": object,  # a name or scs.LinearSolver: SCS checks it
}

Start = tuple[FloatArray, FloatArray, FloatArray]


def scs_solve_problem(
    problem: ConicProblem, request: Request, *, form: str = "primal", **options: Any
) -> Solution:
    """Solve ``form`` of ``problem`` with SCS (see the module's table)."""
    start, model, polish = prepare(problem, form, options)
    warm_start = request.warm_start
    first = None if warm_start is None else _START[form](model, warm_start)
    settings = _settings(request, options)
    data, cone = _data(model)
    runner = _Runner(data, cone, settings, first)

    def attempt(native_tol: float, time_left: float | None) -> Attempt:
        sol = runner.run(native_tol, time_left)
        info = sol["info"]
        p, u = answer(model, sol["x"], sol["y"])
        status = STATUS_MAP.get(int(info["status_val"]), Status.ERROR)
        iterations = int(info["iter"])
        p = project_coulomb(p, problem.mu)
        return Attempt(p, u, status, str(info["status"]), iterations, _extras(info))

    return to_target(
        problem,
        form,
        request,
        attempt,
        base="scs",
        start=start,
        polish=polish,
        first_factor=FIRST_EPS_FACTOR,
        floor=min(SMALLEST_EPS, request.tol),
    )


#: The force-based dual, for direct calls (the registry passes ``form="dual"``).
scs_dual_solve_problem = functools.partial(scs_solve_problem, form="dual")


class _Runner:
    """Runs SCS at a given eps; each run after the first starts from the last answer.

    SCS fixes its settings when it is built, so a tighter eps needs a new
    solver (one more factorisation of its small KKT matrix); the warm start
    carries the progress over.
    """

    def __init__(
        self,
        data: dict[str, Any],
        cone: dict[str, Any],
        settings: dict[str, Any],
        start: Start | None,
    ) -> None:
        self.data, self.cone, self.settings = data, cone, settings
        self.start = start

    def run(self, eps: float, time_left: float | None) -> dict[str, Any]:
        settings = dict(self.settings, eps_abs=eps, eps_rel=eps)
        if time_left is not None:
            settings["time_limit_secs"] = time_left
        solver = scs.SCS(self.data, self.cone, **settings)
        if self.start is None:
            sol: dict[str, Any] = solver.solve(warm_start=False)
        else:
            x, y, s = self.start
            sol = solver.solve(warm_start=True, x=x, y=y, s=s)
        if all(np.all(np.isfinite(sol[k])) for k in ("x", "y", "s")):
            self.start = (sol["x"], sol["y"], sol["s"])
        return sol


def _settings(request: Request, options: dict[str, Any]) -> dict[str, Any]:
    for key in options:
        if key not in _FREE:
            raise no_free_setting(
                "scs",
                key,
                "eps, max_iters and time_limit_secs follow tol, max_iter and time_limit",
                f"free settings: {', '.join(sorted(_FREE))}",
            )
        check_setting("scs", key, options[key], _FREE[key])
    settings = dict(options)
    settings["verbose"] = bool(request.verbose)
    max_iter = request.max_iter
    settings["max_iters"] = DEFAULT_MAX_ITERS if max_iter is None else int(max_iter)
    return settings


def _data(form: PrimalConicForm | DualConicForm) -> tuple[dict[str, Any], dict[str, Any]]:
    data = {
        "P": sp.triu(form.P, format="csc"),
        "A": sp.csc_matrix(form.A),
        "b": np.asarray(form.b, dtype=np.float64),
        "c": np.asarray(form.q, dtype=np.float64),
    }
    cone: dict[str, Any] = {}
    for kind, size in form.cones:
        if kind == "zero":
            cone["z"] = cone.get("z", 0) + size
        elif kind == "nonneg":
            cone["l"] = cone.get("l", 0) + size
        else:
            cone.setdefault("q", []).append(size)
    return data, cone


def _project(v: NDArray[np.float64], cones: Sequence[tuple[str, int]], dual: bool) -> Any:
    """Project ``v`` on the cone ``K`` (``dual=False``) or on ``K*`` (``dual=True``).

    Cones follow SCS's order (zero, nonnegative, second-order of dimension 3).
    """
    out = np.array(v, dtype=np.float64)
    i = 0
    for kind, size in cones:
        block = out[i : i + size]
        if kind == "zero":
            if not dual:
                block[:] = 0.0
        elif kind == "nonneg":
            np.maximum(block, 0.0, out=block)
        else:
            t, z = block[0], block[1:]
            nz = float(np.linalg.norm(z))
            if nz <= -t:
                block[:] = 0.0
            elif nz > t:
                a = 0.5 * (t + nz)
                block[0] = a
                block[1:] = a * z / nz
        i += size
    return out


def _primal_start(form: PrimalConicForm, p0: NDArray[np.float64]) -> Start:
    """``(x, y, s)`` of the primal form for impulses ``p0``."""
    pr = form.problem
    p = project_coulomb(np.asarray(p0, dtype=np.float64).reshape(pr.nc, pr.contact_dim), pr.mu)
    x = (pr.velocity(p) - pr.U) / form.velocity_scale
    y = _multipliers(pr, p) / (form.mass_scale * form.velocity_scale)
    s = _project(form.b - form.A @ x, form.cones, dual=False)
    return x, np.asarray(y, dtype=np.float64), s


def _multipliers(problem: ConicProblem, p: NDArray[np.float64]) -> NDArray[np.float64]:
    """The inverse of :meth:`PrimalConicForm.impulses` (before its scaling), flattened.

    3D: ``(p_N, p_T / mu)``; 2D: the two half-plane multipliers ``l1, l2`` with
    ``p_N = l1 + l2`` and ``p_T = mu (l1 - l2)``, i.e. ``(p_N +- p_T / mu) / 2``
    (clipped at 0); frictionless contacts split ``p_N`` evenly.
    """
    mu = problem.mu
    if problem.contact_dim == 1:
        return np.asarray(p.reshape(-1))
    rough = mu > 0.0
    safe = np.where(rough, mu, 1.0)
    if problem.contact_dim == 2:
        ratio = np.where(rough, p[:, 1] / safe, 0.0)
        lam = np.stack([p[:, 0] + ratio, p[:, 0] - ratio], axis=1) / 2.0
        return np.asarray(np.maximum(lam, 0.0).reshape(-1))
    z = p.copy()
    z[:, 1:] = np.where(rough[:, None], p[:, 1:] / safe[:, None], 0.0)
    return np.asarray(z.reshape(-1))


def _dual_start(form: DualConicForm, p0: NDArray[np.float64]) -> Start:
    """``(x, y, s)`` of the dual form for impulses ``p0``.

    ``s = -A x`` is ``p0`` in the cone's coordinates; ``y`` solves the
    stationarity condition ``P x + q + A'y = 0`` (``A`` is square and
    invertible: one row per impulse component, friction coefficients on the
    diagonal of its blocks), then is projected on ``K*``.
    """
    pr = form.problem
    p = project_coulomb(np.asarray(p0, dtype=np.float64).reshape(pr.nc, pr.contact_dim), pr.mu)
    x = form.point(p)
    s = _project(-(form.A @ x), form.cones, dual=False)
    grad = form.P @ x + form.q
    try:
        y = spla.spsolve(sp.csc_matrix(form.A.T), -grad)
    except RuntimeError:
        y = np.zeros(form.A.shape[0])
    if not np.all(np.isfinite(y)):
        y = np.zeros(form.A.shape[0])
    return x, _project(np.asarray(y, dtype=np.float64), form.cones, dual=True), s


#: The starting point of each form for impulses ``p0``.
_START: dict[str, Callable[[Any, NDArray[np.float64]], Start]] = {
    "primal": _primal_start,
    "dual": _dual_start,
}


def _extras(info: dict[str, Any]) -> dict[str, Any]:
    return {
        "objective": float(info["pobj"]),
        "objective_dual": float(info["dobj"]),
        "r_prim": float(info["res_pri"]),
        "r_dual": float(info["res_dual"]),
        "gap": float(info["gap"]),
        "scs_setup_ms": float(info["setup_time"]),
        "scs_solve_ms": float(info["solve_time"]),
    }
