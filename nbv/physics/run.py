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

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from fluidsim import SimulationDiverged, SolverConfig, StepStats, run_probes
from fluidsim.output import stats_table
from fluidsim.simulation import check_time_step
from nbv import scores
from nbv.physics.config import PhysicsConfig
from nbv.physics.early_stop import ConvergenceCheck
from nbv.physics.empty_cache import EmptyReference
from nbv.physics.empty_scene import empty_scene_probes
from nbv.physics.empty_worker import EmptyHelper, empty_helper, offer_empty
from nbv.physics.memory import check_memory, check_memory_bound
from nbv.physics.plan import ProbePlan, ProbeRunContext, RunFrame
from nbv.physics.progress import RunProgress
from nbv.physics.recorder import ProbeRecorder
from nbv.physics.replicas import replica_offsets
from nbv.physics.result import PhysicsResult, ProbeDiverged, _t, combine_replicas
from nbv.physics.solidify import SolidLattice
from nbv.physics.trajectory import RecordConfig, check_record_size

log = logging.getLogger(__name__)

# A probe that retires more than this fraction of its fluid (it left the walled domain) gets a warning.
RETIRED_WARNING_FRACTION = 0.5


def probe_warnings(direction: str, counts: np.ndarray, history: list[StepStats]) -> list[str]:
    """What makes one probe's D_g suspect, logged as warnings: no fluid particle came within reach of any
    Gaussian (its D_g^(IC) is 0 everywhere), or more than RETIRED_WARNING_FRACTION of the fluid left the domain."""
    out = []
    steps = len(history)
    if not np.any(np.asarray(counts) > 0):
        out.append(
            f"no fluid particle came within reach of any Gaussian in {steps} steps, so D_g of this probe is 0 "
            "everywhere; check the time step (--dt), the scale and the up direction"
        )
    initial = history[0].active + history[0].retired if history else 0
    retired = sum(s.retired for s in history)
    if initial and retired > RETIRED_WARNING_FRACTION * initial:
        out.append(
            f"{retired} of {initial} fluid particles ({100.0 * retired / initial:.0f} %) left the domain "
            f"within {steps} steps; reduce the time step (--dt)"
        )
    for w in out:
        log.warning("probe %s: %s", direction, w)
    return out


def early_stop(recorder: ProbeRecorder, config: PhysicsConfig):
    """The stop predicate of the probes (``config.stop_tolerance``, :mod:`nbv.physics.early_stop`: a probe stops once
    its running D_g^(IC) has converged; None when off). A stopped probe moves the run's bar past its unrun steps."""
    rule = config.stop_rule()
    if not rule.enabled:
        return None
    checks: dict[str, ConvergenceCheck] = {}

    def stop(direction: str, solver, stats: StepStats) -> bool:
        check = checks.setdefault(direction, ConvergenceCheck(rule, lambda: recorder.acc.means()))
        run = stats.step + 1
        if not check(run):
            return False
        log.info(
            "probe %s: stopped after %d of %d steps (its D_g moved by %.2g %% in the last %d steps)",
            direction,
            run,
            config.steps,
            100.0 * check.changes[-1][1],
            rule.window,
        )
        recorder.progress.stopped(run)
        return True

    return stop


def simulate_replicas(run: ProbeRunContext) -> PhysicsResult:
    """The probes of ``run.frame`` (:class:`nbv.physics.plan.RunFrame`) once per replica of ``frame.config.replicas``,
    each against its own solid on the shifted lattice (:func:`nbv.physics.replicas.replica_offsets`), combined
    (:func:`nbv.physics.result.combine_replicas`).

    Args:
        run: the run's context (:class:`nbv.physics.plan.ProbeRunContext`); its recording is made in replica 0 only.
    Returns:
        PhysicsResult, one row per Gaussian of ``frame.gaussians``, with ``replicas`` set (None for one replica).
    Raises:
        ValueError: as :func:`nbv.physics.simulate_gaussians`, before the replica's probes run.
        ProbeDiverged: a probe of some replica diverged; its ``result`` holds that replica's completed probes, and
            its probe names the replica.
    """
    offsets = replica_offsets(run.frame.config.replicas)
    results = []
    for k, offset in enumerate(offsets):
        t0 = time.perf_counter()
        if len(offsets) > 1:
            log.info(
                "replica %d (of 0-%d): lattice shifted by (%.3f, %.3f, %.3f) spacings", k, len(offsets) - 1, *offset
            )
        solid = run.frame.solidify(tuple(offset))
        replica = replace(run, record=run.record if k == 0 else None, started=t0, solidify_s=time.perf_counter() - t0)
        try:
            results.append(simulate_solid(replica, solid))
        except ProbeDiverged as exc:
            if k == 0:
                raise
            label = f"{exc.probe} of replica {k} (lattice shifted by {np.round(offset, 3).tolist()} spacings)"
            failure = {**(exc.result.failure or {}), "probe": label}
            raise ProbeDiverged(label, exc.step, exc.reason, replace(exc.result, failure=failure)) from exc
    return combine_replicas(results, offsets, run.started)


