"""Closed shells of flat Gaussians (discs) much thinner than the lattice spacing, like the hollow surface elements
of real captures."""

from __future__ import annotations

import math

import numpy as np
import torch

from recon.gaussians import GaussianSet

from helpers.spheres import fibonacci_sphere

SPACING = 0.05
SIGMA_N = SPACING / 10.0  # the shells' normal standard deviation
SIGMA_T = 0.02  # in-plane standard deviation
OPACITY = 0.9


def flat_gaussians(
    means: np.ndarray, normals: np.ndarray, sigma_t: float = SIGMA_T, sigma_n: float = SIGMA_N, opacity: float = OPACITY
) -> GaussianSet:
    """Discs: local z (the smallest scale) along ``normals``; quaternion (1 + n_z, -n_y, n_x, 0) turns z to n."""
    n = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    q = np.stack([1.0 + n[:, 2], -n[:, 1], n[:, 0], np.zeros(len(n))], 1)
    q[q[:, 0] < 1e-9] = [0.0, 1.0, 0.0, 0.0]  # n = -z: a half turn about x
    log_scales = np.tile(np.log([sigma_t, sigma_t, sigma_n]), (len(n), 1))
    logit = math.log(opacity / (1.0 - opacity))
    return GaussianSet(
        torch.tensor(means, dtype=torch.float64),
        torch.tensor(q),
        torch.tensor(log_scales),
        torch.full((len(n),), logit, dtype=torch.float64),
        torch.zeros(len(n), 1, 3, dtype=torch.float64),
    )


def sphere_shell(radius: float, centre=(0.0, 0.0, 0.0), sigma_t: float = SIGMA_T, sigma_n: float = SIGMA_N):
    n = int(4 * math.pi * radius**2 / (1.2 * sigma_t) ** 2)
    d = fibonacci_sphere(n)
    return flat_gaussians(np.asarray(centre) + radius * d, d, sigma_t, sigma_n)
