"""recon.camera_files: every camera file a 3DGS user has, chosen by content. The same poses written as a
transforms.json, a COLMAP model (binary and text, as the model folder, sparse/, or the dataset root) and graphdeco's
cameras.json give the same cameras; graphdeco's layout decoded by hand; a folder that exists is never "missing"."""

import json
import math
import struct

import numpy as np
import pytest
import torch

from recon.camera import Camera
from recon.camera_files import (
    colmap_text,
    find_camera_file,
    graphdeco_json,
    load_camera_file,
    rotation_to_quaternion_wxyz,
    transforms_json,
)
from recon.camera_paths import random_sphere
from recon.colmap import MODELS_BY_NAME, quaternion_wxyz_to_matrix


def _cams():
    cams = random_sphere(6, 4.0, 48, 36, 0.9, seed=3, hemisphere=True, target=(0.5, -0.2, 0.1))
    return [
        Camera(c.width, c.height, c.fx, c.fy * 1.02, c.width / 2, c.height / 2, c.world_to_camera, f"img_{i:02d}")
        for i, c in enumerate(cams)
    ]


def _colmap_binary(cams) -> tuple[bytes, bytes]:
    """cameras.bin and images.bin as COLMAP writes them (reconstruction_io_binary.cc): PINHOLE cameras."""
    cam_bytes = struct.pack("<Q", len(cams))
    img_bytes = struct.pack("<Q", len(cams))
    for i, c in enumerate(cams, start=1):
        cam_bytes += struct.pack(
            "<IiQQ4d", i, MODELS_BY_NAME["PINHOLE"].model_id, c.width, c.height, c.fx, c.fy, c.cx, c.cy
        )
        w2c = c.world_to_camera.numpy()
        q = rotation_to_quaternion_wxyz(w2c[:3, :3])
        img_bytes += struct.pack("<I4d3dI", i, *q, *w2c[:3, 3], i) + f"{c.name}.png".encode() + b"\0"
        img_bytes += struct.pack("<Q", 0)
    return cam_bytes, img_bytes


def _write_all(root, cams):
    """{kind: path} of the same cameras in every format and place."""
    root.mkdir(parents=True, exist_ok=True)
    (root / "poses.json").write_text(json.dumps(transforms_json(cams)))
    (root / "model_cameras.json").write_text(json.dumps(graphdeco_json(cams)))
    text = root / "text" / "sparse" / "0"
    text.mkdir(parents=True)
    cams_txt, images_txt = colmap_text(cams)
    (text / "cameras.txt").write_text(cams_txt)
    (text / "images.txt").write_text(images_txt)
    binary = root / "binary" / "sparse" / "0"
    binary.mkdir(parents=True)
    cam_bin, img_bin = _colmap_binary(cams)
    (binary / "cameras.bin").write_bytes(cam_bin)
    (binary / "images.bin").write_bytes(img_bin)
    return {
        "transforms": root / "poses.json",
        "graphdeco": root / "model_cameras.json",
        "colmap text, model folder": text,
        "colmap text, sparse": text.parent,
        "colmap text, dataset root": text.parent.parent,
        "colmap binary, dataset root": binary.parent.parent,
        "colmap binary, a model file": binary / "images.bin",
    }


def test_the_same_poses_in_every_format_give_the_same_cameras(tmp_path):
    cams = _cams()
    for where, path in _write_all(tmp_path, cams).items():
        got = load_camera_file(path)
        assert [c.name for c in got] == [c.name for c in cams], where
        for a, b in zip(got, cams, strict=True):
            assert (a.width, a.height) == (b.width, b.height), where
            np.testing.assert_allclose([a.fx, a.fy, a.cx, a.cy], [b.fx, b.fy, b.cx, b.cy], rtol=1e-12, err_msg=where)
            torch.testing.assert_close(a.world_to_camera, b.world_to_camera, atol=1e-10, rtol=0, msg=where)
    assert find_camera_file(tmp_path / "text").kind == "colmap"
    assert find_camera_file(tmp_path / "poses.json").kind == "transforms"
    assert find_camera_file(tmp_path / "model_cameras.json").kind == "graphdeco"


def test_res_scales_every_kind(tmp_path):
    cams = _cams()
    for where, path in _write_all(tmp_path, cams).items():
        got = load_camera_file(path, res=24)
        assert all((c.width, c.height) == (24, 18) for c in got), where
        assert got[0].fx == pytest.approx(cams[0].fx / 2), where


