"""The orbit cameras of `--cameras orbit:N` (recon.camera_paths.orbit_rings, nbv.orbit): every camera sees the whole
object, centred and upright, for any up direction; the rings, the framing distance and the bad inputs."""

import math

import numpy as np
import pytest
import torch

from nbv.orbit import Orbit, object_sphere, orbit_cameras, orbit_count
from nbv.physics import PhysicsConfig
from recon.camera_paths import framing_distance, orbit_rings, ring_counts
from recon.gaussians import GaussianSet
from recon.render import render


def _figure(up, centre=(0.3, -0.2, 0.5), height=1.0, seed=0):
    """An upright column (grey body, red head at the top along ``up``, blue feet at the bottom) with a far floater
    that the robust box must ignore; scene coordinates."""
    rng = np.random.default_rng(seed)
    up = np.asarray(up, float) / np.linalg.norm(up)
    a = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(up, a)
    t = rng.uniform(-0.5, 0.5, 600) * height
    ang = rng.uniform(0, 2 * math.pi, 600)
    pts = np.asarray(centre) + t[:, None] * up + 0.15 * height * (np.cos(ang)[:, None] * a + np.sin(ang)[:, None] * b)
    colors = np.full((600, 3), 0.5)
    colors[t > 0.35 * height] = (1.0, 0.0, 0.0)
    colors[t < -0.35 * height] = (0.0, 0.0, 1.0)
    pts = np.vstack([pts, np.asarray(centre) + 40.0 * a])  # one far floater
    colors = np.vstack([colors, [0.5, 0.5, 0.5]])
    return GaussianSet.from_points(
        torch.tensor(pts, dtype=torch.float32),
        torch.tensor(colors, dtype=torch.float32),
        scale=0.02 * height,
        opacity=0.9,
    )


def _centroid(weight):
    rows, cols = torch.meshgrid(torch.arange(weight.shape[0]) + 0.5, torch.arange(weight.shape[1]) + 0.5, indexing="ij")
    total = weight.sum()
    return float((weight * rows).sum() / total), float((weight * cols).sum() / total)


@pytest.mark.parametrize("up", ["+y", "-y", "+z", (0.3, -1.0, 0.2)])
def test_every_orbit_camera_sees_the_object_centred_and_upright(up):
    from nbv.physics.scene_frame import parse_up

    u = parse_up(up)
    g = _figure(u)
    orbit = Orbit(8, elevations_deg=(-20.0, 15.0, 60.0), fov_x_deg=50.0, width=64)
    cams = orbit_cameras(g, PhysicsConfig(up=up), orbit)
    assert len(cams) == 8 and (cams[0].width, cams[0].height) == (64, 48)
    body = g.subset(torch.arange(600))  # the render leaves the floater out: it may lie in a view's background
    for cam in cams:
        out = render(body, cam, background=0.0, backend="torch")
        alpha, img = out.alpha, out.image
        assert alpha.sum() > 20, cam.name
        row, col = _centroid(alpha)
        assert abs(row - 24) < 0.12 * 48 and abs(col - 32) < 0.12 * 64, (cam.name, row, col)  # centred
        border = torch.cat([alpha[0], alpha[-1], alpha[:, 0], alpha[:, -1]])
        assert float(border.max()) < 0.05, cam.name  # the whole object is inside the frame
        red, blue = img[..., 0] * (img[..., 2] < 0.2), img[..., 2] * (img[..., 0] < 0.2)
        assert _centroid(red)[0] < row < _centroid(blue)[0], cam.name  # head above the body, feet below: upright


