"""The registry that maps backend names to :class:`SolverInfo`.

Built-in backends are declared below as data; families (``qp:<name>`` for every
qpsolvers backend, ``cvxpy:<SOLVER>`` for every cvxpy solver) are expanded from
tables of the packages they need. Third parties add backends through the
entry-point group ``cocd.solvers``, whose objects are :class:`SolverInfo`
instances (or callables returning one).

A name may carry options after its base name, ``base:key=value[:key=value]``,
e.g. ``qp:osqp:facets=8``; they are passed to the backend.
"""

from __future__ import annotations

import ast
import functools
import warnings
from importlib.metadata import entry_points
from typing import Any

from cocd.errors import SolverNotFound
from solvers.base import SolverInfo

__all__ = [
    "ENTRY_POINT_GROUP",
    "available",
    "get",
    "register",
    "registered",
    "resolve",
    "unavailable",
]

ENTRY_POINT_GROUP = "cocd.solvers"


@functools.cache
def _mosek_licence() -> str | None:
    """``None`` if Mosek can optimise here, else why not (probed on an empty task)."""
    try:
        import mosek

        with mosek.Env() as env, env.Task() as task:
            task.optimize()
    except Exception as exc:  # any failure means unusable; say why
        return f"Mosek cannot run here: {str(exc).splitlines()[0][:160]}"
    return None


#: qpsolvers backend name -> Python module it needs.
QP_SOLVERS: dict[str, str] = {
    "clarabel": "clarabel",
    "cvxopt": "cvxopt",
    "daqp": "daqp",
    "ecos": "ecos",
    "gurobi": "gurobipy",
    "highs": "highspy",
    "mosek": "mosek",
    "osqp": "osqp",
    "piqp": "piqp",
    "proxqp": "proxsuite",
    "qpalm": "qpalm",
    "quadprog": "quadprog",
    "scs": "scs",
}
#: First-order QP methods (ADMM, splitting): limited attainable accuracy.
QP_FIRST_ORDER = {"osqp", "scs", "qpalm"}
#: qpsolvers backends that use a starting point.
QP_WARM_START = {"osqp", "proxqp", "scs", "daqp", "qpalm", "cvxopt"}

#: cvxpy solver name -> (Python module, takes second-order cones, first order).
CVXPY_SOLVERS: dict[str, tuple[str, bool, bool]] = {
    "CLARABEL": ("clarabel", True, False),
    "ECOS": ("ecos", True, False),
    "SCS": ("scs", True, True),
    "MOSEK": ("mosek", True, False),
    "CVXOPT": ("cvxopt", True, False),
    "OSQP": ("osqp", False, True),
    "PIQP": ("piqp", False, False),
    "PROXQP": ("proxsuite", False, False),
    "DAQP": ("daqp", False, False),
    "HIGHS": ("highspy", False, False),
}


