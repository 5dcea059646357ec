"""Differentiable 3DGS rendering: one function, two backends (Kerbl et al. 2023, "3D Gaussian Splatting", Eqs. 1-3, 5).

A pixel's colour is front-to-back alpha compositing of the Gaussians covering it, sorted by view depth:

    C = sum_i c_i alpha_i T_i + T_final * background,   T_i = prod_{j < i} (1 - alpha_j),
    alpha_i = min(0.99, o_i exp(-1/2 d_i^T Sigma'^-1 d_i)),

with the conventions of the reference CUDA rasterizer (diff-gaussian-rasterization): a (pixel,
Gaussian) pair with alpha < 1/255 is skipped, and a pixel stops at the first Gaussian that would bring
its transmittance below 1e-4 (that Gaussian is not composited). The accumulated opacity is
``alpha = 1 - T_final`` and the depth map is ``sum_i alpha_i T_i z_i`` (not normalised by alpha).
Colours come from SH (:mod:`recon.sh`), the projection from :mod:`recon.projection`.

The modules of the renderer, none of which imports another for a type:

- :mod:`recon.render_types`: :class:`RenderOutput`, :class:`PairList`, the alpha conventions and the
  background check, shared by every backend;
- :mod:`recon._rasterize`: the torch rasterizer, CPU-first (the sparse pair list :func:`build_pairs`, then
  compositing with a hand-written backward; its docstring explains the layout);
- :mod:`recon.render_gsplat`: gsplat's CUDA rasterizer behind the same function (``backend="gsplat"``);
- this module: the input checks, the SH colours, :func:`render` and :func:`pair_statistics`.

``render_dense_reference`` in :mod:`recon.render_reference` is the slow twin (every pixel x every
Gaussian, sequential in depth, autograd) that the tests compare against. The names of
:mod:`recon.render_types` and ``build_pairs`` stay importable from here.
"""

from __future__ import annotations

import torch

from ._rasterize import Composite, build_pairs, transmittance
from .camera import Camera
from .gaussians import GaussianSet
from .projection import project_gaussians, view_directions
from .render_gsplat import gsplat_available, render_gsplat
from .render_types import ALPHA_MAX, ALPHA_MIN, T_MIN, PairList, RenderOutput, background_tensor
from .sh import sh_to_color

__all__ = [
    "ALPHA_MAX",
    "ALPHA_MIN",
    "BACKENDS",
    "T_MIN",
    "PairList",
    "RenderOutput",
    "build_pairs",
    "gaussian_colors",
    "pair_statistics",
    "render",
    "render_layers",
]

BACKENDS = ("auto", "torch", "gsplat")


def _check_inputs(gaussians: GaussianSet, camera: Camera, sh_degree: int | None, backend: str) -> int:
    """Validate the arguments of :func:`render`; return the SH degree to use."""
    if not isinstance(gaussians, GaussianSet):
        raise ValueError(f"gaussians must be a GaussianSet, got {type(gaussians).__name__}")
    if not isinstance(camera, Camera):
        raise ValueError(f"camera must be a recon.camera.Camera, got {type(camera).__name__}")
    if gaussians.dtype not in (torch.float32, torch.float64):
        raise ValueError(f"Gaussians must be float32 or float64, got {gaussians.dtype}; convert with .to(dtype=...)")
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    stored = gaussians.sh_degree
    degree = stored if sh_degree is None else sh_degree
    if not isinstance(degree, int) or not 0 <= degree <= stored:
        raise ValueError(f"sh_degree must be an int in 0..{stored} (the stored degree), got {sh_degree!r}")
    for name in ("means", "quats", "log_scales", "opacity_logits"):
        if not torch.isfinite(getattr(gaussians, name)).all():
            raise ValueError(f"GaussianSet.{name} has NaN or Inf values; repair or prune those Gaussians")
    return degree


def gaussian_colors(gaussians: GaussianSet, camera: Camera, sh_degree: int) -> torch.Tensor:
    """[N, 3] view-dependent RGB of the Gaussians seen from ``camera`` (SH bands up to ``sh_degree``)."""
    sh = gaussians.sh[:, : (sh_degree + 1) ** 2]
    return sh_to_color(sh, view_directions(gaussians, camera))


def pair_statistics(gaussians: GaussianSet, camera: Camera) -> dict[str, int]:
    """Counts of the sparse pair list of a view (for benchmarks and tests).

    Returns:
        ``visible`` Gaussians, ``candidates`` (pairs in the footprint boxes), ``skipped_alpha`` (of those,
        alpha < 1/255), ``pairs`` (alpha >= 1/255), ``stopped`` (pairs at or after a pixel's early stop,
        not composited) and ``stopped_pixels`` (pixels that stopped early).
    """
    with torch.no_grad():
        proj = project_gaussians(gaussians, camera)
        pairs = build_pairs(proj, gaussians.opacities, camera.width, camera.height)
        _, _, live = transmittance(pairs, camera.width * camera.height)
        kept = pairs.alpha > 0
        stopped = kept & ~live
        stopped_pixels = torch.unique(pairs.pixels[stopped]).numel()
        num_kept = int(kept.sum())
    return {
        "visible": int((proj.radii > 0).sum()),
        "candidates": pairs.candidates,
        "skipped_alpha": pairs.candidates - num_kept,
        "pairs": num_kept,
        "stopped": int(stopped.sum()),
        "stopped_pixels": int(stopped_pixels),
    }


