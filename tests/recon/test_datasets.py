"""Tests for recon/camera_paths.py and recon/datasets.py: camera generators (radius, aim, image-up,
hemisphere, uniformity, seeds), the Blender loader on hand-written files (poses, intrinsics keys,
compositing, 16-bit and grey images, down-scaling, error messages) and the COLMAP text loader on a
hand-written model whose 2-D observations were computed by hand."""

import json
import logging
import math

import cv2
import numpy as np
import pytest
import torch

from recon.camera import Camera
from recon.camera_paths import orbit, orbit_around, random_sphere, sphere_directions, up_vector
from recon.colmap import quaternion_wxyz_to_matrix
from recon.datasets import load_blender, load_colmap, load_dataset
from recon.gaussians import quaternion_to_rotation

FOV = math.radians(45.0)


# ---- camera paths ----------------------------------------------------------------------------------


def _centers(cams):
    return torch.stack([c.center for c in cams]).numpy()


@pytest.mark.parametrize("up_axis", ["y", "z"])
@pytest.mark.parametrize("hemisphere", [False, True])
def test_random_sphere_radius_aim_and_image_up(up_axis, hemisphere):
    target = np.array([0.3, -0.2, 0.5])
    cams = random_sphere(40, 6.0, 64, 48, FOV, seed=3, hemisphere=hemisphere, up_axis=up_axis, target=target)
    centers = _centers(cams)
    np.testing.assert_allclose(np.linalg.norm(centers - target, axis=1), 6.0, rtol=1e-9)
    up = up_vector(up_axis)
    if hemisphere:
        assert ((centers - target) @ up >= 0).all()
    for cam in cams:
        uv, depth = cam.project(torch.tensor(np.stack([target, target + 0.5 * up])))
        np.testing.assert_allclose(uv[0].numpy(), [32.0, 24.0], atol=1e-9)  # the target at the image centre
        assert depth[0] == pytest.approx(6.0)
        # a point above the target appears above the centre (smaller v) unless the camera looks along up
        horizontal = np.linalg.norm(np.cross(cam.center.numpy() - target, up))
        if horizontal > 0.5:
            assert uv[1, 1] < 24.0 - 1e-6


def test_random_sphere_is_seeded():
    a = random_sphere(10, 6.0, 32, 32, FOV, seed=7)
    b = random_sphere(10, 6.0, 32, 32, FOV, seed=7)
    c = random_sphere(10, 6.0, 32, 32, FOV, seed=8)
    for x, y in zip(a, b, strict=True):
        assert torch.equal(x.world_to_camera, y.world_to_camera)
    assert not np.allclose(_centers(a), _centers(c))


def test_sphere_directions_are_uniform():
    """Uniform on the sphere: mean 0 and E[d d^T] = I/3; on the upper hemisphere E[d . up] = 1/2."""
    d = sphere_directions(20000, seed=0)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
    assert np.abs(d.mean(axis=0)).max() < 0.02
    np.testing.assert_allclose(d.T @ d / len(d), np.eye(3) / 3, atol=0.01)
    h = sphere_directions(20000, seed=0, hemisphere=True, up_axis="z")
    assert h[:, 2].min() >= 0
    assert h[:, 2].mean() == pytest.approx(0.5, abs=0.01)
    assert np.abs(h[:, :2].mean(axis=0)).max() < 0.02


def test_orbit_positions_and_poles():
    cams = orbit(8, 5.0, 30.0, 40, 40, FOV, up_axis="y")
    centers = _centers(cams)
    np.testing.assert_allclose(np.linalg.norm(centers, axis=1), 5.0)
    np.testing.assert_allclose(centers[:, 1], 5.0 * math.sin(math.radians(30.0)))
    np.testing.assert_allclose(centers[0], [0.0, 2.5, 5.0 * math.cos(math.radians(30.0))], atol=1e-12)
    azimuths = np.arctan2(centers[:, 0], centers[:, 2])
    np.testing.assert_allclose(np.diff(np.unwrap(azimuths)), 2 * math.pi / 8)  # evenly spaced, counter-clockwise
    for elevation in (90.0, -90.0):  # straight above / below: the image-up is undefined but the aim is not
        (cam,) = orbit(1, 5.0, elevation, 40, 40, FOV, up_axis="z")
        uv, _ = cam.project(torch.zeros(1, 3, dtype=torch.float64))
        np.testing.assert_allclose(uv[0].numpy(), [20.0, 20.0], atol=1e-9)
        np.testing.assert_allclose(cam.center.numpy(), [0, 0, 5.0 * math.copysign(1, elevation)], atol=1e-12)


