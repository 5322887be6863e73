"""The velocity-based primal (COCD) written in cvxpy, solved by any cvxpy solver.

``cvxpy:<SOLVER>`` is the modelling reference: the primal of DESIGN.md section 1
written as cvxpy expressions, straight from the mathematics, not from the
matrix forms of :mod:`cocd.problem`. The unknown is the dimensionless velocity
correction ``x = (u - U) / velocity_scale`` and the objective is divided by
``mass_scale * velocity_scale**2`` (the scaling of
:meth:`~cocd.problem.ConicProblem.primal_conic_form`)::

    min_x  1/2 sum(M / mass_scale * square(x))
    s.t.   per contact a, with u = U + velocity_scale x and everything divided
           by velocity_scale:
           3D:            SOC(D_a/dt + N_a u,  mu_a T_a u)   (cp.SOC, axis=1)
           2D:            D_a/dt + N_a u >= mu_a T_a u  and  >= -mu_a T_a u
           frictionless:  D_a/dt + N_a u >= 0

Minimising the kinetic energy of the correction is the COCD objective
``1/2 u'Mu - u'MU`` up to a constant. It is not written
``sum_squares(sqrt(M / mass_scale) x)``: cvxpy would canonicalise that with
``ndof`` auxiliary variables and equality rows, doubling the problem, and
HiGHS's QP solver rejects the result as non-convex. The 2D cone is written as its two
half-planes, so 2D and frictionless problems are QPs that QP-only solvers
(OSQP, PIQP, PROXQP, DAQP, HIGHS) accept; 3D friction needs a conic solver
(``facets`` is not offered here: use ``qp:<name>:facets=k``).

Impulses are the multipliers of the constraints (``constraint.dual_value``),
times ``mass_scale * velocity_scale``: for ``cp.SOC(t, X)`` cvxpy returns the
pair ``[z_t (nc,), z_X (nc, 2)]`` in the (self-dual) cone, and
``p = (z_t, mu z_X)``; in 2D the multipliers ``l-, l+ >= 0`` of the half-planes
``N u + D/dt -+ mu T u >= 0`` give ``p = (l- + l+, mu (l+ - l-))``; frictionless
``p_N = l``. ``tests/test_cvxpy.py`` checks them against ``clarabel``'s.

Tolerances. The target is the framework's ``ccp_residual <= tol``
(:mod:`solvers.refine`): the solver runs with its native tolerances at
``tol * 1e-2`` (first-order solvers, SCS and OSQP: at ``tol``), an answer
above the target is polished (:mod:`solvers.polish`, off with
``polish=False``), then solved again with native tolerances 100 times
tighter, down to the solver's floor. Re-solves reuse cvxpy's compiled problem,
and cvxpy starts SCS, OSQP and HIGHS from the previous attempt's answer (its
solver cache); not PROXQP, whose cached re-solve in cvxpy 1.9 keeps the old
tolerances, so it is solved afresh. Iterations and times add up over the
solves.

========  ===========================================  ==================  ==============  =====
solver    native tolerances, at the native tol ``e``   ``max_iter``        ``time_limit``  floor
========  ===========================================  ==================  ==============  =====
CLARABEL  ``tol_gap_abs = tol_gap_rel = tol_feas = e``  ``max_iter``        ``time_limit``  1e-12
          and ``tol_ktratio = min(1e-6, e)``
ECOS      ``abstol = reltol = feastol = e`` (below      ``max_iters``       not supported   1e-10
          1e-10 ECOS stops ``optimal_inaccurate``
          with a worse answer than at 1e-10)
SCS       ``eps_abs = eps_rel = e``                     ``max_iters``       ``time_limit_   1e-12
                                                                            secs``
MOSEK     ``mosek_params``: ``MSK_DPAR_INTPNT_CO_TOL_   ``mosek_params``:   ``mosek_params  1e-14
          {PFEAS,DFEAS,REL_GAP} = e``, and the same     ``MSK_IPAR_INTPNT_  ``: ``MSK_DPAR_
          ``INTPNT_QO_TOL_*``                           MAX_ITERATIONS``    OPTIMIZER_MAX_
                                                                            TIME``
CVXOPT    ``abstol = reltol = feastol = e``             ``max_iters``       not supported   1e-10
OSQP      ``eps_abs = eps_rel = e`` and                 ``max_iter``        ``time_limit``  1e-10
          ``polishing=True`` (``polish`` before 1.0)
PIQP      ``eps_abs = eps_rel = e`` and                 ``max_iter``        not supported   1e-13
          ``eps_duality_gap_abs = _rel = e``
PROXQP    ``eps_abs = e``, ``eps_rel = 0`` (cvxpy's     ``max_iter``        not supported   1e-13
          dense backend: its ``backend="sparse"``
          fails with proxsuite 0.8)
DAQP      ``primal_tol = dual_tol = e`` (active set;    ``iter_limit``      not supported   1e-13
          cvxpy densifies the problem); ``eps_prox =
          0`` (``P`` is positive definite)
HIGHS     ``primal_feasibility_tolerance = dual_        ``qp_iteration_     ``time_limit``  1e-10
          feasibility_tolerance = max(e, 1e-10)``       limit``
          (HiGHS refuses less); its active-set QP
          solver gives the same answer whatever
          they are: its accuracy comes from polishing
========  ===========================================  ==================  ==============  =====

``max_iter`` applies per solve; ``time_limit`` is shared by the solves (the time
left is passed to each). "not supported": the solver has no such setting and
the limit is not enforced.

========================  =====================================================
cocd                      cvxpy
========================  =====================================================
``status``                ``optimal`` when ``ccp_residual <= tol``,
                          ``inaccurate`` when the solver answered
                          (``optimal`` or ``optimal_inaccurate``) but the
                          target was not reached; otherwise ``STATUS_MAP`` on
                          cvxpy's status (``user_limit`` is ``time_limit`` when
                          a time limit was given and used up, else
                          ``max_iter``); a ``cvxpy.error.SolverError`` is
                          ``error``
``warm_start``            not supported (the registry says so and
                          :func:`solvers.solve` drops it): cvxpy warm-starts a
                          solver only from its own previous solve of the same
                          ``cvxpy.Problem``, and the problem is new at every
                          step. A ``warm_start`` passed directly is ignored.
``verbose``               cvxpy's ``verbose`` (cvxpy's log and the solver's)
``setup_time``            building the cvxpy problem and compiling it
                          (``get_problem_data``; re-solves add cvxpy's
                          ``compilation_time`` of their cached fast path)
``solve_time``            the rest of each ``Problem.solve`` call: the
                          solver's own set-up and solve, behind cvxpy's
                          interface; plus polishing. The solver's own
                          reported time (``solver_stats.solve_time``) is in
                          ``extras["native_solve_time"]``
``iterations``            ``solver_stats.num_iters``, summed over the solves
``**options``             ``polish`` (bool), and the solver's settings not
                          mapped above, passed to ``Problem.solve`` (e.g.
                          ``direct_solve_method`` for CLARABEL,
                          ``acceleration_lookback`` for SCS, ``backend`` for
                          PIQP and PROXQP); an unknown name is a ProblemError
========================  =====================================================
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import cvxpy as cp
import cvxpy.settings as cps
import numpy as np

from cocd.errors import ProblemError
from solvers.base import Request, Solution, Status
from solvers.refine import Attempt, solve_to_target
from solvers.registry import CVXPY_SOLVERS

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from cocd.problem import ConicProblem

__all__ = ["STATUS_MAP", "CvxpyModel", "build_model", "cvxpy_solve_problem"]

#: cvxpy status -> shared status (``user_limit`` is refined by the time used).
STATUS_MAP: dict[str, Status] = {
    cps.OPTIMAL: Status.OPTIMAL,
    cps.OPTIMAL_INACCURATE: Status.INACCURATE,
    cps.INFEASIBLE: Status.INFEASIBLE,
    cps.INFEASIBLE_INACCURATE: Status.INFEASIBLE,
    cps.UNBOUNDED: Status.INFEASIBLE,
    cps.UNBOUNDED_INACCURATE: Status.INFEASIBLE,
    cps.INFEASIBLE_OR_UNBOUNDED: Status.INFEASIBLE,
    cps.USER_LIMIT: Status.MAX_ITER,
    cps.SOLVER_ERROR: Status.ERROR,
    cps.UNKNOWN: Status.ERROR,
}

#: Solvers whose cached re-solve in cvxpy ignores new settings (tolerances, limits).
_FRESH_RESOLVE = frozenset({"PROXQP"})

_MOSEK_TOLERANCES = (
    "MSK_DPAR_INTPNT_CO_TOL_PFEAS",
    "MSK_DPAR_INTPNT_CO_TOL_DFEAS",
    "MSK_DPAR_INTPNT_CO_TOL_REL_GAP",
    "MSK_DPAR_INTPNT_QO_TOL_PFEAS",
    "MSK_DPAR_INTPNT_QO_TOL_DFEAS",
    "MSK_DPAR_INTPNT_QO_TOL_REL_GAP",
)


@dataclass(frozen=True)
class _Native:
    """How one cvxpy solver's settings follow cocd's ``tol``, ``max_iter``, ``time_limit``."""

    tolerances: Callable[[float], dict[str, Any]]
    max_iter: str | None
    time_limit: str | None
    floor: float
    #: Fixed settings (overridable by the user).
    defaults: tuple[tuple[str, Any], ...] = ()
    #: Settings a user may not pass besides the tolerances (another name for them).
    aliases: frozenset[str] = frozenset()

    @property
    def mapped(self) -> frozenset[str]:
        """Settings a user may not pass (cocd sets them): the tolerances' names (inside
        MOSEK's ``mosek_params``) and the aliases."""
        names: set[str] = set()
        for key, value in self.tolerances(1.0).items():
            names |= set(value) if isinstance(value, dict) else {key}
        return frozenset(names) | self.aliases