def test_rings_distance_and_order():
    centre, radius, fov = np.array([1.0, 2.0, 3.0]), 0.5, math.radians(50.0)
    cams = orbit_rings(7, centre, radius, (0, 0, 2.0), (1.0, 0, 0), (0.0, 30.0), 40, 30, fov)
    assert ring_counts(7, 2) == [4, 3] and [c.name for c in cams] == [f"orbit_{i:03d}" for i in range(7)]
    fov_y = 2 * math.atan(0.75 * math.tan(fov / 2))
    d = framing_distance(radius, fov, 40, 30)
    assert d == pytest.approx(radius / math.sin(fov_y / 2))  # the narrower field of view frames the sphere
    offsets = np.stack([c.center.numpy() for c in cams]) - centre
    np.testing.assert_allclose(np.linalg.norm(offsets, axis=1), d, rtol=1e-12)
    elev = np.degrees(np.arcsin(offsets[:, 2] / d))
    np.testing.assert_allclose(elev, [0, 0, 0, 0, 30, 30, 30], atol=1e-9)
    np.testing.assert_allclose(offsets[0] / d, [1, 0, 0], atol=1e-12)  # azimuth 0 on `front`
    np.testing.assert_allclose(offsets[1] / d, [0, 1, 0], atol=1e-12)  # then counter-clockwise seen from above
    az = np.degrees(np.arctan2(offsets[4:, 1], offsets[4:, 0])) % 360
    np.testing.assert_allclose(az, [60, 180, 300], atol=1e-9)  # the second ring is offset by half a step
    for c in cams:  # the optical axis passes through the centre
        uv, z = c.project(torch.tensor(centre)[None])
        np.testing.assert_allclose(uv[0].numpy(), [20, 15], atol=1e-9)
        assert z[0] == pytest.approx(d)


def test_the_orbit_frames_the_robust_box_not_the_floater():
    g = _figure((0, 1.0, 0))
    centre, radius = object_sphere(g, PhysicsConfig())
    assert np.linalg.norm(centre - [0.3, -0.2, 0.5]) < 0.05 and radius < 0.8  # the floater 40 units away is ignored


def test_bad_orbits_name_the_option_and_the_fix():
    assert orbit_count("orbit:24") == 24 and orbit_count("cams.json") is None and orbit_count("ORBIT:3") == 3
    with pytest.raises(ValueError, match=r"orbit:0.*at least 1 camera.*orbit:24"):
        Orbit(orbit_count("orbit:0"))
    with pytest.raises(ValueError, match=r"orbit:10000000: at most 10000 cameras"):  # minutes of silence before
        Orbit(orbit_count("orbit:10000000"))
    with pytest.raises(ValueError, match=r"orbit:10\^30.*whole number"):
        orbit_count("orbit:10^30")
    with pytest.raises(ValueError, match=r"--cameras orbit:x: orbit:N takes a whole number"):
        orbit_count("orbit:x")
    with pytest.raises(ValueError, match=r"--elevations .*\(-90, 90\)"):
        Orbit(4, elevations_deg=(90.0,))
    g = _figure((0, 1.0, 0))
    with pytest.raises(ValueError, match=r"--crop .* keeps none"):
        orbit_cameras(g, PhysicsConfig(crop=(10.0, 10.0, 10.0, 11.0, 11.0, 11.0)), Orbit(4))
    one = g.subset(torch.tensor([0]))
    with pytest.raises(ValueError, match=r"--cameras orbit:4: the Gaussians have no extent.*camera file"):
        orbit_cameras(one, PhysicsConfig(), Orbit(4))


def test_orbit_cameras_written_in_every_format_give_the_same_scores(tmp_path):
    """The orbit of a capture written as transforms.json, graphdeco cameras.json and a COLMAP text model: the same
    cameras back, hence the same S(T) (Eq. 4-5) of the same D_g."""
    import json

    from nbv.scores import projected_view_scores
    from recon.camera_files import colmap_text, graphdeco_json, load_camera_file, transforms_json

    g = _figure((0.0, -1.0, 0.0))
    cams = orbit_cameras(g, PhysicsConfig(up="-y"), Orbit(6, width=48))
    (tmp_path / "transforms.json").write_text(json.dumps(transforms_json(cams)))
    (tmp_path / "cameras.json").write_text(json.dumps(graphdeco_json(cams)))
    model = tmp_path / "capture" / "sparse" / "0"
    model.mkdir(parents=True)
    for name, text in zip(("cameras.txt", "images.txt"), colmap_text(cams), strict=True):
        (model / name).write_text(text)
    d = torch.rand(g.num, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    reference = projected_view_scores(d, g, cams).scores
    assert reference.min() > 0
    for path in (tmp_path / "transforms.json", tmp_path / "cameras.json", tmp_path / "capture"):
        scores = projected_view_scores(d, g, load_camera_file(path)).scores
        torch.testing.assert_close(scores, reference, rtol=1e-9, atol=0, msg=str(path))
