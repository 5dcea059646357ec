"""View scores (paper Eq. 4-5), ranking, D-bar and critical scores against loop twins and hand cases."""

import math
from dataclasses import dataclass

import pytest
import torch

from nbv import scores
from recon.camera import Camera
from recon.projection import project_visibility_reference

from helpers.random_scenes import random_scene


@dataclass
class FakeRender:
    """A RenderOutput-like object: only what the scorer reads."""

    image: torch.Tensor
    radii: torch.Tensor
    visible: torch.Tensor


def _renders(radii: torch.Tensor, h: int, w: int) -> list[FakeRender]:
    return [FakeRender(torch.zeros(h, w, 3), r.to(torch.int32), r > 0) for r in radii]


def test_view_weights_clamp_and_formula():
    w = scores.view_weights(torch.tensor([0, 1, 4, 1000]), 10, 20)
    assert w[0] == 0
    assert w[1] == pytest.approx(math.pi / 200)
    assert w[2] == pytest.approx(16 * math.pi / 200)
    assert w[3] == 1.0  # clamped
    with pytest.raises(ValueError):
        scores.view_weights(torch.tensor([1]), 0, 5)


def test_view_scores_match_loop_twin():
    gen = torch.Generator().manual_seed(0)
    c, n, h, w = 5, 40, 24, 32
    radii = torch.randint(0, 12, (c, n), generator=gen)
    radii[2] = 0  # one view sees nothing
    metric = torch.rand(n, generator=gen, dtype=torch.float64) * 3
    fast = scores.view_scores(metric, _renders(radii, h, w))
    ref = scores.view_scores_reference(metric, radii, radii > 0, h, w)
    assert torch.allclose(fast, torch.tensor(ref, dtype=torch.float64), rtol=1e-12, atol=1e-12)
    assert fast[2] == 0
    # a radii tensor with an explicit image size gives the same
    assert torch.allclose(scores.view_scores(metric, radii, image_size=(h, w)), fast)


def test_unweighted_and_visibility_only():
    metric = torch.tensor([1.0, 2.0, 4.0])
    vis = torch.tensor([[True, False, True], [False, True, False]])
    assert scores.view_scores(metric, vis).tolist() == [5.0, 2.0]
    r = torch.tensor([[3, 0, 1], [0, 7, 0]])
    assert scores.view_scores(metric, _renders(r, 8, 8), weighted=False).tolist() == [5.0, 2.0]
    with pytest.raises(ValueError, match="same Gaussian set"):
        scores.view_scores(torch.ones(4), vis)
    with pytest.raises(ValueError, match="image_size"):
        scores.view_scores(metric, r)


def test_rank_descending_stable_ties():
    s = torch.tensor([1.0, 3.0, 3.0, 0.5, 2.0])
    assert scores.rank(s).tolist() == [1, 2, 4, 0, 3]
    with pytest.raises(ValueError):
        scores.rank(torch.tensor([1.0, float("nan")]))


def test_geometry_divergence_hand_case():
    cov = torch.stack([torch.diag(torch.tensor([1.0, 2.0, 3.0])), torch.eye(3) * 0.5])
    d = torch.tensor([2.0, 4.0])
    expected = (math.pi * 36 * 2 + math.pi * 1.5**2 * 4) / 2
    assert scores.geometry_divergence(cov, d) == pytest.approx(expected)
    # rotation-invariant: s_g = tr(Sigma_g)
    q = torch.linalg.qr(torch.randn(3, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(1)))[0]
    rotated = q @ cov.to(torch.float64) @ q.T
    assert scores.geometry_divergence(rotated, d) == pytest.approx(expected)
    with pytest.raises(ValueError):
        scores.geometry_divergence(cov, torch.ones(3))


def test_critical_scores_and_subset():
    counts = torch.tensor([10, 0, 5, 100])
    r = torch.tensor([[2, 2, 2, 0], [0, 0, 0, 2], [2, 2, 0, 0]])
    c = scores.critical_scores(counts, _renders(r, 4, 4))
    w = math.pi * 4 / 16
    assert torch.allclose(c, torch.tensor([15 * w, 100 * w, 10 * w], dtype=torch.float64))
    assert scores.critical_subset(c, k=2).tolist() == [1, 0]
    assert scores.critical_subset(c, k=20).tolist() == [1, 0, 2]


