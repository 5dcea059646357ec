"""Probe runs on 3D Gaussians and the per-Gaussian divergence D_g (paper Sec. 3.2-3.3, Eq. 2-3).

The Gaussians are turned into a static solid (:mod:`nbv.solidify`), the five probes of
:mod:`fluidsim.probes` are run against it in the current Taichi runtime (one runtime, never
re-initialised here), and at every k-th step each fluid particle i within n r_g of Gaussian g adds its
divergence D_i (paper Eq. 1) to g's sum and count (:class:`nbv.aggregate.GaussianAccumulator`, a grid,
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
import math
import os
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import taichi as ti

from fluidsim import DIRECTIONS, DFSPHSolver, ProbeConfig, SolverConfig, StepStats, run_probes
from fluidsim.output import check_writable, stats_table
from fluidsim.probes import probe_setup
from fluidsim.scene import lattice_in_box
from fluidsim.simulation import run as run_solver
from fluidsim.sources import wall_particles

from . import scores

log = logging.getLogger(__name__)

QUICK = {"particle_radius": 0.05, "steps": 300}
# Estimator radii h_r and h_k of paper Eq. 1 in particle radii: 4 r = 0.1 m at the paper's r = 0.025 m. A fixed
# 0.1 m would leave no neighbour inside h_r at r >= 0.05 m (spacing >= h_r), so D_i would read 0.
ESTIMATOR_RADII = 4.0
# Rough memory per particle of one probe (neighbour lists of 64 fluid + 64 boundary slots, solver arrays,
# the accumulator's lists) and per static boundary particle; calibrated on `fluidgs bench sim` (460 MiB).
BYTES_PER_FLUID = 4096
BYTES_PER_BOUNDARY = 160
BYTES_PER_LATTICE_POINT = 2


@dataclass(frozen=True)
class PhysicsConfig:
    """How the Gaussians are probed.

    Attributes:
        particle_radius: r, m (spacing 2 r; the solid lattice uses the same spacing). Paper 0.025, quick 0.05.
        steps: steps per probe (paper 750, quick 300).
        dt: time step, s.
        speed: inflow speed lambda of the horizontal probes, m/s.
        viscosity: dynamic viscosity mu, Pa s.
        rest_density: rho_0, kg/m^3.
        directions: probes to run, a subset of ("-x", "+x", "-z", "+z", "-y").
        accumulate_every: accumulate D_i every k-th step (k >= 1).
        n_radius: n of Eq. 2: particles within n r_g of a Gaussian count for it.
        opacity_threshold: tau of the solidification (combined opacity >= tau is solid).
        up_axis: the scene's up axis, "y" or "z" (z-up scenes are rotated to Y-up).
        scale: metres per scene unit, or "auto" (largest object extent -> ``target_extent``).
        target_extent: m, the object's largest extent when ``scale`` is "auto".
        fill_cavities: fill enclosed empty regions of the solid (hollow shells become solid).
        track_distinct: count distinct fluid particles per Gaussian (|P_g|, for critical regions).
        empty_reference: also run the probes without the solid for the empty-scene D-bar.
        precision: "f32" or "f64"; must match the Taichi runtime's default float.
        max_memory_gb: refuse to start above this estimated memory, GiB (None: the available memory).
        solver: extra ``fluidsim.SolverConfig`` fields (tolerances, iteration bounds), as (key, value) pairs.
            The estimator radii h_r, h_k default to 4 r (the paper's 0.1 m at r = 0.025 m) unless given here.
    """

    particle_radius: float = 0.025
    steps: int = 750
    dt: float = 0.002
    speed: float = 3.0
    viscosity: float = 10.0
    rest_density: float = 1000.0
    directions: tuple[str, ...] = DIRECTIONS
    accumulate_every: int = 1
    n_radius: float = 3.0
    opacity_threshold: float = 0.3
    up_axis: str = "y"
    scale: float | str = "auto"
    target_extent: float = 2.0
    fill_cavities: bool = False
    track_distinct: bool = False
    empty_reference: bool = True
    precision: str = "f32"
    max_memory_gb: float | None = None
    solver: tuple[tuple[str, Any], ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        for name in ("particle_radius", "dt", "rest_density", "n_radius", "target_extent"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ValueError(f"PhysicsConfig.{name} must be a finite number > 0, got {v!r}")
        for name in ("speed", "viscosity"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ValueError(f"PhysicsConfig.{name} must be a finite number >= 0, got {v!r}")
        for name in ("steps", "accumulate_every"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"PhysicsConfig.{name} must be an integer >= 1, got {v!r}")
        if not 0.0 < self.opacity_threshold < 1.0:
            raise ValueError(f"PhysicsConfig.opacity_threshold must be in (0, 1), got {self.opacity_threshold}")
        dirs = tuple(self.directions)
        if not dirs or any(d not in DIRECTIONS for d in dirs) or len(set(dirs)) != len(dirs):
            raise ValueError(f"PhysicsConfig.directions must be distinct probes from {DIRECTIONS}, got {dirs}")
        object.__setattr__(self, "directions", dirs)
        if self.up_axis not in ("y", "z"):
            raise ValueError(f"PhysicsConfig.up_axis must be 'y' or 'z', got {self.up_axis!r}")
        if self.scale != "auto" and (isinstance(self.scale, bool) or not isinstance(self.scale, (int, float))
                                     or not math.isfinite(self.scale) or self.scale <= 0):
            raise ValueError(f"PhysicsConfig.scale must be 'auto' or a number > 0 (m per scene unit), "
                             f"got {self.scale!r}")
        if self.precision not in ("f32", "f64"):
            raise ValueError(f"PhysicsConfig.precision must be 'f32' or 'f64', got {self.precision!r}")
        if self.max_memory_gb is not None and not self.max_memory_gb > 0:
            raise ValueError(f"PhysicsConfig.max_memory_gb must be > 0 or None, got {self.max_memory_gb}")
        solver = tuple((str(k), v) for k, v in (self.solver.items() if isinstance(self.solver, dict) else self.solver))
        object.__setattr__(self, "solver", solver)
        self.solver_config()  # validates the pass-through keys now

    @classmethod
    def quick(cls, **overrides: Any) -> PhysicsConfig:
        """The quick preset (r = 0.05 m, 300 steps per probe) with optional overrides."""
        return cls(**{**QUICK, **overrides})

    def solver_config(self, dt: float | None = None) -> SolverConfig:
        """The fluidsim solver parameters of these probes (``dt`` overrides the time step)."""
        known = {f.name for f in fields(SolverConfig)}
        extra = dict(self.solver)
        bad = sorted(set(extra) - known)
        if bad:
            raise ValueError(f"PhysicsConfig.solver: unknown SolverConfig keys {bad}; valid keys: {sorted(known)}")
        # h_r = h_k = 4 r: the paper's 0.1 m at r = 0.025 m, scaled so that coarse presets still see neighbours
        extra.setdefault("estimator_radius", ESTIMATOR_RADII * self.particle_radius)
        extra.setdefault("estimator_kernel_radius", ESTIMATOR_RADII * self.particle_radius)
        return SolverConfig(**{**extra, "particle_radius": self.particle_radius, "dt": self.dt if dt is None else dt,
                               "viscosity": self.viscosity, "rest_density": self.rest_density,
                               "precision": self.precision})

    def probe_config(self) -> ProbeConfig:
        """The fluidsim probe parameters (slab, walls, directions)."""
        return ProbeConfig(speed=self.speed, directions=self.directions)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able dict (``from_dict`` reads it back)."""
        d = asdict(self)
        d["directions"] = list(self.directions)
        d["solver"] = dict(self.solver)
        return d

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> PhysicsConfig:
        """Inverse of :meth:`to_dict`; unknown keys are errors naming the key."""
        known = {f.name for f in fields(cls)}
        bad = sorted(set(data) - known)
        if bad:
            raise ValueError(f"unknown PhysicsConfig keys {bad}; valid keys: {sorted(known)}")
        d = dict(data)
        if "directions" in d:
            d["directions"] = tuple(d["directions"])
        if "solver" in d:
            d["solver"] = tuple(dict(d["solver"]).items())
        return cls(**d)


@dataclass
class PhysicsResult:
    """Everything one probe run on a Gaussian set produced (see :func:`save_result` for the HDF5 layout).

    Attributes:
        directions: the probes, in run order (P of them).
        per_probe: [P, G] float64 D_g^(IC), 1/s.
        per_probe_counts: [P, G] int64 (particle, step) samples per Gaussian.
        per_probe_distinct: [P, G] int64 |P_g| per probe, or None when not tracked.
        divergence: [G] D_g = max over the probes, 1/s.
        divergence_mean: [G] mean over the probes, 1/s.
        dbar, dbar_mean: D-bar of the max- and mean-combined D_g, m^4/s.
        dbar_empty, dbar_empty_mean: the same for the empty scene (None when not computed).
        empty_per_probe: [P, G] D_g^(IC) of the empty scene, or None.
        solid: [M, 3] solid particles, sim metres.
        transform: the scene -> simulation transform.
        means: [G, 3] Gaussian centres, sim metres. covariances: [G, 3, 3] sim metres^2.
        reach: [G] n r_g, sim metres.
        stats: per direction, the structured step statistics (fluidsim.output.stats_table).
        domains: per direction, (domain_min, domain_max) in sim metres.
        timings: seconds: solidify, simulation (steps only), aggregation, empty_reference, total.
        config: the PhysicsConfig. source: where the Gaussians came from.
    """

    directions: tuple[str, ...]
    per_probe: np.ndarray
    per_probe_counts: np.ndarray
    per_probe_distinct: np.ndarray | None
    divergence: np.ndarray
    divergence_mean: np.ndarray
    dbar: float
    dbar_mean: float
    dbar_empty: float | None
    dbar_empty_mean: float | None
    empty_per_probe: np.ndarray | None
    solid: np.ndarray
    transform: Any
    means: np.ndarray
    covariances: np.ndarray
    reach: np.ndarray
    stats: dict[str, np.ndarray]
    domains: dict[str, tuple[np.ndarray, np.ndarray]]
    timings: dict[str, float]
    config: PhysicsConfig
    source: str = ""

    @property
    def num_gaussians(self) -> int:
        return int(self.divergence.shape[0])

    def distinct_counts(self) -> np.ndarray:
        """[G] |P_g| summed over the probes (each probe has its own fluid particles); needs track_distinct."""
        if self.per_probe_distinct is None:
            raise ValueError("this result has no distinct particle counts; simulate with track_distinct=True")
        return self.per_probe_distinct.sum(0)


# ---- transform and guards ------------------------------------------------------------------------
def scene_transform(gaussians, config: PhysicsConfig):
    """The :class:`nbv.solidify.SceneTransform` for ``config.up_axis`` and ``config.scale`` ("auto" resolved).

    "auto": metres per scene unit such that the largest extent of the centres of the Gaussians with
    opacity >= ``opacity_threshold`` (all centres when none reach it) is ``target_extent`` m.
    """
    from .solidify import SceneTransform

    if config.scale != "auto":
        return SceneTransform(up_axis=config.up_axis, scale=float(config.scale))
    means = gaussians.means.detach().cpu().double().numpy()
    opaque = gaussians.opacities.detach().cpu().numpy() >= config.opacity_threshold
    pts = means[opaque] if opaque.sum() >= 2 else means
    extent = float(np.ptp(pts, axis=0).max()) if len(pts) >= 2 else 0.0
    if not extent > 0:
        raise ValueError("cannot pick scale='auto': the Gaussians have no spatial extent; "
                         "pass a number (metres per scene unit) as the scale")
    return SceneTransform(up_axis=config.up_axis, scale=config.target_extent / extent)


def _available_memory_bytes() -> int:
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))


