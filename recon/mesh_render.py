"""Render a triangle mesh into a Blender-format multi-view dataset with CPU ray casting (open3d).

This replaces the Blender + BlenderNeRF step of the paper's appendix ("Rendering" of DrivAerNet++):
"We set the axis-aligned bounding box to 4 and used a camera radius of 6. The first 200 rendered images
were used for training or as candidate views, and another 100 were reserved for testing. The camera order
was randomized. We set the background to transparent and assigned the object a gray color with hex code
#909090." :class:`MeshDatasetConfig` holds exactly these defaults.

Pipeline (:func:`render_mesh_dataset`):

1. Read the ``.obj`` / ``.stl`` / ``.ply`` mesh and normalise it: centre its axis-aligned bounding box at
   the origin and scale it so the largest extent is ``box_size``; axes are kept (no rotation), so the
   input's up axis (``up_axis``, "y" or "z") stays the scene's up axis.
2. Draw ``n_train + n_test`` cameras uniformly on the sphere of radius ``radius`` (or the upper
   hemisphere) with :func:`recon.camera_paths.random_sphere` and ``seed``; the first ``n_train`` are the
   train / candidate views, the rest the test views. Each camera looks at the origin with the up axis up.
3. Cast ``supersample`` x ``supersample`` rays per pixel through :class:`~recon.camera.Camera`'s own
   intrinsics and pose (:func:`camera_rays`), so the images follow the loader's conventions by construction.
4. Shade hits with Lambert + ambient (:func:`shade`), the triangle normal flipped to face the camera. The
   lights (:func:`light_directions`) are fixed in the world, not headlights, so the radiance of a surface
   point is the same from every view, which is what a 3DGS model with view-independent colour can
   reproduce. No shadows, no gamma.
5. Alpha is the fraction of sub-pixel rays that hit (255 on full hits, 0 on the background); colour is
   the mean over the hits (straight alpha, as NeRF-synthetic's PNGs).

Output (written to a temporary folder next to the target, then renamed into place)::

    DIR/train/r_000.png ...      RGBA, n_train views
    DIR/test/r_000.png ...       RGBA, n_test views
    DIR/transforms_train.json    camera_angle_x (radians), frames (file_path without extension, OpenGL c2w)
    DIR/transforms_test.json
    DIR/transforms_val.json      the test frames again (NeRF tools expect a val split; the active loop uses
                                 train as the candidate pool and test for evaluation)
    DIR/mesh.ply                 the normalised mesh, in the cameras' frame (reference for Chamfer distance)
    DIR/dataset.json             source mesh, normalisation (mesh.ply = scale * source + offset), up axis,
                                 config, seed, lights

Resolution: the paper's images are 800 x 800; the default here is 256 x 256 so a 300-view dataset renders
in seconds on a CPU (pass ``resolution=800`` for the paper's size). Field of view: 50 degrees, so an object
whose bounding sphere has radius up to ``radius * sin(25 deg)`` = 2.54 (e.g. a car of 4 x 1.8 x 1.5, radius
2.3) is never cut by the image border; a warning is logged when the normalised mesh's bounding sphere is
larger (a full 4 x 4 x 4 cube would need 71 degrees).

Example:
    >>> config = MeshDatasetConfig(n_train=20, n_test=10)
    >>> render_mesh_dataset("assets/torus.obj", "data/torus", config)  # doctest: +SKIP
"""

from __future__ import annotations

import json
import logging
import math
import os
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from fluidsim.files import OutputError, atomic_folder

from .camera import Camera
from .camera_paths import UP_AXES, random_sphere

logger = logging.getLogger(__name__)

MESH_SUFFIXES = (".obj", ".stl", ".ply")
KEY_WEIGHT, FILL_WEIGHT = 0.7, 0.3


MAX_VIEWS = 10_000  # views of one dataset (train + test)
MAX_RAY_SIDE = 4096  # rays per image side (resolution x supersample): 2^24 rays, about 2.5 GB in memory per view


