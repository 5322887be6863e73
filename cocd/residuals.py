"""One error measure for every backend (DESIGN.md section 2).

The framework, not the backend, judges an answer ``(u, p)``. Every residual is
unit-free: contact ``a`` is scaled by ``rho_a = m / trace(W_aa)`` (a mass), and
sums are normalised by the problem's data (``||rho b||``), never by the answer.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cocd.cones import project_coulomb, project_dual_coulomb
from cocd.problem import ConicProblem

__all__ = [
    "Residuals",
    "ccp_residual",
    "complementarity",
    "cone_violation",
    "coulomb_residual",
    "dual_cone_violation",
    "dynamics_residual",
    "project_coulomb",
    "project_dual_coulomb",
    "residuals",
]

FloatArray = NDArray[np.float64]


def ccp_residual(problem: ConicProblem, p: ArrayLike) -> float:
    """Natural map of the cone complementarity problem ``K ∋ p ⊥ Wp + b ∈ K*``.

    ``F_a = p_a - P_K(p_a - rho_a w_a)`` with ``w = Wp + b``; returns
    ``||F|| / ||rho b||`` (0 when there is no contact).
    """
    p = _impulses(problem, p)
    return _natural_map(problem, p, _w(problem, p))


def coulomb_residual(problem: ConicProblem, p: ArrayLike) -> float:
    """Natural map of the non-convex Coulomb law, with De Saxcé's velocity.

    As :func:`ccp_residual` with ``ŵ = w + (mu |w_T|, 0)`` in place of ``w``.
    """
    p = _impulses(problem, p)
    w = _w(problem, p)
    if problem.contact_dim > 1:
        w = w.copy()
        w[:, 0] += problem.mu * np.linalg.norm(w[:, 1:], axis=1)
    return _natural_map(problem, p, w)


def dynamics_residual(problem: ConicProblem, u: ArrayLike, p: ArrayLike) -> float:
    """``||M(u - U) - H'p|| / ||M U||``: how far ``u`` is from the velocity ``p`` implies.

    The denominator falls back to ``||H'p||`` when ``MU = 0``.
    """
    u = np.asarray(u, dtype=np.float64).reshape(-1)
    p = _impulses(problem, p)
    Hp = problem.H.T @ p.reshape(-1)
    r = float(np.linalg.norm(problem.mass * (u - problem.U) - Hp))
    den = float(np.linalg.norm(problem.mass * problem.U)) or float(np.linalg.norm(Hp))
    return _ratio(r, den)


def cone_violation(problem: ConicProblem, p: ArrayLike) -> FloatArray:
    """Distance of each impulse to its Coulomb cone, divided by the rms of ``rho b``.

    Shape ``(nc,)``.
    """
    p = _impulses(problem, p)
    return np.asarray(
        np.linalg.norm(p - project_coulomb(p, problem.mu), axis=1) / _impulse_scale(problem)
    )


def dual_cone_violation(problem: ConicProblem, p: ArrayLike) -> FloatArray:
    """Distance of each ``rho_a w_a`` to the dual cone, divided by the rms of ``rho b``.

    Shape ``(nc,)``; positive where the step leaves an interpenetration or a
    slip larger than the cone allows.
    """
    p = _impulses(problem, p)
    rw = problem.rho[:, None] * _w(problem, p)
    dist = np.linalg.norm(rw - project_dual_coulomb(rw, problem.mu), axis=1)
    return np.asarray(dist / _impulse_scale(problem))


def complementarity(problem: ConicProblem, p: ArrayLike) -> FloatArray:
    """``|p_a . rho_a w_a|`` per contact, divided by the squared rms of ``rho b``."""
    p = _impulses(problem, p)
    rw = problem.rho[:, None] * _w(problem, p)
    return np.asarray(np.abs(np.sum(p * rw, axis=1)) / _impulse_scale(problem) ** 2)


@dataclass(frozen=True)
class Residuals:
    """Every residual of one answer; see the functions of the same names."""

    ccp: float
    coulomb: float
    dynamics: float
    cone_violation_max: float
    cone_violation_rms: float
    dual_violation_max: float
    dual_violation_rms: float
    complementarity_max: float
    complementarity_rms: float

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def residuals(problem: ConicProblem, u: ArrayLike, p: ArrayLike) -> Residuals:
    """All residuals of the answer ``(u, p)`` to ``problem``."""
    p = _impulses(problem, p)
    cv = cone_violation(problem, p)
    dv = dual_cone_violation(problem, p)
    cp = complementarity(problem, p)
    return Residuals(
        ccp=ccp_residual(problem, p),
        coulomb=coulomb_residual(problem, p),
        dynamics=dynamics_residual(problem, u, p),
        cone_violation_max=_max(cv),
        cone_violation_rms=_rms(cv),
        dual_violation_max=_max(dv),
        dual_violation_rms=_rms(dv),
        complementarity_max=_max(cp),
        complementarity_rms=_rms(cp),
    )


# -- helpers -----------------------------------------------------------------
def _impulses(problem: ConicProblem, p: ArrayLike) -> FloatArray:
    p = np.asarray(p, dtype=np.float64)
    shape = (problem.nc, problem.contact_dim)
    if p.size != problem.nc * problem.contact_dim:
        raise ValueError(f"impulses have {p.size} entries, expected {shape}")
    return p.reshape(shape)


def _w(problem: ConicProblem, p: FloatArray) -> FloatArray:
    """``W p + b`` without forming W: the relative velocity ``p`` implies."""
    return problem.contact_velocity(p)


def _natural_map(problem: ConicProblem, p: FloatArray, w: FloatArray) -> float:
    if problem.nc == 0:
        return 0.0
    rho = problem.rho[:, None]
    F = p - project_coulomb(p - rho * w, problem.mu)
    rb = rho * problem.b.reshape(problem.nc, problem.contact_dim)
    return _ratio(float(np.linalg.norm(F)), float(np.linalg.norm(rb)))


def _impulse_scale(problem: ConicProblem) -> float:
    """Root mean square of ``rho_a b_a`` over contacts (an impulse), 1 when zero."""
    rb = problem.rho[:, None] * problem.b.reshape(problem.nc, problem.contact_dim)
    s = float(np.linalg.norm(rb)) / np.sqrt(max(problem.nc, 1))
    return s if s > 0.0 else 1.0


def _ratio(num: float, den: float) -> float:
    if num == 0.0:
        return 0.0
    return num / den if den > 0.0 else float("inf")


def _max(a: FloatArray) -> float:
    return float(a.max()) if a.size else 0.0


def _rms(a: FloatArray) -> float:
    return float(np.sqrt(np.mean(a**2))) if a.size else 0.0
