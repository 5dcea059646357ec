"""Tests for recon/colmap.py: COLMAP binary models written by a struct encoder of this file (the layout of
COLMAP's reconstruction_io_binary.cc) read back identically to the same model written as text; records
decoded from hand-written bytes; every truncation, an oversized count, trailing bytes and unknown or
unsupported models raise ValueErrors naming the file; the loaders prefer binary over text."""

import logging
import math
import struct

import cv2
import numpy as np
import pytest
import torch

from recon.colmap import (
    BINARY_FILES,
    CAMERA_MODELS,
    MODELS_BY_NAME,
    TEXT_FILES,
    colmap_model_kind,
    find_colmap_sparse,
    quaternion_wxyz_to_matrix,
    read_colmap_cameras,
    read_colmap_cameras_binary,
    read_colmap_images,
    read_colmap_images_binary,
    read_colmap_model,
    read_colmap_points,
    read_colmap_points_binary,
)
from recon.datasets import dataset_format, load_colmap, load_dataset

INVALID_POINT3D = 2**64 - 1  # COLMAP's kInvalidPoint3DId: a 2-D point without a 3-D point

# ---- a model, and encoders for both formats -------------------------------------------------------

CAMERAS = [  # camera_id, model, width, height, params
    (1, "PINHOLE", 64, 48, [100.0, 120.0, 32.0, 24.0]),
    (2, "SIMPLE_RADIAL", 60, 40, [90.0, 30.0, 20.0, 0.0]),
    (7, "SIMPLE_PINHOLE", 32, 32, [40.5, 16.0, 16.25]),
    (9, "OPENCV", 80, 60, [70.0, 71.0, 40.5, 29.5, 0.0, 0.0, 0.0, 0.0]),
    (2**32 - 2, "RADIAL", 50, 30, [55.0, 25.0, 15.0, 0.0, 0.0]),
]


def _images():
    rng = np.random.default_rng(0)
    out = []
    records = [
        (3, 1, "a.png"),
        (5, 2, "b.png"),
        (4, 1, "c.png"),
        (3_000_000_000, 7, "sub dir/d e.png"),
        (40, 9, "f.jpg"),
        (2, 2**32 - 2, "g.png"),
    ]  # ids >= 2^31: COLMAP's ids are unsigned
    for k, (image_id, cam_id, name) in enumerate(records):
        q = rng.standard_normal(4)
        q = q / np.linalg.norm(q)
        t = rng.standard_normal(3) * 3
        points2d = [
            (float(x), float(y), int(pid))
            for x, y, pid in zip(rng.random(k) * 50, rng.random(k) * 40, [7, 8, INVALID_POINT3D, 7, 8][:k], strict=True)
        ]
        out.append((image_id, q, t, cam_id, name, points2d))
    return out


IMAGES = _images()
POINTS = [  # point3D_id, xyz, rgb, error, track [(image_id, point2D_idx)]
    (7, (1.0, 0.5, 0.0), (255, 0, 51), 0.1, [(3, 0), (5, 0)]),
    (8, (-1.0, 2.0, 3.0), (0, 255, 0), 0.2, [(4, 1)]),
    (2**40 + 3, (0.125, -7.5, 1e-3), (12, 34, 56), 0.0, []),
]


def _encode_cameras(cameras) -> bytes:
    out = struct.pack("<Q", len(cameras))
    for cam_id, model, width, height, params in cameras:
        out += struct.pack("<IiQQ", cam_id, MODELS_BY_NAME[model].model_id, width, height)
        out += struct.pack(f"<{len(params)}d", *params)
    return out


def _encode_images(images) -> bytes:
    out = struct.pack("<Q", len(images))
    for image_id, q, t, cam_id, name, points2d in images:
        out += struct.pack("<I4d3dI", image_id, *q, *t, cam_id) + name.encode() + b"\0"
        out += struct.pack("<Q", len(points2d))
        for x, y, pid in points2d:
            out += struct.pack("<ddQ", x, y, pid)
    return out


def _encode_points(points) -> bytes:
    out = struct.pack("<Q", len(points))
    for pid, xyz, rgb, error, track in points:
        out += struct.pack("<Q3d3BdQ", pid, *xyz, *rgb, error, len(track))
        for image_id, idx in track:
            out += struct.pack("<II", image_id, idx)
    return out


def _text_cameras(cameras) -> str:
    return "# Camera list\n" + "".join(
        f"{c} {m} {w} {h} {' '.join(repr(p) for p in params)}\n" for c, m, w, h, params in cameras
    )


