"""Gaussians recoloured by per-Gaussian values (a D_g heat-map in 3DGS viewers).

The colour map and its scale have one owner, :mod:`viz.colors` (Taichi- and torch-free, for the viewer): a value v
maps to a colour of OpenCV's TURBO map at v / v_max, with v_max a high percentile (99th by default) of the values,
so that a few extreme Gaussians do not wash out the rest. The recoloured set
keeps the geometry (means, rotations, scales, opacities) and has SH degree 0 with the DC coefficient
set so that the 3DGS colour (SH_C0 * f_dc + 0.5) is the map's colour.
"""

from __future__ import annotations

import numpy as np
import torch

from recon.gaussians import GaussianSet, rgb_to_sh0
from viz.colors import PERCENTILE, color_scale, turbo

__all__ = ["color_scale", "colored_gaussians", "colormap"]


def colormap(values: np.ndarray, vmax: float | None = None, percentile: float = PERCENTILE) -> np.ndarray:
    """RGB colours in [0, 1] of ``values`` [N] on the TURBO map (:func:`viz.colors.turbo`), 0 -> dark blue, >= vmax ->
    dark red.

    Args:
        values: [N] non-negative values (e.g. D_g in 1/s).
        vmax: the value mapped to the top of the scale (None: the ``percentile`` of ``values``,
            :func:`viz.colors.color_scale`).
    Returns:
        [N, 3] float32 RGB.
    """
    v = np.nan_to_num(np.asarray(values, np.float64).reshape(-1), nan=0.0, posinf=0.0, neginf=0.0)
    return turbo(v, color_scale(v, percentile) if vmax is None else float(vmax))


def colored_gaussians(gaussians: GaussianSet, values, vmax: float | None = None,
                      percentile: float = PERCENTILE) -> GaussianSet:
    """The same Gaussians with SH degree 0 and colours from :func:`colormap` of ``values`` [N]."""
    vals = values.detach().cpu().numpy() if isinstance(values, torch.Tensor) else np.asarray(values)
    if vals.reshape(-1).shape[0] != gaussians.num:
        raise ValueError(f"{vals.size} values for {gaussians.num} Gaussians; pass one value per Gaussian")
    rgb = torch.from_numpy(colormap(vals, vmax, percentile)).to(gaussians.means)
    sh = rgb_to_sh0(rgb)[:, None, :].contiguous()
    g = gaussians.detach()
    return GaussianSet(g.means.clone(), g.quats.clone(), g.log_scales.clone(), g.opacity_logits.clone(), sh)