def estimate_memory(gaussians, config: PhysicsConfig, transform=None,
                    solid_points: np.ndarray | None = None) -> dict[str, float]:
    """An upper estimate of the memory one probe needs, before any probe is allocated.

    Without ``solid_points`` it is cheap: the bounding box of the Gaussians (centres +- 3 sigma, Gaussians
    with opacity >= tau / 10) stands for the solid's box. With ``solid_points`` [P, 3] (sim metres, the
    solidified Gaussians) the probes are laid out around the real solid, which is smaller when faint or
    scattered Gaussians widen the box but make no solid. Uses the per-particle byte counts ``BYTES_PER_*``
    and the solid lattice estimate of :func:`nbv.solidify.estimate_lattice_points`.

    Returns:
        dict: lattice_points, fluid_particles (largest probe), boundary_particles, bytes.
    """
    from .solidify import SolidifyConfig, estimate_lattice_points, gaussian_arrays_in_sim

    transform = transform if transform is not None else scene_transform(gaussians, config)
    spacing = 2.0 * config.particle_radius
    scfg = SolidifyConfig(spacing=spacing, opacity_threshold=config.opacity_threshold,
                          fill_cavities=config.fill_cavities, max_points=2**62)
    lattice = int(estimate_lattice_points(gaussians, scfg, transform))
    if solid_points is not None and len(solid_points):
        pts = np.asarray(solid_points, np.float64)
        box, solid_count = np.stack([pts.min(0), pts.max(0)]), len(pts)
    else:
        means, _, opacities, radii = gaussian_arrays_in_sim(gaussians, transform)
        # faint Gaussians (under a tenth of tau) cannot make the solid on their own: they do not widen the box
        solid_like = opacities >= 0.1 * config.opacity_threshold
        if solid_like.any():
            means, radii = means[solid_like], radii[solid_like]
        lo, hi = (means - 3 * radii[:, None]).min(0), (means + 3 * radii[:, None]).max(0)
        box, solid_count = np.array([[lo[0], lo[1], lo[2]], [hi[0], hi[1], hi[2]]]), lattice
    probe = config.probe_config()
    fluid = boundary = 0
    for d in config.directions:
        s = probe_setup(box, d, probe, spacing)
        f = float(np.prod(np.floor((np.subtract(s.fluid_max, s.fluid_min)) / spacing)))
        ext = np.subtract(s.domain_max, s.domain_min)
        area = 2 * (ext[0] * ext[1] + ext[1] * ext[2] + ext[0] * ext[2])
        walls = area * probe.wall_layers / spacing**2
        fluid, boundary = max(fluid, int(f)), max(boundary, int(walls) + solid_count)
    total = fluid * BYTES_PER_FLUID + boundary * BYTES_PER_BOUNDARY + lattice * BYTES_PER_LATTICE_POINT
    return {"lattice_points": lattice, "fluid_particles": fluid, "boundary_particles": boundary,
            "bytes": float(total)}


