"""FCLib HDF5 problems: exact round trips, the published files, conversions, bad files."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest
import scipy.sparse as sp
from conftest import external

from cocd.errors import ProblemError, ProblemFileError
from cocd.io import read_problem, write_problem
from cocd.io.fclib import read_fclib, read_fclib_solution, write_fclib
from cocd.io.problems import GlobalProblem, LocalProblem, natural_map_error

HDF5_FILES = [
    "spheres-in-a-box-98-i10000-256-10.hdf5",
    "LMGC_100_PR_PerioBox-i00361-60-03000.hdf5",
    "Capsules-i125-1213.hdf5",
]


def random_global(dim=3, nbodies=6, nc=8, seed=0, diagonal=True) -> GlobalProblem:
    """Rigid bodies with 6 (3D) or 3 (2D) unknowns; full inertia blocks if not ``diagonal``."""
    rng = np.random.default_rng(seed)
    per = 6 if dim == 3 else 3
    ndof = per * nbodies
    if diagonal:
        M = sp.diags(rng.uniform(0.5, 2.0, ndof))
    else:
        blocks = []
        for _ in range(nbodies):
            a = rng.normal(size=(per, per))
            blocks.append(a @ a.T + per * np.eye(per))
        M = sp.block_diag(blocks)
    H = sp.random(ndof, dim * nc, density=0.3, random_state=seed) + sp.eye(ndof, dim * nc)
    return GlobalProblem(
        M=sp.csc_matrix(M),
        H=sp.csc_matrix(H),
        f=rng.normal(size=ndof),
        w=rng.normal(size=dim * nc),
        mu=rng.uniform(0.1, 0.8, nc),
        dim=dim,
        title="random",
        description="a random global problem",
    )


def same_sparse(a, b) -> bool:
    a, b = sp.csc_matrix(a), sp.csc_matrix(b)
    return (
        a.shape == b.shape
        and np.array_equal(a.indptr, b.indptr)
        and np.array_equal(a.indices, b.indices)
        and np.array_equal(a.data, b.data)
    )


# -- round trips ------------------------------------------------------------------
@pytest.mark.parametrize("diagonal", [True, False])
def test_global_round_trip_is_exact(tmp_path, diagonal):
    g = random_global(diagonal=diagonal)
    path = write_problem(tmp_path / "g.hdf5", g)
    back = read_problem(path)
    assert isinstance(back, GlobalProblem)
    for name in ("M", "H"):
        assert same_sparse(getattr(g, name), getattr(back, name)), name
    for name in ("f", "w", "mu"):
        assert np.array_equal(getattr(g, name), getattr(back, name)), name
    assert back.dim == g.dim and back.title == "random"
    assert back.description == "a random global problem"
    # A second write of what was read gives the same bytes of data again.
    again = read_problem(write_problem(tmp_path / "g2.hdf5", back))
    assert same_sparse(again.H, g.H) and np.array_equal(again.f, g.f)


def test_local_round_trip_is_exact_with_solution(tmp_path):
    local = random_global(dim=2, diagonal=False).local()
    local.ndof = 18
    r = np.arange(local.q.size, dtype=float)
    sol = local.solution(r)
    path = write_fclib(tmp_path / "l.hdf5", local, solution=sol)
    back = read_fclib(path)
    assert isinstance(back, LocalProblem)
    assert same_sparse(back.W, local.W)
    assert np.array_equal(back.q, local.q) and np.array_equal(back.mu, local.mu)
    assert back.ndof == 18
    stored = read_fclib_solution(path)
    assert stored is not None and np.array_equal(stored.r, r)
    assert np.array_equal(stored.u, local.W @ r + local.q) and stored.v is None
    assert not (tmp_path / "l.hdf5.part").exists()


@pytest.mark.parametrize("name", HDF5_FILES)
def test_published_file_round_trip_is_exact(tmp_path, name):
    p = read_fclib(external(name))
    back = read_fclib(write_fclib(tmp_path / name, p))
    if isinstance(p, LocalProblem):
        assert same_sparse(p.W, back.W)
        assert np.array_equal(p.q, back.q)
    else:
        assert same_sparse(p.M, back.M) and same_sparse(p.H, back.H)
        assert np.array_equal(p.f, back.f) and np.array_equal(p.w, back.w)
    assert np.array_equal(p.mu, back.mu)


# -- the published files ---------------------------------------------------------
def test_published_files_load_with_their_sizes():
    spheres = read_problem(external(HDF5_FILES[0]))
    assert isinstance(spheres, GlobalProblem)
    assert (spheres.dim, spheres.nc, spheres.ndof) == (3, 256, 588)
    assert np.all(spheres.mu == 0.1) and spheres.mass_is_diagonal
    perio = read_problem(external(HDF5_FILES[1]))
    assert isinstance(perio, LocalProblem) and (perio.dim, perio.nc) == (3, 60)
    assert perio.ndof == 606
    capsules = read_problem(external(HDF5_FILES[2]))
    assert isinstance(capsules, LocalProblem) and (capsules.dim, capsules.nc) == (3, 286)
    assert np.all(capsules.mu == 0.7)


def test_condensed_global_file_is_symmetric_psd():
    g = read_problem(external(HDF5_FILES[0]))
    local = g.local()
    W = local.W.toarray()
    scale = np.abs(W).max()
    assert np.abs(W - W.T).max() <= 1e-14 * scale
    assert np.linalg.eigvalsh(W).min() >= -1e-12 * scale
    # W = H' M^-1 H and q = w + H' M^-1 f, computed independently.
    Minv = np.diag(1.0 / g.M.diagonal())
    H = g.H.toarray()
    assert np.allclose(W, H.T @ Minv @ H, rtol=0, atol=1e-12 * scale)
    assert np.allclose(local.q, g.w + H.T @ Minv @ g.f, rtol=1e-12, atol=1e-15)


def test_non_symmetric_local_file_is_refused_by_the_backends_with_a_reason():
    capsules = read_problem(external(HDF5_FILES[2]))
    assert capsules.symmetry_error() > 1e-4  # as written by Siconos (Bullet contacts)
    with pytest.raises(ProblemError, match="W is not symmetric"):
        capsules.conic  # noqa: B018


@pytest.mark.parametrize(
    ("diagonal", "message"),
    [
        ([-1.0, 1.0, 1.0], r"W\[0, 0\] is -1: a Delassus operator has no negative diagonal"),
        ([0.0, 0.0, 0.0], "contact 0's block of W has a zero diagonal"),
    ],
)
def test_a_local_problem_whose_w_cannot_be_a_delassus_operator_is_refused(diagonal, message):
    # Such a W would scale its contacts' residuals by 0: any answer would look exact.
    # It is read (and can be inspected), but not solved or judged.
    from cocd.external import conic_of, describe, local_data, local_residuals

    problem = LocalProblem(sp.diags(diagonal), np.array([-1.0, 0.0, 0.0]), np.array([0.3]), 3)
    uses = (
        lambda: problem.conic,
        lambda: conic_of(problem, "clarabel"),  # not sent to the local forms: they refuse it too
        lambda: local_data(problem),
        lambda: local_residuals(problem, np.zeros(3)),
    )
    for use in uses:
        with pytest.raises(ProblemError, match=message):
            use()
    assert describe(problem)["solvable"].startswith("no: ")


# -- conversions ------------------------------------------------------------------
@pytest.mark.parametrize("diagonal", [True, False])
@pytest.mark.parametrize("dim", [2, 3])
def test_global_conic_has_the_condensed_operator(dim, diagonal):
    g = random_global(dim=dim, diagonal=diagonal, seed=3)
    c = g.conic
    Minv = np.linalg.inv(g.M.toarray())
    H = g.H.toarray()
    W = H.T @ Minv @ H
    q = g.w + H.T @ Minv @ g.f
    assert np.allclose(c.W.toarray(), W, atol=1e-12 * np.abs(W).max())
    assert np.allclose(c.b, q, atol=1e-12 * np.abs(q).max())
    r = np.random.default_rng(1).normal(size=H.shape[1])
    v = g.generalized_velocity(r)
    assert np.allclose(g.M @ v, H @ r + g.f, atol=1e-12 * np.abs(H @ r + g.f).max())


def test_local_conic_factors_w_exactly_or_with_a_tiny_shift():
    # A singular W (3 contacts on 2 unknowns), as with several contacts per body pair.
    rng = np.random.default_rng(2)
    B = rng.normal(size=(6, 4))
    W = B @ B.T
    local = LocalProblem(W=sp.csc_matrix(W), q=rng.normal(size=6), mu=np.full(3, 0.3), dim=2)
    c = local.conic
    assert 0.0 < local.shift <= 1e-12 * np.abs(W).max()
    assert np.allclose(c.W.toarray(), W + local.shift * np.eye(6), rtol=0, atol=1e-12)
    assert np.allclose(c.b, local.q)
    pd_local = LocalProblem(W=sp.csc_matrix(W + np.eye(6)), q=local.q, mu=local.mu, dim=2)
    assert pd_local.shift == 0.0
    assert np.allclose(pd_local.conic.W.toarray(), W + np.eye(6), rtol=0, atol=1e-12)


def test_natural_map_error_is_zero_at_the_coulomb_solutions():
    # One 2D contact, W = I: q = (-1, 2) slides (r = (1, -mu)), q = (-1, 0.1) sticks.
    mu = np.array([0.5])
    for q, r in [((-1.0, 2.0), (1.0, -0.5)), ((-1.0, 0.1), (1.0, -0.1))]:
        local = LocalProblem(W=sp.identity(2), q=np.array(q), mu=mu, dim=2)
        assert local.natural_map_error(np.array(r)) == pytest.approx(0.0, abs=1e-15)
        assert local.natural_map_error(np.array(r) * 1.1) > 1e-2
    # Normalised by max(1, ||q||), not by the answer.
    assert natural_map_error([2.0, 0.0], [0.0, 0.0], [0.5], 2, [0.1, 0.0]) == pytest.approx(0.0)
    assert natural_map_error([0.0, 0.0], [-4.0, 0.0], [0.5], 2, [3.0, 4.0]) == pytest.approx(
        4.0 / 5.0
    )


# -- bad files -------------------------------------------------------------------
def _good_local(path: Path) -> Path:
    local = LocalProblem(
        W=sp.csc_matrix(np.eye(4) * 2.0),
        q=np.array([-1.0, 0.1, -1.0, 0.0]),
        mu=np.array([0.3, 0.3]),
        dim=2,
    )
    return write_fclib(path, local)


def _edit(path: Path, change) -> Path:
    with h5py.File(path, "r+") as fh:
        change(fh)
    return path


def _replace(fh, name, value):
    del fh[name]
    fh[name] = value


BAD_EDITS = {
    "NaN in q": (lambda fh: _replace(fh, "fclib_local/vectors/q", [np.nan, 0, 0, 0]), "q\\[0\\]"),
    "q too short": (
        lambda fh: _replace(fh, "fclib_local/vectors/q", [1.0, 2.0]),
        "q has 2 entries, expected 4",
    ),
    "mu wrong size": (
        lambda fh: _replace(fh, "fclib_local/vectors/mu", [0.3]),
        "mu has 1 entries, expected 2",
    ),
    "negative mu": (
        lambda fh: _replace(fh, "fclib_local/vectors/mu", [0.3, -1.0]),
        "friction must be >= 0",
    ),
    "dimension 4": (lambda fh: _replace(fh, "fclib_local/spacedim", [4]), "dimension must be 2"),
    "W not square": (lambda fh: _replace(fh, "fclib_local/W/n", [3]), "pointers p have 5"),
    "pointer decreasing": (
        lambda fh: _replace(fh, "fclib_local/W/p", np.array([0, 2, 1, 3, 4], dtype=np.int32)),
        "never decrease",
    ),
    "row index out of range": (
        lambda fh: _replace(fh, "fclib_local/W/i", np.array([0, 1, 2, 9], dtype=np.int32)),
        "row index 9 outside",
    ),
    "bad nz": (lambda fh: _replace(fh, "fclib_local/W/nz", [-7]), "nz = -7"),
    "missing q": (lambda fh: fh.__delitem__("fclib_local/vectors/q"), "missing dataset"),
    "missing W": (lambda fh: fh.__delitem__("fclib_local/W"), "missing matrix group 'W'"),
    "wrong group name": (lambda fh: fh.move("fclib_local", "fclib_locale"), "found fclib_locale"),
    "text in q": (lambda fh: _replace(fh, "fclib_local/vectors/q", b"abc"), "expected numbers"),
}


@pytest.mark.parametrize("case", sorted(BAD_EDITS))
def test_malformed_hdf5_names_the_file_and_the_problem(tmp_path, case):
    change, match = BAD_EDITS[case]
    path = _edit(_good_local(tmp_path / "bad.hdf5"), change)
    with pytest.raises(ProblemFileError, match=match) as err:
        read_problem(path)
    assert str(path) in str(err.value)


def test_truncated_and_foreign_files_are_clear_errors(tmp_path):
    good = _good_local(tmp_path / "good.hdf5")
    data = good.read_bytes()
    cut = tmp_path / "cut.hdf5"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(ProblemFileError, match=r"cut\.hdf5"):
        read_problem(cut)
    other = tmp_path / "other.hdf5"
    with h5py.File(other, "w") as fh:
        fh["x"] = [1, 2, 3]
    with pytest.raises(ProblemFileError, match="found x"):
        read_problem(other)
    with pytest.raises(ProblemFileError, match="no such file"):
        read_problem(tmp_path / "missing.hdf5")
    with pytest.raises(ProblemFileError, match="is a folder"):
        read_problem(tmp_path)


def test_global_with_equality_constraints_is_refused(tmp_path):
    path = write_fclib(tmp_path / "g.hdf5", random_global())
    with h5py.File(path, "r+") as fh:
        fh["fclib_global/vectors/b"] = [1.0, 2.0]
    with pytest.raises(ProblemFileError, match="equality constraints"):
        read_problem(path)
