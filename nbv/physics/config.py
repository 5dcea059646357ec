"""The probe-run configuration (:class:`PhysicsConfig`), its quick preset, and the scene -> simulation
transform and kept Gaussians it implies."""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, fields
from typing import TYPE_CHECKING, Any

import numpy as np

from fluidsim.config import MAX_STEPS, SolverConfig
from fluidsim.directions import DIRECTIONS
from nbv.lists import parse_list
from nbv.physics.early_stop import StopRule
from nbv.physics.scene_frame import SceneTransform, crop_box, inside_box, parse_crop, parse_up, robust_box, up_label

if TYPE_CHECKING:
    from fluidsim.probes import ProbeConfig
    from nbv.physics.solidify import SolidifyConfig

log = logging.getLogger(__name__)

QUICK = {"particle_radius": 0.035, "steps": 750, "stop_tolerance": 0.01}

# Estimator radii h_r and h_k of paper Eq. 1 in particle radii: 4 r = 0.1 m at the paper's r = 0.025 m. A fixed
# 0.1 m would leave no neighbour inside h_r at r >= 0.05 m (spacing >= h_r), so D_i would read 0.
ESTIMATOR_RADII = 4.0


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
        reach_floor: the smallest reach, in SPH support radii h = 4 r: a Gaussian's reach is max(n r_g,
            reach_floor h) (:meth:`reach`). 0 (default): the paper's n r_g. 1 gives thin surface Gaussians, whose
            n r_g is smaller than the gap the fluid keeps from the solid, a value; a study variant (docs/results.md).
        opacity_threshold: tau: combined opacity at or above which a lattice point is solid (unitless, 0..1).
        up: the scene's up direction, which becomes simulation +y: an axis ("+y", "-y", "+z", ...) or a 3-tuple
            (:func:`nbv.physics.scene_frame.parse_up`). COLMAP captures are often y-down: up "-y".
        scale: metres per scene unit, or "auto" (largest extent of the robust object box -> ``target_extent``).
        crop: None (every Gaussian), "auto" (the robust object box grown by 10 % per side) or (xmin, ymin, zmin,
            xmax, ymax, zmax) in scene units: only the Gaussians whose centres lie inside make solid, are scored
            and size the domain; the others get D_g = 0 and are marked in ``PhysicsResult.kept``.
        target_extent: m, the object's largest extent when ``scale`` is "auto".
        fill_cavities: fill what the Gaussians enclose (default: a closed shell of thin surface Gaussians becomes a
            filled body; :mod:`nbv.physics.solidify`). False keeps the one-point-thick shell.
        track_distinct: count distinct fluid particles per Gaussian (|P_g|, for critical regions).
        empty_reference: also run the probes without the solid for the empty-scene D-bar.
        empty_cache: reuse the empty scene's fluid from the user cache folder, and store it there
            (:mod:`nbv.physics.empty_cache`; False: simulate it afresh and store nothing).
        precision: "f32" or "f64"; must match the Taichi runtime's default float.
        max_memory_gb: refuse to start above this estimated memory, GiB (None: the available memory).
        probe_snap: snap the solid's bounding box outward to a grid of this many particle spacings before the
            probes' slabs and domains are laid out around it (``fluidsim.ProbeConfig.snap``), so that solids whose
            boxes' sides lie in the same grid cells share their probes and so the empty scene's cached fluid.
            0 (default): the box as it is; docs/performance.md measures what it costs and gains.
        replicas: run the probes this many times, the solid lattice and the fluid slab shifted by a fraction of a
            spacing each time, and average D_g over the runs (1: one run; :mod:`nbv.physics.replicas`).
        stop_tolerance: stop a probe once a window of 50 steps moved its running D_g^(IC) by at most this fraction
            (relative L1 change, checked from step 150; :mod:`nbv.physics.early_stop`); its empty-scene probe stops at
            the same step. 0, the paper's setting: every probe runs ``steps``.
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
    reach_floor: float = 0.0
    opacity_threshold: float = 0.3
    up: str | tuple[float, float, float] = "+y"
    scale: float | str = "auto"
    crop: str | tuple[float, ...] | None = None
    target_extent: float = 2.0
    fill_cavities: bool = True
    track_distinct: bool = False
    empty_reference: bool = True
    empty_cache: bool = True
    precision: str = "f32"
    max_memory_gb: float | None = None
    probe_snap: int = 0
    replicas: int = 1
    stop_tolerance: float = 0.0
    solver: tuple[tuple[str, Any], ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        for name in ("particle_radius", "dt", "rest_density", "n_radius", "target_extent"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ValueError(f"PhysicsConfig.{name} must be a finite number > 0, got {v!r}")
        for name in ("speed", "viscosity", "reach_floor", "stop_tolerance"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ValueError(f"PhysicsConfig.{name} must be a finite number >= 0, got {v!r}")
        for name in ("steps", "accumulate_every", "replicas"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"PhysicsConfig.{name} must be an integer >= 1, got {v!r}")
        if self.steps > MAX_STEPS:
            raise ValueError(
                f"PhysicsConfig.steps must be at most {MAX_STEPS:,} time steps per probe (the paper's run 750), "
                f"got {self.steps}"
            )
        if self.accumulate_every > self.steps:  # steps k, 2k, ... are accumulated: none of 1..steps
            raise ValueError(
                f"PhysicsConfig.accumulate_every must be at most the {self.steps} steps per probe, got "
                f"{self.accumulate_every}: no step would be accumulated and D_g would be 0 everywhere"
            )
        if isinstance(self.probe_snap, bool) or not isinstance(self.probe_snap, int) or self.probe_snap < 0:
            raise ValueError(
                f"PhysicsConfig.probe_snap must be an integer >= 0 (particle spacings), got {self.probe_snap!r}"
            )
        if not 0.0 < self.opacity_threshold < 1.0:
            raise ValueError(f"PhysicsConfig.opacity_threshold must be in (0, 1), got {self.opacity_threshold}")
        dirs = tuple(self.directions)
        if not dirs or any(d not in DIRECTIONS for d in dirs) or len(set(dirs)) != len(dirs):
            raise ValueError(f"PhysicsConfig.directions must be distinct probes from {DIRECTIONS}, got {dirs}")
        object.__setattr__(self, "directions", dirs)
        up = parse_up(self.up, "PhysicsConfig.up")
        object.__setattr__(self, "up", up_label(up) if isinstance(self.up, str) else tuple(float(c) for c in up))
        object.__setattr__(self, "crop", parse_crop(self.crop))
        if self.scale != "auto" and (
            isinstance(self.scale, bool)
            or not isinstance(self.scale, (int, float))
            or not math.isfinite(self.scale)
            or self.scale <= 0
        ):
            raise ValueError(
                f"PhysicsConfig.scale must be 'auto' or a number > 0 (m per scene unit), got {self.scale!r}"
            )
        if self.precision not in ("f32", "f64"):
            raise ValueError(f"PhysicsConfig.precision must be 'f32' or 'f64', got {self.precision!r}")
        if self.max_memory_gb is not None and not self.max_memory_gb > 0:
            raise ValueError(f"PhysicsConfig.max_memory_gb must be > 0 or None, got {self.max_memory_gb}")
        solver = tuple((str(k), v) for k, v in (self.solver.items() if isinstance(self.solver, dict) else self.solver))
        object.__setattr__(self, "solver", solver)
        try:
            self.solver_config()  # validates the pass-through keys now
        except ValueError as exc:
            name = str(exc).split(" ", 1)[0]
            if name in ("particle_radius", "dt", "viscosity", "rest_density", "precision"):
                raise ValueError(f"PhysicsConfig.{exc}") from None  # a field of this config: named as one
            if name.startswith("estimator_") and name not in dict(solver):  # derived from r: r is what is wrong
                raise ValueError(
                    f"PhysicsConfig.particle_radius must be a finite number > 0 whose {ESTIMATOR_RADII:g} r (the "
                    f"estimator radius) is finite, got {self.particle_radius!r}"
                ) from None
            raise

    def check_inflow(self) -> None:
        """Refuse a speed of 0 with horizontal probes: they would have no inflow and measure nothing (D_g = 0
        everywhere, and no warning). Results of such runs still load; commands call this before a new run.

        Raises:
            ValueError: naming ``PhysicsConfig.speed`` (the commands name their option or key).
        """
        horizontal = [d for d in self.directions if d != "-y"]
        if self.speed == 0 and horizontal:
            raise ValueError(
                f"PhysicsConfig.speed is 0 m/s: the probes {', '.join(horizontal)} would have no inflow and measure "
                "nothing (D_g = 0 everywhere); use a speed > 0 m/s (default 3), or only the -y probe"
            )

    @classmethod
    def quick(cls, **overrides: Any) -> PhysicsConfig:
        """The quick preset (:data:`QUICK`: r = 0.035 m, at most 750 steps per probe, stopped once D_g^(IC) moves
        by at most 1 % in 50 steps) with optional overrides."""
        return cls(**{**QUICK, **overrides})

    def reach(self, radii: np.ndarray) -> np.ndarray:
        """[K] float64 reach of Gaussians of largest standard deviation ``radii`` (m): n r_g (Eq. 2), at least
        ``reach_floor`` SPH support radii."""
        reach = self.n_radius * np.asarray(radii, np.float64)
        if self.reach_floor > 0:
            reach = np.maximum(reach, self.reach_floor * self.solver_config().support_radius)
        return np.ascontiguousarray(reach)

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
        return SolverConfig(
            **{
                **extra,
                "particle_radius": self.particle_radius,
                "dt": self.dt if dt is None else dt,
                "viscosity": self.viscosity,
                "rest_density": self.rest_density,
                "precision": self.precision,
            }
        )

    def stop_rule(self) -> StopRule:
        """The early stop of the probes (:class:`nbv.physics.early_stop.StopRule`; off at ``stop_tolerance`` 0)."""
        return StopRule(self.stop_tolerance)

    def probe_config(self) -> ProbeConfig:
        """The fluidsim probe parameters (slab, walls, directions)."""
        from fluidsim.probes import ProbeConfig  # noqa: PLC0415 - loads Taichi; `fluidgs CMD --help` needs only the config

        return ProbeConfig(speed=self.speed, directions=self.directions, snap=self.probe_snap)

    def solidify_config(self, **overrides: Any) -> SolidifyConfig:
        """How these Gaussians become solid (:class:`nbv.physics.solidify.SolidifyConfig`): the lattice at the fluid
        spacing 2 r, tau and the filling of these probes; ``overrides`` (e.g. ``max_points`` for an estimate) replace
        fields."""
        from nbv.physics.solidify import SolidifyConfig  # noqa: PLC0415 - loads Taichi; --help needs only the config

        return SolidifyConfig(
            **{
                "spacing": 2.0 * self.particle_radius,
                "opacity_threshold": self.opacity_threshold,
                "fill_cavities": self.fill_cavities,
                **overrides,
            }
        )

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able dict (``from_dict`` reads it back). ``replicas`` is left out at its default, 1, so that the
        record of one run (RESULT.h5, scores.json, an active run's config.json) is the one written before replicas
        existed, and such a run resumes."""
        d = asdict(self)
        # records before these existed
        for name, default in (("replicas", 1), ("reach_floor", 0.0), ("probe_snap", 0), ("stop_tolerance", 0.0)):
            if d[name] == default:
                del d[name]
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
        raise ValueError(
            f"--crop {config.crop}: the box [{', '.join(f'{v:.4g}' for v in lo)}] - "
            f"[{', '.join(f'{v:.4g}' for v in hi)}] (scene units) keeps none of the {len(means):,} "
            f"Gaussians, whose centres span [{', '.join(f'{v:.4g}' for v in means.min(0))}] - "
            f"[{', '.join(f'{v:.4g}' for v in means.max(0))}]; widen the box or use --crop auto"
        )
    if report:
        log.info(
            "crop %s: kept %d of %d Gaussians (%d dropped)", config.crop, int(kept.sum()), len(kept), int((~kept).sum())
        )
    return kept


_CROP_NOT_GIVEN = object()


# The smallest object box, in scene units, that scale "auto" blows up to ``target_extent``: below it the scale passes
# 1e12 m per unit and the Gaussians' covariances (scale^2 sigma^2) leave float32's range.
MIN_AUTO_EXTENT = 1.0e-12


def scene_transform(gaussians, config: PhysicsConfig, *, kept=_CROP_NOT_GIVEN):
    """The :class:`nbv.physics.scene_frame.SceneTransform` for ``config.up`` and ``config.scale`` ("auto" resolved).

    "auto": metres per scene unit such that the largest extent of the robust object box
    (:func:`nbv.physics.scene_frame.robust_box`, in simulation axes; only the Gaussians that ``config.crop`` keeps)
    is ``target_extent`` m. ``kept``: :func:`kept_gaussians` already computed (None: no crop); default computed here.
    """
    if config.scale != "auto":
        return SceneTransform(config.up, float(config.scale))
    box = object_box(gaussians, config, kept=kept)
    extent = 0.0 if box is None else float((box[1] - box[0]).max())
    if not extent >= MIN_AUTO_EXTENT:
        raise ValueError(
            f"cannot pick scale='auto': the Gaussians' object box is {extent:.3g} scene units across (their centres "
            f"coincide or nearly: one point, or subnormal coordinates), less than the {MIN_AUTO_EXTENT:g} units the "
            "scale can blow up to the object's size; check the file's coordinates, or pass --scale (metres per "
            "scene unit)"
        )
    return SceneTransform(config.up, config.target_extent / extent)


def object_box(gaussians, config: PhysicsConfig, *, kept=_CROP_NOT_GIVEN) -> tuple[np.ndarray, np.ndarray] | None:
    """The robust object box (:func:`nbv.physics.scene_frame.robust_box`) of the Gaussians that ``config.crop``
    keeps, in the simulation axes at scene units (``SceneTransform(config.up, 1)``): (lo [3], hi [3]), or None when
    fewer than two Gaussians are kept. The auto scale and the orbit cameras both frame this box. ``kept``: as
    :func:`scene_transform`.

    Raises:
        ValueError: the crop keeps no Gaussian (:func:`kept_gaussians`).
    """
    means = gaussians.means.detach().cpu().double().numpy()
    opacities = gaussians.opacities.detach().cpu().double().numpy()
    if kept is _CROP_NOT_GIVEN:
        kept = kept_gaussians(gaussians, config, report=False)
    if kept is not None:
        means, opacities = means[kept], opacities[kept]
    if len(means) < 2:
        return None
    return robust_box(SceneTransform(config.up, 1.0).to_sim(means), opacities, config.opacity_threshold)


def parse_directions(text: str | Sequence[str]) -> tuple[str, ...]:
    """'-x,+x' or a list -> a tuple of probe names (validated)."""
    return parse_list(text, str, "--directions", allowed=DIRECTIONS, unique=True, what="probe")
