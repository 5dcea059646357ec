"""Small pictures of the candidate views for the viewer's list: the picture `fluidgs score` wrote, or the Gaussian
centres seen through the camera.

No paper equation is implemented here. A centre x (simulation frame) is seen by a view with centre c and
camera-to-world rotation R (OpenCV axes: x right, y down, z forward) at p = R^T (x - c); it lands at pixel
(f p_x / p_z + W/2, f p_y / p_z + H/2) with f = (H/2) / tan(fov_y / 2), and only when p_z > 0. Dots are drawn with
the z-buffer of :func:`viz.frames.splat`, so a nearer centre hides a farther one.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from .cameras import CandidateView
from .frames import splat

THUMB_WIDTH = 200  # px
BACKGROUND = (238, 238, 238)  # RGB, a little darker than the viewer's white page


def project_to_view(view: CandidateView, points: np.ndarray, height: int) -> tuple[np.ndarray, np.ndarray]:
    """(uv [N, 2] int pixel column and row, depth [N] m along the view) of sim-frame points in a picture ``height``
    pixels high (width height x aspect); depth <= 0 is behind the camera."""
    p = (np.asarray(points, np.float64) - view.position) @ view.rotation  # rows: R^T (x - c)
    f = 0.5 * height / math.tan(0.5 * view.fov_y)
    width = height * view.aspect
    z = p[:, 2]
    safe = np.where(z > 1e-9, z, 1.0)
    uv = np.stack([f * p[:, 0] / safe + 0.5 * width, f * p[:, 1] / safe + 0.5 * height], axis=1)
    return np.floor(uv).astype(np.int64), z


def view_thumbnail(view: CandidateView, means: np.ndarray, rgb: np.ndarray, width: int = THUMB_WIDTH) -> np.ndarray:
    """[H, W, 3] uint8 RGB picture of ``view``: its `fluidgs score` PNG scaled to ``width`` when it has one, else
    the centres ``means`` [G, 3] (sim metres) in their colours ``rgb`` [G, 3] (0..1) through the camera."""
    if view.png is not None:
        image = cv2.imread(str(view.png), cv2.IMREAD_COLOR)
        if image is not None:
            h = max(1, round(image.shape[0] * width / image.shape[1]))
            return cv2.resize(image, (width, h), interpolation=cv2.INTER_AREA)[..., ::-1].copy()
    height = max(1, round(width / view.aspect))
    image = np.empty((height, width, 3), np.uint8)
    image[:] = BACKGROUND
    uv, depth = project_to_view(view, means, height)
    front = depth > 0
    colors = np.clip(np.round(np.asarray(rgb, np.float64) * 255), 0, 255).astype(np.uint8)
    splat(image, uv[front], depth[front], colors[front], 1)
    return image
