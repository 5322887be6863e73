"""Siconos numerics text files: the real test data, exact round trips of the
three storages written here in Siconos's layout, and malformed files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from cocd.errors import ProblemError, ProblemFileError
from cocd.io.problems import GlobalProblem, LocalProblem
from cocd.io.siconos import read_siconos

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "external"


def data_file(name: str) -> Path:
    if not DATA.is_dir():
        pytest.skip(f"external data folder {DATA} is absent")
    path = DATA / name
    if not path.is_file():
        pytest.skip(f"external data file {path} is absent")
    return path


# -- helpers ----------------------------------------------------------------------
def sym_error(A: sp.spmatrix) -> float:
    A = sp.csc_matrix(A)
    D = A - A.T
    return float(abs(D).max()) / float(abs(A).max()) if D.nnz else 0.0


def min_eigenvalue(A: sp.spmatrix) -> float:
    """Smallest eigenvalue of the symmetric part, per connected block."""
    S = sp.csr_matrix(0.5 * (A + A.T))
    _, labels = connected_components(S, directed=False)
    lo = np.inf
    for lab in np.unique(labels):
        idx = np.flatnonzero(labels == lab)
        lo = min(lo, float(np.linalg.eigvalsh(S[idx][:, idx].toarray())[0]))
    return lo


def fmt(x: float) -> str:
    return f"{x:32.24e}"


def vec(v) -> str:
    return " ".join(fmt(x) for x in v) + " \n"


def header(dim: int, nc: int) -> str:
    return f"{dim}\n{nc}\n"


def dense_text(A: np.ndarray) -> str:
    """NM_write_in_file, storage 0: sizes twice, values column-major."""
    m, n = A.shape
    out = [f"0\n{m}\n{n}\n{m}\t{n}\n"]
    flat = A.reshape(-1, order="F")
    for i, x in enumerate(flat):
        out.append(fmt(x) + " ")
        if (i + 1) % n == 0:
            out.append("\n")
    return "".join(out)


def sbm_text(size0: int, size1: int, rsizes: list[int], csizes: list[int], blocks: dict) -> str:
    """NM_write_in_file, storage 1 (SBM_write_in_file); ``blocks[(I, J)]`` dense."""
    cum0, cum1 = np.cumsum(rsizes), np.cumsum(csizes)
    keys = sorted(blocks)
    out = [f"1\n{size0}\n{size1}\n{len(keys)}\n{len(rsizes)}\n{len(csizes)}\n"]
    out.append("".join(f"{c}\t" for c in cum0) + "\n")
    out.append("".join(f"{c}\t" for c in cum1) + "\n")
    ptr = [0]
    for i in range(len(rsizes)):
        ptr.append(ptr[-1] + sum(1 for key in keys if key[0] == i))
    out.append(f"{len(ptr)}\n{len(keys)}\n")
    out.append("".join(f"{p}\t" for p in ptr) + "\n")
    out.append("".join(f"{key[1]}\t" for key in keys) + "\n")
    for number, key in enumerate(keys):
        out.append(f"{number}\n")
        out.extend(f"{fmt(x)}\n" for x in np.asarray(blocks[key]).reshape(-1, order="F"))
    return "".join(out)


CS_VERSION = "CSparse Version 3.1.9, May 4, 2016.  Copyright (c) Timothy A. Davis, 2006-2016\n"


def cs_triplet_text(m: int, n: int, rows, cols, vals) -> str:
    """NM_write_in_file, storage 2, origin 1: CSparse's triplet dump (%g)."""
    nz = len(vals)
    out = [f"2\n{m}\n{n}\n1\n", CS_VERSION, f"triplet: {m}-by-{n}, nzmax: {nz} nnz: {nz}\n"]
    out.extend(f"    {i} {j} : {x:g}\n" for i, j, x in zip(rows, cols, vals, strict=True))
    return "".join(out)


