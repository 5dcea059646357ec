"""Tests for viz/frames.py (the renderer) and apps/render_frames.py (its command line): projection on hand-computed
cases, the z-buffer splat against a slow painter's twin, PNG and H.264 MP4 output on a synthetic OUT.h5, and input
errors raised before any output."""

import argparse
import json
import logging
from dataclasses import replace

import cv2
import h5py
import numpy as np
import pytest

from apps import render_frames as cli
from viz import frame_source
from viz import frames as rf
from viz.frames import FrameStyle, project, render_frames, scene_viewport
from viz.video import read_mp4, video_info

DOMAIN_MIN = np.array([0.0, 0.0, 0.0])
DOMAIN_MAX = np.array([2.0, 1.0, 1.0])
HOT_DIVERGENCE = 100.0  # 1/s, far above every other particle
W, H = 320, 240


COLD_POSITION = np.array([0.2, 0.9, 0.3])  # one particle with zero divergence, apart from the block


def _hot_position(i: int) -> np.ndarray:
    """Where frame i puts its one hot particle: apart from the block, moving along x."""
    return np.array([1.3 + 0.2 * i, 0.8, 0.9])


def _write_h5(path, keys=("000000", "000010", "000020"), n=300, scene=True, boundary=None):
    """A block of particles with divergence in [0, 1) 1/s in the lower left, one particle with zero
    divergence at COLD_POSITION and one with HOT_DIVERGENCE at _hot_position(i), where i is the numeric
    rank of the key (the file stores keys in the order given)."""
    rng = np.random.default_rng(1)
    order = {k: i for i, k in enumerate(sorted(keys, key=int))}
    with h5py.File(path, "w") as f:
        if scene:
            domain = {"min": DOMAIN_MIN.tolist(), "max": DOMAIN_MAX.tolist(), "walls": True}
            f.attrs["scene"] = json.dumps({"domain": domain, "name": "test"})
        if boundary is not None:
            f["boundary/x"] = boundary
        for k in keys:
            i = order[k]
            x = rng.random((n, 3)) * [0.6, 0.4, 0.6] + 0.05
            x[0], x[1] = _hot_position(i), COLD_POSITION
            divergence = rng.random(n).astype(np.float32)
            divergence[0], divergence[1] = HOT_DIVERGENCE, 0.0
            g = f.create_group(f"frames/{k}")
            g["x"] = x.astype(np.float32)
            g["v"] = rng.normal(size=(n, 3)).astype(np.float32)
            g["divergence"] = divergence
            g.attrs["time"] = 0.01 * i
            g.attrs["step"] = int(k)
        f["stats"] = np.zeros(4)
    return path


def _pixel(point, view="front"):
    """Expected frame pixel (column, row) of a world point, from the public projection and viewport."""
    x0, y0, w, h = scene_viewport(W, H)
    uv, _ = project(np.asarray(point)[None], DOMAIN_MIN, DOMAIN_MAX, view, w, h)
    return int(uv[0, 0] + x0), int(uv[0, 1] + y0)


def _is_warm(bgr) -> bool:
    b, g, r = (int(c) for c in bgr)
    return r > 100 and r > 2 * b


# ----------------------------------------------------------------------------------------------- project


def test_front_projection_maps_domain_corners_to_margin_corners():
    # 4 m x 3 m front face into a canvas whose inner area is 400 x 300 px: 100 px/m on both axes
    lo, hi, width, height, m = [0, 0, 0], [4, 3, 1], 421, 321, 10
    pts = np.array([[0, 0, 0], [4, 3, 0], [0, 3, 1], [4, 0, 1], [2, 1.5, 0.5], [1, 1, 0.25]], float)
    uv, depth = project(pts, lo, hi, "front", width, height, margin=m)
    assert uv.dtype == np.int64 and uv.shape == (6, 2)
    assert uv.tolist() == [[10, 310], [410, 10], [10, 10], [410, 310], [210, 160], [110, 210]]
    np.testing.assert_allclose(depth, -pts[:, 2])  # front looks along -z: larger z is nearer


def test_projection_keeps_aspect_ratio_and_centres_the_free_axis():
    # 1 m cube into 421 x 321: height limits the scale to 300 px/m, width is centred
    uv, _ = project(np.array([[0, 0, 0], [1, 1, 1]], float), [0] * 3, [1] * 3, "front", 421, 321, margin=10)
    assert uv.tolist() == [[60, 310], [360, 10]]


