"""FisherRF view scores on 3D Gaussians (Jiang et al. 2024, "FisherRF"; the paper's visual planner, Sec. 3.1).

The Fisher information of the parameters theta under a Gaussian pixel-noise model is J^T J, with J the
Jacobian of the rendered colours. FisherRF keeps its diagonal,

    H(T) = sum over the pixels p of view T of (d C_p / d theta)^2,   C_p = sum over the channels of the colour,

i.e. the colour is summed over its three channels *before* squaring (FisherRF's convention), and the
squares are per pixel: squaring the gradient of the summed image would let the contributions of
different pixels cancel. The parameters (per Gaussian, in this column order) are the ones the trainer
optimises, in its parameterisation:

    means (3, scene units) | log_scales (3) | opacity_logit (1) | sh (K x 3 raw coefficients, row-major)
    | quats (4, only with ``include_rotations``; excluded by default, as in FisherRF).

H is the exact diagonal of J^T J in these parameters: the log-scale column is s^2 sum_p (d C_p / d s)^2 and the
logit column o'^2 sum_p (d C_p / d o)^2. FisherRF's public code squares the gradient with respect to the activated
scale and opacity and lets autograd apply exp' and sigmoid' once (s, o' instead of their squares); we follow the
derivation. Only the SH bands the trainer fits are parameters (``sh_degree``; the planner takes the trainer's active
degree from the planning context), as FisherRF's rasterizer renders the active degree only.

The score of a candidate view c given the selected views is (FisherRF Eq. 9 with a diagonal H)

    Score(c) = sum_theta H_c / (H_train + lambda),   H_train = sum over the selected views of H,  lambda = 1e-6,

and a top-K list is chosen greedily: pick the best, add its H to H_train, rescore. Every score is
non-increasing as H_train grows, so the greedy list is built lazily (a stale score is an upper bound;
the best stale candidate is rescored and accepted when it stays best), which gives exactly the greedy
list without recomputing every candidate at every step; :func:`greedy_top_k_reference` is the plain twin.

How H(T) is computed (:func:`view_fisher`), per view:

1. per-pair gradients G_p = d C_{pixel(p)} / d a_g of the 2-D attributes a_g = (means2d, conic, opacity,
   colour) of the pair's Gaussian, in one backward pass (:func:`recon.pairs.pair_attribute_gradients`);
2. the local Jacobians A_g = d a_g / d theta_g of the projection and SH colour, one backward pass per
   attribute component over [N]-sized graphs (a_g depends on theta_g only, so the gradient of
   sum_g a_g[k] w.r.t. theta is row k of every A_g);
3. J_p = G_p A_{g(p)} and H_g[d] = sum over the pairs p of g of J_p[d]^2. Since A depends on g only,
   H_g[d] = A_g[:, d]^T M_g A_g[:, d] with the per-Gaussian 9 x 9 Gram matrix M_g = sum_p G_p G_p^T
   (1-D index_adds over the pairs); only the entries (k, m) with a column that both attributes move are
   formed (all of them for the means; the diagonal alone for opacity and SH, since colour channel c
   depends on the SH of channel c only).

:func:`view_fisher_reference` is the brute-force twin: the dense reference renderer and one backward
pass per pixel.
"""

from __future__ import annotations

import heapq
import logging
from collections.abc import Sequence
from dataclasses import dataclass

import torch

from recon.camera import Camera
from recon.gaussians import GaussianSet
from recon.pairs import pair_attribute_gradients
from recon.projection import project_gaussians
from recon.render import gaussian_colors
from recon.render_reference import render_dense_reference

log = logging.getLogger(__name__)

DEFAULT_LAMBDA = 1e-6


@dataclass(frozen=True)
class FisherConfig:
    """The FisherRF planner.

    Attributes:
        seed: recorded for the registry contract; the planner is deterministic and draws no random numbers.
        regularization: lambda of Score(c) = sum H_c / (H_train + lambda) (FisherRF: 1e-6).
        include_rotations: add the quaternions (4 per Gaussian) to the parameters (default: excluded).
        sh_degree: SH bands rendered and differentiated, 0..stored degree (None = all stored bands).
        cache_mb: memory for the per-candidate H of the greedy list, MiB; the best-scoring candidates are
            kept and any other is recomputed if the greedy list reaches it.
    """

    seed: int = 0
    regularization: float = DEFAULT_LAMBDA
    include_rotations: bool = False
    sh_degree: int | None = None
    cache_mb: float = 256.0

    def __post_init__(self) -> None:
        if not isinstance(self.seed, int) or isinstance(self.seed, bool):
            raise ValueError(f"FisherConfig.seed must be an int, got {self.seed!r}")
        if not self.regularization > 0.0:
            raise ValueError(f"FisherConfig.regularization must be > 0, got {self.regularization!r}")
        if self.sh_degree is not None and self.sh_degree not in (0, 1, 2, 3):
            raise ValueError(f"FisherConfig.sh_degree must be None or 0..3, got {self.sh_degree!r}")
        if not self.cache_mb >= 0.0:
            raise ValueError(f"FisherConfig.cache_mb must be >= 0, got {self.cache_mb!r}")