def cs_compressed_text(A: np.ndarray, origin: int = 2) -> str:
    """NM_write_in_file, storage 2, origin 2: CSparse's compressed-column dump (%g)."""
    C = sp.csc_matrix(A)
    C.sort_indices()
    m, n = C.shape
    norm = float(abs(C).sum(axis=0).max()) if C.nnz else 0.0
    out = [f"2\n{m}\n{n}\n{origin}\n", CS_VERSION]
    out.append(f"{m}-by-{n}, nzmax: {C.nnz} nnz: {C.nnz}, 1-norm: {norm:g}\n")
    for j in range(n):
        a, b = C.indptr[j], C.indptr[j + 1]
        out.append(f"    col {j} : locations {a} to {b - 1}\n")
        out.extend(f"      {C.indices[p]} : {C.data[p]:g}\n" for p in range(a, b))
    return "".join(out)


def write(tmp_path: Path, text: str | bytes, name: str = "problem.dat") -> Path:
    path = tmp_path / name
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text)
    return path


def bad_file(tmp_path: Path, text: str | bytes, match: str | None, **kw) -> ProblemFileError:
    path = write(tmp_path, text)
    with pytest.raises(ProblemFileError, match=match) as info:
        read_siconos(path, **kw)
    assert str(info.value).startswith(f"{path}: "), str(info.value)
    return info.value


# -- the real files ---------------------------------------------------------------
# name: (kind, dim, nc, ndof, storage of the first matrix)
REAL = {
    "fc2d_granularflowonwall_00667_00000.dat": ("local", 2, 667, None, "compressed-column"),
    "fc2d_granularflowonwall_02020_00213.dat": ("local", 2, 2020, None, "compressed-column"),
    "gfc2d_granularflowonwall_00069_00350.dat": ("global", 2, 69, 900, "triplet"),
    "Capsules-i100-1090.dat": ("local", 3, 276, None, "sparse-block"),
    "BoxesStack1-i100000-32.hdf5.dat": ("local", 3, 52, None, "sparse-block"),
    "NESpheres_10_1.dat": ("local", 3, 9, None, "dense"),
    "FC3D_Example1.dat": ("local", 3, 3, None, "dense"),
    "GFC3D_TwoRods1.dat": ("global", 3, 3, 54, "sparse-block"),
}


@pytest.mark.parametrize("name", sorted(REAL))
def test_real_file_loads(name):
    kind, dim, nc, ndof, storage = REAL[name]
    path = data_file(name)
    P = read_siconos(path)
    assert P.kind == kind
    assert P.dim == dim and P.nc == nc
    assert P.title == path.stem and P.source == str(path)
    assert storage in P.description
    assert P.mu.shape == (nc,)
    assert np.all((P.mu >= 0.0) & (P.mu <= 1.0))
    if kind == "local":
        assert isinstance(P, LocalProblem)
        assert isinstance(P.W, sp.csc_matrix) and P.W.dtype == np.float64
        assert P.W.shape == (dim * nc, dim * nc) and P.q.shape == (dim * nc,)
        assert np.all(P.W.diagonal() > 0.0)
    else:
        assert isinstance(P, GlobalProblem)
        assert isinstance(P.M, sp.csc_matrix) and isinstance(P.H, sp.csc_matrix)
        assert P.M.dtype == np.float64 and P.H.dtype == np.float64
        assert P.ndof == ndof
        assert P.M.shape == (ndof, ndof) and P.H.shape == (ndof, dim * nc)
        assert P.f.shape == (ndof,) and P.w.shape == (dim * nc,)
    # The same file with its kind given explicitly, and with the wrong one.
    assert read_siconos(path, kind=kind).kind == kind
    with pytest.raises(ProblemFileError, match=str(path)):
        read_siconos(path, kind="global" if kind == "local" else "local")


