"""Farthest view sampling (FVS): the coverage baseline of the view-selection literature.

NeRF Director (Xiao et al., CVPR 2024) found that picking the candidate camera farthest from the views already
selected, farthest point sampling in camera space, is as good a selector as the uncertainty-based ones. Here the
distance is between camera centres (scene units): a candidate's score is its distance to the nearest selected view,
d(c) = min_{s selected} |o_c - o_s|, and the planner takes the candidate with the largest d. Its list of k is the
greedy farthest-point order: each next candidate is the farthest from the selected views *and* the candidates
already listed. No image, Gaussian or probe is used.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import torch

from nbv.plan.base import ConfiguredPlanner, PlanningContext, Selection, check_candidates, nan_scores
from recon.camera import Camera


@dataclass(frozen=True)
class FVSConfig:
    """The farthest-view planner.

    Attributes:
        seed: recorded for the registry contract; the planner is deterministic and draws no random numbers.
    """

    seed: int = 0

    def __post_init__(self) -> None:
        if not isinstance(self.seed, int) or isinstance(self.seed, bool):
            raise ValueError(f"FVSConfig.seed must be an int, got {self.seed!r}")


def farthest_view_distances(candidates: Sequence[Camera], selected: Sequence[Camera]) -> list[float]:
    """d(c) = min over the selected cameras of the camera-centre distance (scene units), per candidate.

    Args:
        candidates: C cameras. selected: S cameras (S = 0: every distance is +inf).
    Returns:
        C floats >= 0.
    """
    if not candidates:
        return []
    cand = torch.stack([c.center.to(torch.float64) for c in candidates])
    if not selected:
        return [float("inf")] * len(candidates)
    sel = torch.stack([c.center.to(torch.float64) for c in selected])
    return torch.cdist(cand, sel).amin(dim=1).tolist()


def farthest_view_order(candidates: Sequence[Camera], selected: Sequence[Camera], k: int) -> list[int]:
    """The greedy farthest-point list of ``k`` candidate positions (ties: the lower position).

    Each step takes the candidate whose distance to the nearest of the selected and already listed cameras is the
    largest, then adds it to the set it is measured against.
    """
    if k < 1:
        raise ValueError(f"farthest_view_order: k must be >= 1, got {k}")
    dist = torch.tensor(farthest_view_distances(candidates, selected), dtype=torch.float64)
    centres = torch.stack([c.center.to(torch.float64) for c in candidates])
    order: list[int] = []
    for _ in range(min(k, len(candidates))):
        masked = dist.clone()
        if order:
            masked[order] = -1.0
        best = max(range(len(candidates)), key=lambda i: (float(masked[i]), -i))
        order.append(best)
        dist = torch.minimum(dist, (centres - centres[best]).norm(dim=1))
    return order


class FVSPlanner(ConfiguredPlanner):
    """Farthest view sampling: the candidate farthest from the selected views (module docstring)."""

    name = "fvs"
    config_type = FVSConfig

    def rank(self, context: PlanningContext, k: int) -> tuple[list[int], list[float]]:
        """The greedy farthest-point list of k positions and every candidate's distance d(c) to the selected."""
        selected = [v.camera for v in context.train_views]
        return (
            farthest_view_order(context.candidates, selected, k),
            farthest_view_distances(context.candidates, selected),
        )

    def select(self, context: PlanningContext) -> Selection:
        check_candidates(context, self.name)
        start = time.perf_counter()
        count = len(context.candidates)
        order, scores = self.rank(context, count)
        return Selection(
            pick=order[0],
            shortlist=order,
            k=None,
            scores={"visual": scores, "physics": nan_scores(count)},
            seconds={"visual": time.perf_counter() - start, "physics": 0.0},
        )