def test_orbit_around_aims_at_the_box_centre_from_its_extent():
    """The cameras sit 1.6 x the largest extent from the bounding box's centre and see it in the image centre."""
    points = np.array([[1.0, 2.0, 3.0], [3.0, 2.5, 4.0], [2.0, 3.0, 3.5]])  # box centre (2, 2.5, 3.5), extent 2
    cams = orbit_around(points, 6, 40)
    assert len(cams) == 6 and (cams[0].width, cams[0].height) == (40, 30)
    centre = np.array([2.0, 2.5, 3.5])
    np.testing.assert_allclose(np.linalg.norm(_centers(cams) - centre, axis=1), 3.2)
    np.testing.assert_allclose(_centers(cams)[:, 1] - 2.5, 3.2 * math.sin(math.radians(20.0)))
    uv, _ = cams[3].project(torch.from_numpy(centre[None]))
    np.testing.assert_allclose(uv[0].numpy(), [20.0, 15.0], atol=1e-9)


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"n": 0}, "n"),
        ({"radius": -1.0}, "radius"),
        ({"fov_x": 4.0}, "fov_x"),
        ({"up_axis": "x"}, "up_axis"),
        ({"width": 0}, "width"),
        ({"target": (0, 0)}, "target"),
    ],
)
def test_camera_path_errors_name_the_argument(kwargs, field):
    args = {"n": 4, "radius": 6.0, "width": 32, "height": 32, "fov_x": FOV, "seed": 0} | kwargs
    with pytest.raises(ValueError, match=field):
        random_sphere(**args)


# ---- Blender loader ----------------------------------------------------------------------------------


