"""Tests for recon.datasets.load_cameras, the one reader of Blender / NeRF cameras files (used by
``fluidgs score`` / ``critical`` / ``demo`` directly and by make-assets): the same
cameras as load_blender, the --res scaling of the former score reader, the image-size fallbacks, and a
ValueError naming the file, the frame (index and file_path) and the key for every malformed entry."""

import json
import math

import cv2
import numpy as np
import pytest
import torch

from recon.camera import Camera
from recon.camera_paths import random_sphere
from recon.datasets import load_blender, load_cameras

FOV = 0.8
EYE = [[1, 0, 0, 0.5], [0, 1, 0, -0.25], [0, 0, 1, 4.0], [0, 0, 0, 1]]  # OpenGL c2w: camera at (0.5, -0.25, 4)


def _write(path, meta):
    path.write_text(json.dumps(meta))
    return path


def _file(tmp_path, frames=None, **keys):
    meta = {"camera_angle_x": FOV, "w": 48, "h": 40, **keys}
    meta["frames"] = (
        frames
        if frames is not None
        else [
            {"file_path": "./a", "transform_matrix": EYE},
            {
                "file_path": "./b",
                "transform_matrix": Camera.look_at((3, 1, 2), (0, 0, 0), (0, 1, 0), 8, 8, 1.0).opengl_c2w().tolist(),
            },
        ]
    )
    return _write(tmp_path / "transforms.json", {k: v for k, v in meta.items() if v is not None})


def test_same_cameras_as_load_blender(tmp_path):
    cams = random_sphere(5, 4.0, 12, 10, FOV, seed=1)
    frames = [{"file_path": f"./train/{c.name}", "transform_matrix": c.opengl_c2w().tolist()} for c in cams]
    (tmp_path / "train").mkdir()
    for c in cams:
        cv2.imwrite(str(tmp_path / "train" / f"{c.name}.png"), np.zeros((10, 12, 3), np.uint8))
    _write(tmp_path / "transforms_train.json", {"camera_angle_x": FOV, "frames": frames})  # size from the images
    ours = load_cameras(tmp_path / "transforms_train.json")
    theirs = [v.camera for v in load_blender(tmp_path).train]
    assert [c.name for c in ours] == [c.name for c in theirs] == [c.name for c in cams]
    for a, b, ref in zip(ours, theirs, cams, strict=True):
        assert (a.width, a.height, a.fx, a.fy, a.cx, a.cy) == (b.width, b.height, b.fx, b.fy, b.cx, b.cy)
        assert torch.equal(a.world_to_camera, b.world_to_camera)
        torch.testing.assert_close(a.world_to_camera, ref.world_to_camera, atol=1e-12, rtol=0)
        assert a.fx == pytest.approx(ref.fx)


def test_res_scales_every_camera_to_that_width(tmp_path):
    """The former score reader's rule: width = res, height = round(res h / w), intrinsics scaled per axis."""
    path = _file(tmp_path, camera_angle_x=None, fl_x=50.0, fl_y=52.0, cx=24.5, cy=19.0)
    cam = load_cameras(path, res=30)[0]
    assert (cam.width, cam.height) == (30, 25)
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == pytest.approx((50 * 30 / 48, 52 * 25 / 40, 24.5 * 30 / 48, 19 * 25 / 40))
    cam = load_cameras(_file(tmp_path), res=24)[1]
    assert (cam.width, cam.height) == (24, 20) and cam.fx == pytest.approx(12 / math.tan(FOV / 2))
    assert cam.name == "b" and load_cameras(_file(tmp_path))[0].width == 48