def _builtin() -> list[SolverInfo]:
    infos = [
        SolverInfo(
            name="clarabel",
            entry="solvers.clarabel_:clarabel_solve_problem",
            requires=("clarabel",),
            description="Velocity-based primal (COCD) by Clarabel's interior point.",
        ),
        SolverInfo(
            name="ipm",
            entry="solvers.ipm_:ipm_solve_problem",
            requires=("qdldl",),
            description=(
                "Velocity-based primal (COCD) by cocd's interior point: Nesterov-Todd "
                "scaling, reduced SPD system on the velocities, sparse Cholesky."
            ),
            accepts=("linsolve", "threads", "polish", "correctors"),
        ),
        SolverInfo(
            name="clarabel-dual",
            entry="solvers.clarabel_:clarabel_dual_solve_problem",
            formulation="dual",
            requires=("clarabel",),
            description="Force-based dual (impulses) by Clarabel's interior point.",
        ),
        SolverInfo(
            name="scs",
            entry="solvers.scs_:scs_solve_problem",
            requires=("scs",),
            warm_start=True,
            first_order=True,
            description="Velocity-based primal by SCS (operator splitting).",
        ),
        SolverInfo(
            name="scs-dual",
            entry="solvers.scs_:scs_dual_solve_problem",
            formulation="dual",
            requires=("scs",),
            warm_start=True,
            first_order=True,
            description="Force-based dual by SCS (operator splitting).",
        ),
        SolverInfo(
            name="ecos",
            entry="solvers.ecos_:ecos_solve_problem",
            requires=("ecos",),
            description="Velocity-based primal by ECOS (interior point, epigraph objective).",
        ),
        SolverInfo(
            name="mosek",
            entry="solvers.mosek_:mosek_solve_problem",
            requires=("mosek",),
            needs_licence=True,
            probe=_mosek_licence,
            description="Velocity-based primal by Mosek's interior point (the seed paper's).",
        ),
        SolverInfo(
            name="mosek-dual",
            entry="solvers.mosek_:mosek_dual_solve_problem",
            formulation="dual",
            requires=("mosek",),
            needs_licence=True,
            probe=_mosek_licence,
            description="Force-based dual by Mosek's interior point.",
        ),
    ]
    infos += [
        SolverInfo(
            name="pgs",
            entry="solvers.pgs_:pgs_solve_problem",
            formulation="ccp",
            requires=("numba",),
            warm_start=True,
            first_order=True,
            description="Projected Gauss-Seidel on the cone complementarity problem.",
            accepts=("omega", "check_every", "polish"),
        ),
        SolverInfo(
            name="bgs",
            entry="solvers.bgs_:bgs_solve_problem",
            formulation="ccp",
            requires=("numba",),
            warm_start=True,
            first_order=True,
            description="Block Gauss-Seidel on the CCP with exact local (3 x 3) solves.",
            accepts=("order", "colour", "check_every", "polish"),
        ),
        SolverInfo(
            name="apgd",
            entry="solvers.apgd_:apgd_solve_problem",
            formulation="dual",
            requires=("numba",),
            warm_start=True,
            first_order=True,
            description="Accelerated projected gradient descent (Nesterov, restart) on the dual.",
            accepts=("check_every", "scaling", "polish"),
        ),
        SolverInfo(
            name="nscd",
            entry="solvers.nscd_:nscd_solve_problem",
            formulation="coulomb",
            convex=False,
            requires=("numba",),
            warm_start=True,
            first_order=True,
            description="Non-convex Coulomb law (NSCD): Gauss-Seidel with an exact local solver.",
            accepts=("relax", "symmetric", "check_every", "local"),
        ),
        SolverInfo(
            name="fp",
            entry="solvers.fixed_point_:fp_solve_problem",
            formulation="coulomb",
            convex=False,
            warm_start=True,
            description=(
                "Non-convex Coulomb law as a sequence of convex problems: fp:<backend> "
                "(bare fp: fp:clarabel-dual)."
            ),
            accepts=("inner", "inner_tol", "max_outer", "inner_options"),
        ),
    ]
    for qp, module in QP_SOLVERS.items():
        infos.append(
            SolverInfo(
                name=f"qp:{qp}",
                entry="solvers.qpsolvers_:qp_solve_problem",
                requires=("qpsolvers", module),
                needs_licence=qp in ("mosek", "gurobi"),
                probe=_mosek_licence if qp == "mosek" else None,
                options={"qp_solver": qp},
                linear_cones_only=True,
                first_order=qp in QP_FIRST_ORDER,
                warm_start=qp in QP_WARM_START,
                description=f"Velocity-based primal as a QP by {qp} through qpsolvers.",
            )
        )
    for solver, (module, soc, first_order) in CVXPY_SOLVERS.items():
        infos.append(
            SolverInfo(
                name=f"cvxpy:{solver}",
                entry="solvers.cvxpy_:cvxpy_solve_problem",
                requires=("cvxpy", module),
                needs_licence=solver == "MOSEK",
                probe=_mosek_licence if solver == "MOSEK" else None,
                options={"cvxpy_solver": solver},
                linear_cones_only=not soc,
                first_order=first_order,
                description=f"Velocity-based primal written in cvxpy, solved by {solver}.",
            )
        )
    return infos