def _text_images(images) -> str:
    lines = ["# Image list"]
    for image_id, q, t, cam_id, name, points2d in images:
        lines.append(" ".join([str(image_id), *(repr(float(v)) for v in (*q, *t)), str(cam_id), name]))
        lines.append(" ".join(f"{x!r} {y!r} {-1 if pid == INVALID_POINT3D else pid}" for x, y, pid in points2d))
    return "\n".join(lines) + "\n"


def _text_points(points) -> str:
    return "# 3D point list\n" + "".join(
        f"{pid} {' '.join(repr(v) for v in xyz)} {' '.join(str(c) for c in rgb)} {error!r} "
        f"{' '.join(f'{i} {j}' for i, j in track)}\n"
        for pid, xyz, rgb, error, track in points
    )


def _write_model(folder, binary=True, text=True, cameras=CAMERAS, images=IMAGES, points=POINTS):
    folder.mkdir(parents=True, exist_ok=True)
    if binary:
        (folder / "cameras.bin").write_bytes(_encode_cameras(cameras))
        (folder / "images.bin").write_bytes(_encode_images(images))
        (folder / "points3D.bin").write_bytes(_encode_points(points))
    if text:
        (folder / "cameras.txt").write_text(_text_cameras(cameras))
        (folder / "images.txt").write_text(_text_images(images))
        (folder / "points3D.txt").write_text(_text_points(points))
    return folder


# ---- binary == text ---------------------------------------------------------------------------------


def test_binary_and_text_readers_agree_exactly(tmp_path):
    folder = _write_model(tmp_path)
    cams_bin, cams_txt = read_colmap_cameras_binary(folder / "cameras.bin"), read_colmap_cameras(folder / "cameras.txt")
    assert cams_bin == cams_txt
    assert cams_bin[7] == (32, 32, 40.5, 40.5, 16.0, 16.25) and cams_bin[9] == (80, 60, 70.0, 71.0, 40.5, 29.5)
    imgs_bin, imgs_txt = read_colmap_images_binary(folder / "images.bin"), read_colmap_images(folder / "images.txt")
    assert (
        [(i, c, n) for i, _, c, n in imgs_bin]
        == [(i, c, n) for i, _, c, n in imgs_txt]
        == [(i, c, n) for i, _, _, c, n, _ in IMAGES]
    )
    for (_, w2c_bin, _, _), (_, w2c_txt, _, _), (_, q, t, _, _, _) in zip(imgs_bin, imgs_txt, IMAGES, strict=True):
        np.testing.assert_array_equal(w2c_bin, w2c_txt)
        np.testing.assert_allclose(w2c_bin[:3, :3], quaternion_wxyz_to_matrix(q), atol=1e-15)
        np.testing.assert_array_equal(w2c_bin[:3, 3], t)
        np.testing.assert_array_equal(w2c_bin[3], [0, 0, 0, 1])
    (xyz_b, rgb_b), (xyz_t, rgb_t) = (
        read_colmap_points_binary(folder / "points3D.bin"),
        read_colmap_points(folder / "points3D.txt"),
    )
    np.testing.assert_array_equal(xyz_b, xyz_t)
    np.testing.assert_array_equal(rgb_b, rgb_t)
    assert xyz_b.dtype == rgb_b.dtype == np.float32 and xyz_b.shape == (3, 3)
    np.testing.assert_array_equal(xyz_b, np.float32([p[1] for p in POINTS]))
    np.testing.assert_array_equal(rgb_b, np.float32([p[2] for p in POINTS]) / 255.0)


def test_model_prefers_binary_and_names_its_files(tmp_path):
    both = _write_model(tmp_path / "both")
    assert colmap_model_kind(both) == "binary"
    # make the text copy differ: the binary points must win
    (both / "points3D.txt").write_text(_text_points([(1, (9.0, 9.0, 9.0), (1, 2, 3), 0.0, [])]))
    model = read_colmap_model(both)
    assert model.kind == "binary" and model.files == BINARY_FILES and len(model.points) == 3
    text = read_colmap_model(_write_model(tmp_path / "text", binary=False))
    assert text.kind == "text" and text.files == TEXT_FILES
    assert text.cameras == model.cameras
    # a partial binary model falls back to the complete text one
    (both / "images.bin").unlink()
    assert colmap_model_kind(both) == "text"
    (both / "images.txt").unlink()
    assert colmap_model_kind(both) is None
    with pytest.raises(ValueError, match=r"no COLMAP model.*cameras\.bin.*cameras\.txt"):
        read_colmap_model(both)


