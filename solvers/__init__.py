"""Interchangeable backends for the step problem, registered by name.

>>> import solvers
>>> solvers.available()                      # doctest: +SKIP
['clarabel']
>>> sol = solvers.solve(problem, solver="clarabel", tol=1e-8)  # doctest: +SKIP
"""

from __future__ import annotations

import time
import warnings
from typing import TYPE_CHECKING, Any

import numpy as np

from cocd.errors import CocdError, ProblemError, SolverError, SolverNotFound
from solvers.base import Request, Solution, SolverInfo, Status
from solvers.registry import (
    REQUEST_FIELDS,
    available,
    get,
    register,
    registered,
    requested,
    resolve,
    unavailable,
)

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from cocd.problem import ConicProblem

__all__ = [
    "Request",
    "Solution",
    "SolverInfo",
    "SolverNotFound",
    "Status",
    "available",
    "get",
    "register",
    "registered",
    "resolve",
    "solve",
    "unavailable",
]


#: A ``delassus_shift`` below this fraction of the mean diagonal of ``W`` is
#: rounding (a singular ``W`` made factorable), not an approximation.
SHIFT_NEGLIGIBLE = 1e-11


def solve(
    problem: ConicProblem,
    solver: str = "clarabel",
    tol: float = 1e-8,
    warm_start: ArrayLike | None = None,
    max_iter: int | None = None,
    time_limit: float | None = None,
    verbose: bool = False,
    **options: Any,
) -> Solution:
    """Solve one step problem with the backend called ``solver``.

    Parameters
    ----------
    problem : ConicProblem
    solver : str
        A name from :func:`available`.
    tol, warm_start, max_iter, time_limit, verbose
        The :class:`~solvers.base.Request` given to the backend (its fields say
        what each means); a warm start may also have the shape ``(nc * m,)``.
    **options
        Passed to the backend.

    Options written in the name (``"pgs:max_iter=3"``, see :func:`resolve`)
    win over the same options given as arguments, ``tol``, ``max_iter``,
    ``time_limit`` and ``verbose`` included: the name is the most specific
    statement of what is wanted.

    Returns
    -------
    Solution
    """
    info, asked, options = requested(
        solver, dict(tol=tol, max_iter=max_iter, time_limit=time_limit, verbose=verbose), options
    )
    tol, max_iter, time_limit, verbose = (asked[k] for k in REQUEST_FIELDS)
    if info.linear_cones_only and not problem.is_qp and "facets" not in options:
        raise ProblemError(
            f"solver {solver!r} takes linear cones only, and this 3D frictional problem has "
            f"second-order cones: use '{info.name}:facets=8' for a faceted approximation"
        )
    if problem.dim not in info.dims:
        raise ProblemError(
            f"solver {solver!r} handles dimensions {info.dims}, not a {problem.dim}D problem"
        )
    p0 = None
    if warm_start is not None:
        if not info.warm_start:
            warnings.warn(
                f"solver {solver!r} does not use a warm start; it is ignored",
                UserWarning,
                stacklevel=2,
            )
        else:
            p0 = np.asarray(warm_start, dtype=np.float64)
            if p0.size != problem.nc * problem.contact_dim:
                raise ProblemError(
                    f"warm_start has {p0.size} entries, expected "
                    f"{(problem.nc, problem.contact_dim)}"
                )
            p0 = p0.reshape(problem.nc, problem.contact_dim)

    if problem.nc == 0:
        # Free flight: nothing to solve, every backend would agree.
        return Solution.free_flight(problem, solver)

    fn = info.load()
    request = Request(tol, p0, max_iter, time_limit, verbose)
    start = time.perf_counter()
    try:
        solution = fn(problem, request, **options)
    except (CocdError, TypeError):
        raise
    except Exception as exc:
        raise SolverError(
            f"solver {solver!r} failed after {time.perf_counter() - start:.3g} s on a problem "
            f"with {problem.nc} contacts: {type(exc).__name__}: {exc}"
        ) from exc
    solution.solver = solver
    if problem.delassus_shift > SHIFT_NEGLIGIBLE / float(np.mean(problem.rho)) and (
        info.formulation == "primal"
    ):
        # The primal is built on H and M: it answers W + delassus_shift I, not W.
        shifted = f"W + {problem.delassus_shift:.3g} I (primal form of the shifted problem)"
        previous = solution.extras.get("approximation")
        solution.extras["approximation"] = f"{previous}; {shifted}" if previous else shifted
    solution.p = np.asarray(solution.p, dtype=np.float64).reshape(problem.nc, problem.contact_dim)
    solution.u = np.asarray(solution.u, dtype=np.float64).reshape(problem.ndof)
    return solution