def _equal(*names: str) -> Callable[[float], dict[str, Any]]:
    """Native tolerances that are all the native tol."""
    return lambda e: dict.fromkeys(names, e)


def _osqp_polish_key() -> str:
    import osqp

    return "polish" if int(osqp.__version__.split(".")[0]) < 1 else "polishing"


def _native(solver: str) -> _Native:
    if solver == "CLARABEL":
        tolerances = _equal("tol_gap_abs", "tol_gap_rel", "tol_feas")
        return _Native(
            lambda e: {**tolerances(e), "tol_ktratio": min(1e-6, e)},
            "max_iter",
            "time_limit",
            1e-12,
        )
    if solver in ("ECOS", "CVXOPT"):
        return _Native(_equal("abstol", "reltol", "feastol"), "max_iters", None, 1e-10)
    if solver == "SCS":
        eps = _equal("eps_abs", "eps_rel")
        return _Native(eps, "max_iters", "time_limit_secs", 1e-12, aliases=frozenset({"eps"}))
    if solver == "OSQP":
        eps = _equal("eps_abs", "eps_rel")
        return _Native(eps, "max_iter", "time_limit", 1e-10, ((_osqp_polish_key(), True),))
    if solver == "PIQP":
        gaps = _equal("eps_abs", "eps_rel", "eps_duality_gap_abs", "eps_duality_gap_rel")
        return _Native(gaps, "max_iter", None, 1e-13)
    if solver == "PROXQP":
        return _Native(lambda e: {"eps_abs": e, "eps_rel": 0.0}, "max_iter", None, 1e-13)
    if solver == "DAQP":
        # P = diag(M / ms) is positive definite: no proximal term, and no
        # Cholesky test of the dense P by cvxpy (0.26 s at ndof = 180 here).
        daqp = _equal("primal_tol", "dual_tol")
        return _Native(daqp, "iter_limit", None, 1e-13, (("eps_prox", 0.0),))
    if solver == "HIGHS":
        highs = _equal("primal_feasibility_tolerance", "dual_feasibility_tolerance")
        return _Native(lambda e: highs(max(e, 1e-10)), "qp_iteration_limit", "time_limit", 1e-10)
    if solver == "MOSEK":
        return _Native(
            lambda e: {"mosek_params": dict.fromkeys(_MOSEK_TOLERANCES, e)},
            "MSK_IPAR_INTPNT_MAX_ITERATIONS",
            "MSK_DPAR_OPTIMIZER_MAX_TIME",
            1e-14,
            aliases=frozenset({"eps"}),
        )
    raise ProblemError(
        f"cvxpy solver {solver!r} has no cocd mapping; known: {', '.join(CVXPY_SOLVERS)}"
    )