def test_default_margin_is_small_and_positive():
    uv, _ = project(np.array([[0, 0, 0], [2, 1, 0]], float), DOMAIN_MIN, DOMAIN_MAX, "front", 961, 721)
    m = rf.default_margin(961, 721)
    assert 2 <= m <= 0.05 * 721
    assert uv[0, 0] == m and uv[1, 0] == 960 - m  # x limits: 2:1 box in a 4:3 canvas


@pytest.mark.parametrize(
    "view, point, expected",
    [
        ("side", [0, 0, 4], [410, 110]),  # side looks along +x: +z is right, y up
        ("side", [2, 1, 0], [10, 10]),
        ("side", [3, 0.5, 1], [110, 60]),
        ("top", [0, 0, 0], [10, 10]),  # top looks along -y: x right, -z up, so z = min is at the top
        ("top", [4, 0.5, 4], [410, 410]),
        ("top", [1, 0, 3], [110, 310]),
    ],
)
def test_side_and_top_projection_hand_cases(view, point, expected):
    # domain 4 x 1 x 4 m: the side view sees a 4 x 1 m rectangle in 421 x 121 px, the top view 4 x 4 m in
    # 421 x 421 px; with a 10 px margin both are 100 px/m
    lo, hi = [0, 0, 0], [4, 1, 4]
    uv, _ = project(np.array([point], float), lo, hi, view, 421, 421 if view == "top" else 121, margin=10)
    assert uv[0].tolist() == expected


def test_depth_orders_points_along_each_view():
    near_far = {
        "front": ([0.5, 0.5, 0.9], [0.5, 0.5, 0.1]),
        "side": ([0.1, 0.5, 0.5], [0.9, 0.5, 0.5]),
        "top": ([0.5, 0.9, 0.5], [0.5, 0.1, 0.5]),
        "iso": ([0.9, 0.9, 0.9], [0.1, 0.1, 0.1]),
    }
    for view, (near, far) in near_far.items():
        _, depth = project(np.array([near, far]), [0] * 3, [1] * 3, view, 200, 200)
        assert depth[0] < depth[1], view


def test_view_bases_are_orthonormal_and_not_mirrored():
    for view in rf.VIEWS:
        right, up, forward = rf.view_basis(view)
        np.testing.assert_allclose(
            np.stack([right, up, forward]) @ np.stack([right, up, forward]).T, np.eye(3), atol=1e-12
        )
        np.testing.assert_allclose(np.cross(right, up), -forward, atol=1e-12)  # right x up points at camera


def test_iso_projection_fits_the_box_and_puts_the_top_corner_on_the_margin():
    corners = frame_source.box_corners(DOMAIN_MIN, DOMAIN_MAX)
    uv, _ = project(corners, DOMAIN_MIN, DOMAIN_MAX, "iso", 400, 300, margin=10)
    assert uv[:, 0].min() >= 10 and uv[:, 0].max() <= 389 and uv[:, 1].min() >= 10 and uv[:, 1].max() <= 289
    assert uv[:, 1].min() == 10 or uv[:, 0].min() == 10  # one axis touches the margin
    top = np.argmin(uv[:, 1])
    # up = (-1, 2, -1)/sqrt(6): the highest corner has x = min, y = max, z = min
    np.testing.assert_array_equal(corners[top], [DOMAIN_MIN[0], DOMAIN_MAX[1], DOMAIN_MIN[2]])


def test_project_rejects_bad_inputs():
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        project(np.zeros((4, 2)), DOMAIN_MIN, DOMAIN_MAX, "front", W, H)
    with pytest.raises(ValueError, match="NaN"):
        project(np.full((1, 3), np.nan), DOMAIN_MIN, DOMAIN_MAX, "front", W, H)
    with pytest.raises(ValueError, match="view"):
        project(np.zeros((1, 3)), DOMAIN_MIN, DOMAIN_MAX, "back", W, H)
    with pytest.raises(ValueError, match="min < max"):
        project(np.zeros((1, 3)), [0, 0, 0], [1, 0, 1], "front", W, H)


# ----------------------------------------------------------------------------------------------- splat


