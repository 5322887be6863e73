"""Argument checks by type annotation, shared by the builders and the scene files.

:func:`checked` wraps a function so that arguments of the wrong type (a string
for a size, ``None`` for an angle, ``3.5`` for a count) raise a
:class:`~cocd.errors.SceneError` naming the argument, before the function runs;
the function itself then checks the values (ranges, signs).
"""

from __future__ import annotations

import functools
import inspect
import typing
from collections.abc import Callable
from typing import Any, TypeVar

import pydantic
from pydantic import ConfigDict

from cocd.errors import SceneError

__all__ = ["argument_checker", "checked"]

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