@dataclass(frozen=True)
class MeshDatasetConfig:
    """Settings of a rendered mesh dataset (defaults: the paper's appendix, at 256 px).

    Attributes:
        n_train: train / candidate views (paper: 200).
        n_test: test views (paper: 100).
        resolution: image width = height, pixels (paper: 800; 256 runs on a CPU).
        fov_x: horizontal (= vertical) field of view, degrees.
        box_size: largest extent of the normalised object, scene units (paper: 4).
        radius: camera distance from the object's centre, scene units (paper: 6).
        color: object colour, "#RRGGBB" (paper: #909090).
        ambient: ambient term of the shading, in [0, 1].
        up_axis: the input mesh's up axis, "y" or "z"; cameras keep it up in the images.
        hemisphere: cameras only on the upper hemisphere (a car on a road) instead of the full sphere.
        seed: seed of the camera positions.
        supersample: s x s rays per pixel (1 = aliased edges and binary alpha).
    """

    n_train: int = 200
    n_test: int = 100
    resolution: int = 256
    fov_x: float = 50.0
    box_size: float = 4.0
    radius: float = 6.0
    color: str = "#909090"
    ambient: float = 0.25
    up_axis: str = "y"
    hemisphere: bool = False
    seed: int = 0
    supersample: int = 2

    def __post_init__(self) -> None:
        for key, low in (("n_train", 1), ("n_test", 0), ("resolution", 8), ("supersample", 1)):
            val = getattr(self, key)
            if isinstance(val, bool) or int(val) != val or val < low:
                raise ValueError(f"MeshDatasetConfig.{key} must be an integer >= {low}, got {val!r}")
        if self.supersample > 8:
            raise ValueError(f"MeshDatasetConfig.supersample must be <= 8 rays per side, got {self.supersample}")
        if self.n_train + self.n_test > MAX_VIEWS:  # bounded before any work: 10^8 views ran silent for hours
            raise ValueError(
                f"MeshDatasetConfig.n_train + MeshDatasetConfig.n_test must be at most {MAX_VIEWS:,} views (the "
                f"paper's 200 + 100), got {self.n_train} + {self.n_test}"
            )
        if self.resolution * self.supersample > MAX_RAY_SIDE:
            raise ValueError(
                f"MeshDatasetConfig.resolution must be at most {MAX_RAY_SIDE // self.supersample} pixels at "
                f"MeshDatasetConfig.supersample {self.supersample} (at most {MAX_RAY_SIDE}^2 rays a view, about 150 "
                f"bytes each in memory), got {self.resolution}"
            )
        if not 1.0 <= self.fov_x <= 170.0:
            raise ValueError(f"MeshDatasetConfig.fov_x must be in [1, 170] degrees, got {self.fov_x}")
        for key in ("box_size", "radius"):
            val = getattr(self, key)
            if not (math.isfinite(val) and val > 0):
                raise ValueError(f"MeshDatasetConfig.{key} must be finite and > 0, got {val}")
        if self.radius <= 0.5 * self.box_size:
            raise ValueError(
                f"MeshDatasetConfig.radius ({self.radius}) must exceed half the box_size "
                f"({self.box_size}) so the cameras are outside the object"
            )
        if not 0.0 <= self.ambient <= 1.0:
            raise ValueError(f"MeshDatasetConfig.ambient must be in [0, 1], got {self.ambient}")
        if self.up_axis not in UP_AXES:
            raise ValueError(f"MeshDatasetConfig.up_axis must be 'y' or 'z', got {self.up_axis!r}")
        if int(self.seed) != self.seed:
            raise ValueError(f"MeshDatasetConfig.seed must be an integer, got {self.seed!r}")
        parse_color(self.color)

    @property
    def fov_x_rad(self) -> float:
        return math.radians(self.fov_x)


def parse_color(color: str) -> np.ndarray:
    """[3] RGB in [0, 1] of a "#RRGGBB" string."""
    text = str(color).strip()
    if len(text) != 7 or text[0] != "#":
        raise ValueError(f"color must be '#RRGGBB' (e.g. '#909090'), got {color!r}")
    try:
        return np.array([int(text[i : i + 2], 16) for i in (1, 3, 5)], dtype=np.float64) / 255.0
    except ValueError as exc:
        raise ValueError(f"color must be '#RRGGBB' with hexadecimal digits, got {color!r}") from exc