def test_size_from_image_then_res(tmp_path):
    path = _file(tmp_path, w=None, h=None)
    cv2.imwrite(str(tmp_path / "a.png"), np.zeros((7, 9, 3), np.uint8))
    with pytest.raises(ValueError, match=r"frame 1 \(file_path './b'\) has no 'w'/'h' keys and no readable image"):
        load_cameras(path)
    a, b = load_cameras(path, res=18)
    assert (a.width, a.height) == (18, 14) and (b.width, b.height) == (18, 18)  # b: square, no image
    frames = [{"transform_matrix": EYE}]
    cam = load_cameras(_file(tmp_path, frames=frames, h=None), res=24)[0]
    assert cam.name == "view_000" and (cam.width, cam.height) == (24, 24)


def _blank_png(path, width: int, height: int) -> None:
    """A grey 8-bit PNG of ``width`` x ``height`` zeros, streamed row by row (a few hundred KB on disk)."""
    import struct
    import zlib

    packer, row = zlib.compressobj(9), bytes(width + 1)  # filter byte 0, then the row
    data = b"".join(packer.compress(row) for _ in range(height)) + packer.flush()

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    header = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", data) + chunk(b"IEND", b""))


def test_size_from_an_image_reads_its_header_only(tmp_path, monkeypatch):
    """The size of a frame without w/h came from decoding its whole image: a 400 KB PNG of 20000 x 10000 pixels cost
    200 MB (a 20000 x 20000 RGB one, 2.6 GB, on every frame). Only the header is read now, past Pillow's bomb limit
    (nothing is decoded), and the camera gets the image's size."""
    _blank_png(tmp_path / "a.png", 20000, 10000)
    assert (tmp_path / "a.png").stat().st_size < 1_000_000

    def decode(*args, **kwargs):
        raise AssertionError("the image was decoded to read its size")

    monkeypatch.setattr(cv2, "imread", decode)
    frames = [{"file_path": "./a", "transform_matrix": EYE}]
    cam = load_cameras(_file(tmp_path, frames=frames, w=None, h=None))[0]
    assert (cam.width, cam.height) == (20000, 10000)


def _bad(matrix):
    return [{"file_path": "./a", "transform_matrix": EYE}, {"file_path": "./r_7", "transform_matrix": matrix}]


SCALED = [[2, 0, 0, 0], [0, 2, 0, 0], [0, 0, 2, 4], [0, 0, 0, 1]]
MIRROR = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, 4], [0, 0, 0, 1]]
F1 = r"transforms\.json: frame 1 \(file_path './r_7'\)"
TOP = r"transforms\.json: frame 0 \(file_path './a'\)"