@pytest.mark.parametrize(
    "name", ["fc2d_granularflowonwall_00667_00000.dat", "fc2d_granularflowonwall_02020_00213.dat"]
)
def test_granular_2d_delassus_is_symmetric_psd(name):
    P = read_siconos(data_file(name))
    # Printed with %g (6 significant digits): symmetric to that precision.
    assert sym_error(P.W) <= 1e-6
    scale = float(abs(P.W).max())
    assert min_eigenvalue(P.W) >= -1e-6 * scale


def test_granular_2d_values_from_the_dump():
    P = read_siconos(data_file("fc2d_granularflowonwall_00667_00000.dat"))
    # "col 0 : locations 0 to 1 / 0 : 856.713 / 649 : -454.43", "col 1 ... 1 : 2559.98"
    assert P.W[0, 0] == 856.713 and P.W[649, 0] == -454.43 and P.W[1, 1] == 2559.98
    assert P.W.nnz == 3822
    np.testing.assert_array_equal(P.mu, 0.5)
    # 8 entries of the later step are printed as 0 and are dropped.
    Q = read_siconos(data_file("fc2d_granularflowonwall_02020_00213.dat"))
    assert Q.W.nnz == 20616 - 8
    assert Q.W[0, 0] == 814.288 and Q.W[1144, 0] == -416.766


def test_sparse_block_3d_files():
    boxes = read_siconos(data_file("BoxesStack1-i100000-32.hdf5.dat"))
    assert sym_error(boxes.W) <= 1e-12
    assert min_eigenvalue(boxes.W) >= -1e-9 * float(abs(boxes.W).max())
    np.testing.assert_array_equal(boxes.mu, 0.7)
    # Capsules: W is not symmetric in the data itself (its diagonal 3x3 blocks
    # differ from their transposes by ~1e-3 of the largest entry, whatever the
    # block layout; the FCLib Capsules-i125-1213.hdf5 file does the same).
    caps = read_siconos(data_file("Capsules-i100-1090.dat"))
    err = sym_error(caps.W)
    assert 1e-5 < err < 1e-2
    assert min_eigenvalue(caps.W) >= -1e-9 * float(abs(caps.W).max())


def test_dense_3d_files():
    ex = read_siconos(data_file("FC3D_Example1.dat"))
    np.testing.assert_array_equal(ex.W.toarray(), np.eye(9))
    np.testing.assert_array_equal(ex.q, np.tile([-1.0, 1.0, 3.0], 3))
    np.testing.assert_array_equal(ex.mu, 0.1)
    assert "isComplete flag 0" in ex.description  # the old writers' last integer
    ne = read_siconos(data_file("NESpheres_10_1.dat"))
    assert sym_error(ne.W) <= 1e-12
    assert min_eigenvalue(ne.W) > 0.0
    np.testing.assert_array_equal(ne.mu, 0.8)


@pytest.mark.parametrize("name", ["gfc2d_granularflowonwall_00069_00350.dat", "GFC3D_TwoRods1.dat"])
def test_global_files_mass_spd_and_condensed_psd(name):
    P = read_siconos(data_file(name))
    M = P.M.toarray()
    assert np.array_equal(M, M.T)
    np.linalg.cholesky(M)  # positive definite
    H = P.H.toarray()
    W = H.T @ np.linalg.solve(M, H)
    assert np.abs(W - W.T).max() <= 1e-10 * np.abs(W).max()
    assert np.linalg.eigvalsh(0.5 * (W + W.T))[0] >= -1e-9 * np.abs(W).max()