def light_directions(up_axis: str) -> tuple[np.ndarray, np.ndarray]:
    """Unit directions towards the key and fill lights, fixed in the world.

    With (a, u, b) = the right-handed axes whose second is the up axis ((x, y, z) for "y", (y, z, x) for
    "z"): key = (0.5, 1, 0.3) normalised (above, front-right), fill = (-0.6, -0.4, -0.7) normalised.
    """
    if up_axis not in UP_AXES:
        raise ValueError(f"up_axis must be 'y' or 'z', got {up_axis!r}")
    basis = np.eye(3) if up_axis == "y" else np.eye(3)[[1, 2, 0]]  # rows a, u, b in world coordinates
    key = np.array([0.5, 1.0, 0.3]) @ basis
    fill = np.array([-0.6, -0.4, -0.7]) @ basis
    return key / np.linalg.norm(key), fill / np.linalg.norm(fill)


# ---- mesh ------------------------------------------------------------------------------------------


def load_mesh(path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices [V, 3] float64 and triangles [T, 3] int64 of a ``.obj`` / ``.stl`` / ``.ply`` mesh.

    Raises ValueError naming the file when it is missing, has another suffix, cannot be read, has no
    triangles, non-finite vertices or zero extent.
    """
    import open3d as o3d  # noqa: PLC0415 - open3d takes ~1.8 s to import

    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{path}: is a folder; pass a mesh file ({', '.join(MESH_SUFFIXES)})")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise ValueError(f"{path}: mesh must be one of {', '.join(MESH_SUFFIXES)}, got {path.suffix or 'no suffix'!r}")
    if not path.is_file():
        raise ValueError(f"{path}: mesh file does not exist")
    if not os.access(path, os.R_OK):
        raise ValueError(f"{path}: mesh file is not readable; check its permissions")
    mesh = o3d.io.read_triangle_mesh(str(path))
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    triangles = np.asarray(mesh.triangles, dtype=np.int64)
    if len(triangles) == 0 or len(vertices) == 0:
        raise ValueError(
            f"{path}: no triangles read (an unreadable file or a point cloud); render-dataset needs a surface mesh"
        )
    if not np.isfinite(vertices).all():
        raise ValueError(f"{path}: the mesh has non-finite vertex coordinates")
    if np.ptp(vertices[np.unique(triangles)], axis=0).max() <= 0:
        raise ValueError(f"{path}: the mesh has zero extent")
    return vertices, triangles


def normalize_vertices(
    vertices: np.ndarray, triangles: np.ndarray, box_size: float
) -> tuple[np.ndarray, float, np.ndarray]:
    """Centre the bounding box of the used vertices at the origin and scale its largest extent to box_size.

    Returns:
        (normalised vertices [V, 3], scale, offset [3]) with normalised = scale * vertices + offset.
    """
    used = vertices[np.unique(triangles)]
    lo, hi = used.min(axis=0), used.max(axis=0)
    scale = box_size / float((hi - lo).max())
    offset = -scale * 0.5 * (lo + hi) + 0.0  # + 0.0 turns -0.0 into 0.0 in the written JSON
    return vertices * scale + offset, scale, offset


# ---- rays ------------------------------------------------------------------------------------------


def camera_rays(camera: Camera, supersample: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Ray origins and directions through the sub-pixel centres of a camera.

    Pixel (i, j) (column i, row j) is split into s x s sub-pixels with centres (i + (k + 0.5) / s,
    j + (l + 0.5) / s); s = 1 gives the pixel centre i + 0.5. Directions are K^-1 (u, v, 1) rotated to
    the world, so the hit distance t is the depth along the optical axis.

    Returns:
        origins [H s, W s, 3] and directions [H s, W s, 3], float64, row-major (rows = image v).
    """
    s = int(supersample)
    offsets = (np.arange(s) + 0.5) / s
    u, v = ((np.arange(n)[:, None] + offsets[None, :]).reshape(-1) for n in (camera.width, camera.height))
    uu, vv = np.meshgrid(u, v)
    dirs_cam = np.stack([(uu - camera.cx) / camera.fx, (vv - camera.cy) / camera.fy, np.ones_like(uu)], axis=-1)
    c2w = camera.camera_to_world.numpy()
    dirs = dirs_cam @ c2w[:3, :3].T
    origins = np.broadcast_to(c2w[:3, 3], dirs.shape)
    return origins, dirs


class MeshRaycaster:
    """Closest-hit ray casting against one triangle mesh with open3d's CPU BVH (multithreaded)."""

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray) -> None:
        import open3d as o3d  # noqa: PLC0415 - open3d takes ~1.8 s to import

        self._o3d = o3d
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(
            o3d.core.Tensor(np.ascontiguousarray(vertices, dtype=np.float32)),
            o3d.core.Tensor(np.ascontiguousarray(triangles, dtype=np.uint32)),
        )

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Hit distance and triangle of each ray.

        Args:
            origins, directions: [..., 3] rays (directions need not be unit).
        Returns:
            t [...] float64 in units of the direction length (inf on a miss), triangle ids [...] int64
            (-1 on a miss).
        """
        shape = origins.shape[:-1]
        rays = np.concatenate([origins.reshape(-1, 3), directions.reshape(-1, 3)], axis=1).astype(np.float32)
        out = self.scene.cast_rays(self._o3d.core.Tensor(rays))
        t = out["t_hit"].numpy().astype(np.float64)
        ids = out["primitive_ids"].numpy().astype(np.int64)
        miss = ~np.isfinite(t)
        ids[miss] = -1
        t[miss] = np.inf
        return t.reshape(shape), ids.reshape(shape)


def cast_rays_reference(
    vertices: np.ndarray, triangles: np.ndarray, origins: np.ndarray, directions: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Slow twin of :meth:`MeshRaycaster.cast`: brute-force Moller-Trumbore over all rays x triangles.

    Same arguments and returns; meant for small meshes and images (memory O(rays x triangles)).
    """
    shape = origins.shape[:-1]
    o = origins.reshape(-1, 1, 3)
    d = directions.reshape(-1, 1, 3)
    v0, v1, v2 = (vertices[triangles[:, k]][None] for k in range(3))
    e1, e2 = v1 - v0, v2 - v0
    p = np.cross(d, e2)
    det = np.sum(e1 * p, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        s = o - v0
        bu = np.sum(s * p, axis=-1) * inv
        q = np.cross(s, e1)
        bv = np.sum(d * q, axis=-1) * inv
        t = np.sum(e2 * q, axis=-1) * inv
    ok = (np.abs(det) > 1e-12) & (bu >= 0) & (bv >= 0) & (bu + bv <= 1) & (t > 0)
    t = np.where(ok, t, np.inf)
    ids = np.argmin(t, axis=1)
    t_min = t[np.arange(len(t)), ids]
    ids = np.where(np.isfinite(t_min), ids, -1)
    return t_min.reshape(shape), ids.reshape(shape)


# ---- shading ---------------------------------------------------------------------------------------


def triangle_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """[T, 3] unit normals (zero for degenerate triangles)."""
    n = np.cross(
        vertices[triangles[:, 1]] - vertices[triangles[:, 0]], vertices[triangles[:, 2]] - vertices[triangles[:, 0]]
    )
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)