@pytest.mark.parametrize("layout", ["sparse/0", "sparse", "."])
def test_find_sparse_and_dataset_format_see_binary_models(tmp_path, layout):
    _write_model(tmp_path / layout, text=False)
    assert find_colmap_sparse(tmp_path) == tmp_path / layout
    assert dataset_format(tmp_path) == "colmap"


# ---- records decoded by hand ------------------------------------------------------------------------


def _le_double(hex_be: str) -> bytes:
    """Little-endian bytes of an IEEE double given as its big-endian hex (as printed by float.hex tables)."""
    return bytes.fromhex(hex_be)[::-1]


def test_records_decoded_by_hand(tmp_path):
    # cameras.bin: count 1; camera 7, model 1 (PINHOLE), 640 x 480, fx 500, fy 510, cx 320, cy 240.
    cams = (
        bytes.fromhex("0100000000000000")
        + bytes.fromhex("07000000")
        + bytes.fromhex("01000000")
        + bytes.fromhex("8002000000000000")
        + bytes.fromhex("e001000000000000")
        + _le_double("407f400000000000")
        + _le_double("407fe00000000000")
        + _le_double("4074000000000000")
        + _le_double("406e000000000000")
    )
    (tmp_path / "cameras.bin").write_bytes(cams)
    assert read_colmap_cameras_binary(tmp_path / "cameras.bin") == {7: (640, 480, 500.0, 510.0, 320.0, 240.0)}
    # images.bin: count 1; image 3, q = (0, 0, 1, 0) (a half turn about y), t = (0, 0, 5), camera 7, "a.png",
    # one 2-D point (52, 36) without a 3-D point.
    one, zero, five = _le_double("3ff0000000000000"), bytes(8), _le_double("4014000000000000")
    images = (
        bytes.fromhex("0100000000000000")
        + bytes.fromhex("03000000")
        + zero
        + zero
        + one
        + zero
        + zero
        + zero
        + five
        + bytes.fromhex("07000000")
        + b"a.png\x00"
        + bytes.fromhex("0100000000000000")
        + _le_double("404a000000000000")
        + _le_double("4042000000000000")
        + b"\xff" * 8
    )
    (tmp_path / "images.bin").write_bytes(images)
    ((image_id, w2c, cam_id, name),) = read_colmap_images_binary(tmp_path / "images.bin")
    assert (image_id, cam_id, name) == (3, 7, "a.png")
    np.testing.assert_allclose(w2c, [[-1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, 5], [0, 0, 0, 1]], atol=1e-15)
    # points3D.bin: count 1; point 2^32 + 7 at (1, 0.5, -2), colour (255, 0, 51), error 0.25, track of 2.
    points = (
        bytes.fromhex("0100000000000000")
        + bytes.fromhex("0700000001000000")
        + one
        + _le_double("3fe0000000000000")
        + _le_double("c000000000000000")
        + bytes([255, 0, 51])
        + _le_double("3fd0000000000000")
        + bytes.fromhex("0200000000000000")
        + bytes.fromhex("03000000")
        + bytes.fromhex("00000000")
        + bytes.fromhex("05000000")
        + bytes.fromhex("02000000")
    )
    (tmp_path / "points3D.bin").write_bytes(points)
    xyz, rgb = read_colmap_points_binary(tmp_path / "points3D.bin")
    np.testing.assert_array_equal(xyz, [[1.0, 0.5, -2.0]])
    np.testing.assert_allclose(rgb, [[1.0, 0.0, 0.2]], atol=1e-7)
    # the hand-written bytes are what the test encoder writes (so the encoder above follows the same layout)
    assert cams == _encode_cameras([(7, "PINHOLE", 640, 480, [500.0, 510.0, 320.0, 240.0])])
    assert images == _encode_images(
        [(3, (0.0, 0.0, 1.0, 0.0), (0.0, 0.0, 5.0), 7, "a.png", [(52.0, 36.0, INVALID_POINT3D)])]
    )
    assert points == _encode_points([(2**32 + 7, (1.0, 0.5, -2.0), (255, 0, 51), 0.25, [(3, 0), (5, 2)])])


