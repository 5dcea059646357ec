"""Particle frames as VTK for ParaView and Houdini: one ``.vtu`` point cloud per saved frame and a ``.pvd`` series.

No paper equation is implemented here: this re-encodes what the simulation already wrote.

Sources (read with h5py; nothing is simulated):

- **OUT.h5** of ``fluidgs sim`` (:mod:`fluidsim.output`): every ``/frames/<k>`` group, with its ``time`` (s). The
  static boundary ``/boundary/x`` is split by the scene's domain box: wall particles lie outside the box
  (:func:`fluidsim.sources.wall_particles`), the solid inside it.
- **RESULT.h5** of ``fluidgs simulate`` with recorded probes (``--record-probe``; :mod:`nbv.physics.trajectory`):
  every frame of every recorded probe, at time steps x dt; the solid is ``/solid/x``. A particle that has left
  the domain (retired: NaN in the file) is left out of the frames after it left; ``id`` keeps each particle
  traceable across frames, and the count of frames and particles is logged.

Files, in the folder DIR (written as a whole: a temporary folder swapped in at the end, :mod:`fluidsim.files`):

- ``<name>_<step>.vtu``: VTK XML unstructured grid (one vertex cell per particle, zlib-compressed binary, written
  by meshio), positions in simulation metres (Y-up) and the point data ``velocity`` (m/s, 3 components),
  ``divergence`` (D_i of paper Eq. 1, 1/s), ``density`` (rho_i / rho_0), ``speed`` (m/s) and ``id`` (the
  particle's initial index). ``<name>`` is ``fluid`` for OUT.h5 and ``probe_neg_x`` ... ``probe_pos_z`` for
  RESULT.h5. Files written before velocity or density were recorded lack them (a warning names the field).
- ``<name>.pvd``: the ParaView collection of those files with their times (s): open it to play the run.
- ``solid.vtu`` (the solid particles) and, for OUT.h5 with walls, ``walls.vtu``.
"""

from __future__ import annotations

import json
import logging
import os
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import h5py
import meshio
import numpy as np
from tqdm import tqdm

from fluidsim.files import atomic_folder, check_writable
from recon.inflate import check_hdf5_sizes

log = logging.getLogger(__name__)

FIELDS = ("velocity", "divergence", "density", "speed", "id")


@dataclass(frozen=True)
class ParticleFrame:
    """One saved frame: ``x`` [K, 3] float32 m, and per particle ``point_data`` (FIELDS, [K] or [K, 3])."""

    step: int
    time: float
    x: np.ndarray
    point_data: dict[str, np.ndarray]


@dataclass(frozen=True)
class Series:
    """The frames of one run (``name`` names its files) and how many there are."""

    name: str
    count: int
    frames: Iterator[ParticleFrame]


def probe_series_name(direction: str) -> str:
    """``probe_neg_x`` for -x, ``probe_pos_z`` for +z: a file name free of signs."""
    return f"probe_{'neg' if direction[0] == '-' else 'pos'}_{direction[1:]}"


def file_kind(f: h5py.File, path: Path) -> str:
    """``"out"`` (an OUT.h5 with frames) or ``"result"`` (a RESULT.h5 with recorded probes).

    Raises:
        ValueError: neither: no frames and no trajectories, naming --vtk and how to make a file that has them.
    """
    frames = f.get("frames")
    if isinstance(frames, h5py.Group) and len(frames):
        return "out"
    probes = f.get("probes")
    if isinstance(probes, h5py.Group) and any("trajectory" in probes[d] for d in probes):
        return "result"
    if "gaussians" in f or isinstance(probes, h5py.Group):
        raise ValueError(
            f"--vtk: {path} is a RESULT.h5 without recorded trajectories; re-run simulate with "
            "--record-probe -x (or the probes you want) to record its fluid frames"
        )
    raise ValueError(
        f"--vtk: {path} holds neither /frames (an OUT.h5 of `fluidgs sim`) nor recorded probe "
        "trajectories (a RESULT.h5 of `fluidgs simulate --record-probe`); pass one of those"
    )


def _scene(f: h5py.File) -> dict:
    raw = f.attrs.get("scene")
    if raw is None:
        return {}
    try:
        return json.loads(raw.decode() if isinstance(raw, bytes) else str(raw))
    except ValueError:
        return {}


