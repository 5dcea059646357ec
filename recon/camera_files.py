"""Camera files of the 3DGS world, read by content: transforms.json, COLMAP models and graphdeco's cameras.json.

No paper equation is implemented here. A user who trained Gaussians on a capture holds the capture's cameras in
one of three forms, and :func:`load_camera_file` reads each of them, chosen by what the path holds (never by its
name alone):

- **transforms.json** (Blender / NeRF-synthetic / nerfstudio): a JSON object with a ``frames`` list; each frame's
  ``transform_matrix`` is an OpenGL camera-to-world matrix (x right, y up, z backward); read by
  :func:`recon.datasets.load_cameras`.
- **a COLMAP model**, binary (``cameras.bin``, ``images.bin``) or text (``cameras.txt``, ``images.txt``): the
  model folder itself, ``sparse/`` or a dataset root holding ``sparse/0``; ``points3D`` is not needed. COLMAP
  poses are world-to-camera in the OpenCV axes (x right, y down, z forward), :class:`~recon.camera.Camera`'s own
  convention. Images are ordered by name, as :func:`recon.datasets.load_colmap` orders them.
- **graphdeco's cameras.json** (written next to every model the reference 3DGS trainer saves): a JSON list of
  ``{id, img_name, width, height, position, rotation, fx, fy}``, where ``position`` is the camera centre and
  ``rotation`` the 3x3 camera-to-world rotation in the OpenCV axes (its columns are the camera's x, y, z axes in
  the world), ``fx`` / ``fy`` the focal lengths in pixels and the principal point the image centre.

A folder may hold several of them (a dataset root with ``sparse/0`` and a ``transforms.json``): the COLMAP model is
read first, then ``cameras.json``, then ``transforms.json``, and the log names the one read. The writers
:func:`transforms_json`, :func:`graphdeco_json` and :func:`colmap_text` write the same cameras back.

Example:
    >>> cams = load_camera_file("data/garden")  # doctest: +SKIP
    >>> cams[0].name, cams[0].width  # doctest: +SKIP
    ('DSC07956', 4946)
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from fluidsim.files import read_json

from .camera import Camera
from .colmap import (
    BINARY_FILES,
    TEXT_FILES,
    read_colmap_cameras,
    read_colmap_cameras_binary,
    read_colmap_images,
    read_colmap_images_binary,
)
from .datasets import load_cameras

logger = logging.getLogger(__name__)

ACCEPTED = (
    "a Blender / NeRF / nerfstudio transforms.json (a 'frames' list of OpenGL camera-to-world "
    "'transform_matrix'), a COLMAP model folder (cameras.bin + images.bin or cameras.txt + images.txt, "
    "or a folder holding sparse/0 or sparse), or graphdeco's cameras.json (a list of {id, img_name, width, "
    "height, position, rotation, fx, fy})"
)
GRAPHDECO_KEYS = ("width", "height", "position", "rotation", "fx", "fy")
# The folders searched for a COLMAP model, relative to the folder given (the model, sparse/, the dataset root).
COLMAP_PLACES = ((), ("0",), ("sparse", "0"), ("sparse",))


@dataclass(frozen=True)
class CameraSource:
    """What :func:`find_camera_file` found: ``kind`` ("transforms", "colmap" or "graphdeco") and ``path`` (the json
    file, or the folder holding the COLMAP model)."""

    kind: str
    path: Path


def colmap_camera_files(folder: Path) -> tuple[Path, Path] | None:
    """(cameras file, images file) of a COLMAP model in ``folder`` (binary preferred), or None."""
    for names in (BINARY_FILES, TEXT_FILES):
        cams, images = (folder / n for n in names[:2])
        if cams.is_file() and images.is_file():
            return cams, images
    return None


def _json_kind(path: Path) -> str:
    """ "transforms" or "graphdeco" from a json file's content; ValueError listing what is accepted."""
    data = read_json(path, "camera file", f"pass {ACCEPTED}")
    if isinstance(data, dict) and "frames" in data:
        return "transforms"
    if (
        isinstance(data, list)
        and data
        and all(isinstance(e, dict) for e in data)
        and {"position", "rotation"} <= set(data[0])
    ):
        return "graphdeco"
    what = (
        "an empty list"
        if data == []
        else f"a JSON {type(data).__name__}"
        if not isinstance(data, dict)
        else f"an object with keys {sorted(data)[:8]} and no 'frames' list"
    )
    raise ValueError(f"{path}: not a camera file: it holds {what}; pass {ACCEPTED}")


