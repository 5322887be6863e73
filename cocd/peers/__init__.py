"""Peers: other projects' solvers run beside cocd's backends on the same problems.

A peer is a module with ``peer_unavailable_reason()`` (one line, or None),
``solvers_for(problem, names)`` (the full names of its solvers that apply),
``parse(name)`` (checks a name) and ``solve(problem, solver, tol, ...)`` (a
record whose impulses cocd judges with its own error measure).
``cocd bench peers DIR --peer NAME`` (:mod:`cocd.studies.peers`) runs them.

- ``siconos`` (:mod:`cocd.peers.siconos`): Siconos's ``fc2d``/``fc3d``/``gfc3d``
  solvers, run under the Python that imports ``siconos.numerics``.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from cocd.errors import CocdError

__all__ = ["PEERS", "get"]

#: Peer name -> module.
PEERS = {"siconos": "cocd.peers.siconos"}


def get(name: str) -> ModuleType:
    """The module of peer ``name``; an unknown name raises :class:`CocdError`."""
    key = name.strip().lower()
    if key not in PEERS:
        raise CocdError(f"unknown peer {name!r}; known: {', '.join(sorted(PEERS))}")
    return importlib.import_module(PEERS[key])