def memory_limit_bytes(config: PhysicsConfig) -> float:
    """The memory a probe may use: ``config.max_memory_gb``, or the memory available now."""
    return config.max_memory_gb * 2**30 if config.max_memory_gb is not None else float(_available_memory_bytes())


def check_memory(gaussians, config: PhysicsConfig, transform=None,
                 solid_points: np.ndarray | None = None) -> dict[str, float]:
    """Raise ValueError, with the estimate and the fix, when a probe would not fit in memory.

    See :func:`estimate_memory` for ``solid_points`` (the exact check once the solid is known)."""
    est = estimate_memory(gaussians, config, transform, solid_points)
    limit = memory_limit_bytes(config)
    if est["bytes"] > limit:
        raise ValueError(
            f"the probe would need about {est['bytes'] / 2**30:.1f} GiB ({est['fluid_particles']:,} fluid and "
            f"{est['boundary_particles']:,} boundary particles at r = {config.particle_radius} m, a solid lattice of "
            f"{est['lattice_points']:,} points) but {limit / 2**30:.1f} GiB are available; use a larger particle "
            "radius (--particle-radius or --quick) or a smaller scale")
    return est


# ---- the probe runs --------------------------------------------------------------------------------
def _progress_bar(direction: str, steps: int, enabled: bool):
    from tqdm import tqdm

    return tqdm(total=steps, desc=f"probe {direction}", unit="step", disable=not enabled, leave=False)


