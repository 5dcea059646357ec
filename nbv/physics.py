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

import hashlib
import json
import logging
import math
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import taichi as ti
import torch
from tqdm import tqdm

from fluidsim import DIRECTIONS, DFSPHSolver, ProbeConfig, SimulationDiverged, SolverConfig, StepStats, run_probes
from fluidsim.memory import available_memory_bytes
from fluidsim.output import stats_table
from fluidsim.probes import probe_setup
from fluidsim.scene import lattice_in_box
from fluidsim.simulation import check_time_step
from fluidsim.simulation import run as run_solver
from fluidsim.sources import wall_particles

from . import floaters, scores
from .aggregate import GaussianAccumulator, reach_classes
from .io import atomic_h5
from .leaks import LeakCounter, read_probe_leaks, write_probe_leaks
from .lists import parse_list
from .scene_frame import SceneTransform, crop_box, inside_box, parse_crop, parse_up, robust_box, up_label
from .solidify import BYTES_PER_GAUSSIAN as BYTES_PER_GAUSSIAN_SOLIDIFY
from .solidify import (
    SolidifyConfig,
    estimate_lattice_points,
    estimate_solidify_bytes,
    gaussian_arrays_in_sim,
    gaussians_to_solid,
    solid_boxes,
)
from .trajectory import TrajectoryRecorder, check_record_size, probe_fluid_counts, read_trajectory, write_trajectory

log = logging.getLogger(__name__)

QUICK = {"particle_radius": 0.05, "steps": 300}
# Estimator radii h_r and h_k of paper Eq. 1 in particle radii: 4 r = 0.1 m at the paper's r = 0.025 m. A fixed
# 0.1 m would leave no neighbour inside h_r at r >= 0.05 m (spacing >= h_r), so D_i would read 0.
ESTIMATOR_RADII = 4.0
# Memory per fluid particle of one probe (solver state, pressure-solver arrays, fluid and boundary neighbour lists)
# and per boundary particle (walls and solid), doubled for headroom: the peak resident memory of probes around a
# solid sphere (-x, f32, 2 threads, 20 steps, after the JIT) grew by 1,050-1,140 B per fluid particle with their
# boundary (r = 0.04-0.02 m, 12k-106k fluid and 32k-154k boundary particles), of which about 130 B per boundary
# particle. The per-Gaussian accumulator is estimated apart (nbv.aggregate.GaussianAccumulator.estimate_bytes).
BYTES_PER_FLUID = 2048
BYTES_PER_BOUNDARY = 256
# Per Gaussian, held through the whole run besides the Gaussian set itself: simulation-frame means, covariances and
# reach (float64, 104 B), and per probe the result rows (means, counts, distinct counts: 24 B).
BYTES_PER_GAUSSIAN_RUN = 104
BYTES_PER_GAUSSIAN_PROBE = 24
BYTES_PER_LATTICE_POINT = 2
# A probe that retires more than this fraction of its fluid (it left the walled domain) gets a warning.
RETIRED_WARNING_FRACTION = 0.5


