"""COLMAP sparse models: the text (``cameras.txt``, ``images.txt``, ``points3D.txt``) and the binary
(``cameras.bin``, ``images.bin``, ``points3D.bin``, COLMAP's default output) formats.

No paper equation is implemented here; the paper's Mip-NeRF 360 scenes come as COLMAP models.

Binary layout (COLMAP ``src/colmap/scene/reconstruction_io_binary.cc``; little-endian, no padding): a uint64
record count, then per record its fixed head (``_CAMERA_HEAD``, ``_IMAGE_HEAD``, ``_POINT_HEAD`` below, field by
field) and a variable part: a camera's ``num_params`` doubles (:data:`CAMERA_MODELS`); an image's name ending in a
NUL, then a uint64 count of (double x, double y, uint64 point3D_id); a point's track_length x (uint32 image_id,
uint32 point2D_idx).

Each declared count is checked against the bytes left in the file before anything is read or allocated,
so a truncated or corrupt file raises a ValueError naming the file, the record and the byte offset.
Newer COLMAP versions also write ``rigs.bin`` and ``frames.bin``; ``images.bin`` still holds every
image's camera-from-world pose, so those files are not needed here.

Only the undistorted-style models SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL and OPENCV are turned
into pinhole intrinsics; their distortion coefficients are dropped with a warning naming the camera.
The pose convention (world-to-camera, OpenCV axes, pixel centres at i + 0.5) is exactly
:class:`recon.camera.Camera`'s.

Where both models are present, the binary one is read (as graphdeco's 3DGS trainer does).

Example:
    >>> model = read_colmap_model(find_colmap_sparse(Path("data/garden")))  # doctest: +SKIP
    >>> model.kind, len(model.images), model.points.shape  # doctest: +SKIP
    ('binary', 185, (138766, 3))
"""

from __future__ import annotations

import logging
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

logger = logging.getLogger(__name__)

TEXT_FILES = ("cameras.txt", "images.txt", "points3D.txt")
BINARY_FILES = ("cameras.bin", "images.bin", "points3D.bin")
# COLMAP's default re-export command, named in the error messages.
_REEXPORT = "re-export it with `colmap model_converter --input_path SPARSE --output_path SPARSE --output_type BIN`"


@dataclass(frozen=True)
class CameraModel:
    """One COLMAP camera model: its id in binary files, its name in text files, its parameter count."""

    model_id: int
    name: str
    num_params: int


# COLMAP src/colmap/sensor/models.h (CameraModelId and each model's focal + principal point + extra counts).
CAMERA_MODELS = (
    CameraModel(0, "SIMPLE_PINHOLE", 3),
    CameraModel(1, "PINHOLE", 4),
    CameraModel(2, "SIMPLE_RADIAL", 4),
    CameraModel(3, "RADIAL", 5),
    CameraModel(4, "OPENCV", 8),
    CameraModel(5, "OPENCV_FISHEYE", 8),
    CameraModel(6, "FULL_OPENCV", 12),
    CameraModel(7, "FOV", 5),
    CameraModel(8, "SIMPLE_RADIAL_FISHEYE", 4),
    CameraModel(9, "RADIAL_FISHEYE", 5),
    CameraModel(10, "THIN_PRISM_FISHEYE", 12),
    CameraModel(11, "RAD_TAN_THIN_PRISM_FISHEYE", 16),
    CameraModel(12, "SIMPLE_DIVISION", 4),
    CameraModel(13, "DIVISION", 5),
    CameraModel(14, "SIMPLE_FISHEYE", 3),
    CameraModel(15, "FISHEYE", 4),
    CameraModel(16, "EUCM", 6),
    CameraModel(17, "EQUIRECTANGULAR", 2),
)
MODELS_BY_ID = {m.model_id: m for m in CAMERA_MODELS}
MODELS_BY_NAME = {m.name: m for m in CAMERA_MODELS}
# The models read as pinhole cameras -> their parameter count; the single-focal ones list f, cx, cy first.
SUPPORTED_MODELS = {
    name: MODELS_BY_NAME[name].num_params for name in ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")
}
_SINGLE_FOCAL = ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL")

