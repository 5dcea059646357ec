"""Probe runs on 3D Gaussians and the per-Gaussian divergence D_g (paper Sec. 3.2-3.3, Eq. 2-3).

The Gaussians are turned into a static solid (:mod:`nbv.physics.solidify`), the five probes of
:mod:`fluidsim.probes` are run against it in the current Taichi runtime (one runtime, never
re-initialised here), and at every k-th step each fluid particle i within n r_g of Gaussian g adds its
divergence D_i (paper Eq. 1) to g's sum and count (:class:`nbv.physics.aggregate.GaussianAccumulator`, a grid,
never all particles x all Gaussians):

- D_g^(IC) = sum / count for one probe IC (0 when nothing came near; Eq. 2-3), n = 3, r_g = the largest
  principal standard deviation of g;
- D_g = max over the probes (as in the paper); the mean over the probes is kept too;
- D-bar = (1 / |G|) sum_g pi s_g^2 D_g with s_g = tr(Sigma_g) in simulation metres^2 (m^4/s), for the
  max- and the mean-combined D_g, and the same quantity for an *empty scene*: the same probes in the
  same walled domains with no solid, accumulated onto the same Gaussians ("what D-bar would read if the
  geometry did nothing").

Units: the Gaussians live in scene units; the simulation in metres, Y-up (:class:`SceneTransform`).
``scale="auto"`` scales the scene so that the object's largest extent (of the centres of the Gaussians
whose opacity reaches the threshold) is ``target_extent`` = 2 m, which puts it in the paper's
about [-1.5, 1.5]^3 domain at r = 0.025 m.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np
import taichi as ti
import torch
from tqdm import tqdm

from fluidsim import DFSPHSolver, SimulationDiverged, SolverConfig, StepStats, run_probes
from fluidsim.output import stats_table
from fluidsim.probes import probe_setup
from fluidsim.scene import lattice_in_box
from fluidsim.simulation import check_time_step
from fluidsim.simulation import run as run_solver
from fluidsim.sources import wall_particles
from nbv import scores
from nbv.physics.aggregate import GaussianAccumulator
from nbv.physics.config import PhysicsConfig, kept_gaussians, scene_transform
from nbv.physics.leaks import LeakCounter
from nbv.physics.memory import check_memory, estimate_memory, memory_limit_bytes
from nbv.physics.result import PhysicsResult, ProbeDiverged, _t, gaussians_sha256
from nbv.physics.solidify import (
    SimGaussians,
    SolidifyConfig,
    gaussian_arrays_in_sim,
    gaussians_to_solid,
)
from nbv.physics.trajectory import (
    TrajectoryRecorder,
    check_record_size,
    probe_fluid_counts,
)

log = logging.getLogger(__name__)

# A probe that retires more than this fraction of its fluid (it left the walled domain) gets a warning.
RETIRED_WARNING_FRACTION = 0.5



def probe_warnings(direction: str, counts: np.ndarray, history: list[StepStats]) -> list[str]:
    """What makes one probe's D_g suspect, logged as warnings: no fluid particle came within reach of any
    Gaussian (its D_g^(IC) is 0 everywhere), or more than RETIRED_WARNING_FRACTION of the fluid left the domain."""
    out = []
    steps = len(history)
    if not np.any(np.asarray(counts) > 0):
        out.append(f"no fluid particle came within reach of any Gaussian in {steps} steps, so D_g of this probe is 0 "
                   "everywhere; check the time step (--dt), the scale and the up direction")
    initial = history[0].active + history[0].retired if history else 0
    retired = sum(s.retired for s in history)
    if initial and retired > RETIRED_WARNING_FRACTION * initial:
        out.append(f"{retired} of {initial} fluid particles ({100.0 * retired / initial:.0f} %) left the domain "
                   f"within {steps} steps; reduce the time step (--dt)")
    for w in out:
        log.warning("probe %s: %s", direction, w)
    return out



# ---- the probe runs --------------------------------------------------------------------------------
def _progress_bar(direction: str, steps: int, enabled: bool):
    return tqdm(total=steps, desc=f"probe {direction}", unit="step", disable=not enabled, leave=False)



class _ProbeRecorder:
    """Callbacks for ``fluidsim.run_probes``: one accumulator for all the probes (retargeted), timings and a progress
    bar."""

    def __init__(self, centers: np.ndarray, reach: np.ndarray, config: PhysicsConfig, progress: bool,
                 label: str = "", grid_bounds: tuple[np.ndarray, np.ndarray] | None = None, solid=None,
                 record=None):
        self.centers, self.reach, self.config, self.progress, self.label = centers, reach, config, progress, label
        # fluid particles deep inside the (filled) solid lattice, counted at every step (nbv.physics.leaks)
        self.leak_counter = None if solid is None else LeakCounter(solid.occupancy, solid.lattice_min, solid.spacing)
        # the fluid of the recorded probes every k steps (nbv.physics.trajectory; None: nothing recorded)
        self.trajectory = None if record is None else TrajectoryRecorder(record, config.steps)
        self.leaks: dict[str, Any] = {}
        self.grid_bounds = grid_bounds
        self.acc = None
        self.bar = None
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
        # The lists cover the union of the probes' domains, so every probe reuses them (only the sums are zeroed).
        if self.acc is None or not self.acc.retarget(solver.domain_min, solver.domain_max):
            self.acc = GaussianAccumulator(self.centers, self.reach, solver.domain_min, solver.domain_max,
                                           track_distinct=self.config.track_distinct,
                                           max_fluid=solver.fluid.capacity, grid_bounds=self.grid_bounds)
        self.build_s += time.perf_counter() - t0
        self.domains[direction] = (solver.domain_min.copy(), solver.domain_max.copy())
        self.current = direction
        if self.leak_counter is not None:
            self.leak_counter.start(self.config.steps)
        if self.trajectory is not None:
            self.trajectory.start(direction, solver)
        self.bar = _progress_bar(f"{self.label}{direction}", self.config.steps, self.progress)
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

    def tick(self, direction: str, stats: StepStats) -> None:
        self.bar.update(1)
        self.bar.set_postfix(it=f"{stats.density_iterations}/{stats.divergence_iterations}",
                             vmax=f"{stats.max_speed:.2f}", fluid=stats.active, refresh=False)

    def end(self, direction: str, solver: DFSPHSolver, history: list[StepStats]) -> None:
        t0 = time.perf_counter()
        self.acc.flush()  # the last staged steps count as aggregation time
        ti.sync()
        self.aggregation_s += time.perf_counter() - t0
        self.probe_s += time.perf_counter() - self._t_start
        self.bar.close()
        self.means[direction] = np.asarray(self.acc.means(), np.float64)
        self.counts[direction] = np.asarray(self.acc.counts, np.int64)
        if self.config.track_distinct:
            self.distinct[direction] = np.asarray(self.acc.distinct_counts, np.int64)
        if self.leak_counter is not None:
            self.leaks[direction] = self.leak_counter.finish(solver)
        self.histories[direction] = history
        if self.trajectory is not None:
            self.trajectory.end(direction)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()



def probe_domains_union(solid: np.ndarray, config: PhysicsConfig, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """(min [3], max [3]) m: the box around the domains of all of ``config``'s probes."""
    setups = [probe_setup(solid, d, config.probe_config(), spacing) for d in config.directions]
    return (np.min([np.asarray(s.domain_min, np.float64) for s in setups], axis=0),
            np.max([np.asarray(s.domain_max, np.float64) for s in setups], axis=0))