def find_camera_file(path) -> CameraSource:
    """The camera file at ``path``, chosen by content.

    Args:
        path: a transforms.json or cameras.json file, a COLMAP model file (its folder is read), a COLMAP model
            folder, or a folder holding one of them (``sparse/0``, ``sparse``, ``cameras.json``,
            ``transforms.json``).
    Raises:
        ValueError: the path does not exist, or holds none of them; the message lists what is accepted.
    """
    p = Path(path)
    if p.is_file():
        if p.name in BINARY_FILES[:2] + TEXT_FILES[:2]:
            return find_camera_file(p.parent)
        return CameraSource(_json_kind(p), p)
    if not p.exists():
        raise ValueError(f"{p}: no such file or folder; pass {ACCEPTED}")
    if not p.is_dir():
        raise ValueError(f"{p}: neither a file nor a folder; pass {ACCEPTED}")
    found = [
        CameraSource("colmap", p.joinpath(*place))
        for place in COLMAP_PLACES
        if colmap_camera_files(p.joinpath(*place)) is not None
    ][:1]
    found += [
        CameraSource(kind, p / name)
        for name, kind in (("cameras.json", "graphdeco"), ("transforms.json", "transforms"))
        if (p / name).is_file()
    ]
    if not found:
        raise ValueError(
            f"{p}: a folder with no camera file: no COLMAP model ({', '.join(BINARY_FILES[:2])} or "
            f"{', '.join(TEXT_FILES[:2])}) in it, in 0/, sparse/0 or sparse, and no cameras.json or "
            f"transforms.json; pass {ACCEPTED}"
        )
    if len(found) > 1:
        logger.info(
            "%s holds %s: reading %s (pass the other's path to read it instead)",
            p,
            " and ".join(f"{s.kind} ({s.path})" for s in found),
            found[0].path,
        )
    return found[0]


def _scaled(cams: list[Camera], res: int | None) -> list[Camera]:
    return [c if res is None or c.width == res else c.scaled(res / c.width) for c in cams]


def read_colmap_cameras_only(folder) -> list[Camera]:
    """The cameras of a COLMAP model folder (binary, else text), ordered by image name; points3D is not read.

    Raises:
        ValueError: no model in the folder, a malformed file (naming it), or an image whose camera is missing.
    """
    folder = Path(folder)
    files = colmap_camera_files(folder)
    if files is None:
        raise ValueError(f"{folder}: no COLMAP model ({', '.join(BINARY_FILES[:2])} or {', '.join(TEXT_FILES[:2])})")
    cams_file, images_file = files
    binary = cams_file.suffix == ".bin"
    intrinsics = (read_colmap_cameras_binary if binary else read_colmap_cameras)(cams_file)
    images = (read_colmap_images_binary if binary else read_colmap_images)(images_file)
    if not images:
        raise ValueError(f"{images_file}: the model has no images, so no cameras; pass {ACCEPTED}")
    out = []
    for image_id, w2c, cam_id, name in sorted(images, key=lambda e: e[3]):
        if cam_id not in intrinsics:
            raise ValueError(
                f"{images_file}: image {image_id} ({name}) uses camera {cam_id}, which is not in {cams_file.name}"
            )
        width, height, fx, fy, cx, cy = intrinsics[cam_id]
        try:
            out.append(Camera(width, height, fx, fy, cx, cy, torch.from_numpy(w2c), name=Path(name).stem))
        except ValueError as exc:
            raise ValueError(f"{images_file}: image {image_id} ({name}): {exc}") from exc
    return out