Intrinsics = tuple[int, int, float, float, float, float]  # width, height, fx, fy, cx, cy (pixels)
ImageRecord = tuple[int, np.ndarray, int, str]  # image_id, world_to_camera [4, 4] float64, camera_id, name


@dataclass(frozen=True)
class ColmapModel:
    """A COLMAP sparse model, reduced to what a 3DGS trainer needs.

    Attributes:
        folder: the folder holding the model files.
        kind: "binary" or "text", the files that were read.
        cameras: {camera_id: (width, height, fx, fy, cx, cy)}, pixels.
        images: [(image_id, world_to_camera [4, 4] float64, camera_id, name)] in file order.
        points: [P, 3] float32 point positions, scene units.
        point_colors: [P, 3] float32 colours in [0, 1].
    """

    folder: Path
    kind: str
    cameras: dict[int, Intrinsics]
    images: list[ImageRecord]
    points: np.ndarray
    point_colors: np.ndarray

    @property
    def files(self) -> tuple[str, str, str]:
        """The names of the cameras, images and points files of this model's kind."""
        return BINARY_FILES if self.kind == "binary" else TEXT_FILES


# ---- shared ---------------------------------------------------------------------------------------


def quaternion_wxyz_to_matrix(q: np.ndarray) -> np.ndarray:
    """[3, 3] rotation of a (w, x, y, z) quaternion (normalised first)."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _pinhole(where: str, cam_id: int, model: str, width: int, height: int, params: list[float]) -> Intrinsics:
    """(width, height, fx, fy, cx, cy) of a supported model's parameters; distortion dropped with a warning.

    ``where`` names the file (and line) in the error messages.
    """
    if model not in SUPPORTED_MODELS:
        raise ValueError(
            f"{where}: camera {cam_id} has model {model}; supported: {', '.join(SUPPORTED_MODELS)} "
            "(undistort the images first: `colmap image_undistorter` writes PINHOLE cameras)"
        )
    if len(params) != SUPPORTED_MODELS[model]:
        raise ValueError(f"{where}: model {model} takes {SUPPORTED_MODELS[model]} parameters, got {len(params)}")
    if not np.isfinite(params).all():
        raise ValueError(f"{where}: camera {cam_id} has non-finite parameters {params}")
    if width < 1 or height < 1:
        raise ValueError(f"{where}: camera {cam_id} has image size {width}x{height}; width and height must be >= 1")
    if model in _SINGLE_FOCAL:  # f, cx, cy, ...: fx = fy = f
        params = [params[0], *params]
    fx, fy, cx, cy = params[:4]
    distortion = params[4:]
    if any(d != 0.0 for d in distortion):
        logger.warning(
            "%s: camera %d (%s) has distortion %s, which is ignored; undistort the images for exact projections",
            where,
            cam_id,
            model,
            distortion,
        )
    return width, height, fx, fy, cx, cy


def _pose(where: str, image_id: int, qt: list[float]) -> np.ndarray:
    """[4, 4] world-to-camera of (qw, qx, qy, qz, tx, ty, tz): a quaternion and a translation."""
    qt = np.asarray(qt, dtype=np.float64)
    if not np.isfinite(qt).all() or np.linalg.norm(qt[:4]) == 0:
        raise ValueError(f"{where}: image {image_id} has a non-finite or zero quaternion/translation")
    w2c = np.eye(4)
    w2c[:3, :3] = quaternion_wxyz_to_matrix(qt[:4])
    w2c[:3, 3] = qt[4:]
    return w2c


# ---- text ------------------------------------------------------------------------------------------


def _text_records(path: Path, expected: str, parse, lines_per_record: int = 1) -> list[tuple[str, tuple]]:
    """(``"FILE:LINE"``, parse(tokens)) of each record of a COLMAP text file; comments and blank lines are skipped, and
    so are the ``lines_per_record - 1`` lines after a record's first, even when empty."""
    path = Path(path)
    text = enumerate(path.read_text().splitlines(), start=1)
    lines = ((lineno, line.strip()) for lineno, line in text if not line.lstrip().startswith("#"))
    out = []
    for lineno, line in lines:
        if not line:
            continue
        try:
            out.append((f"{path}:{lineno}", parse(line.split())))
        except (IndexError, ValueError) as exc:
            raise ValueError(f"{path}:{lineno}: expected '{expected}', got {line!r}") from exc
        for _ in range(lines_per_record - 1):
            next(lines, None)
    return out


