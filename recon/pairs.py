"""Per-(pixel, Gaussian) compositing quantities of one view, for view planners (Kerbl et al. 2023, Eqs. 1-3).

The renderer (:mod:`recon.render`) composites a pixel front to back,

    C = sum_i c_i w_i + T_final * background,   w_i = alpha_i T_i,   T_i = prod_{j < i} (1 - alpha_j),

over a sparse list of (pixel, Gaussian) pairs sorted by pixel, then depth. Next-best-view scores need
these per-pair quantities themselves, not only their sums:

- :func:`view_pairs` returns, per pair, the pixel, the Gaussian, the (clamped) alpha, the transmittance
  T_i before the Gaussian, the live mask (pairs at or after a pixel's early stop are not composited) and
  the compositing weight w_i = alpha_i T_i [live]. The ActiveNeRF-style variance planner
  (:mod:`nbv.plan.variance_model`) uses alpha_i * T_after_i with T_after_i = T_i (1 - alpha_i).
- :func:`pair_attribute_gradients` returns, per pair p = (pixel, Gaussian g), the gradient of the pixel's
  colour summed over channels, sum_c C_{p,c}, with respect to g's 2-D attributes a_g = (means2d 2,
  conic 3, opacity 1, colour 3). FisherRF (:mod:`nbv.plan.fisher_info`) needs per-pixel Jacobians; the gradient
  of the summed image would add the contributions of all pixels before squaring and let them cancel.
  Here every pair gets its own copy of its Gaussian's attributes (a PairList whose "Gaussians" and
  footprint rows are the pairs themselves), so one backward pass of the renderer's own compositing
  function yields every per-pair gradient at once: copy p only influences the pixel of pair p.

The pair list and the compositing are the renderer's (:mod:`recon._rasterize`: same skip and early-stop rules),
so sums of these quantities reproduce the rendered image and opacity exactly (the tests check this).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ._rasterize import Composite, build_pairs, transmittance
from .camera import Camera
from .gaussians import GaussianSet
from .projection import Projection, project_gaussians
from .render import gaussian_colors
from .render_types import ALPHA_MAX, PairList, background_tensor

ATTRIBUTES = ("u", "v", "conic_a", "conic_b", "conic_c", "opacity", "red", "green", "blue")  # columns of a_g


@dataclass
class ViewPairs:
    """The composited (pixel, Gaussian) pairs of one view, sorted by pixel, then by depth.

    Attributes:
        pixels: [P] int32 pixel index y * W + x.
        gaussians: [P] int32 Gaussian index.
        alpha: [P] alpha_i clamped at 0.99 (0 for a skipped pair with alpha < 1/255).
        transmittance: [P] T_i, the transmittance in front of the Gaussian.
        live: [P] bool, False at and after the pixel's early stop (not composited).
        weights: [P] w_i = alpha_i T_i where live, else 0.
        width, height: image size, pixels.
    """

    pixels: torch.Tensor
    gaussians: torch.Tensor
    alpha: torch.Tensor
    transmittance: torch.Tensor
    live: torch.Tensor
    weights: torch.Tensor
    width: int
    height: int

    @property
    def num(self) -> int:
        """P, the number of pairs."""
        return int(self.pixels.numel())

    @property
    def num_pixels(self) -> int:
        return self.width * self.height

    @property
    def transmittance_after(self) -> torch.Tensor:
        """[P] T_i (1 - alpha_i), the transmittance behind the Gaussian (0 for pairs that are not live)."""
        return torch.where(self.live, self.transmittance * (1.0 - self.alpha), torch.zeros_like(self.alpha))

    def pixel_sum(self, values: torch.Tensor) -> torch.Tensor:
        """[H * W] per-pixel sums of per-pair ``values`` [P] (differentiable w.r.t. ``values``)."""
        out = torch.zeros(self.num_pixels, dtype=values.dtype, device=values.device)
        return out.index_add(0, self.pixels, values)


def _pairs_of(gaussians: GaussianSet, camera: Camera) -> tuple[Projection, PairList]:
    proj = project_gaussians(gaussians, camera)
    return proj, build_pairs(proj, gaussians.opacities, camera.width, camera.height)


def view_pairs(gaussians: GaussianSet, camera: Camera) -> ViewPairs:
    """The per-pair compositing quantities of one view (no gradient).

    Args:
        gaussians: N Gaussians (float32 or float64, any device).
        camera: the view, W x H pixels.
    Returns:
        :class:`ViewPairs`; ``pixel_sum(weights)`` is the rendered opacity ``render(...).alpha`` (flattened).

    Example:
        >>> pairs = view_pairs(gaussians, camera)
        >>> opacity = pairs.pixel_sum(pairs.weights).reshape(camera.height, camera.width)
    """
    if not isinstance(gaussians, GaussianSet):
        raise ValueError(f"gaussians must be a GaussianSet, got {type(gaussians).__name__}")
    with torch.no_grad():
        g = gaussians.detach()
        _, pairs = _pairs_of(g, camera)
        alpha, trans, live = transmittance(pairs, camera.width * camera.height)
        weights = torch.where(live, alpha * trans, torch.zeros_like(alpha))
    return ViewPairs(
        pixels=pairs.pixels,
        gaussians=pairs.gaussians,
        alpha=alpha,
        transmittance=trans,
        live=live,
        weights=weights,
        width=camera.width,
        height=camera.height,
    )


@dataclass
class PairGradients:
    """Per-pair gradients of a pixel's channel-summed colour w.r.t. its Gaussian's 2-D attributes.

    Attributes:
        pixels: [P] int32 pixel of each pair.
        gaussians: [P] int32 Gaussian of each pair.
        grads: [P, 9] d(sum_c C_{pixel,c}) / d a_g, columns as :data:`ATTRIBUTES` (means2d u, v in pixels,
            conic A, B, C in 1/px^2, opacity, colour R, G, B). Zero for skipped or stopped pairs. The three colour
            columns are equal (each is the pair's compositing weight w_p). The fast path stores it attribute-major
            (``grads.T`` is contiguous).
        image: [H, W, 3] the rendered image (identical to ``render(...).image``).
    """

    pixels: torch.Tensor
    gaussians: torch.Tensor
    grads: torch.Tensor
    image: torch.Tensor


def _weighted_bincount(index: torch.Tensor, values: torch.Tensor, size: int) -> torch.Tensor:
    """out[k] = sum of values[i] with index[i] == k, [size], as the compositing sums it (a weighted bincount)."""
    return torch.bincount(index, weights=values, minlength=size).to(values.dtype)


def _check_degree(gaussians: GaussianSet, sh_degree: int | None) -> int:
    if not isinstance(gaussians, GaussianSet):
        raise ValueError(f"gaussians must be a GaussianSet, got {type(gaussians).__name__}")
    degree = gaussians.sh_degree if sh_degree is None else sh_degree
    if not isinstance(degree, int) or not 0 <= degree <= gaussians.sh_degree:
        raise ValueError(f"sh_degree must be an int in 0..{gaussians.sh_degree} (the stored degree), got {sh_degree!r}")
    return degree


def pair_attribute_gradients(
    gaussians: GaussianSet,
    camera: Camera,
    background: torch.Tensor | float | None = None,
    *,
    sh_degree: int | None = None,
) -> PairGradients:
    """Per-(pixel, Gaussian) gradients of the channel-summed pixel colour w.r.t. the 2-D attributes.

    The closed form of the compositing backward (:mod:`recon._rasterize`) with a unit gradient on every pixel's
    three channels, evaluated per pair instead of summed per Gaussian: with f_p the pair's colour summed over the
    channels and S_p = sum over the composited pairs q behind p in its pixel of w_q f_q, plus T_final sum(bg),

        d C / d colour_c = w_p,   d C / d alpha_p = T_p f_p - S_p / (1 - alpha_p),
        d C / d power_p = alpha_p d C / d alpha_p (0 where alpha is clamped at 0.99),

    and power = -1/2 (A dx^2 + C dy^2) - B dx dy gives the mean and conic columns, alpha = o exp(power) the
    opacity column. No autograd graph and no per-pair copies: the arithmetic is the twin's
    (:func:`pair_attribute_gradients_reference`), operation for operation, so the results are bit-identical.

    Args:
        gaussians: N Gaussians (float32 or float64; gradients are not taken w.r.t. them).
        camera: the view, W x H pixels.
        background: [3] tensor, float grey level or None (black); the background enters through T_final.
        sh_degree: SH bands used for the colours (None = all stored).
    Returns:
        :class:`PairGradients` with P pairs.

    Example:
        >>> pg = pair_attribute_gradients(gaussians, camera, 1.0)
        >>> pg.grads.shape == (pg.pixels.numel(), 9)
        True
    """
    degree = _check_degree(gaussians, sh_degree)
    g = gaussians.detach()
    bg = background_tensor(background, g.means)
    w, h = camera.width, camera.height
    num_pixels = w * h
    with torch.no_grad():
        proj, pairs = _pairs_of(g, camera)
        colors = gaussian_colors(g, camera, degree)
        alpha, trans, live = transmittance(pairs, num_pixels)
        ends = torch.cumsum(torch.bincount(pairs.pixels, minlength=num_pixels), 0) - 1  # each pixel's last pair
        weights = alpha * trans * live
        pix, gid = pairs.pixels, pairs.gaussians
        t_final = 1.0 - _weighted_bincount(pix, weights, num_pixels)
        pair_colors = [colors[:, k].contiguous().index_select(0, gid) for k in range(3)]
        image = torch.stack(
            [_weighted_bincount(pix, weights * c, num_pixels) + t_final * bg[k] for k, c in enumerate(pair_colors)], -1
        )
        dot = (pair_colors[0] + pair_colors[1]) + pair_colors[2]
        # suffix sums over the composited pairs behind each pair, plus the background term (float64 cumsum)
        csum = torch.cumsum((weights * dot).to(torch.float64), 0)
        total = csum.index_select(0, ends.clamp_min(0)) if pairs.num else csum.new_zeros(ends.numel())
        total = total + (t_final * (torch.ones(num_pixels, 3, dtype=bg.dtype, device=bg.device) @ bg)).to(torch.float64)
        suffix = total.index_select(0, pix) - csum
        grad_alpha = torch.where(
            live, trans * dot - (suffix / (1.0 - alpha.to(torch.float64))).to(dot.dtype), torch.zeros_like(dot)
        )
        grad_power = torch.where(pairs.alpha < ALPHA_MAX, grad_alpha * alpha, torch.zeros_like(alpha))
        dx, dy = pairs.dx, pairs.row_dy.index_select(0, pairs.rows)
        s1 = grad_power * dx
        ca, cb, cc = (proj.conics[:, k].contiguous().index_select(0, gid) for k in range(3))
        opacities = g.opacities.index_select(0, gid)
        columns = (
            ca * s1 + cb * dy * grad_power,
            cb * s1 + cc * dy * grad_power,
            -0.5 * (s1 * dx),
            -dy * s1,
            -0.5 * dy * dy * grad_power,
            grad_power / opacities.clamp_min(torch.finfo(opacities.dtype).tiny),
            weights,
            weights,
            weights,
        )
        grads = torch.stack(columns, 0).T  # [P, 9] over attribute-major storage: .T is contiguous
    return PairGradients(pixels=pix, gaussians=gid, grads=grads, image=image.reshape(h, w, 3))


def pair_attribute_gradients_reference(
    gaussians: GaussianSet,
    camera: Camera,
    background: torch.Tensor | float | None = None,
    *,
    sh_degree: int | None = None,
) -> PairGradients:
    """Autograd twin of :func:`pair_attribute_gradients`: one forward and one backward pass of the renderer's
    compositing (:class:`recon._rasterize.Composite`) over per-pair copies of the attributes (see the module
    docstring). Same Args and Returns; the results are bit-identical.
    """
    degree = _check_degree(gaussians, sh_degree)
    g = gaussians.detach()
    bg = background_tensor(background, g.means)
    w, h = camera.width, camera.height
    with torch.no_grad():
        proj, pairs = _pairs_of(g, camera)
        colors = gaussian_colors(g, camera, degree)
        opacities = g.opacities
    gid = pairs.gaussians
    own = torch.arange(pairs.num, dtype=torch.int32, device=gid.device)
    per_pair = PairList(
        pixels=pairs.pixels,
        gaussians=own,
        rows=own,
        dx=pairs.dx,
        alpha=pairs.alpha,
        row_gaussians=own,
        row_dy=pairs.row_dy.index_select(0, pairs.rows),
        candidates=pairs.candidates,
    )
    leaves = [t.index_select(0, gid).requires_grad_(True) for t in (proj.means2d, proj.conics, opacities, colors)]
    with torch.enable_grad():
        image, _, _ = Composite.apply(*leaves, proj.depths.index_select(0, gid), bg, per_pair, w * h)
        grads = torch.autograd.grad(image.sum(), leaves)
    stacked = torch.cat([grads[0], grads[1], grads[2][:, None], grads[3]], -1)
    return PairGradients(pixels=pairs.pixels, gaussians=gid, grads=stacked, image=image.detach().reshape(h, w, 3))