_registry: dict[str, SolverInfo] = {}
_entry_points_loaded = False


def register(info: SolverInfo, *, replace: bool = False) -> None:
    """Add a backend; ``replace=True`` to overwrite one of the same name."""
    if not isinstance(info, SolverInfo):
        raise TypeError(f"register() takes a SolverInfo, got {type(info).__name__}")
    _ensure_loaded()
    if info.name in _registry and not replace:
        raise ValueError(f"a backend named {info.name!r} is already registered")
    _registry[info.name] = info


def registered() -> dict[str, SolverInfo]:
    """Every registered backend, usable or not, by name."""
    _ensure_loaded()
    return dict(_registry)


def available() -> list[str]:
    """Names of the backends usable on this machine, sorted."""
    return sorted(n for n, info in registered().items() if info.unavailable_reason() is None)


def unavailable() -> dict[str, str]:
    """Registered backends that cannot be used here, with the reason."""
    out = {}
    for name, info in registered().items():
        reason = info.unavailable_reason()
        if reason is not None:
            out[name] = reason
    return out


def get(name: str) -> SolverInfo:
    """The usable backend called ``name`` (options after the base name are ignored here).

    Raises
    ------
    SolverNotFound
        If no backend has that name, or it cannot be used here; the message
        lists the available names and, for an unusable one, why.
    """
    return resolve(name)[0]


def resolve(name: str) -> tuple[SolverInfo, dict[str, Any]]:
    """The usable backend for ``name`` and the options its name carries.

    ``"qp:osqp:facets=8"`` gives the ``qp:osqp`` backend and ``{"facets": 8}``.
    """
    if not isinstance(name, str):
        raise SolverNotFound(f"a solver name is a string, got {type(name).__name__}")
    infos = registered()
    base, options = _split(name, infos)
    info = infos.get(base)
    if info is None:
        raise SolverNotFound(f"unknown solver {name!r}; available solvers: {_names()}")
    reason = info.unavailable_reason()
    if reason is not None:
        raise SolverNotFound(
            f"solver {base!r} is registered but unavailable: {reason}; "
            f"available solvers: {_names()}"
        )
    return info, options


def _names() -> str:
    return ", ".join(available()) or "none"


def _split(name: str, infos: dict[str, SolverInfo]) -> tuple[str, dict[str, Any]]:
    """Split ``base:key=value:...`` into the longest registered base and its options.

    ``fp:<backend>`` is the fixed-point family: base ``fp``, option ``inner``.
    """
    if name.startswith("fp:") and "fp" in infos and len(name) > 3:
        return "fp", {"inner": name[3:]}
    parts = name.split(":")
    for cut in range(len(parts), 0, -1):
        base = ":".join(parts[:cut])
        rest = parts[cut:]
        if base in infos and all("=" in item for item in rest):
            options: dict[str, Any] = {}
            for item in rest:
                key, _, text = item.partition("=")
                try:
                    options[key] = ast.literal_eval(text)
                except (ValueError, SyntaxError):
                    options[key] = text
            return base, options
    return name, {}


def _ensure_loaded() -> None:
    global _entry_points_loaded
    if not _registry:
        for info in _builtin():
            _registry[info.name] = info
    if _entry_points_loaded:
        return
    _entry_points_loaded = True
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        try:
            obj = ep.load()
            info = obj() if callable(obj) and not isinstance(obj, SolverInfo) else obj
            if not isinstance(info, SolverInfo):
                raise TypeError(f"entry point gave {type(info).__name__}, not SolverInfo")
            _registry.setdefault(info.name, info)
        except Exception as exc:  # a broken plug-in must not break the registry
            warnings.warn(
                f"cocd.solvers entry point {ep.name!r} could not be loaded: {exc}",
                RuntimeWarning,
                stacklevel=2,
            )
