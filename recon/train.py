"""3D Gaussian Splatting training (Kerbl et al. 2023, "3D Gaussian Splatting", Sec. 5 and 7.1).

One iteration: set the position learning rate (exponential decay, :func:`recon.optim.expon_lr`), raise
the active SH degree every ``sh_increase_interval`` iterations, render one training view over the
background, take the loss (1 - lambda) L1 + lambda D-SSIM (Eq. 7, :mod:`recon.losses`), back-propagate,
accumulate the view-space gradient statistics, run adaptive density control and the opacity reset on
schedule (:mod:`recon.densify`), and take one Adam step (:mod:`recon.optim`). The hyper-parameters are
those of the reference trainer (``arguments/__init__.py``); :meth:`TrainConfig.for_iterations` compresses
its 30k-iteration schedule for short CPU runs.

Scene extent: 1.1 x the largest distance of a camera centre from their mean (``getNerfppNorm``); the
position learning rates and the clone/split/prune size limits are multiples of it.

Randomness (view order, random backgrounds, split samples, random initial points) comes from explicit
``torch.Generator`` objects seeded from ``TrainConfig.seed``, so a CPU run is repeatable.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import torch

from .camera import Camera
from .densify import DensityStats, densify_and_prune, ndc_gradient, reset_opacity
from .gaussians import GaussianSet
from .losses import photometric_loss
from .metrics import psnr, ssim
from .optim import GroupedAdam, expon_lr
from .render import render
from .train_config import (  # noqa: F401 - INITS .. SCHEDULE_FIELDS: re-exported, recon.train.X keeps working
    BACKGROUNDS,
    INITS,
    MIN_DENSIFICATION_INTERVAL,
    PARAM_NAMES,
    REFERENCE_ITERATIONS,
    SCHEDULE_FIELDS,
    TrainConfig,
)

log = logging.getLogger(__name__)

# ---- scene geometry and initialisation ---------------------------------------------------------------


def scene_extent(cameras: Sequence[Camera]) -> float:
    """1.1 x the radius of the camera centres' bounding sphere about their mean (3DGS ``getNerfppNorm``).

    Args:
        cameras: the training cameras (at least one).
    Returns:
        The extent, scene units (1.1 when all cameras coincide, so that it is never 0).
    """
    if not cameras:
        raise ValueError("scene_extent: no cameras; pass at least one training view")
    centres = torch.stack([c.center for c in cameras])
    radius = float((centres - centres.mean(0)).norm(dim=-1).max())
    return 1.1 * (radius if radius > 0 else 1.0)


def look_at_point(cameras: Sequence[Camera]) -> torch.Tensor:
    """[3] float64 point closest (least squares) to all optical axes; the centres' mean if they are parallel."""
    centres = torch.stack([c.center for c in cameras])
    dirs = torch.stack([c.camera_to_world[:3, 2] for c in cameras])
    projs = torch.eye(3, dtype=torch.float64) - dirs[:, :, None] * dirs[:, None, :]
    a, b = projs.sum(0), (projs @ centres[:, :, None]).sum(0)[:, 0]
    if torch.linalg.matrix_rank(a) < 3:
        return centres.mean(0)
    return torch.linalg.solve(a, b)


def default_init_box(cameras: Sequence[Camera]) -> tuple[float, ...]:
    """The cube of half-size 0.3 x extent centred at :func:`look_at_point` (see ``TrainConfig.init_box``)."""
    centre, half = look_at_point(cameras), 0.3 * scene_extent(cameras)
    return tuple((centre - half).tolist()) + tuple((centre + half).tolist())


