"""Multi-view datasets: NeRF-synthetic / Blender ``transforms_*.json`` and COLMAP models (binary or text).

No paper equation is implemented here. The paper evaluates on NeRF Synthetic (Blender), Mip-NeRF 360
(COLMAP) and DrivAerNet++ rendered in the Blender format (appendix, "Rendering"); ``fluidgs
render-dataset`` writes the latter (:mod:`recon.mesh_render`).

Blender / NeRF-synthetic (:func:`load_blender`; :func:`load_cameras` reads the cameras of one file
without images):
    ``transforms_{train,val,test}.json`` next to each other; train is required, val and test are
    optional (empty lists when missing). Intrinsics from ``camera_angle_x`` (radians; focal
    ``0.5 W / tan(angle / 2)``), or nerfstudio's ``fl_x`` (pixels), with optional ``camera_angle_y`` /
    ``fl_y`` (default: square pixels), ``cx``, ``cy`` (default: the image centre) and ``w``, ``h``; a
    frame may override any of these keys. Frames give ``file_path`` (relative to the json, with or
    without ``.png``) and ``transform_matrix`` (4x4 or 3x4 OpenGL camera-to-world: a rotation and a
    translation). Images are read with cv2 (8- or 16-bit, grey, RGB or RGBA); RGBA is composited on
    ``background`` (straight alpha). Without a ``dataset.json`` the up axis is "z" (Blender's world, as
    in NeRF-synthetic). A malformed key raises a ValueError naming the file, the frame (index and
    ``file_path``) and the key.
COLMAP (:func:`load_colmap`; :mod:`recon.colmap` reads the model and says which camera models and pose
    convention it takes): ``cameras``, ``images``, ``points3D`` as ``.bin`` (preferred) or ``.txt`` in
    ``sparse/0/``, ``sparse/`` or the folder itself; images in an ``images/`` folder next to the sparse
    folder or one or two levels above it. Images are sorted by name and every 8th (index 0, 8, 16, ...)
    goes to test, the rest to train, as in the LLFF / 3DGS evaluations; val is empty. COLMAP frames are
    arbitrary: the up axis is reported as "y" by convention only (for Mip-NeRF 360 scenes the true up is
    often close to -y; :func:`recon.frames.up_from_cameras` estimates it).
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

import logging
import math
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import cv2
import numpy as np
import torch
from PIL import Image, UnidentifiedImageError

from fluidsim.files import input_problem, read_json

from .camera import MAX_IMAGE_SIDE, Camera
from .colmap import BINARY_FILES, TEXT_FILES, find_colmap_sparse, read_colmap_model

logger = logging.getLogger(__name__)

SPLITS = ("train", "val", "test")
# Pixels an image file may declare before it is decoded: Pillow's decompression-bomb limit (89.5 MP, beyond a 50 MP
# photo). Decoding a larger one costs 16 bytes a pixel (8 bits per channel, then float RGB): a 2.7 MB PNG of
# 30000 x 30000 took 23 GiB.
MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS
COLMAP_TEST_EVERY = 8


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


def read_image(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """Read an image as float32 RGB in [0, 1] and its alpha (None without an alpha channel).

    Args:
        path: a PNG/JPEG/... file; 8-bit (divided by 255) or 16-bit (divided by 65535), grey, grey + alpha,
            RGB or RGBA.
    Returns:
        rgb [H, W, 3] float32, alpha [H, W] float32 or None.
    Raises:
        ValueError: an image that cannot be read, or whose header declares more than :data:`MAX_IMAGE_PIXELS`.
    """
    size = image_size(path, decode=False)
    if size is not None and size[0] * size[1] > MAX_IMAGE_PIXELS:
        raise ValueError(
            f"{path}: the image declares {size[0]:,} x {size[1]:,} pixels, more than the {MAX_IMAGE_PIXELS:,} an "
            "image may have (decoding it would take gigabytes); downscale the images"
        )
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"{path}: cannot read the image (missing, unreadable or not an image file)")
    if img.dtype in (np.uint8, np.uint16):
        img = img.astype(np.float32) / np.iinfo(img.dtype).max
    elif img.dtype == np.float32:
        img = np.clip(img, 0.0, 1.0)
    else:
        raise ValueError(f"{path}: unsupported pixel type {img.dtype}; use 8- or 16-bit images")
    img = img.reshape(*img.shape[:2], -1)
    channels = img.shape[2]
    if channels > 4:
        raise ValueError(f"{path}: {channels} channels; expected grey, RGB or RGBA")
    # grey, grey + alpha, BGR, BGRA
    rgb = np.repeat(img[:, :, :1], 3, axis=2) if channels < 3 else np.ascontiguousarray(img[:, :, 2::-1])
    return rgb, np.ascontiguousarray(img[:, :, -1]) if channels in (2, 4) else None


class _ViewLoader:
    """``load(make_camera, path) -> View`` with checked background and scale settings; splits that name the same
    file (a val split copying test) share its pixel tensors."""

    def __init__(self, background, downscale: float, resolution: int | None):
        try:
            bg = tuple(float(c) for c in background)
        except TypeError:  # not iterable
            bg = ()
        if len(bg) != 3 or not all(0.0 <= c <= 1.0 for c in bg):
            raise ValueError(f"background must be an (r, g, b) tuple in [0, 1], got {background!r}")
        if not (math.isfinite(downscale) and downscale >= 1.0):
            raise ValueError(f"downscale must be a finite factor >= 1 (2 halves the images), got {downscale}")
        if resolution is not None and (int(resolution) != resolution or resolution < 1):
            raise ValueError(f"resolution must be a positive integer image width in pixels, got {resolution}")
        self.background, self.downscale, self.resolution = bg, downscale, resolution
        self.cache: dict = {}

    def __call__(self, make_camera, path: Path) -> View:
        """Load, composite and resize one image and build its camera with ``make_camera(width, height)``."""
        key = path.resolve()
        if key not in self.cache:
            rgb, alpha = read_image(path)
            if alpha is not None:
                a = alpha[:, :, None]
                rgb = rgb * a + np.asarray(self.background, dtype=np.float32) * (1.0 - a)
            self.cache[key] = rgb, alpha
        rgb, alpha = self.cache[key]
        h, w = rgb.shape[:2]
        camera = make_camera(w, h)
        if (w, h) != (camera.width, camera.height):
            raise ValueError(
                f"{path}: image is {w}x{h} pixels but its camera says {camera.width}x{camera.height}; "
                "fix the w/h keys or the image"
            )
        factor = self.resolution / w if self.resolution is not None else 1.0 / self.downscale
        if factor != 1.0:
            camera = camera.scaled(factor)
        size = (camera.width, camera.height)
        if (key, size) not in self.cache:
            if size != (w, h):
                rgb = cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)
                alpha = None if alpha is None else cv2.resize(alpha, size, interpolation=cv2.INTER_AREA)
            self.cache[key, size] = tuple(
                None if a is None else torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32)) for a in (rgb, alpha)
            )
        image, alpha_t = self.cache[key, size]
        return View(camera=camera, image=image, alpha=alpha_t, name=path.stem)


def _read_dataset_json(root: Path) -> tuple[Path | None, str | None]:
    """(mesh_path, up_axis) from ``root/dataset.json`` when present."""
    path = root / "dataset.json"
    if not path.is_file():
        return None, None
    meta = read_json(path, "the dataset's", "fix or delete the file")
    if not isinstance(meta, dict):
        raise ValueError(f"the dataset's {path} holds a JSON {type(meta).__name__}, not an object; fix or delete it")
    mesh_path = meta.get("mesh_path")
    if mesh_path is not None:
        mesh_path = root / mesh_path
        problem = input_problem(mesh_path)
        if problem is not None:  # "does not exist", or a FIFO, a device, a folder, a link loop named as such
            raise ValueError(f"{path}: key 'mesh_path' names {mesh_path}, which {problem}")
    up_axis = meta.get("up_axis")
    if up_axis is not None and up_axis not in ("y", "z"):
        raise ValueError(f"{path}: key 'up_axis' must be 'y' or 'z', got {up_axis!r}")
    return mesh_path, up_axis


# ---- Blender / NeRF-synthetic --------------------------------------------------------------------


_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".exr", ".tif", ".tiff")
_INTRINSIC_KEYS = ("camera_angle_x", "camera_angle_y", "fl_x", "fl_y", "cx", "cy", "w", "h")
_GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])  # OpenGL camera axes (y up, z back) -> OpenCV (y down, z forward)


def _frame_where(json_path: Path, frame: dict, index: int) -> str:
    """``"FILE: frame I (file_path 'P')"``, the prefix of every error about one frame."""
    fp = frame.get("file_path")
    return f"{json_path}: frame {index}" + ("" if fp is None else f" (file_path {str(fp)!r})")


def _frame_image_candidates(json_path: Path, frame: dict) -> list[Path]:
    base = json_path.parent / str(frame["file_path"])
    return ([base] if base.suffix.lower() in _IMAGE_SUFFIXES else []) + [Path(str(base) + ".png")]


def _frame_image_path(json_path: Path, frame: dict, index: int) -> Path:
    if "file_path" not in frame:
        raise ValueError(f"{json_path}: frame {index} has no 'file_path' key")
    candidates = _frame_image_candidates(json_path, frame)
    for cand in candidates:
        if cand.is_file():
            return cand
    raise ValueError(
        f"{_frame_where(json_path, frame, index)}: no image file at {' or '.join(str(c) for c in candidates)}"
    )


def _blender_pose(json_path: Path, frame: dict, index: int) -> np.ndarray:
    """[4, 4] world-to-camera (OpenCV axes) of a frame's OpenGL ``transform_matrix`` (camera-to-world).

    Raises:
        ValueError: naming the file and the frame when the matrix is missing, not numeric, not 4x4 / 3x4,
            not finite, has a last row other than (0, 0, 0, 1), or a 3x3 part that is not a rotation.
    """
    where = _frame_where(json_path, frame, index)
    if "transform_matrix" not in frame:
        raise ValueError(f"{where} has no 'transform_matrix' key (its 4x4 camera-to-world matrix)")
    try:
        c2w = np.asarray(frame["transform_matrix"], dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(
            f"{where}: 'transform_matrix' is not a numeric matrix ({exc}); it must be 4 rows of 4 numbers"
        ) from exc
    if c2w.shape not in ((4, 4), (3, 4)):
        raise ValueError(f"{where}: 'transform_matrix' must be a 4x4 (or 3x4) matrix, got shape {c2w.shape}")
    if not np.isfinite(c2w).all():
        raise ValueError(f"{where}: 'transform_matrix' holds NaN or infinite entries")
    if c2w.shape == (3, 4):
        c2w = np.vstack([c2w, [0.0, 0.0, 0.0, 1.0]])
    if np.abs(c2w[3] - [0.0, 0.0, 0.0, 1.0]).max() > 1e-6:
        raise ValueError(f"{where}: 'transform_matrix' last row must be [0, 0, 0, 1], got {c2w[3].tolist()}")
    rot = c2w[:3, :3]
    det = float(np.linalg.det(rot))
    if abs(det) < 1e-9:
        raise ValueError(
            f"{where}: 'transform_matrix' is singular (its 3x3 rotation part has determinant "
            f"{det:.3g}); it must be a rotation and a translation"
        )
    err = float(np.abs(rot @ rot.T - np.eye(3)).max())
    if err > 1e-4 or det < 0:
        what = "a reflection (determinant -1)" if err <= 1e-4 else f"not orthonormal (max |R R^T - I| = {err:.3g})"
        raise ValueError(
            f"{where}: 'transform_matrix' 3x3 part is {what}; it must be a rotation (no scale, "
            "shear or mirror) and a translation"
        )
    return np.linalg.inv(c2w @ _GL_TO_CV)


def _intrinsic_value(where: str, key: str, raw, top_level: bool):
    """One intrinsic key as a checked number: w, h positive integers; focal lengths > 0; angles in (0, pi)."""
    origin = " (top level)" if top_level else ""
    try:
        if isinstance(raw, bool):
            raise TypeError
        val = float(raw)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: key '{key}'{origin} must be a number, got {raw!r}") from exc
    if not math.isfinite(val):
        raise ValueError(f"{where}: key '{key}'{origin} must be finite, got {raw!r}")
    if key in ("w", "h"):
        if val != int(val) or val < 1:
            raise ValueError(
                f"{where}: key '{key}'{origin} must be a positive integer image size in pixels, got "
                f"{raw!r}; fix it, or remove 'w' and 'h' to take the size from the image"
            )
        if val > MAX_IMAGE_SIDE:
            size = f"{int(val):,}" if val < 1e15 else f"{val:.3g}"  # not 300 digits for 1e308
            raise ValueError(
                f"{where}: key '{key}'{origin} is {size} pixels, more than {MAX_IMAGE_SIDE:,}, the largest "
                "image side a camera may have; fix it, or remove 'w' and 'h' to take the size from the image"
            )
        return int(val)
    if key in ("fl_x", "fl_y") and val <= 0:
        raise ValueError(f"{where}: key '{key}'{origin} (focal length, pixels) must be > 0, got {raw!r}")
    if key.startswith("camera_angle") and not 0.0 < val < math.pi:
        raise ValueError(f"{where}: key '{key}'{origin} (field of view) must be in (0, pi) radians, got {raw!r}")
    return val


def _blender_intrinsics(json_path: Path, meta: dict, frame: dict, index: int) -> dict:
    """The intrinsic keys of a frame (frame values override the file's), checked; None where absent."""
    where = _frame_where(json_path, frame, index)
    keys = {}
    for key in _INTRINSIC_KEYS:
        raw = frame[key] if key in frame else meta.get(key)
        keys[key] = None if raw is None else _intrinsic_value(where, key, raw, key not in frame)
    if keys["fl_x"] is None and keys["camera_angle_x"] is None:
        raise ValueError(
            f"{json_path}: missing 'camera_angle_x' (horizontal field of view, radians) "
            f"or 'fl_x' (focal length, pixels) for frame {index}; add one of them"
        )
    return keys


def _blender_camera(keys: dict, w2c: np.ndarray, where: str, name: str, image_width: int, image_height: int) -> Camera:
    """The camera of checked intrinsic ``keys``; the image size fills in a missing ``w`` / ``h``."""
    # w, h, the focal lengths and the angles are > 0 where given (:func:`_intrinsic_value`), so `or` picks the default
    width, height = keys["w"] or image_width, keys["h"] or image_height
    fx = keys["fl_x"] or 0.5 * width / math.tan(0.5 * keys["camera_angle_x"])
    fy = keys["fl_y"] or (0.5 * height / math.tan(0.5 * keys["camera_angle_y"]) if keys["camera_angle_y"] else fx)
    cx = keys["cx"] if keys["cx"] is not None else width / 2.0
    cy = keys["cy"] if keys["cy"] is not None else height / 2.0
    try:
        return Camera(width, height, fx, fy, cx, cy, torch.from_numpy(w2c), name=name)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from exc


def _read_transforms(json_path: Path) -> tuple[dict, list[dict]]:
    """(the file's top-level dict, its frames) of a transforms json, checked to be a dict with a list of dicts."""
    meta = read_json(json_path, "the camera file", "pass a Blender / NeRF transforms.json")
    frames = meta.get("frames") if isinstance(meta, dict) else None
    if not isinstance(frames, list):
        raise ValueError(
            f"{json_path}: missing 'frames' list; a transforms.json holds frames with 'file_path' and "
            "'transform_matrix'"
        )
    for i, frame in enumerate(frames):
        if not isinstance(frame, dict):
            raise ValueError(f"{json_path}: frame {i} is not an object")
    return meta, frames


def image_size(path: Path, decode: bool = True) -> tuple[int, int] | None:
    """(width, height) of the image at ``path`` from its header alone, or None when it is not an image.

    Pillow reads the header without decoding the pixels, so a small file that declares a huge image costs nothing
    (its decompression-bomb limit guards decoding, which does not happen here, so it is lifted while the header is
    read); the formats Pillow does not know (OpenEXR) are decoded by OpenCV, or give None when ``decode`` is False.
    """
    limit, Image.MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS, None
    try:
        with Image.open(path) as img:
            return img.size
    except (UnidentifiedImageError, OSError, ValueError):
        if not decode:
            return None
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        return None if img is None else (img.shape[1], img.shape[0])
    finally:
        Image.MAX_IMAGE_PIXELS = limit


def _frame_size(json_path: Path, frame: dict, keys: dict, index: int, res: int | None) -> tuple[int, int]:
    """(width, height) of a frame for :func:`load_cameras`: ``w`` / ``h``, else its image, else ``res`` (square)."""
    if keys["w"] is not None and keys["h"] is not None:
        return keys["w"], keys["h"]
    if "file_path" in frame:
        for cand in _frame_image_candidates(json_path, frame):
            size = image_size(cand) if cand.is_file() else None
            if size is not None:
                return size
    if res is None:
        raise ValueError(
            f"{_frame_where(json_path, frame, index)} has no 'w'/'h' keys and no readable image; add "
            "'w' and 'h' (pixels) or give a width (res; the --res option)"
        )
    width = keys["w"] if keys["w"] is not None else res
    return width, keys["h"] if keys["h"] is not None else width


def load_cameras(path, res: int | None = None) -> list[Camera]:
    """The cameras of one Blender / NeRF ``transforms.json`` (camera part only: images are not loaded).

    The image size comes from the ``w`` / ``h`` keys, else from the frame's image file (its header is
    read), else from ``res`` (square).

    Args:
        path: the transforms json file.
        res: target image width in pixels: every camera is scaled to it (:meth:`Camera.scaled`, keeping the
            aspect); None keeps the file's sizes.
    Returns:
        list of :class:`Camera` in frame order, named after the stem of ``file_path`` (``view_000``, ...
        without one).
    Raises:
        ValueError: naming the file, the frame (index and ``file_path``) and the key that is missing or wrong.
    """
    json_path = Path(path)
    if res is not None and (isinstance(res, bool) or int(res) != res or res < 1):
        raise ValueError(f"res (--res) must be a positive integer image width in pixels, got {res!r}")
    meta, frames = _read_transforms(json_path)
    if not frames:
        raise ValueError(
            f"{json_path}: 'frames' is empty; a cameras file needs at least one frame with 'transform_matrix'"
        )
    cams = []
    for i, frame in enumerate(frames):
        keys, w2c = _blender_intrinsics(json_path, meta, frame, i), _blender_pose(json_path, frame, i)
        width, height = _frame_size(json_path, frame, keys, i, res)
        name = Path(str(frame["file_path"])).stem if "file_path" in frame else f"view_{i:03d}"
        cam = _blender_camera(keys, w2c, _frame_where(json_path, frame, i), name, width, height)
        cams.append(cam if res is None or cam.width == res else cam.scaled(res / cam.width))
    return cams


def _load_blender_split(json_path: Path, load_view: _ViewLoader) -> list[View]:
    meta, frames = _read_transforms(json_path)
    # Validate every frame (keys, paths, matrices) before reading any pixel data.
    checked = []
    for i, frame in enumerate(frames):
        path = _frame_image_path(json_path, frame, i)
        keys, w2c = _blender_intrinsics(json_path, meta, frame, i), _blender_pose(json_path, frame, i)
        checked.append((partial(_blender_camera, keys, w2c, f"{json_path}: frame {i}", path.stem), path))
    return [load_view(make_camera, path) for make_camera, path in checked]


def load_blender(path, *, background=(1.0, 1.0, 1.0), downscale: float = 1.0, resolution: int | None = None) -> Dataset:
    """Load a NeRF-synthetic / Blender dataset folder (``transforms_{train,val,test}.json``).

    Args:
        path: the folder holding the transforms files.
        background, downscale, resolution: as :func:`load_dataset`.
    Returns:
        :class:`Dataset`; ``points`` is None, ``up_axis`` is "z" unless ``dataset.json`` says otherwise.
    """
    root = Path(path)
    load_view = _ViewLoader(background, downscale, resolution)
    if not (root / "transforms_train.json").is_file():
        raise ValueError(f"{root}: no transforms_train.json; a Blender dataset needs at least the train split")
    mesh_path, up_axis = _read_dataset_json(root)
    json_paths = {split: root / f"transforms_{split}.json" for split in SPLITS}
    splits = {split: _load_blender_split(p, load_view) if p.is_file() else [] for split, p in json_paths.items()}
    if not splits["train"]:
        raise ValueError(
            f"{root / 'transforms_train.json'}: 'frames' is empty; a dataset needs at least one train view (a frame "
            "with 'file_path' and 'transform_matrix')"
        )
    logger.info("loaded Blender dataset %s: %d train, %d val, %d test views", root, *map(len, splits.values()))
    return Dataset(
        **splits,
        background=load_view.background,
        points=None,
        point_colors=None,
        mesh_path=mesh_path,
        up_axis=up_axis or "z",
        root=root,
    )


# ---- COLMAP ---------------------------------------------------------------------------------------


def _colmap_images_dir(sparse: Path) -> Path:
    candidates = [sparse / "images", sparse.parent / "images", sparse.parent.parent / "images"]
    for cand in candidates:
        if cand.is_dir():
            return cand
    raise ValueError(f"{sparse}: no images folder; looked for {', '.join(str(c) for c in candidates)}")


def _colmap_entries(model, images_dir: Path) -> list[tuple[Camera, Path]]:
    """(camera, image file) of every image of a :class:`recon.colmap.ColmapModel`, sorted by image name."""
    cams_file, images_file = (model.folder / f for f in model.files[:2])
    entries = []
    for image_id, w2c, cam_id, name in sorted(model.images, key=lambda e: e[3]):
        if cam_id not in model.cameras:
            raise ValueError(
                f"{images_file}: image {image_id} ({name}) uses camera {cam_id}, which is not in {cams_file.name}"
            )
        image_path = images_dir / name
        if not image_path.is_file():
            raise ValueError(f"{images_file}: image {image_id}: no file {image_path}")
        try:
            cam = Camera(*model.cameras[cam_id], torch.from_numpy(w2c), name=Path(name).stem)
        except ValueError as exc:
            raise ValueError(
                f"{cams_file} / {images_file.name}: image {image_id} ({name}), camera {cam_id}: {exc}"
            ) from exc
        entries.append((cam, image_path))
    return entries


def load_colmap(path, *, background=(1.0, 1.0, 1.0), downscale: float = 1.0, resolution: int | None = None) -> Dataset:
    """Load a COLMAP model (binary, else text) and its images.

    Args:
        path: the scene folder (holding ``sparse/0``, ``sparse`` or the model files) or the sparse folder.
        background, downscale, resolution: as :func:`load_dataset`.
    Returns:
        :class:`Dataset` with views sorted by image name, every 8th in test, val empty, ``points`` and
        ``point_colors`` from points3D, ``up_axis`` "y" (a convention: COLMAP frames are arbitrary).
    """
    root = Path(path)
    load_view = _ViewLoader(background, downscale, resolution)
    sparse = find_colmap_sparse(root)
    if sparse is None:
        raise ValueError(
            f"{root}: no COLMAP model ({', '.join(BINARY_FILES)} or {', '.join(TEXT_FILES)}) in sparse/0, sparse or "
            "the folder itself; run COLMAP's mapper, or point at the folder holding the model"
        )
    model = read_colmap_model(sparse)
    entries = _colmap_entries(model, _colmap_images_dir(sparse))
    views = [load_view(lambda w, h, cam=cam: cam, image_path) for cam, image_path in entries]
    test, train = views[::COLMAP_TEST_EVERY], [v for i, v in enumerate(views) if i % COLMAP_TEST_EVERY]
    mesh_path, up_axis = _read_dataset_json(root)
    logger.info(
        "loaded COLMAP %s dataset %s: %d train, %d test views, %d points",
        model.kind,
        root,
        len(train),
        len(test),
        len(model.points),
    )
    return Dataset(
        train=train,
        val=[],
        test=test,
        background=load_view.background,
        points=torch.from_numpy(model.points),
        point_colors=torch.from_numpy(model.point_colors),
        mesh_path=mesh_path,
        up_axis=up_axis or "y",
        root=root,
    )


# ---- auto-detection ------------------------------------------------------------------------------


def _dataset_folder(path) -> Path:
    """``path``, or the folder of the ``transforms_*.json`` file it names."""
    path = Path(path)
    return path.parent if path.is_file() and path.name.startswith("transforms_") and path.suffix == ".json" else path


def dataset_format(path) -> str:
    """``"blender"`` or ``"colmap"``: the format of a dataset folder, detected from its files without loading them.

    Args:
        path: the dataset folder (or its ``transforms_*.json`` file).
    Raises:
        ValueError: the folder does not exist or holds neither format (the message lists what was looked for).
    """
    root = _dataset_folder(path)
    if root.is_file():
        raise ValueError(
            f"{root}: a file, not a dataset folder; pass the folder that holds transforms_train.json "
            "or a COLMAP model (or its transforms_*.json file)"
        )
    if not root.is_dir():
        problem = input_problem(root, folder_ok=True)
        raise ValueError(
            f"{root}: dataset folder does not exist"
            if problem in (None, "does not exist")
            else f"{root} {problem}; pass a dataset folder"
        )
    if (root / "transforms_train.json").is_file():
        return "blender"
    if find_colmap_sparse(root) is not None:
        return "colmap"
    raise ValueError(
        f"{root}: not a dataset; looked for transforms_train.json (Blender / NeRF-synthetic) and a "
        f"COLMAP model ({', '.join(BINARY_FILES)} or {', '.join(TEXT_FILES)}) in sparse/0, sparse or "
        "the folder"
    )


def load_dataset(path, *, background=(1.0, 1.0, 1.0), downscale: float = 1.0, resolution: int | None = None) -> Dataset:
    """Load a Blender/NeRF-synthetic or COLMAP (binary or text) dataset, detected from the folder's contents.

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
    root = _dataset_folder(path)
    loader = load_blender if dataset_format(root) == "blender" else load_colmap
    dataset = loader(root, background=background, downscale=downscale, resolution=resolution)
    if not dataset.train:
        raise ValueError(f"{root}: the dataset has no train views; add images to it (every 8th is held out for test)")
    return dataset


def count_train_views(path) -> int | None:
    """The train (candidate) views of a dataset folder (or of the folder of a transforms_*.json given), counted from
    its cameras without reading an image; None when the folder cannot be read that way (:func:`load_dataset` then
    says what is wrong). COLMAP: every image but the test split (images 0, 8, 16, ...)."""
    root = Path(path)
    root = root.parent if root.is_file() else root
    try:
        if dataset_format(root) == "blender":
            frames = read_json(root / "transforms_train.json", "the camera file", "").get("frames")
            return len(frames) if isinstance(frames, list) else None
        images = len(read_colmap_model(find_colmap_sparse(root)).images)
        return images - math.ceil(images / COLMAP_TEST_EVERY)
    except (ValueError, OSError, TypeError, AttributeError):
        return None
