"""Tests for nbv/plan/variance_model.py: the prior/posterior formulas on a hand-built 1-pixel, 2-Gaussian case against
hand arithmetic; the vectorised score against its pixel-loop twin on a real view; the pair-weight variance
render against rendering v as a colour; that a view seeing Gaussians with larger v scores higher; that the
NLL fit lowers the loss and raises v where the render error is larger; and config/input validation."""

import math

import pytest
import torch

from nbv.plan.variance_model import (
    VarianceConfig,
    fit_variances,
    nll_loss,
    rendered_variance,
    rendered_variance_reference,
    variance_reduction,
    variance_reduction_reference,
    variance_scores,
)
from recon.camera import Camera
from recon.datasets import View
from recon.gaussians import GaussianSet
from recon.pairs import ViewPairs, view_pairs
from recon.render import render

F64 = torch.float64


def _two_clusters(dtype=F64) -> GaussianSet:
    """Six Gaussians around x = -1 (ids 0-2) and six around x = +1 (ids 3-5)."""
    gen = torch.Generator().manual_seed(1)
    offsets = 0.15 * torch.randn(12, 3, generator=gen, dtype=F64)
    centres = torch.tensor([[-1.0, 0.0, 0.0]] * 6 + [[1.0, 0.0, 0.0]] * 6, dtype=F64)
    colors = torch.rand(12, 3, generator=gen, dtype=F64)
    return GaussianSet.from_points(centres + offsets, colors, scale=0.12, opacity=0.7).to(dtype=dtype)


def _camera_at(x: float, size=12) -> Camera:
    return Camera.look_at((x, 0.0, -2.5), (x, 0.0, 0.0), (0.0, -1.0, 0.0), size, size, math.radians(40))


def test_prior_posterior_by_hand_one_pixel_two_gaussians():
    alpha = torch.tensor([0.5, 0.4], dtype=F64)
    trans = torch.tensor([1.0, 0.5], dtype=F64)
    pairs = ViewPairs(
        pixels=torch.tensor([0, 0], dtype=torch.int32),
        gaussians=torch.tensor([0, 1], dtype=torch.int32),
        alpha=alpha,
        transmittance=trans,
        live=torch.tensor([True, True]),
        weights=alpha * trans,
        width=1,
        height=1,
    )
    v = torch.tensor([0.2, 0.05], dtype=F64)
    w1, w2 = 0.5 * (1.0 * (1 - 0.5)), 0.4 * (0.5 * (1 - 0.4))  # alpha x transmittance after the Gaussian
    prior = 1e-4 + 0.2 * w1**2 + 0.05 * w2**2
    posterior = w1**2 / (1 / 0.2 + w1**2 / prior) + w2**2 / (1 / 0.05 + w2**2 / prior)
    assert (w1, w2) == pytest.approx((0.25, 0.12))
    assert float(variance_reduction(pairs, v)) == pytest.approx(prior - posterior, rel=1e-12)
    assert variance_reduction_reference(pairs, v) == pytest.approx(prior - posterior, rel=1e-12)
    # a pair after the early stop contributes nothing
    stopped = ViewPairs(pairs.pixels, pairs.gaussians, alpha, trans, torch.tensor([True, False]), pairs.weights, 1, 1)
    prior1 = 1e-4 + 0.2 * w1**2
    assert float(variance_reduction(stopped, v)) == pytest.approx(prior1 - w1**2 / (5.0 + w1**2 / prior1), rel=1e-12)


def test_variance_reduction_matches_loop_twin_on_a_view():
    g = _two_clusters()
    cam = _camera_at(-0.5, 10)
    pairs = view_pairs(g, cam)
    v = torch.linspace(0.01, 0.3, g.num, dtype=F64)
    assert pairs.num > 50
    assert float(variance_reduction(pairs, v)) == pytest.approx(variance_reduction_reference(pairs, v), rel=1e-10)


def test_rendered_variance_matches_render_of_v_as_colour():
    g = _two_clusters()
    cam = _camera_at(0.0, 16)
    v = torch.linspace(0.05, 0.4, g.num, dtype=F64)
    fast = rendered_variance(view_pairs(g, cam), v)
    slow = rendered_variance_reference(g, cam, v)
    assert slow.max() > 0.05
    torch.testing.assert_close(fast, slow, rtol=1e-10, atol=1e-12)