def read_graphdeco_cameras(path) -> list[Camera]:
    """The cameras of graphdeco's ``cameras.json``, in file order (see the module docstring for the layout).

    Raises:
        ValueError: naming the file, the entry and the key that is missing or wrong.
    """
    path = Path(path)
    entries = read_json(path, "camera file", f"pass {ACCEPTED}")
    if not isinstance(entries, list) or not entries:
        raise ValueError(f"{path}: a graphdeco cameras.json is a non-empty list of cameras; pass {ACCEPTED}")
    cams = []
    for i, e in enumerate(entries):
        where = f"{path}: entry {i}" + (f" ({e.get('img_name')!r})" if isinstance(e, dict) and "img_name" in e else "")
        if not isinstance(e, dict):
            raise ValueError(f"{where} is not an object")
        missing = [k for k in GRAPHDECO_KEYS if k not in e]
        if missing:
            raise ValueError(f"{where} lacks {', '.join(missing)}; each camera needs {', '.join(GRAPHDECO_KEYS)}")
        try:
            centre = np.asarray(e["position"], dtype=np.float64)
            rot = np.asarray(e["rotation"], dtype=np.float64)
            width, height, fx, fy = (float(e[k]) for k in ("width", "height", "fx", "fy"))
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{where}: a key is not numeric ({exc})") from exc
        if centre.shape != (3,) or rot.shape != (3, 3):
            raise ValueError(
                f"{where}: 'position' must be 3 numbers and 'rotation' 3 rows of 3, got shapes "
                f"{centre.shape} and {rot.shape}"
            )
        if not (np.isfinite(centre).all() and np.isfinite(rot).all()):
            raise ValueError(f"{where}: 'position' or 'rotation' holds NaN or infinite entries")
        if abs(float(np.linalg.det(rot)) - 1.0) > 1e-3:
            raise ValueError(f"{where}: 'rotation' is not a rotation (determinant {np.linalg.det(rot):.4g}, not 1)")
        w2c = np.eye(4)
        w2c[:3, :3] = rot.T
        w2c[:3, 3] = -rot.T @ centre
        name = str(e.get("img_name", f"view_{i:03d}"))
        try:
            cams.append(Camera(width, height, fx, fy, width / 2.0, height / 2.0, torch.from_numpy(w2c), name=name))
        except ValueError as exc:
            raise ValueError(f"{where}: {exc}") from exc
    return cams


def load_camera_file(path, res: int | None = None) -> list[Camera]:
    """The cameras of any camera file a 3DGS user has (:func:`find_camera_file` chooses by content).

    Args:
        path: a transforms.json, a graphdeco cameras.json, a COLMAP model folder or a folder holding one.
        res: target image width in pixels: every camera is scaled to it, keeping the aspect (a transforms.json
            frame without a size takes it as a square); None keeps the file's sizes.
    Returns:
        list of :class:`Camera` (world-to-camera, OpenCV axes), in the file's order (COLMAP: by image name).
    Raises:
        ValueError: the path holds no camera file (the message lists what is accepted) or a malformed one.
    """
    if res is not None and (isinstance(res, bool) or int(res) != res or res < 1):
        raise ValueError(f"res (--res) must be a positive integer image width in pixels, got {res!r}")
    source = find_camera_file(path)
    if source.kind == "transforms":
        return load_cameras(source.path, res)
    cams = read_colmap_cameras_only(source.path) if source.kind == "colmap" else read_graphdeco_cameras(source.path)
    logger.debug("read %d cameras from %s (%s)", len(cams), source.path, source.kind)
    return _scaled(cams, res)


