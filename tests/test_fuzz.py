"""Hostile input: random and malformed files, scene files and scene arguments.

Whatever comes in, only :class:`cocd.errors.CocdError` comes out: never a raw
IndexError, KeyError, ValueError from numpy, or a crash.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import h5py
import numpy as np
import scipy.sparse as sp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cocd import Scene, Wall
from cocd.builders import column_2d, jammed_box, stack, tall_stack, wedged_grain
from cocd.config import ConfigError, build_scene, load_config, parse_config
from cocd.errors import CocdError
from cocd.io import read_problem, write_problem
from cocd.io.problems import GlobalProblem, LocalProblem

SETTINGS = settings(
    max_examples=150,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)

# -- values ---------------------------------------------------------------------------------
finite = st.floats(-1e3, 1e3, allow_nan=False)
anything_numeric = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-(10**20), 10**20),
    st.booleans(),
    st.none(),
    st.text(max_size=5),
)


def _arrays(draw, shape_max=4):
    kind = draw(st.sampled_from(["float", "int", "nan", "empty", "text", "nested", "scalar"]))
    shape = tuple(draw(st.lists(st.integers(0, shape_max), min_size=1, max_size=3)))
    if kind == "float":
        return np.asarray(draw(st.lists(finite, min_size=int(np.prod(shape)),
                                        max_size=int(np.prod(shape))))).reshape(shape)  # fmt: skip
    if kind == "int":
        return np.arange(int(np.prod(shape))).reshape(shape) - 2
    if kind == "nan":
        a = np.ones(shape)
        a.flat[:1] = draw(st.sampled_from([np.nan, np.inf, -np.inf]))
        return a
    if kind == "empty":
        return np.zeros((0,) + shape[1:])
    if kind == "text":
        return draw(st.text(max_size=4))
    if kind == "nested":
        return [[1.0, 2.0], [3.0]]
    return draw(anything_numeric)


arrays = st.composite(_arrays)()


def _only_cocd_errors(call):
    try:
        call()
    except CocdError:
        pass


# -- scene constructors -----------------------------------------------------------------------
@SETTINGS
@given(
    positions=arrays,
    radii=arrays,
    density=st.one_of(arrays, st.floats()),
    velocities=st.one_of(st.none(), arrays),
    angular=st.one_of(st.none(), arrays),
    fixed=st.one_of(st.none(), arrays, st.lists(st.booleans(), max_size=4).map(np.asarray)),
    gravity=st.one_of(st.none(), arrays),
    mu=anything_numeric,
    mu_wall=st.one_of(st.none(), anything_numeric),
)
def test_scene_constructor_raises_only_scene_errors(
    positions, radii, density, velocities, angular, fixed, gravity, mu, mu_wall
):
    _only_cocd_errors(
        lambda: Scene(
            positions,
            radii,
            density=density,
            velocities=velocities,
            angular_velocities=angular,
            fixed=fixed,
            gravity=gravity,
            mu=mu,
            mu_wall=mu_wall,
        )
    )


@SETTINGS
@given(point=arrays, normal=arrays, mu=st.one_of(st.none(), anything_numeric))
def test_wall_constructor_raises_only_scene_errors(point, normal, mu):
    _only_cocd_errors(lambda: Wall(point, normal, mu))


small_ints = st.one_of(st.integers(-3, 40), st.sampled_from([10**13, 2**63]))


@SETTINGS
@given(
    builder=st.sampled_from([column_2d, stack, tall_stack, jammed_box]),
    n=st.one_of(small_ints, st.floats(), st.text(max_size=3), st.none(), st.booleans()),
    dim=st.one_of(st.integers(-1, 4), st.floats(), st.text(max_size=2)),
    mu=anything_numeric,
)
def test_builders_raise_only_cocd_errors(builder, n, dim, mu):
    if builder is column_2d:
        _only_cocd_errors(lambda: column_2d(n, mu=mu))
    else:
        _only_cocd_errors(lambda: builder(n, dim=dim, mu=mu))


@SETTINGS
@given(angle=anything_numeric, dim=st.one_of(st.integers(-1, 4), st.text(max_size=2)))
def test_wedged_grain_raises_only_cocd_errors(angle, dim):
    _only_cocd_errors(lambda: wedged_grain(angle, dim=dim))


# -- scene files --------------------------------------------------------------------------------
KEYS = ["builder", "params", "run", "dt", "until", "steps", "solver", "tol", "frame_every",
        "n_grains", "dim", "mu", "radius", "fallback", "warm_start", "zzz"]  # fmt: skip
toml_scalars = st.one_of(
    st.integers(-(10**15), 10**15),
    st.floats(allow_nan=True, allow_infinity=True),
    st.booleans(),
    st.text(max_size=8),
    st.sampled_from(["column_2d", "stack", "jammed_box", "clarabel", "nope"]),
)
toml_values = st.recursive(
    toml_scalars,
    lambda children: st.one_of(
        st.lists(children, max_size=3), st.dictionaries(st.sampled_from(KEYS), children, max_size=4)
    ),
    max_leaves=12,
)


@SETTINGS
@given(data=st.dictionaries(st.sampled_from(KEYS), toml_values, max_size=4))
def test_scene_file_content_gives_a_config_or_a_config_error(data):
    try:
        config = parse_config(data, "fuzz.toml")
    except ConfigError:
        return
    if config.builder in ("stack", "jammed_box", "column_2d"):
        _only_cocd_errors(lambda: build_scene(config, "fuzz.toml"))


@SETTINGS
@given(text=st.one_of(st.text(max_size=200), st.binary(max_size=200)))
def test_scene_file_bytes_give_a_config_or_a_config_error(text):
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "scene.toml"
        if isinstance(text, bytes):
            path.write_bytes(text)
        else:
            path.write_text(text, encoding="utf-8")
        _only_cocd_errors(lambda: load_config(path))


# -- problem files ------------------------------------------------------------------------------
def _local_problem() -> LocalProblem:
    rng = np.random.default_rng(1)
    B = rng.normal(size=(6, 4))
    return LocalProblem(W=sp.csc_matrix(B @ B.T + np.eye(6)), q=rng.normal(size=6),
                        mu=np.full(3, 0.3), dim=2)  # fmt: skip


def _global_problem() -> GlobalProblem:
    rng = np.random.default_rng(2)
    return GlobalProblem(
        M=sp.identity(4, format="csc"),
        H=sp.csc_matrix(rng.normal(size=(4, 4))),
        f=rng.normal(size=4),
        w=rng.normal(size=4),
        mu=np.full(2, 0.5),
        dim=2,
    )


def _datasets(path: Path) -> list[str]:
    names: list[str] = []
    with h5py.File(path, "r") as f:
        f.visit(lambda name: names.append(name))
    return names


def _mutate(path: Path, pick: int, mutation: str, value: object, cut: float) -> None:
    """Damage an HDF5 file: cut or flip a byte, or delete, replace or annotate an object."""
    names = _datasets(path)
    name = names[pick % len(names)]
    if mutation in ("truncate", "flip"):
        data = bytearray(path.read_bytes())
        if mutation == "truncate":
            data = data[: int(cut * len(data))]
        else:
            data[int(cut * (len(data) - 1))] ^= 0xFF
        path.write_bytes(bytes(data))
        return
    with h5py.File(path, "a") as f:
        if mutation == "attr":
            f[name].attrs["junk"] = 1
            # (HDF5 strings cannot hold a NUL.)
            text = str(value)[:10].replace("\x00", "?")
            f.attrs[("version", "config", "dim", "format")[pick % 4]] = text
            return
        del f[name]
        if mutation == "replace" and not isinstance(value, list):
            try:
                f[name] = value
            except (TypeError, ValueError):
                pass


@SETTINGS
@given(
    which=st.sampled_from(["local", "global"]),
    pick=st.integers(0, 1000),
    mutation=st.sampled_from(["delete", "replace", "attr", "truncate", "flip"]),
    value=arrays,
    cut=st.floats(0.0, 1.0),
)
def test_mutated_fclib_files_give_problems_or_problem_file_errors(which, pick, mutation, value, cut):
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "p.hdf5"
        write_problem(path, _local_problem() if which == "local" else _global_problem())
        _mutate(path, pick, mutation, value, cut)
        _only_cocd_errors(lambda: read_problem(path))


SICONOS = (
    "2\n2\n0\n4\n4\n4\t4\n4 -1 0.5 0 \n-2 3 0 0.25 \n0.1 0 5 -1.5 \n0 0.3 -1 2 \n"
    "-1 0.2 1e-17 3 \n0.3 0.333 \n"
)


@SETTINGS
@given(
    edits=st.lists(
        st.tuples(st.integers(0, 200), st.sampled_from(["drop", "swap", "dup", "junk"]),
                  st.sampled_from(["x", "-", "1e999", "nan", "3", "-7", "0.5.5", "", "\x00"])),
        min_size=1, max_size=4,
    ),  # fmt: skip
)
def test_mutated_siconos_files_give_problems_or_problem_file_errors(edits):
    tokens = SICONOS.split(" ")
    for where, kind, junk in edits:
        k = where % max(1, len(tokens))
        if not tokens:
            break
        if kind == "drop":
            tokens.pop(k)
        elif kind == "swap":
            tokens[k], tokens[-1] = tokens[-1], tokens[k]
        elif kind == "dup":
            tokens.insert(k, tokens[k])
        else:
            tokens[k] = junk
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "p.dat"
        path.write_text(" ".join(tokens))
        _only_cocd_errors(lambda: read_problem(path))


@SETTINGS
@given(data=st.binary(max_size=300))
def test_random_bytes_as_a_problem_file(data):
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "p.dat"
        path.write_bytes(data)
        _only_cocd_errors(lambda: read_problem(path))
        h5 = Path(folder) / "p.hdf5"
        h5.write_bytes(b"\x89HDF\r\n\x1a\n" + data)
        _only_cocd_errors(lambda: read_problem(h5))


# -- run files ----------------------------------------------------------------------------------
_RUN_FILE: list[bytes] = []


def _run_file(folder: Path) -> Path:
    """A small valid run file (simulated once, then copied)."""
    from cocd.runs import run

    path = folder / "run.h5"
    if not _RUN_FILE:
        config = parse_config(
            {"builder": "stack", "params": {"n_grains": 2, "dim": 2}, "run": {"steps": 2}}
        )
        _RUN_FILE.append(run(config, folder).path.read_bytes())
    path.write_bytes(_RUN_FILE[0])
    return path


@SETTINGS
@given(
    pick=st.integers(0, 1000),
    mutation=st.sampled_from(["delete", "replace", "attr", "truncate", "flip"]),
    value=arrays,
    cut=st.floats(0.0, 1.0),
)
def test_mutated_run_files_give_run_file_errors(pick, mutation, value, cut):
    from cocd.io.runfile import RunFile

    with tempfile.TemporaryDirectory() as folder:
        path = _run_file(Path(folder))
        _mutate(path, pick, mutation, value, cut)

        def read() -> None:
            with RunFile(path) as rf:
                for k in range(rf.n_frames):
                    rf.frame(k)
                rf.scene(-1)
                rf.stats()

        _only_cocd_errors(read)
