"""The procedural Ahmed body: closed and outward-oriented, the 1984 dimensions, volume, slant angle, nose radius."""

import math

import numpy as np
import open3d as o3d
import pytest

from apps import cli
from recon.ahmed import AhmedBody, ahmed_body, ahmed_mesh_arrays, enclosed_volume, write_ahmed

L, W, H, R, SLANT, CLEAR, STILT_R = 1.044, 0.389, 0.288, 0.1, 0.222, 0.05, 0.015


def _analytic_volume(slant_deg: float, stilts: bool) -> float:
    """Nose (two circular fillets intersected) + straight part + slanted rear, + 4 stilt cylinders."""
    phi = math.radians(slant_deg)
    run = SLANT * math.cos(phi)
    # nose: section (H - 2R + 2g)(W - 2R + 2g) with g(s) = sqrt(R^2 - s^2), s in [0, R];
    # int g ds = pi R^2 / 4, int g^2 ds = 2 R^3 / 3
    a, b = H - 2 * R, W - 2 * R
    nose = a * b * R + 2 * (a + b) * math.pi * R * R / 4 + 4 * 2 * R**3 / 3
    straight = H * W * (L - R - run)
    rear = W * (H * run - run * run * math.tan(phi) / 2)
    legs = 4 * math.pi * STILT_R**2 * CLEAR if stilts else 0.0
    return nose + straight + rear + legs


def _signed_volume(v, t):
    return float(np.einsum("ij,ij->i", v[t[:, 0]], np.cross(v[t[:, 1]], v[t[:, 2]])).sum() / 6)


def _fit_circle(p: np.ndarray) -> tuple[np.ndarray, float]:
    """Algebraic least-squares circle through 2-D points: centre and radius."""
    a = np.c_[2 * p, np.ones(len(p))]
    sol = np.linalg.lstsq(a, (p**2).sum(1), rcond=None)[0]
    return sol[:2], float(np.sqrt(sol[2] + sol[:2] @ sol[:2]))


@pytest.mark.parametrize("slant,stilts", [(25.0, True), (0.0, False), (40.0, True), (12.5, True)])
def test_mesh_is_closed_manifold_and_outward(slant, stilts):
    mesh = ahmed_body(slant, 0.02, stilts=stilts)
    assert mesh.is_watertight() and mesh.is_orientable()  # watertight: edge/vertex manifold, no self-intersection
    v, t = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    directed = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    assert len(np.unique(directed, axis=0)) == len(directed)  # every directed edge once: consistent orientation
    reverse = {tuple(e) for e in directed[:, ::-1]}
    assert all(tuple(e) in reverse for e in directed)
    assert _signed_volume(v, t) > 0  # outward normals
    assert _signed_volume(v, t) == pytest.approx(_analytic_volume(slant, stilts), rel=2e-3)


def test_dimensions_and_frame():
    mesh = ahmed_body()
    lo, hi = mesh.get_axis_aligned_bounding_box().get_min_bound(), mesh.get_axis_aligned_bounding_box().get_max_bound()
    assert np.allclose(lo, [-L / 2, 0.0, -W / 2], atol=1e-12) and np.allclose(hi, [L / 2, H + CLEAR, W / 2], atol=1e-12)
    body = ahmed_body(stilts=False).get_axis_aligned_bounding_box()
    assert body.get_min_bound()[1] == pytest.approx(CLEAR, abs=1e-12)
    v = np.asarray(mesh.vertices)
    base = v[np.isclose(v[:, 0], -L / 2)]
    assert base[:, 1].max() == pytest.approx(CLEAR + H - SLANT * math.sin(math.radians(25)), abs=1e-12)
    nose = v[np.isclose(v[:, 0], L / 2)]  # the flat nose face: (H - 2R) x (W - 2R)
    assert np.ptp(nose[:, 1]) == pytest.approx(H - 2 * R, abs=1e-12)
    assert np.ptp(nose[:, 2]) == pytest.approx(W - 2 * R, abs=1e-12)


def test_volume_matches_the_analytic_shape():
    v, t = ahmed_mesh_arrays(AhmedBody())
    assert _signed_volume(v, t) == pytest.approx(_analytic_volume(25.0, True), rel=1e-3)
    assert enclosed_volume(ahmed_body()) == pytest.approx(_analytic_volume(25.0, True), rel=1e-3)
    coarse = ahmed_body(resolution=0.03)  # open3d's own volume (it re-checks watertightness, slow on fine meshes)
    assert coarse.get_volume() == pytest.approx(_analytic_volume(25.0, True), rel=3e-3)