def split_boundary(boundary: np.ndarray, scene: dict) -> tuple[np.ndarray, np.ndarray]:
    """(solid, walls) of an OUT.h5 boundary: walls lie outside the scene's domain box, the solid inside it (all
    of it is the solid when the scene names no domain)."""
    b = np.asarray(boundary, np.float32).reshape(-1, 3)
    domain = scene.get("domain") or {}
    if "min" not in domain or "max" not in domain:
        return b, b[:0]
    lo, hi = np.asarray(domain["min"], np.float64), np.asarray(domain["max"], np.float64)
    inside = ((b >= lo) & (b <= hi)).all(axis=1)
    return b[inside], b[~inside]


def _out_frames(f: h5py.File, missing: set[str]) -> Iterator[ParticleFrame]:
    group = f["frames"]
    for key in sorted(group, key=int):
        g = group[key]
        x = np.asarray(g["x"][()], np.float32)
        data: dict[str, np.ndarray] = {}
        if "v" in g:
            v = np.asarray(g["v"][()], np.float32)
            data["velocity"], data["speed"] = v, np.linalg.norm(v, axis=1).astype(np.float32)
        data["divergence"] = np.asarray(g["divergence"][()], np.float32)
        if "density" in g:
            data["density"] = np.asarray(g["density"][()], np.float32)
        if "ids" in g:
            data["id"] = np.asarray(g["ids"][()], np.int32)
        missing.update(set(FIELDS) - set(data))
        yield ParticleFrame(int(g.attrs["step"]), float(g.attrs["time"]), x, data)


def _trajectory_frames(group: h5py.Group, dt: float, missing: set[str], retired: list[int]) -> Iterator[ParticleFrame]:
    t = group["trajectory"]
    steps = np.asarray(t["steps"][()], np.int64)
    for i, step in enumerate(steps.tolist()):
        x = np.asarray(t["x"][i], np.float32)
        keep = np.isfinite(x).all(axis=1)
        retired.append(int((~keep).sum()))
        data: dict[str, np.ndarray] = {
            "divergence": np.asarray(t["D"][i], np.float32)[keep],
            "speed": np.asarray(t["speed"][i], np.float32)[keep],
            "id": np.flatnonzero(keep).astype(np.int32),
        }
        if "v" in t:
            data["velocity"] = np.asarray(t["v"][i], np.float32)[keep]
        if "density" in t:
            data["density"] = np.asarray(t["density"][i], np.float32)[keep]
        missing.update(set(FIELDS) - set(data))
        yield ParticleFrame(int(step), step * dt, x[keep], data)


def write_vtu(path: Path, x: np.ndarray, point_data: dict[str, np.ndarray] | None = None) -> Path:
    """One point cloud as a VTK XML unstructured grid (a vertex cell per point; meshio, zlib binary)."""
    x = np.asarray(x, np.float32).reshape(-1, 3)
    cells = [("vertex", np.arange(len(x), dtype=np.int64)[:, None])] if len(x) else []
    mesh = meshio.Mesh(x, cells, point_data=dict(point_data or {}))
    meshio.write(path, mesh, file_format="vtu", binary=True, compression="zlib")
    return Path(path)


def write_pvd(path: Path, entries: list[tuple[float, str]]) -> Path:
    """A ParaView collection: one ``DataSet`` per (time s, file name relative to ``path``'s folder)."""
    root = ET.Element("VTKFile", type="Collection", version="0.1", byte_order="LittleEndian")
    coll = ET.SubElement(root, "Collection")
    for time, name in entries:
        ET.SubElement(coll, "DataSet", timestep=repr(float(time)), group="", part="0", file=name)
    ET.indent(root)
    Path(path).write_bytes(b'<?xml version="1.0"?>\n' + ET.tostring(root) + b"\n")
    return Path(path)