def splat_reference(image, uv, depth, colors, radius):
    """Slow twin of rf.splat: paint each disk far to near (stable for equal depth), one pixel at a time."""
    h, w = image.shape[:2]
    for i in np.argsort(-depth, kind="stable"):
        for dx, dy in rf.disk_offsets(radius):
            x, y = uv[i, 0] + dx, uv[i, 1] + dy
            if 0 <= x < w and 0 <= y < h:
                image[y, x] = colors[i]
    return image


@pytest.mark.parametrize("radius", [0, 1, 2, 4])
def test_splat_matches_painters_reference(radius):
    rng = np.random.default_rng(radius)
    n, h, w = 400, 37, 53
    uv = rng.integers(-6, 60, size=(n, 2))
    uv[:50] = uv[50:100]  # shared centres: the nearest must win
    depth = rng.integers(0, 30, size=n).astype(float)  # many ties: input order breaks them
    colors = rng.integers(0, 256, size=(n, 3), dtype=np.uint8)
    fast = rf.splat(np.zeros((h, w, 3), np.uint8), uv, depth, colors, radius)
    slow = splat_reference(np.zeros((h, w, 3), np.uint8), uv, depth, colors, radius)
    np.testing.assert_array_equal(fast, slow)


def test_disk_offsets_shape():
    assert len(rf.disk_offsets(0)) == 1
    assert len(rf.disk_offsets(1)) == 9
    assert len(rf.disk_offsets(2)) == 21


def test_colorize_scale_ends():
    lut = rf._COLORMAP_LUT
    colors = rf.colorize(np.array([0.0, 5.0, 10.0, 50.0, np.nan]), vmax=10.0)
    np.testing.assert_array_equal(colors, lut[[0, 128, 255, 255, 255]])


# ----------------------------------------------------------------------------------------------- render


def test_png_frames_show_the_hot_particle_in_warm_colours(tmp_path):
    h5 = _write_h5(tmp_path / "OUT.h5")
    out = tmp_path / "frames"
    paths = render_frames(h5, out, FrameStyle(width=W, height=H, point_size=2), progress=False)
    assert [p.name for p in paths] == ["frame_000000.png", "frame_000001.png", "frame_000002.png"]
    assert sorted(p.name for p in out.iterdir()) == [p.name for p in paths]  # no temporary files left
    for i, p in enumerate(paths):
        image = cv2.imread(str(p))
        assert image.shape == (H, W, 3)
        u, v = _pixel(_hot_position(i))
        assert _is_warm(image[v, u]), (i, image[v, u])
        u, v = _pixel(COLD_POSITION)
        np.testing.assert_array_equal(image[v, u], rf._COLORMAP_LUT[0])  # bottom of the scale


def test_a_render_stopped_midway_keeps_the_earlier_frames(tmp_path, monkeypatch):
    """PNG frames went into -o one by one: a render into the folder of an earlier one, stopped midway (Ctrl-C,
    SIGTERM), left some frames new and the rest old. They are drawn aside and moved in together at the end."""
    h5 = _write_h5(tmp_path / "OUT.h5")
    out = tmp_path / "frames"
    render_frames(h5, out, FrameStyle(width=W, height=H), progress=False)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    drawn = rf._Renderer.frames

    def stopped(self):
        for i, image in enumerate(drawn(self)):
            if i == 2:
                raise KeyboardInterrupt
            yield image

    monkeypatch.setattr(rf._Renderer, "frames", stopped)
    with pytest.raises(KeyboardInterrupt):
        render_frames(h5, out, FrameStyle(view="iso", width=W, height=H), progress=False)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # no temporary folder left either


@pytest.mark.parametrize(
    "option, value", [("--width", "100000"), ("--height", "1000000"), ("--point-size", "1000000"), ("--fps", "1000")]
)
def test_drawing_numbers_are_bounded_when_parsed(tmp_path, capsys, option, value):
    """simulate --video --height 10^6 drew 3 GB frames (20 GB of memory, exit 4 after a minute), --width 10^5 wrote
    an empty .mp4 with exit 0, --point-size 10^6 was a 116 TiB MemoryError traceback and --fps 1000 a video of 0
    frames per second; each is refused when parsed (exit 2), naming its range, as FrameStyle refuses it."""
    from apps import cli as fluidgs

    with pytest.raises(SystemExit) as info:
        fluidgs.main(["render-frames", str(tmp_path / "OUT.h5"), "-o", str(tmp_path / "f.mp4"), option, value])
    assert info.value.code == 2 and f"argument {option}: must be an integer from" in capsys.readouterr().err
    with pytest.raises(ValueError, match="must be an int from"):
        FrameStyle(**{option[2:].replace("-", "_"): int(value)})
    assert not (tmp_path / "f.mp4").exists()