def _run_with(recorder: _ProbeRecorder, solid: np.ndarray, config: PhysicsConfig, steps: int,
              scfg: SolverConfig) -> dict[str, list[StepStats]]:
    try:
        return run_probes(solid, scfg, config.probe_config(), steps, on_step=recorder.step,
                          on_probe_start=recorder.start, on_probe_end=recorder.end, progress=recorder.tick)
    finally:
        recorder.close()



def empty_scene_probes(solid: np.ndarray, centers: np.ndarray, reach: np.ndarray, config: PhysicsConfig,
                       progress: bool = True, cache: dict | None = None,
                       accumulator=None) -> tuple[np.ndarray, float]:
    """D_g^(IC) of the empty scene: each probe's slab in its walled domain with no solid, onto the same Gaussians.

    Args:
        solid: [M, 3] the solid the domains are fitted to (not simulated), sim metres.
        centers, reach: [G, 3], [G] sim metres.
        config: the probe settings.
        progress: show a bar per probe.
        cache: a dict to reuse results within a process, keyed by domain, settings and Gaussians.
        accumulator: a :class:`nbv.physics.aggregate.GaussianAccumulator` of these Gaussians to reuse (the probe run's:
            its lists cover the same domains; its distinct counts are dropped). None: one is built over the union of
            the probes' domains, and every probe reuses it.
    Returns:
        ([P, G] float64 per-probe means, seconds spent).
    """
    t0 = time.perf_counter()
    scfg = config.solver_config()
    probe = config.probe_config()
    key_cfg = json.dumps(config.to_dict(), sort_keys=True, default=str)
    key_g = hash((centers.tobytes(), reach.tobytes()))
    out = []
    rec = _ProbeRecorder(centers, reach, replace(config, track_distinct=False), progress, label="empty ",
                         grid_bounds=probe_domains_union(solid, config, scfg.spacing))
    if accumulator is not None:
        accumulator.drop_distinct()
        rec.acc = accumulator
    for d in config.directions:
        setup = probe_setup(solid, d, probe, scfg.spacing)
        key = (setup, key_cfg, key_g)
        if cache is not None and key in cache:
            out.append(cache[key])
            continue
        fluid = lattice_in_box(setup.fluid_min, setup.fluid_max, scfg.spacing)
        vel = np.broadcast_to(np.asarray(setup.velocity), fluid.shape)
        walls = wall_particles(setup.domain_min, setup.domain_max, scfg.spacing, probe.wall_layers)
        solver = DFSPHSolver(scfg, setup.domain_min, setup.domain_max, fluid, vel, walls)
        rec.start(d, solver)
        try:
            history = run_solver(solver, config.steps, on_step=lambda s, st, d=d, r=rec: r.step(d, s, st),
                                 progress=lambda st, d=d, r=rec: r.tick(d, st))
        except SimulationDiverged as exc:
            exc.probe = f"empty-scene {d}"  # which run diverged, for ProbeDiverged
            raise
        finally:
            rec.close()
        rec.end(d, solver, history)
        out.append(rec.means[d])
        if cache is not None:
            cache[key] = rec.means[d]
    return np.stack(out), time.perf_counter() - t0



