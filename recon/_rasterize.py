"""The torch rasterizer behind :func:`recon.render.render` (Kerbl et al. 2023, Eqs. 1-3): pairs, then compositing.

Private to ``recon``: :mod:`recon.render` and :mod:`recon.pairs` call it; everyone else calls
:func:`recon.render.render` or :mod:`recon.pairs`. The conventions (alpha clamp 0.99, skip below 1/255, stop
before T < 1e-4) are the constants of :mod:`recon.render_types`. Every per-pair array is a 1-D tensor, because
on one CPU thread 1-D gathers and scatters are 10x faster than row gathers of [P, k] tensors.

1. :func:`build_pairs` (no gradient): visible Gaussians are sorted by depth, their 3-sigma boxes are expanded
   into rows (repeat_interleave / arange arithmetic, int32), and each row into only the pixels where
   alpha >= 1/255: along a row log alpha is a concave quadratic in dx, so those pixels form one interval,
   found from its roots. The list comes out Gaussian-major in depth order; alpha is computed per pair from
   per-row coefficients (one multiply-add chain and one exp), and one *stable* sort by pixel index yields
   (pixel, depth) order. Trimming instead of generating and filtering the whole box halves the pairs the CPU
   has to touch.
2. :class:`Composite`, a custom autograd function: log T is a segmented exclusive cumulative sum of
   log(1 - alpha) (a global float64 cumsum minus each pixel's base, :func:`transmittance`), the early stop is
   the mask T_i (1 - alpha_i) >= 1e-4, and weighted bincounts reduce weights to pixels. Its hand-written
   backward uses the suffix sums S_i = sum_{j > i} w_j (f_j . g) + T_final (bg . g) (again a float64 cumsum),
   dL/dalpha_i = T_i (f_i . g) - S_i / (1 - alpha_i), and reduces the conic and mean gradients per footprint
   row through the moments sum dP, sum dP dx, sum dP dx^2 (dy is constant along a row). Where alpha is clamped
   at 0.99 its gradient is zero (the true derivative; the reference CUDA code passes the gradient straight
   through the clamp).
"""

from __future__ import annotations

import math

import torch

from .projection import Projection
from .render_types import ALPHA_MAX, ALPHA_MIN, T_MIN, PairList


def _ranges(counts: torch.Tensor, total: int) -> tuple[torch.Tensor, torch.Tensor]:
    """For int32 segment lengths laid end to end: segment id [total] and offset within the segment (int32)."""
    seg = torch.repeat_interleave(
        torch.arange(counts.numel(), dtype=torch.int32, device=counts.device), counts, output_size=total
    )
    starts = torch.cumsum(counts, 0, dtype=torch.int32) - counts
    offset = torch.arange(total, dtype=torch.int32, device=counts.device) - starts.index_select(0, seg)
    return seg, offset