def test_default_vmax_is_the_99th_percentile_over_all_frames(tmp_path):
    h5 = _write_h5(tmp_path / "OUT.h5")
    with h5py.File(h5) as f:
        pooled = np.concatenate([f[f"frames/{k}/divergence"][()] for k in f["frames"]])
        source = frame_source.FrameSource.inspect(f, h5, FrameStyle())
        assert source.percentile_vmax() == pytest.approx(np.percentile(pooled, 99.0), rel=1e-6)


def test_frames_are_sorted_numerically(tmp_path):
    # stored in lexicographic order "300" < "40" < "5"; numeric order is 5, 40, 300
    h5 = _write_h5(tmp_path / "OUT.h5", keys=("300", "40", "5"))
    paths = render_frames(h5, tmp_path / "frames", FrameStyle(width=W, height=H), progress=False)
    for i, p in enumerate(paths):
        u, v = _pixel(_hot_position(i))
        assert _is_warm(cv2.imread(str(p))[v, u]), i


@pytest.mark.parametrize("view", ["side", "top", "iso"])
def test_other_views_put_the_hot_particle_at_its_projection(tmp_path, view):
    h5 = _write_h5(tmp_path / "OUT.h5", keys=("000000",))
    paths = render_frames(h5, tmp_path / view, FrameStyle(view=view, width=W, height=H), progress=False)
    u, v = _pixel(_hot_position(0), view)
    assert _is_warm(cv2.imread(str(paths[0]))[v, u])


def test_color_by_speed_and_fixed_vmax(tmp_path):
    h5 = _write_h5(tmp_path / "OUT.h5", keys=("000000",))
    with h5py.File(h5, "a") as f:
        v = f["frames/000000/v"]
        speeds = np.zeros(v.shape, np.float32)
        speeds[0] = [3.0, 0.0, 4.0]  # |v| = 5 m/s at the hot particle, 0 elsewhere
        v[...] = speeds
    style = FrameStyle(color_by="speed", vmax=5.0, width=W, height=H)
    image = cv2.imread(str(render_frames(h5, tmp_path / "f", style, progress=False)[0]))
    u, v = _pixel(_hot_position(0))
    np.testing.assert_array_equal(image[v, u], rf._COLORMAP_LUT[255])


def test_solid_is_ivory_walls_hidden_by_default_and_all_can_be_hidden(tmp_path):
    solid = np.array([[1.6, 0.3, 0.2]])  # inside the domain: solid, alone on the right, below the hot particles
    wall = np.array([[1.5, 0.5, DOMAIN_MAX[2] + 0.05]])  # outside the box, in front of it: a wall particle
    h5 = _write_h5(tmp_path / "OUT.h5", keys=("000000",), boundary=np.concatenate([solid, wall]))
    (u, v), (wu, wv) = _pixel(solid[0]), _pixel(wall[0])
    style = FrameStyle(width=W, height=H, frame="domain")
    shown = cv2.imread(str(render_frames(h5, tmp_path / "a", style, False)[0]))
    np.testing.assert_array_equal(shown[v, u], rf.SOLID_BGR.astype(np.uint8))  # the nearest (only) solid point
    assert tuple(shown[wv, wu]) == rf._BACKGROUND  # walls hidden by default
    for walls, grey in (("faint", rf._FAINT_GREY_NEAR), ("shown", rf._BOUNDARY_GREY_NEAR)):
        image = cv2.imread(str(render_frames(h5, tmp_path / walls, replace(style, walls=walls), False)[0]))
        b, g, r = (int(c) for c in image[wv, wu])
        assert b == g == r and abs(b - grey) <= 20, (walls, b)
    hidden = cv2.imread(str(render_frames(h5, tmp_path / "b", replace(style, show_boundary=False), False)[0]))
    assert tuple(hidden[v, u]) == rf._BACKGROUND


