"""The solids of a functional comparison: a reference (a mesh, a Gaussian file or a RESULT.h5) and a reconstruction,
made on one lattice in one simulation frame.

Both solids are lattices of the fluid spacing s in simulation metres, Y up, like the Gaussians' solid
(:mod:`nbv.physics.solidify`): points (o + (i, j, k)) s, o the lattice offset in spacings. The frame (up, metres per
scene unit) is the reference's; the reconstruction is put into it, so a render-dataset folder's mesh and Gaussians
trained on that folder compare as they are. A capture against a CAD model needs a 4 x 4 transform that takes the
reference into the reconstruction's scene frame.

- **mesh** (.obj, .stl, .glb, .gltf, .off, or a .ply with faces): the lattice points inside the mesh (ray-parity
  occupancy, :func:`fluidsim.sources.points_inside_mesh`). A mesh that is not watertight has no inside: it is sampled
  on its surface instead, each sample snapped to its lattice point, with a warning;
- **Gaussians**: their solid, as ``fluidgs simulate`` makes it;
- **RESULT.h5**: the stored solid, as the union of its particles' cubes, resampled onto the lattice.

The noise floor's reference is the same reference on a lattice shifted by a fraction of a spacing (the second
replica's offset, :func:`nbv.physics.replicas.replica_offsets`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from nbv.physics.config import PhysicsConfig
from nbv.physics.scene_frame import SceneTransform, rotation_to_y_up

log = logging.getLogger(__name__)

MESH_SUFFIXES = (".obj", ".stl", ".glb", ".gltf", ".off")


def is_mesh_file(path: Path) -> bool:
    """A mesh by its suffix, or a .ply whose header declares faces and no Gaussian fields."""
    p = Path(path)
    if p.suffix.lower() in MESH_SUFFIXES:
        return True
    if p.suffix.lower() != ".ply" or not p.is_file():
        return False
    with open(p, "rb") as f:
        head = f.read(65536)
    header = head.split(b"end_header", 1)[0].decode("ascii", "replace")
    return "element face" in header and "scale_0" not in header and "element chunk" not in header


def is_result_file(path: Path) -> bool:
    """A RESULT.h5 of ``fluidgs simulate`` (by its suffix)."""
    return Path(path).suffix.lower() in (".h5", ".hdf5")


def lattice_points(lo: np.ndarray, hi: np.ndarray, spacing: float, offset) -> np.ndarray:
    """(K, 3) the lattice points (o + (i, j, k)) s inside the box [lo, hi], m."""
    o = np.asarray(offset, np.float64)
    first = np.ceil(np.asarray(lo) / spacing - o)
    last = np.floor(np.asarray(hi) / spacing - o)
    axes = [(np.arange(first[d], last[d] + 1) + o[d]) * spacing for d in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)


def lattice_keys(points: np.ndarray, spacing: float, offset) -> np.ndarray:
    """(K, 3) int64 lattice indices of points that lie on the lattice of ``offset`` (to rounding)."""
    return np.round(np.asarray(points, np.float64) / spacing - np.asarray(offset, np.float64)).astype(np.int64)


def resample_cubes(points: np.ndarray, spacing: float, offset) -> np.ndarray:
    """The lattice points of ``offset`` inside the union of the cubes of side ``spacing`` centred on ``points`` (a
    lattice solid of another offset), m."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    if len(pts) == 0:
        return pts
    src = np.round((pts.min(0) / spacing) % 1.0, 9) % 1.0  # the source lattice's offset
    keys = {tuple(k) for k in lattice_keys(pts, spacing, src)}
    cand = lattice_points(pts.min(0) - spacing, pts.max(0) + spacing, spacing, offset)
    # the source cell a candidate falls in (a tiny bias breaks the tie of a point on a cell face the same way)
    cells = np.floor(cand / spacing - src + 0.5 + 1e-9).astype(np.int64)
    inside = np.fromiter((tuple(c) in keys for c in cells), bool, len(cells))
    return cand[inside]