def _parse_camera(tok: list[str]) -> tuple:
    return int(tok[0]), tok[1], int(tok[2]), int(tok[3]), [float(t) for t in tok[4:]]


def _parse_image(tok: list[str]) -> tuple:
    if len(tok) < 10:  # no name
        raise IndexError
    return int(tok[0]), [float(t) for t in tok[1:8]], int(tok[8]), " ".join(tok[9:])


def _parse_point(tok: list[str]) -> list[float]:
    return [float(tok[k]) for k in (1, 2, 3)] + [int(tok[k]) for k in (4, 5, 6)]


def read_colmap_cameras(path: Path) -> dict[int, Intrinsics]:
    """``cameras.txt`` -> {camera_id: (width, height, fx, fy, cx, cy)}; distortion dropped with a warning."""
    records = _text_records(path, "CAMERA_ID MODEL WIDTH HEIGHT PARAMS...", _parse_camera)
    return {
        cam_id: _pinhole(where, cam_id, model, width, height, params)
        for where, (cam_id, model, width, height, params) in records
    }


def read_colmap_images(path: Path) -> list[ImageRecord]:
    """``images.txt`` -> [(image_id, world_to_camera [4, 4], camera_id, name)] in file order.

    Each image takes two lines: ``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`` then its 2-D points
    (possibly an empty line), which are skipped.
    """
    records = _text_records(path, "IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME", _parse_image, lines_per_record=2)
    return [(image_id, _pose(where, image_id, qt), cam_id, name) for where, (image_id, qt, cam_id, name) in records]


