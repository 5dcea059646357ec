"""The empty scene, the reference of paper Sec. 3.3: each probe's slab in its walled domain with no solid, its D_i
accumulated onto the same Gaussians (D_g^empty, Eq. 2-3: "what D-bar would read if the geometry did nothing").

The empty scene of a probe is the probe of :mod:`fluidsim.probes` with no solid particles
(:func:`fluidsim.probes.build_probe_solver` on an empty solid). Its reference is found, or stored once simulated, by
:class:`nbv.physics.empty_cache.EmptyReference`. This module is the empty scene's runner: its source, and that of the
``fluidsim`` modules it imports, is what the cache's keys digest (:func:`nbv.physics.empty_cache.runner_sources`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping
from dataclasses import replace

import numpy as np

from fluidsim.probes import ProbeSetup, build_probe_solver
from fluidsim.simulation import SimulationDiverged
from fluidsim.simulation import run as run_solver
from fluidsim.solver import StepStats
from nbv.physics.aggregate import GaussianLists
from nbv.physics.config import PhysicsConfig
from nbv.physics.empty_cache import EmptyReference, SampleRecorder
from nbv.physics.plan import ProbePlan
from nbv.physics.progress import RunProgress
from nbv.physics.recorder import ProbeRecorder

log = logging.getLogger(__name__)


def empty_scene_probes(
    plan: ProbePlan,
    centers: np.ndarray,
    reach: np.ndarray,
    config: PhysicsConfig,
    progress: bool | RunProgress = True,
    lists: GaussianLists | None = None,
    reference: EmptyReference | None = None,
    steps: Mapping[str, int] | None = None,
    helper=None,
) -> tuple[np.ndarray, float]:
    """D_g^(IC) of the empty scene: each probe's slab in its walled domain with no solid, onto the same Gaussians.

    Args:
        plan: the probes laid out around the solid (which is not simulated).
        centers, reach: [G, 3], [G] sim metres.
        config: the probe settings.
        progress: show a bar over these probes (True), or move the run's bar (a :class:`RunProgress` that counts
            them; it stays open).
        lists: the cell lists of these Gaussians (:class:`nbv.physics.aggregate.GaussianLists`; the probe run's,
            which cover the same domains). None: built over the union of the probes' domains, for every probe.
        reference: where a probe's reference is looked up and stored (:class:`EmptyReference`: this run's means, the
            disk cache's means and fluid). None: simulate every probe and store nothing.
        steps: the steps each probe's empty scene runs: those its probe with the solid ran, so that D-bar / D-bar_empty
            compares the same time window when the probe stopped early (``config.stop_tolerance``); the cache keys
            hold them. None: ``config.steps``.
        helper: the worker process the probes handed their empty scenes to
            (:class:`nbv.physics.empty_worker.EmptyHelper`, which imports this module in its worker): those it has
            not started run here, it gets the next between them, and its means are gathered (None: all run here).
    Returns:
        ([P, G] float64 per-probe means, seconds spent).
    """
    t0 = time.perf_counter()
    reference = EmptyReference(None) if reference is None else reference
    bar = progress if isinstance(progress, RunProgress) else None
    if bar is None:
        bar = RunProgress(plan, replace(config, empty_reference=False), enabled=bool(progress))
    rec = ProbeRecorder(
        centers, reach, replace(config, track_distinct=False), bar, "empty ", grid_bounds=plan.bounds, lists=lists
    )
    configs = {d: config if steps is None else empty_probe_config(config, steps[d]) for d in config.directions}
    offered = set() if helper is None else helper.offered
    try:
        out = {
            d: empty_probe_means(d, plan.setups[d], configs[d], rec, reference)
            for d in config.directions
            if d not in offered
        }
        if helper is not None:  # the worker's: those it has not started run here, then its means
            while (job := helper.take()) is not None:
                out[job[0]] = empty_probe_means(job[0], plan.setups[job[0]], job[1], rec, reference)
            helper.wait()
            helper.raise_error()
            for d, cfg in helper.lost():
                out[d] = empty_probe_means(d, plan.setups[d], cfg, rec, reference)
            out.update(helper.means)
    finally:
        if bar is not progress:  # a bar of its own: closed here; the run's bar is closed by the run
            bar.close()
    return np.stack([out[d] for d in config.directions]), time.perf_counter() - t0


def empty_probe_config(config: PhysicsConfig, steps: int) -> PhysicsConfig:
    """The settings of one empty-scene probe: ``config`` run for the ``steps`` its probe with the solid ran (no early
    stop of its own)."""
    return replace(config, steps=int(steps))


def empty_probe_means(
    direction: str, setup: ProbeSetup, config: PhysicsConfig, rec: ProbeRecorder, reference: EmptyReference
) -> np.ndarray:
    """One probe's [G] reference: found (its means, or its fluid accumulated here), else simulated; stored."""
    found = reference.lookup(setup, config, rec.centers, rec.reach)
    if found.means is not None:
        log.info("empty-scene probe %s: D_g from the cache", direction)
        rec.progress.skip(direction, "empty ")
        return found.means
    sampler = None
    if found.samples is not None:
        log.info("empty-scene probe %s: the fluid from the cache %s", direction, found.where)
        rec.progress.skip(direction, "empty ")
        rec.replay(direction, setup.domain_min, setup.domain_max, found.samples)
    else:
        sampler = SampleRecorder(config.accumulate_every) if reference.stores else None
        run_empty_probe(direction, setup, config, rec, sampler)
        rec.progress.stopped(config.steps)  # a probe shorter than the run's steps: the bar moves past the rest
    reference.put(found, rec.means[direction], None if sampler is None else sampler.samples())
    return rec.means[direction]


def run_empty_probe(
    direction: str,
    setup: ProbeSetup,
    config: PhysicsConfig,
    recorder: ProbeRecorder,
    sampler: SampleRecorder | None = None,
) -> list[StepStats]:
    """Simulate one probe's empty scene, its D_i onto the Gaussians of ``recorder`` (and its fluid into ``sampler``).

    Args:
        direction: the probe's name. setup: its slab and domain. config: the probe settings.
        recorder: the run's callbacks (:class:`nbv.physics.recorder.ProbeRecorder`); its means of ``direction`` are
            set at the end.
        sampler: keeps the accumulated steps' fluid for the cache (None: nothing kept).
    Returns:
        the step statistics.
    Raises:
        SimulationDiverged: with ``probe`` set to "empty-scene DIRECTION".
    """
    solver = build_probe_solver(np.zeros((0, 3)), setup, config.solver_config(), config.probe_config())
    recorder.start(direction, solver)

    def on_step(s, st):
        recorder.step(direction, s, st)
        if sampler is not None:  # the fluid kept for the cache
            sampler.step(s, st)

    try:
        history = run_solver(solver, config.steps, on_step=on_step, progress=recorder.tick)
    except SimulationDiverged as exc:
        exc.probe = f"empty-scene {direction}"  # which run diverged, for ProbeDiverged
        raise
    recorder.end(direction, solver, history)
    return history