def test_empty_model_files(tmp_path):
    folder = _write_model(tmp_path, text=False, cameras=[], images=[], points=[])
    assert read_colmap_cameras_binary(folder / "cameras.bin") == {}
    assert read_colmap_images_binary(folder / "images.bin") == []
    xyz, rgb = read_colmap_points_binary(folder / "points3D.bin")
    assert xyz.shape == rgb.shape == (0, 3)


def test_camera_model_table_matches_colmap():
    """Ids 0..17 in order with COLMAP's parameter counts (focal + principal point + extra, models.h)."""
    assert [m.model_id for m in CAMERA_MODELS] == list(range(18))
    counts = {m.name: m.num_params for m in CAMERA_MODELS}
    assert counts["SIMPLE_PINHOLE"] == 3 and counts["PINHOLE"] == 4 and counts["OPENCV"] == 8
    assert counts["OPENCV_FISHEYE"] == 8 and counts["FULL_OPENCV"] == 12 and counts["FOV"] == 5
    assert counts["THIN_PRISM_FISHEYE"] == 12 and counts["RAD_TAN_THIN_PRISM_FISHEYE"] == 16
    assert counts["EQUIRECTANGULAR"] == 2


# ---- truncated and corrupt files ----------------------------------------------------------------------

READERS = {
    "cameras.bin": read_colmap_cameras_binary,
    "images.bin": read_colmap_images_binary,
    "points3D.bin": read_colmap_points_binary,
}


@pytest.mark.parametrize("name", BINARY_FILES)
def test_every_truncation_raises_a_value_error_naming_the_file(tmp_path, name):
    folder = _write_model(tmp_path / "model", text=False)
    data = (folder / name).read_bytes()
    cut = tmp_path / name
    for size in range(len(data)):
        cut.write_bytes(data[:size])
        with pytest.raises(ValueError, match=rf"{name}: .*(truncated|too short)") as info:
            READERS[name](cut)
        if size >= 8:
            assert f"ends at byte {size}" in str(info.value) or "follow the count" in str(info.value)


def test_declared_count_is_checked_against_the_file_size(tmp_path):
    folder = _write_model(tmp_path, text=False)
    data = (folder / "images.bin").read_bytes()
    (folder / "images.bin").write_bytes(struct.pack("<Q", 10**15) + data[8:])
    with pytest.raises(ValueError, match=r"images\.bin: truncated or corrupt: declares 1000000000000000 images"):
        read_colmap_images_binary(folder / "images.bin")
    data = (folder / "points3D.bin").read_bytes()
    (folder / "points3D.bin").write_bytes(struct.pack("<Q", 2**63) + data[8:])  # would be exabytes of arrays
    with pytest.raises(ValueError, match=r"points3D\.bin: truncated or corrupt: declares \d+ points"):
        read_colmap_points_binary(folder / "points3D.bin")
    # a record's own count (2-D points, track length) is checked too
    image = bytearray(_encode_images(IMAGES[:1]))
    image[-8:] = struct.pack("<Q", 2**40)
    (folder / "images.bin").write_bytes(bytes(image))
    with pytest.raises(
        ValueError,
        match=r"images\.bin: truncated: declares 1 images but ends at byte \d+ inside "
        r"image 1",
    ):
        read_colmap_images_binary(folder / "images.bin")


