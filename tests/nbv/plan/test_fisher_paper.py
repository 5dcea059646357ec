"""FisherRF against its paper (Jiang, Lei, Daniilidis, ECCV 2024) and its public 3DGS code, from the mathematics.

The paper's H of a view is the Gauss-Newton / Fisher matrix J^T J of the rendered image under unit pixel noise,
kept diagonal; its code squares, per (pixel, Gaussian) pair, the gradient of the pixel's channel sum with respect to
the rasterizer's inputs (means, activated scales and opacities, raw SH) and lets autograd carry that square through
the activations exp (scales) and sigmoid (opacity) *once*, i.e. with the factor d act / d raw and not its square.
Ours is the diagonal of J^T J in the trainer's own parameters (log scales, opacity logits): the factor squared.
These tests pin that choice (and show that it differs from the public code's factor, so they can fail), the
acquisition as the trace of H_c (H_train + lambda I)^-1 with dense matrices, and that the planner differentiates only
the SH bands the trainer fits (FisherRF's rasterizer renders the active SH degree only)."""

import math

import pytest
import torch

from nbv.plan import PlanningContext
from nbv.plan.fisher import FisherPlanner
from nbv.plan.fisher_info import DEFAULT_LAMBDA, FisherConfig, fisher_score, greedy_top_k, view_fisher
from recon.camera import Camera
from recon.datasets import View
from recon.gaussians import GaussianSet
from recon.render import render
from recon.render_reference import render_dense_reference

F64 = torch.float64


def _scene(n=6, seed=0, sh_degree=1, dtype=F64) -> GaussianSet:
    gen = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=gen, dtype=F64) * 2 - 1) * torch.tensor([0.5, 0.5, 0.3], dtype=F64)
    quats = torch.randn(n, 4, generator=gen, dtype=F64)
    log_scales = math.log(0.25) + 0.3 * torch.randn(n, 3, generator=gen, dtype=F64)
    logits = torch.randn(n, generator=gen, dtype=F64)
    sh = 0.4 * torch.randn(n, (sh_degree + 1) ** 2, 3, generator=gen, dtype=F64)
    return GaussianSet(means, quats, log_scales, logits, sh).to(dtype=dtype)


def _camera(eye=(0.3, -0.2, -3.0), size=6) -> Camera:
    return Camera.look_at(eye, (0.0, 0.0, 0.0), (0.0, -1.0, 0.0), size, size, math.radians(50.0))


def _activated_fisher(g: GaussianSet, cam: Camera, background: float) -> dict[str, torch.Tensor]:
    """Brute force: sum over the pixels of (d sum_c C_pc / d x)^2 for the rasterizer's inputs x (scales, opacities)."""
    scales = g.log_scales.exp().clone().requires_grad_(True)
    opac = torch.sigmoid(g.opacity_logits).clone().requires_grad_(True)
    with torch.enable_grad():
        gs = GaussianSet(g.means, g.quats, scales.log(), torch.logit(opac), g.sh)
        image = render_dense_reference(gs, cam, background).image.reshape(-1, 3)
        h = {"scales": torch.zeros_like(scales), "opacities": torch.zeros_like(opac)}
        for p in range(image.shape[0]):
            d_s, d_o = torch.autograd.grad(image[p].sum(), [scales, opac], retain_graph=True)
            h["scales"] += d_s**2
            h["opacities"] += d_o**2
    return h


def test_fisher_is_the_diagonal_of_jtj_in_the_trainers_parameters():
    g, cam = _scene(), _camera()
    h = view_fisher(g, cam, 0.5)  # columns: means 0:3, log_scales 3:6, opacity logit 6, sh 7:
    act = _activated_fisher(g, cam, 0.5)
    assert act["scales"].max() > 1e-2 and act["opacities"].max() > 1e-2  # the scene is seen: not zeros compared
    s, o = g.log_scales.exp(), torch.sigmoid(g.opacity_logits)
    # chain rule of J: d C / d log s = s d C / d s, d C / d logit = o (1 - o) d C / d o; J^T J takes the square
    torch.testing.assert_close(h[:, 3:6], s**2 * act["scales"], rtol=1e-8, atol=1e-12)
    torch.testing.assert_close(h[:, 6], (o * (1 - o)) ** 2 * act["opacities"], rtol=1e-8, atol=1e-12)
    # the public code's factor (d act / d raw once) is a different matrix: the two conventions are distinguishable
    assert not torch.allclose(h[:, 3:6], s * act["scales"], rtol=1e-2)
    assert not torch.allclose(h[:, 6], o * (1 - o) * act["opacities"], rtol=1e-2)