def _c2w(eye, target=(0.0, 0.0, 0.0)):
    """An OpenGL camera-to-world looking from eye at target with +z up (built independently of Camera)."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    back = eye - target
    back /= np.linalg.norm(back)
    right = np.cross([0.0, 0.0, 1.0], back)
    right /= np.linalg.norm(right)
    up = np.cross(back, right)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, up, back, eye
    return m


def _write_rgba(path, rgba_float, bits=8):
    scale = 255 if bits == 8 else 65535
    dtype = np.uint8 if bits == 8 else np.uint16
    data = np.round(np.asarray(rgba_float) * scale).astype(dtype)
    code = cv2.COLOR_RGBA2BGRA if data.shape[-1] == 4 else cv2.COLOR_RGB2BGR
    assert cv2.imwrite(str(path), cv2.cvtColor(data, code) if data.ndim == 3 else data)


def _blender_dataset(root, width=8, height=6, splits=("train", "test"), angle=0.7):
    """Two RGBA frames per split: frame 0 written as 'r_0' (no extension), frame 1 as 'r_1.png'."""
    rng = np.random.default_rng(0)
    images = {}
    for split in splits:
        (root / split).mkdir(parents=True)
        frames = []
        for i in range(2):
            rgba = rng.random((height, width, 4))
            rgba[0, 0, 3] = 0.0
            rgba[0, 1, 3] = 1.0
            _write_rgba(root / split / f"r_{i}.png", rgba)
            images[(split, i)] = np.round(rgba * 255) / 255
            frames.append(
                {
                    "file_path": f"./{split}/r_{i}" + (".png" if i else ""),
                    "transform_matrix": _c2w([4.0, 1.0 + i, 2.0]).tolist(),
                }
            )
        (root / f"transforms_{split}.json").write_text(json.dumps({"camera_angle_x": angle, "frames": frames}))
    return images


def test_blender_poses_intrinsics_and_compositing(tmp_path):
    images = _blender_dataset(tmp_path)
    ds = load_blender(tmp_path, background=(0.2, 0.4, 0.6))
    assert (len(ds.train), len(ds.val), len(ds.test)) == (2, 0, 2)
    assert ds.up_axis == "z" and ds.mesh_path is None and ds.points is None
    view = ds.train[1]
    assert view.name == "r_1"
    cam = view.camera
    assert (cam.width, cam.height, cam.cx, cam.cy) == (8, 6, 4.0, 3.0)
    assert cam.fx == pytest.approx(4.0 / math.tan(0.35)) and cam.fy == cam.fx
    np.testing.assert_allclose(cam.center.numpy(), [4.0, 2.0, 2.0], atol=1e-12)
    uv, depth = cam.project(torch.zeros(1, 3, dtype=torch.float64))  # the look-at target is the image centre
    np.testing.assert_allclose(uv[0].numpy(), [4.0, 3.0], atol=1e-9)
    assert depth[0] > 0
    rgba = images[("train", 1)]
    expected = rgba[..., :3] * rgba[..., 3:] + np.array([0.2, 0.4, 0.6]) * (1 - rgba[..., 3:])
    np.testing.assert_allclose(view.image.numpy(), expected, atol=1e-6)
    np.testing.assert_allclose(view.alpha.numpy(), rgba[..., 3], atol=1e-6)
    np.testing.assert_allclose(view.image[0, 0].numpy(), [0.2, 0.4, 0.6], atol=1e-6)  # alpha 0: background
    assert view.image.dtype == torch.float32 and view.image.shape == (6, 8, 3)


def test_blender_nerfstudio_keys(tmp_path):
    _blender_dataset(tmp_path)
    meta = json.loads((tmp_path / "transforms_train.json").read_text())
    del meta["camera_angle_x"]
    meta |= {"fl_x": 10.0, "fl_y": 11.0, "cx": 3.5, "cy": 2.5, "w": 8, "h": 6}
    meta["frames"][1]["fl_x"] = 12.0  # a frame may override the file's intrinsics
    (tmp_path / "transforms_train.json").write_text(json.dumps(meta))
    ds = load_blender(tmp_path)
    a, b = ds.train[0].camera, ds.train[1].camera
    assert (a.fx, a.fy, a.cx, a.cy) == (10.0, 11.0, 3.5, 2.5)
    assert b.fx == 12.0


def test_blender_downscale_halves_intrinsics(tmp_path):
    _blender_dataset(tmp_path, width=8, height=6)
    full = load_blender(tmp_path)
    for half in (load_blender(tmp_path, downscale=2.0), load_dataset(tmp_path, resolution=4)):
        a, b = full.train[0].camera, half.train[0].camera
        assert (b.width, b.height) == (4, 3)
        for key in ("fx", "fy", "cx", "cy"):
            assert getattr(b, key) == pytest.approx(getattr(a, key) / 2)
        assert torch.equal(a.world_to_camera, b.world_to_camera)
        # area averaging of the composited image: each output pixel is the mean of a 2x2 block
        blocks = full.train[0].image.reshape(3, 2, 4, 2, 3).mean(dim=(1, 3))
        torch.testing.assert_close(half.train[0].image, blocks, atol=1e-6, rtol=0)
        torch.testing.assert_close(
            half.train[0].alpha, full.train[0].alpha.reshape(3, 2, 4, 2).mean(dim=(1, 3)), atol=1e-6, rtol=0
        )


def test_blender_16bit_grey_and_shared_val(tmp_path):
    _blender_dataset(tmp_path, splits=("train",))
    grey16 = np.round(np.linspace(0, 1, 48).reshape(6, 8) * 65535).astype(np.uint16)
    assert cv2.imwrite(str(tmp_path / "train" / "r_0.png"), grey16)
    grey = grey16 / 65535.0
    ds = load_blender(tmp_path)
    view = ds.train[0]
    assert view.alpha is None
    np.testing.assert_allclose(view.image.numpy(), np.repeat(grey[..., None], 3, axis=2), atol=1e-6)
    rgba16 = np.random.default_rng(1).random((6, 8, 4))
    _write_rgba(tmp_path / "train" / "r_1.png", rgba16, bits=16)
    view = load_blender(tmp_path, background=(0.0, 0.0, 0.0)).train[1]
    np.testing.assert_allclose(view.image.numpy(), rgba16[..., :3] * rgba16[..., 3:], atol=1e-4)
    # a val split naming the same files as train shares the pixel tensors instead of loading them twice
    (tmp_path / "transforms_val.json").write_text((tmp_path / "transforms_train.json").read_text())
    ds = load_blender(tmp_path)
    assert ds.val[1].image is ds.train[1].image


def _edit(path, fn):
    meta = json.loads(path.read_text())
    fn(meta)
    path.write_text(json.dumps(meta))


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda m: m.pop("camera_angle_x"), r"transforms_train\.json.*camera_angle_x"),
        (lambda m: m["frames"][0].update(file_path="./train/missing"), r"transforms_train\.json.*missing"),
        (
            lambda m: m["frames"][1].update(transform_matrix=[[1, 0, 0], [0, 1, 0]]),
            r"transforms_train\.json: frame 1 \(file_path './train/r_1.png'\): 'transform_matrix'",
        ),
        (lambda m: m["frames"][1].pop("transform_matrix"), r"transforms_train\.json.*transform_matrix"),
        (lambda m: m.update(w=16, h=12), r"r_0\.png.*8x6"),
    ],
)
def test_blender_errors_name_file_and_key(tmp_path, edit, message):
    _blender_dataset(tmp_path)
    _edit(tmp_path / "transforms_train.json", edit)
    with pytest.raises(ValueError, match=message):
        load_blender(tmp_path)


def _png_header_only(path, width: int, height: int) -> None:
    """A PNG of a few dozen bytes whose header declares ``width`` x ``height`` RGB pixels (its data is one row)."""
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    body = chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(b"\0" * 4)) + chunk(b"IEND", b"")
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + body)


def test_an_image_that_declares_too_many_pixels_is_refused_before_decoding(tmp_path):
    """A 2.7 MB PNG of 30000 x 30000 pixels took 23 GiB and 71 s to load (OpenCV decodes it whole, then float RGB)."""
    from recon.datasets import MAX_IMAGE_PIXELS, read_image

    _blender_dataset(tmp_path)
    _png_header_only(tmp_path / "train" / "r_1.png", 10_000, 10_000)
    assert 10_000 * 10_000 > MAX_IMAGE_PIXELS
    with pytest.raises(ValueError, match=r"r_1\.png: the image declares 10,000 x 10,000 pixels, more than"):
        load_blender(tmp_path)
    _png_header_only(tmp_path / "small.png", 4, 1)  # within the limit the header check lets the decoder judge it
    with pytest.raises(ValueError, match="cannot read the image"):
        read_image(tmp_path / "small.png")


def test_a_fifo_or_device_as_the_dataset_or_its_mesh_is_named_as_such(tmp_path):
    """A FIFO or /dev/zero given as the dataset folder, or as dataset.json's mesh, was said not to exist."""
    import os

    from recon.datasets import dataset_format

    os.mkfifo(tmp_path / "pipe")
    with pytest.raises(ValueError, match=r"pipe is a FIFO \(named pipe\).*; pass a dataset folder"):
        dataset_format(tmp_path / "pipe")
    with pytest.raises(ValueError, match=r"/dev/zero is a character device"):
        dataset_format("/dev/zero")
    _blender_dataset(tmp_path / "ds")
    os.mkfifo(tmp_path / "ds" / "mesh.ply")
    (tmp_path / "ds" / "dataset.json").write_text(json.dumps({"mesh_path": "mesh.ply"}))
    with pytest.raises(ValueError, match=r"'mesh_path' names .*mesh\.ply, which is a FIFO"):
        load_dataset(tmp_path / "ds")


