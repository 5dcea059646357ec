"""Colour maps of per-Gaussian values, Gaussians recoloured by them (a D_g heat-map in 3DGS viewers), and
per-pixel images of them (the physics-uncertainty image of a view).

The colour map and its scale have one owner, :mod:`viz.colors` (Taichi- and torch-free, for the viewer): a value v
maps to a colour of OpenCV's TURBO map at v / v_max, with v_max a high percentile (99th by default) of the values,
so that a few extreme Gaussians do not wash out the rest. Gaussians no probe's fluid reached (``reached`` False:
D_g = 0 unmeasured) are grey (:data:`viz.colors.UNREACHED_RGB`), apart from calm ones, and v_max is taken over the
reached ones. The recoloured set
keeps the geometry (means, rotations, scales, opacities) and has SH degree 0 with the DC coefficient
set so that the 3DGS colour (SH_C0 * f_dc + 0.5) is the map's colour.

The uncertainty image of a view (:func:`uncertainty_image`) composites the values themselves, not their colours:
U(p) = sum_i D_i alpha_i T_i over the Gaussians covering pixel p, front to back (3DGS Eq. 3 with the colour
replaced by D_g), as FisherRF renders its per-Gaussian uncertainty. Its picture (:func:`uncertainty_png`) marks
with "+" where U lies above the colour range, and paints grey the pixels drawn mostly by unreached Gaussians.
"""

from __future__ import annotations

import cv2
import numpy as np
import torch

from recon.gaussians import GaussianSet, rgb_to_sh0
from recon.render import render
from viz.colors import PERCENTILE, TURBO_BGR, color_scale, turbo

__all__ = [
    "color_scale",
    "colored_gaussians",
    "colormap",
    "over_range_marks",
    "uncertainty_image",
    "uncertainty_png",
    "unreached_pixels",
]


def colormap(
    values: np.ndarray, vmax: float | None = None, percentile: float = PERCENTILE, reached: np.ndarray | None = None
) -> np.ndarray:
    """RGB colours in [0, 1] of ``values`` [N] on the TURBO map (:func:`viz.colors.turbo`), 0 -> dark blue, >= vmax ->
    dark red.

    Args:
        values: [N] non-negative values (e.g. D_g in 1/s).
        vmax: the value mapped to the top of the scale (None: the ``percentile`` of ``values``, of the reached ones
            when ``reached`` is given, :func:`viz.colors.color_scale`).
        reached: [N] bool, the Gaussians some probe's fluid reached; the others are grey. None: all reached.
    Returns:
        [N, 3] float32 RGB.
    """
    v = np.nan_to_num(np.asarray(values, np.float64).reshape(-1), nan=0.0, posinf=0.0, neginf=0.0)
    if vmax is None:
        vmax = color_scale(v if reached is None else v[np.asarray(reached, bool).reshape(-1)], percentile)
    return turbo(v, float(vmax), reached)


def colored_gaussians(
    gaussians: GaussianSet,
    values,
    vmax: float | None = None,
    percentile: float = PERCENTILE,
    reached: np.ndarray | None = None,
) -> GaussianSet:
    """The same Gaussians with SH degree 0 and colours from :func:`colormap` of ``values`` [N] (``reached`` [N] bool:
    the others grey)."""
    vals = values.detach().cpu().numpy() if isinstance(values, torch.Tensor) else np.asarray(values)
    if vals.reshape(-1).shape[0] != gaussians.num:
        raise ValueError(f"{vals.size} values for {gaussians.num} Gaussians; pass one value per Gaussian")
    rgb = torch.from_numpy(colormap(vals, vmax, percentile, reached)).to(gaussians.means)
    sh = rgb_to_sh0(rgb)[:, None, :].contiguous()
    g = gaussians.detach()
    return GaussianSet(g.means.clone(), g.quats.clone(), g.log_scales.clone(), g.opacity_logits.clone(), sh)