def _degree(gaussians: GaussianSet, sh_degree: int | None) -> int:
    degree = gaussians.sh_degree if sh_degree is None else sh_degree
    if not 0 <= degree <= gaussians.sh_degree:
        raise ValueError(
            f"sh_degree {sh_degree} exceeds the stored SH degree {gaussians.sh_degree}; "
            "pass sh_degree=None or a smaller degree"
        )
    return degree


def _parameter_leaves(gaussians: GaussianSet, degree: int, include_rotations: bool) -> dict[str, torch.Tensor]:
    """Fresh leaf tensors (requiring grad) of the differentiated parameters, in column order."""
    g = gaussians.detach()
    leaves = {
        "means": g.means,
        "log_scales": g.log_scales,
        "opacity_logits": g.opacity_logits,
        "sh": g.sh[:, : (degree + 1) ** 2],
    }
    if include_rotations:
        leaves["quats"] = g.quats
    return {name: t.clone().requires_grad_(True) for name, t in leaves.items()}


def _leaf_set(gaussians: GaussianSet, leaves: dict[str, torch.Tensor]) -> GaussianSet:
    g = gaussians.detach()
    quats = leaves.get("quats", g.quats)
    return GaussianSet(leaves["means"], quats, leaves["log_scales"], leaves["opacity_logits"], leaves["sh"])


def parameter_count(sh_degree: int, include_rotations: bool = False) -> int:
    """D, the number of Fisher columns per Gaussian: 3 + 3 + 1 + 3 (degree + 1)^2 (+ 4 with rotations)."""
    return 7 + 3 * (sh_degree + 1) ** 2 + (4 if include_rotations else 0)


def local_jacobians(
    gaussians: GaussianSet, camera: Camera, *, sh_degree: int | None = None, include_rotations: bool = False
) -> list[list[tuple[int, torch.Tensor]]]:
    """A_g = d a_g / d theta_g for every Gaussian, grouped by parameter block.

    Args:
        gaussians: N Gaussians. camera: the view. sh_degree, include_rotations: as in :class:`FisherConfig`.
    Returns:
        per parameter block (column order of the module docstring) the list of (attribute k, [N, d_block]
        row k of A restricted to the block) for the attributes that depend on the block.
    """
    degree = _degree(gaussians, sh_degree)
    leaves = _parameter_leaves(gaussians, degree, include_rotations)
    names = list(leaves)
    blocks: list[list[tuple[int, torch.Tensor]]] = [[] for _ in names]
    with torch.enable_grad():
        g = _leaf_set(gaussians, leaves)
        proj = project_gaussians(g, camera)
        colors = gaussian_colors(g, camera, degree)
        attributes = torch.cat([proj.means2d, proj.conics, g.opacities[:, None], colors], -1)  # [N, 9]
        attrs = attributes.shape[1]
        # the nine backward passes as one batched pass: grad_outputs row k is the indicator of attribute k
        unit = torch.eye(attrs, dtype=attributes.dtype, device=attributes.device)[:, None, :].expand(-1, g.num, -1)
        grads = torch.autograd.grad(
            attributes, [leaves[n] for n in names], grad_outputs=unit, is_grads_batched=True, allow_unused=True
        )
    for b, grad in enumerate(grads):
        if grad is None:
            continue
        rows = grad.reshape(attrs, g.num, -1)
        for k in range(attrs):
            if bool(rows[k].any()):
                blocks[b].append((k, rows[k]))
    return blocks