def test_global_values_and_block_layout():
    g2 = read_siconos(data_file("gfc2d_granularflowonwall_00069_00350.dat"))
    assert "triplet" in g2.description and "compressed-column" in g2.description
    assert g2.M.nnz == 900 and g2.H.nnz == 724
    assert g2.M[0, 0] == 0.00150187 and g2.M[2, 2] == 1.46527e-10
    assert g2.H[343, 0] == -1.0 and g2.H[344, 0] == -1.40662e-05
    rods = read_siconos(data_file("GFC3D_TwoRods1.dat"))
    assert "isComplete flag 1" in rods.description
    assert rods.M[0, 0] == 1.386806
    # H's 27 x 3 blocks are column-major: each contact direction acts on the
    # two nodes (3 dof each) around the contact point on each rod.
    rows = np.flatnonzero(rods.H[:, [0]].toarray()[:, 0])
    np.testing.assert_array_equal(rows, [18, 19, 20, 21, 22, 23, 48, 49, 50, 51, 52, 53])
    a, b = rods.H[18:21, [0]].toarray()[:, 0], rods.H[21:24, [0]].toarray()[:, 0]
    np.testing.assert_allclose(np.cross(a, b), 0.0, atol=1e-6)  # one direction, two weights


# -- round trips of the three storages ----------------------------------------------
def test_dense_round_trip(tmp_path):
    A = np.array(
        [
            [4.0, -1.0, 0.5, 0.0],
            [-2.0, 3.0, 0.0, 0.25],
            [0.1, 0.0, 5.0, -1.5],
            [0.0, 0.3, -1.0, 2.0],
        ]
    )
    q = np.array([-1.0, 0.2, 1e-17, 3.0])
    mu = np.array([0.3, 1.0 / 3.0])
    P = read_siconos(write(tmp_path, header(2, 2) + dense_text(A) + vec(q) + vec(mu)))
    assert P.kind == "local" and P.dim == 2 and P.nc == 2
    np.testing.assert_array_equal(P.W.toarray(), A)  # column-major, not transposed
    np.testing.assert_array_equal(P.q, q)
    np.testing.assert_array_equal(P.mu, mu)
    assert P.description == "Siconos local 2D problem, W dense"


def test_sparse_block_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    blocks = {key: rng.standard_normal((3, 3)) for key in [(0, 0), (0, 2), (1, 1), (2, 0), (2, 2)]}
    W = np.zeros((9, 9))
    for (i, j), B in blocks.items():
        W[3 * i : 3 * i + 3, 3 * j : 3 * j + 3] = B
    q, mu = rng.standard_normal(9), np.array([0.1, 0.5, 0.9])
    text = header(3, 3) + sbm_text(9, 9, [3, 3, 3], [3, 3, 3], blocks) + vec(q) + vec(mu)
    P = read_siconos(write(tmp_path, text))
    assert P.kind == "local" and "sparse-block" in P.description
    np.testing.assert_array_equal(P.W.toarray(), W)
    np.testing.assert_array_equal(P.q, q)
    np.testing.assert_array_equal(P.mu, mu)


def test_sparse_block_global_with_rectangular_blocks(tmp_path):
    # M: blocks of 2 and 3 dof; H: 5 x 3 in two 2x3 / 3x3 blocks (column-major).
    M0 = np.array([[2.0, 0.5], [0.5, 1.0]])
    M1 = np.diag([1.0, 2.0, 3.0]) + 0.25
    H0 = np.arange(1.0, 7.0).reshape(2, 3)
    H1 = -np.arange(1.0, 10.0).reshape(3, 3)
    M = np.zeros((5, 5))
    M[:2, :2], M[2:, 2:] = M0, M1
    H = np.vstack([H0, H1])
    f, w, mu = np.array([1.0, -2.0, 0.5, 0.0, 3.0]), np.array([0.1, -0.2, 0.3]), np.array([0.6])
    text = (
        header(3, 1)
        + sbm_text(5, 5, [2, 3], [2, 3], {(0, 0): M0, (1, 1): M1})
        + sbm_text(5, 3, [2, 3], [3], {(0, 0): H0, (1, 0): H1})
        + vec(f)
        + vec(w)
        + vec(mu)
    )
    P = read_siconos(write(tmp_path, text))
    assert P.kind == "global" and P.ndof == 5 and P.nc == 1
    np.testing.assert_array_equal(P.M.toarray(), M)
    np.testing.assert_array_equal(P.H.toarray(), H)
    np.testing.assert_array_equal(P.f, f)
    np.testing.assert_array_equal(P.w, w)
    np.testing.assert_array_equal(P.mu, mu)


