"""The conic problem solved at every step (DESIGN.md section 1).

Velocity-based primal (COCD)::

    min_u  1/2 u'Mu - u'MU
    s.t.   (D_a/dt + N_a u, mu_a T_a u) in SOC      for every contact a

Force-based dual (the cone complementarity problem)::

    min_p  1/2 p'Wp + p'b    s.t.  p in K = prod {|p_T| <= mu_a p_N}
    W = H M^-1 H',  b = H U + (D/dt, 0),  u = U + M^-1 H'p

:class:`ConicProblem` holds ``M, H, D, mu, dt, U`` once and derives the
primal standard conic form, the dual data and the QP form on demand.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Literal

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from cocd.cones import project_coulomb
from cocd.contacts import ContactSet, contact_jacobian, dof_layout
from cocd.errors import ProblemError
from cocd.resources import BYTES_PER_CONTACT, BYTES_PER_GRAIN, check_fits
from cocd.scene import Scene

__all__ = [
    "ConicProblem",
    "DualConicForm",
    "PrimalConicForm",
    "assemble",
    "generalized_velocity",
    "scatter_velocity",
]

FloatArray = NDArray[np.float64]
ConeKind = Literal["zero", "nonneg", "soc"]


@dataclass(frozen=True)
class PrimalConicForm:
    """The primal in standard conic form, dimensionless, in the velocity correction.

    ``min 1/2 x'Px + q'x  s.t.  A x + s = b,  s in K`` with
    ``x = (u - U) / velocity_scale`` (so ``q = 0`` and the objective is the work
    of the contact impulses) and the objective divided by
    ``mass_scale * velocity_scale**2``: millimetre and metre grains, fast and
    slow flows, give the same numbers to a solver, and a solver's relative
    gap is relative to the contact work, not to the kinetic energy of the flow.

    Attributes
    ----------
    P : (ndof, ndof) csc, diagonal
    q : (ndof,), zero
    A : (rows, ndof) csc
    b : (rows,)
    cones : list of (kind, size)
        ``("nonneg", rows)`` when every cone is linear (2D, frictionless, or
        faceted), or ``("soc", 3)`` once per contact in 3D.
    mass_scale, velocity_scale : float
        ``u = U + velocity_scale x``; a dual ``z`` of this form is an impulse divided
        by ``mass_scale * velocity_scale``.
    facets : int or None
        Number of facets of the pyramidal cone replacing each circular one in 3D
        (an approximation: friction up to ``mu`` along ``facets`` directions,
        ``mu cos(pi / facets)`` in between), or ``None`` for the exact cones.
    """

    P: sp.csc_matrix
    q: FloatArray
    A: sp.csc_matrix
    b: FloatArray
    cones: list[tuple[ConeKind, int]]
    mass_scale: float
    velocity_scale: float
    problem: ConicProblem = field(repr=False)
    facets: int | None = None

    def velocity(self, x: FloatArray) -> FloatArray:
        """Generalized velocity ``u`` from a primal point ``x``."""
        return np.asarray(self.problem.U + np.asarray(x, dtype=np.float64) * self.velocity_scale)

    def impulses(self, z: FloatArray) -> FloatArray:
        """Contact impulses ``p``, shape ``(nc, m)``, from the duals of the rows of ``A``."""
        pr = self.problem
        z = np.asarray(z, dtype=np.float64) * (self.mass_scale * self.velocity_scale)
        if self.facets is not None:
            lam = z.reshape(pr.nc, self.facets)
            e = _facet_directions(self.facets)  # (k, 2)
            pt = pr.mu[:, None] * (lam @ e)
            return np.concatenate([lam.sum(axis=1)[:, None], pt], axis=1)
        if pr.contact_dim == 1:
            return z.reshape(pr.nc, 1)
        if pr.contact_dim == 2:
            lam = z.reshape(pr.nc, 2)
            return np.stack([lam[:, 0] + lam[:, 1], pr.mu * (lam[:, 0] - lam[:, 1])], axis=1)
        zz = z.reshape(pr.nc, 3)
        return np.concatenate([zz[:, :1], pr.mu[:, None] * zz[:, 1:]], axis=1)


@dataclass(frozen=True)
class DualConicForm:
    """The force-based dual in standard conic form, dimensionless.

    ``min 1/2 x'Px + q'x  s.t.  A x + s = b,  s in K`` with ``x`` the impulses
    divided by ``impulse_scale`` (see :meth:`ConicProblem.dual_conic_form`).
    """

    P: sp.csc_matrix
    q: FloatArray
    A: sp.csc_matrix
    b: FloatArray
    cones: list[tuple[ConeKind, int]]
    impulse_scale: float
    problem: ConicProblem = field(repr=False)

    def impulses(self, x: FloatArray) -> FloatArray:
        """Impulses ``(nc, m)`` from a point ``x`` of this form."""
        pr = self.problem
        return np.asarray(x, dtype=np.float64).reshape(pr.nc, pr.contact_dim) * self.impulse_scale

    def point(self, p: FloatArray) -> FloatArray:
        """The point ``x`` of this form for impulses ``p`` (e.g. a warm start)."""
        return np.asarray(p, dtype=np.float64).reshape(-1) / self.impulse_scale


@dataclass(eq=False)
class ConicProblem:
    """One step's contact problem.

    Attributes
    ----------
    dim : int
        Space dimension, 2 or 3.
    contact_dim : int
        Components per contact ``m``: 1 (frictionless, normal only) or ``dim``.
    mass : (ndof,)
        Diagonal of ``M``. Rotational unknowns are spin times radius, so every
        entry is a mass (``J / R^2``).
    H : (m nc, ndof) csr
        Contact Jacobian, normal row first in each contact block.
    D : (nc,)
        Gaps at the start of the step.
    mu : (nc,)
        Friction coefficients.
    dt : float
        Time step.
    U : (ndof,)
        Free velocity ``u^k + dt M^-1 f_ext``.
    slip_offset : (nc, m - 1), optional
        A constant tangential relative velocity added to ``H_T u`` (a moving
        wall, or the tangential part of an external problem's ``w``): the
        relative velocity is ``w = H u + (D/dt, slip_offset)``. ``None`` (the
        default, every scene problem) means zero.
    delassus_shift : float
        The problem's Delassus operator is ``W = H M^-1 H' - delassus_shift I``
        (0, the default, for every scene problem). An external local problem
        whose ``W`` is positive semi-definite only to rounding is factored as
        ``H H' = W + delta I`` (:mod:`cocd.io.problems`) and carries ``delta``
        here: the dual data (:attr:`W`, :attr:`rho`), :meth:`contact_velocity`
        and every residual are those of the true ``W``; the primal forms, which
        are built on ``H`` and ``M``, are those of the shifted, convex problem.
    """

    dim: int
    contact_dim: int
    mass: FloatArray
    H: sp.csr_matrix
    D: FloatArray
    mu: FloatArray
    dt: float
    U: FloatArray
    slip_offset: FloatArray | None = None
    delassus_shift: float = 0.0

    def __post_init__(self) -> None:
        self.delassus_shift = float(self.delassus_shift)
        if not (np.isfinite(self.delassus_shift) and self.delassus_shift >= 0.0):
            raise ProblemError(f"delassus_shift must be finite and >= 0, got {self.delassus_shift}")
        self.mass = np.asarray(self.mass, dtype=np.float64)
        self.D = np.asarray(self.D, dtype=np.float64).reshape(-1)
        self.mu = np.asarray(self.mu, dtype=np.float64).reshape(-1)
        self.U = np.asarray(self.U, dtype=np.float64).reshape(-1)
        self.H = sp.csr_matrix(self.H, dtype=np.float64)
        if self.slip_offset is not None:
            t = np.asarray(self.slip_offset, dtype=np.float64)
            if t.size != self.D.size * (self.contact_dim - 1):
                raise ProblemError(
                    f"slip_offset has {t.size} entries, expected {self.D.size} contacts x "
                    f"{self.contact_dim - 1} tangential components"
                )
            if not np.all(np.isfinite(t)):
                raise ProblemError("slip_offset has non-finite entries")
            self.slip_offset = t.reshape(self.D.size, self.contact_dim - 1)
        if self.dim not in (2, 3):
            raise ProblemError(f"dim must be 2 or 3, got {self.dim}")
        if self.contact_dim not in (1, self.dim):
            raise ProblemError(f"contact_dim must be 1 or {self.dim}, got {self.contact_dim}")
        if not (np.isfinite(self.dt) and self.dt > 0.0):
            raise ProblemError(f"time step dt must be finite and > 0, got {self.dt}")
        nc, ndof = self.D.size, self.mass.size
        if self.H.shape != (self.contact_dim * nc, ndof):
            raise ProblemError(
                f"H has shape {self.H.shape}, expected {(self.contact_dim * nc, ndof)} "
                f"for {nc} contacts of dimension {self.contact_dim} and {ndof} unknowns"
            )
        if self.mu.shape != (nc,) or self.U.shape != (ndof,):
            raise ProblemError(
                f"mu has shape {self.mu.shape} (expected ({nc},)) and U {self.U.shape} "
                f"(expected ({ndof},))"
            )
        for name in ("mass", "D", "mu", "U"):
            bad = np.flatnonzero(~np.isfinite(getattr(self, name)))
            if bad.size:
                raise ProblemError(
                    f"{name}[{bad[0]}] is {getattr(self, name)[bad[0]]}: {name} must be finite "
                    f"({bad.size} entries are not)"
                )
        if not np.all(np.isfinite(self.H.data)):
            raise ProblemError("H has non-finite entries")
        bad = np.flatnonzero(self.mass <= 0.0)
        if bad.size:
            raise ProblemError(f"mass[{bad[0]}] is {self.mass[bad[0]]:g}: every mass must be > 0")
        bad = np.flatnonzero(self.mu < 0.0)
        if bad.size:
            raise ProblemError(
                f"mu[{bad[0]}] is {self.mu[bad[0]]:g}: friction coefficients must be >= 0"
            )

    # -- sizes and simple maps ----------------------------------------------
    @property
    def nc(self) -> int:
        return int(self.D.size)

    @property
    def ndof(self) -> int:
        return int(self.mass.size)

    @cached_property
    def offset(self) -> FloatArray:
        """``(D/dt, slip_offset)`` per contact, flattened, shape ``(m nc,)``."""
        e = np.zeros((self.nc, self.contact_dim))
        e[:, 0] = self.D / self.dt
        if self.slip_offset is not None:
            e[:, 1:] = self.slip_offset
        return e.reshape(-1)

    def velocity(self, p: FloatArray) -> FloatArray:
        """``u = U + M^-1 H'p`` for impulses ``p`` of shape ``(nc, m)``."""
        return np.asarray(self.U + (self.H.T @ np.asarray(p).reshape(-1)) / self.mass)

    def relative_velocity(self, u: FloatArray) -> FloatArray:
        """``w = H u + (D/dt, 0)``, shape ``(nc, m)``: normal gap rate then slip."""
        return np.asarray(self.H @ u + self.offset).reshape(self.nc, self.contact_dim)

    def contact_velocity(self, p: FloatArray) -> FloatArray:
        """``w = W p + b`` for impulses ``p``, shape ``(nc, m)``, without forming ``W``.

        The relative velocity the impulses imply: ``H (U + M^-1 H'p) + offset``,
        minus ``delassus_shift p`` when the problem has one.
        """
        p = np.asarray(p, dtype=np.float64).reshape(self.nc, self.contact_dim)
        w = self.relative_velocity(self.velocity(p))
        if self.delassus_shift:
            w = w - self.delassus_shift * p
        return w

    # -- dual data -----------------------------------------------------------
    @cached_property
    def W(self) -> sp.csr_matrix:
        """Delassus operator ``H M^-1 H' - delassus_shift I``, sparse (never dense)."""
        W = sp.csr_matrix(self.H @ sp.diags(1.0 / self.mass) @ self.H.T)
        if self.delassus_shift:
            W = sp.csr_matrix(W - self.delassus_shift * sp.identity(W.shape[0]))
        return W

    @cached_property
    def b(self) -> FloatArray:
        """Dual linear term ``H U + (D/dt, 0)``, flattened."""
        return np.asarray(self.H @ self.U + self.offset)

    def dual(self) -> tuple[sp.csr_matrix, FloatArray]:
        """``(W, b)`` of the force-based dual."""
        return self.W, self.b

    @cached_property
    def rho(self) -> FloatArray:
        """Per-contact scaling ``m / trace(W_aa)``, shape ``(nc,)`` (a mass)."""
        diag = np.asarray(self.H.multiply(self.H) @ (1.0 / self.mass)) - self.delassus_shift
        return self.contact_dim / diag.reshape(self.nc, self.contact_dim).sum(axis=1)

    # -- primal forms --------------------------------------------------------
    @cached_property
    def scales(self) -> tuple[float, float]:
        """``(mass_scale, velocity_scale)`` that make the primal dimensionless.

        The mass scale is the mean of ``M``; the velocity scale is the largest
        distance of a contact's free relative velocity ``b_a`` to its dual cone,
        i.e. how much the free motion violates the constraints, the size of the
        correction the contacts must make (the largest ``|b|`` when none is violated).
        """
        mass_scale = float(np.mean(self.mass))
        b = self.b.reshape(self.nc, self.contact_dim)
        violation = np.linalg.norm(project_coulomb(-b, self.mu), axis=1)
        v = float(np.max(violation, initial=0.0)) or float(np.max(np.abs(b), initial=0.0))
        return mass_scale, (v if v > 0.0 else 1.0)

    def primal_conic_form(self, facets: int | None = None) -> PrimalConicForm:
        """The primal as ``min 1/2 x'Px + q'x, A x + s = b, s in K`` (see PrimalConicForm).

        ``facets`` replaces each 3D second-order cone by a pyramid of that many
        facets (an inner approximation of the friction cone), giving a QP.
        """
        ms, vs = self.scales
        P = sp.diags(self.mass / ms).tocsc()
        q = np.zeros(self.ndof)
        m, nc = self.contact_dim, self.nc
        cones: list[tuple[ConeKind, int]]
        if facets is not None and m == 3:
            k = int(facets)
            if k < 3 or k != facets:
                raise ProblemError(f"facets must be an integer >= 3, got {facets!r}")
            e = _facet_directions(k)  # (k, 2)
            # Row (a, j) = N_a + mu_a (e_j1 T1_a + e_j2 T2_a): one selection-and-weight
            # matrix S of shape (k nc, 3 nc) applied to H, contact-major.
            rows = np.repeat(np.arange(k * nc), 3)
            cols = (3 * np.repeat(np.arange(nc), k)[:, None] + np.arange(3)).reshape(-1)
            weights = np.empty((nc, k, 3))
            weights[:, :, 0] = 1.0
            weights[:, :, 1:] = self.mu[:, None, None] * e[None, :, :]
            S = sp.csr_matrix((weights.reshape(-1), (rows, cols)), shape=(k * nc, 3 * nc))
            A = -sp.csr_matrix(S @ self.H)
            b = (S @ self.b) / vs
            return PrimalConicForm(
                P=P,
                q=q,
                A=sp.csc_matrix(A),
                b=np.asarray(b, dtype=np.float64),
                cones=[("nonneg", k * nc)] if nc else [],
                mass_scale=ms,
                velocity_scale=vs,
                problem=self,
                facets=k,
            )
        if m == 1:
            A = -self.H
            b = self.b / vs
            cones = [("nonneg", nc)] if nc else []
        elif m == 2:
            # mu |T u| <= D/dt + N u as two half-planes: (N +- mu T) u >= -D/dt.
            N, T = self.H[0::2], self.H[1::2]
            muT = sp.diags(self.mu) @ T
            A = -_interleave(N + muT, N - muT)
            w0 = self.offset.reshape(nc, 2)
            b0 = np.stack([w0[:, 0] + self.mu * w0[:, 1], w0[:, 0] - self.mu * w0[:, 1]], axis=1)
            b = (b0.reshape(-1) - A @ self.U) / vs
            cones = [("nonneg", 2 * nc)] if nc else []
        else:
            scale = np.ones((nc, 3))
            scale[:, 1:] = self.mu[:, None]
            A = -(sp.diags(scale.reshape(-1)) @ self.H)
            b = scale.reshape(-1) * self.b / vs
            cones = [("soc", 3)] * nc
        return PrimalConicForm(
            P=P,
            q=q,
            A=sp.csc_matrix(A),
            b=np.asarray(b, dtype=np.float64),
            cones=cones,
            mass_scale=ms,
            velocity_scale=vs,
            problem=self,
        )

    @property
    def is_qp(self) -> bool:
        """True when every cone is linear (2D or frictionless): the primal is a QP."""
        return self.contact_dim < 3

    def qp_form(
        self, facets: int | None = None
    ) -> tuple[sp.csc_matrix, FloatArray, sp.csc_matrix, FloatArray]:
        """``(P, q, G, h)`` of ``min 1/2 x'Px + q'x  s.t.  G x <= h`` (dimensionless).

        Only for linear cones, or 3D with ``facets``; the duals of ``G`` map to
        impulses with :meth:`PrimalConicForm.impulses` of
        ``primal_conic_form(facets)``, which also maps ``x`` to velocities.
        """
        if not self.is_qp and facets is None:
            raise ProblemError(
                "a 3D frictional problem has second-order cones, not a QP; "
                "pass facets= for a faceted approximation"
            )
        form = self.primal_conic_form(facets)
        return form.P, form.q, form.A, form.b

    def dual_conic_form(self) -> DualConicForm:
        """The force-based dual as ``min 1/2 x'Px + q'x, A x + s = b, s in K``.

        ``x = p / (mass_scale * velocity_scale)`` flattened (normal first in each
        contact), ``P = mass_scale W`` (sparse), ``q = b / velocity_scale``. The
        rows of ``A`` are grouped by cone: ``("zero", .)`` (tangential impulses
        of frictionless contacts), ``("nonneg", .)`` (normal impulses of
        frictionless contacts; ``mu p_N -+ p_T`` in 2D), then one ``("soc", 3)``
        per 3D frictional contact: ``(mu p_N, p_T)``.
        """
        ms, vs = self.scales
        nc, m = self.nc, self.contact_dim
        base = np.arange(nc) * m
        zero_c: list[np.ndarray] = []
        lin_r: list[np.ndarray] = []
        lin_c: list[np.ndarray] = []
        lin_v: list[np.ndarray] = []
        frictional = self.mu > 0.0 if m > 1 else np.zeros(nc, dtype=bool)
        smooth = np.flatnonzero(~frictional)
        # Frictionless contacts: p_N >= 0, p_T = 0.
        lin_r.append(np.arange(smooth.size))
        lin_c.append(base[smooth])
        lin_v.append(np.ones(smooth.size))
        for t in range(1, m):
            zero_c.append(base[smooth] + t)
        n_lin = smooth.size
        rough = np.flatnonzero(frictional)
        if m == 2:
            # mu p_N - p_T >= 0 and mu p_N + p_T >= 0.
            for sign in (-1.0, 1.0):
                r = n_lin + np.arange(rough.size)
                lin_r += [r, r]
                lin_c += [base[rough], base[rough] + 1]
                lin_v += [self.mu[rough], np.full(rough.size, sign)]
                n_lin += rough.size
        zero_cols = np.concatenate(zero_c) if zero_c else np.zeros(0, dtype=np.int64)
        n_zero = zero_cols.size
        soc_r: list[np.ndarray] = []
        soc_c: list[np.ndarray] = []
        soc_v: list[np.ndarray] = []
        n_soc = 0
        if m == 3:
            start = n_zero + n_lin + 3 * np.arange(rough.size)
            soc_r = [start, start + 1, start + 2]
            soc_c = [base[rough], base[rough] + 1, base[rough] + 2]
            soc_v = [self.mu[rough], np.ones(rough.size), np.ones(rough.size)]
            n_soc = rough.size
        r_all = np.concatenate([np.arange(n_zero), n_zero + np.concatenate(lin_r), *soc_r]).astype(
            np.int64
        )
        c_all = np.concatenate([zero_cols, np.concatenate(lin_c), *soc_c]).astype(np.int64)
        v_all = np.concatenate([np.ones(n_zero), np.concatenate(lin_v), *soc_v])
        n_rows = n_zero + n_lin + 3 * n_soc
        A = -sp.csc_matrix((v_all, (r_all, c_all)), shape=(n_rows, nc * m))
        cones: list[tuple[ConeKind, int]] = []
        if n_zero:
            cones.append(("zero", n_zero))
        if n_lin:
            cones.append(("nonneg", n_lin))
        cones += [("soc", 3)] * n_soc
        return DualConicForm(
            P=sp.csc_matrix(ms * self.W),
            q=np.asarray(self.b / vs, dtype=np.float64),
            A=A,
            b=np.zeros(n_rows),
            cones=cones,
            impulse_scale=ms * vs,
            problem=self,
        )


def assemble(
    scene: Scene,
    contacts: ContactSet,
    dt: float,
    *,
    forces: FloatArray | None = None,
    torques: FloatArray | None = None,
) -> ConicProblem:
    """Build the step problem of ``scene`` with the given potential contacts.

    Frictionless scenes drop the rotations and the tangential rows (the
    problem is then a QP in translations only). ``forces`` (``(n, d)``, N) and
    ``torques`` (``(n,)`` in 2D, ``(n, 3)`` in 3D, N m) are external loads on
    every grain (fixed ones ignored), added to gravity in the free velocity
    ``U = v + dt M^-1 (m g + F)``; checked by :func:`cocd.coupling.resolve_loads`.
    Torques do not enter a frictionless problem (it has no rotations).
    """
    if not (np.isfinite(dt) and dt > 0.0):
        raise ProblemError(f"time step dt must be finite and > 0, got {dt}")
    frictionless = scene.frictionless
    check_fits(
        contacts.nc * BYTES_PER_CONTACT + scene.n_free * BYTES_PER_GRAIN,
        f"the step problem of {scene.n_free} grains and {contacts.nc} contacts",
    )
    first, per_grain = dof_layout(scene, frictionless)
    ndof = scene.n_free * per_grain
    H = contact_jacobian(contacts, first, per_grain, ndof)

    free = scene.free
    m = scene.masses[free]
    d = scene.dim
    blocks = np.empty((scene.n_free, per_grain))
    blocks[:, :d] = m[:, None]
    if not frictionless:
        blocks[:, d:] = (scene.inertia[free] / scene.radii[free] ** 2)[:, None]
    mass = blocks.reshape(-1)

    u = generalized_velocity(scene, frictionless)
    accel = np.zeros((scene.n_free, per_grain))
    accel[:, :d] = scene.gravity
    if forces is not None:
        accel[:, :d] += forces[free] / m[:, None]
    if torques is not None and not frictionless:
        # The rotational unknown is r * omega: its rate is r tau / I.
        r = scene.radii[free]
        gain = r / scene.inertia[free]
        accel[:, d:] += (gain * torques[free]) if d == 2 else gain[:, None] * torques[free]
    U = u + dt * accel.reshape(-1)
    return ConicProblem(
        dim=d,
        contact_dim=1 if frictionless else d,
        mass=mass,
        H=H,
        D=contacts.gap,
        mu=contacts.mu,
        dt=float(dt),
        U=U,
    )


def generalized_velocity(scene: Scene, frictionless: bool) -> FloatArray:
    """The free grains' velocities as one vector in the problem's unknowns."""
    free = scene.free
    v = scene.velocities[free]
    if frictionless:
        return np.asarray(v.reshape(-1))
    r = scene.radii[free]
    w = scene.angular_velocities[free]
    spin = (r * w)[:, None] if scene.dim == 2 else r[:, None] * w
    return np.asarray(np.concatenate([v, spin], axis=1).reshape(-1))


def scatter_velocity(scene: Scene, u: FloatArray, frictionless: bool) -> None:
    """Write a generalized velocity back into the scene's free grains."""
    free = scene.free
    d = scene.dim
    per_grain = d if frictionless else (3 if d == 2 else 6)
    blocks = np.asarray(u).reshape(-1, per_grain)
    scene.velocities[free] = blocks[:, :d]
    if not frictionless:
        r = scene.radii[free]
        if d == 2:
            scene.angular_velocities[free] = blocks[:, 2] / r
        else:
            scene.angular_velocities[free] = blocks[:, 3:] / r[:, None]


def _facet_directions(k: int) -> FloatArray:
    """Unit tangential directions ``(cos 2 pi j / k, sin 2 pi j / k)``, shape ``(k, 2)``."""
    theta = 2.0 * np.pi * np.arange(k) / k
    return np.stack([np.cos(theta), np.sin(theta)], axis=1)


def _interleave(a: sp.spmatrix, b: sp.spmatrix) -> sp.csr_matrix:
    """Rows ``a_0, b_0, a_1, b_1, ...``."""
    n = a.shape[0]
    stacked = sp.vstack([a, b]).tocsr()
    order = np.empty(2 * n, dtype=np.int64)
    order[0::2] = np.arange(n)
    order[1::2] = np.arange(n, 2 * n)
    return sp.csr_matrix(stacked[order])