def build_pairs(proj: Projection, opacities: torch.Tensor, width: int, height: int) -> PairList:
    """Expand the visible footprints into (pixel, Gaussian) pairs sorted by pixel, then depth.

    Each footprint box is split into rows. Along a row (dy fixed) log alpha = qa dx^2 + qb dx + qc is a
    concave quadratic, so the pixels with alpha >= 1/255 form one interval, found from its roots (in
    float64, widened by 0.01 px); only those pixels are generated. Pairs that the widening let in with
    alpha < 1/255 get alpha = 0, which skips them exactly as the reference does.

    Args:
        proj: the projection of the view (no gradient is taken here).
        opacities: [N] opacities in (0, 1).
        width, height: image size, pixels.
    Returns:
        :class:`PairList`.
    """
    with torch.no_grad():
        means2d, conics, opacities = proj.means2d.detach(), proj.conics.detach(), opacities.detach()
        ids = torch.nonzero(proj.radii > 0).flatten()
        order = ids.index_select(0, torch.argsort(proj.depths.detach().index_select(0, ids), stable=True))
        x0, y0, x1, y1 = proj.boxes.index_select(0, order).unbind(-1)
        heights = y1 - y0 + 1
        row_seg, row_off = _ranges(heights, int(heights.sum()))
        row_gaussians = order.index_select(0, row_seg).to(torch.int32)
        row_x0 = x0.index_select(0, row_seg)
        row_y = y0.index_select(0, row_seg) + row_off
        box_widths = (x1 - x0 + 1).index_select(0, row_seg)

        u = means2d[:, 0].index_select(0, row_gaussians)
        v = means2d[:, 1].index_select(0, row_gaussians)
        row_dx0 = row_x0.to(u.dtype) + 0.5 - u
        row_dy = row_y.to(v.dtype) + 0.5 - v
        con = conics.index_select(0, row_gaussians)
        qa = -0.5 * con[:, 0]
        qb = -con[:, 1] * row_dy
        qc = -0.5 * con[:, 2] * row_dy * row_dy + torch.log(opacities.index_select(0, row_gaussians))

        # the interval of dx with log alpha >= log(1/255), then columns of the box inside it
        qa64, qb64 = qa.to(torch.float64), qb.to(torch.float64)
        disc = qb64 * qb64 - 4.0 * qa64 * (qc.to(torch.float64) - math.log(ALPHA_MIN))
        center = -qb64 / (2.0 * qa64)
        half = torch.sqrt(torch.clamp_min(disc, 0.0)) / (-2.0 * qa64) + 0.01
        dx0 = row_dx0.to(torch.float64)
        first = torch.clamp_min(torch.ceil(center - half - dx0), 0.0)
        last = torch.minimum(torch.floor(center + half - dx0), (box_widths - 1).to(torch.float64))
        counts = torch.where(disc >= 0.0, torch.clamp_min(last - first + 1.0, 0.0), 0.0).to(torch.int32)
        first = first.to(torch.int32)

        rows, cols = _ranges(counts, int(counts.sum()))
        cols = cols + first.index_select(0, rows)
        dx = row_dx0.index_select(0, rows) + cols.to(row_dx0.dtype)
        alpha = torch.exp((qa.index_select(0, rows) * dx + qb.index_select(0, rows)) * dx + qc.index_select(0, rows))
        alpha = torch.where(alpha >= ALPHA_MIN, alpha, torch.zeros_like(alpha))
        pixels = (row_y * width + row_x0).index_select(0, rows) + cols
        pixels, perm = torch.sort(pixels, stable=True)  # generation order is depth order within a pixel
        rows = rows.index_select(0, perm)
        return PairList(
            pixels=pixels,
            gaussians=row_gaussians.index_select(0, rows),
            rows=rows,
            dx=dx.index_select(0, perm),
            alpha=alpha.index_select(0, perm),
            row_gaussians=row_gaussians,
            row_dy=row_dy,
            candidates=int(box_widths.sum()),
        )


def _scatter_sum(index: torch.Tensor, values: torch.Tensor, size: int) -> torch.Tensor:
    """out[k] = sum of values[i] with index[i] == k, [size] (weighted bincount: faster than index_add_ on CPU)."""
    return torch.bincount(index, weights=values, minlength=size).to(values.dtype)