def test_empty_sparse_block_matrix(tmp_path):
    text = header(2, 1) + "1\n2\n2\n0\n" + vec([1.0, 2.0]) + vec([0.2])
    P = read_siconos(write(tmp_path, text))
    assert P.W.shape == (2, 2) and P.W.nnz == 0


def test_csparse_round_trips(tmp_path):
    # Values exact in %g: 6 significant digits at most.
    M_rows, M_cols = [0, 1, 2, 3, 0, 0], [0, 1, 2, 3, 1, 1]
    M_vals = [2.5, 1.25, 3e-10, 4.0, 0.125, 0.125]  # (0, 1) twice: CSparse adds them
    M = np.zeros((4, 4))
    for i, j, x in zip(M_rows, M_cols, M_vals, strict=True):
        M[i, j] += x
    M[1, 0] = 0.25
    M_rows, M_cols, M_vals = [*M_rows, 1], [*M_cols, 0], [*M_vals, 0.25]
    H = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 0.0], [0.5, 0.0]])  # empty column 1
    f, w, mu = np.array([0.5, -1.0, 2.0, 0.0]), np.array([1e-3, -2.0]), np.array([0.4])
    text = (
        header(2, 1)
        + cs_triplet_text(4, 4, M_rows, M_cols, M_vals)
        + cs_compressed_text(H)
        + vec(f)
        + vec(w)
        + vec(mu)
    )
    P = read_siconos(write(tmp_path, text, "global.dat"))
    assert P.kind == "global"
    assert "CSparse triplet" in P.description and "compressed-column" in P.description
    np.testing.assert_array_equal(P.M.toarray(), M)
    np.testing.assert_array_equal(P.H.toarray(), H)
    np.testing.assert_array_equal(P.f, f)
    np.testing.assert_array_equal(P.w, w)
    # Local, compressed column, then the same matrix dumped as compressed rows.
    W = np.array(
        [[3.0, -1.0, 0.0, 0.0], [-1.0, 2.0, 0.0, 0.5], [0.0, 0.0, 1.0, 0.0], [0.0, 0.5, 0.0, 7.0]]
    )
    W[0, 3] = 0.001
    q, mu2 = np.array([-1.0, 0.0, 0.5, 2.0]), np.array([0.3, 0.7])
    P = read_siconos(write(tmp_path, header(2, 2) + cs_compressed_text(W) + vec(q) + vec(mu2)))
    np.testing.assert_array_equal(P.W.toarray(), W)
    np.testing.assert_array_equal(P.q, q)
    csr = header(2, 2) + cs_compressed_text(W.T, origin=3) + vec(q) + vec(mu2)
    P = read_siconos(write(tmp_path, csr, "csr.dat"))
    assert "compressed-row" in P.description
    np.testing.assert_array_equal(P.W.toarray(), W)


def test_trailing_data_after_mu(tmp_path):
    A = np.diag([1.0, 2.0])
    base = header(2, 1) + dense_text(A) + vec([1.0, 0.0]) + vec([0.5])
    P = read_siconos(write(tmp_path, base + "1\n"))
    assert "isComplete flag 1" in P.description
    P = read_siconos(write(tmp_path, base + vec([0.0, 0.0]) + vec([-1.0, 0.0])))
    assert "4 trailing tokens after mu ignored (from line" in P.description
    np.testing.assert_array_equal(P.q, [1.0, 0.0])


# -- malformed files ----------------------------------------------------------------
LOCAL = header(2, 2) + dense_text(np.eye(4) * 2.0) + vec([1.0, -1.0, 0.5, 0.0]) + vec([0.3, 0.4])
GLOBAL = (
    header(2, 1)
    + cs_triplet_text(3, 3, [0, 1, 2], [0, 1, 2], [1.0, 2.0, 3.0])
    + cs_compressed_text(np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.5]]))
    + vec([0.0, -1.0, 0.0])
    + vec([0.1, 0.0])
    + vec([0.5])
)
SBM = header(3, 1) + sbm_text(3, 3, [3], [3], {(0, 0): np.eye(3)}) + vec([1.0, 0, 0]) + vec([0.5])