def test_projected_counts():
    means = torch.tensor([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.0, 50.0]])
    front = Camera.look_at((0, 0, 3), (0, 0, 0), (0, 1, 0), 32, 32, math.radians(60))
    away = Camera.look_at((0, 0, 3), (0, 0, 6), (0, 1, 0), 32, 32, math.radians(60))
    counts = scores.projected_counts(means, [front, away])
    assert counts.tolist() == [2, 1]


def _points_at_pixels(camera: Camera, pixels: torch.Tensor, depths: torch.Tensor) -> torch.Tensor:
    """[n, 3] float64 world points that ``camera`` projects to ``pixels`` [n, 2] at camera-frame ``depths`` [n]."""
    x = (pixels[:, 0] - camera.cx) / camera.fx * depths
    y = (pixels[:, 1] - camera.cy) / camera.fy * depths
    local = torch.stack([x, y, depths], -1)
    w2c = camera.world_to_camera
    return (local - w2c[:3, 3]) @ w2c[:3, :3]


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_projected_counts_equal_the_float64_twin_at_the_borders(dtype, monkeypatch):
    """The fast count decides most centres in the means' dtype and sends those within round-off of the image border
    or the near plane to the float64 test: the counts equal the twin's exactly, on centres placed on the borders."""
    gen = torch.Generator().manual_seed(3)
    cams = [
        Camera.look_at((0, 0, 3), (0, 0, 0), (0, 1, 0), 32, 24, math.radians(60)),
        Camera.look_at((2.5, -1, 1), (0.2, 0, 0), (0, 0, 1), 17, 40, math.radians(35)),
        Camera.look_at((-40, 3, 2), (0, 0, 0), (0, 1, 0), 64, 64, math.radians(90)),
    ]
    parts = [torch.rand(4000, 3, generator=gen, dtype=torch.float64) * 6 - 3]
    for cam in cams:
        w, h, n = cam.width, cam.height, 600
        edge = torch.tensor([0.0, 1e-7, -1e-7, 1e-4, -1e-4, 0.5])
        u = torch.cat([edge, w + edge, torch.rand(n - 12, generator=gen, dtype=torch.float64) * w])
        v = torch.cat([torch.rand(12, generator=gen, dtype=torch.float64) * h, h * torch.rand(n - 12, generator=gen)])
        v[12:300] = torch.cat([edge, h + edge]).repeat(24)[:288]
        depth = torch.rand(n, generator=gen, dtype=torch.float64) * 5 + 0.1
        depth[:50] = 0.2 + torch.linspace(-1e-6, 1e-6, 50, dtype=torch.float64)  # at the near plane
        parts.append(_points_at_pixels(cam, torch.stack([u, v], -1).to(torch.float64), depth))
    parts.append(torch.tensor([[1e4, -2e4, 3e3], [0.0, 0.0, -7.0]], dtype=torch.float64))
    means = torch.cat(parts).to(dtype)
    expected = scores.projected_counts_reference(means, cams)
    assert expected.min() > 0 and expected.max() < means.shape[0]
    for block, threads in ((None, 1), (333, 2), (7, 3)):
        assert torch.equal(scores.projected_counts(means, cams, block=block, threads=threads), expected)
    from nbv import camera_shares

    monkeypatch.setattr(camera_shares, "FORK_MIN_PAIRS", 0)  # the shares in forked processes (on Linux)
    assert torch.equal(scores.projected_counts(means, cams, block=333, threads=3), expected)
    assert scores.projected_counts(means, cams, at_most=1).tolist() == [1, 1, 1]
    capped = scores.projected_counts(means, cams, at_most=500, block=64)
    assert torch.equal(capped, expected.clamp_max(500))
    cluster = (torch.rand(300, 3, generator=gen, dtype=torch.float64) * 0.2).to(dtype)  # all surely inside cams[0]
    assert scores.projected_counts(cluster, cams[:1], block=64).tolist() == [300]
    broken = means.clone()
    broken[0, 0] = math.nan  # no bound holds: every centre takes the float64 test
    assert torch.equal(scores.projected_counts(broken, cams), scores.projected_counts_reference(broken, cams))
    assert scores.projected_counts(broken, cams, at_most=3).tolist() == [3, 3, 3]
    assert torch.equal(scores.projected_counts(means, cams, 0.0), scores.projected_counts_reference(means, cams, 0.0))


