"""ParaView export of a run file: VTU files per frame, collected in PVD series.

Per exported frame ``k`` (file names ``grains_{k:06d}.vtu``, ``contacts_{k:06d}.vtu``):

- grains: one point per grain (a ``vertex`` cell each) with ``radius``,
  ``velocity`` (3 components, ``z = 0`` in 2D), ``speed``,
  ``angular_velocity`` (3 components; about ``z`` in 2D), ``fixed`` (0/1) and
  ``id``. In ParaView: a Glyph filter, sphere glyphs scaled by ``radius``.
- contacts: one ``line`` cell per contact, from the centre of grain ``i`` to the
  centre of grain ``j`` (for a wall, to the foot of the perpendicular on it), with
  ``normal_impulse`` (N s, N s/m in 2D), ``normal_force`` (impulse / dt),
  ``tangential_impulse`` (its norm) and ``gap``: force chains, e.g. a Tube
  filter scaled by ``normal_force``.

``grains.pvd`` and ``contacts.pvd`` list the frames with their times, so
ParaView opens each as one time series. VTU files are written by meshio
(compressed binary).
"""

from __future__ import annotations

import contextlib
import io
import os
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from cocd.io.runfile import Frame, RunFile

__all__ = ["VTU_SERIES", "export_vtu"]

#: The series written, each as ``<name>.pvd`` and ``<name>_{k:06d}.vtu``.
VTU_SERIES = ("grains", "contacts")


def export_vtu(
    run_path: str | os.PathLike[str], out: str | os.PathLike[str], every: int = 1
) -> list[Path]:
    """Write every ``every``-th frame of a run file (and the last) to ``out``.

    Returns the paths of the two ``.pvd`` files.
    """

    from cocd.errors import CocdError

    if every < 1:
        raise CocdError(f"--every must be >= 1, got {every}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    series: dict[str, list[tuple[float, str]]] = {name: [] for name in VTU_SERIES}
    with RunFile(run_path) as rf:
        dt = float(rf.config.get("run", {}).get("dt", float("nan")))
        fixed = np.asarray(rf.f["scene/fixed"][:], dtype=np.int8)
        walls = (rf.f["scene/walls/point"][:], rf.f["scene/walls/normal"][:])
        chosen = sorted(set(range(0, rf.n_frames, every)) | {rf.n_frames - 1})
        for k in chosen:
            frame = rf.frame(k)
            grains = _grain_mesh(frame, rf.radii, fixed)
            contacts = _contact_mesh(frame, walls, dt)
            for name, mesh in zip(VTU_SERIES, (grains, contacts), strict=True):
                file = f"{name}_{k:06d}.vtu"
                if len(mesh.points):
                    mesh.write(out / file)
                else:  # meshio's binary writer cannot encode empty arrays; ASCII can
                    with contextlib.redirect_stderr(io.StringIO()):  # its "debugging" warning
                        mesh.write(out / file, binary=False)
                series[name].append((frame.time, file))
    paths = []
    for name, entries in series.items():
        path = out / f"{name}.pvd"
        _write_pvd(path, entries)
        paths.append(path)
    return paths


def _pad3(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    if a.ndim == 1:  # 2D rotations: about z
        out = np.zeros((a.size, 3))
        out[:, 2] = a
        return out
    if a.shape[1] == 3:
        return a
    out = np.zeros((a.shape[0], 3))
    out[:, : a.shape[1]] = a
    return out


def _grain_mesh(frame: Frame, radii: np.ndarray, fixed: np.ndarray):
    import meshio

    n = radii.size
    velocity = _pad3(frame.velocities)
    return meshio.Mesh(
        _pad3(frame.positions),
        [("vertex", np.arange(n, dtype=np.int64).reshape(n, 1))],
        point_data={
            "radius": radii,
            "velocity": velocity,
            "speed": np.linalg.norm(velocity, axis=1),
            "angular_velocity": _pad3(frame.angular_velocities),
            "fixed": fixed,
            "id": np.arange(n, dtype=np.int64),
        },
    )


def _contact_mesh(frame: Frame, walls: tuple[np.ndarray, np.ndarray], dt: float):
    import meshio

    nc = frame.nc
    x = frame.positions
    start = x[frame.i] if nc else np.zeros((0, x.shape[1]))
    end = np.empty_like(start)
    grain = frame.j >= 0
    end[grain] = x[frame.j[grain]]
    wall = ~grain
    # On a wall: the foot of the perpendicular from the grain's centre to the plane.
    k = -1 - frame.j[wall]
    point, normal = walls[0][k], walls[1][k]
    centre = x[frame.i[wall]]
    height = np.einsum("ij,ij->i", centre - point, normal)
    end[wall] = centre - height[:, None] * normal
    points = _pad3(np.concatenate([start, end]) if nc else np.zeros((0, x.shape[1])))
    lines = np.stack([np.arange(nc), nc + np.arange(nc)], axis=1).astype(np.int64)
    normal = frame.impulse[:, 0] if nc else np.zeros(0)
    tangential = np.linalg.norm(frame.impulse[:, 1:], axis=1) if nc else np.zeros(0)
    return meshio.Mesh(
        points,
        [("line", lines.reshape(nc, 2))],
        cell_data={
            "normal_impulse": [normal],
            "normal_force": [normal / dt],
            "tangential_impulse": [tangential],
            "gap": [np.asarray(frame.gap, dtype=np.float64)],
        },
    )


def _write_pvd(path: Path, entries: list[tuple[float, str]]) -> None:
    root = ET.Element("VTKFile", type="Collection", version="0.1", byte_order="LittleEndian")
    collection = ET.SubElement(root, "Collection")
    for t, file in entries:
        ET.SubElement(collection, "DataSet", timestep=repr(float(t)), group="", part="0", file=file)
    ET.indent(root)
    ET.ElementTree(root).write(path, xml_declaration=True, encoding="utf-8")
