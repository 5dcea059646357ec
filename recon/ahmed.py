"""A procedural Ahmed body, the standard car-aerodynamics reference shape, as a watertight triangle mesh.

Dimensions follow Ahmed, Ramm & Faltin (1984), "Some salient features of the time-averaged ground vehicle wake",
SAE 840300: a body 1044 mm long, 389 mm wide and 288 mm high; the front is rounded with a radius of 100 mm in
the side view and in the plan view; the rear has a flat slant of 222 mm (measured along the slanted surface) at
an angle phi (25 deg by default, 0-40 deg here) above a vertical base; the body stands 50 mm above the ground
on four cylindrical stilts 30 mm in diameter. The stilt positions are not given in the paper's text; we use
those of common CAD renditions of the model: axes 202 mm behind the nose and 372 mm ahead of the base,
163.5 mm either side of the centre plane.

Shape. The body is the intersection of two prisms: the side-view profile (rectangle with the two front corners
rounded and the rear top corner cut by the slant) extruded across the width, and the plan-view profile (the two
front corners rounded) extruded vertically. So the longitudinal edges stay sharp, every cross-section at a
station x is a rectangle y in [y_lo(x), y_hi(x)], |z| <= z_half(x), and the body is a loft of such rectangles:
consecutive sections are joined by quads split into triangles, and the flat nose face and the base are capped
with grids. The stilts are cylinders stitched into the underside through a triangulated annulus, so the mesh
is one closed, consistently oriented 2-manifold.

Frame (metres, right-handed): X along the length with the nose at +x (a probe flowing toward -x meets the
front like a head wind), Y up with the ground at y = 0 (the stilts' feet), Z across; the body is centred at
x = 0 and z = 0. Its underside is at y = 0.05 with or without stilts.

Example:
    >>> mesh = ahmed_body(25.0)
    >>> mesh.is_watertight()
    True
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
import open3d as o3d
import torch

from fluidsim.files import atomic_output

from .gaussians import GaussianSet

MESH_SUFFIXES = (".obj", ".stl", ".ply", ".off", ".gltf", ".glb")


# The finest mesh edge: the triangle count grows as 1 / resolution^2 (35,492 at 0.01 m), and 1e-9 m asked for 10^20
# triangles, so the machine ran out of memory before any message.
MIN_RESOLUTION = 0.001


@dataclass(frozen=True)
class AhmedBody:
    """Geometry of the Ahmed body, metres and degrees (defaults: Ahmed et al. 1984).

    Attributes:
        slant_deg: rear slant angle phi, 0 to 40 degrees.
        stilts: add the four cylindrical stilts.
        resolution: target edge length of the mesh [m] (the rounded nose and stilts get at least 8 and 24
            segments per quarter circle and circle).
        length, width, height: body dimensions without stilts [m].
        front_radius: radius of the four rounded front edges [m].
        slant_length: length of the slanted surface, measured along it [m].
        clearance: height of the underside above the ground, the stilt length [m].
        stilt_diameter: [m].
        stilt_from_nose, stilt_from_base: distance of the front / rear stilt axes from the nose / base [m].
        stilt_half_track: distance of the stilt axes from the centre plane z = 0 [m].
    """

    slant_deg: float = 25.0
    stilts: bool = True
    resolution: float = 0.01
    length: float = 1.044
    width: float = 0.389
    height: float = 0.288
    front_radius: float = 0.100
    slant_length: float = 0.222
    clearance: float = 0.050
    stilt_diameter: float = 0.030
    stilt_from_nose: float = 0.202
    stilt_from_base: float = 0.372
    stilt_half_track: float = 0.1635

    def __post_init__(self) -> None:
        for field in fields(self)[2:]:  # every length: the fields after slant_deg and stilts
            value = getattr(self, field.name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(f"AhmedBody.{field.name} must be a finite number > 0, got {value!r}")
        if not (isinstance(self.slant_deg, int | float) and 0.0 <= self.slant_deg <= 40.0):
            raise ValueError(f"AhmedBody.slant_deg must be in [0, 40] degrees, got {self.slant_deg!r}")
        r = self.front_radius
        if 2 * r >= min(self.width, self.height):
            raise ValueError(f"AhmedBody.front_radius {r} must be below half the width and height")
        if self.slant_run + r >= self.length:
            raise ValueError(f"AhmedBody.slant_length {self.slant_length} leaves no straight roof before the nose")
        if self.slant_drop >= self.height:
            raise ValueError(
                f"AhmedBody.slant_length {self.slant_length} at {self.slant_deg} deg cuts through "
                f"the whole height {self.height}"
            )
        if self.resolution < MIN_RESOLUTION:  # about 35,000 x (0.01 / resolution)^2 triangles: 3.5 million here
            raise ValueError(
                f"AhmedBody.resolution {self.resolution} m is finer than {MIN_RESOLUTION} m, which already makes "
                "about 3.5 million triangles; use a coarser resolution (default 0.01)"
            )
        if self.resolution > min(self.width, self.height) / 4:
            raise ValueError(
                f"AhmedBody.resolution {self.resolution} m is coarser than a quarter of the body; "
                f"use at most {min(self.width, self.height) / 4:.3f}"
            )
        if self.stilts:
            margin = self.stilt_diameter
            xs = [self.length - self.stilt_from_nose, self.stilt_from_base]
            if (
                not all(self.slant_run + margin < x < self.length - r - margin for x in xs)
                or not 0 < self.stilt_half_track < self.width / 2 - margin
            ):
                raise ValueError(
                    "AhmedBody stilt positions must lie under the flat underside, clear of the nose "
                    "and the slant (stilt_from_nose, stilt_from_base, stilt_half_track)"
                )

    @property
    def slant_run(self) -> float:
        """Horizontal extent of the slant [m]: slant_length cos(phi)."""
        return self.slant_length * math.cos(math.radians(self.slant_deg))

    @property
    def slant_drop(self) -> float:
        """Vertical extent of the slant [m]: slant_length sin(phi); the base is height - slant_drop high."""
        return self.slant_length * math.sin(math.radians(self.slant_deg))

    def section(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The rectangular cross-section at body-frame stations ``x`` (0 = base, length = nose).

        Returns:
            (y_lo, y_hi, z_half), each like ``x``: the section is y_lo <= y <= y_hi above the underside (y = 0)
            and |z| <= z_half.
        """
        x = np.asarray(x, dtype=np.float64)
        r = self.front_radius
        tip = np.clip(self.length - x, 0.0, r)  # distance behind the nose tip, within the rounding
        bulge = np.sqrt(tip * (2 * r - tip))  # r where the nose rounding starts, exactly 0 at the tip
        y_lo = r - bulge
        y_hi = np.minimum(
            self.height - r + bulge,
            self.height - np.clip(self.slant_run - x, 0.0, None) * math.tan(math.radians(self.slant_deg)),
        )
        z_half = self.width / 2 - r + bulge
        return y_lo, y_hi, z_half

    def stilt_axes(self) -> list[tuple[float, float]]:
        """(x, z) of the four stilt axes in the body frame."""
        xs = (self.length - self.stilt_from_nose, self.stilt_from_base)
        return [(x, s * self.stilt_half_track) for x in xs for s in (-1.0, 1.0)]