@dataclass
class CvxpyModel:
    """The COCD primal of one problem as a cvxpy problem.

    ``x`` is the velocity correction ``(u - U) / velocity_scale``; ``constraints``
    are the contact constraints whose multipliers are the impulses.
    """

    problem: ConicProblem
    cvx: cp.Problem
    x: cp.Variable
    constraints: list[cp.Constraint]

    def velocity(self) -> NDArray[np.float64]:
        """``u = U + velocity_scale x`` at the solver's answer."""
        _, vs = self.problem.scales
        return np.asarray(self.problem.U + vs * np.asarray(self.x.value), dtype=np.float64)

    def impulses(self) -> NDArray[np.float64]:
        """Contact impulses ``(nc, m)`` from the constraints' multipliers."""
        pr = self.problem
        ms, vs = pr.scales
        if pr.contact_dim == 1:
            p = np.asarray(self.constraints[0].dual_value).reshape(pr.nc, 1)
        elif pr.contact_dim == 2:
            minus = np.asarray(self.constraints[0].dual_value).reshape(-1)  # N u + D/dt >= mu T u
            plus = np.asarray(self.constraints[1].dual_value).reshape(-1)  # ... >= -mu T u
            p = np.stack([minus + plus, pr.mu * (plus - minus)], axis=1)
        else:
            z_t, z_x = self.constraints[0].dual_value
            p = np.concatenate(
                [np.reshape(z_t, (pr.nc, 1)), pr.mu[:, None] * np.reshape(z_x, (pr.nc, 2))],
                axis=1,
            )
        return np.asarray(p * (ms * vs), dtype=np.float64)


