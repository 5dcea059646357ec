"""Points spread nearly uniformly over a sphere (the Fibonacci lattice), and the 300-Gaussian test sphere the app,
viewer and probe tests simulate, score and render."""

from __future__ import annotations

import math

import numpy as np
import torch

from recon.gaussians import GaussianSet


def fibonacci_sphere(n: int) -> np.ndarray:
    """[n, 3] nearly uniform unit vectors, z the polar axis."""
    k = np.arange(n) + 0.5
    phi, theta = np.arccos(1 - 2 * k / n), math.pi * (1 + 5**0.5) * k
    return np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], 1)


def sphere_points(n: int = 300, radius: float = 0.5) -> np.ndarray:
    """[n, 3] points on a sphere of ``radius`` about the origin, y the polar axis."""
    return fibonacci_sphere(n)[:, [0, 2, 1]] * radius


def sphere_gaussians(n: int = 300, radius: float = 0.5, scale: float = 0.06, colours=None) -> GaussianSet:
    """``n`` isotropic Gaussians (float32, standard deviation ``scale``, opacity 0.9) at :func:`sphere_points`,
    grey unless ``colours`` [n, 3] in [0, 1] are given."""
    pts = torch.tensor(sphere_points(n, radius), dtype=torch.float32)
    return GaussianSet.from_points(pts, colours, scale=scale, opacity=0.9)