def test_boundary_is_split_by_the_domain_and_subsampled(tmp_path, monkeypatch):
    monkeypatch.setattr(frame_source, "MAX_BOUNDARY_POINTS", 100)
    monkeypatch.setattr(frame_source, "MAX_SOLID_POINTS", 50)
    with h5py.File(tmp_path / "b.h5", "w") as f:
        f["x"] = np.random.default_rng(0).random((1000, 3)) * 2 - 0.5  # [-0.5, 1.5)^3
        domain = (np.zeros(3), np.ones(3))
        solid, walls = frame_source._read_boundary(f["x"], tmp_path / "b.h5", domain)
        assert solid.shape == (50, 3) and walls.shape == (100, 3)
        assert ((solid >= 0) & (solid <= 1)).all() and (((walls < 0) | (walls > 1)).any(axis=1)).all()
        assert len(np.unique(walls, axis=0)) == 100 and np.isin(walls[:, 0], f["x"][:, 0]).all()
        everything, none = frame_source._read_boundary(f["x"], tmp_path / "b.h5", None)  # no domain: all of it is solid
        assert len(everything) == 50 and len(none) == 0


def _sphere_scene(path):
    """A probe-like OUT.h5: a solid ball of lattice points in the middle of a large box, walls around it, fluid
    around and in front of the ball (a slab in front along +z, the camera's side in the front view)."""
    s = 0.05
    g = np.mgrid[-6:7, -6:7, -6:7].reshape(3, -1).T
    ball = g[(g**2).sum(1) <= 36] * s + 1.5
    walls = np.array([[x, y, z] for x in (-0.1, 3.1) for y in np.linspace(0, 3, 30) for z in np.linspace(0, 3, 30)])
    rng = np.random.default_rng(2)
    fluid = rng.random((4000, 3)) * [3, 3, 0.3] + [0, 0, 2.2]  # a slab between the ball and the camera, partly
    fluid = fluid[(fluid[:, 0] < 1.3) | (fluid[:, 1] < 1.3)]  # a corner cut out, so the ball shows there
    behind = rng.random((3000, 3)) * [3, 3, 0.3] + [0, 0, 0.2]  # a slab behind the ball: hidden by it
    x = np.concatenate([fluid, behind]).astype(np.float32)
    with h5py.File(path, "w") as f:
        f.attrs["scene"] = json.dumps({"domain": {"min": [0, 0, 0], "max": [3, 3, 3], "walls": True}})
        f["boundary/x"] = np.concatenate([ball, walls]).astype(np.float32)
        grp = f.create_group("frames/000000")
        grp["x"], grp["v"] = x, np.zeros_like(x)
        grp["divergence"] = rng.random(len(x)).astype(np.float32)
        grp.attrs["time"], grp.attrs["step"] = 0.0, 0
    return path, ball


def test_a_frame_shows_the_solid_distinct_from_the_fluid_and_framed(tmp_path):
    path, ball = _sphere_scene(tmp_path / "OUT.h5")
    image = cv2.imread(str(render_frames(path, tmp_path / "f", FrameStyle(width=W, height=H), False)[0]))
    x0, y0, vw, vh = scene_viewport(W, H)
    scene = image[y0 : y0 + vh, x0 : x0 + vw].reshape(-1, 3).astype(np.int64)
    # a pixel is the solid's when its colour is a shade of ivory: proportional to SOLID_BGR within rounding
    scale = scene @ rf.SOLID_BGR / (rf.SOLID_BGR @ rf.SOLID_BGR)
    ivory = (np.abs(scene - scale[:, None] * rf.SOLID_BGR).max(axis=1) <= 2) & (scale >= rf._SOLID_FAR - 0.02)
    # visible: the ball's unhidden quarter covers many pixels
    assert ivory.sum() > 300
    # distinct: every shade of the solid is far from every colour the fluid can take (the TURBO map)
    shades = rf.solid_colors(np.linspace(0, 1, 50)).astype(np.int64)
    gap = np.linalg.norm(shades[:, None, :] - rf._COLORMAP_LUT[None].astype(np.int64), axis=2).min()
    assert gap > 60
    # no fluid pixel is ivory: the fluid pixels are the other non-background ones, all TURBO colours
    fluid = ~ivory & (np.abs(scene - np.array(rf._BACKGROUND)).max(axis=1) > 0)
    assert fluid.sum() > 300
    lut_gap = np.linalg.norm(scene[fluid][:, None, :] - rf._COLORMAP_LUT[None].astype(np.int64), axis=2).min(axis=1)
    assert np.median(lut_gap) < 5
    # framed: the ball (1.2 m of a 3 m box) spans more than half the viewport's height; the walls are hidden
    rows = np.nonzero(ivory.reshape(vh, vw).any(axis=1))[0]
    assert rows.max() - rows.min() > 0.25 * vh  # its visible quarter alone
    lo, hi = rf.camera_box(ball, [0, 0, 0], [3, 3, 3])
    np.testing.assert_allclose(hi - lo, 0.6 * (1 + 2 * rf.OBJECT_MARGIN))
    # the slab behind the ball is hidden where the ball is: the centre of the cut-out corner is ivory
    u, v = _pixel_in(ball.mean(axis=0) + [-0.15, -0.15, 0.3], lo, hi)
    np.testing.assert_array_less(
        np.abs(image[v, u].astype(int) - rf.SOLID_BGR * (image[v, u] @ rf.SOLID_BGR) / (rf.SOLID_BGR @ rf.SOLID_BGR)), 3
    )


