"""The types and conventions shared by the renderer's backends and the per-pair quantities (Kerbl et al. 2023).

:mod:`recon.render` (the public :func:`~recon.render.render`), its torch rasterizer (:mod:`recon._rasterize`),
the gsplat backend (:mod:`recon.render_gsplat`), the dense twin (:mod:`recon.render_reference`) and the per-pair
quantities for view planners (:mod:`recon.pairs`) all import from here, so none of them imports another for a type:

- the alpha conventions of the reference CUDA rasterizer (diff-gaussian-rasterization): ``ALPHA_MAX``,
  ``ALPHA_MIN`` and ``T_MIN``;
- :class:`RenderOutput`, one rendered view, and :class:`PairList`, the sparse (pixel, Gaussian) pairs of one view;
- :func:`background_tensor`, the background check of every backend.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

ALPHA_MAX = 0.99  # alpha clamp of the reference rasterizer
ALPHA_MIN = 1.0 / 255.0  # pairs below this alpha are skipped
T_MIN = 1e-4  # a pixel stops before the Gaussian that would bring its transmittance below this


@dataclass
class RenderOutput:
    """One rendered view.

    Attributes:
        image: [H, W, 3] colour composited over the background.
        alpha: [H, W] accumulated opacity 1 - T_final.
        depth: [H, W] alpha-weighted view depth sum_i w_i z_i (0 where empty; divide by alpha for the mean).
        radii: [N] int32 screen-space radius in pixels, ceil(3 sigma_max); 0 when culled.
        visible: [N] bool, radii > 0.
        means2d: [N, 2] projected centres in pixels; when grad is enabled, a tensor whose ``.grad`` holds
            the view-space positional gradient after backward (for adaptive density control).
    """

    image: torch.Tensor
    alpha: torch.Tensor
    depth: torch.Tensor
    radii: torch.Tensor
    visible: torch.Tensor
    means2d: torch.Tensor


@dataclass
class PairList:
    """The sparse (pixel, Gaussian) pairs of one view, sorted by pixel, then by depth.

    Attributes:
        pixels: [P] int32 pixel index y * W + x, ascending.
        gaussians: [P] int32 Gaussian index of each pair.
        rows: [P] int32 footprint row of each pair (index into ``row_gaussians`` / ``row_dy``).
        dx: [P] pixel-centre x minus the projected mean's u, pixels.
        alpha: [P] unclamped alpha o exp(power) where >= 1/255, else 0 (a skipped pair).
        row_gaussians: [R] int32 Gaussian index of each footprint row.
        row_dy: [R] pixel-centre y of the row minus the projected mean's v, pixels.
        candidates: number of pairs in the footprint boxes before the alpha < 1/255 skip.
    """

    pixels: torch.Tensor
    gaussians: torch.Tensor
    rows: torch.Tensor
    dx: torch.Tensor
    alpha: torch.Tensor
    row_gaussians: torch.Tensor
    row_dy: torch.Tensor
    candidates: int

    @property
    def num(self) -> int:
        return int(self.pixels.numel())


def background_tensor(background, like: torch.Tensor) -> torch.Tensor:
    """The background of a render as a [3] tensor of ``like``'s dtype and device.

    Args:
        background: a [3] RGB tensor on ``like``'s device, a float grey level, or None (black).
        like: any tensor of the Gaussians (its dtype and device are used).
    Raises:
        ValueError: a wrong type, shape or device, or NaN / Inf values.
    """
    if background is None:
        return torch.zeros(3, dtype=like.dtype, device=like.device)
    if isinstance(background, (int, float)):
        return torch.full((3,), float(background), dtype=like.dtype, device=like.device)
    if not isinstance(background, torch.Tensor):
        raise ValueError(
            f"background must be a [3] tensor, a float grey level or None, got {type(background).__name__}"
        )
    if tuple(background.shape) != (3,):
        raise ValueError(f"background must have shape (3,), got {tuple(background.shape)}; pass one RGB colour")
    if background.device != like.device:
        raise ValueError(
            f"background is on {background.device} but the Gaussians are on {like.device}; "
            f"move it with .to({str(like.device)!r})"
        )
    if not torch.isfinite(background).all():
        raise ValueError("background has NaN or Inf values")
    return background.to(like.dtype)