def _spaced(a: float, b: float, step: float) -> np.ndarray:
    """Points from a to b (both included) at most ``step`` apart."""
    n = max(1, math.ceil((b - a) / step - 1e-9))
    return np.linspace(a, b, n + 1)


class _MeshBuilder:
    def __init__(self) -> None:
        self.vertices: list[np.ndarray] = []
        self.triangles: list[np.ndarray] = []
        self.count = 0

    def add_vertices(self, v: np.ndarray) -> np.ndarray:
        v = np.asarray(v, dtype=np.float64).reshape(-1, 3)
        ids = np.arange(self.count, self.count + len(v))
        self.vertices.append(v)
        self.count += len(v)
        return ids

    def add_triangles(self, t) -> None:
        self.triangles.append(np.asarray(t, dtype=np.int64).reshape(-1, 3))


def _orient(vertices: np.ndarray, tris: np.ndarray, outward: np.ndarray) -> np.ndarray:
    """Flip the triangles whose normal points against ``outward`` ([T, 3] or one [3] direction)."""
    a, b, c = (vertices[tris[:, i]] for i in range(3))
    flip = (np.cross(b - a, c - a) * outward).sum(1) < 0
    tris = tris.copy()
    tris[flip] = tris[flip][:, [0, 2, 1]]
    return tris


