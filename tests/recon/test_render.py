"""Tests for recon/render.py and recon/projection.py: the projection on hand-computed cases and against
its per-Gaussian twin, the sparse rasterizer against the dense pixels x Gaussians reference (values and
gradients, with the early-stop and alpha-skip rules triggered), float64 gradients against finite
differences, culling, empty views, background compositing, means2d.grad, input errors, the gsplat
backend (CUDA + gsplat only) and the `fluidgs bench render` smoke test."""

import math

import pytest
import torch

from apps import cli
from recon.camera import Camera
from recon.gaussians import GaussianSet, rgb_to_sh0
from recon.projection import project_gaussians
from recon.render import pair_statistics, render
from recon.render_gsplat import gsplat_available
from recon.render_reference import project_gaussians_reference, render_dense_reference

from helpers.random_scenes import random_blobs

F64 = torch.float64


def _axis_camera(width=64, height=48, focal=50.0, cx=None, cy=None) -> Camera:
    """Camera at the origin looking down +z with OpenCV axes (world = camera frame)."""
    return Camera(
        width,
        height,
        focal,
        focal,
        width / 2 if cx is None else cx,
        height / 2 if cy is None else cy,
        torch.eye(4, dtype=F64),
    )


def _isotropic(points, sigma, opacity=0.5, rgb=(0.2, 0.6, 0.9), dtype=F64) -> GaussianSet:
    pts = torch.as_tensor(points, dtype=dtype).reshape(-1, 3)
    colors = torch.tensor(rgb, dtype=dtype).expand(pts.shape[0], 3)
    return GaussianSet.from_points(pts, colors, scale=sigma, opacity=opacity)


def _random_scene(n, seed, dtype=F64, sh_degree=1, logit_mean=0.0, scale=0.08) -> tuple[GaussianSet, Camera]:
    cam = Camera.look_at((0.3, -0.2, -3.0), (0.0, 0.0, 0.0), (0.0, -1.0, 0.0), 28, 22, math.radians(50))
    return random_blobs(n, seed, (0.8, 0.6, 0.5), scale, 0.4, sh_degree, logit_mean, dtype), cam


# ---- projection ---------------------------------------------------------------------------------------
def test_projection_isotropic_on_axis_hand_computed():
    z, sigma, f = 2.0, 0.05, 50.0
    cam = _axis_camera(focal=f)
    proj = project_gaussians(_isotropic([0.0, 0.0, z], sigma), cam)
    var = sigma**2 * f**2 / z**2 + 0.3
    torch.testing.assert_close(proj.means2d[0], torch.tensor([32.0, 24.0], dtype=F64))
    torch.testing.assert_close(proj.conics[0], torch.tensor([1 / var, 0.0, 1 / var], dtype=F64))
    assert proj.depths[0].item() == pytest.approx(z)
    assert proj.radii[0].item() == math.ceil(3 * math.sqrt(var)) == 5
    # pixel centres i + 0.5 within [32 - 5, 32 + 5]: i = 27 .. 36 (and 19 .. 28 vertically)
    assert proj.boxes[0].tolist() == [27, 19, 36, 28]


def test_projection_off_axis_and_guard_band_hand_computed():
    z, sigma, f = 2.0, 0.05, 50.0
    cam = _axis_camera(focal=f)  # tan(fov_x / 2) = 32 / 50, so the guard band is |x / z| <= 1.3 * 0.64
    for x_over_z in (0.5, 1.5):
        proj = project_gaussians(_isotropic([x_over_z * z, 0.0, z], sigma), cam)
        xc = min(x_over_z, 1.3 * 0.64)
        # J = [[f/z, 0, -f xc/z], [0, f/z, 0]] so J J^T = f^2/z^2 [[1 + xc^2, 0], [0, 1]]
        a = sigma**2 * f**2 / z**2 * (1 + xc**2) + 0.3
        c = sigma**2 * f**2 / z**2 + 0.3
        torch.testing.assert_close(proj.conics[0], torch.tensor([1 / a, 0.0, 1 / c], dtype=F64))
        assert proj.means2d[0, 0].item() == pytest.approx(f * x_over_z + 32.0)
    assert proj.radii[0] == 0  # x/z = 1.5 lands at u = 107, its box misses the 64-px image


