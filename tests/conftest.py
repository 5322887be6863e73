"""Shared fixtures.

Every solve made in the test suite goes through :func:`checked_solve`, which
asserts that the impulses lie in their Coulomb cones and, for every answer a
backend reports ``optimal``, that its ``ccp_residual`` (``coulomb_residual`` for
the non-convex backends) is at most ``10 tol``
(unless a test marks itself ``unchecked_solutions``, e.g. to provoke a
failure). ``inaccurate`` answers, and faceted approximations (which solve
another problem, ``extras["approximation"]``), are checked for cone membership
only; their accuracy is asserted by the tests that make them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

import solvers
from cocd.io.problems import LocalProblem
from cocd.residuals import ccp_residual, coulomb_residual

CONE_SLACK = 1e-6


def assert_answer_ok(problem, solution, tol):
    p = solution.p
    assert np.all(np.isfinite(p)) and np.all(np.isfinite(solution.u))
    if problem.nc == 0:
        return
    assert np.all(p[:, 0] >= 0.0), f"negative normal impulse {p[:, 0].min()}"
    if problem.contact_dim > 1:
        pt = np.linalg.norm(p[:, 1:], axis=1)
        excess = pt - problem.mu * p[:, 0] * (1.0 + CONE_SLACK)
        assert np.all(excess <= 0.0), f"impulse outside its Coulomb cone by {excess.max():g}"
    if solution.status != "optimal" or "approximation" in solution.extras:
        return
    try:
        convex = solvers.get(solution.solver).convex
    except solvers.SolverNotFound:  # a test double registered for one test
        convex = True
    if convex:
        r = ccp_residual(problem, p)
        assert r <= 10 * tol, f"{solution.solver}: ccp_residual {r:.3g} > 10 tol = {10 * tol:g}"
    else:
        r = coulomb_residual(problem, p)
        assert r <= 10 * tol, f"{solution.solver}: coulomb_residual {r:.3g} > 10 tol = {10 * tol:g}"


@pytest.fixture(autouse=True)
def checked_solutions(request, monkeypatch):
    if request.node.get_closest_marker("unchecked_solutions"):
        yield []
        return
    real_solve = solvers.solve
    seen = []

    def checked_solve(problem, solver="clarabel", tol=1e-8, *args, **kwargs):
        solution = real_solve(problem, solver, tol, *args, **kwargs)
        if solution.found:
            assert_answer_ok(problem, solution, tol)
        seen.append(solution)
        return solution

    monkeypatch.setattr(solvers, "solve", checked_solve)
    yield seen


def pytest_configure(config):
    config.addinivalue_line(
        "markers", "unchecked_solutions: do not assert cone membership and ccp <= 10 tol"
    )


def normal_impulses_from_top(scene, contacts, p):
    """Normal impulses of the touching contacts of a vertical stack, from the top one down.

    A contact's height is the mid-height of its two grains, 0 for a wall.
    """
    z = scene.positions[:, -1]
    wall = contacts.j < 0
    height = np.where(wall, 0.0, 0.5 * (z[contacts.i] + z[np.where(wall, 0, contacts.j)]))
    touching = contacts.gap < 1e-9
    return p[touching, 0][np.argsort(-height[touching])]


def jittered_lattice(rng, shape, radius, sizes, spacing, jitter):
    """Grains on a square (cubic) lattice of ``shape``: lattice indices ``(n, d)``,
    radii ``radius * U(sizes)`` and centres ``spacing * radius * index`` moved by
    ``radius * U(-jitter, jitter)``, drawn from ``rng`` in that order."""
    dim = len(shape)
    idx = np.indices(shape).reshape(dim, -1).T
    n = idx.shape[0]
    radii = radius * rng.uniform(*sizes, n)
    x = spacing * radius * idx + radius * rng.uniform(-jitter, jitter, (n, dim))
    return idx, radii, x


def run_study(study, out, **settings):
    """Run a registered study into ``out``, its progress lines kept: ``(out, table, lines)``."""
    lines: list[str] = []
    table = study(out=out, progress=lines.append, **settings)
    return out, table, lines


#: The external problem files beside the project (``../shared/data/external``), optional.
EXTERNAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "external"


def external(name: str) -> Path:
    """The external problem file ``name``; the test is skipped when it is not here."""
    path = EXTERNAL / name
    if not path.is_file():
        pytest.skip(f"{path} is not here (the external problems are optional)")
    return path


# -- local problems (tests of the local forms) ------------------------------------------
def random_local(nc: int, dim: int, seed: int, skew: float = 0.0, mu: float = 0.3):
    """``u = W r + q`` with ``W = B B' + I/2`` (positive definite), plus ``skew`` times a
    skew-symmetric part of the same size; ``q`` of mixed signs (some contacts separate)."""
    rng = np.random.default_rng(seed)
    n = nc * dim
    B = rng.normal(size=(n, n // 2)) / np.sqrt(n)
    W = B @ B.T + 0.5 * np.eye(n)
    if skew:
        A = rng.normal(size=(n, n)) / np.sqrt(n)
        W = W + skew * (A - A.T)
    q = rng.normal(size=(nc, dim))
    q[:, 0] -= 0.5  # most contacts closing
    return LocalProblem(W=sp.csc_matrix(W), q=q.reshape(-1), mu=np.full(nc, mu), dim=dim)


def assert_coulomb_law(r: np.ndarray, u: np.ndarray, mu: np.ndarray, tol: float) -> None:
    """Coulomb's law contact by contact: ``r`` in its cone, De Saxcé's ``û`` in the dual
    cone (``u_N >= 0``), ``r . û = 0``; a sticking contact has ``u = 0``, a sliding one
    ``u_N = 0`` and ``r_T`` against ``u_T``."""
    scale = max(1.0, float(np.abs(r).max()), float(np.abs(u).max()))
    eps = tol * scale
    for a in range(len(mu)):
        rn, rt, un, ut = r[a, 0], r[a, 1:], u[a, 0], u[a, 1:]
        nrt, nut = np.linalg.norm(rt), np.linalg.norm(ut)
        assert rn >= -eps and nrt <= mu[a] * rn + eps, (a, r[a])
        assert un >= -eps, (a, u[a])
        assert abs(rn * (un + mu[a] * nut) + rt @ ut) <= eps * scale, (a, r[a], u[a])
        if rn <= eps:
            continue  # separated: r = 0, u_N >= 0
        if nrt < mu[a] * rn - eps:  # sticking
            assert np.abs(u[a]).max() <= eps, (a, r[a], u[a])
        else:  # sliding: no normal velocity, friction against the slip
            assert abs(un) <= eps, (a, u[a])
            if nut > eps:
                assert np.allclose(rt / nrt, -ut / nut, atol=1e-5), (a, r[a], u[a])
