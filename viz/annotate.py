"""Labelled pictures of views: float RGB images to BGR uint8, text boxes in a corner, side-by-side panels.

Used by the per-view PNGs of `fluidgs score` (:func:`nbv.view_scoring.write_view_pngs`): the render of a candidate
view beside its D_g heat-map (paper Eq. 2-3 on the TURBO map), each with its rank, score or colour range written in
the top-left corner. numpy and OpenCV only; no equations of the paper live here.
"""

from __future__ import annotations

import cv2
import numpy as np


def to_bgr(image: np.ndarray, min_width: int = 320) -> np.ndarray:
    """An [H, W, 3] float RGB image in [0, 1] (values outside are clipped) -> [H', W', 3] BGR uint8, enlarged by
    the smallest integer factor (nearest neighbour) that makes it at least ``min_width`` pixels wide.

    Raises:
        ValueError: when ``image`` is not [H, W, 3] or ``min_width`` < 1.
    """
    arr = np.asarray(image)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[0] < 1 or arr.shape[1] < 1:
        raise ValueError(f"to_bgr needs an [H, W, 3] RGB image, got shape {arr.shape}")
    if min_width < 1:
        raise ValueError(f"min_width must be >= 1 pixel, got {min_width}")
    arr = np.clip(arr, 0, 1)
    out = np.ascontiguousarray((arr[..., ::-1] * 255 + 0.5).astype(np.uint8))
    if out.shape[1] < min_width:
        f = -(-min_width // out.shape[1])
        out = cv2.resize(out, (out.shape[1] * f, out.shape[0] * f), interpolation=cv2.INTER_NEAREST)
    return out


def label(img: np.ndarray, lines: list[str]) -> np.ndarray:
    """Write text ``lines`` (black on a white box, one below the other) in the top-left corner of the BGR uint8
    image ``img`` [H, W, 3], in place; the font grows with the width (0.35 at <= 315 px). Returns ``img``."""
    scale = max(0.35, img.shape[1] / 900)
    for k, text in enumerate(lines):
        y = int(16 * scale / 0.45) * (k + 1)
        (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
        cv2.rectangle(img, (2, y - th - 3), (6 + tw, y + 3), (255, 255, 255), -1)
        cv2.putText(img, text, (4, y), cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 1, cv2.LINE_AA)
    return img