class _ProbeRecorder:
    """Callbacks for ``fluidsim.run_probes``: one accumulator per probe, timings and a progress bar."""

    def __init__(self, centers: np.ndarray, reach: np.ndarray, config: PhysicsConfig, progress: bool,
                 label: str = "", grid_bounds: tuple[np.ndarray, np.ndarray] | None = None):
        self.centers, self.reach, self.config, self.progress, self.label = centers, reach, config, progress, label
        self.grid_bounds = grid_bounds
        self.acc = None
        self.bar = None
        self.means: dict[str, np.ndarray] = {}
        self.counts: dict[str, np.ndarray] = {}
        self.distinct: dict[str, np.ndarray] = {}
        self.domains: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self.aggregation_s = 0.0
        self.build_s = 0.0
        self._t_start = 0.0
        self.probe_s = 0.0

    def start(self, direction: str, solver: DFSPHSolver) -> None:
        from .aggregate import GaussianAccumulator

        t0 = time.perf_counter()
        # The lists cover the union of the probes' domains, so every probe reuses them (only the sums are zeroed).
        if self.acc is None or not self.acc.retarget(solver.domain_min, solver.domain_max):
            self.acc = GaussianAccumulator(self.centers, self.reach, solver.domain_min, solver.domain_max,
                                           track_distinct=self.config.track_distinct,
                                           max_fluid=solver.fluid.capacity, grid_bounds=self.grid_bounds)
        self.build_s += time.perf_counter() - t0
        self.domains[direction] = (solver.domain_min.copy(), solver.domain_max.copy())
        self.bar = _progress_bar(f"{self.label}{direction}", self.config.steps, self.progress)
        self._t_start = time.perf_counter()

    def step(self, direction: str, solver: DFSPHSolver, stats: StepStats) -> None:
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
                       progress: bool = True, cache: dict | None = None) -> tuple[np.ndarray, float]:
    """D_g^(IC) of the empty scene: each probe's slab in its walled domain with no solid, onto the same Gaussians.

    Args:
        solid: [M, 3] the solid the domains are fitted to (not simulated), sim metres.
        centers, reach: [G, 3], [G] sim metres.
        config: the probe settings.
        progress: show a bar per probe.
        cache: a dict to reuse results within a process, keyed by domain, settings and Gaussians.
    Returns:
        ([P, G] float64 per-probe means, seconds spent).
    """
    t0 = time.perf_counter()
    scfg = config.solver_config()
    probe = config.probe_config()
    key_cfg = json.dumps(config.to_dict(), sort_keys=True, default=str)
    key_g = hash((centers.tobytes(), reach.tobytes()))
    out = []
    for d in config.directions:
        setup = probe_setup(solid, d, probe, scfg.spacing)
        key = (setup, key_cfg, key_g)
        if cache is not None and key in cache:
            out.append(cache[key])
            continue
        rec = _ProbeRecorder(centers, reach, replace(config, track_distinct=False), progress, label="empty ")
        fluid = lattice_in_box(setup.fluid_min, setup.fluid_max, scfg.spacing)
        vel = np.broadcast_to(np.asarray(setup.velocity), fluid.shape)
        walls = wall_particles(setup.domain_min, setup.domain_max, scfg.spacing, probe.wall_layers)
        solver = DFSPHSolver(scfg, setup.domain_min, setup.domain_max, fluid, vel, walls)
        rec.start(d, solver)
        try:
            history = run_solver(solver, config.steps, on_step=lambda s, st, d=d, r=rec: r.step(d, s, st),
                                 progress=lambda st, d=d, r=rec: r.tick(d, st))
        finally:
            rec.close()
        rec.end(d, solver, history)
        out.append(rec.means[d])
        if cache is not None:
            cache[key] = rec.means[d]
    return np.stack(out), time.perf_counter() - t0


