"""PSNR, SSIM, LPIPS availability and the Chamfer distance against known values and slow references."""

import importlib

import numpy as np
import pytest
import torch

from recon import metrics
from recon.metrics import (
    MetricUnavailable,
    chamfer_distance,
    chamfer_distance_reference,
    lpips,
    lpips_available,
    lpips_unavailable_reason,
    nearest_distances,
    nearest_distances_reference,
    psnr,
    ssim,
)

C1, C2 = 0.01**2, 0.03**2


def _ssim_numpy(x: np.ndarray, y: np.ndarray, size=11, sigma=1.5, padding="same") -> float:
    """Slow SSIM: explicit 2-D Gaussian window, explicit loops over pixels, zero padding for 'same'."""
    r = size // 2
    t = np.arange(size) - r
    g = np.exp(-(t**2) / (2 * sigma**2))
    window = np.outer(g, g) / np.outer(g, g).sum()
    h, w, c = x.shape
    if padding == "same":
        x = np.pad(x, ((r, r), (r, r), (0, 0)))
        y = np.pad(y, ((r, r), (r, r), (0, 0)))
        rows, cols = range(h), range(w)
    else:
        rows, cols = range(h - 2 * r), range(w - 2 * r)
    values = []
    for ch in range(c):
        for i in rows:
            for j in cols:
                px, py = x[i : i + size, j : j + size, ch], y[i : i + size, j : j + size, ch]
                mx, my = (window * px).sum(), (window * py).sum()
                vx = (window * px * px).sum() - mx * mx
                vy = (window * py * py).sum() - my * my
                cxy = (window * px * py).sum() - mx * my
                values.append((2 * mx * my + C1) * (2 * cxy + C2) / ((mx * mx + my * my + C1) * (vx + vy + C2)))
    return float(np.mean(values))


def test_psnr_known_values():
    ref = torch.rand(16, 12, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0)) * 0.8
    assert float(psnr(ref + 0.1, ref)) == pytest.approx(20.0, abs=1e-9)
    assert float(psnr(ref - 0.01, ref)) == pytest.approx(40.0, abs=1e-9)
    assert float(psnr((ref + 0.1) * 255, ref * 255, max_val=255.0)) == pytest.approx(20.0, abs=1e-9)
    batch = psnr(torch.stack([ref + 0.1, ref + 0.01]), torch.stack([ref, ref]))
    assert batch.shape == (2,) and torch.allclose(batch, torch.tensor([20.0, 40.0], dtype=torch.float64))
    assert torch.isinf(psnr(ref, ref))


def test_ssim_of_identical_images_is_one_and_gradients_flow():
    x = torch.rand(24, 20, 3, generator=torch.Generator().manual_seed(1))
    assert float(ssim(x, x)) == pytest.approx(1.0, abs=1e-6)
    y = x.clone().requires_grad_(True)
    noisy = (x + 0.1 * torch.randn(x.shape, generator=torch.Generator().manual_seed(2))).clamp(0, 1)
    loss = 1.0 - ssim(y, noisy)
    loss.backward()
    assert y.grad is not None and torch.isfinite(y.grad).all() and y.grad.abs().sum() > 0


@pytest.mark.parametrize("a,b", [(0.2, 0.7), (0.5, 0.5), (0.05, 0.9)])
def test_ssim_of_constant_images_matches_the_luminance_formula(a, b):
    x = torch.full((20, 20, 3), a, dtype=torch.float64)
    y = torch.full((20, 20, 3), b, dtype=torch.float64)
    expected = (2 * a * b + C1) / (a * a + b * b + C1)  # contrast-structure term is C2 / C2 = 1
    assert float(ssim(x, y, padding="valid")) == pytest.approx(expected, abs=1e-10)


@pytest.mark.parametrize("padding", ["same", "valid"])
def test_ssim_matches_the_slow_numpy_reference(padding):
    gen = torch.Generator().manual_seed(3)
    x = torch.rand(17, 15, 3, dtype=torch.float64, generator=gen)
    y = 0.6 * x + 0.4 * torch.rand(17, 15, 3, dtype=torch.float64, generator=gen)
    fast = float(ssim(x, y, padding=padding))
    slow = _ssim_numpy(x.numpy(), y.numpy(), padding=padding)
    assert fast == pytest.approx(slow, abs=1e-10)
    assert float(ssim(x.float(), y.float(), padding=padding)) == pytest.approx(slow, abs=2e-5)
    assert fast < 0.95  # the pair is genuinely different, so the comparison is not trivial
    batch = ssim(torch.stack([x, y]), torch.stack([y, y]), padding=padding)
    assert batch.shape == (2,) and float(batch[0]) == pytest.approx(fast, abs=1e-12) and float(batch[1]) == 1.0


def test_ssim_decreases_monotonically_with_noise():
    gen = torch.Generator().manual_seed(4)
    x = torch.rand(32, 32, 3, generator=gen)
    noise = torch.randn(32, 32, 3, generator=gen)
    values = [float(ssim(x + s * noise, x)) for s in (0.0, 0.02, 0.05, 0.1, 0.2, 0.4)]
    assert values[0] == pytest.approx(1.0, abs=1e-6)
    assert all(v1 > v2 for v1, v2 in zip(values, values[1:], strict=False)), values