def shade(normals: np.ndarray, directions: np.ndarray, albedo: np.ndarray, ambient: float, up_axis: str) -> np.ndarray:
    """Lambert + ambient colour of surface points seen along ``directions``.

    Args:
        normals: [N, 3] unit surface normals (either orientation; flipped to face the viewer).
        directions: [N, 3] viewing ray directions (from the camera to the point).
        albedo: [3] RGB in [0, 1]. ambient: in [0, 1].
        up_axis: "y" or "z" (fixes the world lights, :func:`light_directions`).
    Returns:
        [N, 3] RGB in [0, 1].
    """
    facing = np.where(np.sum(normals * directions, axis=1, keepdims=True) > 0, -normals, normals)
    key, fill = light_directions(up_axis)
    diffuse = KEY_WEIGHT * np.clip(facing @ key, 0, None) + FILL_WEIGHT * np.clip(facing @ fill, 0, None)
    return np.clip(albedo[None, :] * (ambient + (1.0 - ambient) * diffuse[:, None]), 0.0, 1.0)


def render_view(caster: MeshRaycaster, normals: np.ndarray, camera: Camera, config: MeshDatasetConfig) -> np.ndarray:
    """RGBA image [H, W, 4] uint8 (RGB order, straight alpha) of the mesh seen by ``camera``."""
    s = config.supersample
    origins, dirs = camera_rays(camera, s)
    _, ids = caster.cast(origins, dirs)
    hit = ids >= 0
    rgb = np.zeros(ids.shape + (3,))
    rgb[hit] = shade(normals[ids[hit]], dirs[hit], parse_color(config.color), config.ambient, config.up_axis)
    h, w = camera.height, camera.width
    coverage = hit.reshape(h, s, w, s).sum(axis=(1, 3))
    rgb_sum = rgb.reshape(h, s, w, s, 3).sum(axis=(1, 3))
    colour = np.divide(rgb_sum, coverage[..., None], out=np.zeros_like(rgb_sum), where=coverage[..., None] > 0)
    alpha = coverage / float(s * s)
    rgba = np.concatenate([colour, alpha[..., None]], axis=-1)
    return np.round(np.clip(rgba, 0.0, 1.0) * 255.0).astype(np.uint8)


