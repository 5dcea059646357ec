"""Tests for nbv/plan/fisher_info.py and recon/pairs.py: the per-pixel Fisher diagonal against brute force (one backward
pass per pixel through the dense reference renderer) in float64, with and without rotations, with the early
stop triggered; that the naive square of the summed-image gradient differs (so the twin test can fail); the
per-pair compositing quantities against the rendered image and opacity; the closed-form per-pair gradients
against their autograd twin (bit for bit); the fast H against the earlier computation (a twin kept here: per-pair
copies through autograd, nine backward passes, every Gram entry formed) bit for bit, with the greedy list and the
scores of a fixture pinned; the score formula by hand; the lazy greedy top-K against the plain greedy twin, with
and without the H cache; and config validation."""

import math

import pytest
import torch

from nbv.plan.fisher_info import (
    FisherConfig,
    _block_matrix,
    _degree,
    _leaf_set,
    _parameter_leaves,
    fisher_score,
    greedy_top_k,
    greedy_top_k_reference,
    parameter_count,
    view_fisher,
    view_fisher_reference,
)
from recon.camera import Camera
from recon.gaussians import GaussianSet
from recon.pairs import pair_attribute_gradients, pair_attribute_gradients_reference, view_pairs
from recon.projection import project_gaussians
from recon.render import gaussian_colors, render

from helpers.random_scenes import random_blobs

F64 = torch.float64


def _scene(n=6, seed=0, sh_degree=1, logit_mean=0.0, scale=0.25, dtype=F64) -> GaussianSet:
    return random_blobs(n, seed, (0.5, 0.5, 0.3), scale, 0.3, sh_degree, logit_mean, dtype)


def _camera(eye=(0.3, -0.2, -3.0), size=6, fov_deg=50.0) -> Camera:
    return Camera.look_at(eye, (0.0, 0.0, 0.0), (0.0, -1.0, 0.0), size, size, math.radians(fov_deg))


def _ring(count, size=10, radius=3.0):
    return [
        _camera(
            (radius * math.sin(2 * math.pi * i / count), -0.4 + 0.2 * i, -radius * math.cos(2 * math.pi * i / count)),
            size,
        )
        for i in range(count)
    ]


@pytest.mark.parametrize("include_rotations", [False, True])
def test_view_fisher_matches_brute_force_per_pixel_backward(include_rotations):
    g, cam = _scene(), _camera()
    background = torch.tensor([0.3, 0.5, 0.7], dtype=F64)
    fast = view_fisher(g, cam, background, include_rotations=include_rotations)
    slow = view_fisher_reference(g, cam, background, include_rotations=include_rotations)
    assert fast.shape == (6, parameter_count(1, include_rotations)) == slow.shape
    assert slow.abs().max() > 1e-2  # the scene is seen: the comparison is not between zeros
    torch.testing.assert_close(fast, slow, rtol=1e-8, atol=1e-10)


def test_view_fisher_matches_brute_force_with_early_stop_and_sh_degree_2():
    g = _scene(n=8, seed=3, logit_mean=4.0, scale=0.3, sh_degree=2)
    cam = _camera(size=7)
    pairs = view_pairs(g, cam)
    assert (~pairs.live & (pairs.alpha > 0)).any()  # the early stop is exercised
    fast = view_fisher(g, cam, 1.0)
    slow = view_fisher_reference(g, cam, 1.0)
    torch.testing.assert_close(fast, slow, rtol=1e-8, atol=1e-10)
    # a lower SH degree drops the higher bands' columns
    low = view_fisher(g, cam, 1.0, sh_degree=0)
    assert low.shape[1] == parameter_count(0)
    torch.testing.assert_close(low, view_fisher_reference(g, cam, 1.0, sh_degree=0), rtol=1e-8, atol=1e-10)


def test_square_of_summed_gradient_differs_from_per_pixel_squares():
    g, cam = _scene(), _camera()
    h = view_fisher(g, cam, 0.5)
    leaves = [t.clone().requires_grad_(True) for t in (g.means, g.log_scales, g.opacity_logits, g.sh)]
    gs = GaussianSet(leaves[0], g.quats, leaves[1], leaves[2], leaves[3])
    grads = torch.autograd.grad(render(gs, cam, 0.5).image.sum(), leaves)
    naive = torch.cat([d.reshape(g.num, -1) for d in grads], -1) ** 2
    assert naive.shape == h.shape
    assert (naive - h).abs().max() > 0.1 * h.abs().max()


