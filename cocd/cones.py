"""Exact projections onto the Coulomb cones and their duals (2D and 3D)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["project_coulomb", "project_dual_coulomb"]

FloatArray = NDArray[np.float64]


def project_coulomb(x: ArrayLike, mu: ArrayLike) -> FloatArray:
    """Exact projection onto the Coulomb cones ``{|x_T| <= mu x_N}``.

    Parameters
    ----------
    x : (nc, m) array
        Vectors, normal first; ``m`` = 1 (the half-line ``x_N >= 0``), 2 or 3.
    mu : (nc,) array or float

    Returns
    -------
    (nc, m) array
    """
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2:
        raise ValueError(f"x must have shape (nc, m), got {x.shape}")
    if x.shape[1] == 1:
        return np.maximum(x, 0.0)
    mu = np.broadcast_to(np.asarray(mu, dtype=np.float64), (x.shape[0],))
    xn = x[:, 0]
    xt = x[:, 1:]
    nt = np.linalg.norm(xt, axis=1)
    # xn >= 0 matters when mu = 0: then 0 <= mu * xn also holds for xn < 0 (as -0.0).
    inside = (nt <= mu * xn) & (xn >= 0.0)
    polar = ~inside & (mu * nt <= -xn)
    side = ~inside & ~polar  # nt > 0 here
    out = x.copy()
    out[polar] = 0.0
    s = (xn[side] + mu[side] * nt[side]) / (1.0 + mu[side] ** 2)
    out[side, 0] = s
    out[side, 1:] = (mu[side] * s / nt[side])[:, None] * xt[side]
    return out


def project_dual_coulomb(y: ArrayLike, mu: ArrayLike) -> FloatArray:
    """Projection onto the dual cones ``{mu |y_T| <= y_N}`` (Moreau: ``y + P_K(-y)``)."""
    y = np.asarray(y, dtype=np.float64)
    return np.asarray(y + project_coulomb(-y, mu))
