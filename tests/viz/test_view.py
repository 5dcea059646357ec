"""`fluidgs view` (viz) and the probe trajectories it replays (nbv.physics.trajectory), on a tiny sphere.

- the recorded frames are what the probe accumulated: D_g^(-x) and the sample counts recomputed from the frames
  (brute force, nbv.physics.aggregate_reference.within_reach_reference) match RESULT.h5, and the last frame is
  the probe's end state;
- RESULT.h5 for the viewer: missing arrays, other Gaussians, a missing trajectory: errors naming the fix;
- the cameras in the simulation frame, the colours (nbv.heatmap's), the viser server (colours, frames, camera
  clicks, a port in use, Ctrl-C) and a real headless Chromium screenshot of the splat and its colour bar.
"""

import base64
import contextlib
import json
import math
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import h5py
import numpy as np
import pytest
import torch

from apps import cli
from nbv.physics.aggregate_reference import within_reach_reference
from recon.camera import Camera
from recon.datasets import load_cameras
from recon.formats import load_gaussians
from recon.formats.ply import save_gaussians
from recon.gaussians import GaussianSet, sh0_to_rgb
from viz.cameras import candidate_views, read_scores, rotation_to_wxyz, view_png
from viz.colors import UNREACHED_RGB, color_scale, colorbar_image, turbo
from viz.data import load_trajectory, load_view_data
from viz.screenshot import CLOSE_NOTIFICATIONS, READY, ScreenshotUnavailable, devtools_page, find_browser
from viz.splats import splat_looks
from viz.thumbnails import project_to_view, view_thumbnail
from viz.viewer import FluidViewer

from helpers.cameras import ring_cameras, write_transforms
from helpers.paths import REPO as ROOT
from helpers.spheres import sphere_gaussians, sphere_points

FAST = ["--particle-radius", "0.08", "--steps", "40", "--dt", "0.004", "--no-empty-reference", "--threads", "2"]
EVERY = 5
FOV = math.radians(50)


def _two(value: float) -> str:
    """Two significant digits, as `fluidgs score` and the viewer print them."""
    return f"{float(f'{value:.2g}'):g}"


def _sphere(n: int = 300) -> GaussianSet:
    colours = torch.tensor(np.clip(sphere_points(n) + 0.5, 0, 1), dtype=torch.float32)  # varies over the sphere
    return sphere_gaussians(n, colours=colours)


def _cameras(path: Path) -> Path:
    return write_transforms(path, ring_cameras(6))


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """simulate (-x recorded every 5 steps, D_i accumulated at the same steps) and score, through the CLI."""
    root = tmp_path_factory.mktemp("view")
    ply = save_gaussians(_sphere(), root / "sphere.ply")
    cameras = _cameras(root / "transforms.json")
    h5, scores = root / "result.h5", root / "scores.json"
    record = ["--record-probe", "-x", "--record-every", str(EVERY), "--accumulate-every", str(EVERY)]
    assert cli.main(["simulate", str(ply), "-o", str(h5), "--directions=-x,+z", *record, *FAST]) == 0
    assert (
        cli.main(["score", str(ply), "--cameras", str(cameras), "--result", str(h5), "-o", str(scores), "--no-png"])
        == 0
    )
    return SimpleNamespace(root=root, ply=ply, cameras=cameras, h5=h5, scores=scores)


# ---- trajectories ----------------------------------------------------------------------------------------------
def test_trajectory_frames_are_what_the_probe_accumulated(scene):
    data = load_view_data(scene.h5)
    assert data.recorded == ("-x",) and data.directions == ("-x", "+z")
    traj = load_trajectory(data, "-x")
    np.testing.assert_array_equal(traj.steps, np.arange(1, 9) * EVERY)
    assert traj.x.dtype == np.float32 and traj.divergence.dtype == np.float16 and traj.x.shape[0] == 8
    with h5py.File(scene.h5) as f:
        reach = f["gaussians/reach"][()]
        pg = f["probes/-x"]
        counts, lo, hi = pg["counts"][()], pg.attrs["domain_min"], pg.attrs["domain_max"]
        ids_final, x_final = pg["ids_final"][()], pg["x_final"][()]
    # the last frame (step 40 of 40) is the probe's end state; particles that left the domain read NaN
    np.testing.assert_array_equal(traj.x[-1][ids_final], x_final)
    gone = np.setdiff1d(np.arange(traj.x.shape[1]), ids_final)
    assert np.isnan(traj.x[-1][gone]).all() and np.isnan(traj.divergence[-1][gone].astype(np.float32)).all()
    # D_g^(-x) from the frames by brute force (accumulated at the recorded steps only: --accumulate-every 5)
    sums, samples = np.zeros(data.num_gaussians), np.zeros(data.num_gaussians, np.int64)
    ambiguous = np.zeros(data.num_gaussians, bool)
    for k in range(traj.num_frames):
        x, d = traj.frame(k, "divergence")
        near = within_reach_reference(data.means, reach, x, lo, hi)
        dist2 = ((x[:, None, :].astype(np.float64) - data.means[None]) ** 2).sum(-1)
        ambiguous |= (np.abs(dist2 - reach[None] ** 2) < 1e-5 * reach[None] ** 2).any(0)  # f32 vs f64 ties
        sums += near.T.astype(np.float64) @ d.astype(np.float64)
        samples += near.sum(0)
    clear = ~ambiguous
    assert clear.sum() > 0.9 * data.num_gaussians and (samples[clear] > 0).sum() > 20
    np.testing.assert_array_equal(samples[clear], counts[clear])
    mean = np.where(samples > 0, sums / np.maximum(samples, 1), 0.0)
    # D_i is stored as float16 (relative step 2^-11)
    np.testing.assert_allclose(mean[clear], data.per_probe["-x"][clear], rtol=2e-3, atol=1e-4)
    assert float(np.nanmax(traj.speed.astype(np.float32))) > 2.0  # the -x inflow runs at 3 m/s


