"""Tests for recon/mesh_render.py and `fluidgs render-dataset`: the ray caster against a brute-force
Moller-Trumbore twin, rays against Camera.project, the shading formula, and the issue's round trip:
render a dataset, load it back, project surface points of mesh.ply with the loaded cameras and check that
they land inside the alpha masks; plus the layout, normalisation, seeds, up axes and input errors."""

import json
import math
import shutil

import cv2
import numpy as np
import open3d as o3d
import pytest
import torch

from apps import cli
from recon.camera_paths import random_sphere, up_vector
from recon.datasets import load_dataset
from recon.mesh_render import (
    FILL_WEIGHT,
    KEY_WEIGHT,
    MeshDatasetConfig,
    MeshRaycaster,
    camera_rays,
    cast_rays_reference,
    light_directions,
    load_mesh,
    render_mesh_dataset,
    shade,
    triangle_normals,
)

from helpers.paths import TORUS

SMALL = MeshDatasetConfig(n_train=6, n_test=3, resolution=56, seed=1)


@pytest.fixture(scope="module")
def torus_dataset(tmp_path_factory):
    return render_mesh_dataset(TORUS, tmp_path_factory.mktemp("render") / "torus", SMALL, progress=False)


def _sample_surface(vertices, triangles, n, seed):
    """Area-weighted uniform samples on a triangle mesh (numpy; independent of the renderer)."""
    rng = np.random.default_rng(seed)
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    areas = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    tri = rng.choice(len(triangles), size=n, p=areas / areas.sum())
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    return (1 - s)[:, None] * a[tri] + (s * (1 - r2))[:, None] * b[tri] + (s * r2)[:, None] * c[tri]


def _read_mesh(path):
    mesh = o3d.io.read_triangle_mesh(str(path))
    return np.asarray(mesh.vertices), np.asarray(mesh.triangles)


# ---- rays, caster and shading ------------------------------------------------------------------------


def test_raycaster_matches_bruteforce_twin():
    mesh = o3d.geometry.TriangleMesh.create_torus(
        torus_radius=1.0, tube_radius=0.4, radial_resolution=10, tubular_resolution=6
    )
    vertices, triangles = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    caster = MeshRaycaster(vertices, triangles)
    for cam in random_sphere(3, 3.5, 20, 16, math.radians(60.0), seed=5):
        origins, dirs = camera_rays(cam, supersample=1)
        t, ids = caster.cast(origins, dirs)
        t_ref, ids_ref = cast_rays_reference(vertices, triangles, origins, dirs)
        hit, hit_ref = ids >= 0, ids_ref >= 0
        assert 0.1 < hit_ref.mean() < 0.9  # the object is in view and does not fill it
        assert (hit != hit_ref).sum() <= 2  # rays grazing an edge may differ in float32
        both = hit & hit_ref
        np.testing.assert_allclose(t[both], t_ref[both], rtol=1e-5)
        assert (ids[both] == ids_ref[both]).mean() > 0.98


def test_rays_follow_the_camera_convention():
    """A hit point o + t d projects back onto its pixel centre (i + 0.5, j + 0.5) at depth t."""
    vertices, triangles = load_mesh(TORUS)
    caster = MeshRaycaster(vertices * 2.0, triangles)
    (cam,) = random_sphere(1, 4.0, 24, 18, math.radians(50.0), seed=2)
    origins, dirs = camera_rays(cam, supersample=1)
    t, ids = caster.cast(origins, dirs)
    jj, ii = np.nonzero(ids >= 0)
    assert len(ii) > 20
    points = origins[jj, ii] + t[jj, ii, None] * dirs[jj, ii]
    uv, depth = cam.project(torch.from_numpy(points))
    np.testing.assert_allclose(uv.numpy(), np.stack([ii + 0.5, jj + 0.5], axis=1), atol=1e-6)
    np.testing.assert_allclose(depth.numpy(), t[jj, ii], rtol=1e-6)
    o2, d2 = camera_rays(cam, supersample=2)  # sub-pixel centres at i + 0.25 and i + 0.75
    assert d2.shape == (36, 48, 3)
    uv2, _ = cam.project(torch.from_numpy(o2[1, 3] + d2[1, 3])[None])
    np.testing.assert_allclose(uv2[0].numpy(), [1.75, 0.75], atol=1e-9)


def test_shading_formula():
    albedo = np.array([0.5, 0.6, 0.7])
    key, fill = light_directions("z")
    away = np.cross(key, fill)
    away /= np.linalg.norm(away)
    normals = np.stack([key, -key, away])
    view = -key  # looking at a surface facing the key light
    out = shade(normals, np.repeat(view[None], 3, axis=0), albedo, 0.25, "z")
    expected_key = albedo * (0.25 + 0.75 * (KEY_WEIGHT + FILL_WEIGHT * max(0.0, key @ fill)))
    np.testing.assert_allclose(out[0], expected_key)
    np.testing.assert_allclose(out[1], out[0])  # two-sided: the normal is flipped to face the camera
    np.testing.assert_allclose(out[2], albedo * 0.25)  # lit by neither light: ambient only
    assert key @ up_vector("z") > 0.5  # the key light comes from above