def build_model(problem: ConicProblem) -> CvxpyModel:
    """Write the COCD primal of ``problem`` in cvxpy (see the module docstring)."""
    ms, vs = problem.scales
    m = problem.contact_dim
    H, mu = problem.H, problem.mu

    x = cp.Variable(problem.ndof, name="x")  # (u - U) / vs
    u = problem.U + vs * x
    # 1/2 sum_i (M_i / ms) x_i^2: cvxpy passes it to the solver as the diagonal P. Written as
    # sum_squares(sqrt(M / ms) x) it would be canonicalised with ndof auxiliary variables
    # and equality rows, which doubles the problem and which HiGHS's QP solver rejects.
    objective = cp.Minimize(0.5 * cp.sum(cp.multiply(problem.mass / ms, cp.square(x))))

    N = H[0::m]  # normal rows
    w0 = problem.offset.reshape(problem.nc, m)  # (D/dt, slip_offset)
    normal = (w0[:, 0] + N @ u) / vs  # gap rate at the end of the step
    constraints: list[cp.Constraint]
    if m == 1:
        constraints = [normal >= 0]
    elif m == 2:
        slip = cp.multiply(mu, H[1::2] @ u + w0[:, 1]) / vs  # mu T u
        constraints = [normal >= slip, normal >= -slip]
    else:
        tangential = cp.vstack([H[1::3] @ u + w0[:, 1], H[2::3] @ u + w0[:, 2]]).T
        slip = cp.multiply(np.repeat(mu[:, None], 2, axis=1), tangential) / vs
        constraints = [cp.SOC(normal, slip, axis=1)]
    return CvxpyModel(problem, cp.Problem(objective, constraints), x, constraints)