def test_record_size_is_f_t_16_bytes(scene):
    from nbv.physics import PhysicsConfig
    from nbv.physics.plan import ProbePlan
    from nbv.physics.trajectory import RecordConfig, check_record_size

    data = load_view_data(scene.h5)
    cfg = PhysicsConfig.from_dict(data.config)
    counts = ProbePlan.of(data.solid, cfg).fluid_counts(["-x", "+z"])
    assert counts["-x"] == load_trajectory(data, "-x").x.shape[1]  # the estimate is the probe's own count
    record = RecordConfig(("-x", "+z"), every=EVERY)
    assert check_record_size(counts, 40, record) == (counts["-x"] + counts["+z"]) * 8 * 24
    with pytest.raises(ValueError, match="--record-every 1[0-9] or record fewer"):
        check_record_size(counts, 40, RecordConfig(("-x", "+z"), every=EVERY, max_bytes=counts["-x"] * 8 * 24))
    for bad in (dict(every=0), dict(every=1.5), dict(max_bytes=-1.0)):
        with pytest.raises(ValueError, match="--record"):
            RecordConfig(("-x",), **bad)


def test_recording_is_checked_before_simulating(scene, tmp_path, caplog):
    base = ["simulate", str(scene.ply), "-o", str(tmp_path / "r.h5"), *FAST, "--directions=-x"]
    t0 = time.perf_counter()
    assert cli.main([*base, "--record-probe", "-x", "--record-max-gb", "1e-7"]) == 2
    assert "--record-every" in caplog.text and "MiB" in caplog.text and "24 bytes" in caplog.text
    assert cli.main([*base, "--record-probe", "+z"]) == 2
    assert "not among the probes run" in caplog.text
    assert cli.main([*base, "--record-probe", "-x", "--record-every", "41"]) == 2
    assert "no frame" in caplog.text
    assert (
        cli.main(
            [
                "score",
                str(scene.ply),
                "--cameras",
                str(scene.cameras),
                "--result",
                str(scene.h5),
                "-o",
                str(tmp_path / "s.json"),
                "--record-probe",
                "-x",
                "--no-png",
            ]
        )
        == 2
    )
    assert "--save-result" in caplog.text
    assert time.perf_counter() - t0 < 60 and not (tmp_path / "r.h5").exists()


def test_result_without_recording_stays_small(scene):
    with h5py.File(scene.h5) as f:
        assert "trajectory" in f["probes/-x"] and "trajectory" not in f["probes/+z"]
        frames, fluid = f["probes/-x/trajectory/x"].shape[:2]
    # what the recording added: about F T 24 bytes (gzip takes some off)
    assert frames * fluid * 24 < 3e6


# ---- RESULT.h5 for the viewer ----------------------------------------------------------------------------------
def test_missing_trajectory_says_how_to_record_it(scene):
    data = load_view_data(scene.h5)
    with pytest.raises(ValueError, match="no trajectory for probe \\+z") as err:
        load_trajectory(data, "+z")
    command = str(err.value).split("`")[1]
    args = cli.build_parser().parse_args(cli.join_dash_values(shlex.split(command)[1:]))
    assert (args.command, args.record_probe, args.particle_radius, args.steps) == ("simulate", "+z", 0.08, 40)
    assert args.directions == "-x,+z" and args.no_empty_reference and Path(args.gaussians) == scene.ply
    with pytest.raises(ValueError, match="has the probes -x, \\+z"):
        load_trajectory(data, "-y")


