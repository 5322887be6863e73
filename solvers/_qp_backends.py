"""How :mod:`solvers.qpsolvers_` drives each qpsolvers backend (see its table).

One :class:`Backend` per qpsolvers name: the native settings that follow
``tol``, ``max_iter`` and ``time_limit``, the names of every native setting (read
from the installed package), how to read the status and the iteration count
from qpsolvers' ``Solution``, the smallest native tolerance, and whether the
duals can be given as a start. Whether a backend takes a starting point at all
is its registry fact (:data:`solvers.registry.QP_SOLVERS`). Packages are imported
only when asked about.
"""

from __future__ import annotations

import inspect
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from solvers.base import Status

__all__ = ["BACKENDS", "GENERIC", "Backend"]

Settings = Callable[[float, int | None, float | None], dict[str, Any]]


def _found_status(sol: Any) -> tuple[str, Status]:
    """For wrappers that expose only ``found``."""
    return ("found", Status.OPTIMAL) if sol.found else ("not found", Status.ERROR)


def _no_iterations(sol: Any) -> int | None:
    return None


@dataclass(frozen=True)
class Backend:
    """How one qpsolvers backend is driven (see the table of :mod:`solvers.qpsolvers_`)."""

    settings: Settings
    #: Every native setting name, or None when it cannot be checked here.
    names: Callable[[], set[str]] | None
    status: Callable[[Any], tuple[str, Status]] = _found_status
    iterations: Callable[[Any], int | None] = _no_iterations
    #: Smallest native tolerance, or None for a single solve.
    floor: float | None = 1e-12
    dual_start: bool = False
    dense: bool = False
    defaults: dict[str, Any] = field(default_factory=dict)

    @property
    def mapped(self) -> frozenset[str]:
        """Native names set from tol, max_iter, time_limit (not settable by the user)."""
        return frozenset(self.settings(1.0, 1, 1.0))


def _opt(**kwargs: Any) -> dict[str, Any]:
    """Drop the ``None`` values."""
    return {k: v for k, v in kwargs.items() if v is not None}


# -- osqp ---------------------------------------------------------------------
_OSQP_STATUS = {
    "OSQP_SOLVED": Status.OPTIMAL,
    "OSQP_SOLVED_INACCURATE": Status.INACCURATE,
    "OSQP_MAX_ITER_REACHED": Status.MAX_ITER,
    "OSQP_TIME_LIMIT_REACHED": Status.TIME_LIMIT,
    "OSQP_PRIMAL_INFEASIBLE": Status.INFEASIBLE,
    "OSQP_PRIMAL_INFEASIBLE_INACCURATE": Status.INFEASIBLE,
    "OSQP_DUAL_INFEASIBLE": Status.INFEASIBLE,
    "OSQP_DUAL_INFEASIBLE_INACCURATE": Status.INFEASIBLE,
}


def _osqp_status(sol: Any) -> tuple[str, Status]:
    from osqp import SolverStatus

    info = sol.extras["info"]
    names = {int(getattr(SolverStatus, n)): n for n in dir(SolverStatus) if n.startswith("OSQP_")}
    name = names.get(int(info.status_val), str(info.status))
    return name, _OSQP_STATUS.get(name, Status.ERROR)


def _osqp_names() -> set[str]:
    from osqp import OSQP

    fields = {k for k in OSQP().ext.OSQPSettings.__dict__ if not k.startswith("_")}
    return fields | {"solver_type", "cg_preconditioner", "raise_error"}


# -- proxqp -------------------------------------------------------------------
_PROXQP_STATUS = {
    "PROXQP_SOLVED": Status.OPTIMAL,
    "PROXQP_MAX_ITER_REACHED": Status.MAX_ITER,
    "PROXQP_PRIMAL_INFEASIBLE": Status.INFEASIBLE,
    "PROXQP_DUAL_INFEASIBLE": Status.INFEASIBLE,
    "PROXQP_SOLVED_CLOSEST_PRIMAL_FEASIBLE": Status.INFEASIBLE,
}


def _enum_name(value: Any) -> str:
    return str(value).split(".")[-1]


def _proxqp_status(sol: Any) -> tuple[str, Status]:
    name = _enum_name(sol.extras["info"].status)
    return name, _PROXQP_STATUS.get(name, Status.ERROR)


def _proxqp_names() -> set[str]:
    from proxsuite import proxqp

    head = (proxqp.sparse.solve.__doc__ or "").split(")")[0]
    names = set(re.findall(r"(\w+):", head)) - {"H", "g", "A", "b", "C", "l", "u", "x", "z"}
    return names | {"backend"}