def knn_mean_sq_dist(points: torch.Tensor, k: int = 3, chunk: int = 1024) -> torch.Tensor:
    """Mean squared distance of each point to its ``k`` nearest other points, in row chunks (O(N) memory).

    Args:
        points: [N, 3] with N > k.
        k: neighbours.
        chunk: rows per block of the distance matrix.
    Returns:
        [N] mean of the k smallest squared distances (the reference's ``distCUDA2`` with k = 3).
    """
    n = points.shape[0]
    if n <= k:
        raise ValueError(f"knn_mean_sq_dist needs more than k = {k} points, got {n}")
    out = torch.empty(n, dtype=points.dtype, device=points.device)
    for start in range(0, n, chunk):
        block = points[start : start + chunk]
        d2 = torch.cdist(block, points).square()
        rows = torch.arange(block.shape[0], device=points.device)
        d2[rows, rows + start] = float("inf")
        out[start : start + chunk] = d2.topk(k, dim=1, largest=False).values.mean(1)
    return out


def knn_mean_sq_dist_reference(points: torch.Tensor, k: int = 3) -> torch.Tensor:
    """Slow twin of :func:`knn_mean_sq_dist`: the full N x N matrix of squared differences, sorted."""
    d2 = ((points[:, None, :] - points[None, :, :]) ** 2).sum(-1)
    d2.fill_diagonal_(float("inf"))
    return d2.sort(dim=1).values[:, :k].mean(1)


def init_gaussians(points: torch.Tensor, colors: torch.Tensor, sh_degree: int, opacity: float = 0.1) -> GaussianSet:
    """Isotropic Gaussians at ``points`` as the reference initialises them.

    Scale = sqrt(max(mean squared distance to the 3 nearest neighbours, 1e-7)), identity rotation,
    opacity ``opacity``, SH DC from ``colors`` and zero higher bands.

    Args:
        points: [N, 3] float32, N >= 4.
        colors: [N, 3] in [0, 1].
        sh_degree: degree of the stored SH (0 to 3).
        opacity: in (0, 1).
    """
    points = points.to(torch.float32)
    scale = knn_mean_sq_dist(points).clamp_min(1e-7).sqrt()
    g = GaussianSet.from_points(points, colors.to(torch.float32), scale=scale, opacity=opacity, sh_degree=0)
    return g.with_sh_degree(sh_degree)


def random_box_gaussians(
    count: int, box: Sequence[float], sh_degree: int, generator: torch.Generator, opacity: float = 0.1
) -> GaussianSet:
    """``count`` Gaussians at uniform points of ``box`` (xmin, ymin, zmin, xmax, ymax, zmax), random colours."""
    lo, hi = torch.tensor(box[:3]), torch.tensor(box[3:])
    points = lo + (hi - lo) * torch.rand(count, 3, generator=generator)
    colors = torch.rand(count, 3, generator=generator)
    return init_gaussians(points, colors, sh_degree, opacity)


# ---- the trainer -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TrainStepStats:
    """One iteration: its number, loss, PSNR (dB) of the render against its target, and the Gaussian count."""

    iteration: int
    loss: float
    psnr: float
    num_gaussians: int


@dataclass
class TrainLog:
    """History of a run.

    Attributes:
        losses, psnrs, num_gaussians: per iteration.
        events: density-control and opacity-reset events (dicts with "iteration", "kind" and counts).
        evaluations: periodic held-out evaluations (dicts with "iteration", "psnr", "ssim").
        wall_time_s: seconds spent in :meth:`Trainer.train`.
    """

    losses: list[float] = field(default_factory=list)
    psnrs: list[float] = field(default_factory=list)
    num_gaussians: list[int] = field(default_factory=list)
    events: list[dict] = field(default_factory=list)
    evaluations: list[dict] = field(default_factory=list)
    wall_time_s: float = 0.0


def _gaussians_to_params(g: GaussianSet) -> dict[str, torch.Tensor]:
    tensors = (g.means, g.quats, g.log_scales, g.opacity_logits, g.sh[:, :1], g.sh[:, 1:])
    return dict(zip(PARAM_NAMES, tensors, strict=True))


def _params_to_gaussians(p: dict[str, torch.Tensor]) -> GaussianSet:
    return GaussianSet(
        p["means"], p["quats"], p["log_scales"], p["opacity_logits"], torch.cat([p["sh_dc"], p["sh_rest"]], 1)
    )


