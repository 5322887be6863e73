"""Which cocd made a file: its version and, from a git checkout, the commit."""

from __future__ import annotations

import functools
import os
import platform
import subprocess
import sys
from pathlib import Path
from typing import Any

__all__ = ["cpu_name", "machine_name", "provenance"]


#: The work tree's results folder: files a command writes, not the software.
RESULTS = "results"


@functools.cache
def provenance() -> dict[str, Any]:
    """``{"cocd": version, "commit": sha or None, "dirty": bool or None}``.

    ``commit`` is the checkout's ``HEAD`` when cocd runs from a git work tree
    (an editable install), with ``dirty`` true when it has uncommitted changes outside
    its results folder (:data:`RESULTS`: a figure written before its record does not
    make the software dirty); both are None otherwise (an installed wheel, or no git).
    """
    from cocd import __version__

    root = Path(__file__).resolve().parents[1]
    commit: str | None = None
    dirty: bool | None = None
    try:
        head = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "HEAD"],
            capture_output=True, text=True, timeout=5, check=False,
        )  # fmt: skip
        if head.returncode == 0 and (root / "cocd").is_dir():
            commit = head.stdout.strip() or None
            status = subprocess.run(
                ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no",
                 "--", ".", f":(exclude){RESULTS}"],
                capture_output=True, text=True, timeout=5, check=False,
            )  # fmt: skip
            dirty = bool(status.stdout.strip()) if status.returncode == 0 else None
    except (OSError, subprocess.SubprocessError):
        pass
    return {"cocd": __version__, "commit": commit, "dirty": dirty}


@functools.cache
def cpu_name() -> str:
    """The CPU's model name (Linux's ``/proc/cpuinfo``; else what :mod:`platform` says)."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return cpu


def machine_name() -> str:
    """``CPU, n cores``, and ``on k threads`` when the numerical libraries were given
    fewer threads than cores (a run among several at once): what a step's time depends
    on, recorded with a run's steps."""
    cores = os.cpu_count() or 1
    threads = _threads(cores)
    text = f"{cpu_name()}, {cores} cores"
    return text if threads >= cores else f"{text}, on {threads} thread{'s' * (threads > 1)}"


def _threads(cores: int) -> int:
    """Threads of numba's pool (the solvers' loops): numba's own count once it is
    loaded, else what its environment variable will give it."""
    numba = sys.modules.get("numba")
    if numba is not None:
        return int(numba.get_num_threads())
    try:
        return int(os.environ.get("NUMBA_NUM_THREADS", cores))
    except ValueError:
        return cores