def check_vtk_source(path: str | Path) -> str:
    """The kind of ``path`` (:func:`file_kind`) after checking it is a readable HDF5 file, before any writing."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path} does not exist or is not a file; pass an OUT.h5 or a RESULT.h5")
    if not h5py.is_hdf5(path):
        raise ValueError(f"{path} is not an HDF5 file; pass an OUT.h5 of `fluidgs sim` or a RESULT.h5")
    with h5py.File(path, "r") as f:
        check_hdf5_sizes(f, str(path))
        return file_kind(f, path)


def check_recorded(path: str | Path, probes: tuple[str, ...] | None = None) -> list[str]:
    """The recorded probes of a RESULT.h5 among ``probes`` (None: all recorded), in file order.

    Raises:
        ValueError: a probe of ``probes`` that was not recorded (naming --probe and those recorded).
    """
    with h5py.File(path, "r") as f:
        group = f.get("probes")
        recorded = [d for d in group if "trajectory" in group[d]] if isinstance(group, h5py.Group) else []
    absent = [d for d in probes or () if d not in recorded]
    if absent:
        raise ValueError(
            f"--probe {','.join(absent)}: not recorded in {path} (recorded: "
            f"{','.join(recorded) or 'none'}); choose among those"
        )
    return recorded if probes is None else list(probes)


def check_vtk_folder(folder: Path, outputs: dict[str, Path | None]) -> None:
    """Refuse, before any work, what replacing the --vtk folder of :func:`export_vtk` as a whole would destroy:
    another output inside it (``outputs``: option -> path) and an existing folder holding anything but an earlier
    export's .vtu and .pvd files (ValueError, exit 2); and a folder beside which no new one can be made, as the
    export is written under a temporary name beside it and renamed into place (OutputError, exit 4)."""
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"--vtk {folder} exists and is not a folder; name a folder")
    for label, path in outputs.items():
        if label != "--vtk" and path is not None and Path(path).resolve().is_relative_to(folder.resolve()):
            raise ValueError(
                f"{label} {path} lies inside --vtk {folder}, which is replaced as a whole; write it elsewhere"
            )
    if folder.is_dir():
        others = sorted(p.name for p in folder.iterdir() if not (p.is_file() and p.suffix in (".vtu", ".pvd")))
        if others:
            shown = ", ".join(others[:3]) + (", ..." if len(others) > 3 else "")
            raise ValueError(
                f"--vtk {folder} holds more than an earlier VTK export ({shown}), and replacing the folder would "
                "delete it; give a new or empty folder, or one an earlier --vtk wrote"
            )
    where = Path(os.path.abspath(folder))  # the parent of the folder as named: a link is replaced, not followed
    check_writable(where.with_name(where.name + ".pvd") if where.is_dir() else where)


def export_vtk(
    source: str | Path, folder: str | Path, probes: tuple[str, ...] | None = None, progress: bool = False
) -> dict:
    """Write the particle frames of ``source`` (OUT.h5 or RESULT.h5) into ``folder`` (module docstring).

    Args:
        source: the HDF5 file. folder: the output folder (replaced as a whole when it exists).
        probes: RESULT.h5 only: the recorded probes to write (None: all recorded).
        progress: a tqdm bar over the frames.
    Returns:
        {"kind", "series": {name: frames}, "files": the number of files, "missing": fields the file lacks}.
    Raises:
        ValueError: a file without frames or trajectories (:func:`file_kind`), or a probe not recorded.
    """
    source, folder = Path(source), Path(folder)
    kind = check_vtk_source(source)
    missing: set[str] = set()
    retired: list[int] = []
    written: dict[str, int] = {}
    files = 0
    with h5py.File(source, "r") as f:
        if kind == "out":
            solid, walls = split_boundary(f["boundary/x"][()] if "boundary/x" in f else np.zeros((0, 3)), _scene(f))
            series = [Series("fluid", len(f["frames"]), _out_frames(f, missing))]
        else:
            cfg = json.loads(f.attrs["config"]) if "config" in f.attrs else {}
            dt = float(cfg.get("dt", 0.0))
            chosen = check_recorded(source, probes)
            solid, walls = np.asarray(f["solid/x"][()], np.float32), np.zeros((0, 3), np.float32)
            series = [
                Series(
                    probe_series_name(d),
                    len(f["probes"][d]["trajectory/steps"]),
                    _trajectory_frames(f["probes"][d], dt, missing, retired),
                )
                for d in chosen
            ]
        total = sum(s.count for s in series)
        with atomic_folder(folder) as tmp, tqdm(total=total, desc="vtk", unit="frame", disable=not progress) as bar:
            for s in series:
                entries = []
                for frame in s.frames:
                    name = f"{s.name}_{frame.step:06d}.vtu"
                    write_vtu(tmp / name, frame.x, frame.point_data)
                    entries.append((frame.time, name))
                    bar.update(1)
                write_pvd(tmp / f"{s.name}.pvd", entries)
                written[s.name] = len(entries)
                files += len(entries) + 1
            write_vtu(tmp / "solid.vtu", solid)
            files += 1
            if len(walls):
                write_vtu(tmp / "walls.vtu", walls)
                files += 1
    for name in sorted(missing):
        log.warning("%s: the frames hold no %s (written before it was recorded); the VTK files lack it", source, name)
    if retired and max(retired):
        log.info(
            "%s: particles that had left the domain are left out of the frames (up to %d per frame)",
            source,
            max(retired),
        )
    return {"kind": kind, "series": written, "files": files, "missing": sorted(missing)}
