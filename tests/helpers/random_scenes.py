"""The random Gaussian scene the scoring tests share: Gaussians of random shape and colour in a 1.5 m cube about the
origin, seen by four cameras on a ring, and a value per Gaussian."""

from __future__ import annotations

import math

import torch

from recon.camera import Camera
from recon.gaussians import GaussianSet

RING_ANGLES = (0.0, 1.3, 2.9, 4.4)  # radians: four uneven views around the cube


def random_gaussians(n: int, gen: torch.Generator, dtype: torch.dtype = torch.float32) -> GaussianSet:
    """``n`` Gaussians drawn (in float64, from ``gen``) with centres in [-0.75, 0.75]^3, log-scales about -2.8 and
    random rotations, opacities and colours, as ``dtype``."""
    return GaussianSet(
        (torch.rand(n, 3, generator=gen, dtype=torch.float64) - 0.5) * 1.5,
        torch.randn(n, 4, generator=gen, dtype=torch.float64),
        torch.randn(n, 3, generator=gen, dtype=torch.float64) * 0.4 - 2.8,
        torch.randn(n, generator=gen, dtype=torch.float64) + 0.5,
        0.3 * torch.randn(n, 1, 3, generator=gen, dtype=torch.float64),
    ).to(dtype=dtype)


def random_scene(n: int, seed: int, dtype: torch.dtype = torch.float32):
    """:func:`random_gaussians`, four cameras 3 m out at :data:`RING_ANGLES` (36x28 to 48x34 pixels, fov 55
    degrees) and ``n`` float64 values in [0, 5); the values are drawn after the Gaussians from one generator."""
    gen = torch.Generator().manual_seed(seed)
    g = random_gaussians(n, gen, dtype)
    cams = []
    for k, a in enumerate(RING_ANGLES):
        eye = (3 * math.cos(a), 0.4, 3 * math.sin(a))
        cams.append(Camera.look_at(eye, (0, 0, 0), (0, 1, 0), 36 + 4 * k, 28 + 2 * k, math.radians(55), name=f"c{k}"))
    return g, cams, torch.rand(n, generator=gen, dtype=torch.float64) * 5


def random_blobs(
    n: int,
    seed: int,
    half_extent: tuple[float, float, float],
    scale: float,
    spread: float,
    sh_degree: int = 1,
    logit_mean: float = 0.0,
    dtype: torch.dtype = torch.float64,
) -> GaussianSet:
    """``n`` Gaussians drawn in float64 from ``seed``: centres in the box +-``half_extent``, random rotations,
    log-scales log(``scale``) + ``spread`` N(0, 1), opacity logits ``logit_mean`` + N(0, 1) and SH of degree
    ``sh_degree`` of standard deviation 0.4; returned as ``dtype``."""
    f64 = torch.float64
    gen = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=gen, dtype=f64) * 2 - 1) * torch.tensor(half_extent, dtype=f64)
    quats = torch.randn(n, 4, generator=gen, dtype=f64)
    log_scales = math.log(scale) + spread * torch.randn(n, 3, generator=gen, dtype=f64)
    logits = logit_mean + torch.randn(n, generator=gen, dtype=f64)
    sh = 0.4 * torch.randn(n, (sh_degree + 1) ** 2, 3, generator=gen, dtype=f64)
    return GaussianSet(means, quats, log_scales, logits, sh).to(dtype=dtype)