def test_pair_quantities_reproduce_the_render():
    g, cam = _scene(n=10, seed=5, logit_mean=2.0), _camera(size=9)
    background = torch.tensor([0.2, 0.4, 0.9], dtype=F64)
    out = render(g, cam, background)
    pairs = view_pairs(g, cam)
    opacity = pairs.pixel_sum(pairs.weights)
    torch.testing.assert_close(opacity, out.alpha.reshape(-1), rtol=1e-12, atol=1e-12)
    # T_after = T (1 - alpha) on the composited pairs; pairs after the early stop have no weight
    torch.testing.assert_close(
        pairs.transmittance_after[pairs.live], (pairs.transmittance * (1 - pairs.alpha))[pairs.live]
    )
    assert torch.all(pairs.weights[~pairs.live] == 0)
    grads = pair_attribute_gradients(g, cam, background)
    torch.testing.assert_close(grads.image, out.image, rtol=1e-12, atol=1e-12)
    assert grads.grads.shape == (pairs.num, 9)
    assert torch.equal(grads.pixels, pairs.pixels) and torch.equal(grads.gaussians, pairs.gaussians)


def test_pair_gradients_sum_to_the_summed_image_gradient():
    """Summed over a Gaussian's pairs, the per-pair gradients are the gradient of the summed image."""
    g, cam = _scene(n=7, seed=2, logit_mean=1.0), _camera(size=8)
    grads = pair_attribute_gradients(g, cam, 0.25)
    per_gaussian = torch.zeros(g.num, 9, dtype=F64).index_add_(0, grads.gaussians, grads.grads)
    means, opacity_logits = g.means.clone().requires_grad_(True), g.opacity_logits.clone().requires_grad_(True)
    gs = GaussianSet(means, g.quats, g.log_scales, opacity_logits, g.sh)
    out = render(gs, cam, 0.25)
    (d_means2d, d_logits) = torch.autograd.grad(out.image.sum(), [out.means2d, opacity_logits])
    torch.testing.assert_close(per_gaussian[:, :2], d_means2d, rtol=1e-10, atol=1e-12)
    opac = torch.sigmoid(g.opacity_logits)
    torch.testing.assert_close(per_gaussian[:, 5] * opac * (1 - opac), d_logits, rtol=1e-10, atol=1e-12)


def test_fisher_score_by_hand():
    h_c = torch.tensor([[1.0, 2.0], [0.5, 0.0]], dtype=F64)
    h_t = torch.tensor([[0.0, 1.0], [3.0, 2.0]], dtype=F64)
    expected = 1.0 / 1e-6 + 2.0 / (1.0 + 1e-6) + 0.5 / (3.0 + 1e-6)
    assert fisher_score(h_c, h_t) == pytest.approx(expected, rel=1e-12)
    assert fisher_score(h_c, h_t, 0.5) == pytest.approx(1 / 0.5 + 2 / 1.5 + 0.5 / 3.5, rel=1e-12)
    with pytest.raises(ValueError, match="differ"):
        fisher_score(h_c, h_t[:1])


@pytest.mark.parametrize("cache_mb", [256.0, 0.0])
def test_lazy_greedy_top_k_matches_plain_greedy(cache_mb):
    g = _scene(n=12, seed=7, scale=0.2, dtype=torch.float32)
    cams = _ring(7)
    train = [_camera((0.0, 0.0, -3.0), 10)]
    config = FisherConfig(cache_mb=cache_mb)
    ranking = greedy_top_k(g, cams, train, 1.0, 5, config)
    h_train = view_fisher(g, train[0], 1.0).double()
    h_cands = [view_fisher(g, c, 1.0) for c in cams]
    assert ranking.order == greedy_top_k_reference(h_train, h_cands, 5)
    assert ranking.order[0] == max(range(7), key=lambda i: ranking.scores[i])
    assert ranking.scores == pytest.approx([fisher_score(h, h_train) for h in h_cands], rel=1e-6)
    assert len(set(ranking.order)) == 5
    if cache_mb == 0.0:
        assert ranking.recomputed > 0


def test_greedy_list_accounts_for_picked_views():
    """A duplicate of the best candidate carries little new information once the best is picked: it ties in
    the first-round scores but the greedy list does not take it second."""
    g = _scene(n=12, seed=7, scale=0.2, dtype=torch.float32)
    cams, train = _ring(5), [_camera((0.0, 0.0, -3.0), 10)]
    first = greedy_top_k(g, cams, train, 1.0, 1).order[0]
    ranking = greedy_top_k(g, cams + [cams[first]], train, 1.0, 3)
    assert ranking.scores[5] == pytest.approx(ranking.scores[first])
    assert ranking.order[0] == first
    assert 5 not in ranking.order[1:2]
    by_score = sorted(range(6), key=lambda i: (-ranking.scores[i], i))
    assert by_score[1] == 5  # plain sorting would have taken the duplicate second


def test_fisher_config_validation_and_inputs():
    with pytest.raises(ValueError, match="regularization"):
        FisherConfig(regularization=0.0)
    with pytest.raises(ValueError, match="cache_mb"):
        FisherConfig(cache_mb=-1.0)
    with pytest.raises(ValueError, match="sh_degree"):
        view_fisher(_scene(sh_degree=0), _camera(), sh_degree=2)
    with pytest.raises(ValueError, match="no candidate"):
        greedy_top_k(_scene(), [], [], 1.0, 1)


