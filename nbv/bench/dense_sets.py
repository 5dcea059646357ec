"""Denser Gaussian sets of the same object, for the scale benchmarks (million-Gaussian sets from a small capture).

Two constructions, both keeping the original Gaussians first and unchanged:

- :func:`jittered_copies` (``fluidgs bench score --densify K``): K - 1 copies of every Gaussian, each mean moved by
  ``jitter`` x z standard deviations along the Gaussian's own principal axes, z ~ N(0, I_3), that is
  mu' = mu + R_g diag(sigma_g) z jitter (R_g the rotation of the quaternion, sigma_g the per-axis scales); all other
  attributes kept. The moved means have covariance jitter^2 Sigma_g, the Gaussian's own shape.
- :func:`jittered_to_count` (``fluidgs bench views --count``): the set repeated until it holds ``count`` Gaussians,
  every copy after the first moved by N(0, r_g^2 I_3), r_g the largest principal standard deviation.

No equation of the paper lives here: these sets only make the workload larger with the object unchanged.
"""

from __future__ import annotations

import math
from dataclasses import replace

import torch

from recon.gaussians import GaussianSet, concat, quaternion_to_rotation


def jittered_copies(gaussians: GaussianSet, copies: int, jitter: float, seed: int = 0) -> GaussianSet:
    """A ``copies`` x denser set of the same object: the original, then ``copies`` - 1 copies whose means move by
    ``jitter`` x N(0, 1) standard deviations along each Gaussian's principal axes (scales, rotations, opacities and
    colours kept).

    Args:
        gaussians: N Gaussians.
        copies: K >= 1. jitter: >= 0, in standard deviations. seed: of the jitter.
    Returns:
        GaussianSet of K N Gaussians; the first N are ``gaussians``.
    Raises:
        ValueError: naming --densify and --jitter when K < 1 or the jitter is negative or not finite.
    """
    if copies < 1 or not (jitter >= 0 and math.isfinite(jitter)):
        raise ValueError(f"--densify must be >= 1 and --jitter a finite number >= 0, got {copies} and {jitter}")
    gen = torch.Generator().manual_seed(seed)
    rot = quaternion_to_rotation(gaussians.quats.double())
    sigma = gaussians.log_scales.double().exp()
    sets = [gaussians]
    for _ in range(copies - 1):
        z = torch.randn(sigma.shape, generator=gen, dtype=torch.float64) * jitter * sigma
        means = gaussians.means + torch.einsum("nij,nj->ni", rot, z).to(gaussians.means.dtype)
        sets.append(replace(gaussians, means=means))
    return concat(sets)


def jittered_to_count(gaussians: GaussianSet, count: int, seed: int) -> GaussianSet:
    """``count`` Gaussians: the set repeated (the first N unchanged), each later copy moved by N(0, r_g^2) per axis.

    Args:
        gaussians: N Gaussians. count: >= 1 Gaussians in the result (the last copy is cut short). seed: of the jitter.
    Returns:
        GaussianSet of ``count`` Gaussians; Gaussian i is a copy of ``gaussians[i % N]``.
    Raises:
        ValueError: naming --count when it is < 1.
    """
    if count < 1:
        raise ValueError(f"--count must be >= 1, got {count}")
    n = gaussians.num
    reps = -(-count // n)
    gen = torch.Generator().manual_seed(seed)
    index = torch.arange(reps * n) % n
    jitter = torch.randn(reps * n, 3, generator=gen, dtype=gaussians.dtype) * gaussians.max_radii()[index, None]
    jitter[:n] = 0.0
    copies = gaussians.subset(index[:count])
    return replace(copies, means=copies.means + jitter[:count])
