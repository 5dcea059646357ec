"""The O(P G) numpy twins of the per-Gaussian accumulation (paper Eq. 2-3): every fluid particle against every
Gaussian, for the tests of :class:`nbv.physics.aggregate.GaussianAccumulator` and its cell lists."""

from __future__ import annotations

import numpy as np

__all__ = ["accumulate_reference", "within_reach_reference"]


def within_reach_reference(
    centers: np.ndarray, reach: np.ndarray, positions: np.ndarray, domain_min=None, domain_max=None
) -> np.ndarray:
    """O(P G) twin of the grid test: [P, G] bool, |x_i - mu_g|^2 < reach_g^2 (and x_i inside the domain, if given)."""
    c = np.asarray(centers, np.float64).reshape(-1, 3)
    r = np.asarray(reach, np.float64).reshape(-1)
    p = np.asarray(positions, np.float64).reshape(-1, 3)
    d = p[:, None, :] - c[None, :, :]
    near = (d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1] + d[..., 2] * d[..., 2]) < (r * r)[None, :]
    if domain_min is not None and domain_max is not None:
        lo = np.asarray(domain_min, np.float64).reshape(3)
        hi = np.asarray(domain_max, np.float64).reshape(3)
        near &= np.all((p >= lo) & (p <= hi), axis=1)[:, None]
    return near


def accumulate_reference(
    centers: np.ndarray, reach: np.ndarray, positions: np.ndarray, values: np.ndarray, domain_min=None, domain_max=None
) -> tuple[np.ndarray, np.ndarray]:
    """O(P G) twin of :class:`nbv.physics.aggregate.GaussianAccumulator`: every particle against every Gaussian.

    Args:
        centers: [G, 3] m. reach: [G] m. positions: [P, 3] m. values: [P].
        domain_min, domain_max: optional [3] m; particles outside are ignored (as the accumulator does).
    Returns:
        (sums [G] float64, counts [G] int64).
    """
    near = within_reach_reference(centers, reach, positions, domain_min, domain_max)
    vals = np.asarray(values, np.float64).reshape(-1)
    return near.T.astype(np.float64) @ vals, near.sum(axis=0).astype(np.int64)
