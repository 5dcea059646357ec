"""The ActiveNeRF-style variance planner; :mod:`nbv.plan.variance_model` computes its scores."""

from __future__ import annotations

import time

import torch

from nbv.plan.base import ConfiguredPlanner, PlanningContext, Selection, check_candidates, descending, nan_scores
from nbv.plan.variance_model import VarianceConfig, fit_variances, variance_scores


class VariancePlanner(ConfiguredPlanner):
    """ActiveNeRF on 3D Gaussians: the largest variance reduction (:mod:`nbv.plan.variance_model`).

    Keeps the fitted log-variances between rounds and warm-starts the next fit from them when the number
    of Gaussians is unchanged (a resumed run starts afresh).
    """

    name = "variance"
    config_type = VarianceConfig

    def __init__(self, config: VarianceConfig | None = None) -> None:
        super().__init__(config)
        self.log_variances: torch.Tensor | None = None

    def rank(self, context: PlanningContext, k: int) -> tuple[list[int], list[float]]:
        """The top-k positions by variance reduction and every candidate's score."""
        g = context.gaussians.detach()
        warm = self.log_variances if self.log_variances is not None and self.log_variances.numel() == g.num else None
        fit = fit_variances(g, context.train_views, context.background.to(g.device), self.config, warm)
        self.log_variances = fit.log_variances
        scores = variance_scores(g, context.candidates, fit.variances, self.config.prior_floor)
        return descending(scores)[:k], scores

    def select(self, context: PlanningContext) -> Selection:
        check_candidates(context, self.name)
        start = time.perf_counter()
        _, scores = self.rank(context, len(context.candidates))
        return Selection(
            pick=descending(scores)[0],
            shortlist=descending(scores),
            k=None,
            scores={"visual": scores, "physics": nan_scores(len(scores))},
            seconds={"visual": time.perf_counter() - start, "physics": 0.0},
        )