_EMPTY_CACHE: dict = {}



def simulate_gaussians(gaussians, config: PhysicsConfig, progress: bool = True, source: str = "",
                       record=None, *, solid_edit=None, source_frame: str = "") -> PhysicsResult:
    """Run the probes against the solid of ``gaussians`` and aggregate D_i onto every Gaussian (Eq. 2-3).

    Uses the Taichi runtime already initialised by the caller (never calls ``ti.init``).

    Args:
        gaussians: a ``recon.gaussians.GaussianSet`` in scene units.
        config: probe settings.
        progress: a tqdm bar per probe (steps, solver iterations, max speed).
        source: a label for the result (the .ply path).
        source_frame: the JSON record of the frame the file was read in (``recon.formats.SourceFrame.to_json``),
            stored in RESULT.h5.
        record: a :class:`nbv.physics.trajectory.RecordConfig`: keep those probes' fluid every k steps in
            ``PhysicsResult.trajectories`` (None: nothing recorded).
        solid_edit: for measurements only: a function ``Solid -> Solid`` applied to the solid before the probes
            (``fluidgs bench hole --ideal`` cuts an ideal hole with :func:`nbv.holes.cut_cylinder`); None: the
            Gaussians' own solid.
    Returns:
        PhysicsResult.
    Raises:
        ValueError: bad Gaussians, an empty solid, a run too large for memory, a time step too large for the
            particle spacing (CFL), or a recording too large or of a probe not run, before any simulation.
        ProbeDiverged: a probe diverged; its ``result`` holds the probes completed before it.
    """
    t_total = time.perf_counter()
    if record is not None:
        record.check_probes(config.directions, config.steps)
    gaussians = gaussians.detach().to("cpu").check(source or "Gaussians")
    digest = gaussians_sha256(gaussians)
    transform = scene_transform(gaussians, config)
    kept = kept_gaussians(gaussians, config)
    if kept is not None:  # simulate the kept Gaussians at the resolved scale, then give every Gaussian its row
        inner = replace(config, crop=None, scale=transform.scale)
        try:
            part = simulate_gaussians(gaussians.subset(torch.from_numpy(np.nonzero(kept)[0])), inner, progress,
                                      source, record, solid_edit=solid_edit)
        except ProbeDiverged as exc:
            exc.result = replace(expand_to_all(exc.result, gaussians, kept, config), gaussians_sha256=digest,
                                 source_frame=source_frame)
            raise
        return replace(expand_to_all(part, gaussians, kept, config), gaussians_sha256=digest,
                       source_frame=source_frame)
    # The cheap bound (the Gaussians' box) decides first; when it does not fit but the lattice does, the
    # solid is computed and the probes are re-estimated around it, since scattered faint Gaussians widen
    # the box without making solid. Either way the check comes before any probe is allocated.
    sim = SimGaussians.of(gaussians, transform)  # the one simulation-frame value of the Gaussians of this run
    cheap = estimate_memory(gaussians, config, transform, sim=sim)
    exact_check = cheap["bytes"] > memory_limit_bytes(config)
    if exact_check and (cheap["lattice_points"] > SolidifyConfig.max_points
                        or cheap["resident_bytes"] + cheap["solidify_bytes"] > memory_limit_bytes(config)):
        # the solid is too costly to compute: raise with the estimate
        check_memory(gaussians, config, transform, sim=sim)
    scfg = config.solver_config()
    t0 = time.perf_counter()
    solid = gaussians_to_solid(sim, SolidifyConfig(spacing=scfg.spacing,
                                                         opacity_threshold=config.opacity_threshold,
                                                         fill_cavities=config.fill_cavities), transform)
    if solid_edit is not None:
        solid = solid_edit(solid)
    solidify_s = time.perf_counter() - t0
    if exact_check:
        check_memory(gaussians, config, transform, solid_points=solid.points, sim=sim)
    means, covs, radii = sim.means, sim.covariances, sim.radii
    means, covs = np.ascontiguousarray(means, np.float64), np.ascontiguousarray(covs, np.float64)
    reach = np.ascontiguousarray(config.n_radius * np.asarray(radii, np.float64))
    log.info("solid: %d particles from %d Gaussians (scale %.4g m/unit)", len(solid.points), len(means),
             transform.scale)

    check_probe_time_steps(solid.points, config, scfg)
    if record is not None:
        check_record_size(probe_fluid_counts(solid.points, record.directions, config.probe_config(), scfg.spacing),
                          config.steps, record)
    recorder = _ProbeRecorder(means, reach, config, progress, solid=solid, record=record,
                              grid_bounds=probe_domains_union(solid.points, config, scfg.spacing))
    base = dict(solid=np.asarray(solid.points, np.float64), transform=transform, means=means, covariances=covs,
                reach=reach, config=config, source=source, gaussians_sha256=digest,
                source_frame=source_frame)

    def timings(empty_s: float = 0.0) -> dict[str, float]:
        return {"solidify": solidify_s, "simulation": recorder.probe_s - recorder.aggregation_s,
                "aggregation": recorder.aggregation_s, "accumulator_setup": recorder.build_s,
                "empty_reference": empty_s, "total": time.perf_counter() - t_total}

    try:
        _run_with(recorder, solid.points, config, config.steps, scfg)
    except SimulationDiverged as exc:  # keep the probes completed before it, say which one diverged where
        done = tuple(d for d in config.directions if d in recorder.histories)
        failure = {"probe": recorder.current, "step": int(exc.step), "reason": exc.reason}
        result = _assemble(recorder, done, base, timings(), status="diverged", failure=failure)
        raise ProbeDiverged(str(recorder.current), exc.step, exc.reason, result) from exc
    result = _assemble(recorder, config.directions, base, timings())
    if not config.empty_reference:
        return result
    try:
        empty, empty_s = empty_scene_probes(solid.points, means, reach, config, progress, _EMPTY_CACHE,
                                            accumulator=recorder.acc)
    except SimulationDiverged as exc:
        probe = getattr(exc, "probe", "empty-scene")
        failure = {"probe": probe, "step": int(exc.step), "reason": exc.reason}
        raise ProbeDiverged(probe, exc.step, exc.reason, replace(result, status="diverged", failure=failure)) from exc
    return replace(result, empty_per_probe=empty, timings=timings(empty_s),
                   dbar_empty=scores.geometry_divergence(_t(covs), _t(empty.max(0))),
                   dbar_empty_mean=scores.geometry_divergence(_t(covs), _t(empty.mean(0))))



