"""What the conic backends (clarabel, scs, ecos, mosek) share.

Each takes the form it solves as ``form``: ``"primal"`` (the velocity-based
primal, :meth:`cocd.problem.ConicProblem.primal_conic_form`) or ``"dual"``
(the force-based dual, :meth:`cocd.problem.ConicProblem.dual_conic_form`);
the registry's ``<name>-dual`` entries pass ``form="dual"``. Here: the form
itself and the start of a solve, how impulses and velocities are read from a native answer, the
refusal of a native setting, and the run to the framework's target.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from cocd.errors import ProblemError
from cocd.problem import PrimalConicForm
from solvers.refine import FIRST_TOL_FACTOR, SMALLEST_NATIVE_TOL, Attempt, solve_to_target

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

    from cocd.problem import ConicProblem, DualConicForm
    from solvers.base import Request, Solution

__all__ = [
    "FORMS",
    "answer",
    "check_setting",
    "conic_form",
    "no_free_setting",
    "prepare",
    "to_target",
]

FORMS = ("primal", "dual")


def conic_form(problem: ConicProblem, form: str) -> PrimalConicForm | DualConicForm:
    """The ``form`` (``"primal"`` or ``"dual"``) of ``problem``."""
    if form == "primal":
        return problem.primal_conic_form()
    if form == "dual":
        return problem.dual_conic_form()
    raise ProblemError(f"form must be one of {', '.join(FORMS)}, got {form!r}")


def prepare(
    problem: ConicProblem, form: str, options: dict[str, Any]
) -> tuple[float, PrimalConicForm | DualConicForm, bool]:
    """The start of a conic backend's solve: its start time (``time.perf_counter()``),
    the ``form`` of ``problem`` and whether to polish (the option ``polish``, default
    True, taken out of ``options``)."""
    start = time.perf_counter()
    return start, conic_form(problem, form), bool(options.pop("polish", True))


def answer(
    form: PrimalConicForm | DualConicForm,
    x: NDArray[np.float64],
    z: NDArray[np.float64] | None,
) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
    """Impulses and velocity (``None``: it follows from them) of a native answer.

    The primal's impulses are the duals ``z`` of its contact rows and its velocity
    the primal ``x``; the dual's impulses are its primal ``x``.
    """
    if isinstance(form, PrimalConicForm):
        assert z is not None
        return form.impulses(z), form.velocity(x)
    return form.impulses(x), None


def no_free_setting(name: str, key: str, follows: str, settings: str) -> ProblemError:
    """The error for a setting ``key`` that ``name`` does not leave to the user."""
    return ProblemError(f"{name} has no free setting {key!r} ({follows}); {settings}")


def check_setting(name: str, key: str, value: Any, kind: type) -> None:
    """A one-line :class:`ProblemError` unless ``value`` is a ``kind`` (``bool``,
    ``int``, ``float``, where an int will do, or ``str``) for ``name``'s setting ``key``."""
    if kind is bool:
        ok = isinstance(value, (bool, np.bool_))
    elif kind in (int, float):
        whole = isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))
        ok = whole or (kind is float and isinstance(value, (float, np.floating)))
    else:
        ok = isinstance(value, kind)
    if not ok:
        what = {bool: "True or False", int: "an integer", float: "a number"}.get(kind, "a word")
        raise ProblemError(f"{name}: setting {key} must be {what}, got {value!r}")


def to_target(
    problem: ConicProblem,
    form: str,
    request: Request,
    attempt: Callable[[float, float | None], Attempt],
    *,
    base: str,
    start: float,
    polish: bool,
    first_factor: float = FIRST_TOL_FACTOR,
    floor: float = SMALLEST_NATIVE_TOL,
) -> Solution:
    """:func:`solvers.refine.solve_to_target` for backend ``base`` on ``form``; set-up is
    everything since ``start``. The solver is named ``base`` or ``base-dual``."""
    return solve_to_target(
        problem,
        request,
        attempt,
        solver=base if form == "primal" else f"{base}-{form}",
        setup_time=time.perf_counter() - start,
        polish=polish,
        first_factor=first_factor,
        floor=floor,
    )