def test_projection_matches_twin_and_camera_project():
    gaussians, cam = _random_scene(40, seed=3)
    fast, slow = project_gaussians(gaussians, cam), project_gaussians_reference(gaussians, cam)
    torch.testing.assert_close(fast.means2d, slow.means2d, rtol=1e-12, atol=1e-9)
    torch.testing.assert_close(fast.conics, slow.conics, rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(fast.depths, slow.depths)
    assert torch.equal(fast.radii, slow.radii)
    visible = fast.radii > 0
    assert visible.sum() > 20
    assert torch.equal(fast.boxes[visible], slow.boxes[visible])
    uv, depth = cam.project(gaussians.means)
    torch.testing.assert_close(fast.means2d, uv, rtol=1e-12, atol=1e-9)
    torch.testing.assert_close(fast.depths, depth)


def test_culling_behind_near_plane_and_outside():
    cam = _axis_camera()
    points = [[0.0, 0.0, 2.0], [0.0, 0.0, -1.0], [0.0, 0.0, 0.15], [5.0, 0.0, 2.0]]
    gaussians = _isotropic(points, 0.05, opacity=0.8)
    out = render(gaussians, cam, 0.25)
    assert out.radii.dtype == torch.int32
    assert out.radii[0] > 0 and out.visible.tolist() == [True, False, False, False]
    assert out.radii[1:].tolist() == [0, 0, 0]
    alone = render(gaussians.subset(torch.tensor([0])), cam, 0.25)
    torch.testing.assert_close(out.image, alone.image, rtol=0, atol=0)


# ---- compositing --------------------------------------------------------------------------------------
def test_background_and_single_gaussian_hand_computed():
    cam = _axis_camera(cx=32.5, cy=24.5)  # the mean projects onto the centre of pixel (32, 24)
    o, z, rgb, bg = 0.6, 2.0, torch.tensor([0.2, 0.6, 0.9], dtype=F64), torch.tensor([1.0, 0.5, 0.0], dtype=F64)
    out = render(_isotropic([0.0, 0.0, z], 0.05, opacity=o, rgb=rgb.tolist()), cam, bg)
    torch.testing.assert_close(out.image[24, 32], o * rgb + (1 - o) * bg)
    assert out.alpha[24, 32].item() == pytest.approx(o)
    assert out.depth[24, 32].item() == pytest.approx(o * z)
    # outside the 3-sigma box: exactly the background, zero alpha and depth
    far = torch.ones(48, 64, dtype=torch.bool)
    far[24 - 5 : 24 + 6, 32 - 5 : 32 + 6] = False
    assert torch.equal(out.image[far], bg.expand(int(far.sum()), 3))
    assert (out.alpha[far] == 0).all() and (out.depth[far] == 0).all()


def test_empty_view_returns_background_and_backpropagates():
    cam = _axis_camera()
    gaussians = _isotropic([[0.0, 0.0, -2.0], [0.0, 0.0, 0.1]], 0.05).map(lambda t: t.requires_grad_(True))
    out = render(gaussians, cam, torch.tensor([0.1, 0.2, 0.3], dtype=F64))
    assert torch.equal(out.image, torch.tensor([0.1, 0.2, 0.3], dtype=F64).expand(48, 64, 3))
    assert (out.alpha == 0).all() and (out.depth == 0).all() and (out.radii == 0).all() and not out.visible.any()
    out.image.sum().backward()
    assert (gaussians.means.grad == 0).all() and (out.means2d.grad == 0).all()


def test_visible_but_faint_gaussians_composite_nothing():
    cam = _axis_camera()
    faint = _isotropic([[0.0, 0.0, 2.0], [0.1, 0.0, 2.5]], 0.05, opacity=0.003).map(lambda t: t.requires_grad_(True))
    out = render(faint, cam, 0.5)  # every alpha is below 1/255: visible, yet no pair is composited
    assert out.visible.all() and pair_statistics(faint, cam)["pairs"] == 0
    assert (out.image == 0.5).all() and (out.alpha == 0).all()
    out.image.sum().backward()
    assert (faint.opacity_logits.grad == 0).all()


def test_sparse_matches_dense_reference_with_early_stop_and_alpha_skip():
    gaussians, cam = _random_scene(45, seed=7, logit_mean=3.0, scale=0.12)
    stats = pair_statistics(gaussians, cam)
    assert stats["stopped"] > 0 and stats["stopped_pixels"] > 0, stats  # T < 1e-4 early stop happened
    assert stats["skipped_alpha"] > 0, stats  # alpha < 1/255 pairs inside the 3-sigma boxes
    # some composited pairs also hit the alpha <= 0.99 clamp
    assert (torch.sigmoid(gaussians.opacity_logits) > 0.99).any()
    params = [t.requires_grad_(True) for t in gaussians.tensors()]
    bg = torch.tensor([0.3, 0.5, 0.7], dtype=F64)
    fast, slow = render(gaussians, cam, bg), render_dense_reference(gaussians, cam, bg)
    for name in ("image", "alpha", "depth"):
        torch.testing.assert_close(getattr(fast, name), getattr(slow, name), rtol=0, atol=1e-12)
    assert torch.equal(fast.radii, slow.radii)
    weights = torch.rand(22, 28, 3, generator=torch.Generator().manual_seed(0), dtype=F64)

    def loss(out):
        return (out.image * weights).sum() + 0.3 * out.depth.sum() + 0.7 * out.alpha.sum()

    grads_fast = torch.autograd.grad(loss(fast), params + [fast.means2d], retain_graph=True)
    grads_slow = torch.autograd.grad(loss(slow), params + [slow.means2d])
    for name, gf, gs in zip(
        ("means", "quats", "log_scales", "opacity_logits", "sh", "means2d"), grads_fast, grads_slow, strict=True
    ):
        assert gs.abs().max() > 0, name
        torch.testing.assert_close(gf, gs, rtol=1e-9, atol=1e-10, msg=name)


def test_float32_matches_float64_reference():
    gaussians, cam = _random_scene(45, seed=11, logit_mean=1.0)
    ref = render_dense_reference(gaussians, cam, 1.0)
    out = render(gaussians.to(dtype=torch.float32), cam, 1.0)
    assert out.image.dtype == torch.float32
    torch.testing.assert_close(out.image.double(), ref.image, rtol=0, atol=2e-5)
    torch.testing.assert_close(out.depth.double(), ref.depth, rtol=0, atol=1e-4)


def test_gradients_match_finite_differences():
    # three large, semi-transparent Gaussians covering the whole 8 x 8 image: every pair is far above
    # alpha = 1/255 and below 0.99, and T never nears 1e-4, so the render is smooth in all parameters
    cam = Camera.look_at((0.0, 0.0, -3.0), (0.0, 0.0, 0.0), (0.0, -1.0, 0.0), 8, 8, math.radians(15))
    gen = torch.Generator().manual_seed(2)
    means = torch.tensor([[0.05, -0.03, 0.0], [-0.1, 0.08, 0.3], [0.07, 0.1, -0.2]], dtype=F64)
    quats = torch.randn(3, 4, generator=gen, dtype=F64)
    log_scales = torch.log(torch.tensor([[0.5, 0.35, 0.4], [0.45, 0.6, 0.3], [0.3, 0.4, 0.55]], dtype=F64))
    logits = torch.tensor([-0.5, 0.3, 0.0], dtype=F64)
    sh = torch.zeros(3, 4, 3, dtype=F64)
    sh[:, 0] = rgb_to_sh0(torch.rand(3, 3, generator=gen, dtype=F64) * 0.6 + 0.2)
    sh[:, 1:] = 0.1 * torch.randn(3, 3, 3, generator=gen, dtype=F64)
    bg = torch.tensor([0.2, 0.4, 0.6], dtype=F64)

    def fn(*tensors):
        out = render(GaussianSet(*tensors[:5]), cam, tensors[5])
        return out.image, out.alpha, out.depth

    inputs = tuple(t.clone().requires_grad_(True) for t in (means, quats, log_scales, logits, sh, bg))
    stats = pair_statistics(GaussianSet(*inputs[:5]), cam)
    assert stats["pairs"] == stats["candidates"] == 3 * 64 and stats["stopped"] == 0, stats
    alphas = render(GaussianSet(*inputs[:5]), cam, bg).alpha
    assert 0.1 < alphas.min() and alphas.max() < 0.9
    assert torch.autograd.gradcheck(fn, inputs, eps=1e-6, atol=1e-6, rtol=1e-5)


def test_means2d_grad_is_populated():
    gaussians, cam = _random_scene(30, seed=5, dtype=torch.float32)
    gaussians = gaussians.map(lambda t: t.requires_grad_(True))
    out = render(gaussians, cam, 1.0)
    assert not out.means2d.is_leaf
    out.image.mean().backward()
    grad = out.means2d.grad
    assert grad is not None and grad.shape == (30, 2)
    assert (grad[out.visible].abs().sum(-1) > 0).all()
    assert (grad[~out.visible] == 0).all()
    with torch.no_grad():
        assert not render(gaussians, cam).means2d.requires_grad


def test_sh_degree_selects_bands():
    gaussians, cam = _random_scene(20, seed=9, sh_degree=3)
    dc = render(gaussians, cam, sh_degree=0)
    truncated = render(gaussians.with_sh_degree(0), cam)
    torch.testing.assert_close(dc.image, truncated.image)
    assert not torch.allclose(dc.image, render(gaussians, cam).image)


# ---- input checks -------------------------------------------------------------------------------------
def test_bad_inputs_raise_value_errors():
    gaussians, cam = _random_scene(5, seed=1)
    with pytest.raises(ValueError, match=r"shape \(3,\), got \(4,\)"):
        render(gaussians, cam, torch.zeros(4, dtype=F64))
    with pytest.raises(ValueError, match="sh_degree"):
        render(gaussians, cam, sh_degree=2)
    with pytest.raises(ValueError, match="backend"):
        render(gaussians, cam, backend="opengl")
    with pytest.raises(ValueError, match="float32 or float64"):
        render(gaussians.to(dtype=torch.float16), cam)
    with pytest.raises(ValueError, match="camera must be"):
        render(gaussians, "front")
    broken = gaussians.clone()
    broken.means[2, 0] = float("nan")
    with pytest.raises(ValueError, match="means has NaN"):
        render(broken, cam)
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="gsplat"):
            render(gaussians, cam, backend="gsplat")