_EMPTY_CACHE: dict = {}


def simulate_gaussians(gaussians, config: PhysicsConfig, progress: bool = True, source: str = "") -> PhysicsResult:
    """Run the probes against the solid of ``gaussians`` and aggregate D_i onto every Gaussian (Eq. 2-3).

    Uses the Taichi runtime already initialised by the caller (never calls ``ti.init``).

    Args:
        gaussians: a ``recon.gaussians.GaussianSet`` in scene units.
        config: probe settings.
        progress: a tqdm bar per probe (steps, solver iterations, max speed).
        source: a label for the result (the .ply path).
    Returns:
        PhysicsResult.
    Raises:
        ValueError: bad Gaussians, an empty solid, or a run too large for memory, before any simulation.
    """
    from .solidify import SolidifyConfig, gaussian_arrays_in_sim, gaussians_to_solid

    t_total = time.perf_counter()
    gaussians = gaussians.detach().to("cpu").check(source or "Gaussians")
    transform = scene_transform(gaussians, config)
    # The cheap bound (the Gaussians' box) decides first; when it does not fit but the lattice does, the
    # solid is computed and the probes are re-estimated around it, since scattered faint Gaussians widen
    # the box without making solid. Either way the check comes before any probe is allocated.
    cheap = estimate_memory(gaussians, config, transform)
    exact_check = cheap["bytes"] > memory_limit_bytes(config)
    if exact_check and (cheap["lattice_points"] > SolidifyConfig.max_points
                        or cheap["lattice_points"] * BYTES_PER_LATTICE_POINT > memory_limit_bytes(config)):
        check_memory(gaussians, config, transform)  # the solid is too costly to compute: raise with the estimate
    scfg = config.solver_config()
    t0 = time.perf_counter()
    solid = gaussians_to_solid(gaussians, SolidifyConfig(spacing=scfg.spacing,
                                                         opacity_threshold=config.opacity_threshold,
                                                         fill_cavities=config.fill_cavities), transform)
    solidify_s = time.perf_counter() - t0
    if exact_check:
        check_memory(gaussians, config, transform, solid_points=solid.points)
    means, covs, _, radii = gaussian_arrays_in_sim(gaussians, transform)
    means, covs = np.ascontiguousarray(means, np.float64), np.ascontiguousarray(covs, np.float64)
    reach = np.ascontiguousarray(config.n_radius * np.asarray(radii, np.float64))
    log.info("solid: %d particles from %d Gaussians (scale %.4g m/unit)", len(solid.points), len(means),
             transform.scale)

    recorder = _ProbeRecorder(means, reach, config, progress,
                              grid_bounds=probe_domains_union(solid.points, config, scfg.spacing))
    histories = _run_with(recorder, solid.points, config, config.steps, scfg)
    dirs = config.directions
    per_probe = np.stack([recorder.means[d] for d in dirs])
    counts = np.stack([recorder.counts[d] for d in dirs])
    distinct = np.stack([recorder.distinct[d] for d in dirs]) if config.track_distinct else None
    d_max, d_mean = per_probe.max(0), per_probe.mean(0)
    dbar = scores.geometry_divergence(_t(covs), _t(d_max))
    dbar_mean = scores.geometry_divergence(_t(covs), _t(d_mean))

    empty = dbar_empty = dbar_empty_mean = None
    empty_s = 0.0
    if config.empty_reference:
        empty, empty_s = empty_scene_probes(solid.points, means, reach, config, progress, _EMPTY_CACHE)
        dbar_empty = scores.geometry_divergence(_t(covs), _t(empty.max(0)))
        dbar_empty_mean = scores.geometry_divergence(_t(covs), _t(empty.mean(0)))
    simulation_s = recorder.probe_s - recorder.aggregation_s
    timings = {"solidify": solidify_s, "simulation": simulation_s, "aggregation": recorder.aggregation_s,
               "accumulator_setup": recorder.build_s,
               "empty_reference": empty_s, "total": time.perf_counter() - t_total}
    return PhysicsResult(
        directions=dirs, per_probe=per_probe, per_probe_counts=counts, per_probe_distinct=distinct,
        divergence=d_max, divergence_mean=d_mean, dbar=dbar, dbar_mean=dbar_mean, dbar_empty=dbar_empty,
        dbar_empty_mean=dbar_empty_mean, empty_per_probe=empty, solid=np.asarray(solid.points, np.float64),
        transform=transform, means=means, covariances=covs, reach=reach,
        stats={d: stats_table(histories[d]) for d in dirs}, domains=recorder.domains, timings=timings,
        config=config, source=source)


