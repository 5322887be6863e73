"""Active-set polishing of contact impulses.

An interior point method stops with every impulse strictly inside its cone.
Where complementarity is degenerate (a contact sliding at a vanishing speed,
a grain leaving a surface tangentially), its natural-map residual then only
falls like the square root of its duality gap, and no tightening of its
tolerances helps past about 1e-7. Polishing reads each contact's state from the
natural map at the answer, ``y_a = p_a - rho_a w_a``:

- ``P_K(y_a) = 0``: separated, ``p_a = 0``;
- ``y_a`` inside the cone: sticking, ``w_a = 0``;
- otherwise sliding along ``e = y_T / |y_T|``: ``p_T = mu p_N e`` and
  ``w_N + mu e.w_T = 0``;

and solves the resulting sparse linear system in ``p`` (a semismooth Newton
step on the natural map with that active set, as OSQP's solution polishing
does for QPs). A polished answer is kept only if it lowers ``ccp_residual``.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from cocd.cones import project_coulomb
from cocd.residuals import ccp_residual

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from cocd.problem import ConicProblem

__all__ = ["polish_impulses"]

SEPARATED, STICKING, SLIDING = 0, 1, 2
STATE_WEIGHTS = (1.0, 1e2, 1e4)
REGULARISATION = 1e-12


def polish_impulses(
    problem: ConicProblem,
    p: NDArray[np.float64],
    target: float = 0.0,
    max_steps: int = 3,
    time_budget: float | None = None,
) -> tuple[NDArray[np.float64], dict[str, Any]]:
    """Polish impulses ``p`` (shape ``(nc, m)``) by active-set Newton steps.

    Near a degenerate contact the state read from ``p - rho w`` depends on the
    weight given to ``w``: each step tries the weights ``rho x (1, 1e2, 1e4)``
    and keeps the best answer, stopping once ``ccp_residual <= target``, and
    starting no new Newton solve once ``time_budget`` seconds have passed (a
    sparse factorisation of a large problem costs seconds each).

    Returns
    -------
    p : (nc, m) array
        The best impulses found (``p`` itself if no step helped).
    info : dict
        ``steps`` taken, ``accepted`` steps, ``ccp_before`` and ``ccp_after``,
        ``out_of_time`` when the budget cut it short.
    """
    start = time.perf_counter()
    best = np.asarray(p, dtype=np.float64).reshape(problem.nc, problem.contact_dim)
    best_r = ccp_residual(problem, best)
    info: dict[str, Any] = {"steps": 0, "accepted": 0, "ccp_before": best_r, "out_of_time": False}
    for _ in range(max_steps):
        if best_r <= target:
            break
        info["steps"] += 1
        improved = False
        for weight in STATE_WEIGHTS:
            if time_budget is not None and time.perf_counter() - start > time_budget:
                info["out_of_time"] = True
                break
            candidate = _newton_step(problem, best, weight)
            if candidate is None:
                continue
            r = ccp_residual(problem, candidate)
            if r < best_r:
                step_best, best_r, improved = candidate, r, True
                if r <= target:
                    break
        if not improved:
            break
        best = step_best
        info["accepted"] += 1
    info["ccp_after"] = best_r
    return best, info


def _newton_step(
    problem: ConicProblem, p: NDArray[np.float64], weight: float
) -> NDArray[np.float64] | None:
    nc, m = problem.nc, problem.contact_dim
    mu = problem.mu
    w = problem.contact_velocity(p)
    y = p - weight * problem.rho[:, None] * w
    proj = project_coulomb(y, mu)
    state = np.full(nc, SLIDING)
    state[np.all(proj == 0.0, axis=1)] = SEPARATED
    state[np.all(proj == y, axis=1) & np.any(y != 0.0, axis=1)] = STICKING
    if m == 1:
        state[state == SLIDING] = STICKING

    base = np.arange(nc) * m
    w_rows: list[np.ndarray] = []
    w_cols: list[np.ndarray] = []
    w_vals: list[np.ndarray] = []
    p_rows: list[np.ndarray] = []
    p_cols: list[np.ndarray] = []
    p_vals: list[np.ndarray] = []

    def add(rows, cols, vals, r, c, v):
        rows.append(np.asarray(r).ravel())
        cols.append(np.asarray(c).ravel())
        vals.append(np.broadcast_to(np.asarray(v, dtype=np.float64), np.shape(r)).ravel())

    comps = np.arange(m)
    sep = base[state == SEPARATED][:, None] + comps
    add(p_rows, p_cols, p_vals, sep, sep, 1.0)
    stick = base[state == STICKING][:, None] + comps
    add(w_rows, w_cols, w_vals, stick, stick, 1.0)

    slide = np.flatnonzero(state == SLIDING)
    if slide.size:
        k = base[slide]
        yt = y[slide, 1:]
        e = yt / np.linalg.norm(yt, axis=1)[:, None]
        mue = mu[slide, None] * e  # (s, m - 1)
        tang = k[:, None] + 1 + np.arange(m - 1)
        # w_N + mu e.w_T = 0
        add(w_rows, w_cols, w_vals, k, k, 1.0)
        add(w_rows, w_cols, w_vals, np.repeat(k[:, None], m - 1, axis=1), tang, mue)
        # p_T - mu e p_N = 0
        add(p_rows, p_cols, p_vals, tang, tang, 1.0)
        add(p_rows, p_cols, p_vals, tang, np.repeat(k[:, None], m - 1, axis=1), -mue)

    size = nc * m
    C = sp.csr_matrix(
        (np.concatenate(w_vals), (np.concatenate(w_rows), np.concatenate(w_cols))),
        shape=(size, size),
    )
    E = sp.csr_matrix(
        (np.concatenate(p_vals), (np.concatenate(p_rows), np.concatenate(p_cols))),
        shape=(size, size),
    )
    # Proximal regularisation W + delta I keeps the system regular when sticking
    # contacts are statically indeterminate; it biases w by delta |p|, far below
    # any tolerance. A state with no consistent answer gives a wild candidate,
    # which the caller rejects.
    delta = REGULARISATION * float(problem.W.diagonal().mean())
    J = sp.csc_matrix(C @ (problem.W + delta * sp.identity(size)) + E)
    rhs = -(C @ problem.b)
    try:
        x = spla.splu(J).solve(rhs)
    except RuntimeError:  # exactly singular: e.g. a row of zeros
        return None
    if not np.all(np.isfinite(x)):
        return None
    return project_coulomb(x.reshape(nc, m), mu)