# ---- gsplat backend -----------------------------------------------------------------------------------
@pytest.mark.skipif(not gsplat_available(), reason="the gsplat backend needs CUDA and the gsplat package")
def test_gsplat_backend_matches_torch():
    gaussians, cam = _random_scene(200, seed=4, dtype=torch.float32, sh_degree=3)
    gaussians = gaussians.to("cuda").map(lambda t: t.requires_grad_(True))
    ours = render(gaussians, cam, 0.5, backend="torch")
    theirs = render(gaussians, cam, 0.5, backend="gsplat")
    assert (ours.visible == theirs.visible).float().mean() > 0.98
    both = ours.visible & theirs.visible
    assert (ours.radii - theirs.radii)[both].abs().max() <= 1  # gsplat floors the eigenvalue gap at 0.01
    # alpha clamps (0.99 vs 0.999) and tile-bounded footprints differ slightly
    torch.testing.assert_close(theirs.image, ours.image, rtol=0, atol=2e-2)
    torch.testing.assert_close(theirs.alpha, ours.alpha, rtol=0, atol=2e-2)
    assert (theirs.image - ours.image).abs().mean() < 2e-3
    theirs.image.sum().backward()
    assert theirs.means2d.grad is not None and theirs.means2d.grad[theirs.visible].abs().sum() > 0