@dataclass(frozen=True)
class PhysicsConfig:
    """How the Gaussians are probed (the defaults are the paper's; :data:`QUICK` is the quick preset).

    Attributes:
        particle_radius: fluid particle radius r, m; the fluid and the solid lattice are spaced 2 r.
        steps: time steps per probe.
        dt: time step, s.
        speed: inflow speed lambda of the horizontal probes, m/s.
        viscosity: dynamic viscosity mu, Pa s.
        rest_density: rho_0, kg/m^3.
        directions: probes to run, a subset of :data:`fluidsim.directions.DIRECTIONS`.
        accumulate_every: accumulate D_i every k-th step (k >= 1).
        n_radius: n of Eq. 2: particles within n r_g of a Gaussian count for it.
        opacity_threshold: tau: combined opacity at or above which a lattice point is solid (unitless, 0..1).
        up: the scene's up direction, which becomes simulation +y: an axis ("+y", "-y", "+z", ...) or a 3-tuple
            (:func:`nbv.scene_frame.parse_up`). COLMAP captures are often y-down: up "-y".
        scale: metres per scene unit, or "auto" (largest extent of the robust object box -> ``target_extent``).
        crop: None (every Gaussian), "auto" (the robust object box grown by 10 % per side) or (xmin, ymin, zmin,
            xmax, ymax, zmax) in scene units: only the Gaussians whose centres lie inside make solid, are scored
            and size the domain; the others get D_g = 0 and are marked in ``PhysicsResult.kept``.
        target_extent: m, the object's largest extent when ``scale`` is "auto".
        fill_cavities: fill what the Gaussians enclose (default: a closed shell of thin surface Gaussians becomes a
            filled body; :mod:`nbv.solidify`). False keeps the one-point-thick shell.
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
    up: str | tuple[float, float, float] = "+y"
    scale: float | str = "auto"
    crop: str | tuple[float, ...] | None = None
    target_extent: float = 2.0
    fill_cavities: bool = True
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
        up = parse_up(self.up, "PhysicsConfig.up")
        object.__setattr__(self, "up", up_label(up) if isinstance(self.up, str) else tuple(float(c) for c in up))
        object.__setattr__(self, "crop", parse_crop(self.crop))
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
        d["up"] = self.up if isinstance(self.up, str) else list(self.up)
        d["crop"] = self.crop if self.crop is None or isinstance(self.crop, str) else list(self.crop)
        return d

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> PhysicsConfig:
        """Inverse of :meth:`to_dict`; unknown keys are errors naming the key."""
        known = {f.name for f in fields(cls)}
        d = dict(data)
        if "up_axis" in d and "up" not in d:  # results written before `up` replaced `up_axis` ("y" or "z")
            d["up"] = d.pop("up_axis")
        bad = sorted(set(d) - known)
        if bad:
            raise ValueError(f"unknown PhysicsConfig keys {bad}; valid keys: {sorted(known)}")
        if isinstance(d.get("up"), list):
            d["up"] = tuple(d["up"])
        if isinstance(d.get("crop"), list):
            d["crop"] = tuple(d["crop"])
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
        kept: [G] bool, the Gaussians inside ``config.crop`` (None without a crop; the others have D_g = 0).
        warnings: per direction, what makes that probe's D_g suspect (no fluid reached any Gaussian, most fluid
            left the domain); empty lists when all is well.
        gaussians_sha256: :func:`gaussians_sha256` of the Gaussians simulated ("" in files written before it).
        status: "complete", or "diverged" (then ``directions`` are the probes completed before ``failure``).
        failure: None, or {"probe", "step", "reason"} of the probe that diverged.
        leaks: per direction, the probe's final fluid state and leak measure (:class:`nbv.leaks.ProbeLeaks`);
            empty in files written before it.
        trajectories: per recorded direction, its fluid every k steps (:class:`nbv.trajectory.ProbeTrajectory`;
            only with ``record``); :func:`load_result` reads them only when asked (``trajectories=True``).
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
    kept: np.ndarray | None = None
    warnings: dict[str, list[str]] = field(default_factory=dict)
    gaussians_sha256: str = ""
    status: str = "complete"
    failure: dict[str, Any] | None = None
    leaks: dict[str, Any] = field(default_factory=dict)
    trajectories: dict[str, Any] = field(default_factory=dict)

    @property
    def num_gaussians(self) -> int:
        return int(self.divergence.shape[0])

    def distinct_counts(self) -> np.ndarray:
        """[G] |P_g| summed over the probes (each probe has its own fluid particles); needs track_distinct."""
        if self.per_probe_distinct is None:
            raise ValueError("this result has no distinct particle counts; simulate with track_distinct=True")
        return self.per_probe_distinct.sum(0)


class ProbeDiverged(SimulationDiverged):
    """A probe diverged. ``probe`` and ``step`` say where; ``result`` holds the probes completed before it
    (``status`` "diverged", ``failure`` set), for saving: nothing computed is lost."""

    def __init__(self, probe: str, step: int, reason: str, result: PhysicsResult):
        super().__init__(step, reason)
        self.probe, self.result = probe, result
        done = ", ".join(result.directions) or "none"
        self.args = (f"probe {probe} diverged at step {step}: {reason} (probes completed: {done})",)


def gaussians_sha256(gaussians) -> str:
    """SHA-256 (hex) of what the probes depend on: the float32 bytes of means, quats, log_scales and
    opacity_logits, in that order (colours are left out, so a re-coloured copy has the same digest)."""
    h = hashlib.sha256()
    for t in (gaussians.means, gaussians.quats, gaussians.log_scales, gaussians.opacity_logits):
        h.update(np.ascontiguousarray(t.detach().cpu().numpy(), np.float32).tobytes())
    return h.hexdigest()


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


# ---- transform and guards ------------------------------------------------------------------------
def kept_gaussians(gaussians, config: PhysicsConfig, report: bool = True) -> np.ndarray | None:
    """[G] bool: the Gaussians that ``config.crop`` keeps (centres inside the crop box), or None without a crop.

    Raises:
        ValueError: the crop keeps no Gaussian (naming the box, the Gaussians' box and the fix).
    """
    if config.crop is None:
        return None
    means = gaussians.means.detach().cpu().double().numpy()
    opacities = gaussians.opacities.detach().cpu().double().numpy()
    lo, hi = crop_box(config.crop, means, opacities, config.opacity_threshold)
    kept = inside_box(means, lo, hi)
    if not kept.any():
        raise ValueError(f"--crop {config.crop}: the box [{', '.join(f'{v:.4g}' for v in lo)}] - "
                         f"[{', '.join(f'{v:.4g}' for v in hi)}] (scene units) keeps none of the {len(means):,} "
                         f"Gaussians, whose centres span [{', '.join(f'{v:.4g}' for v in means.min(0))}] - "
                         f"[{', '.join(f'{v:.4g}' for v in means.max(0))}]; widen the box or use --crop auto")
    if report:
        log.info("crop %s: kept %d of %d Gaussians (%d dropped)", config.crop, int(kept.sum()), len(kept),
                 int((~kept).sum()))
    return kept


def scene_transform(gaussians, config: PhysicsConfig):
    """The :class:`nbv.scene_frame.SceneTransform` for ``config.up`` and ``config.scale`` ("auto" resolved).

    "auto": metres per scene unit such that the largest extent of the robust object box
    (:func:`nbv.scene_frame.robust_box`, in simulation axes; only the Gaussians that ``config.crop`` keeps)
    is ``target_extent`` m.
    """
    rotated = SceneTransform(config.up, 1.0)
    if config.scale != "auto":
        return SceneTransform(config.up, float(config.scale))
    means = gaussians.means.detach().cpu().double().numpy()
    opacities = gaussians.opacities.detach().cpu().double().numpy()
    kept = kept_gaussians(gaussians, config, report=False)
    if kept is not None:
        means, opacities = means[kept], opacities[kept]
    extent = 0.0
    if len(means) >= 2:
        lo, hi = robust_box(rotated.to_sim(means), opacities, config.opacity_threshold)
        extent = float((hi - lo).max())
    if not extent > 0:
        raise ValueError("cannot pick scale='auto': the Gaussians have no spatial extent; "
                         "pass a number (metres per scene unit) as the scale")
    return SceneTransform(config.up, config.target_extent / extent)


def estimate_memory(gaussians, config: PhysicsConfig, transform=None,
                    solid_points: np.ndarray | None = None) -> dict[str, float]:
    """An upper estimate of the memory one probe needs, before any probe is allocated.

    Without ``solid_points`` it is cheap: the box of the solid lattice stands for the solid's box (the
    Gaussians' 3-sigma boxes where they can make solid: a Gaussian with opacity < tau clipped to the others'
    box, those under tau / 10 left out, :mod:`nbv.floaters`). With ``solid_points`` [P, 3] (sim metres, the
    solidified Gaussians) the probes are laid out around the real solid, which is smaller when faint or
    scattered Gaussians widen the box but make no solid. Uses the per-particle byte counts ``BYTES_PER_*``
    and the solid lattice estimate of :func:`nbv.solidify.estimate_lattice_points`.

    The bytes add the Gaussians held all run to the larger of the solidification's peak
    (:func:`nbv.solidify.estimate_solidify_bytes`) and one probe's (its solver, and the per-Gaussian accumulator's
    :meth:`nbv.aggregate.GaussianAccumulator.estimate_bytes`).

    Returns:
        dict: lattice_points, fluid_particles (largest probe), boundary_particles, and the bytes (floats):
        resident_bytes, solidify_bytes, probe_bytes, accumulator_bytes and their total ``bytes``.
    """
    transform = transform if transform is not None else scene_transform(gaussians, config)
    spacing = 2.0 * config.particle_radius
    scfg = SolidifyConfig(spacing=spacing, opacity_threshold=config.opacity_threshold,
                          fill_cavities=config.fill_cavities, max_points=2**62)
    lattice = int(estimate_lattice_points(gaussians, scfg, transform))
    if solid_points is not None and len(solid_points):
        pts = np.asarray(solid_points, np.float64)
        box, solid_count = np.stack([pts.min(0), pts.max(0)]), len(pts)
    else:
        means, covs, opacities, _ = gaussian_arrays_in_sim(gaussians, transform)
        box, solid_count = np.stack(floaters.lattice_extent(*solid_boxes(means, covs, opacities, scfg))), lattice
    probe = config.probe_config()
    fluid = boundary = 0
    for d in config.directions:
        s = probe_setup(box, d, probe, spacing)
        f = float(np.prod(np.floor((np.subtract(s.fluid_max, s.fluid_min)) / spacing)))
        ext = np.subtract(s.domain_max, s.domain_min)
        area = 2 * (ext[0] * ext[1] + ext[1] * ext[2] + ext[0] * ext[2])
        walls = area * probe.wall_layers / spacing**2
        fluid, boundary = max(fluid, int(f)), max(boundary, int(walls) + solid_count)
    return {"lattice_points": lattice, "fluid_particles": fluid, "boundary_particles": boundary,
            **_memory_parts(gaussians, config, lattice, fluid, boundary)}


def _memory_parts(gaussians, config: PhysicsConfig, lattice: int, fluid: int, boundary: int) -> dict[str, float]:
    """The bytes of :func:`estimate_memory`: the Gaussian set and the per-Gaussian arrays held all run
    (``resident_bytes``), the solidification's peak (``solidify_bytes``), one probe's solver (``probe_bytes``) and
    its accumulator (``accumulator_bytes``), and ``bytes`` = resident + the larger of the two phases."""
    g = int(gaussians.num)
    tensors = (gaussians.means, gaussians.quats, gaussians.log_scales, gaussians.opacity_logits, gaussians.sh)
    resident = sum(t.numel() * t.element_size() for t in tensors) \
        + g * (BYTES_PER_GAUSSIAN_RUN + BYTES_PER_GAUSSIAN_PROBE * len(config.directions))
    solidify = estimate_solidify_bytes(g, lattice)
    probe = fluid * BYTES_PER_FLUID + boundary * BYTES_PER_BOUNDARY + lattice * BYTES_PER_LATTICE_POINT
    radii = gaussians.log_scales.detach().max(dim=1).values.double().exp().cpu().numpy()  # ratios: scale-free
    accumulator = GaussianAccumulator.estimate_bytes(g, fluid, config.track_distinct,
                                                     float_bytes=4 if config.precision == "f32" else 8,
                                                     num_levels=reach_classes(radii))
    return {"resident_bytes": float(resident), "solidify_bytes": float(solidify), "probe_bytes": float(probe),
            "accumulator_bytes": float(accumulator),
            "bytes": float(resident + max(solidify, probe + accumulator))}


def memory_limit_bytes(config: PhysicsConfig) -> float:
    """The memory a probe may use: ``config.max_memory_gb``, or the memory available now."""
    return config.max_memory_gb * 2**30 if config.max_memory_gb is not None else float(available_memory_bytes())


def check_memory(gaussians, config: PhysicsConfig, transform=None,
                 solid_points: np.ndarray | None = None) -> dict[str, float]:
    """Raise ValueError, with the estimate and the fix, when a probe would not fit in memory.

    See :func:`estimate_memory` for ``solid_points`` (the exact check once the solid is known)."""
    est = estimate_memory(gaussians, config, transform, solid_points)
    limit = memory_limit_bytes(config)
    if est["bytes"] > limit:
        available = "allowed (--max-memory-gb)" if config.max_memory_gb is not None else "available"
        gib = {k: est[k] / 2**30 for k in ("resident_bytes", "solidify_bytes", "probe_bytes", "accumulator_bytes")}
        raise ValueError(
            f"the probe would need about {est['bytes'] / 2**30:.4g} GiB ({est['fluid_particles']:,} fluid and "
            f"{est['boundary_particles']:,} boundary particles at r = {config.particle_radius} m, a solid lattice of "
            f"{est['lattice_points']:,} points, {gaussians.num:,} Gaussians: {gib['resident_bytes']:.3g} GiB for the "
            f"Gaussians, then {gib['solidify_bytes']:.3g} GiB to solidify, {gib['probe_bytes']:.3g} GiB per probe and "
            f"{gib['accumulator_bytes']:.3g} GiB for its per-Gaussian accumulator) but {limit / 2**30:.3g} GiB are "
            f"{available}{_memory_fix(gaussians, config, transform, est, limit)}")
    return est


def _memory_fix(gaussians, config: PhysicsConfig, transform, est: dict[str, float], limit: float) -> str:
    """The advice of :func:`check_memory`: the Gaussian that alone widens the lattice, if one does (a larger
    radius cannot help then), else the particle radius that would fit, if the object is still resolved."""
    transform = transform if transform is not None else scene_transform(gaussians, config)
    spacing = 2.0 * config.particle_radius
    scfg = SolidifyConfig(spacing=spacing, opacity_threshold=config.opacity_threshold, max_points=2**62)
    means, covs, opacities, _ = gaussian_arrays_in_sim(gaussians, transform)
    boxes = solid_boxes(means, covs, opacities, scfg)
    note = floaters.dominant_note(*boxes, spacing, means, covs, opacities, transform)
    if note:
        return f"{note.replace('widens it', 'widens the solid lattice')}; a larger particle radius cannot help"
    # the Gaussians' own bytes do not shrink with a larger radius
    fixed = est["resident_bytes"] + max(est["accumulator_bytes"], float(gaussians.num) * BYTES_PER_GAUSSIAN_SOLIDIFY)
    if fixed >= limit:
        return (f"; the {gaussians.num:,} Gaussians alone need about {fixed / 2**30:.3g} GiB (the set, the "
                "per-Gaussian accumulator or the solidification), so a larger particle radius cannot help: crop "
                "them to the object (--crop auto, or --crop xmin,ymin,zmin,xmax,ymax,zmax in scene units), prune "
                "them, or allow more memory (--max-memory-gb) on a larger machine")
    # the fluid and the lattice (the rest of the bytes) scale as 1 / r^3: the radius that would fit, if the object
    # stays resolved
    radius = config.particle_radius * ((est["bytes"] - fixed) / (limit - fixed)) ** (1.0 / 3.0)
    extent = float(np.max(np.subtract(*floaters.lattice_extent(*boxes)[::-1])))
    if 2.0 * radius <= extent / 4.0:
        return (f"; use a particle radius of about {radius:.3g} m or more (--particle-radius; --quick is "
                f"{QUICK['particle_radius']} m), a smaller scale (--scale), or crop the Gaussians (--crop)")
    return (f"; a particle radius that fits ({radius:.3g} m) would leave the {extent:.3g} m solid box fewer than 4 "
            "particles across: crop the Gaussians to the object (--crop auto, or --crop xmin,ymin,zmin,xmax,ymax,zmax "
            "in scene units) or use a smaller scale (--scale)")


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
        # fluid particles deep inside the (filled) solid lattice, counted at every step (nbv.leaks)
        self.leak_counter = None if solid is None else LeakCounter(solid.occupancy, solid.lattice_min, solid.spacing)
        # the fluid of the recorded probes every k steps (nbv.trajectory; None: nothing recorded)
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
        accumulator: a :class:`nbv.aggregate.GaussianAccumulator` of these Gaussians to reuse (the probe run's:
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
                       record=None) -> PhysicsResult:
    """Run the probes against the solid of ``gaussians`` and aggregate D_i onto every Gaussian (Eq. 2-3).

    Uses the Taichi runtime already initialised by the caller (never calls ``ti.init``).

    Args:
        gaussians: a ``recon.gaussians.GaussianSet`` in scene units.
        config: probe settings.
        progress: a tqdm bar per probe (steps, solver iterations, max speed).
        source: a label for the result (the .ply path).
        record: a :class:`nbv.trajectory.RecordConfig`: keep those probes' fluid every k steps in
            ``PhysicsResult.trajectories`` (None: nothing recorded).
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
                                      source, record)
        except ProbeDiverged as exc:
            exc.result = replace(expand_to_all(exc.result, gaussians, kept, config), gaussians_sha256=digest)
            raise
        return replace(expand_to_all(part, gaussians, kept, config), gaussians_sha256=digest)
    # The cheap bound (the Gaussians' box) decides first; when it does not fit but the lattice does, the
    # solid is computed and the probes are re-estimated around it, since scattered faint Gaussians widen
    # the box without making solid. Either way the check comes before any probe is allocated.
    cheap = estimate_memory(gaussians, config, transform)
    exact_check = cheap["bytes"] > memory_limit_bytes(config)
    if exact_check and (cheap["lattice_points"] > SolidifyConfig.max_points
                        or cheap["resident_bytes"] + cheap["solidify_bytes"] > memory_limit_bytes(config)):
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

    check_probe_time_steps(solid.points, config, scfg)
    if record is not None:
        check_record_size(probe_fluid_counts(solid.points, record.directions, config.probe_config(), scfg.spacing),
                          config.steps, record)
    recorder = _ProbeRecorder(means, reach, config, progress, solid=solid, record=record,
                              grid_bounds=probe_domains_union(solid.points, config, scfg.spacing))
    base = dict(solid=np.asarray(solid.points, np.float64), transform=transform, means=means, covariances=covs,
                reach=reach, config=config, source=source, gaussians_sha256=digest)

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