def test_unoccluded_hides_what_is_behind_the_surface():
    from recon.gaussians import GaussianSet
    from recon.render import render

    means = torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.6, 0.0, -1.0], [0.0, 0.0, 0.05]])
    g = GaussianSet.from_points(means, scale=torch.tensor([0.15, 0.15, 0.15, 0.05]), opacity=0.99)
    cam = Camera.look_at((0, 0, 3), (0, 0, 0), (0, 1, 0), 48, 48, math.radians(50))
    out = render(g, cam, 1.0)
    assert out.visible.all()  # the renderer's visibility is frustum culling only
    reach = 3 * g.max_radii().double()
    fast = scores.unoccluded(g.means, reach, cam, out)
    assert fast.tolist() == scores.unoccluded_reference(g.means, reach, cam, out)
    # the front blob and the one just in front of it are seen, the one straight behind is hidden, the one
    # behind but off to the side (outside the front blob's footprint) is seen
    assert fast.tolist() == [True, False, True, True]


# ---- scores from the projection alone ---------------------------------------------------------------------
def _scene(n: int = 400, seed: int = 0, dtype=torch.float32):
    g, cams, values = random_scene(n, seed, dtype)
    cams.append(Camera.look_at((0, 0, 0.4), (0, 0, 3), (0, 1, 0), 30, 30, math.radians(60), name="inside"))
    return g, cams, values


def test_view_scores_take_projected_radii_and_per_view_sizes():
    from recon.projection import project_visibility

    g, cams, metric = _scene()
    radii, visible = project_visibility(g, cams)
    sizes = [(c.height, c.width) for c in cams]
    from_pair = scores.view_scores(metric, (radii, visible), image_size=sizes)
    ref = [
        scores.view_scores_reference(metric, radii[k : k + 1], visible[k : k + 1], h, w)[0]
        for k, (h, w) in enumerate(sizes)
    ]
    assert torch.allclose(from_pair, torch.tensor(ref, dtype=torch.float64), rtol=1e-12, atol=0)
    assert torch.allclose(scores.view_scores(metric, radii, image_size=sizes), from_pair, rtol=1e-15, atol=0)
    with pytest.raises(ValueError, match="one per view"):
        scores.view_scores(metric, (radii, visible), image_size=sizes[:2])
    with pytest.raises(ValueError, match="one shape"):
        scores.view_scores(metric, (radii, visible[:2]), image_size=sizes)


@pytest.mark.parametrize("weighted", [True, False])
def test_projected_scores_equal_render_scores(weighted):
    from recon.render import render

    g, cams, metric = _scene()
    renders = [render(g, c, 1.0) for c in cams]
    expected = scores.view_scores(metric, renders, weighted=weighted)
    got = scores.projected_view_scores(metric, g, cams, weighted=weighted, block=97)
    assert torch.allclose(got.scores, expected, rtol=1e-12, atol=0)
    assert got.counted.tolist() == [int(o.visible.sum()) for o in renders]
    assert scores.rank(got.scores).tolist() == scores.rank(expected).tolist()
    assert 0 < int(got.counted[-1]) < g.num  # the camera inside the cloud sees part of it


def test_projected_scores_bad_input():
    g, cams, metric = _scene(50)
    with pytest.raises(ValueError, match="50 Gaussians"):
        scores.projected_view_scores(metric[:10], g, cams)
    bad = metric.clone()
    bad[3] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        scores.projected_view_scores(bad, g, cams)
    with pytest.raises(ValueError, match="DepthBuffer"):
        scores.projected_view_scores(metric, g, cams, depth_buffer=0.5)
    for kwargs in ({"cell_radii": 0.0}, {"depth_bins": 0}, {"min_alpha": 1.5}, {"reach_sigmas": -1.0}):
        with pytest.raises(ValueError, match="DepthBuffer"):
            scores.DepthBuffer(**kwargs)


