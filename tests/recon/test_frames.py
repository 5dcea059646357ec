"""Tests for recon/frames.py: the up direction from cameras (``--up auto``). Orbits around y and z give +y
and +z exactly (their horizontal parts cancel); a y-down rig gives -y; the up vector is nerfstudio's
(column 1 of the OpenGL camera-to-world) and a point moved along it shows higher in the image; cameras
rolled every way raise a ValueError naming --up."""

import math

import numpy as np
import pytest
import torch

from recon.camera import Camera
from recon.camera_paths import orbit, random_sphere, up_vector
from recon.frames import camera_up_vectors, up_from_cameras

FOV = math.radians(50.0)


@pytest.mark.parametrize("up_axis", ["y", "z"])
@pytest.mark.parametrize("elevation", [-40.0, 0.0, 25.0, 70.0])
def test_orbits_give_their_up_axis(up_axis, elevation):
    cams = orbit(12, 5.0, elevation, 32, 24, FOV, up_axis=up_axis, target=(0.5, -1.0, 2.0))
    np.testing.assert_allclose(up_from_cameras(cams), up_vector(up_axis), atol=1e-12)
    # each camera's up is the world up made perpendicular to its view: its up component is cos(elevation)
    np.testing.assert_allclose(
        camera_up_vectors(cams) @ up_vector(up_axis), math.cos(math.radians(elevation)), atol=1e-12
    )


def test_y_down_cameras_give_minus_y():
    """Cameras upright in a y-down world (the biker capture's convention) give -y."""
    eyes = [(4 * math.cos(a), -1.5, 4 * math.sin(a)) for a in np.linspace(0, 2 * math.pi, 9)[:-1]]
    cams = [Camera.look_at(e, (0, 0, 0), (0, -1, 0), 32, 24, FOV) for e in eyes]
    np.testing.assert_allclose(up_from_cameras(cams), [0, -1, 0], atol=1e-12)


def test_random_hemisphere_is_close_to_up():
    cams = random_sphere(200, 6.0, 16, 16, FOV, seed=2, hemisphere=True, up_axis="z")
    up = up_from_cameras(cams)
    assert math.degrees(math.acos(up[2])) < 5.0


def test_up_vector_is_nerfstudios_and_points_up_in_the_image():
    cams = random_sphere(20, 3.0, 40, 30, FOV, seed=5, up_axis="y")
    ups = camera_up_vectors(cams)
    gl = np.stack([c.opengl_c2w()[:3, 1].numpy() for c in cams])  # nerfstudio averages poses[:, :3, 1]
    np.testing.assert_allclose(ups, gl, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(ups, axis=1), 1.0, atol=1e-12)
    for cam, up in zip(cams, ups, strict=True):
        forward = cam.world_to_camera[2, :3]
        ahead = cam.center + 2.0 * forward
        uv, _ = cam.project(torch.stack([ahead, ahead + 0.1 * torch.from_numpy(up)]))
        assert uv[1, 1] < uv[0, 1] - 1.0  # higher in the image (v grows downwards)
        assert abs(float(uv[1, 0] - uv[0, 0])) < 1e-9  # straight up: no sideways shift


def test_inconsistent_up_raises_naming_the_option():
    cams = orbit(6, 4.0, 10.0, 16, 16, FOV)
    flip = torch.diag(torch.tensor([-1.0, -1.0, 1.0, 1.0], dtype=torch.float64))  # a half roll about the view axis
    rolled = [Camera(c.width, c.height, c.fx, c.fy, c.cx, c.cy, flip @ c.world_to_camera) for c in cams]
    np.testing.assert_allclose(up_from_cameras(rolled), [0, -1, 0], atol=1e-12)
    with pytest.raises(ValueError, match=r"no consistent up direction.*--up"):
        up_from_cameras(cams + rolled)
    with pytest.raises(ValueError, match="no cameras"):
        up_from_cameras([])
    with pytest.raises(ValueError, match="min_agreement"):
        up_from_cameras(cams, min_agreement=0.0)
    # a looser threshold accepts a weak agreement: 5 upright + 3 rolled average to length 2/8
    mixed = orbit(8, 4.0, 0.0, 16, 16, FOV)
    mixed = mixed[:5] + [Camera(c.width, c.height, c.fx, c.fy, c.cx, c.cy, flip @ c.world_to_camera) for c in mixed[5:]]
    with pytest.raises(ValueError, match="length 0.2"):
        up_from_cameras(mixed, min_agreement=0.3)
    assert up_from_cameras(mixed, min_agreement=0.2)[1] > 0.9
