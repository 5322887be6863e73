"""What every backend is asked, returns and declares.

A backend is a function ``solve(problem, request, **options) -> Solution``, with
``request`` a :class:`Request`, plus a :class:`SolverInfo` that states its
capabilities as data.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import importlib.util
import inspect
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from cocd.problem import ConicProblem

__all__ = ["Request", "Solution", "SolveFunction", "SolverInfo", "Status", "installed"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


class Status(str, Enum):
    """The shared status vocabulary every native status is mapped onto."""

    OPTIMAL = "optimal"
    INACCURATE = "inaccurate"
    MAX_ITER = "max_iter"
    TIME_LIMIT = "time_limit"
    INFEASIBLE = "infeasible"
    ERROR = "error"

    def __str__(self) -> str:
        return self.value


@dataclass(frozen=True)
class Request:
    """What a solve asks of any backend besides the problem and the backend's own options.

    :func:`solvers.solve` builds it from its arguments (options written in the
    solver's name included) after checking them; each backend's module has the
    table of how these map onto its native settings.

    Attributes
    ----------
    tol : float
        Target accuracy, finite and ``> 0``: an answer is ``optimal`` when the
        framework's ``ccp_residual <= tol`` (``coulomb_residual`` for a backend of
        the non-convex law, :mod:`cocd.residuals`).
    warm_start : (nc, m) array or None
        Impulses to start from, one row per contact in the problem's order,
        normal first. :func:`solvers.solve` gives one only to a backend declared
        ``SolverInfo.warm_start`` (it warns and drops it for the others) and
        reshapes it to ``(nc, m)``.
    max_iter : int or None
        Cap on the backend's iterations (what one is: its table), ``>= 1``;
        ``None`` for the backend's default.
    time_limit : float or None
        Wall-clock seconds, ``> 0``; ``None`` for no limit.
    verbose : bool
        Let the backend print its log.
    """

    tol: float = 1e-8
    warm_start: FloatArray | None = None
    max_iter: int | None = None
    time_limit: float | None = None
    verbose: bool = False


@dataclass
class Solution:
    """A backend's answer to one :class:`~cocd.problem.ConicProblem`.

    Attributes
    ----------
    u : (ndof,) array
        Generalized velocity at the end of the step, as the backend computed it.
    p : (nc, m) array
        Contact impulses, normal first.
    status : Status
    iterations : int
    setup_time, solve_time : float
        Seconds spent building the backend's data and solving.
    solver : str
        Registry name of the backend.
    extras : dict
        Native information: status string, objective, native residuals.
    """

    u: FloatArray
    p: FloatArray
    status: Status
    iterations: int
    setup_time: float
    solve_time: float
    solver: str
    extras: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def from_impulses(
        cls,
        problem: ConicProblem,
        p: FloatArray,
        status: Status,
        iterations: int,
        times: tuple[float, float],
        solver: str,
        native: str,
        /,
        **extras: Any,
    ) -> Solution:
        """The answer of a method that finds the impulses ``p``: ``u = problem.velocity(p)``;
        ``times`` are the set-up and solve times, ``extras`` follow the native status."""
        return cls(
            u=problem.velocity(p),
            p=p,
            status=status,
            iterations=iterations,
            setup_time=times[0],
            solve_time=times[1],
            solver=solver,
            extras={"native_status": native, **extras},
        )

    @classmethod
    def free_flight(cls, problem: ConicProblem, solver: str, setup_time: float = 0.0) -> Solution:
        """The answer without contacts: the free velocity, nothing to solve."""
        return cls(
            u=problem.U.copy(),
            p=np.zeros((0, problem.contact_dim)),
            status=Status.OPTIMAL,
            iterations=0,
            setup_time=setup_time,
            solve_time=0.0,
            solver=solver,
        )

    @property
    def found(self) -> bool:
        """True when the backend claims an answer (optimal or inaccurate)."""
        return self.status in (Status.OPTIMAL, Status.INACCURATE)


class SolveFunction(Protocol):
    def __call__(self, problem: ConicProblem, request: Request, /, **options: Any) -> Solution: ...


@dataclass(frozen=True)
class SolverInfo:
    """A backend's name, capabilities and where its code lives.

    Attributes
    ----------
    name : str
        Registry name.
    entry : str
        ``"module:function"`` of the solve function; imported on first use.
    dims : tuple of int
        Space dimensions accepted.
    formulation : str
        ``"primal"`` (velocity-based COCD), ``"dual"`` (force-based) or ``"ccp"``.
    convex : bool
        False for solvers of the non-convex Coulomb law.
    warm_start : bool
        Whether impulses from the previous step are used.
    needs_licence : bool
    requires : tuple of str
        Python modules that must be importable.
    description : str
    probe : callable, optional
        Returns ``None`` when usable, else the reason it is not (e.g. no licence).
    options : dict
        Fixed keyword arguments given to the solve function (e.g. which
        qpsolvers backend a ``qp:<name>`` entry drives).
    linear_cones_only : bool
        The backend takes only linear cones (a QP): 2D and frictionless
        problems, or 3D friction through a faceted cone (option ``facets``).
    first_order : bool
        A first-order method: its attainable accuracy is limited.
    accepts : tuple of str, optional
        The options the backend takes besides ``options``; :func:`solvers.solve`
        rejects any other with a message naming them. ``None`` for a backend that
        hands its options on to a library that checks them (its native settings).
    local_entry : str, optional
        ``"module:function"`` of the backend's local form, which solves a local
        problem ``u = W r + q`` on ``W`` itself, symmetric or not
        (:func:`solvers.local.solve_local`); ``None`` for a backend that solves
        only the ConicProblem (of a factor ``H H' = W``, so a symmetric ``W``).
    """

    name: str
    entry: str
    dims: tuple[int, ...] = (2, 3)
    formulation: str = "primal"
    convex: bool = True
    warm_start: bool = False
    needs_licence: bool = False
    requires: tuple[str, ...] = ()
    description: str = ""
    probe: Callable[[], str | None] | None = None
    options: dict[str, Any] = field(default_factory=dict)
    linear_cones_only: bool = False
    first_order: bool = False
    accepts: tuple[str, ...] | None = None
    local_entry: str | None = None

    def unavailable_reason(self) -> str | None:
        """Why the backend cannot be used here, or ``None`` if it can."""
        for module in self.requires:
            if not installed(module):
                return f"Python package '{module}' is not installed"
        if self.probe is not None:
            return self.probe()
        return None

    def load(self) -> SolveFunction:
        """The solve function of :attr:`entry`.

        A function of the earlier keyword form, ``solve(problem, *, tol, warm_start,
        max_iter, time_limit, verbose, **options)`` (one that takes a single
        positional argument), is given the request's fields as keywords.
        """
        solve: SolveFunction = entry_function(self.entry)
        if _takes_request(solve):  # type: ignore[arg-type]  # functions are hashable
            return solve
        keywords: SolveFunction = functools.partial(_by_keywords, solve)
        return keywords


def entry_function(entry: str) -> Any:
    """The function an ``"module:function"`` entry names (the module imported on first use)."""
    module, _, function = entry.partition(":")
    return getattr(importlib.import_module(module), function)


@functools.lru_cache(maxsize=256)
def _takes_request(solve: Callable[..., Solution]) -> bool:
    """Whether ``solve`` takes the request as its second positional argument (read once
    per function: a solve of a small problem should not pay for ``inspect``)."""
    try:
        parameters = inspect.signature(solve).parameters.values()
    except (TypeError, ValueError):  # no signature to read: assume the current form
        return True
    positional = (inspect.Parameter.POSITIONAL_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)
    if any(p.kind is inspect.Parameter.VAR_POSITIONAL for p in parameters):
        return True
    return sum(p.kind in positional for p in parameters) >= 2


def _by_keywords(
    solve: Callable[..., Solution], problem: ConicProblem, request: Request, /, **options: Any
) -> Solution:
    """Call a solve function of the keyword form with the fields of ``request``."""
    fields = {f.name: getattr(request, f.name) for f in dataclasses.fields(request)}
    return solve(problem, **fields, **options)


@functools.cache
def installed(module: str) -> bool:
    """Whether ``module`` can be imported, found without importing it."""
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        return False
