"""The steps every Gaussian file reader shares: size checks before allocating, and the checked float32 set at the end.

A reader decodes its format into numpy arrays in the 3DGS parametrisation (Kerbl et al. 2023: log scales, opacity
logits, (w, x, y, z) quaternions, SH coefficients [N, K, 3]) and hands them to :func:`gaussians_from_arrays`;
quantised opacities go through :func:`opacity_logits_from_unit` first.

Example:
    >>> logits = opacity_logits_from_unit(alpha)  # doctest: +SKIP
    >>> g = gaussians_from_arrays("a.splat", means, quats, log_scales, logits, sh)  # doctest: +SKIP
"""

from __future__ import annotations

import numpy as np
import torch

from ..gaussians import GaussianSet


def check_declared_size(source: str, what: str, declared: int, available: int) -> None:
    """Raise ``ValueError`` when a header declares more bytes than the file holds (checked before allocating).

    Args:
        source: the file name, for the message.
        what: what the bytes are, e.g. "152746 vertices of 16 bytes".
        declared: bytes the header implies.
        available: bytes actually present after the header.
    """
    if declared > available:
        raise ValueError(
            f"{source}: truncated or corrupt file: the header declares {what} ({declared} bytes) but "
            f"only {available} bytes follow; re-export or re-download the file"
        )


def check_positive_scales(source: str, scales: np.ndarray, what: str, fix: str) -> None:
    """Raise ``ValueError`` naming the rows of the [N, 3] standard deviations ``scales`` that are zero, negative or not
    finite (a file that stores them linearly; their log would be -inf or NaN). ``what`` names the rows ("Gaussians"),
    ``fix`` ends the message."""
    bad = np.flatnonzero(~(np.isfinite(scales) & (scales > 0)).all(1))
    if len(bad):
        raise ValueError(
            f"{source}: {len(bad)} {what} have a zero, negative or non-finite scale (first rows {bad[:5].tolist()}); "
            f"{fix}"
        )


def gaussians_from_arrays(
    source: str,
    means: np.ndarray,
    quats: np.ndarray,
    log_scales: np.ndarray,
    opacity_logits: np.ndarray,
    sh: np.ndarray,
) -> GaussianSet:
    """A checked float32 :class:`GaussianSet` from decoded numpy arrays (the shared last step of every reader).

    Args:
        source: the file name, for error messages.
        means: [N, 3]; quats: [N, 4] (w, x, y, z); log_scales: [N, 3]; opacity_logits: [N]; sh: [N, K, 3].
    Raises:
        ValueError: wrong shapes, an empty set, NaN or Inf, or a zero quaternion (the message names ``source``).
    """
    try:
        gaussians = GaussianSet(
            *(
                torch.from_numpy(np.require(a, np.float32, ("C_CONTIGUOUS", "WRITEABLE")))
                for a in (means, quats, log_scales, opacity_logits, sh)
            )
        )
    except ValueError as exc:
        raise ValueError(f"{source}: {exc}") from None
    return gaussians.check(source)


def opacity_logits_from_unit(opacity: np.ndarray, step: float = 1.0 / 255.0) -> np.ndarray:
    """Logits of quantised opacities in [0, 1], kept half a quantisation step off 0 and 1 so they stay finite.

    A stored 0 or 1 is the nearest code of an opacity within half a step of it, so clamping there changes no
    rendered value by more than the quantisation itself.

    Args:
        opacity: opacities in [0, 1], any shape.
        step: the quantisation step (1/255 for 8-bit codes).
    Returns:
        float32 logits, same shape.
    """
    p = np.clip(opacity.astype(np.float64), 0.5 * step, 1.0 - 0.5 * step)
    return np.log(p / (1.0 - p)).astype(np.float32)
