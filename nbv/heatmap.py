"""Colour maps of per-Gaussian values, and Gaussians recoloured by them (a D_g heat-map in 3DGS viewers).

A value v maps to a colour of OpenCV's TURBO map at v / v_max, with v_max a high percentile (99th by
default) of the values, so that a few extreme Gaussians do not wash out the rest. The recoloured set
keeps the geometry (means, rotations, scales, opacities) and has SH degree 0 with the DC coefficient
set so that the 3DGS colour (SH_C0 * f_dc + 0.5) is the map's colour.
"""

from __future__ import annotations

import cv2
import numpy as np
import torch

from recon.gaussians import GaussianSet, rgb_to_sh0


def color_scale(values: np.ndarray, percentile: float = 99.0) -> float:
    """v_max: the ``percentile`` of the finite values (1 when that is not > 0)."""
    v = np.asarray(values, np.float64).reshape(-1)
    v = v[np.isfinite(v)]
    if not 0 < percentile <= 100:
        raise ValueError(f"percentile must be in (0, 100], got {percentile}")
    vmax = float(np.percentile(v, percentile)) if v.size else 0.0
    return vmax if vmax > 0 else 1.0


def colormap(values: np.ndarray, vmax: float | None = None, percentile: float = 99.0) -> np.ndarray:
    """RGB colours in [0, 1] of ``values`` [N] on the TURBO map, 0 -> dark blue, >= vmax -> dark red.

    Args:
        values: [N] non-negative values (e.g. D_g in 1/s).
        vmax: the value mapped to the top of the scale (None: the ``percentile`` of ``values``).
    Returns:
        [N, 3] float32 RGB.
    """
    v = np.nan_to_num(np.asarray(values, np.float64).reshape(-1), nan=0.0, posinf=0.0, neginf=0.0)
    top = color_scale(v, percentile) if vmax is None else float(vmax)
    if not top > 0:
        raise ValueError(f"vmax must be > 0, got {vmax}")
    idx = np.clip(np.round(v / top * 255.0), 0, 255).astype(np.uint8)
    bgr = cv2.applyColorMap(idx.reshape(-1, 1), cv2.COLORMAP_TURBO).reshape(-1, 3)
    return (bgr[:, ::-1].astype(np.float32) / 255.0).copy()


def colored_gaussians(gaussians: GaussianSet, values, vmax: float | None = None,
                      percentile: float = 99.0) -> GaussianSet:
    """The same Gaussians with SH degree 0 and colours from :func:`colormap` of ``values`` [N]."""
    vals = values.detach().cpu().numpy() if isinstance(values, torch.Tensor) else np.asarray(values)
    if vals.reshape(-1).shape[0] != gaussians.num:
        raise ValueError(f"{vals.size} values for {gaussians.num} Gaussians; pass one value per Gaussian")
    rgb = torch.from_numpy(colormap(vals, vmax, percentile)).to(gaussians.means)
    sh = rgb_to_sh0(rgb)[:, None, :].contiguous()
    g = gaussians.detach()
    return GaussianSet(g.means.clone(), g.quats.clone(), g.log_scales.clone(), g.opacity_logits.clone(), sh)


def colorbar(height: int, width: int, vmax: float, label: str) -> np.ndarray:
    """A vertical colour bar image (BGR uint8, [height, width, 3]) from 0 (bottom) to ``vmax`` (top)."""
    ramp = np.linspace(255, 0, height).astype(np.uint8).reshape(-1, 1)
    bar = cv2.applyColorMap(np.repeat(ramp, max(4, width // 4), axis=1), cv2.COLORMAP_TURBO)
    img = np.full((height, width, 3), 255, np.uint8)
    img[:, : bar.shape[1]] = bar
    font = cv2.FONT_HERSHEY_SIMPLEX
    cv2.putText(img, f"{vmax:.3g}", (bar.shape[1] + 2, 12), font, 0.35, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, "0", (bar.shape[1] + 2, height - 4), font, 0.35, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, label, (bar.shape[1] + 2, height // 2), font, 0.35, (0, 0, 0), 1, cv2.LINE_AA)
    return img
