"""The 3DGS training hyper-parameters (:class:`TrainConfig`), torch-free so that ``fluidgs CMD --help`` loads no torch.

:mod:`recon.train` runs them; it re-exports every name here.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from fluidsim.config import check_choices, check_known_keys

BACKGROUNDS = ("white", "black", "random")
INITS = ("random", "points")
REFERENCE_ITERATIONS = 30000
# Iteration-valued fields that TrainConfig.for_iterations scales by n / 30000.
SCHEDULE_FIELDS = (
    "position_lr_max_steps",
    "densification_interval",
    "opacity_reset_interval",
    "densify_from_iter",
    "densify_until_iter",
    "sh_increase_interval",
)
# A density step averages the gradient over the views seen since the last one: keep at least this many.
MIN_DENSIFICATION_INTERVAL = 10
# Upper bounds checked before any work: far above any real run (the reference trains 30,000 iterations from 100,000
# SfM points at most), low enough that a mistyped number is refused at once instead of running for weeks or asking
# for terabytes (init_points x 59 floats are allocated at the start).
MAX_ITERATIONS = 1_000_000
MAX_INIT_POINTS = 10_000_000
MAX_SEED = 2**32 - 1
PARAM_NAMES = ("means", "quats", "log_scales", "opacity_logits", "sh_dc", "sh_rest")


@dataclass(frozen=True)
class TrainConfig:
    """Hyper-parameters of 3DGS training (defaults: the reference trainer, 30k iterations).

    Attributes:
        iterations: training iterations (one view each).
        position_lr_init, position_lr_final: position learning rates at the start and after
            ``position_lr_max_steps`` (multiplied by the scene extent).
        position_lr_delay_steps, position_lr_delay_mult: sine warm-up of the position rate (the reference
            passes 0 delay steps, so its delay_mult 0.01 has no effect; so do we by default).
        feature_lr: SH DC learning rate; higher SH bands use feature_lr / 20.
        opacity_lr: 0.025 (the current reference; the first paper release used 0.05).
        scaling_lr, rotation_lr: learning rates of log-scales and quaternions.
        lambda_dssim: weight of D-SSIM in the loss.
        percent_dense: clone/split size limit as a fraction of the extent.
        densification_interval, densify_from_iter, densify_until_iter: density control runs every
            interval iterations for densify_from_iter < it < densify_until_iter.
        densify_grad_threshold: mean NDC view-space gradient norm that triggers densification.
        opacity_reset_interval: iterations between opacity resets (also at densify_from_iter with a
            white background, as the reference does).
        sh_increase_interval: iterations between SH degree increments, from 0 up to ``sh_degree``.
        sh_degree: largest SH degree (0 to 3).
        min_opacity: prune below this opacity.
        max_screen_size: prune Gaussians larger than this radius in pixels (after the first opacity reset).
        big_world_fraction: prune Gaussians larger than this fraction of the extent (same condition).
        max_gaussians: optional cap on the number of Gaussians (None: no cap, as the reference).
        background: "white", "black" or "random" (a random colour per iteration).
        init: "random" (uniform points in a box) or "points" (the dataset's point cloud).
        init_points: number of random initial points (at most ``max_gaussians``).
        init_box: (xmin, ymin, zmin, xmax, ymax, zmax) of the random points, scene units; None: a cube
            centred at the cameras' common look-at point with half-size 0.3 x extent (the reference
            Blender init uses +-1.3 for cameras at radius 4, i.e. 0.3 x its extent 4.4).
        init_opacity: initial opacity of every Gaussian.
        seed: seed of every random draw.
        adam_eps: Adam epsilon (1e-15 in 3DGS).
    """

    iterations: int = 30000
    position_lr_init: float = 1.6e-4
    position_lr_final: float = 1.6e-6
    position_lr_delay_steps: int = 0
    position_lr_delay_mult: float = 0.01
    position_lr_max_steps: int = 30000
    feature_lr: float = 2.5e-3
    opacity_lr: float = 0.025
    scaling_lr: float = 5e-3
    rotation_lr: float = 1e-3
    lambda_dssim: float = 0.2
    percent_dense: float = 0.01
    densification_interval: int = 100
    opacity_reset_interval: int = 3000
    densify_from_iter: int = 500
    densify_until_iter: int = 15000
    densify_grad_threshold: float = 2e-4
    sh_increase_interval: int = 1000
    sh_degree: int = 3
    min_opacity: float = 0.005
    max_screen_size: float = 20.0
    big_world_fraction: float = 0.1
    max_gaussians: int | None = None
    background: str = "white"
    init: str = "random"
    init_points: int = 5000
    init_box: tuple[float, ...] | None = None
    init_opacity: float = 0.1
    seed: int = 0
    adam_eps: float = 1e-15

    def __post_init__(self) -> None:
        positive_ints = (
            "iterations",
            "position_lr_max_steps",
            "densification_interval",
            "opacity_reset_interval",
            "sh_increase_interval",
            "init_points",
        )
        for name in positive_ints:
            val = getattr(self, name)
            if isinstance(val, bool) or not isinstance(val, int) or val < 1:
                raise ValueError(f"TrainConfig.{name} must be an integer >= 1, got {val!r}")
        for name, high, what in (
            ("iterations", MAX_ITERATIONS, f"iterations (the reference trains {REFERENCE_ITERATIONS:,})"),
            ("init_points", MAX_INIT_POINTS, "initial points (each holds 59 floats from the start)"),
        ):
            if getattr(self, name) > high:
                raise ValueError(f"TrainConfig.{name} must be at most {high:,} {what}, got {getattr(self, name):,}")
        for name in ("densify_from_iter", "densify_until_iter", "position_lr_delay_steps", "seed"):
            val = getattr(self, name)
            if isinstance(val, bool) or not isinstance(val, int) or val < 0:
                raise ValueError(f"TrainConfig.{name} must be an integer >= 0, got {val!r}")
        for name in (
            "position_lr_init",
            "position_lr_final",
            "feature_lr",
            "opacity_lr",
            "scaling_lr",
            "rotation_lr",
            "percent_dense",
            "densify_grad_threshold",
            "max_screen_size",
            "big_world_fraction",
        ):
            val = getattr(self, name)
            if isinstance(val, bool) or not isinstance(val, (int, float)) or not math.isfinite(val) or val <= 0:
                raise ValueError(f"TrainConfig.{name} must be a finite number > 0, got {val!r}")
        for name in ("lambda_dssim", "position_lr_delay_mult"):
            val = getattr(self, name)
            if isinstance(val, bool) or not isinstance(val, (int, float)) or not 0.0 <= val <= 1.0:
                raise ValueError(f"TrainConfig.{name} must be in [0, 1], got {val!r}")
        for name in ("min_opacity", "init_opacity"):
            val = getattr(self, name)
            if isinstance(val, bool) or not isinstance(val, (int, float)) or not 0.0 < val < 1.0:
                raise ValueError(f"TrainConfig.{name} must be in (0, 1), got {val!r}")
        if self.seed > MAX_SEED:
            raise ValueError(f"TrainConfig.seed must be at most {MAX_SEED:,} (a 32-bit seed), got {self.seed:,}")
        if not isinstance(self.adam_eps, (int, float)) or not self.adam_eps >= 0:
            raise ValueError(f"TrainConfig.adam_eps must be >= 0, got {self.adam_eps!r}")
        if self.sh_degree not in (0, 1, 2, 3) or isinstance(self.sh_degree, bool):
            raise ValueError(f"TrainConfig.sh_degree must be 0, 1, 2 or 3, got {self.sh_degree!r}")
        if self.max_gaussians is not None and (not isinstance(self.max_gaussians, int) or self.max_gaussians < 1):
            raise ValueError(f"TrainConfig.max_gaussians must be None or an integer >= 1, got {self.max_gaussians!r}")
        check_choices(self, {"background": BACKGROUNDS, "init": INITS}, "TrainConfig.")
        if self.init_box is not None:
            box = tuple(float(v) for v in self.init_box)
            ordered = len(box) == 6 and all(box[i] < box[i + 3] for i in range(3))
            if not ordered or not all(math.isfinite(v) for v in box):
                raise ValueError(
                    f"TrainConfig.init_box must be (xmin, ymin, zmin, xmax, ymax, zmax) with min < max, "
                    f"got {self.init_box!r}"
                )
            object.__setattr__(self, "init_box", box)

    @classmethod
    def for_iterations(cls, iterations: int, **overrides) -> TrainConfig:
        """The reference schedule compressed to ``iterations``.

        Every iteration-valued field (position_lr_max_steps, densification_interval, opacity_reset_interval,
        densify_from_iter, densify_until_iter, sh_increase_interval) is the reference value times
        iterations / 30000, rounded, at least 1 (0 stays 0), and the densification interval is at least 10 (so
        that each density step averages the gradient over several views). So 3000 iterations densify every 10
        iterations from 50 to 1500, reset opacities every 300 and raise the SH degree every 100, the same
        fractions of the run as the reference. ``overrides`` then replace any field.

        Example:
            >>> TrainConfig.for_iterations(3000).densify_until_iter
            1500
        """
        if isinstance(iterations, bool) or not isinstance(iterations, int) or iterations < 1:
            raise ValueError(f"TrainConfig.iterations must be an integer >= 1, got {iterations!r}")
        if iterations > MAX_ITERATIONS:
            raise ValueError(
                f"TrainConfig.iterations must be at most {MAX_ITERATIONS:,} iterations (the reference trains "
                f"{REFERENCE_ITERATIONS:,}), got {iterations:,}"
            )
        ref = cls()
        f = iterations / REFERENCE_ITERATIONS
        scaled = {name: max(1, round(getattr(ref, name) * f)) if getattr(ref, name) else 0 for name in SCHEDULE_FIELDS}
        scaled["densification_interval"] = max(MIN_DENSIFICATION_INTERVAL, scaled["densification_interval"])
        check_known_keys(cls, overrides)
        return cls(**{**scaled, "iterations": iterations, **overrides})

    def to_dict(self) -> dict:
        return asdict(self)