def _two_layers(opacity: float, front_layers: int = 1, scale: float = 0.06, back_opacity: float = 0.9):
    """A front sheet (z = 0, ``front_layers`` coincident copies) and a back sheet (z = -1) of 15 x 15 Gaussians of
    ``scale`` each (0.086 and 0.06 apart), seen from z = +3; the back sheet is wholly behind the front one."""
    from recon.gaussians import GaussianSet, concat

    t = torch.linspace(-0.6, 0.6, 15)
    x, y = (m.reshape(-1) for m in torch.meshgrid(t, t, indexing="ij"))
    sheet = lambda z, s: torch.stack([x * s, y * s, torch.full_like(x, z)], -1)  # noqa: E731
    front = [GaussianSet.from_points(sheet(0.0, 1.0), scale=scale, opacity=opacity) for _ in range(front_layers)]
    back = GaussianSet.from_points(sheet(-1.0, 0.7), scale=scale, opacity=back_opacity)
    cam = Camera.look_at((0, 0, 3), (0, 0, 0), (0, 1, 0), 48, 48, math.radians(50))
    return concat([*front, back]), cam, front_layers * 225


@pytest.mark.parametrize("opacity, layers", [(0.9, 1), (0.2, 4)])
def test_depth_buffer_hides_the_back_layer(opacity, layers):
    """An opaque front sheet, or four faint coincident ones (opacity 0.2: no single Gaussian is opaque, their
    composite is), hides the back sheet; the render-based depth test agrees on every Gaussian."""
    from recon.render import render

    g, cam, n_front = _two_layers(opacity, layers)
    seen = scores.coarse_unoccluded(g, [cam])[0]
    assert seen[:n_front].all() and not seen[n_front:].any()
    out = render(g, cam, 1.0)
    assert out.visible.all()  # frustum culling alone counts the back layer
    assert seen.tolist() == scores.unoccluded(g.means, 3 * g.max_radii().double(), cam, out).tolist()
    d = torch.ones(g.num, dtype=torch.float64)
    d[n_front:] = 100.0  # the hidden layer carries the divergence
    plain = scores.projected_view_scores(d, g, [cam])
    hidden = scores.projected_view_scores(d, g, [cam], depth_buffer=scores.DepthBuffer())
    assert int(plain.counted[0]) == g.num and int(hidden.counted[0]) == n_front
    front_only = scores.projected_view_scores(torch.where(torch.arange(g.num) < n_front, d, 0.0), g, [cam])
    assert float(hidden.scores[0]) == pytest.approx(float(front_only.scores[0]), rel=1e-12)
    assert float(hidden.scores[0]) < 0.1 * float(plain.scores[0])
    assert torch.allclose(hidden.scores, scores.view_scores(d, [out], visible=seen[None]), rtol=1e-12, atol=0)


def test_depth_buffer_lets_faint_layers_through():
    """Two sparse faint sheets (small Gaussians of opacity 0.1): the rendered alpha stays below 0.5, so the
    render-based test hides nothing; the coarse buffer, whose cells pool a few splats, hides at most 5 %."""
    from recon.render import render

    g, cam, _ = _two_layers(0.1, 1, scale=0.02, back_opacity=0.1)
    out = render(g, cam, 1.0)
    assert float(out.alpha.max()) < 0.5
    assert scores.unoccluded(g.means, 3 * g.max_radii().double(), cam, out).all()
    assert float(scores.coarse_unoccluded(g, [cam])[0].double().mean()) >= 0.95