def simulate_gaussians(
    gaussians,
    config: PhysicsConfig,
    progress: bool = True,
    source: str = "",
    record: RecordConfig | None = None,
    *,
    source_frame: str = "",
    empty_worker: Callable[[], None] | None = None,
) -> PhysicsResult:
    """Run the probes against the solid of ``gaussians`` and aggregate D_i onto every Gaussian (Eq. 2-3).

    Uses the Taichi runtime already initialised by the caller (never calls ``ti.init``).

    Args:
        gaussians: a ``recon.gaussians.GaussianSet`` in scene units.
        config: probe settings.
        progress: one bar over the probes and the empty scene ("probe k of n", one ETA; :class:`RunProgress`).
        source: a label for the result (the .ply path).
        source_frame: the JSON record of the frame the file was read in (``recon.formats.SourceFrame.to_json``),
            stored in RESULT.h5.
        record: a :class:`nbv.physics.trajectory.RecordConfig`: keep those probes' fluid every k steps in
            ``PhysicsResult.trajectories`` (None: nothing recorded).
        empty_worker: sets up a worker process (logging, signals, its own Taichi runtime on the CPU) that simulates
            empty-scene probes beside the probes (:mod:`nbv.physics.empty_worker`; the same bits); None: they run in
            this process after the probes.
    Returns:
        PhysicsResult; with ``config.replicas`` > 1, the replicas combined
        (:func:`simulate_replicas`).
    Raises:
        ValueError: bad Gaussians, an empty solid, a run too large for memory, a time step too large for the
            particle spacing (CFL), or a recording too large or of a probe not run, before any simulation.
        ProbeDiverged: a probe diverged; its ``result`` holds the probes completed before it.
    """
    started = time.perf_counter()
    if record is not None:
        record.check_probes(config.directions, config.steps)
    frame = RunFrame.of(gaussians, config, source)  # Sec. 3.2: the kept Gaussians in simulation metres, Y-up
    exact_memory = check_memory_bound(frame)  # the Gaussians' box fits, or the solid will be checked
    run = ProbeRunContext(frame, progress, source, record, exact_memory, started, empty_worker=empty_worker)
    try:
        if config.replicas > 1:  # the probes once per shifted lattice, combined
            result = simulate_replicas(run)
        else:
            t0 = time.perf_counter()
            solid = frame.solidify()  # Sec. 3.2: the static boundary (opacity >= tau, filled)
            result = simulate_solid(replace(run, solidify_s=time.perf_counter() - t0), solid)
    except ProbeDiverged as exc:
        exc.result = replace(exc.result, source_frame=source_frame)
        raise
    return replace(result, source_frame=source_frame)


def simulate_solid(run: ProbeRunContext, solid: SolidLattice) -> PhysicsResult:
    """The probes of :func:`simulate_gaussians` against a given solid of ``run.frame``'s Gaussians (that function's
    ``frame.solidify()``, or an edited one: ``fluidgs bench hole --ideal`` cuts a hole into it).

    Args:
        run: the run's context (:class:`nbv.physics.plan.ProbeRunContext`: frame, progress, source, recording, the
            exact memory check, timings).
        solid: [M, 3] sim metres in ``solid.points``.
    Returns:
        PhysicsResult, one row per Gaussian of ``frame.gaussians``.
    Raises:
        ValueError, ProbeDiverged: as :func:`simulate_gaussians`.
    Example:
        >>> simulate_solid(ProbeRunContext(frame, progress=False), frame.solidify())  # doctest: +SKIP
    """
    frame = run.frame
    config = frame.config
    log.info(
        "solid: %d particles from %d Gaussians (scale %.4g m/unit)",
        len(solid.points),
        frame.sim.num,
        frame.transform.scale,
    )
    plan = ProbePlan.of(solid.points, config)  # Sec. 3.2, Fig. 3: one slab and domain per probe
    if run.exact_memory:  # the probes around the real solid
        check_memory(frame, plan)
    check_probe_time_steps(plan, config, config.solver_config())  # CFL: inflow plus free fall through each domain
    if run.record is not None:
        check_record_size(plan.fluid_counts(run.record.directions), config.steps, run.record)
    # the empty scene's reference, its cache's bound read now (a bad FLUIDGS_CACHE_MAX_GB is refused before any probe)
    reference = EmptyReference.of(config)
    bar = RunProgress(plan, config, run.progress)  # "probe k of n", one ETA over the probes and the empty scene
    helper = empty_helper(run, plan, bar)  # a worker process for the empty scene beside the probes, or None
    try:  # Eq. 1-3: D_i of every step onto the Gaussians within n r_g
        result = _probe(run, solid, plan, bar, reference, helper)
    except ProbeDiverged as exc:
        exc.result = frame.expand(exc.result)
        raise
    finally:
        if helper is not None:
            helper.close()
        bar.close()
    return frame.expand(result)  # every Gaussian of the run gets its row


