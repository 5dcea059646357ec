"""View scores (paper Eq. 4-5), ranking, D-bar and critical scores against loop twins and hand cases."""

import math
from dataclasses import dataclass

import pytest
import torch

from nbv import scores
from recon.camera import Camera


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
    expected = (math.pi * 36 * 2 + math.pi * 1.5 ** 2 * 4) / 2
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