def test_graphdeco_layout_decoded_by_hand(tmp_path):
    """graphdeco's camera_to_JSON: position = camera centre, rotation = camera-to-world rotation (OpenCV axes:
    columns x right, y down, z forward in the world); the principal point is the image centre."""
    # a camera at (0, 0, -5) with its axes along the world's looks along +z: the origin is at the image centre, depth 5;
    # a second one turned half about y sits at (0, 0, 5) and sees world +x on its left (image x decreasing)
    entries = [
        {
            "id": 0,
            "img_name": "front",
            "width": 40,
            "height": 30,
            "position": [0, 0, -5.0],
            "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1.0]],
            "fy": 50.0,
            "fx": 60.0,
        },
        {
            "id": 1,
            "img_name": "back",
            "width": 40,
            "height": 30,
            "position": [0, 0, 5.0],
            "rotation": [[-1, 0, 0], [0, 1, 0], [0, 0, -1.0]],
            "fy": 50.0,
            "fx": 60.0,
        },
    ]
    path = tmp_path / "cameras.json"
    path.write_text(json.dumps(entries))
    front, back = load_camera_file(tmp_path)  # the folder holding cameras.json
    pts = torch.tensor([[0.0, 0, 0], [1.0, 0, 0], [0, 1.0, 0]], dtype=torch.float64)
    uv, z = front.project(pts)
    np.testing.assert_allclose(uv.numpy(), [[20, 15], [20 + 60 / 5, 15], [20, 15 + 50 / 5]])
    np.testing.assert_allclose(z.numpy(), [5, 5, 5])
    uv, z = back.project(pts)
    np.testing.assert_allclose(uv.numpy(), [[20, 15], [20 - 60 / 5, 15], [20, 15 + 50 / 5]])
    assert (front.name, back.name, front.fx, front.fy) == ("front", "back", 60.0, 50.0)


def test_quaternion_round_trip():
    rng = np.random.default_rng(0)
    for _ in range(200):
        q = rng.standard_normal(4)
        r = quaternion_wxyz_to_matrix(q)
        back = rotation_to_quaternion_wxyz(r)
        assert back[0] >= 0
        np.testing.assert_allclose(quaternion_wxyz_to_matrix(back), r, atol=1e-12)
        np.testing.assert_allclose(np.abs(back), np.abs(q / np.linalg.norm(q)), atol=1e-12)
    for r in (np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1]), np.diag([-1.0, -1, 1])):  # half turns: w = 0
        np.testing.assert_allclose(quaternion_wxyz_to_matrix(rotation_to_quaternion_wxyz(r)), r, atol=1e-12)


def test_a_folder_that_exists_is_never_missing_and_the_error_lists_what_is_accepted(tmp_path):
    empty = tmp_path / "capture"
    (empty / "sparse" / "0").mkdir(parents=True)
    (empty / "sparse" / "0" / "points3D.bin").write_bytes(b"")
    with pytest.raises(ValueError) as info:
        load_camera_file(empty)
    text = str(info.value)
    assert "no such" not in text and "a folder with no camera file" in text
    for accepted in ("transforms.json", "COLMAP model", "cameras.bin + images.bin", "graphdeco's cameras.json"):
        assert accepted in text
    with pytest.raises(ValueError, match=r"missing_dir: no such file or folder; pass a Blender"):
        load_camera_file(tmp_path / "missing_dir")
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"camera": 1}))
    with pytest.raises(ValueError, match=r"not a camera file: it holds an object with keys \['camera'\].*COLMAP"):
        load_camera_file(other)
    bad = tmp_path / "bad.json"
    bad.write_text(
        json.dumps(
            [
                {
                    "position": [0, 0, 0],
                    "rotation": [[2, 0, 0], [0, 1, 0], [0, 0, 1]],
                    "width": 4,
                    "height": 4,
                    "fx": 1,
                    "fy": 1,
                }
            ]
        )
    )
    with pytest.raises(ValueError, match=r"bad.json: entry 0: 'rotation' is not a rotation"):
        load_camera_file(bad)


def test_transforms_written_keep_the_convention():
    """transform_matrix is OpenGL camera-to-world: its column 2 points backwards, away from what the camera sees."""
    cam = Camera.look_at((0, 0, 3.0), (0, 0, 0), (0, 1, 0), 32, 24, math.radians(50), name="a")
    frame = transforms_json([cam])["frames"][0]
    m = np.asarray(frame["transform_matrix"])
    np.testing.assert_allclose(m[:3, 3], [0, 0, 3], atol=1e-12)
    np.testing.assert_allclose(m[:3, 2], [0, 0, 1], atol=1e-12)  # backwards = +z: the camera looks along -z
    np.testing.assert_allclose(m[:3, 1], [0, 1, 0], atol=1e-12)  # image up = world up
    assert (frame["w"], frame["h"], frame["file_path"]) == (32, 24, "./a")
