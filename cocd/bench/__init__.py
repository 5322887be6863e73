"""The benchmark harness behind ``cocd bench``: Table 1, stability, speed against error, hard cases.

Every command compares backends on the same step problems, with the same error
measure (:mod:`cocd.residuals`) and the same clock (:mod:`cocd.bench.runner`),
and writes its tables and plots with their provenance
(:mod:`cocd.bench.report`).
"""

from __future__ import annotations

import solvers
from cocd.errors import SolverNotFound

__all__ = ["DEFAULT_SOLVERS", "select_solvers", "solver_names"]

#: Backends a harness command runs when none are named: the conic interior
#: points, both SCS formulations, the iterative methods and the non-convex
#: NSCD reference, plus the structure-exploiting interior point when present.
DEFAULT_SOLVERS = [
    "ipm",
    "clarabel",
    "clarabel-dual",
    "mosek",
    "scs",
    "scs-dual",
    "qp:piqp",
    "apgd",
    "pgs",
    "nscd",
]


def solver_names(names: str | list[str] | tuple[str, ...] | None) -> list[str]:
    """Backend names from a comma-separated string or a list (empty for None); an unknown
    name raises :class:`SolverNotFound`, listing the known ones."""
    if not names:
        return []
    chosen = names.split(",") if isinstance(names, str) else list(names)
    chosen = [n.strip() for n in chosen if n.strip()]
    if not chosen:
        raise SolverNotFound(
            f"no solver is named in {names!r}; available solvers: {', '.join(solvers.available())}"
        )
    for name in chosen:
        solvers.resolve(name)
    return chosen


def select_solvers(names: str | list[str] | None, dim: int) -> list[str]:
    """Backends to run on ``dim``-dimensional problems.

    Named backends must exist (an unknown name raises :class:`SolverNotFound`,
    listing the known ones); those that cannot handle ``dim`` (or need linear
    cones on a 3D frictional problem) are left out. With no names, the
    available ones of :data:`DEFAULT_SOLVERS`.
    """
    chosen = solver_names(names)
    if not chosen:  # named ones are usable here, else solver_names raised
        chosen = [n for n in DEFAULT_SOLVERS if n in set(solvers.available())]
    out = []
    for name in chosen:
        info, options = solvers.resolve(name)
        if dim not in info.dims:
            continue
        if info.linear_cones_only and dim == 3 and "facets" not in options:
            continue
        out.append(name)
    return out