# ---- writers -------------------------------------------------------------------------------------------------


def transforms_json(cameras, note: str = "") -> dict:
    """A nerfstudio-style transforms.json of ``cameras``: per frame ``transform_matrix`` (OpenGL camera-to-world),
    ``w``, ``h``, ``fl_x``, ``fl_y``, ``cx``, ``cy``, and ``file_path`` ``./NAME``; ``camera_angle_x`` of the first
    camera at the top (for readers that want it). ``note`` goes into a ``"note"`` key when given."""
    cams = list(cameras)
    if not cams:
        raise ValueError("transforms_json: no cameras")
    frames = [
        {
            "file_path": f"./{c.name or f'view_{i:03d}'}",
            "w": c.width,
            "h": c.height,
            "fl_x": c.fx,
            "fl_y": c.fy,
            "cx": c.cx,
            "cy": c.cy,
            "transform_matrix": c.opengl_c2w().tolist(),
        }
        for i, c in enumerate(cams)
    ]
    out = {"camera_angle_x": cams[0].fov_x, "frames": frames}
    return {"note": note, **out} if note else out


def graphdeco_json(cameras) -> list[dict]:
    """graphdeco's cameras.json of ``cameras`` (the principal point is not stored: it is the image centre there)."""
    out = []
    for i, c in enumerate(cameras):
        c2w = c.camera_to_world
        out.append(
            {
                "id": i,
                "img_name": c.name or f"view_{i:03d}",
                "width": c.width,
                "height": c.height,
                "position": c2w[:3, 3].tolist(),
                "rotation": c2w[:3, :3].tolist(),
                "fy": c.fy,
                "fx": c.fx,
            }
        )
    return out


def rotation_to_quaternion_wxyz(rot: np.ndarray) -> np.ndarray:
    """[4] unit (w, x, y, z) quaternion of a 3x3 rotation, w >= 0 (the inverse of
    :func:`recon.colmap.quaternion_wxyz_to_matrix`; Shepperd's method, stable for every rotation)."""
    r = np.asarray(rot, dtype=np.float64)
    trace = np.trace(r)
    cands = [trace, r[0, 0], r[1, 1], r[2, 2]]
    k = int(np.argmax(cands))
    if k == 0:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = [0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
    else:
        i, j, m = k - 1, k % 3, (k + 1) % 3
        s = 2.0 * math.sqrt(1.0 + r[i, i] - r[j, j] - r[m, m])
        v = [0.0, 0.0, 0.0]
        v[i] = 0.25 * s
        v[j] = (r[j, i] + r[i, j]) / s
        v[m] = (r[m, i] + r[i, m]) / s
        q = [(r[m, j] - r[j, m]) / s, *v]
    q = np.asarray(q)
    return q * (1.0 if q[0] >= 0 else -1.0)


def colmap_text(cameras) -> tuple[str, str]:
    """(cameras.txt, images.txt) of a COLMAP text model of ``cameras``: one PINHOLE camera per image, named
    ``NAME.png``, with no 2-D points (write an empty ``points3D.txt`` beside them for tools that want one)."""
    cams_lines, image_lines = (
        ["# Camera list: CAMERA_ID MODEL WIDTH HEIGHT fx fy cx cy"],
        ["# Image list: IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, then a line of 2-D points (none here)"],
    )
    for i, c in enumerate(cameras, start=1):
        cams_lines.append(f"{i} PINHOLE {c.width} {c.height} {c.fx!r} {c.fy!r} {c.cx!r} {c.cy!r}")
        w2c = c.world_to_camera.numpy()
        q, t = rotation_to_quaternion_wxyz(w2c[:3, :3]), w2c[:3, 3]
        image_lines += [" ".join([str(i), *(repr(float(v)) for v in (*q, *t)), str(i), f"{c.name or i}.png"]), ""]
    return "\n".join(cams_lines) + "\n", "\n".join(image_lines) + "\n"
