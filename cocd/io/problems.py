"""Single-step frictional contact problems as other tools write them.

The field exchanges one time step's contact problem in two forms (FCLib, the
format of the Acary, Brémond and Huber solver comparisons, and Siconos text):

- **local**: ``u = W r + q``;
- **global**: ``M v = H r + f`` and ``u = H' v + w``.

In both, each contact's vectors list the normal component first, and the law
is Coulomb's with De Saxcé's modified velocity: ``û = u + (mu |u_T|, 0)`` and
``K* ∋ û ⊥ r ∈ K`` with ``K = {|r_T| <= mu r_N}``. Condensing a global
problem gives the local one: ``W = H' M^-1 H``, ``q = w + H' M^-1 f``.

Both map onto :class:`~cocd.problem.ConicProblem`, so that every backend
answers them:

- a global problem with a diagonal ``M`` is the ConicProblem with
  ``mass = diag M``, ``H_cocd = H'``, ``U = M^-1 f`` and the offset
  ``(D/dt, slip_offset) = w`` (``dt = 1``); a non-diagonal ``M = L L'`` is
  first put in unit-mass form by ``y = L' v`` (a Cholesky factor per
  connected block of ``M``, the rigid bodies' inertia blocks);
- a local problem is the ConicProblem of unit masses whose Jacobian ``B``
  factors its Delassus operator, ``B B' = W + delta I``, from a sparse
  ``LDL'`` factorisation (QDLDL, fill-reducing order). ``delta`` is 0 when
  ``W`` is positive definite, otherwise the smallest shift (from 1e-13 of the
  largest diagonal entry, in steps of sqrt(10), up to 1e-5) that makes the
  factorisation succeed: a singular ``W`` needs 1e-13, a ``W`` printed with
  six digits, and so indefinite by rounding, about 1e-6. It is recorded as
  :attr:`LocalProblem.shift` and carried by the ConicProblem
  (``delassus_shift``), whose Delassus operator is then exactly ``W``:
  residuals, the dual forms, Gauss-Seidel (``nscd``, ``pgs``) and ``apgd``
  work with ``W`` itself, while the primal forms solve ``W + delta I`` and
  say so in ``extras["approximation"]``. A ``W`` that is not symmetric has no
  such factor: the local forms of ``nscd`` and ``pgs`` (:mod:`solvers.local`)
  solve it on ``W`` itself.

:func:`natural_map_error` is the number Siconos users compare: the unscaled
natural map of the Coulomb law, ``||r - P_K(r - û)||``, divided by
``max(1, ||q||)`` (DESIGN.md section 2); for a global problem ``q`` is that of
its condensed form, so a problem and its condensation give the same number.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray
from scipy.sparse.csgraph import connected_components

from cocd.cones import project_coulomb
from cocd.errors import ProblemError
from cocd.problem import ConicProblem

__all__ = [
    "ExternalSolution",
    "GlobalProblem",
    "LocalProblem",
    "natural_map_error",
]

FloatArray = NDArray[np.float64]

#: Largest connected block of a non-diagonal mass matrix factored densely.
MAX_MASS_BLOCK = 6000
#: A non-diagonal M of at most this many unknowns is factored whole, densely.
DENSE_MASS = 512


@dataclass
class ExternalSolution:
    """An answer in the file's own terms.

    ``r`` impulses (reactions), ``u`` local relative velocities (both ``(m nc,)``,
    normal first, the file's contact order) and, for a global problem, ``v`` the
    generalized velocities ``(ndof,)``.
    """

    r: FloatArray
    u: FloatArray
    v: FloatArray | None = None

    def arrays(self) -> dict[str, FloatArray]:
        out = {"r": self.r, "u": self.u}
        if self.v is not None:
            out["v"] = self.v
        return out


def _label(source: str, kind: str) -> str:
    return source or f"{kind} problem"


def _dimension(dim: Any, where: str) -> int:
    try:
        return int(dim)
    except (TypeError, ValueError):
        raise ProblemError(f"{where}: dimension must be 2 or 3, got {dim!r}") from None


def _vector(name: str, x: ArrayLike, size: int, where: str) -> FloatArray:
    a = np.asarray(x, dtype=np.float64).reshape(-1)
    if a.size != size:
        raise ProblemError(f"{where}: {name} has {a.size} entries, expected {size}")
    bad = np.flatnonzero(~np.isfinite(a))
    if bad.size:
        raise ProblemError(
            f"{where}: {name}[{bad[0]}] is {a[bad[0]]}: {name} must be finite "
            f"({bad.size} entries are not)"
        )
    return a


def _matrix(name: str, A: Any, shape: tuple[int, int], where: str) -> sp.csc_matrix:
    try:
        M = sp.csc_matrix(A, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ProblemError(f"{where}: {name} is not a matrix ({exc})") from None
    if M.shape != shape:
        raise ProblemError(
            f"{where}: {name} is {M.shape[0]} x {M.shape[1]}, expected {shape[0]} x {shape[1]}"
        )
    if not np.all(np.isfinite(M.data)):
        raise ProblemError(f"{where}: {name} has non-finite entries")
    return M


def _check_common(dim: int, mu: ArrayLike, m_nc: int, where: str) -> tuple[int, FloatArray]:
    if dim not in (2, 3):
        raise ProblemError(f"{where}: dimension must be 2 or 3, got {dim}")
    if m_nc % dim:
        raise ProblemError(f"{where}: {m_nc} contact rows is not a multiple of the dimension {dim}")
    nc = m_nc // dim
    mu_a = _vector("mu", mu, nc, where)
    bad = np.flatnonzero(mu_a < 0.0)
    if bad.size:
        raise ProblemError(f"{where}: mu[{bad[0]}] is {mu_a[bad[0]]:g}: friction must be >= 0")
    return nc, mu_a


class _Described:
    """What local and global problems share: a name, a label for messages, the dimension."""

    kind: ClassVar[str]
    dim: int
    title: str
    source: str

    @property
    def name(self) -> str:
        return Path(self.source).name if self.source else (self.title or f"{self.kind} problem")

    @property
    def _where(self) -> str:
        return _label(self.source, self.kind)

    def _check_dimension(self) -> str:
        """Check ``dim``; return the label for messages."""
        where = self._where
        self.dim = _dimension(self.dim, where)
        return where


@dataclass(eq=False)
class LocalProblem(_Described):
    """``u = W r + q`` with Coulomb's law per contact (see the module docstring).

    Attributes
    ----------
    W : (m nc, m nc) csc
        Delassus operator; symmetric positive semi-definite.
    q : (m nc,)
    mu : (nc,)
    dim : int
        2 or 3: the space dimension and the components per contact.
    title, description, math_info : str
        Free text carried by the file.
    source : str
        Where the problem came from (a file name), used in messages.
    """

    W: sp.csc_matrix
    q: FloatArray
    mu: FloatArray
    dim: int
    title: str = ""
    description: str = ""
    math_info: str = ""
    source: str = ""
    ndof: int | None = None
    nc: int = field(init=False)

    kind = "local"

    def __post_init__(self) -> None:
        where = self._check_dimension()
        shape = getattr(self.W, "shape", None)
        if shape is None or len(shape) != 2 or shape[0] != shape[1]:
            raise ProblemError(f"{where}: W must be a square matrix, got shape {shape}")
        n = int(shape[0])
        self.q = _vector("q", self.q, n, where)
        self.nc, self.mu = _check_common(self.dim, self.mu, n, where)
        self.W = _matrix("W", self.W, (n, n), where)

    def local(self) -> LocalProblem:
        """This problem (a local problem is its own condensed form)."""
        return self

    def check_scales(self) -> FloatArray:
        """``trace(W_aa)`` of every contact, the residuals' scales ``rho_a = m / trace``;
        a one-line :class:`ProblemError` if a contact's block of ``W`` has a negative
        diagonal entry or a zero diagonal: a Delassus operator has neither, and such a
        contact's scale would judge any answer exact. Checked before a solve and by the
        residuals, not on reading (a file may be inspected whatever it holds)."""
        where = self._where
        diagonal = self.W.diagonal()
        scale = float(np.abs(diagonal).max()) if diagonal.size else 0.0
        bad = np.flatnonzero(diagonal < -1e-12 * scale)  # not the rounding of a printed 0
        if bad.size:
            raise ProblemError(
                f"{where}: W[{bad[0]}, {bad[0]}] is {diagonal[bad[0]]:g}: a Delassus operator "
                "has no negative diagonal entry"
            )
        trace = diagonal.reshape(self.nc, self.dim).sum(axis=1)
        still = np.flatnonzero(trace <= 0.0)
        if still.size:
            raise ProblemError(
                f"{where}: contact {still[0]}'s block of W has a zero diagonal ({still.size} such "
                "contacts): its residuals have no scale, so no answer can be judged"
            )
        return trace

    def symmetry_error(self) -> float:
        """``max |W - W'| / max |W|`` (0 for an exactly symmetric W)."""
        scale = float(abs(self.W).max()) if self.W.nnz else 0.0
        if scale == 0.0:
            return 0.0
        diff = self.W - self.W.T
        return float(abs(diff).max()) / scale if diff.nnz else 0.0

    @cached_property
    def _factor(self) -> tuple[sp.csr_matrix, float]:
        self.check_scales()
        return _delassus_factor(self.W, self._where)

    @property
    def shift(self) -> float:
        """The diagonal shift ``delta`` of ``B B' = W + delta I`` (0 if none was needed)."""
        return self._factor[1]

    @cached_property
    def conic(self) -> ConicProblem:
        """The ConicProblem of unit masses whose Delassus operator is ``W + shift I``."""
        B, _ = self._factor
        n = B.shape[1]
        q = self.q.reshape(self.nc, self.dim)
        return ConicProblem(
            dim=self.dim,
            contact_dim=self.dim,
            mass=np.ones(n),
            H=B,
            D=q[:, 0].copy(),
            mu=self.mu,
            dt=1.0,
            U=np.zeros(n),
            slip_offset=q[:, 1:].copy(),
            delassus_shift=self.shift,
        )

    def velocity(self, r: ArrayLike) -> FloatArray:
        """``u = W r + q``."""
        return np.asarray(self.W @ np.asarray(r, dtype=np.float64).reshape(-1) + self.q)

    def solution(self, p: ArrayLike) -> ExternalSolution:
        """The answer in the file's terms for the impulses ``p`` of :attr:`conic`."""
        r = np.asarray(p, dtype=np.float64).reshape(-1).copy()
        return ExternalSolution(r=r, u=self.velocity(r))

    def natural_map_error(self, r: ArrayLike) -> float:
        r = np.asarray(r, dtype=np.float64).reshape(-1)
        return natural_map_error(r, self.velocity(r), self.mu, self.dim, self.q)


@dataclass(eq=False)
class GlobalProblem(_Described):
    """``M v = H r + f``, ``u = H' v + w`` with Coulomb's law (module docstring).

    Attributes
    ----------
    M : (ndof, ndof) csc
        Symmetric positive definite.
    H : (ndof, m nc) csc
    f : (ndof,)
    w : (m nc,)
    mu : (nc,)
    dim : int
    title, description, math_info, source : str
    """

    M: sp.csc_matrix
    H: sp.csc_matrix
    f: FloatArray
    w: FloatArray
    mu: FloatArray
    dim: int
    title: str = ""
    description: str = ""
    math_info: str = ""
    source: str = ""
    nc: int = field(init=False)
    ndof: int = field(init=False)

    kind = "global"

    def __post_init__(self) -> None:
        where = self._check_dimension()
        f = np.asarray(self.f, dtype=np.float64).reshape(-1)
        w = np.asarray(self.w, dtype=np.float64).reshape(-1)
        self.nc, self.mu = _check_common(self.dim, self.mu, w.size, where)
        self.ndof = f.size
        self.f = _vector("f", f, f.size, where)
        self.w = _vector("w", w, w.size, where)
        self.M = _matrix("M", self.M, (f.size, f.size), where)
        self.H = _matrix("H", self.H, (f.size, w.size), where)

    @cached_property
    def _mass_factor(self) -> tuple[FloatArray | None, sp.csc_matrix | None]:
        """``(diag M, None)`` for a diagonal M, else ``(None, L^-1)`` with ``M = L L'``."""
        return _mass_factor(self.M, self._where)

    @property
    def mass_is_diagonal(self) -> bool:
        return self._mass_factor[1] is None

    @cached_property
    def conic(self) -> ConicProblem:
        """The ConicProblem in the generalized velocities (``y = L'v`` if M is not diagonal)."""
        diag, Linv = self._mass_factor
        w = self.w.reshape(self.nc, self.dim)
        if diag is not None:
            mass, B, U = diag, self.H.T, self.f / diag
        else:
            assert Linv is not None
            mass = np.ones(self.ndof)
            B = (Linv @ self.H).T
            U = Linv @ self.f
        return ConicProblem(
            dim=self.dim,
            contact_dim=self.dim,
            mass=mass,
            H=sp.csr_matrix(B),
            D=w[:, 0].copy(),
            mu=self.mu,
            dt=1.0,
            U=np.asarray(U, dtype=np.float64),
            slip_offset=w[:, 1:].copy(),
        )

    def generalized_velocity(self, r: ArrayLike) -> FloatArray:
        """``v = M^-1 (H r + f)``."""
        c = self.conic
        y = c.velocity(np.asarray(r, dtype=np.float64))
        _, Linv = self._mass_factor
        return np.asarray(y if Linv is None else Linv.T @ y)

    def velocity(self, r: ArrayLike) -> FloatArray:
        """``u = H' v + w`` for ``v = M^-1 (H r + f)``."""
        v = self.generalized_velocity(r)
        return np.asarray(self.H.T @ v + self.w)

    def solution(self, p: ArrayLike) -> ExternalSolution:
        r = np.asarray(p, dtype=np.float64).reshape(-1).copy()
        v = self.generalized_velocity(r)
        return ExternalSolution(r=r, u=np.asarray(self.H.T @ v + self.w), v=v)

    def local(self) -> LocalProblem:
        """The condensed problem ``W = H' M^-1 H``, ``q = w + H' M^-1 f`` (densely, by one
        Cholesky factor, when M is not diagonal and has at most ``DENSE_MASS`` unknowns)."""
        diag = self.M.diagonal()
        if 0 < self.ndof <= DENSE_MASS and self.M.nnz > np.count_nonzero(diag):
            M = self.M.toarray()
            try:
                factor = sla.cho_factor(0.5 * (M + M.T), lower=True)
            except np.linalg.LinAlgError:
                raise ProblemError(
                    f"{self._where}: M is not positive definite (no Cholesky factor)"
                ) from None
            H = self.H.toarray()
            X = sla.cho_solve(factor, np.column_stack([H, self.f]))
            W = sp.csc_matrix(H.T @ X[:, :-1])
            q = self.w + H.T @ X[:, -1]
        else:
            c = self.conic
            W = sp.csc_matrix(c.H @ sp.diags(1.0 / c.mass) @ c.H.T)
            q = np.asarray(c.b)
        return LocalProblem(
            W=W,
            q=q,
            mu=self.mu.copy(),
            dim=self.dim,
            title=self.title,
            description=self.description,
            math_info=self.math_info,
            source=self.source,
            ndof=self.ndof,
        )

    @cached_property
    def q(self) -> FloatArray:
        """``q`` of the condensed problem, ``w + H' M^-1 f``."""
        return np.asarray(self.conic.b)

    def natural_map_error(self, r: ArrayLike) -> float:
        r = np.asarray(r, dtype=np.float64).reshape(-1)
        return natural_map_error(r, self.velocity(r), self.mu, self.dim, self.q)

    @classmethod
    def from_conic(
        cls, problem: ConicProblem, *, title: str = "", description: str = ""
    ) -> GlobalProblem:
        """The FCLib global form of a step problem: ``M = diag(mass)``, ``H = H_cocd'``,
        ``f = M U``, ``w = (D/dt, slip_offset)``.

        A frictionless problem (normal rows only) is written with zero tangential
        columns and ``mu = 0``, which is the same problem under Coulomb's law.
        """
        d, m, nc = problem.dim, problem.contact_dim, problem.nc
        H = problem.H.T.tocsc()
        w = problem.offset
        mu = problem.mu
        if m == 1:
            rows = sp.csr_matrix(
                (np.ones(nc), (d * np.arange(nc), np.arange(nc))), shape=(d * nc, nc)
            )
            H = sp.csc_matrix(H @ rows.T)
            w = rows @ w
            mu = np.zeros(nc)
        return cls(
            M=sp.diags(problem.mass).tocsc(),
            H=H,
            f=problem.mass * problem.U,
            w=np.asarray(w),
            mu=np.asarray(mu).copy(),
            dim=d,
            title=title,
            description=description,
        )


def natural_map_error(r: ArrayLike, u: ArrayLike, mu: ArrayLike, dim: int, q: ArrayLike) -> float:
    """``||r - P_K(r - û)|| / max(1, ||q||)`` with ``û = u + (mu |u_T|, 0)``.

    The unscaled natural map of Coulomb's law (DESIGN.md section 2),
    normalised by the problem's data only.
    """
    r = np.asarray(r, dtype=np.float64).reshape(-1, dim)
    u = np.asarray(u, dtype=np.float64).reshape(-1, dim).copy()
    mu = np.asarray(mu, dtype=np.float64)
    u[:, 0] += mu * np.linalg.norm(u[:, 1:], axis=1)
    F = r - project_coulomb(r - u, mu)
    return float(np.linalg.norm(F)) / max(1.0, float(np.linalg.norm(q)))


# -- factorisations -------------------------------------------------------------
def _mass_factor(M: sp.csc_matrix, where: str) -> tuple[FloatArray | None, sp.csc_matrix | None]:
    """``(diag, None)`` if ``M`` is diagonal, else ``(None, L^-1)`` with ``M = L L'``.

    ``L`` is block lower triangular: one dense Cholesky factor per connected
    block of ``M``'s graph (each rigid body's inertia block, each deformable
    body's mass matrix).
    """
    M = sp.csc_matrix(M)
    diag = M.diagonal()
    off = M - sp.diags(diag)
    off.eliminate_zeros()
    if off.nnz == 0:
        bad = np.flatnonzero(diag <= 0.0)
        if bad.size:
            raise ProblemError(
                f"{where}: M[{bad[0]}, {bad[0]}] is {diag[bad[0]]:g}: "
                "the mass matrix must be positive definite"
            )
        return diag, None
    asym = abs(M - M.T).max()
    if asym > 1e-10 * abs(M).max():
        raise ProblemError(f"{where}: M is not symmetric (max |M - M'| = {asym:.3g})")
    n = M.shape[0]
    if n <= DENSE_MASS:
        # One dense factor: L^-1 keeps M's blocks (the entries between blocks are exact
        # zeros), without a Python loop over them.
        dense = M.toarray()
        try:
            L = np.linalg.cholesky(0.5 * (dense + dense.T))
        except np.linalg.LinAlgError:
            raise ProblemError(
                f"{where}: M is not positive definite (no Cholesky factor)"
            ) from None
        return None, sp.csc_matrix(sla.solve_triangular(L, np.eye(n), lower=True))
    n_blocks, labels = connected_components(M, directed=False)
    order = np.argsort(labels, kind="stable")
    sizes = np.bincount(labels, minlength=n_blocks)
    if sizes.max() > MAX_MASS_BLOCK:
        raise ProblemError(
            f"{where}: M has a coupled block of {sizes.max()} unknowns; cocd factors blocks of "
            f"at most {MAX_MASS_BLOCK} densely"
        )
    rows: list[NDArray[np.intp]] = []
    cols: list[NDArray[np.intp]] = []
    vals: list[FloatArray] = []
    start = 0
    for size in _run_lengths(labels[order]):
        idx = order[start : start + size]
        start += size
        block = M[idx][:, idx].toarray()
        block = 0.5 * (block + block.T)
        try:
            L = np.linalg.cholesky(block)
        except np.linalg.LinAlgError:
            raise ProblemError(
                f"{where}: M is not positive definite (the block of unknowns "
                f"{idx[:5].tolist()}{'...' if size > 5 else ''} has no Cholesky factor)"
            ) from None
        Linv = sla.solve_triangular(L, np.eye(size), lower=True)
        ii, jj = np.nonzero(Linv)
        rows.append(idx[ii])
        cols.append(idx[jj])
        vals.append(Linv[ii, jj])
    Linv_all = sp.csc_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)
    )
    return None, Linv_all