def background_color(mode: str, generator: torch.Generator | None = None) -> torch.Tensor:
    """[3] float32 background for ``mode`` "white", "black" or "random" (uniform, from ``generator``)."""
    if mode == "white":
        return torch.ones(3)
    if mode == "black":
        return torch.zeros(3)
    if mode == "random":
        return torch.rand(3, generator=generator)
    raise ValueError(f"background must be one of {BACKGROUNDS}, got {mode!r}")


def composite_target(
    image: torch.Tensor, alpha: torch.Tensor | None, data_background: torch.Tensor, background: torch.Tensor
) -> torch.Tensor:
    """Re-composite a dataset image onto another background.

    image = rgb alpha + data_background (1 - alpha), so the same pixel over ``background`` is
    image + (background - data_background) (1 - alpha).

    Args:
        image: [H, W, 3] composited on ``data_background``.
        alpha: [H, W] or None (then the backgrounds must be equal).
        data_background, background: [3].
    Returns:
        [H, W, 3].
    """
    if torch.equal(background.to(image), data_background.to(image)):
        return image
    if alpha is None:
        raise ValueError(
            "the training background differs from the dataset's background and the images have no "
            "alpha channel; train with --background matching the dataset (e.g. white)"
        )
    return image + (background.to(image) - data_background.to(image)) * (1.0 - alpha.to(image))[..., None]


def check_views(views: Sequence, background: str, data_background: Sequence[float]) -> None:
    """Raise ``ValueError`` naming the view when a training view cannot be used (before any training)."""
    if not views:
        raise ValueError("no training views; pass at least one view (check --views and the dataset's train split)")
    needs_alpha = background == "random" or background_color(background).tolist() != [float(c) for c in data_background]
    for v in views:
        if v.image is None:
            raise ValueError(f"view {v.name!r} has no image; training needs ground-truth images")
        want = (v.camera.height, v.camera.width, 3)
        if tuple(v.image.shape) != want:
            raise ValueError(f"view {v.name!r}: image shape {tuple(v.image.shape)} does not match its camera {want}")
        if needs_alpha and v.alpha is None:
            raise ValueError(
                f"view {v.name!r} has no alpha channel, so it cannot be re-composited on a {background} "
                f"background; use --background matching the dataset background {tuple(data_background)}"
            )


