"""The callbacks of a probe run (paper Sec. 3.2-3.3, Eq. 1-3): each probe's D_i onto the Gaussians near it.

:class:`ProbeRecorder` is driven by ``fluidsim.run_probes`` (the probes with the solid, :mod:`nbv.physics.run`) and by
the empty scene (:mod:`nbv.physics.empty_scene`): the Gaussians' cell lists built once over the union of the probes'
domains, fresh sums per probe (:class:`nbv.physics.aggregate.GaussianAccumulator`), the leak count, the recorded
trajectories, the timings and the run's progress bar.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import taichi as ti

from fluidsim.solver import DFSPHSolver, StepStats
from nbv.physics.aggregate import GaussianAccumulator, GaussianLists
from nbv.physics.config import PhysicsConfig
from nbv.physics.empty_cache import EmptySamples
from nbv.physics.progress import RunProgress
from nbv.physics.solid_kernels import LeakCounter
from nbv.physics.trajectory import TrajectoryRecorder


class ProbeRecorder:
    """Callbacks for ``fluidsim.run_probes``: the Gaussians' cell lists built once (over the union of the probes'
    domains), fresh sums per probe, timings, and the steps shown on the run's bar (``progress``)."""

    def __init__(
        self,
        centers: np.ndarray,
        reach: np.ndarray,
        config: PhysicsConfig,
        progress: RunProgress,
        label: str = "",
        grid_bounds: tuple[np.ndarray, np.ndarray] | None = None,
        solid=None,
        record=None,
        lists: GaussianLists | None = None,
    ):
        self.centers, self.reach, self.config, self.progress, self.label = centers, reach, config, progress, label
        self.lists = lists
        # fluid particles deep inside the (filled) solid lattice, counted at every step (nbv.physics.leaks)
        self.leak_counter = None if solid is None else LeakCounter(solid.occupancy, solid.lattice_min, solid.spacing)
        # the fluid of the recorded probes every k steps (nbv.physics.trajectory; None: nothing recorded)
        self.trajectory = None if record is None else TrajectoryRecorder(record, config.steps)
        self.leaks: dict[str, Any] = {}
        self.grid_bounds = grid_bounds
        self.acc = None
        self.means: dict[str, np.ndarray] = {}
        self.counts: dict[str, np.ndarray] = {}
        self.distinct: dict[str, np.ndarray] = {}
        self.domains: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self.histories: dict[str, list[StepStats]] = {}
        self.current: str | None = None  # the probe running now (the one that diverged, on a divergence)
        self.aggregation_s = 0.0
        self.build_s = 0.0
        self._t_start = 0.0
        self.probe_s = 0.0

    def start(self, direction: str, solver: DFSPHSolver) -> None:
        t0 = time.perf_counter()
        # The lists cover the union of the probes' domains, so every probe reuses them; its sums are its own.
        if self.lists is None:
            self.lists = GaussianLists(self.centers, self.reach, *self.grid_bounds)
        self.acc = None  # the last probe's sums go before this one's are allocated
        self.acc = GaussianAccumulator(
            self.lists,
            solver.domain_min,
            solver.domain_max,
            track_distinct=self.config.track_distinct,
            max_fluid=solver.fluid.capacity,
        )
        self.build_s += time.perf_counter() - t0
        self.domains[direction] = (solver.domain_min.copy(), solver.domain_max.copy())
        self.current = direction
        if self.leak_counter is not None:
            self.leak_counter.start(self.config.steps)
        if self.trajectory is not None:
            self.trajectory.start(direction, solver)
        self.progress.start(direction, self.label)
        self._t_start = time.perf_counter()

    def step(self, direction: str, solver: DFSPHSolver, stats: StepStats) -> None:
        if self.leak_counter is not None:
            self.leak_counter.count(solver, stats.step)
        if self.trajectory is not None:
            self.trajectory.step(direction, solver, stats.step)
        if (stats.step + 1) % self.config.accumulate_every == 0:
            ti.sync()  # on a GPU, wait for the solver's step so that only the aggregation is timed
            t0 = time.perf_counter()
            self.acc.add_from_solver(solver)
            ti.sync()
            self.aggregation_s += time.perf_counter() - t0

    def tick(self, stats: StepStats) -> None:
        self.progress.tick(stats)

    def stop(self) -> None:
        """The current probe ended early (it diverged): its time so far counts as probe time, as its aggregation
        time already does."""
        if self.current is not None and self.current not in self.histories:
            self.probe_s += time.perf_counter() - self._t_start

    def end(self, direction: str, solver: DFSPHSolver, history: list[StepStats]) -> None:
        t0 = time.perf_counter()
        self.acc.flush()  # the last staged steps count as aggregation time
        ti.sync()
        self.aggregation_s += time.perf_counter() - t0
        self.probe_s += time.perf_counter() - self._t_start
        self.means[direction] = np.asarray(self.acc.means(), np.float64)
        self.counts[direction] = np.asarray(self.acc.counts, np.int64)
        if self.config.track_distinct:
            self.distinct[direction] = np.asarray(self.acc.distinct_counts, np.int64)
        self.acc = None  # read: its sums go (the lists stay for the next probe)
        if self.leak_counter is not None:
            self.leaks[direction] = self.leak_counter.finish(solver)
        self.histories[direction] = history
        if self.trajectory is not None:
            self.trajectory.end(direction)

    def replay(self, direction: str, domain_min, domain_max, samples: EmptySamples) -> None:
        """A probe's recorded steps (the empty-scene cache) onto the Gaussians: the means and counts that
        :meth:`start`, :meth:`step` and :meth:`end` give while its solver runs, bit for bit."""
        t0 = time.perf_counter()
        if self.lists is None:
            self.lists = GaussianLists(self.centers, self.reach, *self.grid_bounds)
        acc = GaussianAccumulator(self.lists, domain_min, domain_max)
        t1 = time.perf_counter()
        acc.add_samples(samples.positions, samples.values, samples.step_counts)
        self.means[direction] = np.asarray(acc.means(), np.float64)
        self.counts[direction] = np.asarray(acc.counts, np.int64)
        self.domains[direction] = (np.asarray(domain_min, np.float64), np.asarray(domain_max, np.float64))
        self.build_s += t1 - t0
        self.aggregation_s += time.perf_counter() - t1