def transmittance(pairs: PairList, num_pixels: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per pair: clamped alpha, exclusive transmittance T_i and the live mask (before the early stop).

    Args:
        pairs: the pairs of one view (:func:`build_pairs`).
        num_pixels: W * H.
    Returns:
        alpha [P] clamped at 0.99, T_i [P] (alpha's dtype), live [P] bool (False at and after the early stop).
    """
    alpha, trans, live, _ = _transmittance_and_ends(pairs, num_pixels)
    return alpha, trans, live


def _transmittance_and_ends(pairs: PairList, num_pixels: int):
    """:func:`transmittance` plus, per pixel, the index of its last pair (-1 when it has none)."""
    alpha = pairs.alpha.clamp_max(ALPHA_MAX)
    log1m = torch.log1p(-alpha.to(torch.float64))
    csum = torch.cumsum(log1m, 0)
    excl = csum - log1m
    counts = torch.bincount(pairs.pixels, minlength=num_pixels)
    ends = torch.cumsum(counts, 0) - 1
    starts = ends + 1 - counts
    base = excl.index_select(0, starts.clamp_max(max(pairs.num - 1, 0))) if pairs.num else excl.new_zeros(num_pixels)
    log_t = excl - base.index_select(0, pairs.pixels)
    live = (log_t + log1m) >= math.log(T_MIN)
    return alpha, torch.exp(log_t).to(alpha.dtype), live, ends


class Composite(torch.autograd.Function):
    """Front-to-back compositing of sorted pairs, with a hand-written backward (see the module docstring).

    ``Composite.apply(means2d [N, 2], conics [N, 3], opacities [N], colors [N, 3], depths [N], background [3],
    pairs, num_pixels)`` -> (image [W*H, 3], accumulated opacity [W*H], depth [W*H]); gradients flow to the
    first six arguments.
    """

    @staticmethod
    def forward(ctx, means2d, conics, opacities, colors, depths, background, pairs: PairList, num_pixels: int):
        alpha, trans, live, ends = _transmittance_and_ends(pairs, num_pixels)
        weights = alpha * trans * live
        pix, gid = pairs.pixels, pairs.gaussians
        acc = _scatter_sum(pix, weights, num_pixels)
        t_final = 1.0 - acc
        channels = []
        for k in range(3):
            ck = colors[:, k].contiguous().index_select(0, gid)
            channels.append(_scatter_sum(pix, weights * ck, num_pixels) + t_final * background[k])
        image = torch.stack(channels, -1)
        depth = _scatter_sum(pix, weights * depths.index_select(0, gid), num_pixels)
        ctx.pairs = pairs
        ctx.save_for_backward(conics, opacities, colors, depths, background, alpha, trans, weights, live, t_final, ends)
        return image, acc, depth

    @staticmethod
    def backward(ctx, grad_image, grad_alpha, grad_depth):
        conics, opacities, colors, depths, background, alpha, trans, weights, live, t_final, ends = ctx.saved_tensors
        pairs: PairList = ctx.pairs
        pix, gid, n = pairs.pixels, pairs.gaussians, colors.shape[0]
        grad_image = grad_image.contiguous()
        gd = grad_depth.index_select(0, pix)
        dot = grad_alpha.index_select(0, pix) + depths.index_select(0, gid) * gd
        gathered = []
        for k in range(3):
            gk = grad_image[:, k].contiguous().index_select(0, pix)
            gathered.append(gk)
            dot = dot + colors[:, k].contiguous().index_select(0, gid) * gk
        # suffix sums S_i over the composited pairs after i in the same pixel, plus the background term
        csum = torch.cumsum((weights * dot).to(torch.float64), 0)
        total = csum.index_select(0, ends.clamp_min(0)) if pairs.num else csum.new_zeros(ends.numel())
        total = total + (t_final * (grad_image @ background)).to(torch.float64)
        suffix = total.index_select(0, pix) - csum
        grad_pair_alpha = torch.where(
            live, trans * dot - (suffix / (1.0 - alpha.to(torch.float64))).to(dot.dtype), torch.zeros_like(dot)
        )
        grad_colors = torch.stack([_scatter_sum(gid, weights * gk, n) for gk in gathered], -1)
        grad_depths = _scatter_sum(gid, weights * gd, n)

        # d alpha / d power = alpha below the clamp, 0 above it; moments per footprint row (dy is fixed there)
        grad_power = torch.where(pairs.alpha < ALPHA_MAX, grad_pair_alpha * alpha, torch.zeros_like(alpha))
        num_rows, rows, dx = pairs.row_dy.numel(), pairs.rows, pairs.dx
        gdx = grad_power * dx
        s0 = _scatter_sum(rows, grad_power, num_rows)
        s1 = _scatter_sum(rows, gdx, num_rows)
        s2 = _scatter_sum(rows, gdx * dx, num_rows)
        rg, dy = pairs.row_gaussians, pairs.row_dy
        ca, cb, cc = (conics[:, k].contiguous().index_select(0, rg) for k in range(3))
        # power = -1/2 (A dx^2 + C dy^2) - B dx dy with dx = px - u, dy = py - v
        row_grads = (ca * s1 + cb * dy * s0, cb * s1 + cc * dy * s0, -0.5 * s2, -dy * s1, -0.5 * dy * dy * s0, s0)
        per_gaussian = [_scatter_sum(rg, g, n) for g in row_grads]
        grad_means2d = torch.stack(per_gaussian[:2], -1)
        grad_conics = torch.stack(per_gaussian[2:5], -1)
        grad_opacities = per_gaussian[5] / opacities.clamp_min(torch.finfo(opacities.dtype).tiny)
        grad_background = (grad_image * t_final[:, None]).sum(0)
        return grad_means2d, grad_conics, grad_opacities, grad_colors, grad_depths, grad_background, None, None
