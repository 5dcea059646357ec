"""Where the solid is thin or open: a per-Gaussian mask (the oracle study's ``thin`` rules, the ``+thin-area``
planners).

The fluid sees a thick, closed part of the solid only at its surface, where the reconstruction is usually right. A
hole, a gap or a thin sheet is where the flow would go through or around, and where the paper's physics should
matter. This module marks the Gaussians near such places, from the probe run's solid lattice alone:

- **open**: no solid lattice point within the Gaussian's reach (plus one spacing) -- the Gaussian makes no solid
  there (a floater, a transparent part, a gap the lattice did not close);
- **thin**: every solid point within that distance is removed by the lattice's morphological opening of ``depth``
  (``depth`` erosions, then as many dilations, 6-connected): the solid there is too thin for a (2 ``depth`` + 1)
  spacing probe to fit.

Everything else is "thick". In the oracle study (docs/results.md) the coverage of the thin-or-open Gaussians
predicted a view's gain better than the coverage at seed 0 on six shapes, and not at seeds 1-4 nor on two held-out
shapes; D_g restricted to them did no better than the mask alone. :func:`thin_or_open_gaussians` needs the solid
only, no probe. It is no planner's default.
"""

from __future__ import annotations

import numpy as np
import torch
from scipy import ndimage
from scipy.spatial import cKDTree


def lattice_volume(points: np.ndarray, spacing: float, pad: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Solid lattice points [M, 3] (on a lattice of ``spacing``, any offset) -> (a bool volume with ``pad`` empty
    voxels around it, and [M, 3] int64 voxel indices of the points in it).

    Raises:
        ValueError: the points are not on one lattice of ``spacing`` (off by more than a tenth of it).
    """
    points = np.asarray(points, np.float64).reshape(-1, 3)
    origin = points.min(axis=0)
    f = (points - origin) / spacing
    idx = np.rint(f).astype(np.int64)
    off = np.abs(f - idx).max() if len(f) else 0.0
    if off > 0.1:
        raise ValueError(
            f"lattice_volume: the solid points are not on a lattice of spacing {spacing} m (off by {off:.2f})"
        )
    idx += pad
    vol = np.zeros(tuple(idx.max(axis=0) + pad + 1), bool)
    vol[tuple(idx.T)] = True
    return vol, idx


def thin_or_open(solid: np.ndarray, spacing: float, means: np.ndarray, reach: np.ndarray, depth: int = 2) -> np.ndarray:
    """[G] bool: the Gaussians (centres ``means`` [G, 3], reach [G], sim metres) near no solid point within
    reach + spacing (open), or near only solid points that the opening of ``depth`` removes (thin)."""
    means = np.asarray(means, np.float64).reshape(-1, 3)
    reach = np.asarray(reach, np.float64).reshape(-1)
    if len(solid) == 0:
        return np.ones(len(means), bool)
    vol, idx = lattice_volume(solid, spacing)
    if depth > 0:  # (scipy repeats an opening of iterations < 1 until nothing changes)
        opened = ndimage.binary_opening(vol, structure=ndimage.generate_binary_structure(3, 1), iterations=depth)
        thick = opened[tuple(idx.T)]
    else:
        thick = np.ones(len(idx), bool)
    radius = reach + spacing
    mask = np.ones(len(means), bool)
    if thick.any():
        tree = cKDTree(np.asarray(solid, np.float64)[thick])
        d, _ = tree.query(means, k=1)
        mask = d > radius  # no thick point within reach: thin or open
    return mask


def thin_or_open_gaussians(gaussians, config) -> torch.Tensor:
    """[N] bool: :func:`thin_or_open` of every Gaussian of ``gaussians`` (a ``recon.gaussians.GaussianSet``, scene
    units), with the solid, the reach and the frame of a probe run under ``config`` (a
    :class:`nbv.physics.PhysicsConfig`), and no fluid. Gaussians outside ``config.crop`` are False (not simulated);
    Gaussians that form no solid at all are all True (open).

    Raises:
        ValueError: bad Gaussians or settings (as :func:`nbv.physics.simulate_gaussians` would, before any probe).
    """
    from nbv.physics.plan import RunFrame  # noqa: PLC0415 - the plan imports the solidification, which loads Taichi
    from nbv.physics.solidify import is_empty_solid  # noqa: PLC0415 - loads Taichi, as above

    frame = RunFrame.of(gaussians, config)
    try:
        solid = frame.solidify().points
    except ValueError as exc:
        if not is_empty_solid(exc):
            raise
        solid = np.zeros((0, 3))
    kept = thin_or_open(solid, 2.0 * config.particle_radius, frame.means, frame.reach)
    if frame.kept is None:
        return torch.from_numpy(kept)
    out = np.zeros(len(frame.kept), bool)
    out[frame.kept] = kept
    return torch.from_numpy(out)
