"""View scores, ranking, the geometry divergence D-bar and function-critical scores (paper Eq. 4-5, Sec. 3.3-3.4).

Everything here is plain torch over per-Gaussian tensors and the renderer's per-view outputs:

- **View weight** (Eq. 5): w_g(T) = clamp(pi R_g^2 / (H W), 0, 1), with R_g the screen-space radius of
  Gaussian g in view T (pixels, ``RenderOutput.radii``) and H x W the image size; 0 when g is culled.
- **View score** (Eq. 4): S(T) = sum over the Gaussians visible in T of w_g(T) M_g, for any per-Gaussian
  metric M (the divergence D_g of Eq. 3, a vorticity magnitude, particle counts). Without radii the
  unweighted sum over the visible Gaussians is used.
- **Geometry divergence**: D-bar = (1 / |G|) sum_g pi s_g^2 D_g with s_g = tr(Sigma_g); with Sigma_g in
  simulation metres^2 and D_g in 1/s, D-bar is in m^4/s.
- **Function-critical score**: C(T) = sum_g w_g(T) |P_g|, with |P_g| the number of distinct fluid
  particles of one probe that came within n r_g of g; the top-k views form the critical subset.

S(T) needs the screen radii and the visibility only, which are the projection's: :func:`projected_view_scores`
and its coarse depth test (:class:`DepthBuffer`) live in :mod:`nbv.projected_scores` and are importable from here
(:func:`unoccluded` is the render-based depth test).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Sequence

import torch

from .centre_counts import projected_counts, projected_counts_reference  # noqa: F401  (re-exported)
from .projected_scores import (  # noqa: F401  (re-exported: nbv.scores is where callers look for them)
    DepthBuffer,
    ProjectedScores,
    coarse_unoccluded,
    coarse_unoccluded_reference,
    depth_test,
    projected_view_scores,
    projected_view_scores_reference,
)


def view_weights(radii: torch.Tensor, height: int, width: int) -> torch.Tensor:
    """Per-Gaussian view weights w_g = clamp(pi R_g^2 / (H W), 0, 1) (paper Eq. 5).

    Args:
        radii: [N] or [C, N] screen-space radii R_g in pixels (0 = culled).
        height, width: image size in pixels.
    Returns:
        float64 tensor of the shape of ``radii``.
    """
    if height <= 0 or width <= 0:
        raise ValueError(f"image size must be positive, got height={height}, width={width}")
    r = torch.as_tensor(radii).to(torch.float64)
    return (math.pi * r * r / float(height * width)).clamp(0.0, 1.0)


def _image_sizes(image_size, count: int) -> list[tuple[int, int]] | None:
    """``image_size`` as C (H, W) pairs: one (H, W) for every view, or a sequence of C of them."""
    if image_size is None:
        return None
    if len(image_size) == 2 and all(isinstance(v, numbers.Integral) for v in image_size):
        return [(int(image_size[0]), int(image_size[1]))] * count
    sizes = [tuple(int(v) for v in hw) for hw in image_size]
    if len(sizes) != count or any(len(hw) != 2 for hw in sizes):
        raise ValueError(
            f"view_scores: image_size must be one (height, width) or {count} of them, one per view; got {len(sizes)}"
        )
    return sizes  # type: ignore[return-value]


def _stack_tensor_views(views, image_size) -> tuple[torch.Tensor | None, torch.Tensor, list[tuple[int, int]] | None]:
    """(radii, visible, sizes) from a [C, N] radii/visibility tensor or a (radii, visible) pair."""
    if isinstance(views, tuple):
        radii, vis = (torch.as_tensor(t) for t in views)
        radii = radii.reshape(1, -1) if radii.dim() == 1 else radii
        vis = vis.reshape(1, -1).bool() if vis.dim() == 1 else vis.bool()
        if tuple(radii.shape) != tuple(vis.shape):
            raise ValueError(
                f"view_scores: radii {tuple(radii.shape)} and visible {tuple(vis.shape)} must have one "
                "shape [C, N] (as recon.projection.project_visibility returns them)"
            )
    else:
        radii = views if views.dim() == 2 else views.reshape(1, -1)
        if radii.dtype == torch.bool:
            return None, radii, None
        vis = radii > 0
    if image_size is None:
        raise ValueError("view_scores: radii given as a tensor need image_size=(height, width) (or one per view)")
    return radii, vis, _image_sizes(image_size, radii.shape[0])


def _stack_views(views, image_size) -> tuple[torch.Tensor | None, torch.Tensor, list[tuple[int, int]] | None]:
    """(radii [C, N] or None, visible [C, N] bool, per-view (H, W) or None) from renders or tensors."""
    if isinstance(views, torch.Tensor) or (
        isinstance(views, tuple) and len(views) == 2 and all(isinstance(t, torch.Tensor) for t in views)
    ):
        return _stack_tensor_views(views, image_size)
    if not isinstance(views, Sequence) or len(views) == 0:
        raise ValueError(
            "view_scores: pass a non-empty list of RenderOutput, a [C, N] radii/visibility tensor or "
            "the (radii, visible) pair of recon.projection.project_visibility"
        )
    fallback = _image_sizes(image_size, len(views))
    radii, visible, sizes = [], [], []
    for i, v in enumerate(views):
        vis = getattr(v, "visible", None)
        rad = getattr(v, "radii", None)
        if vis is None and rad is None:
            raise ValueError(f"view_scores: view {i} has neither 'radii' nor 'visible'")
        visible.append(torch.as_tensor(vis if vis is not None else rad > 0).bool().reshape(-1))
        radii.append(None if rad is None else torch.as_tensor(rad).reshape(-1))
        image = getattr(v, "image", None)
        sizes.append(tuple(image.shape[:2]) if image is not None else (fallback[i] if fallback else None))
    vis_t = torch.stack(visible)
    if any(r is None for r in radii) or any(s is None for s in sizes):
        return None, vis_t, None
    return torch.stack(radii), vis_t, sizes  # type: ignore[arg-type]


def view_scores(
    per_gaussian: torch.Tensor, views, *, image_size=None, weighted: bool = True, visible: torch.Tensor | None = None
) -> torch.Tensor:
    """View scores S(T) = sum_{g visible in T} w_g(T) M_g (paper Eq. 4) for every candidate view.

    Args:
        per_gaussian: [N] any per-Gaussian metric M_g (D_g in 1/s, a vorticity, distinct particle counts).
        views: a list of C ``RenderOutput`` (``radii`` [N] pixels, ``visible`` [N], ``image`` [H, W, 3]);
            or the pair (radii [C, N], visible [C, N]) of :func:`recon.projection.project_visibility` (needs
            ``image_size``); or a [C, N] tensor: integer/float radii in pixels (needs ``image_size``) or a
            bool visibility.
        image_size: (H, W) pixels of every view, or a sequence of C of them, for radii tensors or renders
            without an image.
        weighted: use the Eq. 5 weights; False (or no radii available) gives the plain sum over the visible.
        visible: optional [C, N] bool replacing the views' visibility (e.g. :func:`unoccluded`).
    Returns:
        [C] float64 scores (0 for a view that sees no Gaussian).

    Example:
        >>> radii = torch.tensor([[2, 0], [1, 1]])
        >>> view_scores(torch.tensor([1.0, 3.0]), (radii, radii > 0), image_size=(4, 4)).tolist()
        [0.7853981633974483, 0.7853981633974483]
    """
    m = torch.as_tensor(per_gaussian).detach().to(torch.float64).reshape(-1).cpu()
    radii, vis, sizes = _stack_views(views, image_size)
    if visible is not None:
        if tuple(visible.shape) != tuple(vis.shape):
            raise ValueError(f"view_scores: visible {tuple(visible.shape)} must match the views {tuple(vis.shape)}")
        vis = vis & visible.bool().to(vis.device)
    visible = vis.cpu()
    if visible.shape[1] != m.shape[0]:
        raise ValueError(
            f"view_scores: {m.shape[0]} per-Gaussian values but the views have {visible.shape[1]} "
            "Gaussians; score the same Gaussian set that was rendered"
        )
    if not weighted or radii is None:
        return (visible.to(torch.float64) * m).sum(-1)
    weights = torch.stack([view_weights(r.cpu(), h, w) for r, (h, w) in zip(radii, sizes, strict=True)])
    return (weights * visible.to(torch.float64) * m).sum(-1)


def view_scores_reference(per_gaussian, radii, visible, height: int, width: int) -> list[float]:
    """Loop-over-Gaussians twin of :func:`view_scores` (weighted), for tests.

    Args:
        per_gaussian: [N] metric. radii: [C, N] pixels. visible: [C, N] bool. height, width: pixels.
    Returns:
        C python floats.
    """
    out = []
    for c in range(len(radii)):
        total = 0.0
        for g in range(len(per_gaussian)):
            if bool(visible[c][g]):
                r = float(radii[c][g])
                total += min(max(math.pi * r * r / (height * width), 0.0), 1.0) * float(per_gaussian[g])
        out.append(total)
    return out


def rank(scores: torch.Tensor) -> torch.Tensor:
    """Indices of ``scores`` [C] from best to worst (descending; ties keep the lower index first).

    Returns:
        [C] int64.
    """
    s = torch.as_tensor(scores).reshape(-1)
    if torch.isnan(s).any():
        raise ValueError("rank: the scores contain NaN; check the per-Gaussian metric")
    return torch.argsort(s, descending=True, stable=True)


def geometry_divergence(covariances: torch.Tensor, divergence: torch.Tensor) -> float:
    """D-bar = (1 / |G|) sum_g pi s_g^2 D_g with s_g = tr(Sigma_g).

    Args:
        covariances: [N, 3, 3] Sigma_g in simulation metres^2.
        divergence: [N] D_g in 1/s.
    Returns:
        D-bar in m^4/s (0 for an empty set).
    """
    return geometry_divergences(covariances, [divergence])[0]


def geometry_divergences(covariances: torch.Tensor, divergences: Sequence[torch.Tensor]) -> list[float]:
    """:func:`geometry_divergence` of one Gaussian set for several D_g (e.g. each probe's), the weights pi s_g^2
    computed once: the same numbers as one call per D_g.

    Args:
        covariances: [N, 3, 3] Sigma_g in simulation metres^2. divergences: each [N] D_g in 1/s.
    Returns:
        one D-bar per D_g, m^4/s.
    """
    cov = torch.as_tensor(covariances).to(torch.float64)
    ds = [torch.as_tensor(d).to(torch.float64).reshape(-1) for d in divergences]
    for d in ds:
        if cov.shape[0] != d.shape[0] or tuple(cov.shape[1:]) != (3, 3):
            raise ValueError(
                f"geometry_divergence: covariances {tuple(cov.shape)} and divergence {tuple(d.shape)} "
                "must be [N, 3, 3] and [N]"
            )
    if cov.shape[0] == 0:
        return [0.0] * len(ds)
    s = cov.diagonal(dim1=-2, dim2=-1).sum(-1)
    weights = math.pi * s * s
    return [float((weights * d).mean()) for d in ds]


def critical_scores(distinct_counts: torch.Tensor, views, *, image_size: tuple[int, int] | None = None) -> torch.Tensor:
    """Function-critical view scores C(T) = sum_g w_g(T) |P_g| (Sec. 3.4).

    Args:
        distinct_counts: [N] |P_g|, distinct fluid particles that came within n r_g of g.
        views: as in :func:`view_scores`.
        image_size: as in :func:`view_scores`.
    Returns:
        [C] float64.
    """
    return view_scores(torch.as_tensor(distinct_counts).to(torch.float64), views, image_size=image_size)


def critical_subset(scores: torch.Tensor, k: int = 20) -> torch.Tensor:
    """The k views with the highest C(T) (all when fewer), best first; [min(k, C)] int64."""
    if k <= 0:
        raise ValueError(f"critical subset size k must be >= 1, got {k}")
    return rank(scores)[:k]


def unoccluded(means: torch.Tensor, reach: torch.Tensor, camera, render_out, min_alpha: float = 0.5) -> torch.Tensor:
    """Visible Gaussians that are not hidden behind the rendered surface (an optional, stricter visibility).

    The renderer's ``visible`` is frustum culling only, so a Gaussian behind the object counts in S(T). Here
    g also needs its centre depth z_g <= d(u_g) + reach_g, where d = depth / alpha is the rendered surface
    depth at g's pixel (a pixel with alpha < ``min_alpha`` hides nothing). Not part of the paper.

    Args:
        means: [N, 3] centres (scene units). reach: [N] depth tolerance (scene units, e.g. 3 r_g).
        camera: the view. render_out: its RenderOutput (``visible``, ``depth``, ``alpha``).
    Returns:
        [N] bool.
    """
    pts = torch.as_tensor(means).detach().to(torch.float64).cpu()
    uv, z = camera.project(pts)
    depth = render_out.depth.detach().to(torch.float64).cpu()
    alpha = render_out.alpha.detach().to(torch.float64).cpu()
    h, w = depth.shape
    px = uv[:, 0].floor().long().clamp(0, w - 1)
    py = uv[:, 1].floor().long().clamp(0, h - 1)
    a = alpha[py, px]
    surface = depth[py, px] / a.clamp_min(1e-12)
    tol = torch.as_tensor(reach).detach().to(torch.float64).cpu().reshape(-1)
    ok = (a < min_alpha) | (z <= surface + tol)
    return render_out.visible.detach().cpu().bool() & ok


def unoccluded_reference(means, reach, camera, render_out, min_alpha: float = 0.5) -> list[bool]:
    """Per-Gaussian loop twin of :func:`unoccluded`, for tests."""
    out = []
    depth, alpha = render_out.depth.double(), render_out.alpha.double()
    h, w = depth.shape
    for g in range(len(means)):
        uv, z = camera.project(torch.as_tensor(means[g : g + 1]).double())
        x = min(max(int(math.floor(float(uv[0, 0]))), 0), w - 1)
        y = min(max(int(math.floor(float(uv[0, 1]))), 0), h - 1)
        a = float(alpha[y, x])
        ok = a < min_alpha or float(z[0]) <= float(depth[y, x]) / max(a, 1e-12) + float(reach[g])
        out.append(bool(render_out.visible[g]) and ok)
    return out
