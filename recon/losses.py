"""The 3DGS photometric loss (Kerbl et al. 2023, "3D Gaussian Splatting", Sec. 7.1, Eq. 7).

L = (1 - lambda) L1 + lambda D-SSIM, with D-SSIM = 1 - SSIM and lambda = 0.2. SSIM is the
differentiable Gaussian-window version of :func:`recon.metrics.ssim` (window 11, sigma 1.5).
"""

from __future__ import annotations

import torch

from .metrics import ssim


def l1_loss(image: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean absolute difference of two images of the same shape ([H, W, 3] in [0, 1])."""
    if image.shape != target.shape:
        raise ValueError(f"l1_loss: image shape {tuple(image.shape)} differs from target shape {tuple(target.shape)}")
    return (image - target).abs().mean()


def photometric_loss(image: torch.Tensor, target: torch.Tensor, lambda_dssim: float = 0.2) -> torch.Tensor:
    """(1 - lambda) L1 + lambda (1 - SSIM) between a render and its target (Kerbl et al. Eq. 7).

    Args:
        image: [H, W, 3] rendered image in [0, 1] (differentiable).
        target: [H, W, 3] ground truth in [0, 1].
        lambda_dssim: weight of the D-SSIM term, in [0, 1].
    Returns:
        Scalar loss.
    """
    l1 = l1_loss(image, target)
    if lambda_dssim == 0.0:
        return l1
    return (1.0 - lambda_dssim) * l1 + lambda_dssim * (1.0 - ssim(image, target))