def _t(a: np.ndarray):
    import torch

    return torch.from_numpy(np.asarray(a, np.float64))


# ---- HDF5 ------------------------------------------------------------------------------------------
def save_result(path: str | Path, result: PhysicsResult) -> Path:
    """Write a result to HDF5 atomically (a temporary file in the same folder, then rename).

    Layout::

        /gaussians/D            (G,) D_g, max over the probes, 1/s
        /gaussians/D_mean       (G,) mean over the probes, 1/s
        /gaussians/means        (G, 3) centres, sim metres
        /gaussians/covariances  (G, 3, 3) sim metres^2
        /gaussians/reach        (G,) n r_g, sim metres
        /probes/<dir>/D         (G,) D_g^(IC), 1/s
        /probes/<dir>/counts    (G,) (particle, step) samples
        /probes/<dir>/distinct  (G,) |P_g| (only with track_distinct)
        /probes/<dir>/D_empty   (G,) the empty-scene D_g^(IC) (only with the empty reference)
        /probes/<dir>/stats     one row per step (fluidsim StepStats fields)
                                attributes: domain_min, domain_max (sim metres)
        /solid/x                (M, 3) solid particles, sim metres
        attributes: config (PhysicsConfig JSON), directions, dbar, dbar_mean, dbar_empty, dbar_empty_mean
                    (m^4/s; NaN when not computed), up_axis, scale (m per scene unit), source, timings (JSON)

    Returns:
        the path written.
    """
    p = check_writable(path)
    tmp = p.with_name(f".{p.name}.{os.getpid()}.tmp")
    try:
        with h5py.File(tmp, "w") as f:
            g = f.create_group("gaussians")
            g["D"], g["D_mean"], g["means"] = result.divergence, result.divergence_mean, result.means
            g["covariances"], g["reach"] = result.covariances, result.reach
            for i, d in enumerate(result.directions):
                pg = f.create_group(f"probes/{d}")
                pg["D"], pg["counts"] = result.per_probe[i], result.per_probe_counts[i]
                if result.per_probe_distinct is not None:
                    pg["distinct"] = result.per_probe_distinct[i]
                if result.empty_per_probe is not None:
                    pg["D_empty"] = result.empty_per_probe[i]
                pg["stats"] = result.stats[d]
                if d in result.domains:
                    pg.attrs["domain_min"], pg.attrs["domain_max"] = result.domains[d]
            f.create_dataset("solid/x", data=result.solid, compression="gzip", compression_opts=1)
            f.attrs["config"] = json.dumps(result.config.to_dict())
            f.attrs["directions"] = json.dumps(list(result.directions))
            for key in ("dbar", "dbar_mean", "dbar_empty", "dbar_empty_mean"):
                v = getattr(result, key)
                f.attrs[key] = float("nan") if v is None else float(v)
            f.attrs["up_axis"], f.attrs["scale"] = result.transform.up_axis, float(result.transform.scale)
            f.attrs["source"] = str(result.source)
            f.attrs["timings"] = json.dumps(result.timings)
        os.replace(tmp, p)
    except BaseException:
        if tmp.exists():
            tmp.unlink()
        raise
    return p