@dataclass(frozen=True)
class SolidSource:
    """One side of a comparison: how to make its solid on a lattice of a given offset, in one frame.

    Attributes:
        path: the file. kind: "mesh", "gaussians" or "result". transform: the scene -> simulation transform used.
        warnings: what the reader had to assume (a non-watertight mesh sampled on its surface).
    """

    path: Path
    kind: str
    transform: SceneTransform
    warnings: tuple[str, ...]
    _mesh: object = None
    _frame: object = None
    _solid: np.ndarray | None = None

    def solid(self, spacing: float, offset=(0.0, 0.0, 0.0)) -> np.ndarray:
        """(M, 3) float64 solid particles on the lattice of ``offset`` (spacings), simulation metres."""
        if self.kind == "mesh":
            return _mesh_solid(self._mesh, spacing, offset, watertight=not self.warnings)
        if self.kind == "gaussians":
            return np.asarray(self._frame.solidify(lattice_offset=tuple(offset)).points, np.float64)
        return resample_cubes(self._solid, spacing, offset)


def _mesh_solid(mesh, spacing: float, offset, watertight: bool) -> np.ndarray:
    import open3d as o3d  # noqa: PLC0415 - heavy; only a mesh needs it

    from fluidsim.sources import mesh_particles, points_inside_mesh  # noqa: PLC0415

    verts = np.asarray(mesh.vertices)
    if watertight:
        cand = lattice_points(verts.min(0), verts.max(0), spacing, offset)
        return cand[points_inside_mesh(mesh, cand)] if len(cand) else cand
    surface = mesh_particles(o3d.geometry.TriangleMesh(mesh), spacing, fill=False)
    keys = np.unique(lattice_keys(surface, spacing, offset), axis=0)
    return (keys + np.asarray(offset, np.float64)) * spacing


MATRIX_FILE_BYTES = 1 << 16  # a 4 x 4 matrix as text or .npy is a few hundred bytes


def matrix_file(text: str | None) -> Path | None:
    """The file ``--reference-transform`` names (a .npy/.txt/.json path), else None (numbers or no option)."""
    return Path(text) if text is not None and Path(text).suffix in (".npy", ".txt", ".json") else None


def parse_matrix(text: str | None) -> np.ndarray | None:
    """A 4 x 4 transform from 16 comma- or space-separated numbers (row-major) or a .npy/.txt/.json file; None: none.

    Raises:
        ValueError: naming the option, when the file is missing, not a regular file or too large, or when it is not
            16 finite numbers with an invertible 3 x 3 part.
    """
    if text is None:
        return None
    p = matrix_file(text)
    if p is not None and not p.is_file():
        what = "does not exist" if not p.exists() else "is not a regular file"
        raise ValueError(f"--reference-transform {p} {what}; pass a .npy, .txt or .json file or 16 numbers")
    if p is not None and p.stat().st_size > MATRIX_FILE_BYTES:
        raise ValueError(
            f"--reference-transform {p}: {p.stat().st_size:,} bytes, too large for a 4 x 4 matrix; pass its 16 numbers"
        )
    try:
        if p is not None and p.suffix == ".npy":
            values = np.load(p, allow_pickle=False)
        elif p is not None:
            values = np.array(p.read_text().replace("[", " ").replace("]", " ").replace(",", " ").split(), float)
        else:
            values = np.array(str(text).replace(",", " ").split(), float)
    except (ValueError, OSError) as exc:
        raise ValueError(f"--reference-transform {text!r}: not 16 numbers ({exc}); give 16 numbers, row-major") from exc
    m = np.asarray(values, np.float64).reshape(-1)
    if m.size != 16:
        raise ValueError(f"--reference-transform: {m.size} numbers given; give the 16 of a 4 x 4 matrix, row-major")
    if not np.isfinite(m).all():
        raise ValueError(
            f"--reference-transform: {int((~np.isfinite(m)).sum())} of its 16 numbers are not finite (NaN or Inf); "
            "give 16 finite numbers"
        )
    m = m.reshape(4, 4)
    if abs(np.linalg.det(m[:3, :3])) < 1e-12 or not np.allclose(m[3], [0, 0, 0, 1]):
        raise ValueError("--reference-transform: its 3 x 3 part is singular or its last row is not 0 0 0 1")
    return m


def _load_mesh(path: Path, matrix: np.ndarray | None):
    import open3d as o3d  # noqa: PLC0415

    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        mesh = o3d.io.read_triangle_mesh(str(path))
    if len(mesh.triangles) == 0:
        raise ValueError(f"{path}: no triangles read; pass a triangle mesh (.obj, .stl, .ply, .glb)")
    if not np.isfinite(np.asarray(mesh.vertices)).all():
        raise ValueError(f"{path}: the mesh has NaN or Inf vertex coordinates; fix the file")
    # an STL stores each triangle's corners apart: merged, so that a closed mesh reads as watertight (has an inside)
    mesh.remove_duplicated_vertices()
    if matrix is not None:
        mesh.transform(matrix)
    return mesh