def test_image_metrics_validate_inputs():
    x = torch.rand(8, 8, 3)
    with pytest.raises(ValueError, match=r"\(8, 8, 3\) and \(8, 7, 3\)"):
        ssim(x, torch.rand(8, 7, 3))
    with pytest.raises(ValueError, match="img must be a float tensor"):
        psnr(torch.zeros(8, 8, 3, dtype=torch.uint8), x)
    with pytest.raises(ValueError, match="valid"):
        ssim(x, x, padding="valid")


def test_lpips_is_reported_unavailable_without_crashing():
    reason = lpips_unavailable_reason()
    if reason is None:
        pytest.skip("LPIPS and its weights are installed on this machine; the unavailable path cannot be shown")
    assert not lpips_available()
    with pytest.raises(MetricUnavailable, match="LPIPS is unavailable") as info:
        lpips(torch.rand(8, 8, 3), torch.rand(8, 8, 3))
    assert isinstance(info.value, RuntimeError) and reason in str(info.value)


def test_lpips_availability_checks_every_weights_file(tmp_path, monkeypatch):
    """With stand-in packages on sys.path, availability follows the weights files, and nothing is imported."""
    for package in ("lpips", "torchvision"):
        (tmp_path / "site" / package).mkdir(parents=True)
        (tmp_path / "site" / package / "__init__.py").write_text("raise ImportError('must not be imported')\n")
    monkeypatch.syspath_prepend(str(tmp_path / "site"))
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "hub"))
    importlib.invalidate_caches()
    assert "linear weights" in lpips_unavailable_reason("alex")
    (tmp_path / "site" / "lpips" / "weights" / "v0.1").mkdir(parents=True)
    (tmp_path / "site" / "lpips" / "weights" / "v0.1" / "alex.pth").write_bytes(b"")
    assert "alexnet-owt-7be5be79.pth" in lpips_unavailable_reason("alex")
    (tmp_path / "hub" / "checkpoints").mkdir(parents=True)
    (tmp_path / "hub" / "checkpoints" / metrics.LPIPS_BACKBONES["alex"]).write_bytes(b"")
    assert lpips_available("alex")
    assert not lpips_available("vgg")


def test_nearest_distances_match_brute_force():
    gen = np.random.default_rng(5)
    a, b = gen.normal(size=(700, 3)), gen.normal(size=(500, 3)) + 0.2
    assert np.allclose(nearest_distances(a, b), nearest_distances_reference(a, b, chunk=128), atol=1e-12)
    brute = np.sqrt(((a[:, None] - b[None]) ** 2).sum(-1)).min(1)
    assert np.allclose(nearest_distances_reference(a, b), brute, atol=1e-12)


def test_chamfer_distance_properties():
    gen = np.random.default_rng(6)
    a, b = gen.uniform(size=(400, 3)), gen.uniform(size=(300, 3))
    for squared in (False, True):
        fast = chamfer_distance(a, b, squared=squared)
        assert fast == pytest.approx(chamfer_distance_reference(a, b, squared=squared), abs=1e-12)
        assert fast == pytest.approx(chamfer_distance(b, a, squared=squared), abs=1e-12)
        assert fast > 0
    assert chamfer_distance(a, a) == 0.0
    assert chamfer_distance(torch.from_numpy(a).float(), torch.from_numpy(b).float()) == pytest.approx(
        chamfer_distance(a, b), abs=1e-6
    )


def test_chamfer_distance_of_parallel_offset_grids():
    u = np.arange(0.0, 1.0 + 1e-9, 0.1)
    grid = np.stack(np.meshgrid(u, u, indexing="ij"), -1).reshape(-1, 2)
    a = np.c_[grid, np.zeros(len(grid))]
    b = a + [0.0, 0.0, 0.03]  # a copy lifted by 0.03: every nearest neighbour is the point straight above
    assert chamfer_distance(a, b) == pytest.approx(0.03, abs=1e-12)
    assert chamfer_distance(a, b, squared=True) == pytest.approx(0.03**2, abs=1e-12)
    shifted = a + [0.05, 0.0, 0.04]  # half a grid step sideways and lifted: every point's nearest neighbour
    expected = np.hypot(0.05, 0.04)  # is a half step away in x, edges included
    assert chamfer_distance(a, shifted) == pytest.approx(expected, abs=1e-12)
    assert chamfer_distance_reference(a, shifted) == pytest.approx(expected, abs=1e-12)


def test_chamfer_rejects_bad_point_sets():
    with pytest.raises(ValueError, match="point set a"):
        chamfer_distance(np.zeros((0, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="point set b contains NaN"):
        chamfer_distance(np.zeros((2, 3)), np.array([[0, 0, np.nan]]))


def test_chamfer_handles_100k_points_without_pairwise_memory():
    gen = np.random.default_rng(7)
    a = gen.uniform(size=(100_000, 3))
    b = a + [0.0, 0.0, 1e-3]  # each point's own shifted copy is 1e-3 away, so the distance is in (0, 1e-3]
    d = chamfer_distance(a, b)
    assert 0.0 < d <= 1e-3 + 1e-12