def view_fisher(
    gaussians: GaussianSet,
    camera: Camera,
    background: torch.Tensor | float | None = None,
    *,
    sh_degree: int | None = None,
    include_rotations: bool = False,
) -> torch.Tensor:
    """The diagonal of J^T J of one view, per Gaussian and parameter (see the module docstring).

    Args:
        gaussians: N Gaussians (float32 or float64, any device; not modified).
        camera: the view, W x H pixels.
        background: [3] tensor, float grey level or None (black).
        sh_degree: SH bands used (None = all stored). include_rotations: add the quaternion columns.
    Returns:
        [N, D] H in the Gaussians' dtype, D = :func:`parameter_count`; columns means, log_scales,
        opacity_logit, sh (row-major K x 3), quats.

    Example:
        >>> h = view_fisher(gaussians, camera, 1.0)
        >>> h.shape == (gaussians.num, parameter_count(gaussians.sh_degree))
        True
    """
    degree = _degree(gaussians, sh_degree)
    pg = pair_attribute_gradients(gaussians, camera, background, sh_degree=degree)
    blocks = local_jacobians(gaussians, camera, sh_degree=degree, include_rotations=include_rotations)
    # float64 accumulation: the quadratic form A^T M A of the means columns sums terms of both signs
    grads, gid = pg.grads.T.to(torch.float64).contiguous(), pg.gaussians  # [9, P]: rows for 1-D products
    n, attrs = gaussians.num, grads.shape[0]
    jac = torch.cat([_block_matrix(rows, n, attrs, grads) for rows in blocks], 1)  # [9, D, N]: A_g^T per g
    support = (jac != 0).any(-1)  # [9, D]: attribute k moves column d for some Gaussian
    # equal rows of G (the three colour channels: each is the pair's weight w_p) give equal Gram entries
    first = list(range(attrs))
    for k in range(attrs):
        first[k] = next(j for j in range(k + 1) if j == k or torch.equal(grads[j], grads[k]))
    grams: dict[tuple[int, int], torch.Tensor] = {}
    h = torch.zeros(jac.shape[1], n, dtype=grads.dtype, device=grads.device)
    for k in range(attrs):
        for m in range(k, attrs):
            cols = torch.nonzero(support[k] & support[m]).flatten()
            if cols.numel() == 0:
                continue
            key = (first[k], first[m])
            if key not in grams:  # M_g[k, m] = sum over the pairs p of g of G_p[k] G_p[m]
                grams[key] = torch.zeros(n, dtype=grads.dtype, device=grads.device).index_add_(
                    0, gid, grads[key[0]] * grads[key[1]]
                )
            jk, jm = jac[k].index_select(0, cols), jac[m].index_select(0, cols)
            h.index_add_(0, cols, jk * jm * ((1.0 if k == m else 2.0) * grams[key]))
    # a sum of squares: the quadratic form may round a few ulps below 0
    return h.T.clamp_min(0.0).to(gaussians.dtype).contiguous()


def _block_matrix(rows: list[tuple[int, torch.Tensor]], n: int, attrs: int, like: torch.Tensor) -> torch.Tensor:
    """[attrs, d, N] one parameter block of A (transposed) from the (attribute, [N, d]) rows of
    :func:`local_jacobians`."""
    width = rows[0][1].shape[1]
    out = torch.zeros(attrs, width, n, dtype=like.dtype, device=like.device)
    for k, a in rows:
        out[k] = a.T
    return out


def view_fisher_reference(
    gaussians: GaussianSet,
    camera: Camera,
    background: torch.Tensor | float | None = None,
    *,
    sh_degree: int | None = None,
    include_rotations: bool = False,
) -> torch.Tensor:
    """Brute-force twin of :func:`view_fisher`: the dense reference renderer, one backward pass per pixel.

    O(H W N) per pass and H W passes: tiny scenes only (tests). Same Args and Returns.
    """
    degree = _degree(gaussians, sh_degree)
    leaves = _parameter_leaves(gaussians, degree, include_rotations)
    params = list(leaves.values())
    with torch.enable_grad():
        g = _leaf_set(gaussians, leaves)
        image = render_dense_reference(g, camera, background, sh_degree=degree).image.reshape(-1, 3)
        h = torch.zeros(g.num, parameter_count(degree, include_rotations), dtype=g.dtype, device=g.device)
        for p in range(image.shape[0]):
            grads = torch.autograd.grad(image[p].sum(), params, retain_graph=True, allow_unused=True)
            flat = [
                torch.zeros_like(t).reshape(g.num, -1) if d is None else d.reshape(g.num, -1)
                for t, d in zip(params, grads, strict=True)
            ]
            h += torch.cat(flat, -1) ** 2
    return h