# ---- benchmark command --------------------------------------------------------------------------------
def test_bench_render_smoke(capsys, tmp_path):
    out_json = tmp_path / "bench.json"
    assert cli.main(["bench", "render", "--sizes", "300@32x24", "--repeats", "1", "--json", str(out_json)]) == 0
    text = capsys.readouterr().out
    assert "300 Gaussians @ 32x24" in text and "forward+backward" in text and "reference workload" in text
    assert out_json.exists()
    assert cli.main(["bench", "render", "--sizes", "300by32"]) == 2


def test_bench_scene_and_time_case():
    """The benchmark scene is seeded and its parameters take gradients; a case reports consistent figures."""
    from recon.render_bench import bench_scene, time_case

    g1, cam = bench_scene(200, 40, 30, seed=3, device=torch.device("cpu"))
    g2, _ = bench_scene(200, 40, 30, seed=3, device=torch.device("cpu"))
    assert torch.equal(g1.means, g2.means) and g1.means.requires_grad and g1.sh.shape == (200, 16, 3)
    assert g1.means.min() >= -1.0 and g1.means.max() <= 1.0 and (cam.width, cam.height) == (40, 30)
    r = time_case(200, 40, 30, seed=3, repeats=2, backend="torch", device=torch.device("cpu"), target_ms=5.0)
    assert r["pixels"] == 1200 and r["target_ms"] == 5.0 and 0 < r["visible"] <= 200
    assert 0 < r["forward_ms"] <= r["forward_backward_ms"] and r["pairs"] <= r["candidate_pairs"]
    assert r["mean_radius_px"] > 0