def test_blender_requires_train_and_rejects_bad_options(tmp_path):
    _blender_dataset(tmp_path)
    with pytest.raises(ValueError, match="background"):
        load_blender(tmp_path, background=(2.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="downscale"):
        load_blender(tmp_path, downscale=0.5)
    (tmp_path / "transforms_train.json").unlink()
    with pytest.raises(ValueError, match="transforms_train.json"):
        load_blender(tmp_path)


def test_load_dataset_reads_dataset_json_and_rejects_unknown_folders(tmp_path):
    _blender_dataset(tmp_path / "b")
    (tmp_path / "b" / "mesh.ply").write_text("ply\n")
    (tmp_path / "b" / "dataset.json").write_text(json.dumps({"mesh_path": "mesh.ply", "up_axis": "y"}))
    ds = load_dataset(tmp_path / "b" / "transforms_train.json")
    assert ds.mesh_path == tmp_path / "b" / "mesh.ply" and ds.up_axis == "y" and ds.root == tmp_path / "b"
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match=r"transforms_train\.json.*cameras\.txt"):
        load_dataset(tmp_path / "empty")


# ---- COLMAP text loader ----------------------------------------------------------------------------


S = math.sqrt(0.5)
CAMERAS_TXT = """# Camera list with one line of data per camera:
#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]
1 PINHOLE 64 48 100 120 32 24
2 SIMPLE_RADIAL 60 40 90 30 20 0.05
"""
# The point (1, 0.5, 0), by hand:
#  image 1: R = I, t = (0, 0, 5): camera (1, 0.5, 5) -> u = 100/5 + 32 = 52, v = 120 * 0.5 / 5 + 24 = 36.
#  image 2: q = (cos 45, 0, sin 45, 0), a +90 degree turn about y: R (1, 0.5, 0) = (0, 0.5, -1); t = (0, 0, 4):
#           camera (0, 0.5, 3) -> u = 30, v = 90 * 0.5 / 3 + 20 = 35 (the distortion is ignored).
IMAGES_TXT = f"""# Image list with two lines of data per image:
#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME
#   POINTS2D[] as (X, Y, POINT3D_ID)
3 1 0 0 0 0 0 5 1 a.png
52 36 7 10.5 11.5 -1
5 {S} 0 {S} 0 0 0 4 2 b.png
30 35 7
4 1 0 0 0 0.5 0 6 1 c.png

"""
POINTS_TXT = """# 3D point list
7 1 0.5 0 255 0 51 0.1 3 0 5 0
8 -1 2 3 0 255 0 0.2 4 1
"""


