"""The registry that maps backend names to :class:`SolverInfo`.

Built-in backends are declared below; third parties add theirs through the
entry-point group ``cocd.solvers``, whose objects are :class:`SolverInfo`
instances (or callables returning one).
"""

from __future__ import annotations

import warnings
from importlib.metadata import entry_points

from cocd.errors import SolverNotFound
from solvers.base import SolverInfo

__all__ = ["ENTRY_POINT_GROUP", "available", "get", "register", "registered", "unavailable"]

ENTRY_POINT_GROUP = "cocd.solvers"

_BUILTIN: tuple[SolverInfo, ...] = (
    SolverInfo(
        name="clarabel",
        entry="solvers.clarabel_:clarabel_solve_problem",
        dims=(2, 3),
        formulation="primal",
        convex=True,
        warm_start=False,
        requires=("clarabel",),
        description="Velocity-based primal (COCD) by Clarabel's interior point.",
    ),
)

_registry: dict[str, SolverInfo] = {}
_entry_points_loaded = False


def register(info: SolverInfo, *, replace: bool = False) -> None:
    """Add a backend; ``replace=True`` to overwrite one of the same name."""
    if not isinstance(info, SolverInfo):
        raise TypeError(f"register() takes a SolverInfo, got {type(info).__name__}")
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
    """The usable backend called ``name``.

    Raises
    ------
    SolverNotFound
        If no backend has that name, or it cannot be used here; the message
        lists the available names and, for an unusable one, why.
    """
    infos = registered()
    info = infos.get(name)
    names = ", ".join(available()) or "none"
    if info is None:
        raise SolverNotFound(f"unknown solver {name!r}; available solvers: {names}")
    reason = info.unavailable_reason()
    if reason is not None:
        raise SolverNotFound(
            f"solver {name!r} is registered but unavailable: {reason}; available solvers: {names}"
        )
    return info


def _ensure_loaded() -> None:
    global _entry_points_loaded
    if not _registry:
        for info in _BUILTIN:
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