def test_score_is_the_trace_of_candidate_h_times_inverse_regularised_train_h():
    """FisherRF's acquisition tr(H_c (H_train + lambda I)^-1) with dense diagonal matrices, one greedy step later."""
    g = _scene(n=5, seed=4)
    views = [_camera((0.3, -0.2, -3.0)), _camera((3.0, 0.1, 0.2)), _camera((-2.0, 0.5, -2.0))]
    h_train, h_c = view_fisher(g, views[0], 1.0), view_fisher(g, views[1], 1.0)
    eye = torch.eye(h_c.numel(), dtype=F64)
    dense = torch.trace(
        torch.diag(h_c.flatten()) @ torch.linalg.inv(torch.diag(h_train.flatten()) + DEFAULT_LAMBDA * eye)
    )
    assert fisher_score(h_c, h_train) == pytest.approx(float(dense), rel=1e-9)
    # greedy batch: after the pick, H_train grows by the picked view's H (information is additive over views)
    h_next = view_fisher(g, views[2], 1.0)
    both = torch.diag((h_train + h_c).flatten()) + DEFAULT_LAMBDA * eye
    dense_next = torch.trace(torch.diag(h_next.flatten()) @ torch.linalg.inv(both))
    assert fisher_score(h_next, h_train + h_c) == pytest.approx(float(dense_next), rel=1e-9)
    assert fisher_score(h_next, h_train + h_c) < fisher_score(h_next, h_train)


def _context(g: GaussianSet, cams: list[Camera], sh_degree: int | None) -> PlanningContext:
    train_cam = _camera((0.3, -0.2, -3.0), size=10)
    train = [View(train_cam, render(g, train_cam, 1.0).image.detach(), None, "train0")]
    return PlanningContext(g, train, cams, list(range(len(cams))), 1, 10, torch.ones(3), sh_degree=sh_degree)


def test_planner_differentiates_the_sh_bands_the_trainer_fits():
    g = _scene(n=12, seed=7, sh_degree=1, dtype=torch.float32)
    sh = g.sh.clone()
    sh[:, 1:] = 0.0  # the trainer pads the bands it has not activated with zeros and does not update them
    g = GaussianSet(g.means, g.quats, g.log_scales, g.opacity_logits, sh)
    cams = [_camera((3 * math.sin(a), 0.3, -3 * math.cos(a)), size=10) for a in (0.4, 1.2, 2.0, 2.8, 3.6)]
    train = [_camera((0.3, -0.2, -3.0), size=10)]
    active = greedy_top_k(g, cams, train, torch.ones(3), 3, FisherConfig(sh_degree=0))
    stored = greedy_top_k(g, cams, train, torch.ones(3), 3, FisherConfig())
    assert active.scores != pytest.approx(stored.scores, rel=1e-3)  # the zero band's columns do count when included
    order, scores = FisherPlanner().rank(_context(g, cams, 0), 3)
    assert (order, scores) == (active.order, active.scores)
    order, scores = FisherPlanner().rank(_context(g, cams, None), 3)  # no degree given: all stored bands
    assert (order, scores) == (stored.order, stored.scores)
    order, scores = FisherPlanner(FisherConfig(sh_degree=1)).rank(_context(g, cams, 0), 3)  # the config wins
    assert (order, scores) == (stored.order, stored.scores)


def test_context_sh_degree_validation():
    g, cams = _scene(n=3, sh_degree=1, dtype=torch.float32), [_camera(size=4)]
    for bad in (2, -1, True, 1.0):
        with pytest.raises(ValueError, match="sh_degree"):
            PlanningContext(g, [], cams, [0], 0, 10, torch.ones(3), sh_degree=bad)