def _t(a: np.ndarray):
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
                                attributes: domain_min, domain_max (sim metres), warnings (JSON list of text)
        /probes/<dir>/leaked    (K,) int32 ids of the fluid particles inside the filled solid at the end (nbv.leaks:
                                the nearest lattice point and its 6 neighbours are solid; contact is not a leak)
                                attributes: final (K), max (the most inside after any step), max_step (0-based)
        /probes/<dir>/leaked_per_step  (S,) int32 particles inside after each step
        /probes/<dir>/x_final   (F, 3) float32 final fluid positions, sim metres, ordered by id (gzip)
        /probes/<dir>/ids_final (F,) int32 their ids (index in the probe's initial fluid set)
        /probes/<dir>/trajectory  only for the probes recorded (``record``): x (T, F, 3), D (T, F), speed (T, F),
                                steps (T,) every k steps (:mod:`nbv.trajectory`; NaN: retired)
        /solid/x                (M, 3) solid particles, sim metres
        attributes: config (PhysicsConfig JSON), directions, dbar, dbar_mean, dbar_empty, dbar_empty_mean
                    (m^4/s; NaN when not computed), up (the scene's up vector, 3 floats), up_label ("-y", ...),
                    scale (m per scene unit), scene_to_sim (4x4: x_sim = M [x_scene, 1]), source, timings (JSON)
        /gaussians/kept         (G,) bool, the Gaussians inside the crop (only with a crop)
        attributes too: gaussians_sha256 (:func:`gaussians_sha256`), status ("complete" or "diverged": then
                    /probes holds the probes completed before it, and diverged_probe, diverged_step,
                    diverged_reason say which probe diverged at which step and why)

    Returns:
        the path written.
    """
    p = Path(path)
    with atomic_h5(p) as f:
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
            pg.attrs["warnings"] = json.dumps(list(result.warnings.get(d, [])))
            if d in result.leaks:
                write_probe_leaks(pg, result.leaks[d])
            if d in result.trajectories:
                write_trajectory(pg, result.trajectories[d])
        f.create_dataset("solid/x", data=result.solid, compression="gzip", compression_opts=1)
        f.attrs["config"] = json.dumps(result.config.to_dict())
        f.attrs["directions"] = json.dumps(list(result.directions))
        for key in ("dbar", "dbar_mean", "dbar_empty", "dbar_empty_mean"):
            v = getattr(result, key)
            f.attrs[key] = float("nan") if v is None else float(v)
        f.attrs["up"], f.attrs["up_label"] = np.asarray(result.transform.up), result.transform.up_label
        f.attrs["scale"], f.attrs["scene_to_sim"] = float(result.transform.scale), result.transform.matrix
        if result.kept is not None:
            g["kept"] = np.asarray(result.kept, bool)
        f.attrs["source"] = str(result.source)
        f.attrs["timings"] = json.dumps(result.timings)
        f.attrs["gaussians_sha256"], f.attrs["status"] = result.gaussians_sha256, result.status
        if result.failure is not None:
            for key in ("probe", "step", "reason"):
                f.attrs[f"diverged_{key}"] = result.failure[key]
    return p


def load_result(path: str | Path, trajectories: bool = False) -> PhysicsResult:
    """Read a result written by :func:`save_result` (``trajectories``: also the recorded probe trajectories, which
    can be large; by default ``PhysicsResult.trajectories`` is left empty).

    Raises:
        ValueError: naming the file when it is not such a result.
    """
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"result file {p} does not exist; run `fluidgs simulate` to create it")
    try:
        with h5py.File(p, "r") as f:
            if "gaussians/D" not in f or "config" not in f.attrs:
                raise ValueError(f"{p} is not a `fluidgs simulate` result (no /gaussians/D); re-run `fluidgs simulate`")
            dirs = tuple(json.loads(f.attrs["directions"]))
            probes = [f[f"probes/{d}"] for d in dirs]
            g = f["gaussians/D"].shape[0]
            per_probe = np.stack([pg["D"][()] for pg in probes]) if probes else np.zeros((0, g))
            counts = np.stack([pg["counts"][()] for pg in probes]) if probes else np.zeros((0, g), np.int64)
            distinct = np.stack([pg["distinct"][()] for pg in probes]) \
                if probes and all("distinct" in pg for pg in probes) else None
            empty = np.stack([pg["D_empty"][()] for pg in probes]) \
                if probes and all("D_empty" in pg for pg in probes) else None
            domains = {d: (np.asarray(pg.attrs["domain_min"]), np.asarray(pg.attrs["domain_max"]))
                       for d, pg in zip(dirs, probes, strict=True) if "domain_min" in pg.attrs}
            warnings = {d: list(json.loads(pg.attrs["warnings"])) if "warnings" in pg.attrs else []
                        for d, pg in zip(dirs, probes, strict=True)}
            failure = {"probe": str(f.attrs["diverged_probe"]), "step": int(f.attrs["diverged_step"]),
                       "reason": str(f.attrs["diverged_reason"])} if "diverged_probe" in f.attrs else None

            def opt(key: str) -> float | None:
                v = float(f.attrs[key])
                return None if math.isnan(v) else v

            return PhysicsResult(
                directions=dirs, per_probe=per_probe, per_probe_counts=counts, per_probe_distinct=distinct,
                divergence=f["gaussians/D"][()], divergence_mean=f["gaussians/D_mean"][()],
                dbar=float(f.attrs["dbar"]), dbar_mean=float(f.attrs["dbar_mean"]), dbar_empty=opt("dbar_empty"),
                dbar_empty_mean=opt("dbar_empty_mean"), empty_per_probe=empty, solid=f["solid/x"][()],
                transform=SceneTransform(tuple(f.attrs["up"]) if "up" in f.attrs else str(f.attrs["up_axis"]),
                                         float(f.attrs["scale"])),
                kept=f["gaussians/kept"][()] if "gaussians/kept" in f else None,
                means=f["gaussians/means"][()], covariances=f["gaussians/covariances"][()],
                reach=f["gaussians/reach"][()], stats={d: pg["stats"][()] for d, pg in zip(dirs, probes, strict=True)},
                domains=domains, timings=json.loads(f.attrs["timings"]),
                config=PhysicsConfig.from_dict(json.loads(f.attrs["config"])), source=str(f.attrs["source"]),
                warnings=warnings, gaussians_sha256=str(f.attrs.get("gaussians_sha256", "")),
                status=str(f.attrs.get("status", "complete")), failure=failure,
                leaks={d: read_probe_leaks(pg) for d, pg in zip(dirs, probes, strict=True) if "leaked" in pg},
                trajectories={d: read_trajectory(pg) for d, pg in zip(dirs, probes, strict=True)
                              if trajectories and "trajectory" in pg})
    except (OSError, KeyError) as exc:
        raise ValueError(f"cannot read the result file {p}: {exc}; re-run `fluidgs simulate`") from exc


def check_result_matches(result: PhysicsResult, gaussians, path: str | Path) -> None:
    """Raise ValueError when a stored result was not computed, completely, for ``gaussians``.

    Args:
        result: a loaded result.
        gaussians: the ``GaussianSet`` the result is used with (an int: only the count is compared).
        path: the result file, for the message.

    The count must match and the run must be complete. Then :func:`gaussians_sha256` must match the stored
    digest; in files written before the digest, the Gaussians' centres mapped by the stored transform must
    match the stored centres (to 1e-5 of the object's size).
    """
    num = gaussians if isinstance(gaussians, int) else gaussians.num
    if result.num_gaussians != num:
        raise ValueError(f"{path} holds D_g for {result.num_gaussians} Gaussians but the .ply has {num}; "
                         "pass the result of this .ply or drop --result to simulate again")
    if result.status != "complete":
        f = result.failure or {}
        raise ValueError(f"{path} is the result of a run that diverged (probe {f.get('probe')} at step "
                         f"{f.get('step')}: {f.get('reason')}); it has only the probes "
                         f"{', '.join(result.directions) or 'none'}; re-run `fluidgs simulate` with a smaller --dt")
    if isinstance(gaussians, int):
        return
    if result.gaussians_sha256:
        digest = gaussians_sha256(gaussians)
        if digest != result.gaussians_sha256:
            raise ValueError(f"{path} was computed for other Gaussians (same count, {num}, but different positions, "
                             f"shapes or opacities: content hash {result.gaussians_sha256[:12]}... vs "
                             f"{digest[:12]}... of this file); pass the result of these Gaussians or drop --result "
                             "to simulate again")
        return

    means = np.asarray(gaussian_arrays_in_sim(gaussians, result.transform)[0], np.float64)
    stored = np.asarray(result.means, np.float64)
    size = float(np.ptp(stored, axis=0).max()) if len(stored) else 0.0
    gap = float(np.abs(means - stored).max()) if len(stored) else 0.0
    if not gap <= 1e-5 * max(size, 1e-12):
        raise ValueError(f"{path} was computed for other Gaussians (same count, {num}, but centres up to {gap:.3g} m "
                         "away from the stored ones); pass the result of these Gaussians or drop --result to "
                         "simulate again")


def parse_directions(text: str | Sequence[str]) -> tuple[str, ...]:
    """'-x,+x' or a list -> a tuple of probe names (validated)."""
    return parse_list(text, str, "--directions", allowed=DIRECTIONS, unique=True, what="probe")
