"""The FisherRF planner; :mod:`nbv.plan.fisher_info` computes its scores."""

from __future__ import annotations

import dataclasses
import logging
import time

from nbv.plan.base import ConfiguredPlanner, PlanningContext, Selection, check_candidates, descending, nan_scores
from nbv.plan.fisher_info import FisherConfig, greedy_top_k

log = logging.getLogger(__name__)


class FisherPlanner(ConfiguredPlanner):
    """FisherRF: the candidate with the largest expected information gain (:mod:`nbv.plan.fisher_info`)."""

    name = "fisher"
    config_type = FisherConfig

    def rank(self, context: PlanningContext, k: int) -> tuple[list[int], list[float]]:
        """The greedy top-k positions and every candidate's score against the selected views.

        The SH bands differentiated are ``config.sh_degree`` when set, else the context's (the trainer's active
        degree: a band it does not fit yet is no parameter of the model, as in FisherRF, whose rasterizer renders
        the active degree only), else all stored bands.
        """
        g = context.gaussians.detach()
        config = self.config
        if config.sh_degree is None and context.sh_degree is not None:
            config = dataclasses.replace(config, sh_degree=context.sh_degree)
        ranking = greedy_top_k(
            g,
            context.candidates,
            [v.camera for v in context.train_views],
            context.background.to(g.device),
            k,
            config,
        )
        if ranking.recomputed:
            log.info("fisher: %d candidate H recomputed (cache_mb=%g)", ranking.recomputed, self.config.cache_mb)
        return ranking.order, ranking.scores

    def select(self, context: PlanningContext) -> Selection:
        check_candidates(context, self.name)
        start = time.perf_counter()
        order, scores = self.rank(context, 1)
        shortlist = order + [i for i in descending(scores) if i not in order]
        return Selection(
            pick=order[0],
            shortlist=shortlist,
            k=None,
            scores={"visual": scores, "physics": nan_scores(len(scores))},
            seconds={"visual": time.perf_counter() - start, "physics": 0.0},
        )