def test_the_bases_of_the_malformed_files_are_valid(tmp_path):
    assert read_siconos(write(tmp_path, LOCAL, "a.dat")).kind == "local"
    assert read_siconos(write(tmp_path, GLOBAL, "b.dat")).kind == "global"
    assert read_siconos(write(tmp_path, SBM, "c.dat")).kind == "local"


def cut_lines(text: str, keep: int) -> str:
    return "".join(text.splitlines(keepends=True)[:keep])


@pytest.mark.parametrize("base", ["LOCAL", "GLOBAL", "SBM"])
def test_truncated_anywhere(tmp_path, base):
    text = {"LOCAL": LOCAL, "GLOBAL": GLOBAL, "SBM": SBM}[base]
    n_lines = len(text.splitlines())
    for keep in range(1, n_lines):
        bad_file(tmp_path, cut_lines(text, keep), None)
    # Mid-line cuts too (inside a vector line, a CSparse line), dropping whole tokens.
    for frac in (0.3, 0.55, 0.8, 0.97):
        cut = text[: int(len(text) * frac)]
        cut = cut[: max(cut.rfind(c) for c in " \t\n")]
        bad_file(tmp_path, cut + "\n", None)


def test_truncated_messages(tmp_path):
    lines = LOCAL.splitlines(keepends=True)
    bad_file(tmp_path, "".join(lines[:2]), r"truncated: expected the storage type of W \(or M\)")
    bad_file(tmp_path, "".join(lines[:7]), r"truncated: expected 16 values of the dense W")
    q_cut = "".join(lines[:-2]) + " ".join(lines[-2].split()[:1]) + "\n"
    bad_file(tmp_path, q_cut, r"truncated: expected 4 values of q, found 1$")
    bad_file(tmp_path, "".join(lines[:-1]), r"truncated: expected 2 values of mu, found 0")
    g = GLOBAL.splitlines(keepends=True)
    bad_file(tmp_path, "".join(g[:-2]), r"truncated: expected 2 values of b \(the global w\)")


@pytest.mark.parametrize(
    ("first", "match"),
    [
        ("4", "line 1: dimension must be 2 or 3, got 4"),
        ("1", "line 1: dimension must be 2 or 3, got 1"),
        ("0", "line 1: dimension must be 2 or 3, got 0"),
        ("2.5", "line 1: expected the dimension, an integer 2 or 3, got '2.5'"),
        ("two", "line 1: expected the dimension, an integer 2 or 3, got 'two'"),
    ],
)
def test_wrong_dimension(tmp_path, first, match):
    bad_file(tmp_path, first + LOCAL[1:], match)


def replace_line(text: str, lineno: int, new: str) -> str:
    lines = text.splitlines(keepends=True)
    lines[lineno - 1] = new + "\n"
    return "".join(lines)


def test_wrong_sizes_and_storage(tmp_path):
    bad_file(
        tmp_path, replace_line(LOCAL, 2, "-2"), "line 2: number of contacts must be >= 1, got -2"
    )
    bad_file(
        tmp_path, replace_line(LOCAL, 2, "3"), "W is 4 x 4 but 3 contacts of dimension 2 need 6 x 6"
    )
    bad_file(
        tmp_path,
        replace_line(LOCAL, 3, "5"),
        "line 3: storage type of W \\(or M\\) must be 0, 1 or 2, got 5",
    )
    bad_file(
        tmp_path,
        replace_line(LOCAL, 3, "x"),
        "line 3: expected the storage type of W \\(or M\\), an integer 0, 1 or 2, got 'x'",
    )
    bad_file(
        tmp_path, replace_line(LOCAL, 4, "-4"), "line 4: row count of W \\(or M\\) must be >= 0"
    )
    bad_file(tmp_path, replace_line(LOCAL, 5, "-4"), "line 5: column count of W")
    bad_file(tmp_path, replace_line(LOCAL, 6, "4\t5"), "line 6: dense W \\(or M\\): the sizes are")
    bad_file(tmp_path, replace_line(LOCAL, 4, "0"), "line 4: W \\(or M\\) is 0 x 4")
    # A global file's H that does not fit M.
    g = GLOBAL.replace("2\n3\n2\n2\nCSparse", "2\n3\n3\n2\nCSparse")
    bad_file(tmp_path, g, None)
    bad_file(
        tmp_path, GLOBAL, "M is 3 x 3: a global problem's M must be square|W is 3 x 3", kind="local"
    )