def _view_fisher_unbatched(gaussians, camera, background, sh_degree=None, include_rotations=False):
    """The earlier :func:`view_fisher`, kept as its twin: per-pair gradients through autograd, one backward pass
    per attribute for the local Jacobians, and every Gram entry formed (no shared colour entries)."""
    degree = _degree(gaussians, sh_degree)
    pg = pair_attribute_gradients_reference(gaussians, camera, background, sh_degree=degree)
    leaves = _parameter_leaves(gaussians, degree, include_rotations)
    names = list(leaves)
    blocks = [[] for _ in names]
    with torch.enable_grad():
        g = _leaf_set(gaussians, leaves)
        proj = project_gaussians(g, camera)
        colors = gaussian_colors(g, camera, degree)
        attributes = torch.cat([proj.means2d, proj.conics, g.opacities[:, None], colors], -1)
        for k in range(attributes.shape[1]):
            grads = torch.autograd.grad(
                attributes[:, k].sum(), [leaves[n] for n in names], retain_graph=True, allow_unused=True
            )
            for b, grad in enumerate(grads):
                if grad is not None:
                    blocks[b].append((k, grad.reshape(g.num, -1)))
    grads, gid = pg.grads.T.to(F64).contiguous(), pg.gaussians
    n, attrs = gaussians.num, grads.shape[0]
    jac = torch.cat([_block_matrix(rows, n, attrs, grads) for rows in blocks], 1)
    support = (jac != 0).any(-1)
    h = torch.zeros(jac.shape[1], n, dtype=F64)
    for k in range(attrs):
        for m in range(k, attrs):
            cols = torch.nonzero(support[k] & support[m]).flatten()
            if cols.numel() == 0:
                continue
            gram = torch.zeros(n, dtype=F64).index_add_(0, gid, grads[k] * grads[m])
            jk, jm = jac[k].index_select(0, cols), jac[m].index_select(0, cols)
            h.index_add_(0, cols, jk * jm * ((1.0 if k == m else 2.0) * gram))
    return h.T.clamp_min(0.0).to(gaussians.dtype).contiguous()


@pytest.mark.parametrize("dtype", [torch.float32, F64])
def test_closed_form_pair_gradients_equal_the_autograd_twin_bit_for_bit(dtype):
    g = _scene(n=8, seed=3, logit_mean=6.0, scale=0.3, sh_degree=2, dtype=dtype)  # early stops, clamped alphas
    cam = _camera(size=7)
    background = torch.tensor([0.1, 0.5, 0.8], dtype=dtype)
    fast = pair_attribute_gradients(g, cam, background)
    slow = pair_attribute_gradients_reference(g, cam, background)
    pairs = view_pairs(g, cam)
    assert (~pairs.live & (pairs.alpha > 0)).any() and (pairs.alpha >= 0.99 - 1e-7).any()
    assert fast.grads.abs().max() > 0.1
    assert torch.equal(fast.grads, slow.grads) and torch.equal(fast.image, slow.image)
    assert torch.equal(fast.pixels, slow.pixels) and torch.equal(fast.gaussians, slow.gaussians)
    assert torch.equal(fast.grads[:, 6], fast.grads[:, 7]) and torch.equal(fast.grads[:, 6], fast.grads[:, 8])


@pytest.mark.parametrize(("dtype", "include_rotations", "sh_degree"), [(torch.float32, False, 1), (F64, True, 2)])
def test_view_fisher_equals_the_earlier_computation_bit_for_bit(dtype, include_rotations, sh_degree):
    g = _scene(n=40, seed=11, scale=0.15, logit_mean=1.0, sh_degree=sh_degree, dtype=dtype)
    for cam in _ring(3, size=16):
        fast = view_fisher(g, cam, 0.3, include_rotations=include_rotations)
        slow = _view_fisher_unbatched(g, cam, 0.3, include_rotations=include_rotations)
        assert slow.abs().max() > 1e-3
        assert torch.equal(fast, slow)


def test_fisher_selection_and_scores_pinned_on_a_fixture():
    """The greedy list and the scores of this fixture, as computed before the fast path (and by its twin)."""
    g = _scene(n=40, seed=11, scale=0.15, logit_mean=1.0, dtype=torch.float32)
    cams, train = _ring(9, size=16), [_camera((0.0, 0.0, -3.0), 16), _camera((3.0, 0.0, 0.0), 16)]
    background = torch.tensor([0.2, 0.4, 0.6])
    ranking = greedy_top_k(g, cams, train, background, 5)
    assert ranking.order == [5, 8, 6, 3, 4]
    pinned = [1207.17, 921.964, 356.054, 9801.9, 41043.9, 86663.6, 64786.0, 37083.3, 13698.5]
    assert ranking.scores == pytest.approx(pinned, rel=1e-5)
    h_train = sum(_view_fisher_unbatched(g, c, background).double() for c in train)
    h_cands = [_view_fisher_unbatched(g, c, background) for c in cams]
    assert ranking.order == greedy_top_k_reference(h_train, h_cands, 5)
    assert ranking.scores == [fisher_score(h, h_train) for h in h_cands]