def cvxpy_solve_problem(
    problem: ConicProblem, request: Request, *, cvxpy_solver: str = "CLARABEL", **options: Any
) -> Solution:
    """Solve the COCD primal of ``problem`` written in cvxpy with ``cvxpy_solver``.

    See the module's tables for how ``tol``, ``max_iter`` and ``time_limit`` map
    onto each solver's settings.
    """
    tol, max_iter, verbose = request.tol, request.max_iter, request.verbose
    start = time.perf_counter()
    solver = str(cvxpy_solver).upper()
    name = f"cvxpy:{solver}"
    if solver not in CVXPY_SOLVERS:
        raise ProblemError(
            f"unknown cvxpy solver {cvxpy_solver!r}; cocd maps: {', '.join(CVXPY_SOLVERS)}"
        )
    if "facets" in options:
        raise ProblemError(
            f"{name} takes no 'facets' (the cvxpy model is exact): use 'qp:<solver>:facets=k' "
            "for a faceted approximation"
        )
    _, takes_soc, first_order = CVXPY_SOLVERS[solver]
    if not takes_soc and not problem.is_qp:
        raise ProblemError(
            f"{name} takes linear cones only, and this 3D frictional problem has second-order cones"
        )
    native = _native(solver)
    polish = bool(options.pop("polish", True))
    free = _free_options(solver, native, options)

    if problem.nc == 0:
        return Solution.free_flight(problem, name, time.perf_counter() - start)

    model = build_model(problem)
    build_time = time.perf_counter() - start

    def settings(native_tol: float, time_left: float | None) -> dict[str, Any]:
        opts: dict[str, Any] = dict(native.defaults)
        opts.update(free)
        opts.update(native.tolerances(native_tol))
        if solver == "MOSEK":
            params = {**free.get("mosek_params", {}), **opts["mosek_params"]}
            if max_iter is not None:
                params[native.max_iter] = max_iter
            if time_left is not None:
                params[native.time_limit] = time_left
            opts["mosek_params"] = params
            return opts
        if max_iter is not None and native.max_iter is not None:
            opts[native.max_iter] = max_iter
        if time_left is not None and native.time_limit is not None:
            opts[native.time_limit] = time_left
        return opts

    # Compile once here: attempts then take cvxpy's cached fast path.
    first_tol = max(tol * (1.0 if first_order else 1e-2), native.floor)
    model.cvx.get_problem_data(solver, verbose=verbose, solver_opts=settings(first_tol, None))
    setup_time = time.perf_counter() - start
    overheads: list[float] = []
    native_times: list[float] = []

    def attempt(native_tol: float, time_left: float | None) -> Attempt:
        begin = time.perf_counter()
        try:
            with warnings.catch_warnings():
                warnings.filterwarnings("ignore", message="Solution may be inaccurate")
                model.cvx.solve(
                    solver=solver,
                    verbose=verbose,
                    warm_start=solver not in _FRESH_RESOLVE,
                    **settings(native_tol, time_left),
                )
        except cp.error.SolverError as exc:
            overheads.append(0.0)
            return Attempt(
                p=np.zeros((problem.nc, problem.contact_dim)),
                u=None,
                status=Status.ERROR,
                native_status=f"{cps.SOLVER_ERROR}: {str(exc).splitlines()[0]}",
                iterations=0,
            )
        elapsed = time.perf_counter() - begin
        status_text = str(model.cvx.status)
        status = STATUS_MAP.get(status_text, Status.ERROR)
        if status == Status.MAX_ITER and time_left is not None and elapsed >= 0.99 * time_left:
            status = Status.TIME_LIMIT
        stats = model.cvx.solver_stats
        compile_time = float(model.cvx.compilation_time or 0.0)
        overheads.append(min(compile_time, elapsed))
        native_times.append(float(stats.solve_time or 0.0))
        answered = status in (Status.OPTIMAL, Status.INACCURATE) and model.x.value is not None
        if answered:
            p = model.impulses()
            u: NDArray[np.float64] | None = model.velocity()
        else:
            p, u = np.zeros((problem.nc, problem.contact_dim)), None
        return Attempt(
            p=p,
            u=u,
            status=status,
            native_status=status_text,
            iterations=int(stats.num_iters or 0),
            extras={"objective": float(model.cvx.value) if answered else float("nan")},
        )

    solution = solve_to_target(
        problem,
        request,
        attempt,
        solver=name,
        setup_time=setup_time,
        polish=polish,
        first_factor=1.0 if first_order else 1e-2,
        floor=native.floor,
    )
    # cvxpy's per-solve compilation (cached fast path) is set-up, not solving.
    overhead = float(sum(overheads))
    solution.setup_time += overhead
    solution.solve_time = max(solution.solve_time - overhead, 0.0)
    solution.extras.update(
        cvxpy_solver=solver,
        build_time=build_time,
        compile_time=setup_time - build_time + overhead,
        native_solve_time=float(sum(native_times)),
    )
    return solution