@pytest.mark.parametrize("slant", [25.0, 35.0])
def test_slant_angle_from_face_normals(slant):
    mesh = ahmed_body(slant, stilts=False)
    v, t = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    n = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
    area = np.linalg.norm(n, axis=1)
    unit = n / area[:, None]
    on_slant = (unit[:, 1] > 0.2) & (unit[:, 0] < -0.05)  # upward faces leaning back
    assert 0.5 * area[on_slant].sum() == pytest.approx(SLANT * W, rel=1e-9)  # the whole slant, nothing else
    mean = (unit[on_slant] * area[on_slant, None]).sum(0)
    angle = math.degrees(math.acos(mean[1] / np.linalg.norm(mean)))
    assert angle == pytest.approx(slant, abs=0.5)


def test_front_rounding_radius_from_surface_samples():
    o3d.utility.random.seed(0)
    mesh = ahmed_body(stilts=False, resolution=0.008)
    p = np.asarray(mesh.sample_points_uniformly(60000).points)
    top = p[(p[:, 0] > L / 2 - R + 0.005) & (p[:, 1] > CLEAR + H - R + 0.005) & (np.abs(p[:, 2]) < W / 2 - R - 0.005)]
    centre, radius = _fit_circle(top[:, [0, 1]])  # side view: the top front edge
    assert len(top) > 500
    assert radius == pytest.approx(R, rel=0.01) and np.allclose(centre, [L / 2 - R, CLEAR + H - R], atol=1e-3)
    side = p[
        (p[:, 0] > L / 2 - R + 0.005)
        & (p[:, 2] > W / 2 - R + 0.005)
        & (p[:, 1] > CLEAR + R + 0.005)
        & (p[:, 1] < CLEAR + H - R - 0.005)
    ]
    centre, radius = _fit_circle(side[:, [0, 2]])  # plan view: the right front edge
    assert len(side) > 200
    assert radius == pytest.approx(R, rel=0.01) and np.allclose(centre, [L / 2 - R, W / 2 - R], atol=1e-3)


def test_stilts_stand_where_documented():
    v = np.asarray(ahmed_body().vertices)
    feet = v[v[:, 1] == 0.0]
    for xc in (L / 2 - 0.202, -L / 2 + 0.372):
        for zc in (-0.1635, 0.1635):
            near = feet[np.hypot(feet[:, 0] - xc, feet[:, 2] - zc) < 0.05]
            d = np.hypot(near[:, 0] - xc, near[:, 2] - zc)
            assert len(near) >= 24 and np.all((np.isclose(d, STILT_R)) | (d < 1e-12))
    assert len(feet) == 4 * (np.sum(np.isclose(np.hypot(feet[:, 0] - L / 2 + 0.202, feet[:, 2] - 0.1635), STILT_R)) + 1)


def test_up_axis_scale_and_validation():
    mesh = ahmed_body(up="z", scale=1000.0, resolution=0.02)
    lo = mesh.get_axis_aligned_bounding_box().get_min_bound()
    hi = mesh.get_axis_aligned_bounding_box().get_max_bound()
    assert np.allclose(hi - lo, [L * 1000, W * 1000, (H + CLEAR) * 1000]) and lo[2] == pytest.approx(0.0)
    assert mesh.is_watertight()
    with pytest.raises(ValueError, match="slant_deg"):
        ahmed_body(45.0)
    with pytest.raises(ValueError, match="resolution"):
        ahmed_body(resolution=-1.0)
    with pytest.raises(ValueError, match="up"):
        ahmed_body(up="x")


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".stl"])
def test_write_ahmed_is_atomic_and_readable(tmp_path, suffix):
    path = write_ahmed(tmp_path / "out" / f"ahmed{suffix}", resolution=0.02)
    assert [p.name for p in path.parent.iterdir()] == [path.name]
    back = o3d.io.read_triangle_mesh(str(path))
    if suffix == ".stl":
        back = back.merge_close_vertices(1e-9)
    assert len(back.triangles) == len(ahmed_body(resolution=0.02).triangles)
    assert back.is_watertight()
    with pytest.raises(ValueError, match="ahmed.txt"):
        write_ahmed(tmp_path / "ahmed.txt")


def test_cli_writes_the_body(tmp_path, capsys):
    out = tmp_path / "ahmed.obj"
    assert cli.main(["ahmed", "-o", str(out), "--slant", "35", "--no-stilts", "--resolution", "0.02"]) == 0
    mesh = o3d.io.read_triangle_mesh(str(out))
    assert mesh.get_axis_aligned_bounding_box().get_min_bound()[1] == pytest.approx(CLEAR, abs=1e-6)
    assert "slant 35 deg" in capsys.readouterr().out
    assert cli.main(["ahmed", "-o", str(tmp_path / "ahmed.txt")]) == 2
    assert cli.main(["ahmed", "-o", str(tmp_path / "bad.obj"), "--slant", "50"]) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ahmed.obj"]
