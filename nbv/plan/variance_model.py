"""ActiveNeRF view scores re-implemented on 3D Gaussians (Pan et al. 2022, "ActiveNeRF", Sec. 4; as FisherRF did).

ActiveNeRF models each radiance sample's colour as Gaussian with a learned variance and picks the view
whose observation would reduce the variance most. On 3D Gaussians:

- **Variance field.** Every Gaussian g carries a variance v_g = exp(log_v_g) (log-parameterised, so
  v > 0 and Adam steps are relative). The rendered variance of pixel p is composited like a colour,
  sigma^2_p = sum_i w_i v_i + floor, with the renderer's weights w_i = alpha_i T_i (the same as rendering
  a degree-0 Gaussian set whose colour is v over a black background; the tests check this).
- **Fit** (ActiveNeRF Eq. 7, the NLL term): with the Gaussians frozen, log_v minimises over the pixels
  of the selected views mean( ||C_p - C_gt||^2 / (2 sigma^2_p) + 1/2 log sigma^2_p ), by Adam for a
  configured number of iterations (warm-started by the planner from the previous round's v when the
  number of Gaussians did not change).
- **Score** (ActiveNeRF Eq. 11-12, the variance reduction of a candidate view), per pixel of the
  candidate, with w_i = alpha_i x the transmittance after Gaussian i (T_i (1 - alpha_i)):

      prior = 1e-4 + sum_i v_i w_i^2,   posterior = sum_i w_i^2 / (1 / v_i + w_i^2 / prior),

  and Score(T) = sum over the pixels of (prior - posterior). Every pixel counts, so an empty pixel adds
  the constant 1e-4 (equal for candidates of equal size).

:func:`variance_reduction_reference` (a loop over pixels and pairs) and
:func:`rendered_variance_reference` (through :func:`recon.render.render`) are the slow twins.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch

from recon.camera import Camera
from recon.gaussians import SH_C0, GaussianSet
from recon.pairs import ViewPairs, view_pairs
from recon.render import render

log = logging.getLogger(__name__)

PRIOR_FLOOR = 1e-4  # the constant of the prior variance of a pixel (ActiveNeRF)


@dataclass(frozen=True)
class VarianceConfig:
    """The ActiveNeRF-style variance planner.

    Attributes:
        seed: recorded for the registry contract; the fit is deterministic (no random initialisation).
        iterations: Adam iterations of the NLL fit at every selection (0 keeps the current v).
        learning_rate: Adam learning rate of log v.
        initial_variance: v of every Gaussian when the fit starts afresh (colour units squared).
        variance_floor: floor added to the rendered variance sigma^2_p in the NLL (colour units squared).
        prior_floor: the constant of the prior variance of a pixel in the score (ActiveNeRF: 1e-4).
        sh_degree: SH bands of the renders whose error the fit explains (None = all stored).
    """

    seed: int = 0
    iterations: int = 100
    learning_rate: float = 0.05
    initial_variance: float = 0.01
    variance_floor: float = 1e-4
    prior_floor: float = PRIOR_FLOOR
    sh_degree: int | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.seed, int) or isinstance(self.seed, bool):
            raise ValueError(f"VarianceConfig.seed must be an int, got {self.seed!r}")
        if not isinstance(self.iterations, int) or self.iterations < 0:
            raise ValueError(f"VarianceConfig.iterations must be an int >= 0, got {self.iterations!r}")
        for name in ("learning_rate", "initial_variance", "variance_floor", "prior_floor"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"VarianceConfig.{name} must be a finite number > 0, got {value!r}")
        if self.sh_degree is not None and self.sh_degree not in (0, 1, 2, 3):
            raise ValueError(f"VarianceConfig.sh_degree must be None or 0..3, got {self.sh_degree!r}")


def rendered_variance(pairs: ViewPairs, variances: torch.Tensor) -> torch.Tensor:
    """[H * W] sum_i w_i v_i per pixel (no floor), differentiable w.r.t. ``variances`` [N]."""
    return pairs.pixel_sum(pairs.weights * variances.index_select(0, pairs.gaussians))


def rendered_variance_reference(gaussians: GaussianSet, camera: Camera, variances: torch.Tensor) -> torch.Tensor:
    """Twin of :func:`rendered_variance` through the renderer: a degree-0 set whose colour is v, black background.

    Returns:
        [H * W].
    """
    g = gaussians.detach()
    dc = ((variances - 0.5) / SH_C0)[:, None, None].expand(g.num, 1, 3)
    painted = GaussianSet(g.means, g.quats, g.log_scales, g.opacity_logits, dc.contiguous())
    return render(painted, camera, 0.0, backend="torch").image[..., 0].reshape(-1)


def variance_reduction(pairs: ViewPairs, variances: torch.Tensor, prior_floor: float = PRIOR_FLOOR) -> torch.Tensor:
    """Score(T) = sum over pixels of (prior - posterior) (module docstring), float64 scalar tensor.

    Args:
        pairs: :class:`recon.pairs.ViewPairs` of the candidate view.
        variances: [N] v > 0.
        prior_floor: the constant of the prior.
    """
    v = variances.detach().to(torch.float64).index_select(0, pairs.gaussians)
    w2 = (pairs.alpha * pairs.transmittance_after).to(torch.float64) ** 2
    prior = prior_floor + pairs.pixel_sum(v * w2)
    posterior = pairs.pixel_sum(w2 / (1.0 / v + w2 / prior.index_select(0, pairs.pixels)))
    return (prior - posterior).sum()


def variance_reduction_reference(pairs: ViewPairs, variances: torch.Tensor, prior_floor: float = PRIOR_FLOOR) -> float:
    """Loop twin of :func:`variance_reduction`: pixel by pixel, pair by pair, in python floats."""
    by_pixel: dict[int, list[tuple[float, float]]] = {}
    for p in range(pairs.num):
        if bool(pairs.live[p]):
            a, t, v = float(pairs.alpha[p]), float(pairs.transmittance[p]), float(variances[pairs.gaussians[p]])
            by_pixel.setdefault(int(pairs.pixels[p]), []).append((a * t * (1.0 - a), v))
    total = 0.0
    for pixel in range(pairs.num_pixels):
        items = by_pixel.get(pixel, [])
        prior = prior_floor + sum(v * w * w for w, v in items)
        posterior = sum(w * w / (1.0 / v + w * w / prior) for w, v in items)
        total += prior - posterior
    return total


def nll_loss(
    log_variances: torch.Tensor, pairs: Sequence[ViewPairs], squared_errors: Sequence[torch.Tensor], floor: float
) -> torch.Tensor:
    """mean over all pixels of ||C - C_gt||^2 / (2 sigma^2) + 1/2 log sigma^2, sigma^2 = sum w v + floor.

    Args:
        log_variances: [N] log v.
        pairs: the selected views' pairs. squared_errors: per view [H * W] ||C_p - C_gt||^2 (channels summed).
        floor: added to sigma^2.
    """
    v = torch.exp(log_variances)
    terms = []
    for vp, err in zip(pairs, squared_errors, strict=True):
        sigma2 = rendered_variance(vp, v) + floor
        terms.append(err / (2.0 * sigma2) + 0.5 * torch.log(sigma2))
    return torch.cat(terms).mean()


@dataclass
class VarianceFit:
    """Result of :func:`fit_variances`: log v [N] and the NLL before and after."""

    log_variances: torch.Tensor
    loss_before: float
    loss_after: float

    @property
    def variances(self) -> torch.Tensor:
        return torch.exp(self.log_variances)


def _check_fit_inputs(views: Sequence, init_log_variances: torch.Tensor | None, n: int) -> None:
    """Every view has its image, and a warm start has one value per Gaussian."""
    for i, view in enumerate(views):
        if getattr(view, "image", None) is None:
            raise ValueError(
                f"fit_variances: train view {i} ({getattr(view, 'name', '?')}) has no image; "
                "the variance fit needs the captured images of the selected views"
            )
    if init_log_variances is not None and tuple(init_log_variances.shape) != (n,):
        raise ValueError(
            f"fit_variances: init_log_variances has shape {tuple(init_log_variances.shape)}, "
            f"expected ({n},); start afresh with None when the Gaussians changed"
        )


def _pairs_and_errors(
    g: GaussianSet, views: Sequence, background: torch.Tensor | float | None, config: VarianceConfig
) -> tuple[list, list]:
    """Per view: its (pixel, Gaussian) pairs and its per-pixel squared colour error [H W] (float64) of the frozen
    render against the captured image."""
    all_pairs, errors = [], []
    with torch.no_grad():
        for view in views:
            cam = view.camera
            image = render(g, cam, background, sh_degree=config.sh_degree).image
            gt = view.image.to(device=image.device, dtype=image.dtype)
            if gt.shape != image.shape:
                raise ValueError(
                    f"fit_variances: view {getattr(view, 'name', '?')} image {tuple(gt.shape)} does "
                    f"not match its camera {tuple(image.shape)}; load images at the camera's size"
                )
            all_pairs.append(view_pairs(g, cam))
            errors.append(((image - gt) ** 2).sum(-1).reshape(-1).to(torch.float64))
    return all_pairs, errors


def _as_one_strip(all_pairs: list, errors: list) -> tuple[list, list]:
    """All views as one strip of pixels: one gather and one scatter per iteration."""
    offsets = [0]
    for vp in all_pairs:
        offsets.append(offsets[-1] + vp.num_pixels)
    merged = [
        ViewPairs(
            torch.cat([vp.pixels + off for vp, off in zip(all_pairs, offsets, strict=False)]),
            torch.cat([vp.gaussians for vp in all_pairs]),
            torch.cat([vp.alpha for vp in all_pairs]),
            torch.cat([vp.transmittance for vp in all_pairs]),
            torch.cat([vp.live for vp in all_pairs]),
            torch.cat([vp.weights for vp in all_pairs]).to(torch.float64),
            offsets[-1],
            1,
        )
    ]
    return merged, [torch.cat(errors)]


def fit_variances(
    gaussians: GaussianSet,
    views: Sequence,
    background: torch.Tensor | float | None,
    config: VarianceConfig = VarianceConfig(),
    init_log_variances: torch.Tensor | None = None,
) -> VarianceFit:
    """Fit the per-Gaussian variances on the selected views with the Gaussians frozen (ActiveNeRF NLL).

    Args:
        gaussians: N Gaussians (not modified).
        views: the selected views, each with ``camera`` and ``image`` [H, W, 3] (``recon.datasets.View``).
        background: the render background ([3] tensor, grey level or None).
        config: :class:`VarianceConfig`.
        init_log_variances: [N] warm start (None = log(initial_variance) everywhere).
    Returns:
        :class:`VarianceFit`.
    """
    n = gaussians.num
    _check_fit_inputs(views, init_log_variances, n)
    g = gaussians.detach()
    all_pairs, errors = _pairs_and_errors(g, views, background, config)
    start = (
        torch.full((n,), math.log(config.initial_variance), dtype=torch.float64, device=g.device)
        if init_log_variances is None
        else init_log_variances.detach().to(device=g.device, dtype=torch.float64)
    )
    log_v = start.clone().requires_grad_(True)
    if not views:
        return VarianceFit(log_v.detach(), math.nan, math.nan)
    merged, merged_errors = _as_one_strip(all_pairs, errors)
    with torch.enable_grad():
        optimizer = torch.optim.Adam([log_v], lr=config.learning_rate)
        before = float(nll_loss(log_v.detach(), merged, merged_errors, config.variance_floor))
        for _ in range(config.iterations):
            optimizer.zero_grad()
            loss = nll_loss(log_v, merged, merged_errors, config.variance_floor)
            loss.backward()
            optimizer.step()
        after = float(nll_loss(log_v.detach(), merged, merged_errors, config.variance_floor))
    log.debug(
        "variance fit: NLL %.5g -> %.5g over %d views, %d iterations", before, after, len(views), config.iterations
    )
    return VarianceFit(log_v.detach(), before, after)


def variance_scores(
    gaussians: GaussianSet,
    candidates: Sequence[Camera],
    variances: torch.Tensor,
    prior_floor: float = PRIOR_FLOOR,
    progress=None,
) -> list[float]:
    """Score(T) of every candidate camera (module docstring).

    Args:
        gaussians: N Gaussians. candidates: C cameras. variances: [N] v > 0. prior_floor: the prior constant.
        progress: optional callable wrapping an iterable (e.g. ``tqdm``).
    Returns:
        C floats.
    """
    if tuple(variances.shape) != (gaussians.num,):
        raise ValueError(
            f"variance_scores: variances {tuple(variances.shape)} must be [{gaussians.num}] "
            "(one per Gaussian); refit them after densification"
        )
    positions = range(len(candidates))
    v = variances.to(gaussians.device)
    return [
        float(variance_reduction(view_pairs(gaussians, candidates[i]), v, prior_floor))
        for i in (progress(positions) if progress is not None else positions)
    ]