def test_non_numeric_and_non_finite_values(tmp_path):
    lines = LOCAL.splitlines()
    q_line = len(lines) - 1  # 1-based number of the q line
    q = lines[q_line - 1].split()
    for token, match in [
        ("nan", f"line {q_line}: NaN in q"),
        ("-NaN", f"line {q_line}: NaN in q"),
        ("inf", f"line {q_line}: infinite value 'inf' in q"),
        ("-Infinity", "infinite value '-Infinity' in q"),
        ("1e999", "value '1e999' in q is out of range"),
        ("abc", f"line {q_line}: expected a number in q, got 'abc'"),
        ("1_0", "expected a number in q, got '1_0'"),
        ("0x10", "expected a number in q, got '0x10'"),
    ]:
        bad_file(tmp_path, replace_line(LOCAL, q_line, " ".join([token, *q[1:]])), match)
    # In the matrix and in mu.
    bad_file(tmp_path, replace_line(LOCAL, 7, "nan 0 0 0"), "line 7: NaN in the dense W")
    bad_file(tmp_path, replace_line(LOCAL, len(lines), "0.3 inf"), "infinite value 'inf' in mu")
    bad_file(tmp_path, replace_line(LOCAL, len(lines), "0.3 -0.1"), r"mu\[1\] is -0.1")
    g = GLOBAL.replace("    1 1 : 2\n", "    1 1 : nan\n")
    bad_file(tmp_path, g, "line 10: NaN in the values of M", kind="global")
    g = GLOBAL.replace("      1 : 1\n", "      1 : x1\n")
    bad_file(tmp_path, g, "expected a number in the values of H, got 'x1'")


def test_sparse_block_defects(tmp_path):
    lines = SBM.splitlines()
    # 1: 3 / 2: 1 / 3: 1 / 4: 3 / 5: 3 / 6: nbblocks / 7: nb0 / 8: nb1 / 9: 3 / 10: 3
    # 11: filled1 / 12: filled2 / 13: index1 / 14: index2 / 15: block number
    assert lines[14] == "0"
    bad_file(
        tmp_path,
        replace_line(SBM, 15, "7"),
        "line 15: sparse-block W .*expected block number 0, got 7",
    )
    bad_file(tmp_path, replace_line(SBM, 13, "0\t2\t"), "block-row pointers must rise from 0 to 1")
    bad_file(tmp_path, replace_line(SBM, 14, "4\t"), "block 0 is in block column 4, outside 0..0")
    bad_file(
        tmp_path, replace_line(SBM, 9, "2\t"), "the row blocks end at 2 but the matrix has 3 rows"
    )
    bad_file(tmp_path, replace_line(SBM, 12, "2"), "filled2 is 2 but the block count is 1")
    bad_file(tmp_path, replace_line(SBM, 6, "-1"), "block count of W \\(or M\\) must be >= 0")