def check_probe_time_steps(solid: np.ndarray, config: PhysicsConfig, scfg: SolverConfig) -> None:
    """Refuse, before any probe runs, a time step too large for the particle spacing in any probe's domain
    (:func:`fluidsim.simulation.check_time_step`: inflow speed plus free fall through the domain)."""
    probe = config.probe_config()
    for d in config.directions:
        s = probe_setup(solid, d, probe, scfg.spacing)
        check_time_step(scfg, float(np.linalg.norm(s.velocity)), s.domain_min, s.domain_max, config.steps,
                        where=f"probe {d} (--dt {scfg.dt:g} s, --speed {config.speed:g} m/s)")



def _assemble(recorder: _ProbeRecorder, dirs: Sequence[str], base: dict[str, Any], timings: dict[str, float],
              **extra: Any) -> PhysicsResult:
    """The PhysicsResult of the probes ``dirs`` that ``recorder`` completed (none: D_g = 0, D-bar NaN)."""
    covs = base["covariances"]
    g, dirs = len(covs), tuple(dirs)
    if dirs:
        per_probe = np.stack([recorder.means[d] for d in dirs])
        counts = np.stack([recorder.counts[d] for d in dirs])
        distinct = np.stack([recorder.distinct[d] for d in dirs]) if recorder.config.track_distinct else None
        d_max, d_mean = per_probe.max(0), per_probe.mean(0)
        dbar = scores.geometry_divergence(_t(covs), _t(d_max))
        dbar_mean = scores.geometry_divergence(_t(covs), _t(d_mean))
    else:
        per_probe, counts = np.zeros((0, g)), np.zeros((0, g), np.int64)
        distinct = counts.copy() if recorder.config.track_distinct else None
        d_max, d_mean, dbar, dbar_mean = np.zeros(g), np.zeros(g), float("nan"), float("nan")
    return PhysicsResult(
        directions=dirs, per_probe=per_probe, per_probe_counts=counts, per_probe_distinct=distinct,
        divergence=d_max, divergence_mean=d_mean, dbar=dbar, dbar_mean=dbar_mean, dbar_empty=None,
        dbar_empty_mean=None, empty_per_probe=None, stats={d: stats_table(recorder.histories[d]) for d in dirs},
        domains={d: recorder.domains[d] for d in dirs}, timings=timings,
        warnings={d: probe_warnings(d, recorder.counts[d], recorder.histories[d]) for d in dirs},
        leaks={d: recorder.leaks[d] for d in dirs if d in recorder.leaks},
        trajectories={} if recorder.trajectory is None else
        {d: recorder.trajectory.results[d] for d in dirs if d in recorder.trajectory.results}, **base, **extra)



