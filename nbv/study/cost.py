"""The cost model of an experiment: each job's seconds from its own protocol, estimated before the first job runs.

A job (:mod:`nbv.study.experiment`) is one active run plus its evaluation. Its wall time on one CPU thread is a sum
of parts, each a count of work from the job's config times a coefficient of :class:`Costs`:

    training  train_s            x training iterations x pixels per image
    visual    visual_s[planner]  x candidate views over the rounds x pixels   (FisherRF's H, the variance fit)
    probes    probe_step_s       x probe-steps of the selections, in reference steps
              + probe_gaussian_s x Gaussians, per probe run                   (the per-Gaussian neighbour lists)
    eval      eval_step_s        x probe-steps of the evaluation (its empty scene counted), in reference steps
              + probe_gaussian_s x Gaussians + eval_s
    rounds    round_s per selection round (scoring, rounds.json, the checkpoint)

A reference step is one step of one probe at r = ``REF_RADIUS`` around an object of extent ``REF_EXTENT`` (the
"auto" scale): the fluid fills a domain that grows with the object, in particles spaced 2 r, so a step at radius r
and extent L is (REF_RADIUS / r)^3 (L / REF_EXTENT)^3 reference steps. Training and the visual planner render every
pixel, so they scale with the image's pixels. A probe stopped early (``stop_tolerance``) costs less than counted.

The jobs run ``workers`` at a time with ``threads`` each on ``cores`` cores: the model divides the one-thread total
by min(workers x threads, cores), ideal sharing, and adds one start-up per worker. Other processes share the
cores too: :func:`cpu_slowdown` measures, just before the start, how much of a core one busy thread gets (its CPU
seconds over the wall seconds of a short spin), and the wall time is multiplied by its inverse, at least 1 (the load
average lags by a minute: a run that just ended still counts in it). The coefficients
(:data:`MEASURED`, docs/performance.md "What an experiment costs") are medians of the per-part timings that
rounds.json and eval.json record, on the shared 2-core CPU at one thread; a loaded machine runs slower, so the
experiment prints its actual time beside the estimate at the end.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, field

from nbv.active import ActiveConfig
from nbv.physics import PhysicsConfig
from nbv.plan import uses_physics
from nbv.plan.rules import FUSED

REF_RADIUS = 0.05  # m, the cpu-small probes' particle radius
REF_EXTENT = 2.0  # m, PhysicsConfig.target_extent's default
PARTS = ("training", "visual", "probes", "eval", "rounds")


@dataclass(frozen=True)
class Costs:
    """Coefficients of the model, seconds on one thread (see the module docstring).

    Attributes:
        train_s: per training iteration per pixel.
        visual_s: per candidate view per pixel, by visual planner (a planner not listed costs nothing: random).
        probe_step_s: per reference probe-step of a selection's probes.
        probe_gaussian_s: per Gaussian per probe run (the neighbour lists built once per run).
        eval_step_s: per reference probe-step of the evaluation (distinct tracking on).
        eval_s: the rest of an evaluation (test renders, Chamfer, critical views, the cached functional probe).
        round_s: the rest of a selection round.
        start_s: a worker's start (imports, Taichi), once per worker.
    """

    train_s: float
    visual_s: Mapping[str, float] = field(default_factory=dict)
    probe_step_s: float = 0.0
    probe_gaussian_s: float = 0.0
    eval_step_s: float = 0.0
    eval_s: float = 0.0
    round_s: float = 0.0
    start_s: float = 0.0


# Medians of 64 jobs (two seeds of 8 scenes x fisher, fisher+area, fisher+fluid, variance at 32 px, B = 5, 300
# iterations, 1,000 Gaussians, eval probes 1 x 300 steps at r = 0.05 m) on the shared 2-core CPU, one thread;
# probe_gaussian_s from one probe run at 1,000 and 4,000 Gaussians (docs/performance.md "What an experiment costs").
MEASURED = Costs(
    train_s=9.0e-6,
    visual_s={"fisher": 17.5e-6, "fvs": 17.5e-6, "variance": 14e-6},
    probe_step_s=8.0e-3,
    probe_gaussian_s=0.3e-3,
    eval_step_s=17.5e-3,
    eval_s=2.2,
    round_s=0.03,
    start_s=4.0,
)


@dataclass(frozen=True)
class Scene:
    """What the model needs of a dataset: its train (candidate) views and the pixels of one image at the run's
    resolution."""

    views: int
    pixels: int


def reference_steps(physics: PhysicsConfig) -> float:
    """Reference probe-steps of one probe run of ``physics`` (every direction, its replicas and its empty scene)."""
    extent = physics.target_extent if physics.scale == "auto" else REF_EXTENT
    particles = (REF_RADIUS / physics.particle_radius) ** 3 * (extent / REF_EXTENT) ** 3
    runs = physics.replicas * (2 if physics.empty_reference else 1)
    return physics.steps * len(physics.directions) * particles * runs


def visual_planner(method: str) -> str:
    """The visual planner whose ranking a method's rounds pay for (``fisher+fluid`` -> fisher)."""
    return FUSED[method].visual if method in FUSED else method


