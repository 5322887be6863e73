"""Checks of user input: scenes, contact detection, measurements, builders, scene files.

Each raises :class:`~cocd.errors.SceneError` with a one-line message naming the
input (validation against the papers is another thing: :mod:`cocd.validate`).

- :func:`checked` wraps a function so that arguments of the wrong type (a string
  for a size, ``None`` for an angle, ``3.5`` for a count) are refused, by their
  type annotations, before the function runs; the function then checks the
  values (ranges, signs).
- The others turn a value into an array or a number of the expected kind.
"""

from __future__ import annotations

import functools
import inspect
import typing
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np
import pydantic
from numpy.typing import ArrayLike, NDArray
from pydantic import ConfigDict

from cocd.errors import SceneError

__all__ = [
    "argument_checker",
    "bin_edges",
    "bool_mask",
    "broadcast_array",
    "checked",
    "finite_array",
    "finite_nonnegative",
    "finite_positive",
    "finite_scalar",
    "first_repeat",
    "float_array",
    "friction_coefficient",
    "nonnegative_number",
    "positive_number",
    "require_finite",
    "shaped_array",
]

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


def first_repeat(values: list[Any], key: Callable[[Any], Any] = lambda v: v) -> int | None:
    """The index of the first of ``values`` whose ``key`` an earlier one has, else None:
    a list that would run one case twice."""
    seen: list[Any] = []
    for k, value in enumerate(values):
        if key(value) in seen:
            return k
        seen.append(key(value))
    return None


def float_array(value: object, name: str) -> FloatArray:
    """``value`` as a float array, or an error saying ``name`` must be numeric."""
    try:
        return np.array(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError) as exc:
        raise SceneError(f"{name} must be numeric: {exc}") from None


def require_finite(a: FloatArray, name: str) -> None:
    """Raise naming the first non-finite entry of ``a``."""
    bad = ~np.isfinite(a)
    if bad.any():
        where = tuple(int(k) for k in np.argwhere(bad)[0])
        subject = f"{name}[{', '.join(map(str, where))}]" if a.ndim else name
        raise SceneError(f"{subject} is {a[where]}: {name} must be finite")


def finite_scalar(value: object, name: str) -> float:
    """``value`` as one finite number."""
    a = float_array(value, name)
    if a.ndim != 0:
        raise SceneError(f"{name} must be a number, got shape {a.shape}")
    require_finite(a, name)
    return float(a)


def finite_positive(value: object, name: str) -> float:
    """``value`` as one finite number > 0."""
    x = finite_scalar(value, name)
    if x <= 0.0:
        raise SceneError(f"{name} must be > 0, got {x:g}")
    return x


def finite_nonnegative(value: object, name: str) -> float:
    """``value`` as one finite number >= 0."""
    x = finite_scalar(value, name)
    if x < 0.0:
        raise SceneError(f"{name} must be >= 0, got {x:g}")
    return x


def positive_number(value: object, name: str) -> float:
    """``value`` as a float, finite and > 0."""
    try:
        x = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise SceneError(f"{name} must be a number, got {value!r}") from None
    if not (np.isfinite(x) and x > 0.0):
        raise SceneError(f"{name} must be finite and > 0, got {value}")
    return x


def nonnegative_number(value: float, name: str) -> None:
    """Raise unless the number ``value`` is finite and >= 0."""
    if not (np.isfinite(value) and value >= 0.0):
        raise SceneError(f"{name} must be finite and >= 0, got {value}")


def friction_coefficient(value: object, name: str) -> float:
    """``value`` as a friction coefficient: a finite number >= 0."""
    try:
        mu = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise SceneError(f"{name} must be a number, got {value!r}") from None
    if not np.isfinite(mu) or mu < 0.0:
        raise SceneError(f"friction coefficient {name} must be finite and >= 0, got {mu}")
    return mu


def finite_array(value: object, name: str) -> FloatArray:
    """``value`` as a finite number or 1-D series."""
    a = float_array(value, name)
    if a.ndim > 1:
        raise SceneError(f"{name} must be a number or a 1-D series, got shape {a.shape}")
    require_finite(a, name)
    return a


def broadcast_array(value: object, n: int, name: str) -> FloatArray:
    """``value`` as a float array of shape ``(n,)``; one number is repeated."""
    a = float_array(value, name)
    if a.ndim == 0:
        return np.full(n, float(a))
    if a.shape != (n,):
        raise SceneError(f"{name} must be a number or have shape ({n},), got {a.shape}")
    return a


def shaped_array(value: object, shape: tuple[int, ...], name: str) -> FloatArray:
    """``value`` as a finite float array of the given shape."""
    a = float_array(value, name)
    if a.shape != shape:
        raise SceneError(f"{name} must have shape {shape}, got {a.shape}")
    require_finite(a, name)
    return a


def bool_mask(value: ArrayLike, n: int, name: str) -> BoolArray:
    """A copy of ``value``, a boolean array of shape ``(n,)``."""
    m = np.asarray(value)
    if m.shape != (n,) or m.dtype != bool:
        raise SceneError(f"{name} must be a boolean array of shape ({n},), got {m.dtype} {m.shape}")
    return m.copy()


def bin_edges(value: ArrayLike, name: str) -> FloatArray:
    """Bin edges: a strictly increasing 1-D array of at least 2 finite numbers."""
    e = float_array(value, name)
    if e.ndim != 1 or e.size < 2:
        raise SceneError(f"{name} must be a 1-D array of at least 2 edges, got shape {e.shape}")
    require_finite(e, name)
    if np.any(np.diff(e) <= 0.0):
        raise SceneError(f"{name} must be strictly increasing")
    return e


F = TypeVar("F", bound=Callable[..., Any])


def argument_checker(func: Callable[..., Any]) -> Callable[..., None]:
    """A function with ``func``'s signature that only validates the argument types
    (pydantic, lax mode) and raises ``pydantic.ValidationError``."""
    signature = inspect.signature(func)
    hints = typing.get_type_hints(func)

    def check(*args: Any, **kwargs: Any) -> None:
        return None

    params = [
        p.replace(annotation=hints.get(name, Any)) for name, p in signature.parameters.items()
    ]
    check.__signature__ = signature.replace(  # type: ignore[attr-defined]
        parameters=params, return_annotation=None
    )
    check.__annotations__ = {p.name: p.annotation for p in params}
    check.__name__ = func.__name__
    return pydantic.validate_call(config=ConfigDict(arbitrary_types_allowed=True))(check)


def checked(func: F) -> F:
    """``func`` with its arguments' types checked first (see the module)."""
    checker: list[Callable[..., None]] = []

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        if not checker:  # built on first use: annotations resolve once the module is loaded
            checker.append(argument_checker(func))
        try:
            checker[0](*args, **kwargs)
        except pydantic.ValidationError as exc:
            first = exc.errors()[0]
            names = list(inspect.signature(func).parameters)
            loc = list(first["loc"])
            if loc and isinstance(loc[0], int) and loc[0] < len(names):
                loc[0] = names[loc[0]]  # a positional argument: its name
            where = ".".join(str(part) for part in loc if not isinstance(part, int))
            message = str(first["msg"]).removeprefix("Value error, ")
            raise SceneError(f"{func.__name__}: {where or 'arguments'}: {message}") from None
        return func(*args, **kwargs)

    return typing.cast(F, wrapper)