def expand_to_all(part: PhysicsResult, gaussians, kept: np.ndarray, config: PhysicsConfig) -> PhysicsResult:
    """A result on the kept Gaussians -> one row per Gaussian of ``gaussians`` (the dropped ones: D_g = 0, no
    samples), with ``kept`` recorded and ``config`` (the crop) restored. D-bar stays the kept Gaussians' own."""
    g = len(kept)

    def full(a: np.ndarray | None, axis: int = 0) -> np.ndarray | None:
        if a is None:
            return None
        shape = list(a.shape)
        shape[axis] = g
        out = np.zeros(shape, a.dtype)
        index = [slice(None)] * a.ndim
        index[axis] = kept
        out[tuple(index)] = a
        return out

    means, covs, _, radii = gaussian_arrays_in_sim(gaussians, part.transform)
    return replace(
        part, per_probe=full(part.per_probe, 1), per_probe_counts=full(part.per_probe_counts, 1),
        per_probe_distinct=full(part.per_probe_distinct, 1), divergence=full(part.divergence),
        divergence_mean=full(part.divergence_mean), empty_per_probe=full(part.empty_per_probe, 1),
        means=np.ascontiguousarray(means), covariances=np.ascontiguousarray(covs),
        reach=np.ascontiguousarray(config.n_radius * radii), config=config, kept=kept.copy())