def read_colmap_points(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """``points3D.txt`` -> (xyz [P, 3] float32, rgb [P, 3] float32 in [0, 1])."""
    records = _text_records(path, "POINT3D_ID X Y Z R G B ERROR TRACK...", _parse_point)
    xyz_rgb = np.asarray([values for _, values in records], dtype=np.float64).reshape(-1, 6)
    return xyz_rgb[:, :3].astype(np.float32), xyz_rgb[:, 3:].astype(np.float32) / 255.0


# ---- binary ----------------------------------------------------------------------------------------

_CAMERA_HEAD = struct.Struct("<IiQQ")  # camera_id, model_id, width, height
_IMAGE_HEAD = struct.Struct("<I4d3dI")  # image_id, world-to-camera qvec (w, x, y, z) and tvec, camera_id
_POINT2D_BYTES = struct.calcsize("<ddQ")  # x, y, point3D_id
_POINT_HEAD = struct.Struct("<Q3d3BdQ")  # point3D_id, xyz, rgb, error, track_length
_TRACK_BYTES = struct.calcsize("<II")  # image_id, point2D_idx
_COUNT = struct.Struct("<Q")


class _Bytes:
    """A binary COLMAP file in memory with a read offset; every read checks that the bytes are there, the record count
    (``declared``) is checked against the file size at once, and :meth:`records` checks that no bytes are left."""

    def __init__(self, path: Path, what: str, min_record_bytes: int):
        self.path, self.what = Path(path), what
        self.data = self.path.read_bytes()
        if len(self.data) < _COUNT.size:
            raise ValueError(
                f"{self.path}: {len(self.data)} bytes, too short for the uint64 {self.what} count; "
                f"the file is empty or not a COLMAP binary model: {_REEXPORT}"
            )
        (n,) = _COUNT.unpack_from(self.data, 0)
        self.declared, self.record, self.offset = n, 0, _COUNT.size
        left = len(self.data) - self.offset
        if n * min_record_bytes > left:
            raise ValueError(
                f"{self.path}: truncated or corrupt: declares {n} {self.what} (at least {n * min_record_bytes} "
                f"bytes) but only {left} bytes follow the count; copy the file again or {_REEXPORT}"
            )

    def records(self):
        """The 0-based index of each record, the one the reads that follow belong to."""
        for record in range(self.declared):
            self.record = record  # named in the errors of the reads
            yield record
        extra = len(self.data) - self.offset
        if extra:
            raise ValueError(
                f"{self.path}: {extra} bytes after the last of its {self.declared} {self.what} "
                f"(byte {self.offset}); the file is corrupt or not a COLMAP {self.path.name}: "
                f"{_REEXPORT}"
            )

    def skip(self, nbytes: int) -> int:
        """Move past the next ``nbytes`` bytes; returns the offset where they start."""
        start, end = self.offset, self.offset + nbytes
        if end > len(self.data):
            raise ValueError(
                f"{self.path}: truncated: declares {self.declared} {self.what} but ends at byte {len(self.data)} "
                f"inside {self.what[:-1]} {self.record + 1} (which needs bytes {start} to {end}); the file is "
                f"incomplete or corrupt: copy it again or {_REEXPORT}"
            )
        self.offset = end
        return start

    def unpack(self, fmt: struct.Struct) -> tuple:
        return fmt.unpack_from(self.data, self.skip(fmt.size))

    def name(self) -> str:
        end = self.data.find(b"\0", self.offset)
        end = len(self.data) if end < 0 else end  # no NUL: the name would need a byte past the end
        raw = self.data[self.skip(end + 1 - self.offset) : end]
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise ValueError(
                f"{self.path}: image {self.record + 1}'s name {raw[:40]!r} is not UTF-8; the file is corrupt: "
                f"{_REEXPORT}"
            ) from exc


def read_colmap_cameras_binary(path: Path) -> dict[int, Intrinsics]:
    """``cameras.bin`` -> {camera_id: (width, height, fx, fy, cx, cy)}; distortion dropped with a warning."""
    buf = _Bytes(path, "cameras", _CAMERA_HEAD.size + 8 * min(m.num_params for m in CAMERA_MODELS))
    cams = {}
    for i in buf.records():
        cam_id, model_id, width, height = buf.unpack(_CAMERA_HEAD)
        model = MODELS_BY_ID.get(model_id)
        if model is None:
            raise ValueError(
                f"{buf.path}: camera {cam_id} (record {i + 1} of {buf.declared}, byte "
                f"{buf.offset - _CAMERA_HEAD.size}) has unknown model id {model_id} (COLMAP's are "
                f"0-{len(CAMERA_MODELS) - 1}); the file is corrupt: {_REEXPORT}"
            )
        params = list(buf.unpack(struct.Struct(f"<{model.num_params}d")))
        cams[cam_id] = _pinhole(str(buf.path), cam_id, model.name, width, height, params)
    return cams


def read_colmap_images_binary(path: Path) -> list[ImageRecord]:
    """``images.bin`` -> [(image_id, world_to_camera [4, 4], camera_id, name)] in file order (2-D points skipped)."""
    buf = _Bytes(path, "images", _IMAGE_HEAD.size + 1 + _COUNT.size)  # the shortest: an empty name, no points
    out = []
    for i in buf.records():
        image_id, *qt, cam_id = buf.unpack(_IMAGE_HEAD)
        name = buf.name()
        buf.skip(buf.unpack(_COUNT)[0] * _POINT2D_BYTES)
        if not name:
            raise ValueError(
                f"{buf.path}: image {image_id} (record {i + 1} of {buf.declared}) has an empty name; {_REEXPORT}"
            )
        out.append((image_id, _pose(str(buf.path), image_id, qt), cam_id, name))
    return out


def read_colmap_points_binary(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """``points3D.bin`` -> (xyz [P, 3] float32, rgb [P, 3] float32 in [0, 1]); errors and tracks skipped.

    The records have variable length (their tracks), so one Python pass finds where each starts (reading
    only its track length) and numpy gathers the positions and colours from those offsets.
    """
    buf = _Bytes(path, "points", _POINT_HEAD.size)  # bounds the arrays below by the file size
    data, size, head = buf.data, len(buf.data), _POINT_HEAD.size
    track_length_at = head - _COUNT.size  # the track length is the record head's last field
    read_count = _COUNT.unpack_from
    offsets = []
    for _ in buf.records():
        nbytes = head
        if buf.offset + head <= size:
            nbytes += _TRACK_BYTES * read_count(data, buf.offset + track_length_at)[0]
        offsets.append(buf.skip(nbytes))
    starts = np.asarray(offsets, dtype=np.int64).reshape(-1, 1)
    raw = np.frombuffer(data, dtype=np.uint8)
    xyz = raw[starts + np.arange(8, 32)].view("<f8").reshape(-1, 3)  # after the uint64 id
    rgb = raw[starts + np.arange(32, 35)]
    return xyz.astype(np.float32), rgb.astype(np.float32) / 255.0


# ---- model folders ---------------------------------------------------------------------------------


def colmap_model_kind(folder: Path) -> str | None:
    """``"binary"`` when ``folder`` holds cameras/images/points3D ``.bin``, else ``"text"`` for the ``.txt``
    files, else None (binary wins where both are complete)."""
    for kind, files in (("binary", BINARY_FILES), ("text", TEXT_FILES)):
        if all((Path(folder) / f).is_file() for f in files):
            return kind
    return None


def find_colmap_sparse(root: Path) -> Path | None:
    """The folder holding a COLMAP model (binary or text): ``root/sparse/0``, ``root/sparse`` or ``root``."""
    root = Path(root)
    for cand in (root / "sparse" / "0", root / "sparse", root):
        if colmap_model_kind(cand) is not None:
            return cand
    return None


def read_colmap_model(folder: Path) -> ColmapModel:
    """Read the COLMAP model in ``folder``: the binary files when all three are there, else the text files.

    Raises:
        ValueError: no model in the folder, or a file is malformed (the message names the file and the fix).
    """
    folder = Path(folder)
    kind = colmap_model_kind(folder)
    if kind is None:
        raise ValueError(f"{folder}: no COLMAP model; expected {', '.join(BINARY_FILES)} or {', '.join(TEXT_FILES)}")
    binary = kind == "binary"
    cams_file, images_file, points_file = (folder / f for f in (BINARY_FILES if binary else TEXT_FILES))
    try:
        cams = (read_colmap_cameras_binary if binary else read_colmap_cameras)(cams_file)
        images = (read_colmap_images_binary if binary else read_colmap_images)(images_file)
        xyz, rgb = (read_colmap_points_binary if binary else read_colmap_points)(points_file)
    except ValueError as exc:
        if binary and all((folder / f).is_file() for f in TEXT_FILES):
            raise ValueError(
                f"{exc} ({folder} also holds a text model, which is read when the .bin files are moved away)"
            ) from exc
        raise
    logger.debug(
        "read COLMAP %s model %s: %d cameras, %d images, %d points", kind, folder, len(cams), len(images), len(xyz)
    )
    return ColmapModel(folder=folder, kind=kind, cameras=cams, images=images, points=xyz, point_colors=rgb)