def _probe(
    run: ProbeRunContext,
    solid: SolidLattice,
    plan: ProbePlan,
    bar: RunProgress,
    reference: EmptyReference,
    helper: EmptyHelper | None,
) -> PhysicsResult:
    """The probes and, with ``config.empty_reference``, the empty scene (from ``reference`` where there; simulated
    by ``helper``'s worker beside the probes, or here): the result on the simulated Gaussians."""
    frame = run.frame
    config, scfg = frame.config, frame.config.solver_config()
    means, covs, reach = frame.means, frame.covariances, frame.reach
    recorder = ProbeRecorder(means, reach, config, bar, solid=solid, record=run.record, grid_bounds=plan.bounds)
    base = dict(
        solid=np.asarray(solid.points, np.float64),
        transform=frame.transform,
        means=means,
        covariances=covs,
        reach=reach,
        config=config,
        source=run.source,
        gaussians_sha256=frame.digest,
    )

    def timings(empty_s: float = 0.0) -> dict[str, float]:
        return {
            "solidify": run.solidify_s,
            "simulation": recorder.probe_s - recorder.aggregation_s,
            "aggregation": recorder.aggregation_s,
            "accumulator_setup": recorder.build_s,
            "empty_reference": empty_s,
            "total": time.perf_counter() - run.started,
        }

    def probe_end(direction: str, solver, history) -> None:
        recorder.end(direction, solver, history)
        if helper is not None:  # its empty scene, unless cached, goes to the worker
            offer_empty(helper, reference, plan, config, direction, len(history), means, reach)

    try:
        run_probes(
            solid.points,
            scfg,
            config.probe_config(),
            config.steps,
            on_step=recorder.step,
            on_probe_start=recorder.start,
            on_probe_end=probe_end,
            progress=lambda d, st: recorder.tick(st),
            setups=plan.setups,
            stop=early_stop(recorder, config),
        )
    except SimulationDiverged as exc:  # keep the probes completed before it, say which one diverged where
        done = tuple(d for d in config.directions if d in recorder.histories)
        recorder.stop()
        failure = {"probe": recorder.current, "step": int(exc.step), "reason": exc.reason}
        result = _assemble(recorder, done, base, timings(), status="diverged", failure=failure)
        raise ProbeDiverged(str(recorder.current), exc.step, exc.reason, result) from exc
    result = _assemble(recorder, config.directions, base, timings())
    if not config.empty_reference:
        return result
    try:
        steps = {d: len(recorder.histories[d]) for d in config.directions}  # each as long as its probe ran
        empty, empty_s = empty_scene_probes(plan, means, reach, config, bar, recorder.lists, reference, steps, helper)
    except SimulationDiverged as exc:
        probe = getattr(exc, "probe", "empty-scene")
        failure = {"probe": probe, "step": int(exc.step), "reason": exc.reason}
        raise ProbeDiverged(probe, exc.step, exc.reason, replace(result, status="diverged", failure=failure)) from exc
    return replace(
        result,
        empty_per_probe=empty,
        timings=timings(empty_s),
        dbar_empty=scores.geometry_divergence(_t(covs), _t(empty.max(0))),
        dbar_empty_mean=scores.geometry_divergence(_t(covs), _t(empty.mean(0))),
    )


def check_probe_time_steps(plan: ProbePlan, config: PhysicsConfig, scfg: SolverConfig) -> None:
    """Refuse, before any probe runs, a time step too large for the particle spacing in any probe's domain
    (:func:`fluidsim.simulation.check_time_step`: inflow speed plus free fall through the domain)."""
    for d, s in plan.setups.items():
        check_time_step(
            scfg,
            float(np.linalg.norm(s.velocity)),
            s.domain_min,
            s.domain_max,
            config.steps,
            where=f"probe {d} (--dt {scfg.dt:g} s, --speed {config.speed:g} m/s)",
        )


def _assemble(
    recorder: ProbeRecorder, dirs: Sequence[str], base: dict[str, Any], timings: dict[str, float], **extra: Any
) -> PhysicsResult:
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
        directions=dirs,
        per_probe=per_probe,
        per_probe_counts=counts,
        per_probe_distinct=distinct,
        divergence=d_max,
        divergence_mean=d_mean,
        dbar=dbar,
        dbar_mean=dbar_mean,
        dbar_empty=None,
        dbar_empty_mean=None,
        empty_per_probe=None,
        stats={d: stats_table(recorder.histories[d]) for d in dirs},
        domains={d: recorder.domains[d] for d in dirs},
        timings=timings,
        warnings={d: probe_warnings(d, recorder.counts[d], recorder.histories[d]) for d in dirs},
        leaks={d: recorder.leaks[d] for d in dirs if d in recorder.leaks},
        trajectories={}
        if recorder.trajectory is None
        else {d: recorder.trajectory.results[d] for d in dirs if d in recorder.trajectory.results},
        **base,
        **extra,
    )
