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
import math
import warnings
from importlib.metadata import entry_points
from typing import Any

import numpy as np

from cocd.errors import ProblemError, SolverNotFound
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


#: Solver package (qpsolvers' name; cvxpy's is its upper case) -> (Python module it
#: needs, first order). First-order methods (ADMM, splitting) have a limited attainable
#: accuracy.
PACKAGES: dict[str, tuple[str, bool]] = {
    "clarabel": ("clarabel", False),
    "cvxopt": ("cvxopt", False),
    "daqp": ("daqp", False),
    "ecos": ("ecos", False),
    "gurobi": ("gurobipy", False),
    "highs": ("highspy", False),
    "mosek": ("mosek", False),
    "osqp": ("osqp", True),
    "piqp": ("piqp", False),
    "proxqp": ("proxsuite", False),
    "qpalm": ("qpalm", True),
    "quadprog": ("quadprog", False),
    "scs": ("scs", True),
}
#: The qpsolvers backends that take a starting point (the one qpsolvers passes on,
#: :mod:`solvers.qpsolvers_`).
_QP_STARTS = {"cvxopt", "daqp", "osqp", "proxqp", "qpalm", "scs"}
#: The packages cvxpy drives here, in order, and those of them given second-order cones.
_CVXPY = ("clarabel", "ecos", "scs", "mosek", "cvxopt", "osqp", "piqp", "proxqp", "daqp", "highs")
_CVXPY_SOC = {"clarabel", "ecos", "scs", "mosek", "cvxopt"}

#: qpsolvers backend name -> (Python module it needs, first order, takes a starting point).
QP_SOLVERS: dict[str, tuple[str, bool, bool]] = {
    name: (module, first_order, name in _QP_STARTS)
    for name, (module, first_order) in PACKAGES.items()
}
#: cvxpy solver name -> (Python module, takes second-order cones, first order).
CVXPY_SOLVERS: dict[str, tuple[str, bool, bool]] = {
    name.upper(): (PACKAGES[name][0], name in _CVXPY_SOC, PACKAGES[name][1]) for name in _CVXPY
}

#: What cocd's iterative methods share: numba kernels, a warm start, first order.
_ITERATIVE: dict[str, Any] = {"requires": ("numba",), "warm_start": True, "first_order": True}
_LICENSED: dict[str, Any] = {"needs_licence": True, "probe": _mosek_licence}


def _conic(package: str, form: str, description: str, **facts: Any) -> SolverInfo:
    """A package's conic backend on ``form``: one solve function per package, given
    ``form="dual"`` by the ``<package>-dual`` entry."""
    return SolverInfo(
        name=package if form == "primal" else f"{package}-{form}",
        entry=f"solvers.{package}_:{package}_solve_problem",
        formulation=form,
        requires=(package,),
        options={} if form == "primal" else {"form": form},
        description=description,
        **facts,
    )


def _own(
    name: str, formulation: str, description: str, module: str = "", **facts: Any
) -> SolverInfo:
    """One of cocd's own methods, ``solvers.<module>_:<name>_solve_problem``."""
    return SolverInfo(
        name=name,
        entry=f"solvers.{module or name}_:{name}_solve_problem",
        formulation=formulation,
        description=description,
        **facts,
    )


def _family(name: str, entry: str, modules: tuple[str, ...], **facts: Any) -> SolverInfo:
    """One member of the ``qp:<name>`` or ``cvxpy:<SOLVER>`` family; ``modules[-1]`` is
    the package that solves."""
    return SolverInfo(
        name=name,
        entry=entry,
        requires=modules,
        needs_licence=modules[-1] in ("mosek", "gurobipy"),
        probe=_mosek_licence if modules[-1] == "mosek" else None,
        **facts,
    )