# -- piqp ---------------------------------------------------------------------
_PIQP_STATUS = {
    "PIQP_SOLVED": Status.OPTIMAL,
    "PIQP_MAX_ITER_REACHED": Status.MAX_ITER,
    "PIQP_PRIMAL_INFEASIBLE": Status.INFEASIBLE,
    "PIQP_DUAL_INFEASIBLE": Status.INFEASIBLE,
}


def _piqp_status(sol: Any) -> tuple[str, Status]:
    name = _enum_name(sol.extras["info"].status)
    return name, _PIQP_STATUS.get(name, Status.ERROR)


def _piqp_names() -> set[str]:
    import piqp

    settings = piqp.SparseSolver().settings
    return {k for k in dir(settings) if not k.startswith("_")} | {"backend"}


def _info_iter(sol: Any) -> int | None:
    return int(sol.extras["info"].iter)


# -- clarabel -----------------------------------------------------------------
def _clarabel_status(sol: Any) -> tuple[str, Status]:
    from solvers.clarabel_ import STATUS_MAP

    if not isinstance(sol.extras, dict) or "status" not in sol.extras:
        return _found_status(sol)
    name = _enum_name(sol.extras["status"])
    return name, STATUS_MAP.get(name, Status.ERROR)


def _clarabel_names() -> set[str]:
    import clarabel

    return {k for k in dir(clarabel.DefaultSettings()) if not k.startswith("_")}


# -- daqp, highs, quadprog ----------------------------------------------------
def _daqp_names() -> set[str]:
    import daqp

    data = {"H", "f", "A", "bupper", "blower", "sense", "primal_start"}
    return set(inspect.signature(daqp.solve).parameters) - data


def _highs_names() -> set[str]:
    import highspy

    return {k for k in dir(highspy.HighsOptions()) if not k.startswith("_")}


def _quadprog_iterations(sol: Any) -> int | None:
    if not isinstance(sol.extras, dict) or "iterations" not in sol.extras:
        return None
    return int(np.atleast_1d(sol.extras["iterations"])[0])


# -- scs, ecos ----------------------------------------------------------------
_SCS_NAMES = {
    "normalize",
    "scale",
    "adaptive_scale",
    "rho_x",
    "max_iters",
    "eps_abs",
    "eps_rel",
    "eps_infeas",
    "alpha",
    "time_limit_secs",
    "acceleration_lookback",
    "acceleration_interval",
    "write_data_filename",
    "log_csv_filename",
}


def _scs_status(sol: Any) -> tuple[str, Status]:
    info = sol.extras
    name = str(info.get("status", "unknown"))
    val = int(info.get("status_val", 0))
    if val == 1:
        return name, Status.OPTIMAL
    if val == 2:
        if "max_iters" in name or "iterations" in name:
            return name, Status.MAX_ITER
        if "time" in name:
            return name, Status.TIME_LIMIT
        return name, Status.INACCURATE
    if val in (-1, -2, -6, -7):
        return name, Status.INFEASIBLE
    return name, Status.ERROR


_ECOS_NAMES = {
    "feastol",
    "abstol",
    "reltol",
    "feastol_inacc",
    "abstol_inacc",
    "reltol_inacc",
    "max_iters",
    "nitref",
}


def _ecos_status(sol: Any) -> tuple[str, Status]:
    from solvers.ecos_ import STATUS_MAP

    flag = int(sol.extras.get("exitFlag", -7))
    name = str(sol.extras.get("infostring", f"exitFlag {flag}"))
    return name, STATUS_MAP.get(flag, Status.ERROR)


def _dict_iter(key: str) -> Callable[[Any], int | None]:
    def iterations(sol: Any) -> int | None:
        extras = sol.extras if isinstance(sol.extras, dict) else {}
        return int(extras[key]) if key in extras else None

    return iterations


# -- not installed where this was written: names from qpsolvers' wrappers ------
def _cvxopt_status(sol: Any) -> tuple[str, Status]:
    name = str(sol.extras.get("status", "unknown")) if isinstance(sol.extras, dict) else "unknown"
    if name == "optimal":
        return name, Status.OPTIMAL
    return name, Status.INACCURATE if sol.x is not None else Status.ERROR


def _qpalm_names() -> set[str]:
    import qpalm

    return {k for k in dir(qpalm.Settings()) if not k.startswith("_")}


def _gurobi_names() -> set[str]:
    from gurobipy import GRB

    return {k for k in dir(GRB.Param) if not k.startswith("_")}


def _qpalm_status(sol: Any) -> tuple[str, Status]:
    name = str(sol.extras["info"].status)
    if name == "solved":
        return name, Status.OPTIMAL
    if "iter" in name:
        return name, Status.MAX_ITER
    if "time" in name:
        return name, Status.TIME_LIMIT
    if "infeasible" in name:
        return name, Status.INFEASIBLE
    return name, Status.ERROR


