"""Adaptive density control of 3D Gaussians (Kerbl et al. 2023, "3D Gaussian Splatting", Sec. 5.2).

Every few iterations the trainer looks at the mean norm of the view-space (NDC) positional gradient of
each Gaussian over the views that saw it since the last density step. Gaussians above the threshold
are under-reconstructed: small ones (largest scale <= percent_dense x scene extent) are cloned, large
ones are split into two children sampled from N(mu, Sigma) with scales divided by 1.6 (= 0.8 x 2).
Then nearly transparent Gaussians (opacity < min_opacity) are pruned, and, once the opacity has been
reset once, Gaussians that are too big on screen (> max_screen_size px) or in the world (largest scale
> big_world_fraction x extent). Periodically the opacities are clamped to at most 0.01 (the opacity
reset) so that floaters must earn their opacity back.

The functions here are pure: they take a :class:`~recon.gaussians.GaussianSet` and statistics and
return the new set together with the row ``origin`` map that the optimiser needs for its state surgery.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from .gaussians import GaussianSet, concat


def ndc_gradient(means2d_grad: torch.Tensor, width: int, height: int) -> torch.Tensor:
    """Convert a gradient w.r.t. pixel positions into one w.r.t. NDC positions, as the reference accumulates.

    pixel = ((ndc + 1) W - 1) / 2, so dL/dndc = dL/dpixel * W / 2 (and H / 2 for y).

    Args:
        means2d_grad: [N, 2] dL/d(u, v) in 1/pixel.
        width, height: image size, pixels.
    Returns:
        [N, 2] dL/d(ndc_x, ndc_y).
    """
    scale = torch.tensor([0.5 * width, 0.5 * height], dtype=means2d_grad.dtype, device=means2d_grad.device)
    return means2d_grad * scale


@dataclass
class DensityStats:
    """Statistics gathered between two density-control steps.

    Attributes:
        grad_accum: [N] sum over the views that saw Gaussian i of |dL/d ndc_i|.
        denom: [N] number of those views.
        max_radii2d: [N] largest screen-space radius (pixels) of Gaussian i in those views.
    """

    grad_accum: torch.Tensor
    denom: torch.Tensor
    max_radii2d: torch.Tensor

    @classmethod
    def zeros(cls, n: int, device=None, dtype: torch.dtype = torch.float32) -> DensityStats:
        return cls(
            torch.zeros(n, dtype=dtype, device=device),
            torch.zeros(n, dtype=dtype, device=device),
            torch.zeros(n, dtype=dtype, device=device),
        )

    @torch.no_grad()
    def update(self, ndc_grad: torch.Tensor, radii: torch.Tensor, visible: torch.Tensor) -> None:
        """Add one view: the NDC gradient norm and the radius of the visible Gaussians.

        Args:
            ndc_grad: [N, 2] view-space positional gradient in NDC units (see :func:`ndc_gradient`).
            radii: [N] screen-space radius in pixels.
            visible: [N] bool, Gaussians that the view rendered (radii > 0).
        """
        vis = visible.to(torch.bool)
        self.grad_accum[vis] += ndc_grad[vis, :2].norm(dim=-1).to(self.grad_accum.dtype)
        self.denom[vis] += 1
        self.max_radii2d[vis] = torch.maximum(self.max_radii2d[vis], radii[vis].to(self.max_radii2d.dtype))

    def mean_grad(self) -> torch.Tensor:
        """[N] mean NDC gradient norm over the views that saw each Gaussian (0 when none did)."""
        return torch.where(self.denom > 0, self.grad_accum / self.denom.clamp_min(1), torch.zeros_like(self.denom))


@dataclass(frozen=True)
class DensifyResult:
    """What one density-control step did.

    Attributes:
        gaussians: the new set, [M] Gaussians: surviving old ones first (in their old order), then clones,
            then split children.
        origin: [M] int64, the old row each new row continues, -1 for a clone or a split child.
        cloned, split, pruned: counts (split counts parents; each parent becomes two children).
        max_radii2d: [M] the screen radii carried to the new rows (parents' values for children).
    """

    gaussians: GaussianSet
    origin: torch.Tensor
    cloned: int
    split: int
    pruned: int
    max_radii2d: torch.Tensor


def _limit(candidates: torch.Tensor, grads: torch.Tensor, budget: int | None) -> torch.Tensor:
    """Keep at most ``budget`` of the candidate rows, those with the largest gradients."""
    if budget is None or int(candidates.sum()) <= budget:
        return candidates
    limited = torch.zeros_like(candidates)
    if budget > 0:
        idx = torch.nonzero(candidates).flatten()
        order = torch.argsort(grads[idx], descending=True, stable=True)
        limited[idx[order[:budget]]] = True
    return limited


def split_samples(
    gaussians: GaussianSet, mask: torch.Tensor, generator: torch.Generator | None, n_children: int = 2
) -> GaussianSet:
    """The children of the Gaussians selected by ``mask``: means from N(mu, Sigma), scales / (0.8 n).

    Children are tiled as in the reference trainer: all first children, then all second children.

    Args:
        gaussians: the current set.
        mask: [N] bool, the parents.
        generator: random source of the samples (CPU generator for CPU tensors).
        n_children: children per parent (2 in 3DGS).
    Returns:
        The ``n_children * mask.sum()`` children.
    """
    parents = gaussians.subset(mask)
    stds = parents.scales.repeat(n_children, 1)
    noise = torch.randn(stds.shape, generator=generator, dtype=stds.dtype, device="cpu").to(stds.device)
    samples = noise * stds
    rots = parents.rotations().repeat(n_children, 1, 1)
    means = (rots @ samples[..., None])[..., 0] + parents.means.repeat(n_children, 1)
    log_scales = torch.log(stds / (0.8 * n_children))
    return GaussianSet(
        means,
        parents.quats.repeat(n_children, 1),
        log_scales,
        parents.opacity_logits.repeat(n_children),
        parents.sh.repeat(n_children, 1, 1),
    )


@torch.no_grad()
def densify_and_prune(
    gaussians: GaussianSet,
    stats: DensityStats,
    *,
    grad_threshold: float,
    percent_dense: float,
    extent: float,
    min_opacity: float,
    max_screen_size: float | None,
    big_world_fraction: float | None,
    generator: torch.Generator | None,
    max_gaussians: int | None = None,
    densify: bool = True,
) -> DensifyResult:
    """One step of adaptive density control: clone, split, then prune (reference order).

    Args:
        gaussians: current set, N Gaussians.
        stats: gradient and radius statistics of the N Gaussians.
        grad_threshold: mean NDC gradient norm above which a Gaussian is densified (2e-4 in 3DGS).
        percent_dense: size limit between clone and split, as a fraction of ``extent`` (0.01).
        extent: scene extent (1.1 x radius of the camera centres' bounding sphere), scene units.
        min_opacity: prune below this opacity (0.005).
        max_screen_size: prune Gaussians whose radius exceeded this many pixels; None disables the
            size pruning (also the world-size rule, as in the reference trainer).
        big_world_fraction: prune Gaussians whose largest scale exceeds this fraction of ``extent`` (0.1)
            when ``max_screen_size`` is set; None disables it.
        generator: random source of the split samples.
        max_gaussians: optional cap on the count after densification (the largest gradients win); not in
            the reference trainer, used to bound the cost of CPU runs and the size of the bundled asset.
        densify: False prunes only.
    Returns:
        A :class:`DensifyResult`.
    """
    n = gaussians.num
    device = gaussians.device
    grads = stats.mean_grad().to(device)
    big_scale = gaussians.scales.max(dim=-1).values
    if densify:
        hot = grads >= grad_threshold
        clone = hot & (big_scale <= percent_dense * extent)
        split = hot & (big_scale > percent_dense * extent)
        budget = None if max_gaussians is None else max(0, max_gaussians - n)
        if budget is not None:  # clones and splits both add one Gaussian net
            both = _limit(clone | split, grads, budget)
            clone, split = clone & both, split & both
    else:
        clone = split = torch.zeros(n, dtype=torch.bool, device=device)
    clones = gaussians.subset(clone)
    children = split_samples(gaussians, split, generator)
    all_set = concat([gaussians, clones, children])
    origin = torch.cat([torch.arange(n, device=device), torch.full((clones.num + children.num,), -1, device=device)])
    radii = torch.cat(
        [
            stats.max_radii2d.to(device),
            stats.max_radii2d.to(device)[clone],
            stats.max_radii2d.to(device)[split].repeat(2),
        ]
    )
    # Split parents are replaced by their children; then the opacity and size rules apply to everyone.
    remove = torch.cat([split, torch.zeros(clones.num + children.num, dtype=torch.bool, device=device)])
    prune = all_set.opacities < min_opacity
    if max_screen_size is not None:
        prune |= radii > max_screen_size
        if big_world_fraction is not None:
            prune |= all_set.scales.max(dim=-1).values > big_world_fraction * extent
    keep = ~(remove | prune)
    return DensifyResult(
        all_set.subset(keep),
        origin[keep],
        int(clone.sum()),
        int(split.sum()),
        int((prune & ~remove).sum()),
        radii[keep],
    )


@torch.no_grad()
def reset_opacity(opacity_logits: torch.Tensor, ceiling: float = 0.01) -> torch.Tensor:
    """Opacity reset: logits of min(opacity, ``ceiling``) (Kerbl et al. Sec. 5.2).

    Args:
        opacity_logits: [N].
        ceiling: the largest opacity kept, in (0, 1).
    Returns:
        [N] new logits.
    """
    opac = torch.sigmoid(opacity_logits).clamp_max(ceiling)
    return torch.log(opac / (1.0 - opac))