def test_view_seeing_larger_variance_scores_higher():
    g = _two_clusters()
    left, right = _camera_at(-1.0), _camera_at(1.0)
    high_left = torch.tensor([0.5] * 6 + [0.01] * 6, dtype=F64)
    s_left, s_right = variance_scores(g, [left, right], high_left)
    assert s_left > s_right
    s_left, s_right = variance_scores(g, [left, right], high_left.flip(0))
    assert s_right > s_left


def test_nll_fit_lowers_the_loss_and_raises_v_where_the_error_is_larger():
    g = _two_clusters()
    cams = [_camera_at(-1.0, 16), _camera_at(1.0, 16), _camera_at(0.0, 16)]
    views = []
    for i, cam in enumerate(cams):
        image = render(g, cam, 1.0).image.detach()
        # the captured image differs from the render strongly on the left half of the scene, slightly elsewhere
        gen = torch.Generator().manual_seed(10 + i)
        noise = torch.randn(image.shape, generator=gen, dtype=F64)
        left = render(g.subset(torch.arange(6)), cam, 0.0).image.detach().sum(-1, keepdim=True) > 0.05
        views.append(View(cam, (image + torch.where(left, 0.3, 0.01) * noise).clamp(0, 1), None, f"v{i}"))
    config = VarianceConfig(iterations=150, learning_rate=0.1)
    fit = fit_variances(g, views, 1.0, config)
    assert fit.loss_after < fit.loss_before
    # the fit's merged-strip loss is the per-view loss of the module docstring
    errors = [((render(g, v.camera, 1.0).image - v.image) ** 2).sum(-1).reshape(-1) for v in views]
    start = torch.full((g.num,), math.log(config.initial_variance), dtype=F64)
    per_view = nll_loss(start, [view_pairs(g, v.camera) for v in views], errors, config.variance_floor)
    assert fit.loss_before == pytest.approx(float(per_view), rel=1e-12)
    v = fit.variances
    assert v[:6].mean() > 5 * v[6:].mean()
    # warm start from the fit: zero iterations keep v, and the loss is the fitted one
    again = fit_variances(g, views, 1.0, VarianceConfig(iterations=0), fit.log_variances)
    torch.testing.assert_close(again.log_variances, fit.log_variances)
    assert again.loss_before == pytest.approx(fit.loss_after)


def test_nll_loss_formula_by_hand():
    alpha = torch.tensor([0.5], dtype=F64)
    pairs = ViewPairs(
        torch.tensor([0], dtype=torch.int32),
        torch.tensor([0], dtype=torch.int32),
        alpha,
        torch.ones(1, dtype=F64),
        torch.tensor([True]),
        alpha.clone(),
        2,
        1,
    )
    err = torch.tensor([0.04, 0.09], dtype=F64)
    loss = nll_loss(torch.log(torch.tensor([0.2], dtype=F64)), [pairs], [err], 1e-3)
    s0, s1 = 0.5 * 0.2 + 1e-3, 1e-3  # pixel 1 sees no Gaussian
    expected = 0.5 * ((0.04 / (2 * s0) + 0.5 * math.log(s0)) + (0.09 / (2 * s1) + 0.5 * math.log(s1)))
    assert float(loss) == pytest.approx(expected, rel=1e-12)


def test_variance_config_and_input_validation():
    with pytest.raises(ValueError, match="iterations"):
        VarianceConfig(iterations=-1)
    with pytest.raises(ValueError, match="initial_variance"):
        VarianceConfig(initial_variance=0.0)
    g = _two_clusters()
    cam = _camera_at(0.0)
    with pytest.raises(ValueError, match="no image"):
        fit_variances(g, [View(cam, None, None, "x")], 1.0)
    with pytest.raises(ValueError, match="init_log_variances"):
        fit_variances(g, [], 1.0, VarianceConfig(), torch.zeros(3, dtype=F64))
    with pytest.raises(ValueError, match="one per Gaussian"):
        variance_scores(g, [cam], torch.ones(3, dtype=F64))