def test_results_of_other_versions_name_what_is_missing(scene, tmp_path):
    old = tmp_path / "old.h5"
    shutil.copy(scene.h5, old)
    with h5py.File(old, "a") as f:
        del f["gaussians/covariances"]
    with pytest.raises(ValueError, match="lacks /gaussians/covariances.*fluidgs simulate"):
        load_view_data(old)
    with h5py.File(old, "a") as f:  # the scene -> sim transform of files before scene_to_sim: up_axis + scale
        f["gaussians/covariances"] = np.zeros((300, 3, 3))
        scale = float(f.attrs["scale"])
        del f.attrs["scene_to_sim"]
        f.attrs["up_axis"] = "z"
    m = load_view_data(old).scene_to_sim
    np.testing.assert_allclose(m[:3, :3] @ [0, 0, 1.0], [0, scale, 0])  # scene z -> sim +y
    (tmp_path / "not.h5").write_text("hello")
    with pytest.raises(ValueError, match="not an HDF5 file"):
        load_view_data(tmp_path / "not.h5")
    with pytest.raises(ValueError, match="does not exist.*fluidgs simulate"):
        load_view_data(tmp_path / "none.h5")


def test_gaussians_must_be_those_of_the_result(scene, tmp_path):
    data = load_view_data(scene.h5)
    looks = splat_looks(scene.ply, data)
    g = load_gaussians(scene.ply)
    np.testing.assert_allclose(looks.rgb, sh0_to_rgb(g.sh[:, 0]).clamp(0, 1).numpy(), atol=1e-6)
    np.testing.assert_allclose(looks.opacity, g.opacities.numpy(), atol=1e-6)
    assert splat_looks(None, data).source == str(scene.ply)  # RESULT.h5's source, when it is there
    recoloured = splat_looks(scene.root / "result_divergence.ply", data)  # simulate's D_g-coloured copy
    assert recoloured.rgb is not None and not np.allclose(recoloured.rgb, looks.rgb)
    fewer = save_gaussians(g.subset(torch.arange(299)), tmp_path / "fewer.ply")
    with pytest.raises(ValueError, match="has 299 Gaussians but .* holds D_g for 300"):
        splat_looks(fewer, data)
    moved = g.clone()
    moved.means[17] += 0.01
    with pytest.raises(ValueError, match="other centres.*Gaussian 17"):
        splat_looks(save_gaussians(moved, tmp_path / "moved.ply"), data)


# ---- cameras and colours ---------------------------------------------------------------------------------------
def test_cameras_are_moved_to_the_simulation_frame(scene):
    from nbv.physics.scene_frame import SceneTransform

    scores = read_scores(scene.scores)
    cams = [
        Camera.look_at((2.5 * math.cos(a), 0.3, 2.5 * math.sin(a)), (0, 0, 0), (0, 1, 0), 48, 40, FOV)
        for a in np.arange(6) * math.pi / 3
    ]
    for transform in (SceneTransform("+y", 2.0), SceneTransform("+z", 0.5), SceneTransform((0.3, -1.0, 0.2), 3.0)):
        views = candidate_views(scene.cameras, transform.matrix, scores)
        assert [v.index for v in views] == list(range(6))
        for v, cam in zip(views, cams, strict=True):
            np.testing.assert_allclose(v.position, transform.to_sim(cam.center.numpy()[None])[0], atol=1e-9)
            np.testing.assert_allclose(v.rotation @ v.rotation.T, np.eye(3), atol=1e-9)
            # every camera looks at the scene origin, which stays the origin
            np.testing.assert_allclose(v.forward, -v.position / np.linalg.norm(v.position), atol=1e-6)
            assert math.isclose(v.fov_y, cam.fov_y) and math.isclose(v.aspect, 48 / 40)
    ranked = {v["index"]: (v["rank"], v["score"]) for v in scores["views"]}
    assert all((v.rank, v.score) == ranked[v.index] for v in views)
    bad = dict(scores, views=[*scores["views"], {"index": 6, "name": "cam6", "score": 1.0, "rank": 7}])
    with pytest.raises(ValueError, match="ranks camera 6 but .* has 6 cameras"):
        candidate_views(scene.cameras, np.eye(4), bad)
    renamed = dict(scores, views=[dict(scores["views"][0], name="other")])
    with pytest.raises(ValueError, match="calls it"):
        candidate_views(scene.cameras, np.eye(4), renamed)