def fisher_score(h_candidate: torch.Tensor, h_train: torch.Tensor, regularization: float = DEFAULT_LAMBDA) -> float:
    """Score(c) = sum_theta H_c / (H_train + lambda), in float64.

    Args:
        h_candidate: [N, D] H of the candidate view. h_train: [N, D] sum of H over the selected views.
        regularization: lambda.
    """
    if h_candidate.shape != h_train.shape:
        raise ValueError(
            f"fisher_score: candidate H {tuple(h_candidate.shape)} and train H "
            f"{tuple(h_train.shape)} differ; compute both from the same Gaussians"
        )
    return float((h_candidate.to(torch.float64) / (h_train.to(torch.float64) + regularization)).sum())


@dataclass
class FisherRanking:
    """A greedy FisherRF list.

    Attributes:
        order: candidate positions, best first (length min(k, C)).
        scores: [C] Score(c) against the selected views only (before any greedy update).
        recomputed: how many candidate H were recomputed because they had left the cache.
    """

    order: list[int]
    scores: list[float]
    recomputed: int = 0


def greedy_top_k_reference(
    h_train: torch.Tensor, h_candidates: Sequence[torch.Tensor], k: int, regularization: float = DEFAULT_LAMBDA
) -> list[int]:
    """Plain greedy twin of the lazy list of :func:`greedy_top_k`: rescore every candidate at every step."""
    h = h_train.clone()
    remaining, order = list(range(len(h_candidates))), []
    for _ in range(min(k, len(h_candidates))):
        scores = [fisher_score(h_candidates[i], h, regularization) for i in remaining]
        best = remaining[max(range(len(remaining)), key=lambda j: (scores[j], -remaining[j]))]
        order.append(best)
        remaining.remove(best)
        h = h + h_candidates[best]
    return order


def greedy_top_k(
    gaussians: GaussianSet,
    candidates: Sequence[Camera],
    train_cameras: Sequence[Camera],
    background: torch.Tensor | float | None,
    k: int,
    config: FisherConfig = FisherConfig(),
    progress=None,
) -> FisherRanking:
    """The greedy FisherRF top-k list of the candidate views (lazy evaluation, exact greedy result).

    Args:
        gaussians: the current reconstruction (N Gaussians; H is recomputed from them at every call, so
            densification between rounds is handled).
        candidates: C candidate cameras. train_cameras: the selected views.
        background: as in :func:`view_fisher`.
        k: list length (clipped to C).
        config: :class:`FisherConfig`.
        progress: optional callable wrapping an iterable (e.g. ``tqdm``) for the candidate pass.
    Returns:
        :class:`FisherRanking`.
    """
    if len(candidates) == 0:
        raise ValueError("greedy_top_k: no candidate cameras; pass at least one")
    if k < 1:
        raise ValueError(f"greedy_top_k: k must be >= 1, got {k}")

    def fisher(camera: Camera) -> torch.Tensor:
        return view_fisher(
            gaussians, camera, background, sh_degree=config.sh_degree, include_rotations=config.include_rotations
        )

    lam = config.regularization
    degree = _degree(gaussians, config.sh_degree)
    shape = (gaussians.num, parameter_count(degree, config.include_rotations))
    h_train = torch.zeros(shape, dtype=torch.float64, device=gaussians.device)
    for camera in train_cameras:
        h_train += fisher(camera)
    budget = int(config.cache_mb * 2**20)
    cache: dict[int, torch.Tensor] = {}
    cached_heap: list[tuple[float, int]] = []  # (score, position) of the cached entries, lowest first
    scores: list[float] = []
    positions = range(len(candidates))
    for i in progress(positions) if progress is not None else positions:
        h = fisher(candidates[i])
        scores.append(fisher_score(h, h_train, lam))
        cache[i] = h
        heapq.heappush(cached_heap, (scores[i], i))
        while cache and sum(t.numel() * t.element_size() for t in cache.values()) > budget:
            _, drop = heapq.heappop(cached_heap)
            del cache[drop]

    recomputed = 0

    def cached(i: int) -> torch.Tensor:
        nonlocal recomputed
        if i not in cache:
            cache[i] = fisher(candidates[i])
            recomputed += 1
        return cache[i]

    bounds = list(scores)
    remaining = set(positions)
    order: list[int] = []
    for _ in range(min(k, len(candidates))):
        fresh: set[int] = set()
        while True:
            best = max(remaining, key=lambda j: (bounds[j], -j))
            if not order or best in fresh:
                break
            bounds[best] = fisher_score(cached(best), h_train, lam)
            fresh.add(best)
        order.append(best)
        remaining.discard(best)
        if len(order) < k and remaining:
            h_train = h_train + cached(best)
    return FisherRanking(order=order, scores=scores, recomputed=recomputed)