class Trainer:
    """Stateful 3DGS optimisation of one Gaussian set (usable step by step by an active-reconstruction loop).

    Args:
        gaussians: initial Gaussians (their SH are padded or truncated to ``config.sh_degree``).
        config: hyper-parameters.
        extent: scene extent (see :func:`scene_extent`), scene units.
        data_background: [3] background the dataset images are composited on (white by default).
        backend: renderer backend ("auto", "torch" or "gsplat").

    Example:
        >>> trainer = Trainer(init, TrainConfig.for_iterations(300), extent=scene_extent([v.camera for v in views]))
        >>> log = trainer.train(views, 300)
        >>> trained = trainer.gaussians
    """

    def __init__(
        self,
        gaussians: GaussianSet,
        config: TrainConfig,
        *,
        extent: float,
        data_background: Sequence[float] = (1.0, 1.0, 1.0),
        backend: str = "auto",
    ) -> None:
        if not extent > 0 or not math.isfinite(extent):
            raise ValueError(f"Trainer: extent must be finite and > 0, got {extent}")
        gaussians.check("Trainer initial Gaussians")
        self.config = config
        self.extent = float(extent)
        self.data_background = torch.tensor([float(c) for c in data_background], dtype=torch.float32)
        self.backend = backend
        self.iteration = 0
        self.active_sh_degree = 0
        self.generator = torch.Generator().manual_seed(config.seed)
        g = gaussians.with_sh_degree(config.sh_degree).detach()
        c = config
        self.adam = GroupedAdam(
            _gaussians_to_params(g),
            {
                "means": c.position_lr_init * self.extent,
                "quats": c.rotation_lr,
                "log_scales": c.scaling_lr,
                "opacity_logits": c.opacity_lr,
                "sh_dc": c.feature_lr,
                "sh_rest": c.feature_lr / 20.0,
            },
            eps=c.adam_eps,
        )
        self.stats = DensityStats.zeros(g.num, device=g.device)
        self._view_queue: list[int] = []
        self._queue_size = 0
        self._events: list[dict] = []

    # ---- state ---------------------------------------------------------------------------------
    @property
    def gaussians(self) -> GaussianSet:
        """The current Gaussians (detached copies)."""
        return _params_to_gaussians(self.adam.params).clone()

    def state_dict(self) -> dict:
        """Everything needed to resume: optimiser (parameters and moments), iteration, statistics, RNG."""
        return {
            "config": self.config.to_dict(),
            "extent": self.extent,
            "iteration": self.iteration,
            "active_sh_degree": self.active_sh_degree,
            "adam": self.adam.state_dict(),
            "stats": {k: getattr(self.stats, k).clone() for k in ("grad_accum", "denom", "max_radii2d")},
            "generator": self.generator.get_state(),
            "view_queue": list(self._view_queue),
            "view_queue_size": self._queue_size,
            "data_background": self.data_background.clone(),
        }

    def load_state_dict(self, state: dict) -> None:
        """Restore a :meth:`state_dict` (the config is taken from the checkpoint)."""
        self.config = TrainConfig(**state["config"])
        self.extent = float(state["extent"])
        self.iteration = int(state["iteration"])
        self.active_sh_degree = int(state["active_sh_degree"])
        self.adam.load_state_dict(state["adam"])
        self.stats = DensityStats(**{k: v.clone() for k, v in state["stats"].items()})
        self.generator.set_state(state["generator"])
        self._view_queue = list(state["view_queue"])
        self._queue_size = int(state["view_queue_size"])
        self.data_background = state["data_background"].clone()

    # ---- one iteration -------------------------------------------------------------------------
    def train_step(self, view) -> TrainStepStats:
        """One iteration on ``view`` (a :class:`recon.datasets.View` with image, optional alpha and camera)."""
        c = self.config
        self.iteration += 1
        it = self.iteration
        self.adam.lrs["means"] = self.extent * expon_lr(
            it,
            c.position_lr_init,
            c.position_lr_final,
            c.position_lr_max_steps,
            c.position_lr_delay_steps,
            c.position_lr_delay_mult,
        )
        if it % c.sh_increase_interval == 0:
            self.active_sh_degree = min(self.active_sh_degree + 1, c.sh_degree)
        bg = background_color(c.background, self.generator)
        target = composite_target(view.image, view.alpha, self.data_background, bg).to(self.adam.params["means"])
        out = render(
            _params_to_gaussians(self.adam.params),
            view.camera,
            bg.to(target),
            sh_degree=self.active_sh_degree,
            backend=self.backend,
        )
        loss = photometric_loss(out.image, target, c.lambda_dssim)
        loss.backward()
        with torch.no_grad():
            step_psnr = float(psnr(out.image.detach().clamp(0, 1), target))
            densified = reset = False
            if it < c.densify_until_iter:
                grad = out.means2d.grad if out.means2d.grad is not None else torch.zeros_like(out.means2d)
                self.stats.update(ndc_gradient(grad, view.camera.width, view.camera.height), out.radii, out.visible)
                if it > c.densify_from_iter and it % c.densification_interval == 0:
                    self._densify(it)
                    densified = True
                if it % c.opacity_reset_interval == 0 or (c.background == "white" and it == c.densify_from_iter):
                    self.adam.reset_state("opacity_logits", reset_opacity(self.adam.params["opacity_logits"]))
                    self.log_event({"iteration": it, "kind": "opacity_reset"})
                    reset = True
            # As in the reference, parameters replaced this iteration (all after densification, the
            # opacities after a reset) lost their gradient and skip this step.
            if not densified:
                self.adam.step(skip=("opacity_logits",) if reset else ())
            self.adam.zero_grad()
        return TrainStepStats(it, float(loss.detach()), step_psnr, self.adam.params["means"].shape[0])

    def _densify(self, it: int) -> None:
        c = self.config
        g = _params_to_gaussians(self.adam.params).detach()
        res = densify_and_prune(
            g,
            self.stats,
            grad_threshold=c.densify_grad_threshold,
            percent_dense=c.percent_dense,
            extent=self.extent,
            min_opacity=c.min_opacity,
            max_screen_size=c.max_screen_size if it > c.opacity_reset_interval else None,
            big_world_fraction=c.big_world_fraction,
            generator=self.generator,
            max_gaussians=c.max_gaussians,
        )
        if res.gaussians.num == 0:
            log.warning("iteration %d: density control would remove every Gaussian; keeping the set unchanged", it)
        else:
            self.adam.remap(_gaussians_to_params(res.gaussians), res.origin)
            self.log_event(
                {
                    "iteration": it,
                    "kind": "densify",
                    "cloned": res.cloned,
                    "split": res.split,
                    "pruned": res.pruned,
                    "num_gaussians": res.gaussians.num,
                }
            )
        self.stats = DensityStats.zeros(self.adam.params["means"].shape[0], device=g.device)

    def log_event(self, event: dict) -> None:
        """Record a density-control event (the running :meth:`train` call collects it)."""
        self._events.append(event)
        log.debug("%s", event)

    # ---- loops ---------------------------------------------------------------------------------
    def next_view_index(self, count: int) -> int:
        """Index of the next training view: views are visited in a fresh random order every epoch."""
        if not self._view_queue or self._queue_size != count:  # a new epoch, or the view list changed
            self._view_queue = torch.randperm(count, generator=self.generator).tolist()
            self._queue_size = count
        return self._view_queue.pop()

    def train(
        self,
        views: Sequence,
        iterations: int,
        callback: Callable[[TrainStepStats], None] | None = None,
        evaluate_every: int = 0,
        eval_views: Sequence = (),
    ) -> TrainLog:
        """Run ``iterations`` training iterations over ``views``.

        Args:
            views: training views (image [H, W, 3], alpha [H, W] or None, camera).
            iterations: iterations to run (continuing from :attr:`iteration`).
            callback: called with the :class:`TrainStepStats` of every iteration (e.g. a progress bar).
            evaluate_every: evaluate on ``eval_views`` every this many iterations (0: never).
            eval_views: held-out views for the periodic evaluation.
        Returns:
            The :class:`TrainLog` of these iterations.
        """
        check_views(views, self.config.background, self.data_background.tolist())
        if isinstance(iterations, bool) or not isinstance(iterations, int) or iterations < 0:
            raise ValueError(f"iterations must be an integer >= 0, got {iterations!r}")
        train_log = TrainLog()
        self._events = train_log.events  # log_event appends to the log of this call
        start = time.perf_counter()
        for _ in range(iterations):
            st = self.train_step(views[self.next_view_index(len(views))])
            train_log.losses.append(st.loss)
            train_log.psnrs.append(st.psnr)
            train_log.num_gaussians.append(st.num_gaussians)
            if callback is not None:
                callback(st)
            if evaluate_every and eval_views and st.iteration % evaluate_every == 0:
                metrics = evaluate(self.gaussians, eval_views, self.data_background.tolist(), backend=self.backend)
                train_log.evaluations.append(
                    {"iteration": st.iteration, "psnr": metrics["psnr"], "ssim": metrics["ssim"]}
                )
        train_log.wall_time_s = time.perf_counter() - start
        self._events = []
        return train_log