def _side_colorbar(height: int, width: int, vmax: float, label: str, over: bool = False) -> np.ndarray:
    """A vertical colour bar image (BGR uint8, [height, width, 3]) on :data:`viz.colors.TURBO_BGR` from 0 (bottom) to
    ``vmax`` (top), with ticks at 0, vmax / 2 and vmax; the top one carries ``label`` (the unit) and, with
    ``over``, a "+" (values above ``vmax`` read as it)."""
    ramp = np.linspace(255, 0, height).round().astype(np.intp)
    bar = np.repeat(TURBO_BGR[ramp][:, None, :], max(4, width // 4), axis=1)
    img = np.full((height, width, 3), 255, np.uint8)
    img[:, : bar.shape[1]] = bar
    font = cv2.FONT_HERSHEY_SIMPLEX
    top = f"{vmax:.3g}" + ("+" if over else "") + f" {label}"  # the unit with the top value: every tick is a value
    cv2.putText(img, top, (bar.shape[1] + 2, 12), font, 0.35, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, f"{vmax / 2:.3g}", (bar.shape[1] + 2, height // 2 + 4), font, 0.35, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, "0", (bar.shape[1] + 2, height - 4), font, 0.35, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def uncertainty_image(gaussians: GaussianSet, camera, values, device: str = "cpu") -> tuple[np.ndarray, np.ndarray]:
    """The alpha-composited per-Gaussian value of every pixel: U(p) = sum_i v_i alpha_i T_i (3DGS Eq. 3 with the
    colour replaced by v), rendered through :func:`recon.render.render` with black background.

    The values ride in the colour channel of an SH-degree-0 copy of the Gaussians, divided by their largest
    magnitude so the channel stays in [0, 1], and the image is multiplied back. A constant v = c gives c times
    the view's alpha image; a single Gaussian's value shows where that Gaussian is drawn.

    Args:
        gaussians: N Gaussians (scene units). camera: the view. values: [N] non-negative (D_g in 1/s).
        device: torch device of the render.
    Returns:
        (U [H, W] float32, alpha [H, W] float32), in the units of ``values``.

    Example:
        >>> img, alpha = uncertainty_image(gaussians, cam, result.divergence)  # doctest: +SKIP
    """
    tinted, top = value_layer(gaussians.detach().to(torch.device(device)), values)
    with torch.no_grad():
        out = render(tinted, camera, background=0.0)
    return composited_values(out, top)


def value_layer(gaussians: GaussianSet, values) -> tuple[GaussianSet, float]:
    """(the Gaussians with SH degree 0 and the grey level v_i / max v as colour, max v): what
    :func:`uncertainty_image` renders; ``values`` [N] finite and >= 0."""
    vals = values.detach().cpu().numpy() if isinstance(values, torch.Tensor) else np.asarray(values)
    vals = np.asarray(vals, np.float64).reshape(-1)
    if vals.shape[0] != gaussians.num:
        raise ValueError(f"{vals.size} values for {gaussians.num} Gaussians; pass one value per Gaussian")
    if not np.isfinite(vals).all() or (vals < 0).any():
        raise ValueError("uncertainty_image: the values must be finite and >= 0 (D_g in 1/s)")
    top = float(vals.max()) if vals.size and vals.max() > 0 else 1.0
    g = gaussians.detach()
    grey = torch.from_numpy(vals / top).to(g.means)[:, None].expand(-1, 3)
    sh = rgb_to_sh0(grey)[:, None, :].contiguous()
    return GaussianSet(g.means, g.quats, g.log_scales, g.opacity_logits, sh), top


def composited_values(out, top: float) -> tuple[np.ndarray, np.ndarray]:
    """(U [H, W], alpha [H, W]) float32 of a render of :func:`value_layer`'s Gaussians (its ``top``)."""
    image = out.image[..., 0].double().cpu().numpy() * top
    return image.astype(np.float32), out.alpha.detach().cpu().numpy().astype(np.float32)


def unreached_pixels(gaussians: GaussianSet, camera, reached, device: str = "cpu", share: float = 0.5) -> np.ndarray:
    """[H, W] bool: the pixels of ``camera`` where the Gaussians not ``reached`` ([N] bool) make up more than
    ``share`` of what is drawn (their composited alpha over the pixel's alpha), so that the pixel's composited D_g
    is mostly unmeasured."""
    missing = ~np.asarray(reached, bool).reshape(-1)
    part, alpha = uncertainty_image(gaussians, camera, missing.astype(np.float64), device)
    return (part > share * alpha) & (alpha > 1.0 / 255.0)


def over_range_marks(image_bgr: np.ndarray, above: np.ndarray, step: int = 8) -> np.ndarray:
    """``image_bgr`` [H, W, 3] uint8 with a white "+" on a grid of ``step`` pixels wherever ``above`` [H, W] (the
    values over the colour range) holds, so that clipped regions read as clipped; a copy."""
    out = image_bgr.copy()
    h, w = above.shape
    if out.shape[:2] != (h, w):
        raise ValueError(f"over_range_marks: image {out.shape[:2]} and mask {above.shape} differ")
    half = max(1, step // 4)
    for y in range(step // 2, h, step):
        for x in range(step // 2, w, step):
            if above[y, x]:
                cv2.line(out, (x - half, y), (x + half, y), (255, 255, 255), 1)
                cv2.line(out, (x, y - half), (x, y + half), (255, 255, 255), 1)
    return out


def uncertainty_png(image: np.ndarray, vmax: float, label: str, unreached: np.ndarray | None = None) -> np.ndarray:
    """The colour picture of an :func:`uncertainty_image`: TURBO from 0 to ``vmax`` with "+" marks where the value is
    above ``vmax``, and a colour bar (its top tick ends with "+") at the right. BGR uint8 [H, W + bar, 3].

    ``unreached`` [H, W] bool: the pixels drawn mostly by Gaussians no probe's fluid reached (their D_g is
    unmeasured, not 0), painted :data:`viz.colors.UNREACHED_RGB` grey (:func:`unreached_pixels`)."""
    u = np.asarray(image, np.float64)
    if not vmax > 0:
        raise ValueError(f"vmax must be > 0, got {vmax}")
    if unreached is not None and np.shape(unreached) != u.shape:
        raise ValueError(f"uncertainty_png: unreached {np.shape(unreached)} must match the image {u.shape}")
    hit = None if unreached is None else ~np.asarray(unreached, bool).reshape(-1)
    rgb = turbo(u.reshape(-1), vmax, hit).reshape(*u.shape, 3)
    bgr = np.ascontiguousarray(np.round(rgb[..., ::-1] * 255.0).astype(np.uint8))
    bgr = over_range_marks(bgr, u > vmax)
    bar = _side_colorbar(u.shape[0], 90, vmax, label, over=True)
    return np.hstack([bgr, bar])