def _pixel_in(point, lo, hi, view="front"):
    x0, y0, w, h = scene_viewport(W, H)
    uv, _ = project(np.asarray(point)[None], lo, hi, view, w, h)
    return int(uv[0, 0] + x0), int(uv[0, 1] + y0)


def test_missing_scene_falls_back_to_particle_bounds(tmp_path, caplog):
    h5 = _write_h5(tmp_path / "OUT.h5", keys=("000000",), scene=False)
    with caplog.at_level(logging.WARNING, logger="viz.frames"):
        paths = render_frames(h5, tmp_path / "f", FrameStyle(width=W, height=H), progress=False)
    assert len(paths) == 1 and "scene" in caplog.text


def test_mp4_has_one_frame_per_h5_frame(tmp_path):
    h5 = _write_h5(tmp_path / "OUT.h5", keys=("000000", "000010", "000020", "000030"))
    out = tmp_path / "video" / "out.mp4"
    assert render_frames(h5, out, FrameStyle(width=W, height=H, fps=10), progress=False) == [out]
    assert [p.name for p in out.parent.iterdir()] == ["out.mp4"]  # the temporary file was renamed
    info = video_info(out)
    assert (info.codec, info.pixel_format, info.width, info.height, info.frames) == ("h264", "yuv420p", W, H, 4)
    assert info.fps == pytest.approx(10.0)
    # the video shows what the PNG frames show: same hot pixel, and close overall
    pngs = render_frames(h5, tmp_path / "png", FrameStyle(width=W, height=H), progress=False)
    decoded = read_mp4(out)[..., ::-1]  # RGB -> BGR
    for i, png in enumerate(pngs):
        image = cv2.imread(str(png)).astype(np.float64)
        assert np.abs(decoded[i] - image).mean() < 4.0, i
        u, v = _pixel(_hot_position(i))
        assert _is_warm(decoded[i][v, u]), (i, decoded[i][v, u])


def test_odd_mp4_size_is_padded_by_one_edge_pixel(tmp_path):
    h5 = _write_h5(tmp_path / "OUT.h5", keys=("000000",))
    out = tmp_path / "odd.mp4"
    render_frames(h5, out, FrameStyle(width=W + 1, height=H + 1), progress=False)
    info = video_info(out)
    assert (info.codec, info.width, info.height, info.frames) == ("h264", W + 2, H + 2, 1)
    frame = read_mp4(out)[0].astype(np.int64)
    # the padding repeats the last column and row (lossy: compared as the mean absolute difference)
    assert np.abs(frame[:, -1] - frame[:, -2]).mean() < 3.0
    assert np.abs(frame[-1] - frame[-2]).mean() < 3.0


# ----------------------------------------------------------------------------------------------- errors


def _broken_inputs(tmp_path):
    not_h5 = tmp_path / "notes.h5"
    not_h5.write_text("not hdf5")
    no_frames = tmp_path / "no_frames.h5"
    with h5py.File(no_frames, "w") as f:
        f["stats"] = np.zeros(3)
    empty = tmp_path / "empty.h5"
    with h5py.File(empty, "w") as f:
        f.create_group("frames")
    bad_shape = _write_h5(tmp_path / "bad_shape.h5", keys=("000000",))
    with h5py.File(bad_shape, "a") as f:
        del f["frames/000000/divergence"]
        f["frames/000000/divergence"] = np.zeros(7)
    return [
        (tmp_path / "missing.h5", FileNotFoundError, "does not exist"),
        (not_h5, ValueError, "not an HDF5 file"),
        (no_frames, ValueError, "no /frames group"),
        (empty, ValueError, "empty"),
        (bad_shape, ValueError, r"\(7,\)"),
    ]