def test_quaternions_match_viser():
    transforms = pytest.importorskip("viser.transforms")
    rng = np.random.default_rng(0)
    mats = [np.eye(3), np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, 1.0, -1.0]), np.diag([-1.0, -1.0, 1.0])]
    mats += [transforms.SO3(q / np.linalg.norm(q)).as_matrix() for q in rng.normal(size=(50, 4))]
    for m in mats:
        q = rotation_to_wxyz(m)
        np.testing.assert_allclose(transforms.SO3(q).as_matrix(), m, atol=1e-9)
        assert q[0] >= 0 and math.isclose(np.linalg.norm(q), 1.0)


def test_colours_are_those_of_nbv_heatmap():
    from nbv.heatmap import color_scale as nbv_scale
    from nbv.heatmap import colormap

    v = np.random.default_rng(1).gamma(1.5, 2.0, size=1000)
    v[:3] = [np.nan, np.inf, 0.0]
    assert color_scale(v) == nbv_scale(v) and color_scale(np.zeros(5)) == 1.0
    np.testing.assert_array_equal(turbo(v, 4.0), colormap(v, 4.0))
    # Gaussians no fluid reached are grey, apart from the calm (dark blue) ones, and the scale is of the reached
    reached = np.arange(1000) % 3 > 0
    v[~reached] = 0.0
    rgb = colormap(v, reached=reached)
    np.testing.assert_array_equal(rgb[~reached], np.tile(np.float32(UNREACHED_RGB), ((~reached).sum(), 1)))
    w = np.nan_to_num(v, nan=0.0, posinf=0.0)  # NaN and inf read 0
    np.testing.assert_array_equal(rgb[reached], turbo(w, color_scale(w[reached]))[reached])
    assert not np.isclose(turbo(np.zeros(1), 1.0), UNREACHED_RGB).all()
    with pytest.raises(ValueError, match="reached"):
        turbo(v, 4.0, reached[:10])
    bar = colorbar_image(4.0, "D_g (max), 1/s")
    row = bar[bar.shape[0] // 6]
    left, right = row[12].astype(int), row[-12].astype(int)
    assert left[2] > left[0] and right[0] > right[2]  # blue at 0, red at the top


def test_the_viewer_knows_the_probes_flows():
    pytest.importorskip("viser")
    from fluidsim.probes import flow_vector
    from viz.viewer import PROBE_FLOWS

    for d, flow in PROBE_FLOWS.items():
        np.testing.assert_array_equal(flow, flow_vector(d))


# ---- the server ------------------------------------------------------------------------------------------------
@pytest.fixture()
def viewer_of(scene):
    pytest.importorskip("viser")
    from viz.serving import ViewerOptions
    from viz.viewer import open_viewer

    opened = []

    def make(result=None, **kwargs):
        opts = {k: kwargs.pop(k) for k in ("probe", "port") if k in kwargs}
        v = open_viewer(result or scene.h5, options=ViewerOptions(**{"port": 0, **opts}), **kwargs)
        opened.append(v)
        return v

    yield make
    for v in opened:
        v.close()


class _FakeCamera:
    def __init__(self):
        self.position, self.look_at, self.wxyz, self.fov = np.zeros(3), np.zeros(3), np.zeros(4), 0.0


class _FakeClient:
    def __init__(self):
        self.camera = _FakeCamera()

    def atomic(self):
        return contextlib.nullcontext()


def test_viewer_colours_frames_and_cameras(scene, viewer_of):
    v = viewer_of(gaussians=scene.ply, scores=scene.scores, probe="-x")
    with urllib.request.urlopen(v.url, timeout=30) as page:
        assert page.status == 200 and b"<html" in page.read(2000).lower()
    assert v.url.startswith("http://127.0.0.1:")
    d = v.data
    rgb, vmax = v.splat_colors("D_g max")
    reached = d.reached_gaussians
    assert reached is not None and reached.shape == d.divergence.shape
    assert vmax == color_scale(d.divergence[reached])  # the scale is of the measured D_g
    np.testing.assert_array_equal(rgb[~reached], np.tile(np.float32(UNREACHED_RGB), ((~reached).sum(), 1)))
    np.testing.assert_array_equal(v._splats.rgbs, np.round(rgb * 255).astype(np.uint8))
    v.set_color_mode("own colours")
    np.testing.assert_allclose(v._splats.rgbs, v.looks.rgb * 255, atol=1.0)  # viser truncates to uint8
    assert not v._colorbar.visible
    v.set_color_mode("D_g +z")
    np.testing.assert_array_equal(
        v._splats.rgbs,
        np.round(turbo(d.per_probe["+z"], color_scale(d.per_probe["+z"][reached]), reached) * 255).astype(np.uint8),
    )
    assert v._colorbar.visible
    # the replay: frame 3 is drawn, then play advances it
    traj = load_trajectory(d, "-x")
    v.show_frame(3)
    x, _ = traj.frame(3)
    np.testing.assert_allclose(v._fluid.points, x, atol=2e-3)  # float16 on the wire
    assert int(v._slider.value) == 3 and "step 20 of 40" in v._fluid_note.content
    v.set_playing(True)
    deadline = time.time() + 20
    while v._frame == 3 and time.time() < deadline:
        time.sleep(0.05)
    v.set_playing(False)
    assert v._frame != 3
    # a probe without a trajectory: the fluid is hidden, the note says how to record it
    v.set_probe("+z")
    assert not v._fluid.visible and "--record-probe=+z" in v._fluid_note.content
    # a click on a camera moves the view to it
    best = min((c for c in v.views if c.rank is not None), key=lambda c: c.rank)
    client = _FakeClient()
    v.go_to(client, best)
    np.testing.assert_allclose(client.camera.position, best.position)
    np.testing.assert_allclose(client.camera.wxyz, best.wxyz)
    assert math.isclose(client.camera.fov, best.fov_y)
    look = client.camera.look_at - best.position
    np.testing.assert_allclose(look / np.linalg.norm(look), best.forward, atol=1e-9)


def test_side_panel_lists_the_top_views_with_their_numbers_and_pictures(scene, viewer_of, tmp_path):
    # scores.json with the per-view coverage and S/A that `score` may add
    data = json.loads(scene.scores.read_text())
    for k, row in enumerate(data["views"]):
        row["coverage"], row["physics_mean"] = 0.5 + 0.05 * k, 1e-3 * (k + 1)
    scores = tmp_path / "scores.json"
    scores.write_text(json.dumps({**data, "cameras": str(scene.cameras)}))
    v = viewer_of(gaussians=scene.ply, scores=scores, probe="-x")
    ranked = sorted(data["views"], key=lambda r: r["rank"])
    assert [b.label for b in v._view_buttons] == [f"#{r['rank']} {r['name']}" for r in ranked]
    for image, row in zip(v._view_images, ranked, strict=True):
        s, a, m = (_two(row[k]) for k in ("score", "coverage", "physics_mean"))
        assert image.label == f"S = {s}, A = {a}, S/A = {m}"
    # no PNGs were written (--no-png): each thumbnail is the centres seen through that camera, not blank
    for image in v._view_images:
        assert image.image.shape == (167, 200, 3) and (np.abs(image.image.astype(int) - 238).max(-1) > 30).sum() > 50
    # a click on an entry moves the view there
    client = _FakeClient()
    best = v.ranked_views()[0]
    v._clicked(SimpleNamespace(client=client), best)
    np.testing.assert_allclose(client.camera.position, best.position)
    # the replay opens at mid-run; each probe's reach and the empty-scene reference are listed
    assert v._frame == load_trajectory(v.data, "-x").num_frames // 2
    table = v.probe_markdown()
    with h5py.File(scene.h5) as f:
        for d in ("-x", "+z"):
            assert f"| {d} | {int((f[f'probes/{d}/counts'][()] > 0).sum()):,} (" in table
    assert "the empty scene was not run" in table  # FAST runs no empty scene
    # without the coverage columns the caption is S(T) alone
    assert FluidViewer.view_caption(replace(best, coverage=None, physics_mean=None)) == f"S = {_two(best.score)}"


def test_thumbnail_is_the_score_png_when_there_is_one(scene, tmp_path):
    import cv2

    data = load_view_data(scene.h5)
    view = replace(candidate_views(scene.cameras, data.scene_to_sim, None, "r.h5")[2], rank=3)
    scores = tmp_path / "scores.json"
    assert view_png(scores, view) is None
    folder = tmp_path / "scores_views"
    folder.mkdir()
    picture = np.zeros((100, 300, 3), np.uint8)
    picture[:] = (0, 0, 255)  # BGR red
    cv2.imwrite(str(folder / f"rank003_{view.index:03d}_{view.name}.png"), picture)
    found = view_png(scores, view)
    assert found == folder / f"rank003_{view.index:03d}_{view.name}.png"
    thumb = view_thumbnail(replace(view, png=found), data.means, np.zeros((data.num_gaussians, 3)))
    assert thumb.shape == (67, 200, 3) and (thumb[..., 0] > 250).all() and (thumb[..., 2] < 5).all()  # RGB red


def test_thumbnail_projection_is_the_cameras(scene):
    data = load_view_data(scene.h5)
    views = candidate_views(scene.cameras, data.scene_to_sim, None, "r.h5")
    cams = load_cameras(scene.cameras)
    scene_pts = np.random.default_rng(0).normal(scale=0.4, size=(200, 3))
    sim_pts = scene_pts @ data.scene_to_sim[:3, :3].T + data.scene_to_sim[:3, 3]
    for view, cam in zip(views, cams, strict=True):
        uv, depth = project_to_view(view, sim_pts, cam.height)
        ref, z = cam.project(torch.tensor(scene_pts))
        front = z.numpy() > 0
        assert ((depth > 0) == front).all()
        np.testing.assert_array_equal(uv[front], np.floor(ref.numpy()[front]).astype(np.int64))


def test_gaussians_outside_the_crop_are_hidden_until_asked_for(scene, viewer_of, tmp_path):
    cropped = tmp_path / "cropped.h5"
    shutil.copy(scene.h5, cropped)
    with h5py.File(cropped, "a") as f:
        kept = f["gaussians/means"][:, 0] > 0  # as if a crop had kept the +x half
        f["gaussians/kept"] = kept
    v = viewer_of(cropped)
    np.testing.assert_allclose(v._splats.centers, v.data.means[kept], atol=1e-6)
    v._show_cropped.value = True  # what the checkbox does
    assert len(v._splats.centers) == 300


def test_cameras_without_scores_are_drawn_unranked(scene, viewer_of):
    v = viewer_of(cameras=scene.cameras)
    assert len(v.views) == 6 and all(c.rank is None and c.score is None for c in v.views)
    assert len(v._frustums) == 6 and all(tuple(f.color) == (60, 60, 60) for f in v._frustums)


def test_without_viser_the_command_says_how_to_install_it(scene, monkeypatch, caplog):
    monkeypatch.setitem(sys.modules, "viser", None)  # import viser raises ImportError
    assert cli.main(["view", str(scene.h5)]) == 2
    assert "pip install -e .[view]" in caplog.text


def test_a_port_in_use_moves_to_the_next(scene, viewer_of, caplog):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        busy = s.getsockname()[1]
        v = viewer_of(port=busy)
        assert v.port != busy and f"port {busy} is in use" in caplog.text


def test_view_command_rejects_bad_input(scene, tmp_path, caplog):
    pytest.importorskip("viser")
    assert cli.main(["view", str(tmp_path / "none.h5")]) == 2
    assert cli.main(["view", str(scene.h5), "--probe", "-y", "--port", "0"]) == 2
    assert "has the probes -x, +z" in caplog.text
    assert cli.main(["view", str(scene.h5), "--port", "70000"]) == 2
    assert "--port" in caplog.text
    fewer = save_gaussians(_sphere(120), tmp_path / "fewer.ply")
    assert cli.main(["view", str(scene.h5), "--gaussians", str(fewer), "--port", "0"]) == 2
    scores = json.loads(scene.scores.read_text())
    lost = tmp_path / "lost.json"
    lost.write_text(json.dumps(dict(scores, cameras=str(tmp_path / "gone.json"))))
    assert cli.main(["view", str(scene.h5), "--scores", str(lost), "--port", "0"]) == 2
    assert "pass --cameras" in caplog.text


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_view_command_stops_cleanly(scene, stop):
    pytest.importorskip("viser")
    proc = subprocess.Popen(
        [sys.executable, "-m", "apps.cli", "view", str(scene.h5), "--port", "0"],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        line = proc.stdout.readline()
        assert line.startswith("fluidgs view: http://127.0.0.1:"), line + proc.stderr.read()
        url = line.split()[2]
        with urllib.request.urlopen(url, timeout=30) as page:
            assert page.status == 200
        proc.send_signal(stop)
        out, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    assert "Traceback" not in err and out == "", (out, err)
    assert err.strip().splitlines()[-1].endswith("viewer stopped")
    assert sum("viewer stopped" in e or "Server stopped" in e for e in (err + out).splitlines()) == 1


# ---- a real browser --------------------------------------------------------------------------------------------
class BrowserUnavailable(RuntimeError):
    """Chromium is installed but does not start (no DevTools port)."""


BARS = (
    "JSON.stringify([...document.images].map(i => i.getBoundingClientRect()).filter(r => r.width > 150)"
    ".map(r => [r.left, r.top, r.width, r.height]))"
)


def browser_screenshots(url: str, size=(1024, 768), timeout: float = 150.0, dismiss: bool = False, ready: str = READY):
    """Yield (RGB uint8 [H, W, 3], colour-bar rectangles [[x, y, w, h], ...]) of ``url`` in headless Chromium, every
    second or so once the page shows a canvas and its colour bars, until ``timeout`` s have passed.

    ``dismiss``: close viser's notifications (the software-WebGL note) before each screenshot. ``ready``: the
    JavaScript condition to wait for."""
    import cv2

    deadline = time.time() + timeout
    with contextlib.ExitStack() as stack:
        try:  # the browser's start: a machine where it cannot start skips
            tools = stack.enter_context(devtools_page(size, time.monotonic() + 60))
        except ScreenshotUnavailable as exc:
            raise BrowserUnavailable(str(exc)) from None
        tools.call("Page.navigate", url=url)
        while not tools.eval(ready):
            if time.time() > deadline:
                text = tools.eval("document.body.innerText")
                raise RuntimeError(f"the page never showed its colour bar: {text!r}")
            time.sleep(0.5)
        while time.time() < deadline:
            time.sleep(1.0)
            if dismiss:
                tools.eval(CLOSE_NOTIFICATIONS)
                time.sleep(0.5)
            png = base64.b64decode(tools.call("Page.captureScreenshot", format="png")["data"])
            bgr = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
            yield bgr[..., ::-1].copy(), json.loads(tools.eval(BARS))


def splat_drawn(img: np.ndarray) -> bool:
    """Non-background pixels in the middle of the viewport (where the initial camera puts the object), background
    in its lower-right corner left of the control panel."""
    h, w = img.shape[:2]
    centre = img[h // 2 - 40 : h // 2 + 40, w // 2 - 40 : w // 2 + 40].astype(int)
    corner = img[h - 90 : h - 10, w // 2 + 40 : w // 2 + 120].astype(int)
    drawn = (np.abs(centre - 255).max(-1) > 40).mean()
    empty = (np.abs(corner - 255).max(-1) <= 10).mean()
    return drawn > 0.9 and empty > 0.9


def colorbar_drawn(img: np.ndarray, rect) -> bool:
    """The TURBO ramp across the colour bar image: blue at 15 % of it, green at 50 %, red at 85 %."""
    x, y, w, h = (int(round(c)) for c in rect)
    row = img[y + h // 6, x : x + w].astype(int)  # the ramp is the top third of the image
    blue, green, red = (row[int(f * (w - 1))] for f in (0.15, 0.5, 0.85))
    return bool(blue[2] > blue[0] + 80 and green[1] > max(green[0], green[2]) + 40 and red[0] > red[2] + 80)


def test_browser_shows_the_splat_and_its_colour_bar(scene, viewer_of, tmp_path):
    if find_browser() is None:
        pytest.skip("no Chromium on this machine (install Debian's: apt-get install chromium; .ci/run does as root)")
    pytest.importorskip("websockets.sync.client")
    import cv2

    v = viewer_of(gaussians=scene.ply, probe="+z")  # no trajectory and no cameras: only the splat in the middle
    last, shots = None, browser_screenshots(v.url)
    try:
        for img, bars in shots:
            last = img
            if bars and splat_drawn(img) and colorbar_drawn(img, bars[0]):
                break
        else:
            bars = None
    except BrowserUnavailable as exc:
        pytest.skip(f"no working browser: {exc}")
    finally:
        shots.close()
    if bars is None:
        out = tmp_path / "view.png"
        if last is not None:
            cv2.imwrite(str(out), last[..., ::-1])
        pytest.fail(f"the splat or its colour bar is not drawn; the last screenshot is {out}")
    assert len(bars) == 1  # the D_g bar; the fluid's is hidden without a trajectory


def test_an_address_of_another_machine_is_refused_at_once(scene, caplog):
    """--host 192.0.2.1 (TEST-NET-1, never this machine's) hung forever: now exit 2 at once, naming the option."""
    pytest.importorskip("viser")
    t0 = time.monotonic()
    assert cli.main(["view", str(scene.h5), "--host", "192.0.2.1", "--port", "0"]) == 2
    assert time.monotonic() - t0 < 10
    assert "--host 192.0.2.1 is not an address of this machine" in caplog.text
    assert cli.main(["view", str(scene.h5), "--host", "no-such-host.invalid", "--port", "0"]) == 2
    assert "--host no-such-host.invalid: not a name or address" in caplog.text


def test_a_taken_last_port_is_a_clear_error(scene, caplog, capsys):
    """--port 65535 in use has no next port to move to: exit 2 naming --port (it printed a traceback, then hung)."""
    pytest.importorskip("viser")
    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", 65535))
        except OSError:
            pytest.skip("port 65535 is taken here already")
        s.listen()
        t0 = time.monotonic()
        assert cli.main(["view", str(scene.h5), "--port", "65535"]) == 2
        assert time.monotonic() - t0 < 10
    assert "--port 65535 is in use" in caplog.text and "Traceback" not in capsys.readouterr().err


def test_a_result_with_nan_d_g_is_served_with_a_warning(scene, viewer_of, tmp_path, caplog):
    import shutil

    bad = tmp_path / "nan.h5"
    shutil.copy(scene.h5, bad)
    with h5py.File(bad, "r+") as f:
        d = f["gaussians/D"][()]
        d[:7] = np.nan
        f["gaussians/D"][...] = d
    viewer_of(bad, gaussians=scene.ply)
    assert "7 of 300 Gaussians have a non-finite D_g" in caplog.text


def test_view_label_shows_the_score_and_its_parts(tmp_path):
    from viz.cameras import CandidateView, _uncertainty_png
    from viz.viewer import FluidViewer

    eye = np.eye(3)
    v = CandidateView(
        3,
        "c3",
        np.zeros(3),
        eye,
        np.array([1.0, 0, 0, 0]),
        0.8,
        1.3,
        score=364.8,
        rank=1,
        coverage=74.97,
        physics_mean=4.866,
    )
    assert FluidViewer._view_label(v) == "#1 c3 (S = 360, A = 75, S/A = 4.9)"
    png = tmp_path / "u.png"
    assert _uncertainty_png({"uncertainty_image": {"png": str(png)}}) is None  # named but missing
    png.write_bytes(b"x")
    assert _uncertainty_png({"uncertainty_image": {"png": str(png)}}) == png and _uncertainty_png(None) is None


PANEL_READY = (
    "(() => { const t = document.body.innerText; const thumbs = [...document.images].filter(i => "
    "i.naturalWidth === 200 && i.complete); return t.includes('Top views') && t.includes('#1 ') && "
    "t.includes('S = ') && thumbs.length >= 3; })()"
)


def test_browser_shows_the_list_of_views(scene, viewer_of, tmp_path):
    """The side panel in a real browser: the 'Top views' folder with the ranked entries, their S(T) and their
    thumbnails loaded (the screenshot is kept in the test's folder)."""
    if find_browser() is None:
        pytest.skip("no Chromium on this machine (install Debian's: apt-get install chromium; .ci/run does as root)")
    pytest.importorskip("websockets.sync.client")
    import cv2

    v = viewer_of(gaussians=scene.ply, scores=scene.scores, probe="-x")
    shots = browser_screenshots(v.url, size=(1280, 1400), timeout=90.0, dismiss=True, ready=PANEL_READY)
    try:
        img, _ = next(shots)  # the first screenshot comes only once PANEL_READY holds
    except BrowserUnavailable as exc:
        pytest.skip(f"no working browser: {exc}")
    finally:
        shots.close()
    cv2.imwrite(str(tmp_path / "panel.png"), img[..., ::-1])
    assert img.shape[:2] == (1400, 1280)


def test_view_finds_the_source_from_any_folder(scene, tmp_path, monkeypatch):
    # RESULT.h5 stores the source's absolute path and its path relative to RESULT.h5's folder
    from nbv.physics import load_result, save_result
    from viz.splats import resolve_gaussians

    work = tmp_path / "work"
    work.mkdir()
    shutil.copy(scene.ply, work / "g.ply")
    monkeypatch.chdir(work)
    result = load_result(scene.h5)
    save_result(work / "out" / "r.h5", replace(result, source="g.ply"))  # as a user types it, relative
    with h5py.File(work / "out" / "r.h5", "r") as f:
        assert f.attrs["source"] == str((work / "g.ply").resolve()) and f.attrs["source_relative"] == "../g.ply"
    monkeypatch.chdir(tmp_path)  # view from another folder
    assert resolve_gaussians(None, load_view_data(work / "out" / "r.h5")) == (work / "g.ply").resolve()
    moved = tmp_path / "moved"  # both files moved together: the relative path still finds it
    shutil.move(str(work), str(moved))
    found = resolve_gaussians(None, load_view_data(moved / "out" / "r.h5"))
    assert found is not None and found.resolve() == (moved / "g.ply").resolve()


def test_view_screenshot_without_chromium_is_a_clear_error(scene, tmp_path, monkeypatch, caplog):
    import viz.screenshot

    monkeypatch.setattr(viz.screenshot, "find_browser", lambda: None)
    out = tmp_path / "view.png"
    assert cli.main(["view", str(scene.h5), "--screenshot", str(out), "--port", "0"]) == 2
    assert "--screenshot needs Chromium" in caplog.text and "apt-get install chromium" in caplog.text
    assert not out.exists()


def test_view_screenshot_writes_the_page(scene, tmp_path):
    if find_browser() is None:
        pytest.skip("no Chromium on this machine (install Debian's: apt-get install chromium; .ci/run does as root)")
    import cv2

    out = tmp_path / "view.png"
    argv = ["view", str(scene.h5), "--gaussians", str(scene.ply), "--screenshot", str(out), "--port", "0"]
    assert cli.main(argv) == 0
    img = cv2.imread(str(out))
    assert img is not None and img.shape[:2] == (800, 1280) and img.std() > 5  # a drawn page, not a blank one