def _zip_loops(outer: np.ndarray, inner: np.ndarray, points: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Triangulate the planar ring between two closed loops around ``centre`` (x, z), merging them by angle."""

    def by_angle(ids):  # the loop sorted by angle and closed: its first point again at the end, one turn later
        ang = np.arctan2(points[ids, 2] - centre[1], points[ids, 0] - centre[0]) % (2 * math.pi)
        order = np.argsort(ang)
        return np.r_[ids[order], ids[order[0]]], np.r_[ang[order], ang[order[0]] + 2 * math.pi]

    o_ids, o_ang = by_angle(outer)
    i_ids, i_ang = by_angle(inner)
    tris, i, j = [], 0, 0
    while i < len(o_ids) - 1 or j < len(i_ids) - 1:
        if j == len(i_ids) - 1 or (i < len(o_ids) - 1 and o_ang[i + 1] <= i_ang[j + 1]):
            tris.append((o_ids[i], o_ids[i + 1], i_ids[j]))
            i += 1
        else:
            tris.append((o_ids[i], i_ids[j + 1], i_ids[j]))
            j += 1
    return np.array(tris, dtype=np.int64)


def _stations(body: AhmedBody, hole: float) -> np.ndarray:
    """Sections along the length [m]: the slant, the straight part (with breaks at the stilt openings, ``hole`` the
    half-size of each), and the nose arc at equal angles (tip exact)."""
    res, r, length = body.resolution, body.front_radius, body.length
    breaks = [0.0, body.slant_run]
    if body.stilts:
        for x in sorted({x for x, _ in body.stilt_axes()}):
            breaks += [x - hole, x + hole]
    breaks.append(length - r)
    straight = np.concatenate([_spaced(a, b, res)[:-1] for a, b in zip(breaks[:-1], breaks[1:], strict=True)])
    n_arc = max(8, math.ceil(0.5 * math.pi * r / res))
    nose = length - r * (1.0 - np.sin(np.linspace(0.0, 0.5 * math.pi, n_arc + 1)))  # equal angles, tip exact
    return np.concatenate([straight, nose])


def _add_stilts(mb: _MeshBuilder, body: AhmedBody, openings: list) -> None:
    """Each stilt: the annulus between its underside opening ``ring`` and its circle, the cylinder wall and the foot."""
    res, stilt_r = body.resolution, body.stilt_diameter / 2
    n_circle = max(24, math.ceil(2 * math.pi * stilt_r / res))
    phi = np.linspace(0.0, 2 * math.pi, n_circle, endpoint=False)
    down = np.array([0.0, -1.0, 0.0])
    for xc, zc, ring in openings:
        circle = np.stack([xc + stilt_r * np.cos(phi), np.zeros(n_circle), zc + stilt_r * np.sin(phi)], 1)
        top = mb.add_vertices(circle)
        foot = mb.add_vertices(circle - [0.0, body.clearance, 0.0])
        centre_id = mb.add_vertices([xc, -body.clearance, zc])[0]
        verts = np.concatenate(mb.vertices)
        annulus = _zip_loops(ring, top, verts, np.array([xc, zc]))
        mb.add_triangles(_orient(verts, annulus, down))
        nxt = np.roll(np.arange(n_circle), -1)
        wall = np.concatenate([np.stack([top, top[nxt], foot[nxt]], 1), np.stack([top, foot[nxt], foot], 1)])
        radial = verts[wall].mean(1) - [xc, 0.0, zc]
        radial[:, 1] = 0.0
        mb.add_triangles(_orient(verts, wall, radial))
        fan = np.stack([np.full(n_circle, centre_id), foot, foot[nxt]], 1)
        mb.add_triangles(_orient(verts, fan, down))


def ahmed_mesh_arrays(body: AhmedBody) -> tuple[np.ndarray, np.ndarray]:
    """Vertices [V, 3] (m, in the module's frame) and outward-oriented triangles [T, 3] of ``body``."""
    res, length = body.resolution, body.length
    hole = 1.6 * body.stilt_diameter / 2  # half-size of the square opening in the underside around each stilt
    stations = _stations(body, hole)
    y_lo, y_hi, z_half = body.section(stations)
    # ---- section loops: bottom edge (z up), right side (y up), top edge (z down), left side (y down) ---------
    kz = max(4, math.ceil(body.width / res))
    ky = max(4, math.ceil(body.height / res))
    t = np.linspace(-1.0, 1.0, kz + 1)
    s = np.linspace(0.0, 1.0, ky + 1)
    loop_t = np.r_[t, np.ones(ky - 1), t[::-1], -np.ones(ky - 1)]  # z / z_half
    loop_s = np.r_[np.zeros(kz + 1), s[1:-1], np.ones(kz + 1), s[-2:0:-1]]  # (y - y_lo) / (y_hi - y_lo)
    n_loop = len(loop_t)
    mb = _MeshBuilder()
    x, lo, hi, zh = (a[:, None] for a in (stations, y_lo, y_hi, z_half))
    secs = np.stack(np.broadcast_arrays(x, lo + loop_s * (hi - lo), loop_t * zh), -1)
    ids = mb.add_vertices(secs).reshape(len(stations), n_loop)
    # ---- lateral surface: quads between consecutive sections, minus the stilt openings in the underside --------
    keep = np.ones((len(stations) - 1, n_loop), dtype=bool)
    openings = []
    if body.stilts:
        z_grid = t * body.width / 2
        for xc, zc in body.stilt_axes():
            i0, i1 = int(np.argmin(abs(stations - (xc - hole)))), int(np.argmin(abs(stations - (xc + hole))))
            j0 = int(np.searchsorted(z_grid, zc - hole, side="right")) - 1
            j1 = int(np.searchsorted(z_grid, zc + hole, side="left"))
            keep[i0:i1, j0:j1] = False
            ring = np.r_[ids[i0, j0:j1], ids[i0:i1, j1], ids[i1, j1:j0:-1], ids[i1:i0:-1, j0]]
            openings.append((xc, zc, ring))
    i, p = np.nonzero(keep)
    q = (p + 1) % n_loop
    a, b, c, d = ids[i, p], ids[i, q], ids[i + 1, q], ids[i + 1, p]
    lateral = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    # ---- caps: the base (x = 0) and the flat nose face (x = length), grids matching the section loops ------
    cap_tris = []
    for k, x in ((0, stations[0]), (len(stations) - 1, stations[-1])):
        grid = np.empty((ky + 1, kz + 1), dtype=np.int64)
        grid[0, :] = ids[k, : kz + 1]
        grid[1:ky, kz] = ids[k, kz + 1 : kz + ky]
        grid[ky, :] = ids[k, kz + ky : 2 * kz + ky + 1][::-1]
        grid[1:ky, 0] = ids[k, 2 * kz + ky + 1 :][::-1]
        yy, zz = np.meshgrid(y_lo[k] + s[1:-1] * (y_hi[k] - y_lo[k]), t[1:-1] * z_half[k], indexing="ij")
        grid[1:ky, 1:kz] = mb.add_vertices(np.stack([np.full(yy.shape, x), yy, zz], -1)).reshape(ky - 1, kz - 1)
        g00, g01, g11, g10 = grid[:-1, :-1], grid[:-1, 1:], grid[1:, 1:], grid[1:, :-1]
        cap_tris += [np.stack([g00, g01, g11], -1).reshape(-1, 3), np.stack([g00, g11, g10], -1).reshape(-1, 3)]
    body_tris = np.concatenate([lateral, *cap_tris])
    verts = np.concatenate(mb.vertices)
    centre = np.array([length / 2, body.height / 2, 0.0])  # the body is convex: faces look away from its centre
    mb.add_triangles(_orient(verts, body_tris, verts[body_tris].mean(1) - centre))
    _add_stilts(mb, body, openings)
    return np.concatenate(mb.vertices) + [-length / 2, body.clearance, 0.0], np.concatenate(mb.triangles)


def ahmed_body(
    slant_deg: float = 25.0, resolution: float = 0.01, *, stilts: bool = True, up: str = "y", scale: float = 1.0
) -> o3d.geometry.TriangleMesh:
    """The Ahmed body as a watertight open3d triangle mesh (frame and dimensions in the module docstring).

    Args:
        slant_deg: rear slant angle, 0 to 40 degrees (25 is the low-drag reference, 35 the high-drag one).
        resolution: target edge length [m].
        stilts: add the four stilts (50 mm long, 30 mm diameter); the body is 50 mm above y = 0 either way.
        up: "y" (default frame) or "z" (rotated +90 deg about x: y -> z, z -> -y; the nose stays at +x).
        scale: multiply all coordinates (1000 gives millimetres).
    Returns:
        A TriangleMesh with vertex and triangle normals, outward-oriented.
    """
    if up not in ("y", "z"):
        raise ValueError(f"up must be 'y' or 'z', got {up!r}")
    if not (math.isfinite(scale) and 1e-6 <= scale <= 1e6):  # 1e300 overflowed the volume to NaN
        raise ValueError(f"scale must be a number from 1e-06 to 1e+06 (1000 gives millimetres), got {scale!r}")
    verts, tris = ahmed_mesh_arrays(AhmedBody(slant_deg=slant_deg, stilts=stilts, resolution=resolution))
    if up == "z":
        verts = np.stack([verts[:, 0], -verts[:, 2], verts[:, 1]], 1)
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(verts * scale), o3d.utility.Vector3iVector(tris.astype(np.int32))
    )
    mesh.compute_triangle_normals()
    mesh.compute_vertex_normals()
    return mesh


def enclosed_volume(mesh: o3d.geometry.TriangleMesh) -> float:
    """Signed volume [units^3] enclosed by a closed, outward-oriented mesh (divergence theorem).

    Unlike ``TriangleMesh.get_volume`` it skips the watertightness test (a self-intersection search that takes
    seconds on a fine mesh); :func:`ahmed_body` meshes are closed by construction and tested to be.
    """
    v, t = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    return float(np.einsum("ij,ij->i", v[t[:, 0]], np.cross(v[t[:, 1]], v[t[:, 2]])).sum() / 6.0)


def save_mesh(mesh: o3d.geometry.TriangleMesh, path: str | Path) -> Path:
    """Write ``mesh`` to ``path`` (.obj, .stl, .ply, .off, .gltf or .glb) atomically
    (:func:`~fluidsim.files.atomic_output`: a temporary file with the same suffix in the same folder,
    renamed into place).

    Returns:
        The written path.
    Raises:
        ValueError: an unsupported suffix (nothing is written).
        fluidsim.files.OutputError: open3d could not write the file (an OSError, exit code 4 of `fluidgs`).
    """
    path = Path(path)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise ValueError(f"{path}: unsupported mesh file type {path.suffix!r}; use one of {list(MESH_SUFFIXES)}")
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(path, path.suffix) as tmp:  # open3d picks the writer by suffix
        with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):  # OBJ cannot hold face normals
            written = o3d.io.write_triangle_mesh(str(tmp), mesh, write_vertex_normals=path.suffix.lower() != ".stl")
        if not written:
            raise OSError("open3d could not write the mesh")
    return path