def test_bad_inputs_raise_naming_the_file_before_writing(tmp_path):
    for path, error, what in _broken_inputs(tmp_path):
        out = tmp_path / f"out_{path.stem}"
        with pytest.raises(error, match=what) as info:
            render_frames(path, out, FrameStyle(width=W, height=H), progress=False)
        assert str(path) in str(info.value)
        assert not out.exists()  # nothing was created


def test_missing_color_dataset_names_the_frame(tmp_path):
    h5 = _write_h5(tmp_path / "OUT.h5", keys=("000000",))
    with h5py.File(h5, "a") as f:
        del f["frames/000000/v"]
    with pytest.raises(ValueError, match="000000.*'v'.*color-by"):
        render_frames(h5, tmp_path / "f", FrameStyle(color_by="speed", width=W, height=H), progress=False)


def test_bad_style_values_raise():
    with pytest.raises(ValueError, match="color_by"):
        FrameStyle(color_by="pressure")
    with pytest.raises(ValueError, match="view"):
        FrameStyle(view="back")
    with pytest.raises(ValueError, match="width"):
        FrameStyle(width=10)
    with pytest.raises(ValueError, match="vmax"):
        FrameStyle(vmax=0.0)


def test_unwritable_outputs_raise_before_rendering(tmp_path):
    h5 = _write_h5(tmp_path / "OUT.h5", keys=("000000",))
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    with pytest.raises(OSError, match="a_file"):
        render_frames(h5, blocker / "frames", FrameStyle(width=W, height=H), progress=False)
    with pytest.raises(OSError, match="a_file"):
        render_frames(h5, blocker / "out.mp4", FrameStyle(width=W, height=H), progress=False)


def test_video_encoder_failure_is_an_oserror_and_leaves_no_file(tmp_path, monkeypatch):
    import imageio_ffmpeg._io

    monkeypatch.setattr(imageio_ffmpeg._io, "get_ffmpeg_exe", lambda: "/bin/false")  # FFmpeg dies at once
    h5 = _write_h5(tmp_path / "OUT.h5", keys=("000000", "000010"))
    with pytest.raises(OSError, match="out.mp4"):
        render_frames(h5, tmp_path / "out.mp4", FrameStyle(width=W, height=H), progress=False)
    assert list(tmp_path.glob("*.mp4")) == []  # pathlib's glob sees the hidden temporary names too


def test_missing_ffmpeg_fails_before_the_first_frame(tmp_path, monkeypatch):
    import imageio_ffmpeg

    def no_ffmpeg():
        raise RuntimeError("No ffmpeg exe could be found")

    monkeypatch.setattr(imageio_ffmpeg, "get_ffmpeg_exe", no_ffmpeg)
    monkeypatch.setattr(rf._Renderer, "draw", lambda *a: pytest.fail("drew a frame without an encoder"))
    h5 = _write_h5(tmp_path / "OUT.h5", keys=("000000",))
    with pytest.raises(OSError, match="out.mp4.*imageio-ffmpeg"):
        render_frames(h5, tmp_path / "out.mp4", FrameStyle(width=W, height=H), progress=False)
    assert not (tmp_path / "out.mp4").exists()


# ----------------------------------------------------------------------------------------------- CLI


def test_cli_arguments_and_run(tmp_path, capsys):
    parser = argparse.ArgumentParser()
    cli.add_arguments(parser)
    help_text = " ".join(parser.format_help().split())
    for option in [
        "--color-by",
        "--view",
        "--width",
        "--height",
        "--point-size",
        "--vmax",
        "--no-boundary",
        "--fps",
        "--walls",
        "--frame",
    ]:
        assert option in help_text
    for phrase in [
        "in pixels",
        "(default: 960)",
        "(default: 720)",
        "1/s",
        "m/s",
        "99th percentile",
        "frames per second, .mp4 only (default: 30)",
    ]:
        assert phrase in help_text

    h5 = _write_h5(tmp_path / "OUT.h5", keys=("000000", "000010"))
    args = parser.parse_args(
        [
            str(h5),
            "-o",
            str(tmp_path / "f"),
            "--width",
            str(W),
            "--height",
            str(H),
            "--view",
            "iso",
            "--color-by",
            "speed",
            "--vmax",
            "2.5",
            "--no-boundary",
        ]
    )
    assert args.no_boundary and args.vmax == 2.5
    assert cli.run(args) == 0
    assert len(list((tmp_path / "f").glob("frame_*.png"))) == 2
    assert "wrote 2 file(s)" in capsys.readouterr().out

    with pytest.raises(SystemExit):
        parser.parse_args([str(h5)])  # -o is required
    with pytest.raises(SystemExit):
        parser.parse_args([str(h5), "-o", "x", "--vmax", "-1"])