def test_triangle_normals_unit_and_degenerate():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0.0]])
    n = triangle_normals(v, np.array([[0, 1, 2], [0, 1, 3]]))
    np.testing.assert_allclose(n, [[0, 0, 1], [0, 0, 0]])


# ---- the rendered dataset ----------------------------------------------------------------------------


def test_dataset_layout_and_json(torus_dataset):
    root = torus_dataset
    for split, n in (("train", 6), ("test", 3)):
        assert sorted(p.name for p in (root / split).iterdir()) == [f"r_{i:03d}.png" for i in range(n)]
        meta = json.loads((root / f"transforms_{split}.json").read_text())
        assert meta["camera_angle_x"] == pytest.approx(math.radians(SMALL.fov_x))
        assert [f["file_path"] for f in meta["frames"]] == [f"./{split}/r_{i:03d}" for i in range(n)]
        assert np.asarray(meta["frames"][0]["transform_matrix"]).shape == (4, 4)
    val = json.loads((root / "transforms_val.json").read_text())
    assert val == json.loads((root / "transforms_test.json").read_text())
    info = json.loads((root / "dataset.json").read_text())
    assert info["mesh_path"] == "mesh.ply" and info["up_axis"] == "y" and info["seed"] == 1
    assert info["config"]["n_train"] == 6 and info["source_mesh"].endswith("torus.obj")
    image = cv2.imread(str(root / "train" / "r_000.png"), cv2.IMREAD_UNCHANGED)
    assert image.shape == (56, 56, 4) and image.dtype == np.uint8
    assert not list(root.parent.glob(".fgs-*"))  # the temporary folder was renamed away


def test_normalised_mesh_and_recorded_transform(torus_dataset):
    vertices, triangles = _read_mesh(torus_dataset / "mesh.ply")
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    assert (hi - lo).max() == pytest.approx(4.0, abs=1e-6)
    np.testing.assert_allclose((lo + hi) / 2, 0.0, atol=1e-6)
    info = json.loads((torus_dataset / "dataset.json").read_text())
    source, source_triangles = load_mesh(TORUS)
    np.testing.assert_allclose(info["scale"] * source + np.asarray(info["offset"]), vertices, atol=1e-6)
    np.testing.assert_array_equal(source_triangles, triangles)


def test_surface_points_land_inside_the_alpha_masks(torus_dataset):
    """The issue's test: any surface point (visible or not) projects inside the object's silhouette."""
    ds = load_dataset(torus_dataset)
    assert ds.mesh_path == torus_dataset / "mesh.ply" and ds.up_axis == "y"
    vertices, triangles = _read_mesh(ds.mesh_path)
    points = torch.from_numpy(_sample_surface(vertices, triangles, 4000, seed=0))
    kernel = np.ones((3, 3), np.uint8)
    for view in ds.train + ds.test:
        alpha = view.alpha.numpy()
        assert alpha.shape == (56, 56)
        assert (alpha == 0).mean() > 0.4  # the mask is not trivially full
        assert alpha[0].max() == alpha[-1].max() == alpha[:, 0].max() == alpha[:, -1].max() == 0  # no border contact
        mask = cv2.dilate((alpha > 0).astype(np.uint8), kernel).astype(bool)
        uv, depth = view.camera.project(points)
        assert (depth > 0).all()
        cols, rows = np.floor(uv.numpy()).astype(int).T
        inside = (cols >= 0) & (cols < 56) & (rows >= 0) & (rows < 56)
        assert inside.all()
        assert mask[rows, cols].mean() >= 0.99
        # and not the other way round: the points cover most of the silhouette
        covered = np.zeros_like(mask)
        covered[rows, cols] = True
        assert covered[alpha > 0.99].mean() > 0.9


def test_round_trip_cameras_and_images(torus_dataset):
    ds = load_dataset(torus_dataset, background=(0.0, 0.0, 0.0))
    assert (len(ds.train), len(ds.val), len(ds.test)) == (6, 3, 3)
    expected = random_sphere(9, SMALL.radius, 56, 56, math.radians(SMALL.fov_x), seed=1)
    for view, cam in zip(ds.train + ds.test, expected, strict=True):
        torch.testing.assert_close(view.camera.world_to_camera, cam.world_to_camera, atol=1e-9, rtol=0)
        assert view.camera.fx == pytest.approx(cam.fx)
    view = ds.train[0]
    solid = view.alpha == 1
    grey = view.image[solid]
    assert solid.sum() > 100
    assert torch.allclose(grey[:, 0], grey[:, 1]) and torch.allclose(grey[:, 1], grey[:, 2])  # #909090 is grey
    assert grey.max() <= 0x90 / 255 + 1e-6 and grey.min() >= 0.25 * 0x90 / 255 - 1 / 255
    assert grey.std() > 0.02  # shaded, not flat
    assert float(view.image[view.alpha == 0].abs().max()) == 0.0  # transparent background composited on black
    assert ((view.alpha > 0) & (view.alpha < 1)).any()  # 2x2 supersampling gives fractional edges