@torch.no_grad()
def evaluate(
    gaussians: GaussianSet, views: Sequence, background: Sequence[float] = (1.0, 1.0, 1.0), backend: str = "auto"
) -> dict:
    """Mean PSNR (dB) and SSIM of renders over ``background`` against held-out views composited on it.

    Args:
        gaussians: trained set (all stored SH bands are used).
        views: views with images composited on ``background``.
        background: [3] in [0, 1].
        backend: renderer backend.
    Returns:
        {"psnr": mean dB, "ssim": mean, "per_view": [{"name", "psnr", "ssim"}]}.
    """
    if not views:
        raise ValueError("evaluate: no views to evaluate on (the dataset's test split is empty?)")
    bg = torch.tensor([float(c) for c in background], dtype=torch.float32)
    rows = []
    for v in views:
        if v.image is None:
            raise ValueError(f"evaluate: view {v.name!r} has no image")
        image = render(gaussians, v.camera, bg.to(gaussians.means), backend=backend).image.clamp(0, 1)
        ref = v.image.to(image)
        rows.append({"name": v.name, "psnr": float(psnr(image, ref)), "ssim": float(ssim(image, ref))})
    means = {k: sum(r[k] for r in rows) / len(rows) for k in ("psnr", "ssim")}
    return {**means, "per_view": rows}