#: Settings accepted by solvers without an introspectable settings object.
_STATIC_OPTIONS: dict[str, frozenset[str]] = {
    "ECOS": frozenset(
        {"abstol", "reltol", "feastol", "abstol_inacc", "reltol_inacc", "feastol_inacc"}
        | {"max_iters", "nitref"}
    ),
    "CVXOPT": frozenset({"abstol", "reltol", "feastol", "max_iters", "refinement", "kktsolver"}),
    "SCS": frozenset(
        {"normalize", "scale", "adaptive_scale", "rho_x", "max_iters", "eps_abs", "eps_rel"}
        | {"eps_infeas", "alpha", "time_limit_secs", "acceleration_lookback"}
        | {"acceleration_interval", "linear_solver", "use_indirect", "use_quad_obj"}
    ),
    "DAQP": frozenset(
        {"primal_tol", "dual_tol", "zero_tol", "pivot_tol", "progress_tol", "cycle_tol"}
        | {"iter_limit", "fval_bound", "eps_prox", "eta_prox"}
    ),
    "MOSEK": frozenset({"mosek_params", "save_file", "bfs", "accept_unknown"}),
}


def _known_options(solver: str) -> frozenset[str]:
    """Names of the native settings ``solver`` takes through cvxpy."""
    if solver in _STATIC_OPTIONS:
        return _STATIC_OPTIONS[solver]
    if solver == "CLARABEL":
        import clarabel

        names = set(dir(clarabel.DefaultSettings())) | {"use_quad_obj"}
    elif solver == "OSQP":
        import osqp

        try:
            from osqp.ext_builtin import OSQPSettings

            names = set(dir(OSQPSettings()))
        except ImportError:  # OSQP < 1.0
            names = set(osqp.OSQP().default_settings())
    elif solver == "PIQP":
        import piqp

        names = set(dir(piqp.SparseSolver().settings)) | {"backend"}
    elif solver == "PROXQP":
        import proxsuite

        names = set(dir(proxsuite.proxqp.Settings())) | {"backend", "rho", "mu_eq", "mu_in"}
    elif solver == "HIGHS":
        import highspy

        names = set(dir(highspy.HighsOptions())) | {"highs_options", "write_model_file"}
    else:
        names = set()
    return frozenset(n for n in names if not n.startswith("_"))


def _free_options(solver: str, native: _Native, options: dict[str, Any]) -> dict[str, Any]:
    """The user's native settings, refused when cocd maps them or ``solver`` lacks them."""
    limits = {native.max_iter, native.time_limit} - {None}
    known = _known_options(solver)
    for key in options.get("mosek_params", {}) if solver == "MOSEK" else ():
        if key in native.mapped or key in limits:
            raise ProblemError(
                f"cvxpy:MOSEK: mosek_params[{key!r}] is set by cocd (tolerances follow tol, "
                "limits follow max_iter and time_limit)"
            )
    for key in options:
        if key in native.mapped or key in limits:
            raise ProblemError(
                f"cvxpy:{solver}: {key!r} is set by cocd (tolerances follow tol, limits "
                "follow max_iter and time_limit)"
            )
        if key not in known:
            raise ProblemError(
                f"cvxpy:{solver} has no setting {key!r}; see the solver's documentation "
                "(settings cocd does not map are passed through cvxpy)"
            )
    return dict(options)