def _gurobi_status(sol: Any) -> tuple[str, Status]:
    code = int(sol.extras.get("status", -1)) if isinstance(sol.extras, dict) else -1
    # GRB.OPTIMAL 2, INFEASIBLE 3, INF_OR_UNBD 4, UNBOUNDED 5, ITERATION_LIMIT 7,
    # TIME_LIMIT 9, SUBOPTIMAL 13.
    mapping = {
        2: Status.OPTIMAL,
        13: Status.INACCURATE,
        3: Status.INFEASIBLE,
        4: Status.INFEASIBLE,
        5: Status.INFEASIBLE,
        7: Status.MAX_ITER,
        9: Status.TIME_LIMIT,
    }
    return f"GRB status {code}", mapping.get(code, Status.ERROR)


#: How each qpsolvers backend is driven, by qpsolvers name.
BACKENDS: dict[str, Backend] = {
    "osqp": Backend(
        settings=lambda t, it, tl: _opt(eps_abs=t, eps_rel=t, max_iter=it, time_limit=tl),
        names=_osqp_names,
        status=_osqp_status,
        iterations=_info_iter,
        floor=1e-10,
        defaults={"polishing": True, "raise_error": False},
    ),
    "proxqp": Backend(
        settings=lambda t, it, tl: _opt(eps_abs=t, eps_rel=t, max_iter=it),
        names=_proxqp_names,
        status=_proxqp_status,
        iterations=_info_iter,
        dual_start=True,
    ),
    "piqp": Backend(
        settings=lambda t, it, tl: _opt(
            eps_abs=t, eps_rel=t, eps_duality_gap_abs=t, eps_duality_gap_rel=t, max_iter=it
        ),
        names=_piqp_names,
        status=_piqp_status,
        iterations=_info_iter,
    ),
    "clarabel": Backend(
        settings=lambda t, it, tl: _opt(
            tol_gap_abs=t,
            tol_gap_rel=t,
            tol_feas=t,
            tol_ktratio=min(1e-6, t),
            max_iter=it,
            time_limit=tl,
        ),
        names=_clarabel_names,
        status=_clarabel_status,
    ),
    "daqp": Backend(
        settings=lambda t, it, tl: _opt(
            primal_tol=t, dual_tol=min(t, 1e-12), iter_limit=it, time_limit=tl
        ),
        names=_daqp_names,
        floor=None,
        dense=True,
    ),
    "highs": Backend(
        settings=lambda t, it, tl: _opt(
            primal_feasibility_tolerance=max(t, 1e-10),
            dual_feasibility_tolerance=max(t, 1e-10),
            qp_iteration_limit=it,
            time_limit=tl,
        ),
        names=_highs_names,
        floor=None,
    ),
    "quadprog": Backend(
        settings=lambda t, it, tl: {},
        names=lambda: {"factorized"},
        iterations=_quadprog_iterations,
        floor=None,
        dense=True,
    ),
    "scs": Backend(
        settings=lambda t, it, tl: _opt(eps_abs=t, eps_rel=t, max_iters=it, time_limit_secs=tl),
        names=lambda: set(_SCS_NAMES),
        status=_scs_status,
        iterations=_dict_iter("iter"),
        floor=1e-10,
    ),
    "ecos": Backend(
        settings=lambda t, it, tl: _opt(abstol=t, reltol=t, feastol=t, max_iters=it),
        names=lambda: set(_ECOS_NAMES),
        status=_ecos_status,
        iterations=_dict_iter("iter"),
        floor=1e-11,
        dense=True,
    ),
    "cvxopt": Backend(
        settings=lambda t, it, tl: _opt(abstol=t, reltol=t, feastol=t, maxiters=it),
        names=None,
        status=_cvxopt_status,
        iterations=_dict_iter("iterations"),
        floor=1e-10,
    ),
    "qpalm": Backend(
        settings=lambda t, it, tl: _opt(eps_abs=t, eps_rel=t, max_iter=it),
        names=_qpalm_names,
        status=_qpalm_status,
        iterations=_info_iter,
        floor=1e-10,
    ),
    "gurobi": Backend(
        settings=lambda t, it, tl: _opt(
            OptimalityTol=max(t, 1e-9),
            FeasibilityTol=max(t, 1e-9),
            BarConvTol=t,
            TimeLimit=tl,
        ),
        names=_gurobi_names,
        status=_gurobi_status,
        floor=1e-9,
    ),
}
#: A backend qpsolvers has and this table does not: native defaults, one solve.
GENERIC = Backend(settings=lambda t, it, tl: {}, names=None, floor=None)
