"""GaussianSet and Camera: shapes, validation, covariance algebra, camera conventions."""

import math

import pytest
import torch

from recon.camera import Camera
from recon.gaussians import (
    GaussianSet,
    concat,
    quaternion_to_rotation,
    rgb_to_sh0,
    sh0_to_rgb,
    sh_coefficient_count,
    sh_degree_of,
)


def random_set(n=6, degree=1, seed=0, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    return GaussianSet(
        torch.randn(n, 3, generator=g, dtype=dtype),
        torch.randn(n, 4, generator=g, dtype=dtype),
        0.3 * torch.randn(n, 3, generator=g, dtype=dtype),
        torch.randn(n, generator=g, dtype=dtype),
        torch.randn(n, sh_coefficient_count(degree), 3, generator=g, dtype=dtype),
    )


def test_rotation_matrices_are_orthonormal_and_match_axis_angle():
    q = torch.randn(50, 4, dtype=torch.float64)
    r = quaternion_to_rotation(q)
    eye = torch.eye(3, dtype=torch.float64).expand(50, 3, 3)
    assert torch.allclose(r @ r.transpose(1, 2), eye, atol=1e-12)
    assert torch.allclose(torch.linalg.det(r), torch.ones(50, dtype=torch.float64), atol=1e-12)
    # 90 degrees about z: (w, x, y, z) = (cos 45, 0, 0, sin 45) maps x -> y
    rz = quaternion_to_rotation(torch.tensor([[math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4)]]))[0]
    assert torch.allclose(rz @ torch.tensor([1.0, 0, 0]), torch.tensor([0.0, 1, 0]), atol=1e-6)


def test_covariance_eigenvalues_are_squared_scales():
    g = random_set(8)
    ev = torch.linalg.eigvalsh(g.covariances())
    assert torch.allclose(ev, torch.sort(g.scales**2, dim=-1).values, rtol=1e-9, atol=1e-12)
    assert torch.allclose(g.max_radii(), g.scales.max(-1).values)


def test_shape_errors_name_the_field():
    g = random_set(4)
    with pytest.raises(ValueError, match="quats"):
        GaussianSet(g.means, g.quats[:, :3], g.log_scales, g.opacity_logits, g.sh)
    with pytest.raises(ValueError, match="sh"):
        GaussianSet(g.means, g.quats, g.log_scales, g.opacity_logits, torch.zeros(4, 5, 3, dtype=g.dtype))


def test_check_names_source_and_problem():
    g = random_set(4)
    g.means[2, 1] = float("nan")
    with pytest.raises(ValueError, match=r"scene\.ply.*NaN or Inf in means.*\[2\]"):
        g.check("scene.ply")
    g = random_set(4)
    g.quats[1] = 0
    with pytest.raises(ValueError, match="zero rotation quaternion"):
        g.check("x")
    with pytest.raises(ValueError, match="empty"):
        random_set(0).check("empty.ply")


def test_sh_helpers_and_degree_padding():
    assert [sh_coefficient_count(d) for d in range(4)] == [1, 4, 9, 16]
    assert sh_degree_of(9) == 2
    with pytest.raises(ValueError):
        sh_degree_of(5)
    rgb = torch.rand(10, 3)
    assert torch.allclose(sh0_to_rgb(rgb_to_sh0(rgb)), rgb, atol=1e-6)
    g = random_set(3, degree=1)
    g3 = g.with_sh_degree(3)
    assert g3.sh.shape == (3, 16, 3) and torch.equal(g3.sh[:, :4], g.sh) and not g3.sh[:, 4:].any()
    assert torch.equal(g3.with_sh_degree(1).sh, g.sh)


def test_from_points_subset_concat():
    pts = torch.randn(5, 3)
    g = GaussianSet.from_points(pts, scale=0.2, opacity=0.5)
    assert torch.allclose(g.scales, torch.full((5, 3), 0.2))
    assert torch.allclose(g.opacities, torch.full((5,), 0.5))
    assert torch.allclose(sh0_to_rgb(g.sh[:, 0]), torch.full((5, 3), 0.5))
    both = concat([g, g.subset(torch.tensor([0, 2]))])
    assert both.num == 7 and torch.equal(both.means[5:], pts[[0, 2]])


def test_look_at_projects_target_to_centre_and_orbits():
    cam = Camera.look_at([3.0, 2.0, 1.0], [0, 0, 0], [0, 1, 0], 80, 60, math.radians(60))
    uv, z = cam.project(torch.zeros(1, 3, dtype=torch.float64))
    assert torch.allclose(uv, torch.tensor([[40.0, 30.0]], dtype=torch.float64))
    assert z.item() == pytest.approx(math.sqrt(14))
    assert torch.allclose(cam.center, torch.tensor([3.0, 2.0, 1.0], dtype=torch.float64))
    # a point above the target appears above the image centre (smaller v)
    uv_up, _ = cam.project(torch.tensor([[0.0, 0.5, 0.0]], dtype=torch.float64))
    assert uv_up[0, 1] < 30.0


def test_opengl_round_trip_and_hand_projection():
    # Blender camera at (0, 0, 4) looking down -z (identity rotation in OpenGL axes).
    c2w = torch.eye(4, dtype=torch.float64)
    c2w[2, 3] = 4.0
    cam = Camera.from_opengl_c2w(c2w, 100, 50, 2 * math.atan(0.5))  # fx = 100
    assert cam.fx == pytest.approx(100.0) and cam.cx == 50.0 and cam.cy == 25.0
    uv, z = cam.project(torch.tensor([[1.0, 1.0, 0.0]], dtype=torch.float64))
    # x right -> +u; world +y is up in the image -> smaller v; depth 4
    assert torch.allclose(uv, torch.tensor([[75.0, 0.0]], dtype=torch.float64)) and z.item() == pytest.approx(4.0)
    assert torch.allclose(cam.opengl_c2w(), c2w)


def test_scaled_camera_keeps_projection_relative():
    cam = Camera.look_at([0, 0, -5], [0, 0, 0], [0, 1, 0], 128, 64, math.radians(40))
    half = cam.scaled(0.5)
    p = torch.tensor([[0.3, -0.2, 0.1]], dtype=torch.float64)
    assert (half.width, half.height) == (64, 32)
    assert torch.allclose(half.project(p)[0], cam.project(p)[0] * 0.5)


def test_bad_cameras_raise():
    with pytest.raises(ValueError, match="width"):
        Camera(0, 10, 1, 1, 0, 0, torch.eye(4))
    with pytest.raises(ValueError, match="orthonormal"):
        Camera(10, 10, 1, 1, 5, 5, 2 * torch.eye(4))
    with pytest.raises(ValueError, match="fx"):
        Camera(10, 10, -1, 1, 5, 5, torch.eye(4))