def _colmap_dataset(root, layout="sparse/0"):
    sparse = root / layout
    sparse.mkdir(parents=True, exist_ok=True)
    (sparse / "cameras.txt").write_text(CAMERAS_TXT)
    (sparse / "images.txt").write_text(IMAGES_TXT)
    (sparse / "points3D.txt").write_text(POINTS_TXT)
    (root / "images").mkdir()
    for name, (w, h) in (("a.png", (64, 48)), ("b.png", (60, 40)), ("c.png", (64, 48))):
        _write_rgba(root / "images" / name, np.full((h, w, 3), 0.5))


def test_colmap_projection_matches_observations(tmp_path, caplog):
    _colmap_dataset(tmp_path)
    with caplog.at_level(logging.WARNING, logger="recon.datasets"):
        ds = load_dataset(tmp_path)
    assert "camera 2" in caplog.text and "distortion" in caplog.text
    # sorted by name: a (index 0) -> test; b, c -> train
    assert [v.name for v in ds.test] == ["a"] and [v.name for v in ds.train] == ["b", "c"] and ds.val == []
    point = torch.tensor([[1.0, 0.5, 0.0]], dtype=torch.float64)
    for view, observed in ((ds.test[0], [52.0, 36.0]), (ds.train[0], [30.0, 35.0])):
        uv, depth = view.camera.project(point)
        np.testing.assert_allclose(uv[0].numpy(), observed, atol=1e-9)
        assert depth[0] > 0
    b = ds.train[0].camera
    assert (b.width, b.height, b.fx, b.fy, b.cx, b.cy) == (60, 40, 90.0, 90.0, 30.0, 20.0)
    assert ds.train[0].image.shape == (40, 60, 3) and ds.train[0].alpha is None
    np.testing.assert_allclose(ds.points.numpy(), [[1, 0.5, 0], [-1, 2, 3]])
    np.testing.assert_allclose(ds.point_colors.numpy(), [[1, 0, 0.2], [0, 1, 0]], atol=1e-6)
    np.testing.assert_allclose(ds.train[1].camera.center.numpy(), [-0.5, 0, -6])


def test_colmap_layouts_and_errors(tmp_path):
    _colmap_dataset(tmp_path / "flat", layout=".")
    assert len(load_colmap(tmp_path / "flat").train) == 2
    _colmap_dataset(tmp_path / "bad")
    cams = tmp_path / "bad" / "sparse" / "0" / "cameras.txt"
    cams.write_text(CAMERAS_TXT.replace("SIMPLE_RADIAL 60 40 90 30 20 0.05", "FISHEYE 60 40 90 30 20 0.05"))
    with pytest.raises(ValueError, match=r"cameras\.txt:4.*FISHEYE"):
        load_dataset(tmp_path / "bad")
    cams.write_text(CAMERAS_TXT)
    (tmp_path / "bad" / "images" / "b.png").unlink()
    with pytest.raises(ValueError, match=r"b\.png"):
        load_dataset(tmp_path / "bad")


def test_quaternion_matches_gaussians_twin():
    q = torch.randn(20, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    ours = np.stack([quaternion_wxyz_to_matrix(x) for x in q.numpy()])
    np.testing.assert_allclose(ours, quaternion_to_rotation(q).numpy(), atol=1e-12)


def test_loaded_camera_equals_camera_from_opengl(tmp_path):
    _blender_dataset(tmp_path, angle=0.9)
    cam = load_blender(tmp_path).test[0].camera
    ref = Camera.from_opengl_c2w(_c2w([4.0, 1.0, 2.0]), 8, 6, 0.9)
    torch.testing.assert_close(cam.world_to_camera, ref.world_to_camera)
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == pytest.approx((ref.fx, ref.fy, ref.cx, ref.cy))
