"""The progress bar of a probe run: "probe k of n" over the probes and the empty scene, with one ETA."""

from __future__ import annotations

from tqdm import tqdm

from fluidsim import StepStats
from nbv.physics.config import PhysicsConfig
from nbv.physics.plan import ProbePlan

__all__ = ["RunProgress"]


class RunProgress:
    """One progress bar for a run's probes and its empty-scene reference: "probe k of n" and the probe's direction
    as the description, and one ETA over all of them.

    A step of a probe costs about in proportion to its fluid particles, so the bar counts fluid particle-steps
    (each step weighted by its slab's particles, :meth:`ProbePlan.fluid_counts`) and shows the percentage, not the
    count: the probes differ in size (the side probes' slabs are larger than the vertical ones'), and the ETA holds
    across them. The first probe's first steps include Taichi's compilation, so the ETA starts high.

    Args:
        plan: the run's probes. config: the run's settings (directions, steps, empty reference).
        enabled: draw the bar (False: a silent one).
        empty: whether the empty-scene probes follow the probes (``config.empty_reference`` by default).
    """

    def __init__(self, plan: ProbePlan, config: PhysicsConfig, enabled: bool, empty: bool | None = None):
        empty = config.empty_reference if empty is None else empty
        self.weights = plan.fluid_counts(config.directions)
        self.steps = config.steps
        self.count = len(config.directions) * (2 if empty else 1)
        self.index = 0
        self.weight = 0
        self.poll = None  # called at every step (EmptyHelper.poll), or None
        total = self.steps * sum(self.weights.values()) * (2 if empty else 1)
        self.bar = tqdm(
            total=total,
            desc=f"probe 0 of {self.count}",
            bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}<{remaining}{postfix}",
            disable=not enabled,
            leave=False,
        )

    def start(self, direction: str, label: str = "") -> None:
        """The next probe (``label``: "empty " for the empty scene's) starts."""
        self.index += 1
        self.weight = self.weights[direction]
        self.bar.set_description_str(f"probe {self.index} of {self.count} ({label}{direction})", refresh=False)

    def skip(self, direction: str, label: str = "") -> None:
        """The next probe is not run (its result was cached): the bar moves past it."""
        self.start(direction, label)
        self.bar.update(self.steps * self.weight)

    def stopped(self, steps_run: int) -> None:
        """The current probe stopped early after ``steps_run`` steps (:mod:`nbv.physics.early_stop`): the bar moves
        past the steps it will not run, so the ETA stays one over what is left."""
        self.bar.update(max(self.steps - steps_run, 0) * self.weight)

    def done_elsewhere(self, direction: str) -> None:
        """An empty-scene probe ran in the worker process (:mod:`nbv.physics.empty_worker`): the bar moves past it."""
        self.index += 1
        self.bar.update(self.steps * self.weights[direction])

    def tick(self, stats: StepStats) -> None:
        """One step of the current probe ran (and ``poll``, when set, is called: the empty-scene worker's
        messages are read between steps)."""
        if self.poll is not None:
            self.poll()
        self.bar.update(self.weight)
        self.bar.set_postfix(
            step=f"{stats.step + 1}/{self.steps}",
            it=f"{stats.density_iterations}/{stats.divergence_iterations}",
            vmax=f"{stats.max_speed:.2f}",
            fluid=stats.active,
            refresh=False,
        )

    def close(self) -> None:
        self.bar.close()
