"""The physics planner and the physics view score S(T) = sum_g w_g(T) D_g of the candidates (paper Eq. 4-5)."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import torch

from nbv.plan.base import ConfiguredPlanner, PlanningContext, Selection, check_candidates, descending, nan_scores
from nbv.scores import DepthBuffer, projected_view_scores
from recon.camera import Camera
from recon.gaussians import GaussianSet


@dataclass(frozen=True)
class PhysicsPlannerConfig:
    """The physics-only planner.

    Attributes:
        seed: recorded for the registry contract; the planner draws no random numbers.
        weighted: use the Eq. 5 view weights w_g(T) (False: the plain sum of D_g over the visible Gaussians).
    """

    seed: int = 0
    weighted: bool = True

    def __post_init__(self) -> None:
        if not isinstance(self.seed, int) or isinstance(self.seed, bool):
            raise ValueError(f"PhysicsPlannerConfig.seed must be an int, got {self.seed!r}")
        if not isinstance(self.weighted, bool):
            raise ValueError(f"PhysicsPlannerConfig.weighted must be a bool, got {self.weighted!r}")


def physics_view_scores(
    gaussians: GaussianSet,
    cameras: list[Camera],
    divergence: torch.Tensor,
    weighted: bool = True,
    occlusion: bool = False,
) -> list[float]:
    """S(T) = sum_g w_g(T) D_g (paper Eq. 4-5) of every camera, from the batched projection (no render).

    Args:
        gaussians: N Gaussians (the set ``divergence`` was computed on).
        cameras: C cameras.
        divergence: [N] D_g, 1/s.
        weighted: Eq. 5 weights (False: plain sum over the visible Gaussians).
        occlusion: count only the Gaussians the coarse depth test finds unhidden (:class:`nbv.scores.DepthBuffer`).
    Returns:
        C floats.
    """
    d = torch.as_tensor(divergence).detach().reshape(-1)
    if d.numel() != gaussians.num:
        raise ValueError(
            f"physics returned {d.numel()} per-Gaussian values for {gaussians.num} Gaussians; "
            "the physics callable must score the Gaussians it is given"
        )
    if not torch.isfinite(d).all():
        raise ValueError("physics returned NaN or Inf per-Gaussian divergences; check the probe run")
    if not cameras:
        return []
    buffer = DepthBuffer() if occlusion else None
    return projected_view_scores(
        d, gaussians.detach(), list(cameras), weighted=weighted, depth_buffer=buffer
    ).scores.tolist()


def shuffled_divergence(divergence: torch.Tensor, seed: int, round_index: int = 0) -> torch.Tensor:
    """D_g permuted across the Gaussians: the same values in random places (the ``+shuffled`` control).

    Args:
        divergence: [N] D_g, 1/s.
        seed: planner seed (any int; negative ones are taken modulo 2^64).
        round_index: selection round, mixed into the seed so every round draws its own permutation.
    Returns:
        [N] ``divergence[perm]`` with perm a permutation from a numpy Generator seeded with (seed, round_index):
        the same multiset of values, deterministic per (seed, round_index).
    """
    d = torch.as_tensor(divergence).detach().reshape(-1)
    rng = np.random.default_rng([int(seed) % 2**64, int(round_index) % 2**64])
    return d[torch.from_numpy(rng.permutation(d.numel())).to(d.device)]


def run_physics(context: PlanningContext, name: str) -> torch.Tensor:
    """[N] D_g of the current Gaussians from ``context.physics`` (the probe runner), for planner ``name``."""
    if context.physics is None:
        raise ValueError(
            f"planner {name!r} needs PlanningContext.physics (the probe runner giving D_g); "
            "pass one, or use a visual-only planner"
        )
    return context.physics(context.gaussians)


class PhysicsPlanner(ConfiguredPlanner):
    """The candidate with the largest physics score S(T) over all candidates."""

    name = "physics"
    config_type = PhysicsPlannerConfig

    def select(self, context: PlanningContext) -> Selection:
        check_candidates(context, self.name)
        start = time.perf_counter()
        divergence = run_physics(context, self.name)
        scores = physics_view_scores(
            context.gaussians, context.candidates, divergence, self.config.weighted, context.occlusion
        )
        order = descending(scores)
        return Selection(
            pick=order[0],
            shortlist=order,
            k=None,
            scores={"visual": nan_scores(len(scores)), "physics": scores},
            seconds={"visual": 0.0, "physics": time.perf_counter() - start},
        )