def write_ahmed(
    path: str | Path,
    slant_deg: float = 25.0,
    resolution: float = 0.01,
    *,
    stilts: bool = True,
    up: str = "y",
    scale: float = 1.0,
) -> Path:
    """Write :func:`ahmed_body` (same arguments) to ``path`` with :func:`save_mesh`; returns the path."""
    return save_mesh(ahmed_body(slant_deg, resolution, stilts=stilts, up=up, scale=scale), path)


def ahmed_surface_gaussians(count: int = 4000, sigma: float = 0.02, seed: int = 0):
    """Gaussians on the Ahmed body surface (metres, Y-up): ``count`` Poisson-disk samples, isotropic ``sigma`` m,
    opacity 0.9, coloured light grey; stand-ins for the trained asset (``fluidgs demo`` and ``bench score`` when
    ``assets/ahmed_gaussians.ply`` is missing). Returns a :class:`recon.gaussians.GaussianSet`."""
    o3d.utility.random.seed(seed)
    pcd = ahmed_body(resolution=0.02).sample_points_poisson_disk(count)
    pts = torch.tensor(np.asarray(pcd.points), dtype=torch.float32)
    return GaussianSet.from_points(pts, torch.full((len(pts), 3), 0.8), scale=sigma, opacity=0.9)