def _run_lengths(sorted_labels: NDArray[np.int64]) -> list[int]:
    """Lengths of the runs of equal values in a sorted label array."""
    cuts = np.flatnonzero(np.diff(sorted_labels)) + 1
    bounds = np.concatenate([[0], cuts, [sorted_labels.size]])
    return np.diff(bounds).astype(int).tolist()


def _delassus_factor(W: sp.csc_matrix, where: str) -> tuple[sp.csr_matrix, float]:
    """``B`` with ``B B' = W + delta I`` (``delta`` 0 if ``W`` is positive definite).

    A sparse ``LDL'`` factorisation (QDLDL, approximate minimum degree order)
    of the symmetric part of ``W``. When a pivot is not positive (``W``
    singular, as with several contacts per pair of bodies, or indefinite by
    the rounding of a printed file), it is retried with a shift ``delta``
    from ``1e-13 max diag W`` up, by factors of sqrt(10), to ``1e-5 max diag
    W``; ``B`` is accepted only if ``B B'`` matches ``W + delta I`` to 1e-9 of
    the largest entry.
    """
    import qdldl

    n = W.shape[0]
    if n == 0:
        return sp.csr_matrix((0, 0)), 0.0
    scale = float(abs(W).max())
    sym = sp.csc_matrix(0.5 * (W + W.T))
    asym = float(abs(W - W.T).max()) if (W - W.T).nnz else 0.0
    if asym > 1e-5 * scale:
        raise ProblemError(
            f"{where}: W is not symmetric (max |W - W'| = {asym:.3g}, "
            f"{asym / scale:.2g} of its largest entry), so it has no factor H H' = W "
            "(no Delassus operator H M^-1 H')"
        )
    dmax = float(sym.diagonal().max())
    if not dmax > 0.0:
        raise ProblemError(f"{where}: W has no positive diagonal entry")
    for delta in (0.0, *(10.0 ** (k / 2) * dmax for k in range(-26, -9))):
        A = sp.csc_matrix(sym + delta * sp.identity(n, format="csc"))
        try:
            Lf, d, perm = qdldl.Solver(sp.triu(A, format="csc")).factors()
        except Exception:  # qdldl raises a bare error on a zero pivot
            continue
        if not np.all(d > 0.0):
            continue
        L = sp.csc_matrix(Lf) + sp.identity(n, format="csc")
        Bp = sp.csr_matrix(L @ sp.diags(np.sqrt(d)))  # rows in the permuted order
        inv = np.empty(n, dtype=np.int64)
        inv[perm] = np.arange(n)
        B = sp.csr_matrix(Bp[inv])
        err = abs(B @ B.T - A)
        if err.nnz == 0 or float(err.max()) <= 1e-9 * scale:
            return B, delta
    raise ProblemError(
        f"{where}: W could not be factored as a positive semi-definite matrix "
        "(a pivot stays negative with a diagonal shift of 1e-5 of its largest entry): "
        "is it a Delassus operator?"
    )
