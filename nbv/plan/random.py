"""The random planner: a uniform pick from a numpy Generator seeded with (seed, round)."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from nbv.plan.base import ConfiguredPlanner, PlanningContext, Selection, check_candidates, nan_scores


@dataclass(frozen=True)
class RandomConfig:
    """The random planner.

    Attributes:
        seed: seeds a numpy Generator together with the round number.
    """

    seed: int = 0

    def __post_init__(self) -> None:
        if not isinstance(self.seed, int) or isinstance(self.seed, bool) or self.seed < 0:
            raise ValueError(f"RandomConfig.seed must be an int >= 0, got {self.seed!r}")


class RandomPlanner(ConfiguredPlanner):
    """A uniformly random candidate (reproducible from (seed, round))."""

    name = "random"
    config_type = RandomConfig

    def rank(self, context: PlanningContext, k: int) -> tuple[list[int], list[float]]:
        """k distinct positions drawn uniformly at random (from (seed, round)) and NaN scores."""
        rng = np.random.default_rng([self.config.seed, context.round, k])
        count = len(context.candidates)
        return [int(i) for i in rng.permutation(count)[:k]], nan_scores(count)

    def select(self, context: PlanningContext) -> Selection:
        check_candidates(context, self.name)
        start = time.perf_counter()
        rng = np.random.default_rng([self.config.seed, context.round])
        pick = int(rng.integers(len(context.candidates)))
        count = len(context.candidates)
        return Selection(
            pick=pick,
            shortlist=list(range(count)),
            k=None,
            scores={"visual": nan_scores(count), "physics": nan_scores(count)},
            seconds={"visual": time.perf_counter() - start, "physics": 0.0},
        )