# ---- dataset -----------------------------------------------------------------------------------------


def _transforms(cameras: list[Camera], split: str, fov_x: float) -> dict:
    frames = [
        {"file_path": f"./{split}/r_{i:03d}", "transform_matrix": cam.opengl_c2w().tolist()}
        for i, cam in enumerate(cameras)
    ]
    return {"camera_angle_x": fov_x, "frames": frames}


def _write_json(path: Path, data: dict) -> None:
    path.write_text(json.dumps(data, indent=2) + "\n")


# What a dataset folder holds at its top (module docstring): the only names --overwrite may delete with it.
DATASET_LAYOUT = frozenset(
    ["train", "test", "mesh.ply", "dataset.json", *(f"transforms_{split}.json" for split in ("train", "test", "val"))]
)


def _check_output(out_dir: Path, overwrite: bool) -> None:
    if out_dir.exists() and not out_dir.is_dir():
        raise OutputError(f"{out_dir}: output exists and is not a folder; choose another -o")
    names = sorted(p.name for p in out_dir.iterdir()) if out_dir.is_dir() else []
    foreign = [name for name in names if name not in DATASET_LAYOUT] or ([] if "dataset.json" in names else names)
    if foreign:
        # --overwrite deletes the old folder as a whole once the new one is swapped in: only an earlier dataset.
        shown = ", ".join(foreign[:3]) + (", ..." if len(foreign) > 3 else "")
        raise ValueError(
            f"-o {out_dir} holds files that are not a dataset of render-dataset ({shown}); --overwrite replaces "
            "only such a dataset folder (its dataset.json, images and transforms); choose a new or empty -o"
        )
    if names and not overwrite:
        raise ValueError(f"{out_dir}: output folder is not empty; pass --overwrite to replace it, or another -o")
    parent = out_dir.parent
    if not parent.is_dir():
        raise ValueError(f"{parent}: parent folder of the output does not exist; create it first")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputError(f"{parent}: parent folder of the output is not writable; choose a writable -o")