def _builtin() -> list[SolverInfo]:
    infos = [
        _conic("clarabel", "primal", "Velocity-based primal (COCD) by Clarabel's interior point."),
        _own(
            "ipm",
            "primal",
            "Velocity-based primal (COCD) by cocd's interior point: Nesterov-Todd "
            "scaling, reduced SPD system on the velocities, sparse Cholesky.",
            requires=("qdldl",),
            accepts=("linsolve", "threads", "polish", "correctors"),
        ),
        _conic("clarabel", "dual", "Force-based dual (impulses) by Clarabel's interior point."),
        _conic(
            "scs",
            "primal",
            "Velocity-based primal by SCS (operator splitting).",
            warm_start=True,
            first_order=True,
        ),
        _conic(
            "scs",
            "dual",
            "Force-based dual by SCS (operator splitting).",
            warm_start=True,
            first_order=True,
        ),
        _conic(
            "ecos", "primal", "Velocity-based primal by ECOS (interior point, epigraph objective)."
        ),
        _conic(
            "mosek",
            "primal",
            "Velocity-based primal by Mosek's interior point (the seed paper's).",
            **_LICENSED,
        ),
        _conic("mosek", "dual", "Force-based dual by Mosek's interior point.", **_LICENSED),
        _own(
            "pgs",
            "ccp",
            "Projected Gauss-Seidel on the cone complementarity problem.",
            accepts=("omega", "check_every", "polish"),
            local_entry="solvers.local:pgs_local",
            **_ITERATIVE,
        ),
        _own(
            "bgs",
            "ccp",
            "Block Gauss-Seidel on the CCP with exact local (3 x 3) solves.",
            accepts=("order", "colour", "check_every", "polish"),
            **_ITERATIVE,
        ),
        _own(
            "apgd",
            "dual",
            "Accelerated projected gradient descent (Nesterov, restart) on the dual.",
            accepts=("check_every", "scaling", "operator", "polish"),
            **_ITERATIVE,
        ),
        _own(
            "nscd",
            "coulomb",
            "Non-convex Coulomb law (NSCD): Gauss-Seidel with an exact local solver.",
            convex=False,
            accepts=("relax", "symmetric", "check_every", "local", "newton"),
            local_entry="solvers.local:nscd_local",
            **_ITERATIVE,
        ),
        _own(
            "fp",
            "coulomb",
            "Non-convex Coulomb law as a sequence of convex problems: fp:<backend> "
            "(bare fp: fp:clarabel-dual).",
            module="fixed_point",
            convex=False,
            warm_start=True,
            accepts=("inner", "inner_tol", "max_outer", "inner_options"),
        ),
    ]
    infos += [
        _family(
            f"qp:{qp}",
            "solvers.qpsolvers_:qp_solve_problem",
            ("qpsolvers", module),
            options={"qp_solver": qp},
            linear_cones_only=True,
            first_order=first_order,
            warm_start=warm_start,
            description=f"Velocity-based primal as a QP by {qp} through qpsolvers.",
        )
        for qp, (module, first_order, warm_start) in QP_SOLVERS.items()
    ]
    infos += [
        _family(
            f"cvxpy:{solver}",
            "solvers.cvxpy_:cvxpy_solve_problem",
            ("cvxpy", module),
            options={"cvxpy_solver": solver},
            linear_cones_only=not soc,
            first_order=first_order,
            description=f"Velocity-based primal written in cvxpy, solved by {solver}.",
        )
        for solver, (module, soc, first_order) in CVXPY_SOLVERS.items()
    ]
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
                if text.lower() in ("true", "false"):  # as TOML and the shell write them
                    options[key] = text.lower() == "true"
                    continue
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


#: The request's fields that a solver name may carry (``"pgs:max_iter=3"``).
REQUEST_FIELDS = ("tol", "max_iter", "time_limit", "verbose")

#: Options that are True or False for every backend that takes them.
FLAGS = ("verbose", "polish", "symmetric", "newton")


def requested(
    solver: str, request: dict[str, Any], options: dict[str, Any], *extra: str
) -> tuple[SolverInfo, dict[str, Any], dict[str, Any]]:
    """The backend for ``solver``, the request and the options it is given.

    Options written in the name win over ``request`` (the fields of
    :data:`REQUEST_FIELDS` and the names in ``extra``) and over ``options``; an
    option the backend does not take, or a warm start in the name, is a one-line
    :class:`~cocd.errors.ProblemError`.
    """
    info, name_options = resolve(solver)
    if "warm_start" in name_options:
        raise ProblemError(f"solver {solver!r}: a warm start cannot be given in a solver name")
    request = dict(request)
    for key in (*REQUEST_FIELDS, *extra):
        if key in name_options:
            request[key] = name_options.pop(key)
    merged = {**info.options, **options, **name_options}
    if info.accepts is not None:
        unknown = sorted(set(merged) - set(info.options) - set(info.accepts))
        if unknown:
            raise ProblemError(
                f"{info.name} has no option {unknown[0]!r}; its options are "
                f"{', '.join(info.accepts) or 'none'}"
            )
    for key, value in (*request.items(), *merged.items()):
        if key in FLAGS and not isinstance(value, (bool, np.bool_)):
            raise ProblemError(f"{info.name}: {key} must be True or False, got {value!r}")
    request["verbose"] = bool(request.get("verbose", False))
    _check_request(request)
    return info, request, merged


def _check_request(request: dict[str, Any]) -> None:
    """``tol`` a finite number > 0 (made a float), ``max_iter`` an integer >= 1 and
    ``time_limit`` seconds > 0, when given; else a one-line ProblemError."""
    if "tol" in request:
        tol = request["tol"]
        try:
            request["tol"] = float(tol)
        except (TypeError, ValueError):
            raise ProblemError(f"tol must be a finite number > 0, got {tol!r}") from None
        if not (math.isfinite(request["tol"]) and request["tol"] > 0):
            raise ProblemError(f"tol must be a finite number > 0, got {tol!r}")
    max_iter = request.get("max_iter")
    if max_iter is not None and (
        isinstance(max_iter, bool) or not isinstance(max_iter, int) or max_iter < 1
    ):
        raise ProblemError(f"max_iter must be a positive integer, got {max_iter!r}")
    limit = request.get("time_limit")
    if limit is not None and not (
        isinstance(limit, (int, float)) and math.isfinite(limit) and limit > 0
    ):
        raise ProblemError(f"time_limit must be > 0 seconds, got {limit!r}")