def initial_gaussians(
    config: TrainConfig,
    cameras: Sequence[Camera],
    points: torch.Tensor | None = None,
    point_colors: torch.Tensor | None = None,
) -> GaussianSet:
    """The starting Gaussians of ``config.init``: random points in the box, or the given point cloud.

    Args:
        config: uses init, init_points, init_box, init_opacity, sh_degree, seed.
        cameras: training cameras (for the default box).
        points: [P, 3] point cloud for init "points"; point_colors [P, 3] in [0, 1] (grey when None).
    """
    if config.init == "points":
        if points is None or points.shape[0] < 4:
            raise ValueError(
                "init 'points' needs a point cloud of at least 4 points (the dataset has none); use --init random"
            )
        colors = point_colors if point_colors is not None else torch.full_like(points, 0.5)
        return init_gaussians(points, colors, config.sh_degree, config.init_opacity)
    box = config.init_box if config.init_box is not None else default_init_box(cameras)
    gen = torch.Generator().manual_seed(config.seed + 1)
    count = config.init_points if config.max_gaussians is None else min(config.init_points, config.max_gaussians)
    return random_box_gaussians(count, box, config.sh_degree, gen, config.init_opacity)


def train(
    data,
    config: TrainConfig,
    *,
    callback: Callable[[TrainStepStats], None] | None = None,
    eval_views: Sequence = (),
    evaluate_every: int = 0,
    backend: str = "auto",
    device: str | torch.device = "cpu",
    initial: GaussianSet | None = None,
) -> tuple[GaussianSet, TrainLog]:
    """Train Gaussians on a dataset or a list of views.

    Args:
        data: a :class:`recon.datasets.Dataset` (its train split, background and point cloud are used) or
            a sequence of views composited on white.
        config: hyper-parameters (``config.iterations`` iterations are run).
        callback: per-iteration :class:`TrainStepStats` hook.
        eval_views, evaluate_every: periodic held-out evaluation.
        backend: renderer backend.
        device: torch device of the Gaussians and images.
        initial: starting Gaussians (default: :func:`initial_gaussians`).
    Returns:
        (trained Gaussians, :class:`TrainLog`).
    """
    if hasattr(data, "train") and hasattr(data, "background"):
        views, data_bg = list(data.train), tuple(data.background)
        points, colors = getattr(data, "points", None), getattr(data, "point_colors", None)
    else:
        views, data_bg, points, colors = list(data), (1.0, 1.0, 1.0), None, None
    check_views(views, config.background, data_bg)
    cameras = [v.camera for v in views]
    g = initial if initial is not None else initial_gaussians(config, cameras, points, colors)
    trainer = Trainer(g.to(device), config, extent=scene_extent(cameras), data_background=data_bg, backend=backend)
    moved = [view_to(v, device) for v in views]
    moved_eval = [view_to(v, device) for v in eval_views]
    train_log = trainer.train(moved, config.iterations, callback, evaluate_every, moved_eval)
    return trainer.gaussians, train_log


def view_to(view, device):
    """A shallow copy of ``view`` with its image and alpha on ``device``."""
    return replace(
        view,
        image=None if view.image is None else view.image.to(device),
        alpha=None if view.alpha is None else view.alpha.to(device),
    )