def job_seconds(
    active: ActiveConfig, eval_physics: PhysicsConfig, scene: Scene, costs: Costs = MEASURED
) -> dict[str, float]:
    """One job's seconds per part (:data:`PARTS`) on one thread.

    Args:
        active: the job's active run. eval_physics: its evaluation's probes (:func:`eval_probes`).
        scene: its dataset's candidate views and pixels per image at ``active.resolution``.
    Returns:
        {part: seconds}.
    Example:
        >>> a = ActiveConfig.from_preset("cpu-small", method="fisher")
        >>> round(job_seconds(a, a.physics, Scene(40, 64 * 64))["training"], 1)
        36.9
    """
    rounds = active.rounds()
    iterations = active.total_iterations + (active.schedule_iterations() if active.mode == "reset" else 0)
    gaussians = active.train_config(active.total_iterations).max_gaussians
    candidates = sum(scene.views - n for n in rounds)
    physics_rounds = len(rounds) if uses_physics(active.method) else 0
    probe_run = reference_steps(active.physics) * costs.probe_step_s + gaussians * costs.probe_gaussian_s
    return {
        "training": costs.train_s * iterations * scene.pixels,
        "visual": costs.visual_s.get(visual_planner(active.method), 0.0) * candidates * scene.pixels,
        "probes": physics_rounds * probe_run,
        "eval": reference_steps(eval_physics) * costs.eval_step_s + gaussians * costs.probe_gaussian_s + costs.eval_s,
        "rounds": len(rounds) * costs.round_s,
    }


def cpu_slowdown(seconds: float = 0.5) -> float:
    """How many times slower than on an idle core one thread runs now: the wall seconds of a busy spin of about
    ``seconds`` over the CPU seconds it got (1 on an idle core, about 3 with 5 other busy threads on 2 cores)."""
    wall0, cpu0 = time.perf_counter(), time.process_time()
    while time.perf_counter() - wall0 < seconds:
        pass
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    return max(1.0, wall / max(cpu, 1e-3))


def parallel(workers: int, threads: int, cores: int) -> int:
    """How many jobs' threads run at once: min(workers x threads, cores), at least 1."""
    return max(1, min(workers * threads, cores))


@dataclass(frozen=True)
class Estimate:
    """An experiment's estimate: one-thread seconds per part summed over the jobs left, and the wall seconds."""

    jobs: int
    seconds: dict[str, float]
    parallel: int
    workers: int
    start_s: float
    slowdown: float = 1.0

    @property
    def wall_s(self) -> float:
        """The one-thread total shared over :attr:`parallel` threads, plus one start per worker used, times the
        :attr:`slowdown` of the machine's other work (:func:`cpu_slowdown`)."""
        if not self.jobs:
            return 0.0
        return self.slowdown * (
            sum(self.seconds.values()) / self.parallel + self.start_s * min(self.workers, self.jobs)
        )


def estimate(
    per_job: list[dict[str, float]],
    workers: int,
    threads: int,
    cores: int,
    slowdown: float = 1.0,
    costs: Costs = MEASURED,
) -> Estimate:
    """The :class:`Estimate` of the jobs whose :func:`job_seconds` are ``per_job``, on ``cores`` cores where other
    work makes a thread ``slowdown`` times slower."""
    seconds = {p: math.fsum(j[p] for j in per_job) for p in PARTS}
    return Estimate(len(per_job), seconds, parallel(workers, threads, cores), workers, costs.start_s, slowdown)


def minutes(seconds: float) -> str:
    """``42`` -> "42 s", ``95`` -> "1.6 min", ``7200`` -> "2.0 h"."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    return f"{seconds / 3600:.1f} h" if seconds >= 5400 else f"{seconds / 60:.1f} min"
