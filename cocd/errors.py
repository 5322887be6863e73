"""Exceptions raised by cocd.

Every error a user can cause is a :class:`CocdError`; its message names what is
wrong (the argument, the grain, the solver) so it can be fixed without reading
a traceback.
"""

from __future__ import annotations

__all__ = [
    "CocdError",
    "OverlapError",
    "PenetrationError",
    "PenetrationWarning",
    "ProblemError",
    "ProblemFileError",
    "ResourceError",
    "SceneError",
    "SolverError",
    "SolverNotFound",
]


class CocdError(Exception):
    """Base class of every error raised on purpose by cocd."""


class SceneError(CocdError, ValueError):
    """A scene (grains, walls, materials, gravity) is invalid."""


class OverlapError(SceneError):
    """Grains overlap each other or a wall by more than the allowed tolerance."""


class ProblemError(CocdError, ValueError):
    """A conic problem or a step parameter (time step, tolerance) is invalid."""


class ProblemFileError(ProblemError):
    """A problem file (FCLib HDF5, Siconos text) cannot be read: the message names
    the file and what in it is wrong."""


class ResourceError(CocdError, MemoryError):
    """What was asked for would not fit in the memory available: the message
    gives the estimate and the memory there is."""


class SolverNotFound(CocdError, LookupError):
    """No usable backend has the requested name."""


class SolverError(CocdError, RuntimeError):
    """A backend failed to answer a problem it accepted."""


class PenetrationError(SolverError):
    """Grains overlap at the end of a step by more than the tolerance: the message
    names the step, the pair and the depth."""


class PenetrationWarning(UserWarning):
    """Grains overlapped at the end of a step by more than the tolerance, and the
    run went on (``on_penetration="warn"``)."""