def test_depth_buffer_matches_its_loop_twin():
    g, cams, _ = _scene(600, seed=3, dtype=torch.float64)
    for config in (scores.DepthBuffer(), scores.DepthBuffer(cell_radii=2.5, depth_bins=3, min_alpha=0.3)):
        fast = scores.coarse_unoccluded(g, cams, config, block=151)
        for k, cam in enumerate(cams):
            assert fast[k].tolist() == scores.coarse_unoccluded_reference(g, cam, config), (config, k)
        visible = torch.stack(
            [torch.as_tensor(scores.coarse_unoccluded_reference(g, c, scores.DepthBuffer(min_alpha=1.0))) for c in cams]
        )  # min_alpha 1: nothing is ever hidden
        assert (fast <= visible).all() and (fast < visible).any()  # the depth test hides some visible ones


def test_score_views_renders_only_the_top_views(tmp_path):
    """`fluidgs score` scores from the projection and renders PNGs of the best --png-top views only."""
    from types import SimpleNamespace

    from nbv.view_scoring import score_views

    g, cams, metric = _scene(200, seed=5)
    result = SimpleNamespace(divergence=metric.numpy(), reached=metric.numpy() > 0)
    idx = [10 + k for k in range(len(cams))]
    rows = score_views(g, cams, idx, result, "max", tmp_path / "top", progress=False, png_top=2, occlusion=False)
    expected = scores.projected_view_scores(metric, g, cams)
    assert [r["score"] for r in rows] == sorted(expected.scores.tolist(), reverse=True)
    assert [r["visible"] for r in rows] == [int(expected.counted[k]) for k in scores.rank(expected.scores)]
    names = sorted(p.name for p in (tmp_path / "top").glob("*.png"))
    assert names == sorted(f"rank{r['rank']:03d}_{r['index']:03d}_{r['name']}.png" for r in rows[:2])
    score_views(g, cams, idx, result, "max", tmp_path / "all", progress=False, png_top=None, occlusion=False)
    assert len(list((tmp_path / "all").glob("*.png"))) == len(cams)
    occluded = score_views(g, cams, idx, result, "max", None, occlusion=True)
    assert all(o["visible"] <= r["visible"] for o in occluded for r in rows if r["index"] == o["index"])


def test_depth_buffer_agrees_with_the_render_on_a_closed_shell():
    """A closed cube shell (the defect test's object): from outside, more than half of it is hidden (the back
    faces, and grazing side faces); the coarse buffer and the render-based test give the same verdict on >= 95 %
    of the visible Gaussians."""
    from recon.gaussians import GaussianSet
    from recon.render import render

    t = torch.linspace(-0.5, 0.5, 13)
    a, b = (m.reshape(-1) for m in torch.meshgrid(t, t, indexing="ij"))
    faces = []
    for axis in range(3):
        for side in (-0.5, 0.5):
            p = torch.zeros(len(a), 3)
            p[:, axis] = side
            p[:, [k for k in range(3) if k != axis]] = torch.stack([a, b], -1)
            faces.append(p)
    g = GaussianSet.from_points(torch.unique(torch.cat(faces), dim=0), scale=0.7 / 12, opacity=0.9)
    cams = [
        Camera.look_at((2.5 * math.cos(x), 0.2, 2.5 * math.sin(x)), (0, 0, 0), (0, 1, 0), 64, 64, math.radians(45))
        for x in (2 * math.pi * k / 8 for k in range(8))
    ]
    outs = [render(g, c, 1.0) for c in cams]
    by_render = torch.stack(
        [scores.unoccluded(g.means, 3 * g.max_radii().double(), c, o) for c, o in zip(cams, outs, strict=True)]
    )
    coarse = scores.coarse_unoccluded(g, cams)
    visible = torch.stack([o.visible for o in outs])
    assert 0.4 < float((visible & ~by_render).sum() / visible.sum()) < 0.8
    assert float((coarse == by_render)[visible].double().mean()) >= 0.95