def render(
    gaussians: GaussianSet,
    camera: Camera,
    background: torch.Tensor | float | None = None,
    *,
    sh_degree: int | None = None,
    backend: str = "auto",
) -> RenderOutput:
    """Rasterize Gaussians into one view (differentiable w.r.t. every Gaussian parameter).

    Args:
        gaussians: N Gaussians, float32 or float64, on any device (the render runs there).
        camera: the view (width W, height H).
        background: [3] RGB tensor on the Gaussians' device, a float grey level, or None (black).
        sh_degree: SH bands to use, 0 .. gaussians.sh_degree (None = all stored).
        backend: "torch" (this module), "gsplat" (CUDA, needs the gsplat package) or "auto" (gsplat when
            the Gaussians are on CUDA and gsplat imports, else torch).
    Returns:
        :class:`RenderOutput` with image [H, W, 3], alpha [H, W], depth [H, W], radii [N], visible [N],
        means2d [N, 2].

    Example:
        >>> cam = Camera.look_at((0, 0, -3.0), (0, 0, 0), (0, -1, 0), 32, 32, 0.8)
        >>> out = render(GaussianSet.from_points(torch.zeros(1, 3), scale=0.1, opacity=0.9), cam, 1.0)
        >>> out.image.shape, bool(out.visible[0])
        (torch.Size([32, 32, 3]), True)
    """
    degree = _check_inputs(gaussians, camera, sh_degree, backend)
    bg = background_tensor(background, gaussians.means)
    if backend == "auto":
        backend = "gsplat" if gaussians.device.type == "cuda" and gsplat_available() else "torch"
    if backend == "gsplat":
        return render_gsplat(gaussians, camera, bg, degree)

    proj = project_gaussians(gaussians, camera)
    means2d = proj.means2d
    if means2d.requires_grad:
        means2d.retain_grad()
    opacities = gaussians.opacities
    colors = gaussian_colors(gaussians, camera, degree)
    w, h = camera.width, camera.height
    pairs = build_pairs(proj, opacities, w, h)
    image, alpha, depth = Composite.apply(means2d, proj.conics, opacities, colors, proj.depths, bg, pairs, w * h)
    return RenderOutput(
        image=image.reshape(h, w, 3),
        alpha=alpha.reshape(h, w),
        depth=depth.reshape(h, w),
        radii=proj.radii,
        visible=proj.radii > 0,
        means2d=means2d,
    )


def render_layers(layers, camera: Camera, backgrounds) -> list[RenderOutput]:
    """Gaussian sets that differ only in colour (the same means, rotations, scales and opacities; e.g. a capture and
    its heat-map copy), rendered into one view: projected and paired once, composited once per set. Each output is
    ``render(layer, camera, background)``'s, bit for bit (the same projection, pairs and compositing); the pairing,
    which is most of a render of a large set, is done once instead of once per set. On CUDA (gsplat) each set is
    rendered on its own.

    Args:
        layers: K GaussianSets on one device, with equal geometry tensors. camera: the view.
        backgrounds: K backgrounds, as :func:`render`'s.
    Returns:
        K :class:`RenderOutput`.
    Raises:
        ValueError: the sets' geometry differs, or the counts of layers and backgrounds differ.
    """
    layers, backgrounds = list(layers), list(backgrounds)
    if not layers or len(layers) != len(backgrounds):
        raise ValueError(f"render_layers: {len(layers)} layers and {len(backgrounds)} backgrounds; give one per layer")
    first = layers[0]
    degrees = [_check_inputs(g, camera, None, "auto") for g in layers]
    for g in layers[1:]:
        if any(
            not torch.equal(getattr(g, n), getattr(first, n))
            for n in ("means", "quats", "log_scales", "opacity_logits")
        ):
            raise ValueError("render_layers: the layers must share means, rotations, scales and opacities")
    if first.device.type == "cuda" and gsplat_available():
        return [render(g, camera, bg) for g, bg in zip(layers, backgrounds, strict=True)]
    proj = project_gaussians(first, camera)
    w, h = camera.width, camera.height
    pairs = build_pairs(proj, first.opacities, w, h)
    outs = []
    for g, bg, degree in zip(layers, backgrounds, degrees, strict=True):
        colors = gaussian_colors(g, camera, degree)
        image, alpha, depth = Composite.apply(
            proj.means2d, proj.conics, g.opacities, colors, proj.depths, background_tensor(bg, g.means), pairs, w * h
        )
        outs.append(
            RenderOutput(
                image=image.reshape(h, w, 3),
                alpha=alpha.reshape(h, w),
                depth=depth.reshape(h, w),
                radii=proj.radii,
                visible=proj.radii > 0,
                means2d=proj.means2d,
            )
        )
    return outs
