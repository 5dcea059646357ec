"""Multi-view datasets: NeRF-synthetic / Blender ``transforms_*.json`` and COLMAP text models.

No paper equation is implemented here. The paper evaluates on NeRF Synthetic (Blender), Mip-NeRF 360
(COLMAP) and DrivAerNet++ rendered in the Blender format (appendix, "Rendering"); ``fluidgs
render-dataset`` writes the latter (:mod:`recon.mesh_render`).

Blender / NeRF-synthetic (:func:`load_blender`):
    ``transforms_{train,val,test}.json`` next to each other; train is required, val and test are
    optional (empty lists when missing). Intrinsics from ``camera_angle_x`` (radians; focal
    ``0.5 W / tan(angle / 2)``), or nerfstudio's ``fl_x`` (pixels), with optional ``camera_angle_y`` /
    ``fl_y`` (default: square pixels), ``cx``, ``cy`` (default: the image centre) and ``w``, ``h``; a
    frame may override any of these keys. Frames give ``file_path`` (relative to the json, with or
    without ``.png``) and ``transform_matrix`` (4x4 or 3x4 OpenGL camera-to-world). Images are read with
    cv2 (8- or 16-bit, grey, RGB or RGBA); RGBA is composited on ``background`` (straight alpha).
    Without a ``dataset.json`` the up axis is "z" (Blender's world, as in NeRF-synthetic).
COLMAP text (:func:`load_colmap`):
    ``cameras.txt``, ``images.txt``, ``points3D.txt`` in ``sparse/0/``, ``sparse/`` or the folder
    itself; images in an ``images/`` folder next to the sparse folder or one or two levels above it.
    Models SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL and OPENCV; distortion is ignored (a warning
    names the camera), so undistorted models are expected. COLMAP's pose is world-to-camera in the
    OpenCV axes with pixel centres at i + 0.5, exactly :class:`~recon.camera.Camera`'s convention.
    Images are sorted by name and every 8th (index 0, 8, 16, ...) goes to test, the rest to train,
    as in the LLFF / 3DGS evaluations; val is empty. COLMAP frames are arbitrary: the up axis is
    reported as "y" by convention only (for Mip-NeRF 360 scenes the true up is often close to -y).
``dataset.json`` (written by ``render-dataset``), when present in the dataset folder, provides the
reference mesh (``mesh_path``, relative to the folder) and ``up_axis``.

Down-scaling (``downscale`` or a target width ``resolution``) resizes images and alpha with
``cv2.INTER_AREA`` after compositing (area averaging is linear, so compositing first is exact) and
scales the cameras with :meth:`Camera.scaled`.

Example:
    >>> ds = load_dataset("data/car", background=(1.0, 1.0, 1.0), resolution=128)  # doctest: +SKIP
    >>> ds.train[0].image.shape  # doctest: +SKIP
    torch.Size([128, 128, 3])
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch

from .camera import Camera

logger = logging.getLogger(__name__)

SPLITS = ("train", "val", "test")
COLMAP_TEST_EVERY = 8
COLMAP_FILES = ("cameras.txt", "images.txt", "points3D.txt")
# COLMAP camera model -> number of parameters (focal length(s), principal point, then distortion)
COLMAP_MODELS = {
    "SIMPLE_PINHOLE": 3,
    "PINHOLE": 4,
    "SIMPLE_RADIAL": 4,
    "RADIAL": 5,
    "OPENCV": 8,
}


@dataclass
class View:
    """One image with its camera.

    Attributes:
        camera: the pinhole camera (its width and height match the image).
        image: [H, W, 3] float32 in [0, 1], composited on the dataset background (None: no image).
        alpha: [H, W] float32 in [0, 1], None when the file had no alpha channel.
        name: the image file stem.
    """

    camera: Camera
    image: torch.Tensor | None
    alpha: torch.Tensor | None
    name: str


@dataclass
class Dataset:
    """A loaded dataset.

    Attributes:
        train, val, test: the views of each split (val and test may be empty).
        background: RGB in [0, 1] that RGBA images were composited on.
        points: [P, 3] initial point cloud (COLMAP points3D), else None.
        point_colors: [P, 3] colours in [0, 1] of ``points``, else None.
        mesh_path: the reference mesh in the cameras' frame (datasets from ``render-dataset``), else None.
        up_axis: "y" or "z", the scene's up axis.
        root: the dataset folder.

    Splits naming the same image file (render-dataset's val copies test) share its pixel tensors, so
    treat the images as read-only.
    """

    train: list[View]
    val: list[View]
    test: list[View]
    background: tuple[float, float, float]
    points: torch.Tensor | None
    point_colors: torch.Tensor | None
    mesh_path: Path | None
    up_axis: str
    root: Path


# ---- shared helpers ------------------------------------------------------------------------------


def _check_background(background) -> tuple[float, float, float]:
    try:
        bg = tuple(float(c) for c in background)
    except TypeError as exc:
        raise ValueError(f"background must be an (r, g, b) tuple in [0, 1], got {background!r}") from exc
    if len(bg) != 3 or not all(0.0 <= c <= 1.0 for c in bg):
        raise ValueError(f"background must be an (r, g, b) tuple in [0, 1], got {background!r}")
    return bg


def _check_scale(downscale: float, resolution: int | None) -> None:
    if not (math.isfinite(downscale) and downscale >= 1.0):
        raise ValueError(f"downscale must be a finite factor >= 1 (2 halves the images), got {downscale}")
    if resolution is not None and (int(resolution) != resolution or resolution < 1):
        raise ValueError(f"resolution must be a positive integer image width in pixels, got {resolution}")


def _scale_factor(width: int, downscale: float, resolution: int | None) -> float:
    return resolution / width if resolution is not None else 1.0 / downscale


def read_image(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """Read an image as float32 RGB in [0, 1] and its alpha (None without an alpha channel).

    Args:
        path: a PNG/JPEG/... file; 8-bit (divided by 255) or 16-bit (divided by 65535), grey, grey + alpha,
            RGB or RGBA.
    Returns:
        rgb [H, W, 3] float32, alpha [H, W] float32 or None.
    """
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"{path}: cannot read the image (missing, unreadable or not an image file)")
    if img.dtype == np.uint8:
        img = img.astype(np.float32) / 255.0
    elif img.dtype == np.uint16:
        img = img.astype(np.float32) / 65535.0
    elif img.dtype == np.float32:
        img = np.clip(img, 0.0, 1.0)
    else:
        raise ValueError(f"{path}: unsupported pixel type {img.dtype}; use 8- or 16-bit images")
    if img.ndim == 2:
        img = img[:, :, None]
    channels = img.shape[2]
    if channels == 1:
        return np.repeat(img, 3, axis=2), None
    if channels == 2:  # grey + alpha
        return np.repeat(img[:, :, :1], 3, axis=2), np.ascontiguousarray(img[:, :, 1])
    if channels == 3:
        return np.ascontiguousarray(img[:, :, ::-1]), None
    if channels == 4:
        return np.ascontiguousarray(img[:, :, 2::-1]), np.ascontiguousarray(img[:, :, 3])
    raise ValueError(f"{path}: {channels} channels; expected grey, RGB or RGBA")


def _make_view(make_camera, path: Path, background: tuple[float, float, float], downscale: float,
               resolution: int | None, cache: dict) -> View:
    """Load, composite and resize one image and build its camera with ``make_camera(width, height)``.

    ``cache`` shares pixel tensors between splits that name the same file (a val split copying test).
    """
    key = path.resolve()
    if key not in cache:
        rgb, alpha = read_image(path)
        if alpha is not None:
            rgb = rgb * alpha[:, :, None] + np.asarray(background, dtype=np.float32) * (1.0 - alpha[:, :, None])
        cache[key] = (rgb, alpha, {})
    rgb, alpha, resized = cache[key]
    h, w = rgb.shape[:2]
    camera = make_camera(w, h)
    if (w, h) != (camera.width, camera.height):
        raise ValueError(f"{path}: image is {w}x{h} pixels but its camera says {camera.width}x{camera.height}; "
                         "fix the w/h keys or the image")
    factor = _scale_factor(w, downscale, resolution)
    if factor != 1.0:
        camera = camera.scaled(factor)
    size = (camera.width, camera.height)
    if size not in resized:
        if size != (w, h):
            rgb = cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)
            alpha = None if alpha is None else cv2.resize(alpha, size, interpolation=cv2.INTER_AREA)
        resized[size] = (torch.from_numpy(np.ascontiguousarray(rgb, dtype=np.float32)),
                         None if alpha is None else torch.from_numpy(np.ascontiguousarray(alpha, dtype=np.float32)))
    image, alpha_t = resized[size]
    return View(camera=camera, image=image, alpha=alpha_t, name=path.stem)


def _read_dataset_json(root: Path) -> tuple[Path | None, str | None]:
    """(mesh_path, up_axis) from ``root/dataset.json`` when present."""
    path = root / "dataset.json"
    if not path.is_file():
        return None, None
    try:
        meta = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc}); fix or delete the file") from exc
    mesh_path = meta.get("mesh_path")
    if mesh_path is not None:
        mesh_path = root / mesh_path
        if not mesh_path.is_file():
            raise ValueError(f"{path}: key 'mesh_path' names {mesh_path}, which does not exist")
    up_axis = meta.get("up_axis")
    if up_axis is not None and up_axis not in ("y", "z"):
        raise ValueError(f"{path}: key 'up_axis' must be 'y' or 'z', got {up_axis!r}")
    return mesh_path, up_axis


# ---- Blender / NeRF-synthetic --------------------------------------------------------------------


def _frame_image_path(json_path: Path, frame: dict, index: int) -> Path:
    if "file_path" not in frame:
        raise ValueError(f"{json_path}: frame {index} has no 'file_path' key")
    rel = str(frame["file_path"])
    base = json_path.parent / rel
    candidates = [base] if base.suffix.lower() in (".png", ".jpg", ".jpeg", ".exr", ".tif", ".tiff") else []
    candidates += [Path(str(base) + ".png")]
    for cand in candidates:
        if cand.is_file():
            return cand
    raise ValueError(f"{json_path}: frame {index} 'file_path' = {rel!r}: no image file at "
                     f"{' or '.join(str(c) for c in candidates)}")


def _blender_pose(json_path: Path, frame: dict, index: int) -> np.ndarray:
    """[4, 4] world-to-camera (OpenCV axes) of a frame's OpenGL ``transform_matrix``."""
    if "transform_matrix" not in frame:
        raise ValueError(f"{json_path}: frame {index} has no 'transform_matrix' key")
    try:
        c2w = np.asarray(frame["transform_matrix"], dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{json_path}: frame {index} 'transform_matrix' is not a numeric matrix") from exc
    if c2w.shape not in ((4, 4), (3, 4)) or not np.isfinite(c2w).all():
        raise ValueError(f"{json_path}: frame {index} 'transform_matrix' must be a finite 4x4 (or 3x4) matrix, "
                         f"got shape {c2w.shape}")
    if c2w.shape == (3, 4):
        c2w = np.vstack([c2w, [0.0, 0.0, 0.0, 1.0]])
    if abs(np.linalg.det(c2w[:3, :3])) < 1e-9:
        raise ValueError(f"{json_path}: frame {index} 'transform_matrix' has a singular rotation")
    return np.linalg.inv(c2w @ np.diag([1.0, -1.0, -1.0, 1.0]))


def _blender_intrinsics(json_path: Path, meta: dict, frame: dict, index: int) -> dict:
    """The intrinsic keys of a frame (frame values override the file's), checked for a focal length."""
    keys = {k: frame[k] if k in frame else meta.get(k)
            for k in ("camera_angle_x", "camera_angle_y", "fl_x", "fl_y", "cx", "cy", "w", "h")}
    if keys["fl_x"] is None and keys["camera_angle_x"] is None:
        raise ValueError(f"{json_path}: missing 'camera_angle_x' (horizontal field of view, radians) "
                         "or 'fl_x' (focal length, pixels); add one of them")
    if keys["camera_angle_x"] is not None and not 0.0 < float(keys["camera_angle_x"]) < math.pi:
        raise ValueError(f"{json_path}: 'camera_angle_x' must be in (0, pi) radians, got {keys['camera_angle_x']}")
    return keys


def _blender_camera(json_path: Path, keys: dict, w2c: np.ndarray, index: int, name: str,
                    image_width: int, image_height: int) -> Camera:
    width = int(keys["w"]) if keys["w"] is not None else image_width
    height = int(keys["h"]) if keys["h"] is not None else image_height
    if keys["fl_x"] is not None:
        fx = float(keys["fl_x"])
    else:
        fx = 0.5 * width / math.tan(0.5 * float(keys["camera_angle_x"]))
    if keys["fl_y"] is not None:
        fy = float(keys["fl_y"])
    elif keys["camera_angle_y"] is not None:
        fy = 0.5 * height / math.tan(0.5 * float(keys["camera_angle_y"]))
    else:
        fy = fx
    cx = float(keys["cx"]) if keys["cx"] is not None else width / 2.0
    cy = float(keys["cy"]) if keys["cy"] is not None else height / 2.0
    try:
        return Camera(width, height, fx, fy, cx, cy, torch.from_numpy(w2c), name=name)
    except ValueError as exc:
        raise ValueError(f"{json_path}: frame {index}: {exc}") from exc


def _load_blender_split(json_path: Path, background, downscale: float, resolution: int | None,
                        cache: dict) -> list[View]:
    try:
        meta = json.loads(json_path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{json_path}: not valid JSON ({exc})") from exc
    frames = meta.get("frames") if isinstance(meta, dict) else None
    if not isinstance(frames, list):
        raise ValueError(f"{json_path}: missing 'frames' list")
    # Validate every frame (keys, paths, matrices) before reading any pixel data.
    checked = []
    for i, frame in enumerate(frames):
        if not isinstance(frame, dict):
            raise ValueError(f"{json_path}: frame {i} is not an object")
        checked.append((i, _frame_image_path(json_path, frame, i), _blender_intrinsics(json_path, meta, frame, i),
                        _blender_pose(json_path, frame, i)))
    views = []
    for i, path, keys, w2c in checked:
        def make_camera(w, h, i=i, path=path, keys=keys, w2c=w2c):
            return _blender_camera(json_path, keys, w2c, i, path.stem, w, h)
        views.append(_make_view(make_camera, path, background, downscale, resolution, cache))
    return views


def load_blender(path, *, background=(1.0, 1.0, 1.0), downscale: float = 1.0,
                 resolution: int | None = None) -> Dataset:
    """Load a NeRF-synthetic / Blender dataset folder (``transforms_{train,val,test}.json``).

    Args:
        path: the folder holding the transforms files.
        background: (r, g, b) in [0, 1] that RGBA images are composited on.
        downscale: divide the image size by this factor (>= 1).
        resolution: target image width in pixels (overrides ``downscale``).
    Returns:
        :class:`Dataset`; ``points`` is None, ``up_axis`` is "z" unless ``dataset.json`` says otherwise.
    """
    root = Path(path)
    bg = _check_background(background)
    _check_scale(downscale, resolution)
    if not (root / "transforms_train.json").is_file():
        raise ValueError(f"{root}: no transforms_train.json; a Blender dataset needs at least the train split")
    mesh_path, up_axis = _read_dataset_json(root)
    cache: dict = {}
    splits = {}
    for split in SPLITS:
        json_path = root / f"transforms_{split}.json"
        splits[split] = _load_blender_split(json_path, bg, downscale, resolution, cache) if json_path.is_file() else []
    logger.info("loaded Blender dataset %s: %d train, %d val, %d test views", root, len(splits["train"]),
                len(splits["val"]), len(splits["test"]))
    return Dataset(train=splits["train"], val=splits["val"], test=splits["test"], background=bg, points=None,
                   point_colors=None, mesh_path=mesh_path, up_axis=up_axis or "z", root=root)


# ---- COLMAP text ---------------------------------------------------------------------------------


def quaternion_wxyz_to_matrix(q: np.ndarray) -> np.ndarray:
    """[3, 3] rotation of a (w, x, y, z) quaternion (normalised first)."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def _data_lines(path: Path) -> list[tuple[int, str]]:
    """(line number, text) of the lines of a COLMAP text file, comments dropped, blank lines kept."""
    return [(i + 1, line.strip()) for i, line in enumerate(path.read_text().splitlines())
            if not line.lstrip().startswith("#")]


def read_colmap_cameras(path: Path) -> dict[int, tuple[int, int, float, float, float, float]]:
    """``cameras.txt`` -> {camera_id: (width, height, fx, fy, cx, cy)}; distortion dropped with a warning."""
    cams = {}
    for lineno, line in _data_lines(path):
        if not line:
            continue
        tok = line.split()
        try:
            cam_id, model, width, height = int(tok[0]), tok[1], int(tok[2]), int(tok[3])
            params = [float(t) for t in tok[4:]]
        except (IndexError, ValueError) as exc:
            raise ValueError(f"{path}:{lineno}: expected 'CAMERA_ID MODEL WIDTH HEIGHT PARAMS...', "
                             f"got {line!r}") from exc
        if model not in COLMAP_MODELS:
            raise ValueError(f"{path}:{lineno}: camera {cam_id} has model {model}; supported: "
                             f"{', '.join(COLMAP_MODELS)} (undistort the images with COLMAP first)")
        if len(params) != COLMAP_MODELS[model]:
            raise ValueError(f"{path}:{lineno}: model {model} takes {COLMAP_MODELS[model]} parameters, "
                             f"got {len(params)}")
        if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
            fx = fy = params[0]
            cx, cy = params[1], params[2]
            distortion = params[3:]
        else:
            fx, fy, cx, cy = params[:4]
            distortion = params[4:]
        if any(d != 0.0 for d in distortion):
            logger.warning("%s: camera %d (%s) has distortion %s, which is ignored; undistort the images for "
                           "exact projections", path, cam_id, model, distortion)
        cams[cam_id] = (width, height, fx, fy, cx, cy)
    return cams


def read_colmap_images(path: Path) -> list[tuple[int, np.ndarray, int, str]]:
    """``images.txt`` -> [(image_id, world_to_camera [4, 4], camera_id, name)] in file order.

    Each image takes two lines: ``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`` then its 2-D points
    (possibly an empty line), which are skipped.
    """
    lines = _data_lines(path)
    out = []
    i = 0
    while i < len(lines):
        lineno, line = lines[i]
        if not line:
            i += 1
            continue
        tok = line.split()
        try:
            image_id = int(tok[0])
            q = np.array([float(t) for t in tok[1:5]])
            t = np.array([float(t) for t in tok[5:8]])
            cam_id = int(tok[8])
            name = " ".join(tok[9:])
            if not name or len(q) != 4 or len(t) != 3:
                raise IndexError
        except (IndexError, ValueError) as exc:
            raise ValueError(f"{path}:{lineno}: expected 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME', "
                             f"got {line!r}") from exc
        if not (np.isfinite(q).all() and np.isfinite(t).all()) or np.linalg.norm(q) == 0:
            raise ValueError(f"{path}:{lineno}: image {image_id} has a non-finite or zero quaternion/translation")
        w2c = np.eye(4)
        w2c[:3, :3] = quaternion_wxyz_to_matrix(q)
        w2c[:3, 3] = t
        out.append((image_id, w2c, cam_id, name))
        i += 2  # the POINTS2D line follows (it may be empty)
    return out


def read_colmap_points(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """``points3D.txt`` -> (xyz [P, 3] float32, rgb [P, 3] float32 in [0, 1])."""
    xyz, rgb = [], []
    for lineno, line in _data_lines(path):
        if not line:
            continue
        tok = line.split()
        try:
            xyz.append([float(t) for t in tok[1:4]])
            rgb.append([int(t) for t in tok[4:7]])
            if len(xyz[-1]) != 3 or len(rgb[-1]) != 3:
                raise IndexError
        except (IndexError, ValueError) as exc:
            raise ValueError(f"{path}:{lineno}: expected 'POINT3D_ID X Y Z R G B ERROR TRACK...', "
                             f"got {line!r}") from exc
    return (np.asarray(xyz, dtype=np.float32).reshape(-1, 3),
            np.asarray(rgb, dtype=np.float32).reshape(-1, 3) / 255.0)


def find_colmap_sparse(root: Path) -> Path | None:
    """The folder holding cameras.txt / images.txt / points3D.txt: ``sparse/0``, ``sparse`` or ``root``."""
    for cand in (root / "sparse" / "0", root / "sparse", root):
        if all((cand / f).is_file() for f in COLMAP_FILES):
            return cand
    return None


def _colmap_images_dir(sparse: Path) -> Path:
    candidates = [sparse / "images", sparse.parent / "images", sparse.parent.parent / "images"]
    for cand in candidates:
        if cand.is_dir():
            return cand
    raise ValueError(f"{sparse}: no images folder; looked for {', '.join(str(c) for c in candidates)}")


def load_colmap(path, *, background=(1.0, 1.0, 1.0), downscale: float = 1.0,
                resolution: int | None = None) -> Dataset:
    """Load a COLMAP text model and its images.

    Args:
        path: the scene folder (holding ``sparse/0``, ``sparse`` or the text files) or the sparse folder.
        background: (r, g, b) in [0, 1] that RGBA images (if any) are composited on.
        downscale: divide the image size by this factor (>= 1).
        resolution: target image width in pixels (overrides ``downscale``).
    Returns:
        :class:`Dataset` with views sorted by image name, every 8th in test, val empty, ``points`` and
        ``point_colors`` from points3D.txt, ``up_axis`` "y" (a convention: COLMAP frames are arbitrary).
    """
    root = Path(path)
    bg = _check_background(background)
    _check_scale(downscale, resolution)
    sparse = find_colmap_sparse(root)
    if sparse is None:
        raise ValueError(f"{root}: no COLMAP text model ({', '.join(COLMAP_FILES)}) in sparse/0, sparse or the "
                         "folder itself; convert a binary model with `colmap model_converter --output_type TXT`")
    cams = read_colmap_cameras(sparse / "cameras.txt")
    images = read_colmap_images(sparse / "images.txt")
    xyz, rgb = read_colmap_points(sparse / "points3D.txt")
    images_dir = _colmap_images_dir(sparse)
    entries = []
    for image_id, w2c, cam_id, name in sorted(images, key=lambda e: e[3]):
        if cam_id not in cams:
            raise ValueError(f"{sparse / 'images.txt'}: image {image_id} ({name}) uses camera {cam_id}, which is "
                             f"not in cameras.txt")
        image_path = images_dir / name
        if not image_path.is_file():
            raise ValueError(f"{sparse / 'images.txt'}: image {image_id}: no file {image_path}")
        width, height, fx, fy, cx, cy = cams[cam_id]
        entries.append((Camera(width, height, fx, fy, cx, cy, torch.from_numpy(w2c), name=Path(name).stem),
                        image_path))
    cache: dict = {}
    train, test = [], []
    for index, (cam, image_path) in enumerate(entries):
        view = _make_view(lambda w, h, cam=cam: cam, image_path, bg, downscale, resolution, cache)
        (test if index % COLMAP_TEST_EVERY == 0 else train).append(view)
    mesh_path, up_axis = _read_dataset_json(root)
    logger.info("loaded COLMAP dataset %s: %d train, %d test views, %d points", root, len(train), len(test),
                len(xyz))
    return Dataset(train=train, val=[], test=test, background=bg, points=torch.from_numpy(xyz),
                   point_colors=torch.from_numpy(rgb), mesh_path=mesh_path, up_axis=up_axis or "y", root=root)


# ---- auto-detection ------------------------------------------------------------------------------


def dataset_format(path) -> str:
    """``"blender"`` or ``"colmap"``: the format of a dataset folder, detected from its files without loading them.

    Args:
        path: the dataset folder (or its ``transforms_*.json`` file).
    Raises:
        ValueError: the folder does not exist or holds neither format (the message lists what was looked for).
    """
    root = Path(path)
    if root.is_file() and root.name.startswith("transforms_") and root.suffix == ".json":
        root = root.parent
    if not root.is_dir():
        raise ValueError(f"{root}: dataset folder does not exist")
    if (root / "transforms_train.json").is_file():
        return "blender"
    if find_colmap_sparse(root) is not None:
        return "colmap"
    raise ValueError(f"{root}: not a dataset; looked for transforms_train.json (Blender / NeRF-synthetic) and "
                     f"{', '.join(COLMAP_FILES)} in sparse/0, sparse or the folder (COLMAP text)")


def load_dataset(path, *, background=(1.0, 1.0, 1.0), downscale: float = 1.0,
                 resolution: int | None = None) -> Dataset:
    """Load a Blender/NeRF-synthetic or COLMAP text dataset, detected from the folder's contents.

    Args:
        path: the dataset folder (or its ``transforms_*.json`` file).
        background: (r, g, b) in [0, 1] that RGBA images are composited on (default white).
        downscale: divide the image size by this factor (>= 1).
        resolution: target image width in pixels (overrides ``downscale``).
    Returns:
        :class:`Dataset`.
    Raises:
        ValueError: the folder holds neither format (the message lists what was looked for).
    """
    root = Path(path)
    if root.is_file():
        root = root.parent
    loader = load_blender if dataset_format(root) == "blender" else load_colmap
    return loader(root, background=background, downscale=downscale, resolution=resolution)
