"""The rasterizer benchmark of ``fluidgs bench render``: its seeded scene and the timing of one case."""

from __future__ import annotations

import math
import statistics
import time

import torch

from .camera import Camera
from .gaussians import GaussianSet
from .render import pair_statistics, render


def bench_scene(n: int, width: int, height: int, seed: int, device: torch.device):
    """The benchmark's N Gaussians (parameters requiring grad, on ``device``) and its width x height camera.

    N seeded random Gaussians in the cube [-1, 1]^3 seen from 4 m by a 60-degree camera, SH degree 3, opacities
    sigmoid(N(0, 1.5)), per-axis scales log-normal around 2 cm (world units).
    """
    gen = torch.Generator().manual_seed(seed)
    means = torch.rand(n, 3, generator=gen) * 2.0 - 1.0
    quats = torch.randn(n, 4, generator=gen)
    log_scales = math.log(0.02) + 0.5 * torch.randn(n, 3, generator=gen)
    logits = 1.5 * torch.randn(n, generator=gen)
    sh = 0.3 * torch.randn(n, 16, 3, generator=gen)
    sh[:, 1:] *= 0.2
    gaussians = GaussianSet(means, quats, log_scales, logits, sh).to(device)
    gaussians = gaussians.map(lambda t: t.detach().requires_grad_(True))
    camera = Camera.look_at((0.0, 0.0, -4.0), (0.0, 0.0, 0.0), (0.0, -1.0, 0.0), width, height, math.radians(60.0))
    return gaussians, camera


def time_case(
    n: int,
    width: int,
    height: int,
    seed: int,
    repeats: int,
    backend: str,
    device: torch.device,
    target_ms: float | None = None,
) -> dict:
    """Forward and forward + backward time of :func:`recon.render.render` on :func:`bench_scene`, median of ``repeats``.

    The loss is a weighted sum of the image, alpha and depth maps; one extra first pass warms caches and allocators.

    Returns:
        the case's figures: sizes, visible Gaussians, their mean radius (px), the pair counts of
        :func:`recon.render.pair_statistics`, ``forward_ms``, ``forward_backward_ms`` and ``target_ms`` (as given).
    """
    gaussians, camera = bench_scene(n, width, height, seed, device)
    bg = torch.tensor([1.0, 1.0, 1.0], device=device)
    weights = torch.rand(height, width, 3, generator=torch.Generator().manual_seed(1)).to(device)
    stats = pair_statistics(gaussians.detach(), camera)

    def sync():
        if device.type == "cuda":
            torch.cuda.synchronize()

    fwd, total = [], []
    for k in range(repeats + 1):
        for t in gaussians.tensors():
            t.grad = None
        sync()
        t0 = time.perf_counter()
        out = render(gaussians, camera, bg, backend=backend)
        sync()
        t1 = time.perf_counter()
        loss = (out.image * weights).sum() + 0.1 * out.depth.sum() + out.alpha.sum()
        loss.backward()
        sync()
        t2 = time.perf_counter()
        if k:  # the first pass warms caches and allocators
            fwd.append(t1 - t0)
            total.append(t2 - t0)
    radii = out.radii[out.visible].float()
    return {
        "gaussians": n,
        "width": width,
        "height": height,
        "pixels": width * height,
        "visible": stats["visible"],
        "mean_radius_px": float(radii.mean()) if radii.numel() else 0.0,
        "candidate_pairs": stats["candidates"],
        "pairs": stats["pairs"],
        "stopped_pairs": stats["stopped"],
        "forward_ms": 1e3 * statistics.median(fwd),
        "forward_backward_ms": 1e3 * statistics.median(total),
        "target_ms": target_ms,
    }