def test_trailing_bytes_unknown_and_unsupported_models(tmp_path, caplog):
    path = tmp_path / "cameras.bin"
    path.write_bytes(_encode_cameras(CAMERAS) + b"\0\0\0")
    with pytest.raises(ValueError, match=r"cameras\.bin: 3 bytes after the last of its 5 cameras"):
        read_colmap_cameras_binary(path)
    raw = bytearray(_encode_cameras(CAMERAS[:1]))
    raw[12:16] = struct.pack("<i", 99)
    path.write_bytes(bytes(raw))
    with pytest.raises(ValueError, match=r"cameras\.bin: camera 1 .*unknown model id 99"):
        read_colmap_cameras_binary(path)
    path.write_bytes(_encode_cameras([(4, "OPENCV_FISHEYE", 64, 48, [50.0, 50.0, 32.0, 24.0, 0.1, 0, 0, 0])]))
    with pytest.raises(ValueError, match=r"cameras\.bin: camera 4 has model OPENCV_FISHEYE; supported: .*undistort"):
        read_colmap_cameras_binary(path)
    path.write_bytes(_encode_cameras([(4, "PINHOLE", 0, 48, [50.0, 50.0, 32.0, 24.0])]))
    with pytest.raises(ValueError, match=r"cameras\.bin: camera 4 has image size 0x48"):
        read_colmap_cameras_binary(path)
    path.write_bytes(_encode_cameras([(4, "OPENCV", 64, 48, [50.0, 50.0, 32.0, 24.0, 0.1, 0, 0, 0])]))
    with caplog.at_level(logging.WARNING, logger="recon.colmap"):
        assert read_colmap_cameras_binary(path) == {4: (64, 48, 50.0, 50.0, 32.0, 24.0)}
    assert "camera 4 (OPENCV) has distortion" in caplog.text
    images = tmp_path / "images.bin"
    images.write_bytes(_encode_images([(1, (0.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 1, "a.png", [])]))
    with pytest.raises(ValueError, match=r"images\.bin: image 1 has a non-finite or zero quaternion"):
        read_colmap_images_binary(images)


def test_corrupt_binary_beside_text_says_so(tmp_path):
    folder = _write_model(tmp_path)
    (folder / "points3D.bin").write_bytes((folder / "points3D.bin").read_bytes()[:-3])
    with pytest.raises(ValueError, match=r"points3D\.bin: truncated.*also holds a text model"):
        read_colmap_model(folder)


# ---- loading a dataset ------------------------------------------------------------------------------


def _dataset(root, **kwargs):
    _write_model(root / "sparse" / "0", **kwargs)
    (root / "images" / "sub dir").mkdir(parents=True)
    sizes = {c[0]: (c[2], c[3]) for c in CAMERAS}
    for _, _, _, cam_id, name, _ in IMAGES:
        w, h = sizes[cam_id]
        cv2.imwrite(str(root / "images" / name), np.full((h, w, 3), 128, np.uint8))
    return root


def test_load_colmap_binary_equals_text(tmp_path):
    ds_bin = load_dataset(_dataset(tmp_path / "bin", text=False))
    ds_txt = load_colmap(_dataset(tmp_path / "txt", binary=False))
    for split in ("train", "test"):
        a, b = getattr(ds_bin, split), getattr(ds_txt, split)
        assert [v.name for v in a] == [v.name for v in b]
        for va, vb in zip(a, b, strict=True):
            assert (va.camera.width, va.camera.height, va.camera.fx, va.camera.fy, va.camera.cx, va.camera.cy) == (
                vb.camera.width,
                vb.camera.height,
                vb.camera.fx,
                vb.camera.fy,
                vb.camera.cx,
                vb.camera.cy,
            )
            assert torch.equal(va.camera.world_to_camera, vb.camera.world_to_camera)
    # sorted by name, every 8th to test: a.png first
    assert [v.name for v in ds_bin.test] == ["a"] and len(ds_bin.train) == 5 and ds_bin.val == []
    assert torch.equal(ds_bin.points, ds_txt.points) and torch.equal(ds_bin.point_colors, ds_txt.point_colors)
    # the pose is COLMAP's: a point in front of camera "a" projects with its intrinsics
    cam = ds_bin.test[0].camera
    _, q, t, _, _, _ = IMAGES[0]
    pc = np.array([0.3, -0.2, 4.0])
    world = quaternion_wxyz_to_matrix(q).T @ (pc - t)
    uv, depth = cam.project(torch.tensor(world[None]))
    np.testing.assert_allclose(uv[0].numpy(), [100 * 0.3 / 4 + 32, 120 * -0.2 / 4 + 24], atol=1e-9)
    assert depth[0].item() == pytest.approx(4.0)


def test_load_colmap_errors_name_the_binary_files(tmp_path):
    root = _dataset(tmp_path, text=False)
    images = [(3, IMAGES[0][1], IMAGES[0][2], 77, "a.png", [])]
    (root / "sparse" / "0" / "images.bin").write_bytes(_encode_images(images))
    with pytest.raises(
        ValueError,
        match=r"images\.bin: image 3 \(a\.png\) uses camera 77, which is not in "
        r"cameras\.bin",
    ):
        load_colmap(root)
    (root / "sparse" / "0" / "images.bin").unlink()
    with pytest.raises(ValueError, match=r"no COLMAP model \(cameras\.bin.*cameras\.txt"):
        load_colmap(root)


def test_quaternion_of_a_quarter_turn():
    c = math.cos(math.pi / 4)
    np.testing.assert_allclose(quaternion_wxyz_to_matrix([c, 0, 0, c]), [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-15)