CSPARSE_DEFECTS = [
    ("    2 2 : 3\n", "    5 2 : 3\n", "line 11: row index of M 5 is outside 0..2"),
    ("    2 2 : 3\n", "    2 -1 : 3\n", "line 11: column index of M -1 is outside 0..2"),
    ("    2 2 : 3\n", "    2 2 3\n", "line 11: expected ':' in the triplet entries of M, got '3'"),
    ("2\n3\n3\n1\n", "2\n3\n3\n2\n", "line 6: M: the sparse origin is 2"),
    ("2\n3\n3\n1\n", "2\n3\n3\n7\n", "line 6: sparse origin of M must be 1, 2 or 3, got 7"),
    ("triplet: 3-by-3", "triplet: 4-by-3", "line 8: the CSparse dump of M is 4-by-3 but"),
    ("triplet: 3-by-3", "triplet: -3-by-3", "line 8: expected the CSparse size line of M"),
    ("nnz: 3\n", "nnz: 4\n", "line 8: M has nnz 4 > nzmax 3"),
    ("CSparse Version", "Sparse Version", "line 7: expected the 'CSparse Version' line of M"),
    (
        "col 1 : locations 2",
        "col 1 : locations 3",
        "column 1 of H starts at location 3, expected 2",
    ),
    ("col 1 :", "kol 1 :", "expected 'col' in the header of column 1 of H, got 'kol'"),
    ("col 1 :", "col 2 :", "expected column 1 of H, got column 2"),
    ("      2 : -1\n", "      9 : -1\n", "row index 9 of H is outside 0..2"),
    ("      2 : -1\n", "      2 : -1x\n", "expected a number in the values of H, got '-1x'"),
]


@pytest.mark.parametrize(("old", "new", "match"), CSPARSE_DEFECTS)
def test_csparse_defects(tmp_path, old, new, match):
    assert GLOBAL.count(old) >= 1
    bad_file(tmp_path, GLOBAL.replace(old, new, 1), match, kind="global")


@pytest.mark.parametrize(
    ("content", "match"),
    [
        (b"", "empty file"),
        (b"  \n\n\t \n", "empty file"),
        (b"\x00\x01\x02binary\xff", "binary data: NUL byte at offset 0"),
        (b"3\n2\n\xff\xfe\x80\n", "byte 0xff at offset 4 is not text"),
        (b"\x89PNG\r\n\x1a\n", "is not text"),
    ],
)
def test_empty_and_binary_files(tmp_path, content, match):
    bad_file(tmp_path, content, match)


def test_random_binary_garbage(tmp_path):
    rng = np.random.default_rng(1)
    for _ in range(20):
        bad_file(tmp_path, rng.bytes(int(rng.integers(1, 4000))), None)


def test_missing_file_and_directory(tmp_path):
    missing = tmp_path / "nope.dat"
    with pytest.raises(ProblemFileError, match=f"^{missing}: no such file$"):
        read_siconos(missing)
    with pytest.raises(ProblemFileError, match="is a directory"):
        read_siconos(tmp_path)
    with pytest.raises(ProblemError, match="kind must be"):
        read_siconos(write(tmp_path, LOCAL), kind="both")  # type: ignore[arg-type]


@pytest.mark.parametrize("base", ["LOCAL", "GLOBAL", "SBM"])
def test_mutated_files_never_raise_raw_errors(tmp_path, base):
    text = {"LOCAL": LOCAL, "GLOBAL": GLOBAL, "SBM": SBM}[base]
    tokens = text.split(" ")
    rng = np.random.default_rng(7)
    junk = ["-1", "0", "1", "3", "99999999999", "nan", ":", "col", "x", "", "\n", "1e400", "-0"]
    path = tmp_path / "mutated.dat"
    for _ in range(150):
        mutated = list(tokens)
        for _ in range(int(rng.integers(1, 4))):
            k = int(rng.integers(len(mutated)))
            parts = mutated[k].split("\n")
            j = int(rng.integers(len(parts)))
            parts[j] = str(rng.choice(junk))
            mutated[k] = "\n".join(parts)
        path.write_text(" ".join(mutated))
        try:
            read_siconos(path)
        except ProblemFileError as exc:
            assert str(exc).startswith(f"{path}: ")