def _auto_scale(points_scene: np.ndarray, config: PhysicsConfig, up) -> float:
    if config.scale != "auto":
        return float(config.scale)
    rotated = points_scene @ rotation_to_y_up(np.asarray(SceneTransform(up).up)).T
    extent = float(np.ptp(rotated, axis=0).max())
    if not extent > 0:
        raise ValueError("the reference has no extent; pass --scale")
    return config.target_extent / extent


def reference_source(path: Path, config: PhysicsConfig, matrix: np.ndarray | None, load_gaussians) -> SolidSource:
    """The reference: its solid maker and the frame (up and scale, ``config.scale`` "auto" resolved on it).

    Args:
        path: a mesh, a Gaussian file or a RESULT.h5. config: the probe settings. matrix: 4 x 4 taking the
            reference into the reconstruction's scene frame (None: they share it). load_gaussians: reads a Gaussian
            file (the command's reader, with its options).
    """
    path = Path(path)
    if is_result_file(path):
        from nbv.physics.result import load_result  # noqa: PLC0415

        res = load_result(path)
        if matrix is not None:
            raise ValueError(
                f"{path}: a RESULT.h5 reference is already in its simulation frame; drop --reference-transform "
                "or pass the reference's mesh or Gaussians"
            )
        if abs(2.0 * res.config.particle_radius - 2.0 * config.particle_radius) > 1e-12:
            raise ValueError(
                f"{path} was simulated at r = {res.config.particle_radius} m but the comparison runs at "
                f"r = {config.particle_radius} m; pass --particle-radius {res.config.particle_radius} or the mesh"
            )
        return SolidSource(path, "result", res.transform, (), _solid=np.asarray(res.solid, np.float64))
    if is_mesh_file(path):
        mesh = _load_mesh(path, matrix)
        warnings = ()
        if not mesh.is_watertight():
            warnings = (
                f"the reference mesh {path.name} is not watertight (it has no inside): its solid is sampled on its "
                "surface, a shell one spacing thick",
            )
            log.warning(warnings[0])
        up = config.up if config.up != "auto" else "+y"
        transform = SceneTransform(up, _auto_scale(np.asarray(mesh.vertices), config, up))
        return SolidSource(path, "mesh", transform, warnings, _mesh=o3d_transformed(mesh, transform))
    from nbv.physics.plan import RunFrame  # noqa: PLC0415

    if matrix is not None:
        raise ValueError(
            f"{path}: --reference-transform applies to a mesh reference; transform the Gaussians with your own tool "
            "first, or pass the reference as a mesh"
        )
    frame = RunFrame.of(load_gaussians(path), config, str(path))
    return SolidSource(path, "gaussians", frame.transform, (), _frame=frame)


def o3d_transformed(mesh, transform: SceneTransform):
    """A copy of ``mesh`` in simulation metres (``transform``)."""
    import open3d as o3d  # noqa: PLC0415

    out = o3d.geometry.TriangleMesh(mesh)
    out.transform(transform.matrix)
    return out


def reconstruction_source(path: Path, config: PhysicsConfig, transform: SceneTransform, load_gaussians) -> SolidSource:
    """The reconstruction in the reference's frame (``transform``): a Gaussian file, a mesh or a RESULT.h5."""
    path = Path(path)
    if is_result_file(path):
        from nbv.physics.result import load_result  # noqa: PLC0415

        res = load_result(path)
        spacing = 2.0 * config.particle_radius
        on_lattice = np.round(transform.to_sim(res.transform.to_scene(res.solid)) / spacing) * spacing
        return SolidSource(path, "result", transform, (), _solid=np.unique(on_lattice, axis=0))
    if is_mesh_file(path):
        mesh = _load_mesh(path, None)
        warnings = () if mesh.is_watertight() else (f"{path.name} is not watertight: sampled on its surface",)
        return SolidSource(path, "mesh", transform, warnings, _mesh=o3d_transformed(mesh, transform))
    from nbv.physics.plan import RunFrame  # noqa: PLC0415

    frame = RunFrame.of(load_gaussians(path), replace(config, scale=transform.scale, up=transform.up), str(path))
    return SolidSource(path, "gaussians", transform, (), _frame=frame)