def test_bench_views_smoke(tmp_path, capsys):
    import json

    from apps import cli
    from recon.formats.ply import save_gaussians

    g, cams, _ = _scene(300, seed=7)
    ply = save_gaussians(g, tmp_path / "set.ply")
    frames = [{"file_path": f"./{c.name}", "transform_matrix": c.opengl_c2w().tolist()} for c in cams[:4]]
    cameras = tmp_path / "transforms.json"
    cameras.write_text(json.dumps({"camera_angle_x": math.radians(55), "w": 40, "h": 30, "frames": frames}))
    out = tmp_path / "bench.json"
    assert (
        cli.main(
            [
                "bench",
                "views",
                "--gaussians",
                str(ply),
                "--cameras",
                str(cameras),
                "--count",
                "1000",
                "--views",
                "3",
                "--width",
                "32",
                "--occlusion",
                "--json",
                str(out),
            ]
        )
        == 0
    )
    text = capsys.readouterr().out
    assert "identical order: True" in text and "radii equal to the renderer's in every view: True" in text
    report = json.loads(out.read_text())
    assert report["ranking"]["spearman"] == pytest.approx(1.0) and report["timing"]["gaussians"] == 1000
    assert 0.0 <= report["ranking"]["occlusion"]["verdict_agreement"] <= 1.0
    assert "M Gaussian-views/s" in text and text.count("same counts: True") == 2  # frustum and depth test
    assert [r["depth_test"] for r in report["timing"]["reference"]] == [False, True]
    assert all(r["max_relative_difference"] < 1e-12 and r["views"] == 3 for r in report["timing"]["reference"])
    with pytest.raises(SystemExit) as refused:  # --count is bounded when parsed (apps.options.numbers): a usage error
        cli.main(["bench", "views", "--gaussians", str(ply), "--count", "0", "--no-ranking"])
    assert refused.value.code == 2


def test_time_projected_scores_figures():
    """The timing figures are consistent: counts as asked, per-view and per-pair times derived from the total."""
    import numpy as np

    from nbv.bench.score_agreement import time_projected_scores

    g, _, _ = _scene(200, seed=3)
    t = time_projected_scores(
        g,
        np.linspace(0.1, 1.0, 200),
        count=500,
        views=4,
        width=24,
        seed=1,
        occlusion=True,
        device=torch.device("cpu"),
        threads=2,
        reference_views=2,
    )
    assert (t["gaussians"], t["views"], t["width"], t["height"], t["threads"]) == (500, 4, 24, 18, 2)
    assert t["gaussian_views_per_s"] == pytest.approx(4 * 500 / t["total_s"])
    assert t["occlusion_gaussian_views_per_s"] == pytest.approx(4 * 500 / t["occlusion_total_s"])
    assert [r["views"] for r in t["reference"]] == [2, 2] and all(r["counted_equal"] for r in t["reference"])
    assert t["per_view_ms"] == pytest.approx(1e3 * t["total_s"] / 4)
    assert t["ns_per_pair"] == pytest.approx(1e9 * t["total_s"] / (4 * 500))
    assert 0.0 < t["visible_fraction"] <= 1.0 and t["peak_rss_mib"] >= t["rss_before_mib"] > 0
    assert t["occlusion_total_s"] > 0


# ---- the fast projected scores against their one-thread twin ----------------------------------------------------
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("occlusion", [False, True])
@pytest.mark.parametrize("weighted", [True, False])
@pytest.mark.parametrize("processes", [False, True])
def test_fast_path_equals_its_twin(dtype, occlusion, weighted, processes, monkeypatch):
    """Counted Gaussians and seen flags exactly; S(T) and A(T) exactly without the depth test (the same block sums
    in the same order), to the float64 summation order with it (the twin sums each view in one dot product); the
    cameras' shares on threads and, on Linux, in forked processes (nbv.camera_shares)."""
    from nbv import camera_shares

    monkeypatch.setattr(camera_shares, "FORK_MIN_PAIRS", 0 if processes else 2**62)
    g, cams, metric = _scene(500, seed=4, dtype=dtype)
    configs = (
        [scores.DepthBuffer(), scores.DepthBuffer(cell_radii=2.5, depth_bins=3, min_alpha=0.3)] if occlusion else [None]
    )
    for config in configs:
        ref = scores.projected_view_scores_reference(
            metric, g, cams, weighted=weighted, depth_buffer=config, block=97, centres=True
        )
        assert 0 < int(ref.counted.min()) and int(ref.counted.max()) <= g.num
        assert torch.equal(ref.centres, scores.projected_counts_reference(g.means, cams))
        for threads in (1, 2, 3, 8):
            got = scores.projected_view_scores(
                metric, g, cams, weighted=weighted, depth_buffer=config, block=97, threads=threads, centres=True
            )
            assert got.counted.tolist() == ref.counted.tolist(), (config, threads)
            assert torch.equal(got.centres, ref.centres), (config, threads)
            assert got.seen.dtype == torch.bool and torch.equal(got.seen, ref.seen)
            if config is None:
                assert torch.equal(got.scores, ref.scores) and torch.equal(got.coverage, ref.coverage)
            else:
                assert torch.allclose(got.scores, ref.scores, rtol=1e-12, atol=0)
                assert torch.allclose(got.coverage, ref.coverage, rtol=1e-12, atol=0)