def test_cli_is_thin_and_reexports_the_renderer():
    assert cli.FrameStyle is FrameStyle and cli.render_frames is render_frames
    assert cli.output_is_video is rf.output_is_video
    source = open(cli.__file__).read()
    # 150 lines before ruff format's layout (one argument per line in long calls), which added 7; --probe 3 more
    assert len(source.splitlines()) <= 163 and "cv2" not in source and "h5py" not in source


def test_viz_frames_needs_neither_taichi_nor_torch():
    import subprocess
    import sys

    code = (
        "import sys, viz.frames, viz.video, viz.plots, fluidsim.files; "
        "print(sorted(m for m in ('taichi', 'torch') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_viz_and_fluidsim_write_through_the_one_atomic_module():
    import fluidsim.files as fgsio_files
    from fluidsim import output
    from viz import frames, plots, video

    assert video.atomic_output is output.atomic_output is fgsio_files.atomic_output
    assert frames.write_bytes_atomic is plots.write_bytes_atomic is fgsio_files.write_bytes_atomic
    a = fgsio_files.temp_path("/x/out.mp4", ".mp4")
    assert str(a.parent) == "/x" and a.name.startswith(".fgs-") and a.name.endswith(".tmp.mp4") and len(a.name) == 21


def _write_result_h5(path, probes=("-x", "+z"), recorded=("+z",), t=3, f=200):
    """A RESULT.h5 with what render-frames reads: a probe's trajectory (x, D, speed, steps), its domain, the solid."""
    rng = np.random.default_rng(4)
    with h5py.File(path, "w") as h:
        h.attrs["config"] = json.dumps({"dt": 0.004, "particle_radius": 0.05})
        h["solid/x"] = rng.uniform(-0.2, 0.2, (400, 3))
        for d in probes:
            g = h.create_group(f"probes/{d}")
            g["D"] = np.zeros(10)
            g.attrs["domain_min"], g.attrs["domain_max"] = np.full(3, -1.0), np.full(3, 1.0)
            if d in recorded:
                x = rng.uniform(-0.9, 0.9, (t, f, 3))
                x[1, :20] = np.nan  # retired particles
                g["trajectory/x"] = x
                g["trajectory/D"] = rng.gamma(2.0, 1.0, (t, f))
                g["trajectory/speed"] = rng.uniform(0, 3, (t, f))
                g["trajectory/steps"] = np.arange(t, dtype=np.int32) * 25
    return path


def test_render_frames_draws_a_recorded_probe_of_a_result_h5(tmp_path, capsys):
    # the README's flow records a probe into RESULT.h5 (--record-probe -x): render-frames draws it
    h5 = _write_result_h5(tmp_path / "result.h5")
    out = tmp_path / "frames"
    assert cli.main([str(h5), "-o", str(out), "--width", "160", "--height", "120"]) == 0
    pngs = sorted(out.glob("frame_*.png"))
    assert len(pngs) == 3 and cv2.imread(str(pngs[1])).shape == (120, 160, 3)
    with h5py.File(h5, "r") as f:
        source = frame_source.FrameSource.inspect(f, h5, FrameStyle(color_by="speed"), None)
        x, values, time, step = source.frame(1)
        assert len(x) == 180 and step == 25 and time == pytest.approx(0.1) and source.value_name == "speed"
        np.testing.assert_array_equal(source.domain_min, [-1, -1, -1])
    with h5py.File(h5, "r") as f, pytest.raises(ValueError, match="no trajectory of probe -x \\(recorded: \\+z\\)"):
        frame_source.FrameSource.inspect(f, h5, FrameStyle(), "-x")