def load_result(path: str | Path) -> PhysicsResult:
    """Read a result written by :func:`save_result`.

    Raises:
        ValueError: naming the file when it is not such a result.
    """
    from .solidify import SceneTransform

    p = Path(path)
    if not p.is_file():
        raise ValueError(f"result file {p} does not exist; run `fluidgs simulate` to create it")
    try:
        with h5py.File(p, "r") as f:
            if "gaussians/D" not in f or "config" not in f.attrs:
                raise ValueError(f"{p} is not a `fluidgs simulate` result (no /gaussians/D); re-run `fluidgs simulate`")
            dirs = tuple(json.loads(f.attrs["directions"]))
            probes = [f[f"probes/{d}"] for d in dirs]
            per_probe = np.stack([pg["D"][()] for pg in probes])
            counts = np.stack([pg["counts"][()] for pg in probes])
            distinct = np.stack([pg["distinct"][()] for pg in probes]) if all("distinct" in pg for pg in probes) \
                else None
            empty = np.stack([pg["D_empty"][()] for pg in probes]) if all("D_empty" in pg for pg in probes) else None
            domains = {d: (np.asarray(pg.attrs["domain_min"]), np.asarray(pg.attrs["domain_max"]))
                       for d, pg in zip(dirs, probes, strict=True) if "domain_min" in pg.attrs}

            def opt(key: str) -> float | None:
                v = float(f.attrs[key])
                return None if math.isnan(v) else v

            return PhysicsResult(
                directions=dirs, per_probe=per_probe, per_probe_counts=counts, per_probe_distinct=distinct,
                divergence=f["gaussians/D"][()], divergence_mean=f["gaussians/D_mean"][()],
                dbar=float(f.attrs["dbar"]), dbar_mean=float(f.attrs["dbar_mean"]), dbar_empty=opt("dbar_empty"),
                dbar_empty_mean=opt("dbar_empty_mean"), empty_per_probe=empty, solid=f["solid/x"][()],
                transform=SceneTransform(up_axis=str(f.attrs["up_axis"]), scale=float(f.attrs["scale"])),
                means=f["gaussians/means"][()], covariances=f["gaussians/covariances"][()],
                reach=f["gaussians/reach"][()], stats={d: pg["stats"][()] for d, pg in zip(dirs, probes, strict=True)},
                domains=domains, timings=json.loads(f.attrs["timings"]),
                config=PhysicsConfig.from_dict(json.loads(f.attrs["config"])), source=str(f.attrs["source"]))
    except (OSError, KeyError) as exc:
        raise ValueError(f"cannot read the result file {p}: {exc}; re-run `fluidgs simulate`") from exc


def check_result_matches(result: PhysicsResult, num_gaussians: int, path: str | Path) -> None:
    """Raise ValueError when a stored result was computed for another Gaussian set."""
    if result.num_gaussians != num_gaussians:
        raise ValueError(f"{path} holds D_g for {result.num_gaussians} Gaussians but the .ply has {num_gaussians}; "
                         "pass the result of this .ply or drop --result to simulate again")


def parse_directions(text: str | Sequence[str]) -> tuple[str, ...]:
    """'-x,+x' or a list -> a tuple of probe names (validated)."""
    items = [s.strip() for s in (text.split(",") if isinstance(text, str) else text) if s.strip()]
    bad = [d for d in items if d not in DIRECTIONS]
    if bad or not items:
        raise ValueError(f"--directions: unknown probes {bad or items}; use a comma list of {','.join(DIRECTIONS)}")
    return tuple(items)