def test_render_layers_equal_separate_renders_bit_for_bit():
    from nbv.heatmap import colored_gaussians, composited_values, uncertainty_image, value_layer
    from recon.render import render_layers

    gen = torch.Generator().manual_seed(3)
    n = 400
    g = GaussianSet(
        torch.randn(n, 3, generator=gen) * 0.4,
        torch.nn.functional.normalize(torch.randn(n, 4, generator=gen), dim=1),
        torch.randn(n, 3, generator=gen) * 0.3 - 3.0,
        torch.randn(n, 1, generator=gen).squeeze(1),
        torch.randn(n, 16, 3, generator=gen) * 0.2,
    )
    cam = Camera.look_at((0.3, 0.2, -3.0), (0, 0, 0), (0, -1, 0), 48, 40, math.radians(50))
    values = torch.rand(n, generator=gen).double()
    heat = colored_gaussians(g, values)
    over, top = value_layer(g, (values > 0.7).double())
    outs = render_layers([g, heat, over], cam, [1.0, 0.0, 0.0])
    for out, (layer, bg) in zip(outs, [(g, 1.0), (heat, 0.0), (over, 0.0)], strict=True):
        ref = render(layer, cam, bg)
        for name in ("image", "alpha", "depth", "radii"):
            assert torch.equal(getattr(out, name), getattr(ref, name)), name
    share, alpha = composited_values(outs[2], top)
    ref_share, ref_alpha = uncertainty_image(g, cam, (values > 0.7).double())
    assert (share == ref_share).all() and (alpha == ref_alpha).all()
    moved = GaussianSet(g.means + 0.01, g.quats, g.log_scales, g.opacity_logits, g.sh)
    with pytest.raises(ValueError, match="share means"):
        render_layers([g, moved], cam, [1.0, 1.0])