@pytest.mark.parametrize(
    "keys, frames, res, message",
    [
        # raised ZeroDivisionError in apps.score.load_cameras
        ({"w": 0, "h": 0}, None, 24, TOP + r": key 'w' \(top level\) must be a positive integer image size in pixels"),
        ({"w": 0, "h": 0}, None, None, TOP + r": key 'w' \(top level\) must be a positive integer"),
        ({"h": 12.5}, None, None, TOP + r": key 'h' \(top level\) must be a positive integer"),
        # the size was written out in full: 309 digits
        ({"w": 1e308}, None, None, TOP + r": key 'w' \(top level\) is 1e\+308 pixels, more than 65,536, the largest"),
        (
            {},
            [{"file_path": "./a", "transform_matrix": EYE}, {"file_path": "./r_7", "transform_matrix": EYE, "w": -3}],
            None,
            F1 + r": key 'w' must be a positive integer",
        ),
        # printed 'Singular matrix' / 'could not convert string to float' without the file and frame
        (
            {},
            _bad([[0, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 4], [0, 0, 0, 1]]),
            None,
            F1 + r": 'transform_matrix' is singular \(its 3x3 rotation part has determinant 0\)",
        ),
        (
            {},
            _bad([["x", 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]),
            None,
            F1 + r": 'transform_matrix' is not a numeric matrix \(could not convert string to float: 'x'\)",
        ),
        (
            {"camera_angle_x": "wide"},
            None,
            None,
            TOP + r": key 'camera_angle_x' \(top level\) must be a number, "
            r"got 'wide'",
        ),
        (
            {},
            [{"file_path": "./a", "transform_matrix": EYE, "fl_x": [1]}],
            None,
            TOP + r": key 'fl_x' must be a number",
        ),
        (
            {},
            [{"file_path": "./a", "transform_matrix": EYE, "fl_x": True}],
            None,
            TOP + r": key 'fl_x' must be a number",
        ),
        (
            {"camera_angle_x": 4.0},
            None,
            None,
            TOP + r": key 'camera_angle_x' \(top level\) \(field of view\) must be in",
        ),
        ({}, [{"file_path": "./a", "transform_matrix": EYE, "fl_y": 0}], None, TOP + r": key 'fl_y' .* must be > 0"),
        ({}, _bad(SCALED), None, F1 + r": 'transform_matrix' 3x3 part is not orthonormal"),
        ({}, _bad(MIRROR), None, F1 + r": 'transform_matrix' 3x3 part is a reflection"),
        ({}, _bad([EYE[0], EYE[1], EYE[2], [0, 0, 1, 1]]), None, F1 + r": 'transform_matrix' last row must be"),
        ({}, _bad([[1, 0, 0], [0, 1, 0]]), None, F1 + r": 'transform_matrix' must be a 4x4 \(or 3x4\) matrix"),
        ({}, _bad([[1, 0, 0, 0], [0, 1, 0]]), None, F1 + r": 'transform_matrix' is not a numeric matrix"),
        ({}, _bad([[math.nan, 0, 0, 0], *EYE[1:]]), None, F1 + r": 'transform_matrix' holds NaN"),
        ({}, [{"file_path": "./a"}], None, TOP + r" has no 'transform_matrix' key"),
        ({"camera_angle_x": None}, None, None, r"transforms\.json: missing 'camera_angle_x'.*'fl_x'.*frame 0"),
        ({}, [], None, r"transforms\.json: 'frames' is empty"),
        ({}, [3], None, r"transforms\.json: frame 0 is not an object"),
        ({}, None, 0, r"res \(--res\) must be a positive integer"),
    ],
)
def test_errors_name_file_frame_and_key(tmp_path, keys, frames, res, message):
    path = _file(tmp_path, frames=frames, **keys)
    with pytest.raises(ValueError, match=message):
        load_cameras(path, res=res)


def test_file_level_errors(tmp_path):
    with pytest.raises(ValueError, match=r"nope\.json does not exist; pass a Blender / NeRF transforms\.json"):
        load_cameras(tmp_path / "nope.json")
    (tmp_path / "x.json").write_text("{frames")
    with pytest.raises(ValueError, match=r"x\.json is not valid JSON"):
        load_cameras(tmp_path / "x.json")
    (tmp_path / "x.json").write_text("[1, 2]")
    with pytest.raises(ValueError, match=r"x\.json: missing 'frames' list"):
        load_cameras(tmp_path / "x.json")


def test_apps_readers_are_this_reader(tmp_path):
    from apps.make_assets import cameras_json, read_cameras_json

    cams = random_sphere(4, 6.0, 16, 16, math.radians(50), seed=3)
    path = _write(tmp_path / "ahmed_cameras.json", cameras_json(cams, math.radians(50)))
    for read in (read_cameras_json(path), load_cameras(path)):
        assert [c.name for c in read] == [c.name for c in cams]
        for a, b in zip(read, cams, strict=True):
            torch.testing.assert_close(a.world_to_camera, b.world_to_camera, atol=1e-12, rtol=0)
            assert (a.width, a.height, a.fx, a.fy, a.cx, a.cy) == pytest.approx(
                (b.width, b.height, b.fx, b.fy, b.cx, b.cy)
            )
    assert [c.width for c in load_cameras(path, 8)] == [8] * 4
    with pytest.raises(ValueError, match=r"frame 1 \(file_path './r_7'\): 'transform_matrix' is singular"):
        load_cameras(_file(tmp_path, frames=_bad([[0] * 4, [0] * 4, [0, 0, 0, 4], [0, 0, 0, 1]])))
