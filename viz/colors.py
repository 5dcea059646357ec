"""Colour maps and colour bars of the viewer.

The one owner of the colour map and its scale, also for :mod:`nbv.heatmap` (the PNGs and the coloured .ply of
`simulate` and `score`): a value v maps to OpenCV's TURBO colour at v / v_max, v_max the 99th percentile of the
values, so that a few extreme Gaussians do not wash out the rest. It lives here, free of Taichi and torch, because
the viewer needs neither.
"""

from __future__ import annotations

import cv2
import numpy as np

PERCENTILE = 99.0
# OpenCV's TURBO map as a lookup table: row k is the BGR colour of k / 255 (uint8, shape (256, 3)).
TURBO_BGR = cv2.applyColorMap(np.arange(256, dtype=np.uint8).reshape(-1, 1), cv2.COLORMAP_TURBO).reshape(256, 3)
TURBO_BGR.setflags(write=False)
# A Gaussian no probe's fluid reached has D_g = 0 for want of a measurement, not because the flow is calm there (dark
# blue): it is drawn in this grey, which TURBO never takes.
UNREACHED_RGB = (0.62, 0.62, 0.62)


def color_scale(values: np.ndarray, percentile: float = PERCENTILE) -> float:
    """v_max: the ``percentile`` of the finite values (1 when that is not > 0)."""
    v = np.asarray(values, np.float64).reshape(-1)
    v = v[np.isfinite(v)]
    if not 0 < percentile <= 100:
        raise ValueError(f"percentile must be in (0, 100], got {percentile}")
    vmax = float(np.percentile(v, percentile)) if v.size else 0.0
    return vmax if vmax > 0 else 1.0


def turbo(values: np.ndarray, vmax: float, reached: np.ndarray | None = None) -> np.ndarray:
    """[N, 3] float32 RGB in [0, 1] of ``values`` [N] on the TURBO map: 0 -> dark blue, >= vmax -> dark red
    (NaN and infinities read 0); with ``reached`` [N] bool, the values not reached are :data:`UNREACHED_RGB` grey."""
    if not vmax > 0:
        raise ValueError(f"vmax must be > 0, got {vmax}")
    v = np.nan_to_num(np.asarray(values, np.float64).reshape(-1), nan=0.0, posinf=0.0, neginf=0.0)
    idx = np.clip(np.round(v / vmax * 255.0), 0, 255).astype(np.intp)
    rgb = (TURBO_BGR[idx][:, ::-1].astype(np.float32) / 255.0).copy()
    if reached is not None:
        hit = np.asarray(reached, bool).reshape(-1)
        if hit.shape != v.shape:
            raise ValueError(f"turbo: reached {hit.shape} must match the values {v.shape}")
        rgb[~hit] = UNREACHED_RGB
    return rgb


def _tick(value: float) -> str:
    return "0" if value == 0 else f"{value:.3g}"


def colorbar_image(vmax: float, label: str, width: int = 300, height: int = 56, vmin: float = 0.0) -> np.ndarray:
    """A horizontal colour bar from ``vmin`` (left) to ``vmax`` (right) with ticks and a caption (with its units).

    Args:
        vmax: the value at the right end (values above read as it: its tick ends with "+" when vmin is 0).
        label: the caption, e.g. "D_g (max), 1/s".
        width, height: pixels.
        vmin: the value at the left end.
    Returns:
        [height, width, 3] uint8 RGB on white.
    """
    if width < 64 or height < 40:
        raise ValueError(f"colour bar must be at least 64 x 40 pixels, got {width} x {height}")
    if not vmax > vmin:
        vmin, vmax = vmin, vmin + 1.0
    img = np.full((height, width, 3), 255, np.uint8)
    margin, bar_h = 10, height // 3
    ramp = turbo(np.linspace(0.0, 1.0, width - 2 * margin), 1.0)
    img[2 : 2 + bar_h, margin : width - margin] = np.round(ramp * 255).astype(np.uint8)[None]
    font, scale, black = cv2.FONT_HERSHEY_SIMPLEX, 0.38, (0, 0, 0)
    y_tick = 2 + bar_h
    for frac in (0.0, 0.5, 1.0):
        x = int(round(margin + frac * (width - 2 * margin - 1)))
        cv2.line(img, (x, y_tick), (x, y_tick + 4), black, 1)
        text = _tick(vmin + frac * (vmax - vmin)) + ("+" if frac == 1.0 and vmin == 0 else "")
        (tw, th), _ = cv2.getTextSize(text, font, scale, 1)
        tx = int(np.clip(x - tw // 2, 0, width - tw))
        cv2.putText(img, text, (tx, y_tick + 6 + th), font, scale, black, 1, cv2.LINE_AA)
    (tw, _), _ = cv2.getTextSize(label, font, scale, 1)
    cv2.putText(img, label, (max(0, (width - tw) // 2), height - 4), font, scale, black, 1, cv2.LINE_AA)
    return img


def score_colors(scores: np.ndarray) -> np.ndarray:
    """[C, 3] uint8 RGB of view scores S(T) on TURBO from the lowest (blue) to the best (red): candidates often
    score within a few tens of per cent of each other, so the range, not 0, is the bottom (all grey when the scores
    are all equal)."""
    s = np.asarray(scores, np.float64).reshape(-1)
    if not s.size or not np.isfinite(s).all() or not s.max() > s.min():
        return np.full((len(s), 3), 128, np.uint8)
    return np.round(turbo(s - s.min(), float(s.max() - s.min())) * 255).astype(np.uint8)