def test_unhidden_radii_equal_the_masked_fill():
    """The arithmetic verdict of the depth-tested view is the comparison's, with NaN and infinite depths and limits."""
    from nbv.projected_scores import _unhidden_radii

    gen = torch.Generator().manual_seed(2)
    radii = torch.randint(0, 9, (400,), generator=gen).float()
    depths, limits = torch.rand(400, generator=gen) * 3, torch.rand(400, generator=gen) * 3
    limits[::5] = depths[::5]  # equal: not hidden
    depths[1::7], limits[2::11], limits[3::13], depths[4::17] = math.nan, math.nan, math.inf, -math.inf
    expected = radii.masked_fill(depths > limits, 0.0)
    assert torch.equal(_unhidden_radii(radii, depths, limits), expected)
    assert 0 < int((expected == 0).sum() - (radii == 0).sum()) < 400


def test_depth_tested_view_hides_what_the_whole_array_test_hides():
    """Per view, the Gaussians counted with the depth test are those of :func:`coarse_unoccluded` (the test on
    whole arrays), and some visible ones are hidden."""
    g, cams, _ = _scene(600, seed=3, dtype=torch.float64)
    ones = torch.ones(g.num, dtype=torch.float64)
    config = scores.DepthBuffer()
    counted = scores.projected_view_scores(ones, g, cams, weighted=False, depth_buffer=config, block=131, threads=2)
    whole = scores.coarse_unoccluded(g, cams, config)
    assert counted.counted.tolist() == whole.sum(1).tolist()
    assert counted.scores.tolist() == whole.sum(1).double().tolist()  # unweighted, M = 1: S(T) is the count
    radii, _ = project_visibility_reference(g, cams)
    assert (whole.sum(1) < (radii > 0).sum(1)).any()


def test_radii_are_the_renderers():
    """Unweighted, M_g = one-hot: S(T) says whether g counts; weighted, A(T) of one Gaussian is pi R^2 / (H W) with
    R the renderer's radius, in every camera and with every thread count."""
    g, cams, _ = _scene(40, seed=5)
    radii, _ = project_visibility_reference(g, cams)
    for i in range(0, g.num, 7):
        one = torch.zeros(g.num, dtype=torch.float64)
        one[i] = 1.0
        got = scores.projected_view_scores(one, g, cams, threads=2)
        expected = [
            min(math.pi * float(r) ** 2 / (c.width * c.height), 1.0) for r, c in zip(radii[:, i], cams, strict=True)
        ]
        assert got.scores.tolist() == pytest.approx(expected, rel=1e-15, abs=0)


def test_threads_bad_input_and_a_view_of_nothing():
    g, cams, metric = _scene(50)
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="threads"):
            scores.projected_view_scores(metric, g, cams, threads=bad)
    away = Camera.look_at((0, 0, 5), (0, 0, 10), (0, 1, 0), 16, 16, math.radians(40))  # looks away from the set
    for config in (None, scores.DepthBuffer()):
        got = scores.projected_view_scores(metric, g, [away, cams[0]], depth_buffer=config, threads=2)
        assert float(got.scores[0]) == 0.0 and int(got.counted[0]) == 0 and float(got.coverage[0]) == 0.0
        assert int(got.counted[1]) > 0