def render_mesh_dataset(
    mesh_path, out_dir, config: MeshDatasetConfig | None = None, *, overwrite: bool = False, progress: bool = True
) -> Path:
    """Render a mesh into a Blender-format dataset (layout in the module docstring).

    Args:
        mesh_path: ``.obj``, ``.stl`` or ``.ply`` triangle mesh (any units; it is normalised).
        out_dir: the dataset folder to create; written atomically (temporary sibling folder, then rename).
        config: :class:`MeshDatasetConfig` (None = defaults).
        overwrite: replace a non-empty ``out_dir`` (else ValueError).
        progress: show a tqdm progress bar over the views.
    Returns:
        ``out_dir`` as a Path.
    """
    config = config or MeshDatasetConfig()
    mesh_path, out_dir = Path(mesh_path), Path(out_dir)
    vertices, triangles = load_mesh(mesh_path)
    _check_output(out_dir, overwrite)
    vertices, scale, offset = normalize_vertices(vertices, triangles, config.box_size)
    bounding_radius = _check_camera_distance(mesh_path, vertices, triangles, config)
    cameras = random_sphere(
        config.n_train + config.n_test,
        config.radius,
        config.resolution,
        config.resolution,
        config.fov_x_rad,
        config.seed,
        hemisphere=config.hemisphere,
        up_axis=config.up_axis,
    )
    splits = {"train": cameras[: config.n_train], "test": cameras[config.n_train :]}
    caster = MeshRaycaster(vertices, triangles)
    normals = triangle_normals(vertices, triangles)

    out_dir = out_dir.absolute()
    with atomic_folder(out_dir) as tmp:
        with tqdm(total=len(cameras), desc="render-dataset", unit="view", disable=not progress, leave=False) as bar:
            for split, cams in splits.items():
                (tmp / split).mkdir()
                for i, cam in enumerate(cams):
                    rgba = render_view(caster, normals, cam, config)
                    target = tmp / split / f"r_{i:03d}.png"
                    if not cv2.imwrite(str(target), cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGRA)):
                        raise OSError(f"{target}: cv2 could not write the image")
                    bar.update(1)
                _write_json(tmp / f"transforms_{split}.json", _transforms(cams, split, config.fov_x_rad))
        _write_json(tmp / "transforms_val.json", _transforms(splits["test"], "test", config.fov_x_rad))
        _write_mesh(tmp / "mesh.ply", vertices, triangles)
        key, fill = light_directions(config.up_axis)
        record = {
            "source_mesh": str(mesh_path.absolute()),
            "mesh_path": "mesh.ply",
            "normalization": "mesh.ply vertices = scale * source vertices + offset",
            "scale": scale,
            "offset": offset.tolist(),
            "bounding_radius": bounding_radius,
            "up_axis": config.up_axis,
            "seed": config.seed,
            "config": asdict(config),
            "lights": {
                "key": key.tolist(),
                "key_weight": KEY_WEIGHT,
                "fill": fill.tolist(),
                "fill_weight": FILL_WEIGHT,
                "ambient": config.ambient,
            },
            "splits": {"train": len(splits["train"]), "test": len(splits["test"]), "val": "copy of test"},
        }
        _write_json(tmp / "dataset.json", record)
    logger.info(
        "wrote %s: %d train and %d test views at %d px, mesh scale %.4g",
        out_dir,
        len(splits["train"]),
        len(splits["test"]),
        config.resolution,
        scale,
    )
    return out_dir


def _check_camera_distance(
    mesh_path: Path, vertices: np.ndarray, triangles: np.ndarray, config: MeshDatasetConfig
) -> float:
    """The normalised object's bounding radius: it must lie inside the camera sphere (else ValueError), and should fit
    the field of view (else a warning)."""
    bounding_radius = float(np.linalg.norm(vertices[np.unique(triangles)], axis=1).max())
    if bounding_radius >= config.radius:
        raise ValueError(
            f"{mesh_path}: the normalised object reaches {bounding_radius:.3f} from its centre, "
            f"beyond the camera radius {config.radius}; increase --radius or decrease --box"
        )
    if bounding_radius > config.radius * math.sin(0.5 * config.fov_x_rad):
        logger.warning(
            "%s: the normalised object's bounding sphere (radius %.2f) does not fit a %.0f-degree view "
            "at distance %.1f; some silhouettes may be cut by the image border (increase --fov or "
            "--radius)",
            mesh_path,
            bounding_radius,
            config.fov_x,
            config.radius,
        )
    return bounding_radius


def _write_mesh(path: Path, vertices: np.ndarray, triangles: np.ndarray) -> None:
    import open3d as o3d  # noqa: PLC0415 - open3d takes ~1.8 s to import

    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(vertices), o3d.utility.Vector3iVector(triangles))
    if not o3d.io.write_triangle_mesh(str(path), mesh):
        raise OSError(f"{path}: open3d could not write the mesh")
