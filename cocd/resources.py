"""Memory estimates made before building something large, so that a problem that
cannot fit gives a clear error instead of an out-of-memory crash.

The estimates are upper bounds of what cocd allocates (grains, contact pairs,
the sparse problem); a backend's own workspace (an interior point's factor)
comes on top and is the backend's business.
"""

from __future__ import annotations

import os

from cocd.errors import ResourceError

__all__ = [
    "BYTES_PER_CONTACT",
    "BYTES_PER_GRAIN",
    "BYTES_PER_PAIR",
    "available_bytes",
    "check_fits",
]

#: A grain of a scene and its share of the step problem (state, unknowns, mass).
BYTES_PER_GRAIN = 1024
#: A candidate pair of contact detection (indices and distances, with slack).
BYTES_PER_PAIR = 64
#: A contact of the step problem: geometry, Jacobian rows (about 12 entries per
#: row, 3 rows), bounds and impulses.
BYTES_PER_CONTACT = 1536


def available_bytes() -> int:
    """Memory this process may still use: ``MemAvailable`` (Linux), else the total
    physical memory; lowered by an address-space limit (``ulimit -v``) if any."""
    limit = None
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    limit = int(line.split()[1]) * 1024
                    break
    except OSError:
        pass
    if limit is None:
        try:
            limit = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
        except (OSError, ValueError, AttributeError):
            limit = 1 << 62
    try:
        import resource

        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
        if soft != resource.RLIM_INFINITY:
            limit = min(limit, soft)
    except (ImportError, OSError, ValueError):
        pass
    return int(limit)


def check_fits(n_bytes: float, what: str) -> None:
    """Raise :class:`ResourceError` when ``n_bytes`` is more than the memory available."""
    have = available_bytes()
    if not n_bytes <= have:
        raise ResourceError(
            f"{what} needs about {n_bytes / 2**30:.3g} GiB, more than the "
            f"{have / 2**30:.3g} GiB of memory available"
        )
