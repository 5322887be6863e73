"""The run file: one HDF5 file per run, appended frame by frame, that survives a crash.

Layout (``format = "cocd-run"``, ``version = 1`` in the root attributes)::

    /                     attrs: format, version, dim, n_grains, contact_dim,
                          cocd_version, git_commit (``+dirty``: modified),
                          machines (JSON: ``[first step, machine_name()]`` for
                          the machine of each stretch of steps, a resumed run's
                          next one appended when it differs; "" for steps made
                          before machines were recorded),
                          units (JSON: the SI unit of every array and statistic),
                          config (the fully resolved configuration, JSON),
                          scene_file (the scene file's text, if any)
    /scene                radii, density, fixed; attrs gravity, mu, mu_wall,
                          groups (JSON); walls/point, walls/normal, walls/mu
                          (NaN: the scene's mu_wall)
    /frames               step (F,), time (F,), positions (F, n, d),
                          velocities (F, n, d), angular_velocities (F, n) in
                          2D or (F, n, 3) in 3D
    /contacts             per frame, CSR-style: ptr (F + 1,) indexes the rows
                          of i, j (grain, or -1 - k for wall k), keys (pair
                          identifiers), gap, normal (C, d) and impulse (C, d):
                          normal component first, then the tangential ones in
                          the contact frame (zero for frictionless scenes)
    /stats                one column per field of :class:`cocd.stepper.StepRecord`,
                          one row per step

Frame 0 is the initial configuration (no contacts). A frame is complete when
``/frames/step`` holds it: it is written last, after the frame's other data,
and the file is flushed after every frame. The file is written in HDF5's
single-writer/multiple-reader mode, whose ordered metadata writes keep it
readable when the writing process is killed; :meth:`RunWriter.resume` then
copies its complete frames (and the statistics of their steps) to a fresh file
that replaces it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np
from numpy.typing import NDArray

from cocd.contacts import ContactSet
from cocd.errors import CocdError
from cocd.provenance import machine_name
from cocd.scene import Scene, Wall
from cocd.stepper import StepRecord

__all__ = ["FORMAT", "VERSION", "Frame", "RunFile", "RunFileError", "RunWriter", "units"]

FORMAT = "cocd-run"
VERSION = 1
FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

_STAT_FIELDS = list(StepRecord.__dataclass_fields__)
_STAT_STRINGS = {"solver", "status", "failures"}
_STAT_INTS = {"step", "n", "nc", "iterations", "missed_contacts", "redos"}
#: Defaults of the statistics added after the first run files were written.
_STAT_DEFAULTS = {
    name: f.default
    for name, f in StepRecord.__dataclass_fields__.items()
    if f.default is not dataclasses.MISSING
}
_CONTACT_FIELDS = ("i", "j", "keys", "gap", "normal", "impulse")


class RunFileError(CocdError, ValueError):
    """A run file cannot be read, or does not match the run asked for."""


@dataclass(frozen=True)
class Frame:
    """One saved configuration and its contacts."""

    index: int
    step: int
    time: float
    positions: FloatArray
    velocities: FloatArray
    angular_velocities: FloatArray
    i: IntArray
    j: IntArray
    keys: IntArray
    gap: FloatArray
    normal: FloatArray
    impulse: FloatArray

    @property
    def nc(self) -> int:
        return int(self.i.size)


# -- writing ------------------------------------------------------------------------------
class RunWriter:
    """Append frames and step statistics to a run file (see the module's layout)."""

    def __init__(self, path: Path, f: h5py.File) -> None:
        self.path = path
        self.f = f
        self.dim = int(f.attrs["dim"])

    @classmethod
    def create(
        cls,
        path: str | os.PathLike[str],
        scene: Scene,
        config: dict[str, Any],
        scene_file: str = "",
    ) -> RunWriter:
        """A new run file holding ``scene`` as frame 0 (an existing file is replaced)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp")
        with h5py.File(tmp, "w", libver="latest") as f:
            _layout(f, scene, config, scene_file)
        os.replace(tmp, path)
        writer = cls._open(path)
        writer.append_frame(0, scene, None, None)
        return writer

    @classmethod
    def _open(cls, path: Path) -> RunWriter:
        f = h5py.File(path, "a", libver="latest")
        f.swmr_mode = True
        return cls(path, f)

    @classmethod
    def resume(
        cls, path: str | os.PathLike[str], config: dict[str, Any] | None = None
    ) -> RunWriter:
        """Reopen a run file for appending after its last complete frame.

        The complete frames and the statistics of the steps up to the last one
        are copied to a fresh file, which replaces ``path``: a file left by a
        killed process cannot be reopened for writing as it is. ``config``: the
        configuration the run goes on with (a later end, a larger iteration cap, a
        longer fallback list), recorded in place of the old one.
        """
        path = Path(path)
        source = RunFile(path)
        tmp = path.with_name(path.name + ".tmp")
        try:
            with h5py.File(tmp, "w", libver="latest") as f:
                _copy_prefix(source, f)
                f.attrs["machines"] = json.dumps(_machines_on(source))
                if config is not None:
                    f.attrs["config"] = json.dumps(config)
        finally:
            source.close()
        os.replace(tmp, path)
        return cls._open(path)

    def append_frame(
        self, step: int, scene: Scene, contacts: ContactSet | None, p: FloatArray | None
    ) -> None:
        """Append the scene's state after ``step`` with its contacts and impulses ``p``."""
        f = self.f
        ptr = f["contacts/ptr"]
        start = int(ptr[-1])
        nc = 0 if contacts is None else contacts.nc
        if contacts is not None and p is not None and nc:
            impulse = np.zeros((nc, self.dim))
            impulse[:, : p.shape[1]] = p
            values = {
                "i": contacts.i,
                "j": contacts.j,
                "keys": contacts.keys,
                "gap": contacts.gap,
                "normal": contacts.normal,
                "impulse": impulse,
            }
            for name in _CONTACT_FIELDS:
                ds = f[f"contacts/{name}"]
                ds.resize(start + nc, axis=0)
                ds[start:] = values[name]
        _append(ptr, start + nc)
        frames = f["frames"]
        _append(frames["positions"], scene.positions)
        _append(frames["velocities"], scene.velocities)
        _append(frames["angular_velocities"], scene.angular_velocities)
        _append(frames["time"], scene.time)
        _append(frames["step"], step)  # last: it marks the frame complete
        f.flush()

    def append_stats(self, record: StepRecord) -> None:
        """Append one step's statistics (flushed with the next frame)."""
        values = record.as_dict()
        for name in _STAT_FIELDS:
            _append(self.f[f"stats/{name}"], values[name])

    def close(self) -> None:
        if self.f.id.valid:
            self.f.flush()
            self.f.close()


def _append(ds: h5py.Dataset, value: Any) -> None:
    n = ds.shape[0]
    ds.resize(n + 1, axis=0)
    ds[n] = value


def units(dim: int) -> dict[str, str]:
    """SI units of the frames' arrays and of the statistics (2D: per metre of depth)."""
    depth = "" if dim == 3 else "/m"
    return {
        "time": "s", "positions": "m", "velocities": "m/s", "angular_velocities": "rad/s",
        "gap": "m", "impulse": f"N s{depth}", "radii": "m", "density": "kg/m^3",
        "t": "s", "detect_time": "s", "setup_time": "s", "solve_time": "s", "redo_time": "s",
        "kinetic_energy": f"J{depth}", "potential_energy": f"J{depth}",
    }  # fmt: skip


def _layout(f: h5py.File, scene: Scene, config: dict[str, Any], scene_file: str) -> None:
    from cocd.provenance import provenance

    n, d = scene.n_grains, scene.dim
    made = provenance()
    f.attrs.update(
        cocd_version=made["cocd"],
        git_commit=(made["commit"] or "") + ("+dirty" if made["dirty"] else ""),
        units=json.dumps(units(d)),
        format=FORMAT,
        version=VERSION,
        dim=d,
        n_grains=n,
        contact_dim=1 if scene.frictionless else d,
        config=json.dumps(config),
        scene_file=scene_file,
        machines=json.dumps([[1, machine_name()]]),
    )
    s = f.create_group("scene")
    s["radii"] = scene.radii
    s["density"] = scene.density
    s["fixed"] = scene.fixed
    s.attrs.update(
        gravity=scene.gravity,
        mu=scene.mu,
        mu_wall=scene.mu_wall,
        groups=json.dumps({k: [v.start, v.stop] for k, v in scene.groups.items()}),
    )
    w = s.create_group("walls")
    walls = scene.walls
    w["point"] = np.array([x.point for x in walls]).reshape(len(walls), d)
    w["normal"] = np.array([x.normal for x in walls]).reshape(len(walls), d)
    w["mu"] = np.array([np.nan if x.mu is None else x.mu for x in walls], dtype=np.float64)
    fr = f.create_group("frames")
    rot = (n,) if d == 2 else (n, 3)
    for name, shape in (("positions", (n, d)), ("velocities", (n, d)), ("angular_velocities", rot)):
        fr.create_dataset(
            name, shape=(0, *shape), maxshape=(None, *shape), chunks=(1, *shape), dtype="f8"
        )
    fr.create_dataset("time", shape=(0,), maxshape=(None,), chunks=(256,), dtype="f8")
    fr.create_dataset("step", shape=(0,), maxshape=(None,), chunks=(256,), dtype="i8")
    c = f.create_group("contacts")
    c.create_dataset("ptr", data=np.zeros(1, dtype=np.int64), maxshape=(None,), chunks=(256,))
    chunk = 4096
    for name, dtype, width in (
        ("i", "i8", None),
        ("j", "i8", None),
        ("keys", "i8", None),
        ("gap", "f8", None),
        ("normal", "f8", d),
        ("impulse", "f8", d),
    ):
        shape = (0,) if width is None else (0, width)
        c.create_dataset(
            name,
            shape=shape,
            maxshape=(None, *shape[1:]),
            chunks=(chunk, *shape[1:]),
            dtype=dtype,
        )
    st = f.create_group("stats")
    for name in _STAT_FIELDS:
        kind: Any = (
            h5py.string_dtype() if name in _STAT_STRINGS else ("i8" if name in _STAT_INTS else "f8")
        )
        st.create_dataset(name, shape=(0,), maxshape=(None,), chunks=(1024,), dtype=kind)


def _machines_on(source: RunFile) -> list[list[Any]]:
    """``source``'s machines as a run resumed here from its last complete frame records
    them: the stretches that made its steps (those after that frame made none), then
    this machine from the next step, unless it made the last stretch."""
    last = int(source.steps[-1]) if source.n_frames else 0
    machines = [[k, m] for k, m in source.machines_to(last)]
    if last > 0 and not machines:  # a file written before machines were recorded
        machines = [[1, ""]]
    if not machines or machines[-1][1] != machine_name():
        machines.append([last + 1, machine_name()])
    return machines


def _copy_prefix(source: RunFile, f: h5py.File) -> None:
    """The complete frames of ``source`` and the statistics of their steps, into ``f``."""
    src = source.f
    n_frames = source.n_frames
    if n_frames == 0:
        raise RunFileError(f"{source.path}: no complete frame to resume from")
    f.attrs.update(dict(src.attrs))
    src.copy(src["scene"], f, "scene")
    f.create_group("frames")
    for name in ("positions", "velocities", "angular_velocities", "time", "step"):
        ds = src[f"frames/{name}"]
        _copy_rows(ds, f["frames"], name, n_frames)
    ptr = src["contacts/ptr"][: n_frames + 1]
    f.create_group("contacts")
    _copy_rows(src["contacts/ptr"], f["contacts"], "ptr", n_frames + 1)
    for name in _CONTACT_FIELDS:
        _copy_rows(src[f"contacts/{name}"], f["contacts"], name, int(ptr[-1]))
    last_step = int(src["frames/step"][n_frames - 1])
    steps = src["stats/step"][:]
    keep = int(np.searchsorted(steps, last_step, side="right"))
    f.create_group("stats")
    for name in _STAT_FIELDS:
        if name in src["stats"]:
            _copy_rows(src[f"stats/{name}"], f["stats"], name, keep)
        else:  # a statistic files written before it existed lack: its default
            values = np.full(keep, _STAT_DEFAULTS[name])
            f["stats"].create_dataset(name, data=values, maxshape=(None,), chunks=(1024,))


def _copy_rows(ds: h5py.Dataset, group: h5py.Group, name: str, rows: int) -> None:
    out = group.create_dataset(
        name,
        shape=(rows, *ds.shape[1:]),
        maxshape=(None, *ds.shape[1:]),
        chunks=ds.chunks,
        dtype=ds.dtype,
    )
    block = max(1, (1 << 24) // max(1, int(np.prod(ds.shape[1:])) * ds.dtype.itemsize))
    for start in range(0, rows, block):
        stop = min(rows, start + block)
        out[start:stop] = ds[start:stop]


# -- reading ------------------------------------------------------------------------------
_DAMAGE = (
    KeyError, ValueError, TypeError, IndexError, OSError, AttributeError, RuntimeError,
    OverflowError,
)  # fmt: skip


@contextlib.contextmanager
def _damaged(path: Path) -> Iterator[None]:
    """h5py and numpy errors met while reading become a :class:`RunFileError`."""
    try:
        yield
    except RunFileError:
        raise
    except _DAMAGE as exc:
        raise RunFileError(f"{path}: damaged or incomplete run file ({exc})") from None


class RunFile:
    """A run file opened for reading (after a crash too; ``live=True`` while a run
    writes it)."""

    def __init__(self, path: str | os.PathLike[str], *, live: bool = False) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise RunFileError(f"run file {self.path} does not exist")
        if self.path.is_dir():
            raise RunFileError(f"{self.path} is a folder, not a run file")
        try:
            # live: HDF5's SWMR reading, for a file a run is writing. It retries reads
            # that fail their checksums, which makes it slow on a damaged file, so it
            # is used only when asked for or when the file says a writer has it open
            # (a run still going, or one that was killed).
            try:
                self.f = h5py.File(self.path, "r", swmr=live)
            except OSError as exc:
                if live or "already open for write" not in str(exc):
                    raise
                self.f = h5py.File(self.path, "r", swmr=True)
        except OSError as exc:
            why = " ".join(str(exc).split())  # HDF5's messages span lines
            raise RunFileError(f"{self.path}: not a readable HDF5 file ({why})") from None
        try:
            if self.f.attrs.get("format") != FORMAT:
                raise RunFileError(f"{self.path}: not a cocd run file")
            version = int(self.f.attrs["version"])
            if version > VERSION:
                raise RunFileError(
                    f"{self.path}: run file version {version} is newer than this cocd's {VERSION}"
                )
            self.dim = int(self.f.attrs["dim"])
            self.n_grains = int(self.f.attrs["n_grains"])
            self.contact_dim = int(self.f.attrs["contact_dim"])
            self.config: dict[str, Any] = json.loads(self.f.attrs["config"])
            self.scene_file = str(self.f.attrs.get("scene_file", ""))
            #: ``(first step, machine_name())`` of each stretch of steps; empty for a
            #: file written before machines were recorded.
            self.machines: list[tuple[int, str]] = _read_machines(self.f.attrs)
            self.radii = np.asarray(self.f["scene/radii"][:], dtype=np.float64)
            # Complete frames: those whose step is written, and whose other data is there.
            steps = self.f["frames/step"]
            n = steps.shape[0]
            n = min(n, self.f["frames/time"].shape[0], self.f["frames/positions"].shape[0])
            n = min(n, self.f["contacts/ptr"].shape[0] - 1)
            self.n_frames = int(n)
            self.steps = np.asarray(steps[: self.n_frames], dtype=np.int64)
            self.times = np.asarray(self.f["frames/time"][: self.n_frames], dtype=np.float64)
        except RunFileError:
            self.f.close()
            raise
        except _DAMAGE as exc:
            self.f.close()
            raise RunFileError(f"{self.path}: damaged or incomplete run file ({exc})") from None

    def __enter__(self) -> RunFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self.f.id.valid:
            self.f.close()

    def frame(self, k: int) -> Frame:
        """Frame ``k`` (negative counts from the end)."""
        n = self.n_frames
        if not -n <= k < n:
            raise RunFileError(f"{self.path}: frame {k} out of range ({n} frames)")
        k %= n
        with _damaged(self.path):
            return self._frame(k)

    def _frame(self, k: int) -> Frame:
        f = self.f
        lo, hi = (int(x) for x in f["contacts/ptr"][k : k + 2])
        c = {name: f[f"contacts/{name}"][lo:hi] for name in _CONTACT_FIELDS}
        return Frame(
            index=k,
            step=int(self.steps[k]),
            time=float(self.times[k]),
            positions=f["frames/positions"][k],
            velocities=f["frames/velocities"][k],
            angular_velocities=f["frames/angular_velocities"][k],
            i=c["i"],
            j=c["j"],
            keys=c["keys"],
            gap=c["gap"],
            normal=c["normal"],
            impulse=c["impulse"],
        )

    def scene(self, k: int = -1) -> Scene:
        """The scene at frame ``k``: static data from ``/scene``, state from the frame."""
        fr = self.frame(k)
        with _damaged(self.path):
            return self._scene(fr)

    def _scene(self, fr: Frame) -> Scene:
        s = self.f["scene"]
        walls = [
            Wall(p, nrm, None if np.isnan(m) else float(m))
            for p, nrm, m in zip(
                s["walls/point"][:], s["walls/normal"][:], s["walls/mu"][:], strict=True
            )
        ]
        scene = Scene(
            fr.positions,
            self.radii,
            density=s["density"][:],
            velocities=fr.velocities,
            angular_velocities=fr.angular_velocities,
            fixed=np.asarray(s["fixed"][:], dtype=bool),
            walls=walls,
            gravity=s.attrs["gravity"],
            mu=float(s.attrs["mu"]),
            mu_wall=float(s.attrs["mu_wall"]),
        )
        scene.time = fr.time
        scene.groups = {k: slice(a, b) for k, (a, b) in json.loads(s.attrs["groups"]).items()}
        return scene

    def machines_to(self, step: int) -> list[tuple[int, str]]:
        """The stretches of :attr:`machines` that made steps 1 to ``step`` (those
        starting after it made none of them)."""
        return [(k, m) for k, m in self.machines if k <= step]

    def stats(self) -> Any:
        """The per-step statistics as a pandas table (one row per step)."""
        with _damaged(self.path):
            return self._stats()

    def _stats(self) -> Any:
        import pandas as pd

        st = self.f["stats"]
        n = min(st[name].shape[0] for name in _STAT_FIELDS if name in st)
        data = {}
        for name in _STAT_FIELDS:
            if name not in st:  # written before this statistic existed
                data[name] = np.full(n, _STAT_DEFAULTS[name])
                continue
            values = st[name][:n]
            if name in _STAT_STRINGS:
                values = [v.decode() if isinstance(v, bytes) else str(v) for v in values]
            data[name] = values
        return pd.DataFrame(data, columns=_STAT_FIELDS)

    def records(self) -> list[StepRecord]:
        """The statistics as :class:`StepRecord` objects."""
        table = self.stats()
        return [StepRecord(**row) for row in table.to_dict("records")]


def _read_machines(attrs: Any) -> list[tuple[int, str]]:
    """The ``machines`` record of a run file's attributes; [] when absent or unreadable
    (it says where the steps were timed, not what they are: the run stays readable)."""
    try:
        return [(int(k), str(m)) for k, m in json.loads(attrs.get("machines", "[]"))]
    except (TypeError, ValueError):
        return []