def test_seeded_and_deterministic(torus_dataset, tmp_path):
    again = render_mesh_dataset(TORUS, tmp_path / "again", SMALL, progress=False)
    for name in ("transforms_train.json", "transforms_test.json", "train/r_002.png", "test/r_001.png"):
        assert (again / name).read_bytes() == (torus_dataset / name).read_bytes()
    other = render_mesh_dataset(
        TORUS, tmp_path / "other", MeshDatasetConfig(n_train=6, n_test=3, resolution=56, seed=2), progress=False
    )
    assert (other / "transforms_train.json").read_bytes() != (torus_dataset / "transforms_train.json").read_bytes()


def test_z_up_hemisphere_and_binary_alpha(tmp_path):
    config = MeshDatasetConfig(n_train=5, n_test=1, resolution=32, up_axis="z", hemisphere=True, supersample=1)
    ds = load_dataset(render_mesh_dataset(TORUS, tmp_path / "z", config, progress=False))
    assert ds.up_axis == "z"
    for view in ds.train + ds.test:
        assert view.camera.center[2] >= 0
        assert set(np.unique(view.alpha.numpy())) <= {0.0, 1.0}
        uv, _ = view.camera.project(torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64))
        assert uv[1, 1] < uv[0, 1]  # +z appears up in the image


# ---- errors and the command ----------------------------------------------------------------------


@pytest.mark.parametrize(
    "field, value",
    [
        ("n_train", 0),
        ("resolution", 4),
        ("fov_x", 200.0),
        ("box_size", -1.0),
        ("radius", 1.0),
        ("color", "grey"),
        ("color", "#12345g"),
        ("ambient", 1.5),
        ("up_axis", "x"),
        ("supersample", 0),
    ],
)
def test_config_errors_name_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        MeshDatasetConfig(**{field: value})


def test_input_errors(tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        render_mesh_dataset(tmp_path / "missing.obj", tmp_path / "out", SMALL)
    (tmp_path / "points.xyz").write_text("0 0 0\n")
    with pytest.raises(ValueError, match=r"points\.xyz.*\.obj"):
        render_mesh_dataset(tmp_path / "points.xyz", tmp_path / "out", SMALL)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.random.default_rng(0).random((10, 3))))
    o3d.io.write_point_cloud(str(tmp_path / "cloud.ply"), cloud)
    with pytest.raises(ValueError, match=r"cloud\.ply.*no triangles"):
        render_mesh_dataset(tmp_path / "cloud.ply", tmp_path / "out", SMALL)
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "dataset.json").write_text("{}")
    with pytest.raises(ValueError, match="overwrite"):
        render_mesh_dataset(TORUS, tmp_path / "full", SMALL)
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "keep.txt").write_text("x")
    with pytest.raises(ValueError, match=r"not a dataset of render-dataset \(keep\.txt\)"):
        render_mesh_dataset(TORUS, tmp_path / "other", SMALL, overwrite=True)
    with pytest.raises(ValueError, match="parent"):
        render_mesh_dataset(TORUS, tmp_path / "no" / "such" / "dir", SMALL)
    assert not (tmp_path / "out").exists() and (tmp_path / "other" / "keep.txt").is_file()
    tiny = MeshDatasetConfig(n_train=1, n_test=0, resolution=16)
    render_mesh_dataset(TORUS, tmp_path / "full", tiny, overwrite=True, progress=False)
    assert (tmp_path / "full" / "train" / "r_000.png").is_file()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".full.")]


def test_cli_smoke(tmp_path, capsys):
    mesh = tmp_path / "torus.obj"
    shutil.copy(TORUS, mesh)
    out = tmp_path / "ds"
    args = [
        "render-dataset",
        str(mesh),
        "-o",
        str(out),
        "--train",
        "3",
        "--test",
        "2",
        "--res",
        "24",
        "--up",
        "z",
        "--hemisphere",
        "--color",
        "#ff8000",
        "--seed",
        "4",
        "--no-progress",
    ]
    assert cli.main(args) == 0
    assert "wrote" in capsys.readouterr().out
    info = json.loads((out / "dataset.json").read_text())
    assert info["config"]["color"] == "#ff8000"
    assert (info["up_axis"], info["seed"], info["config"]["hemisphere"]) == ("z", 4, True)
    ds = load_dataset(out)
    assert (len(ds.train), len(ds.test)) == (3, 2) and ds.train[0].camera.width == 24
    assert cli.main(args) == 2  # the folder is not empty now
    assert cli.main(args + ["--overwrite"]) == 0
    assert cli.main(["render-dataset", str(tmp_path / "nope.stl"), "-o", str(tmp_path / "x")]) == 2
