"""Velocity / Reynolds-number sweep of the geometry divergence D-bar (paper Sec. 4, "flow speed" study).

For each inflow speed U the probes run with a CFL-constant time step over the same physical duration:

- Delta t(U) = Delta t_base * U_base / U (U_base = the config's speed, by default the paper's lambda = 3 m/s;
  Delta t_base = the config's dt),
  so U Delta t / (2 r), the Courant number, stays that of the base setting;
- steps(U) = round(T / Delta t(U)) with T = steps_base * Delta t_base;
- Re = rho U L / mu with rho the rest density (kg/m^3), mu the dynamic viscosity (Pa s) and L a length (m):
  by default the object's extent along the flow (``re_length="object"``: the solid's extent along the axis of
  the -x probe, or of the first probe, plus one lattice spacing, since each solid point stands for a cell), or
  the largest extent of that probe's domain (``"domain"``, what the paper's L = "the domain size" reads as), or a
  given length in metres.
- C_d = 2 F_drag / (rho U^2 A) of that same probe (:func:`probe_drag`): its time-mean drag force on the solid over
  the second half of the run (:mod:`nbv.physics.forces`; a single step's force is noise) and A the solid's area
  projected along its flow, so C_d and Re belong to one probe.

With a second Gaussian set ("OTHER") the gap Delta = D-bar(OTHER) - D-bar is reported per U. Both sets use
the same scene -> metre scale (with ``scale="auto"`` it is resolved on the first set), because D-bar grows
with the fourth power of the scale and a set with a missing part would otherwise be scaled differently. With the
config's empty-scene reference on, each speed also gives D-bar of the empty scene (the paper's reference point).

Cost. The steps per probe grow with U (12,500 at 50 m/s against 750 at 3 m/s), so the sweep's work is counted in
probe-steps: steps(U) x probes x (2 with the empty scene) (+ steps(U) x probes for OTHER). :func:`calibrate` times
one probe's whole base run on this machine, and its empty scene (at most ``CALIBRATION_MAX_STEPS`` steps, the
solid built as the sweep builds it), so that the costlier steps after the fluid meets the object are in the
average, and :func:`estimate` turns the probe-steps into minutes, each probe weighted by its fluid particles,
before the first speed runs. Measured on the 2-core VM with the quick Ahmed asset, five probes at 3 and 6 m/s
and the empty scene: 69 s estimated, 83 s taken.
"""

from __future__ import annotations

import csv
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from fluidsim.config import MAX_STEPS
from nbv.io import atomic_output
from nbv.lists import parse_list
from nbv.physics import PhysicsConfig, PhysicsResult, scene_transform, simulate_gaussians
from nbv.physics.plan import ProbePlan

log = logging.getLogger(__name__)

U_BASE = 3.0  # m/s, the paper's inflow speed lambda
RE_LENGTHS = ("object", "domain")
CALIBRATION_MAX_STEPS = 750
_AXES = {"x": 0, "y": 1, "z": 2}
PAPER_VELOCITIES = (3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 20.0, 50.0)  # m/s, the speeds of the paper's sweep


@dataclass(frozen=True)
class SweepStep:
    """One speed of the sweep: U (m/s), Delta t (s), steps, and the physical duration steps * Delta t (s)."""

    speed: float
    dt: float
    steps: int

    @property
    def duration(self) -> float:
        return self.steps * self.dt


@dataclass(frozen=True)
class SweepPoint:
    """A sweep result row: U m/s, Re, Delta t s, steps, D-bar m^4/s, D-bar of OTHER and the gap (or None), the
    length L of Re (m) and where it came from ("object", "domain", "given"), D-bar of the empty scene (or None), and
    the drag of the probe ``drag_probe`` (the -x probe, else the first probe run: the one L is measured along): the
    time-mean drag force ``drag`` N, its coefficient ``drag_coefficient`` C_d = 2 F / (rho U^2 A) and the projected
    area ``area`` A m^2 (None where the probe reported no force, or has no inflow speed: the -y probe)."""

    speed: float
    reynolds: float
    dt: float
    steps: int
    dbar: float
    dbar_other: float | None = None
    re_length: float = float("nan")
    re_length_from: str = ""
    dbar_empty: float | None = None
    drag_coefficient: float | None = None
    drag: float | None = None
    drag_probe: str = ""
    area: float | None = None

    @property
    def gap(self) -> float | None:
        return None if self.dbar_other is None else self.dbar_other - self.dbar


def parse_velocities(text: str | Sequence[float]) -> tuple[float, ...]:
    """'3,4,5' or a list -> positive speeds in m/s (ValueError naming --velocities otherwise)."""
    return parse_list(text, float, "--velocities", positive=True, unique=True, what="speed")


def schedule(velocities: Sequence[float], dt_base: float, steps_base: int, u_base: float = U_BASE) -> list[SweepStep]:
    """CFL-constant time steps over the base duration T = steps_base * dt_base.

    Args:
        velocities: speeds U, m/s (> 0).
        dt_base: Delta t at ``u_base``, s.
        steps_base: steps at ``u_base``.
        u_base: the reference speed, m/s.
    Returns:
        one SweepStep per speed, in the given order.
    """
    if dt_base <= 0 or steps_base < 1 or u_base <= 0:
        raise ValueError(f"sweep base must have dt > 0, steps >= 1, U > 0; got {dt_base}, {steps_base}, {u_base}")
    total = steps_base * dt_base
    if not math.isfinite(total):
        raise ValueError(f"--dt {dt_base:g} s x {steps_base} steps is not a finite duration; use a dt of milliseconds")
    out = []
    for u in velocities:
        if not u > 0:
            raise ValueError(f"sweep speeds must be > 0 m/s, got {u}")
        # the steps grow with U (CFL-constant dt over the same duration): bounded before any probe runs
        if steps_base * (u / u_base) > MAX_STEPS:
            raise ValueError(
                f"--velocities: U = {u:g} m/s would take {steps_base * (u / u_base):,.0f} steps (the {steps_base} "
                f"steps of {u_base:g} m/s, CFL-constant dt), more than the {MAX_STEPS:,} a probe may run; use speeds "
                f"up to {MAX_STEPS * u_base / steps_base:,.0f} m/s"
            )
        dt = dt_base * u_base / u
        if not math.isfinite(dt):
            raise ValueError(f"--velocities: U = {u:g} m/s makes the time step {dt} s (from --dt {dt_base:g} s)")
        out.append(SweepStep(float(u), dt, max(1, round(total / dt))))
    return out


def reynolds(speed: float, length: float, density: float, viscosity: float) -> float:
    """Re = rho U L / mu (density kg/m^3, speed m/s, length m, dynamic viscosity Pa s); inf for mu = 0."""
    return float("inf") if viscosity == 0 else density * speed * length / viscosity


def parse_re_length(text: str | float) -> str | float:
    """``--re-length``: "object", "domain" or a length in metres (> 0); ValueError naming the option otherwise."""
    if isinstance(text, str) and text.strip().lower() in RE_LENGTHS:
        return text.strip().lower()
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise ValueError(f"--re-length {text!r}: use object, domain or a length in metres > 0") from None
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"--re-length {text!r}: a length must be finite and > 0 m; or use object or domain")
    return value


def _flow_probe(result: PhysicsResult) -> str:
    return "-x" if "-x" in result.domains else result.directions[0]


def domain_length(result: PhysicsResult) -> float:
    """L: the largest extent of the -x probe's domain (else the first probe's), m."""
    lo, hi = result.domains[_flow_probe(result)]
    return float(np.max(np.asarray(hi) - np.asarray(lo)))


def object_length(result: PhysicsResult) -> float:
    """L: the solid's extent along the flow of the -x probe (else the first probe), plus one lattice spacing
    (each solid point stands for a cell of that side), m."""
    axis = _AXES[_flow_probe(result)[1]]
    x = np.asarray(result.solid, np.float64)[:, axis]
    return float(x.max() - x.min() + 2.0 * result.config.particle_radius)


def reynolds_length(result: PhysicsResult, spec: str | float) -> tuple[float, str]:
    """(L in m, "object" | "domain" | "given") for ``spec`` (:func:`parse_re_length`)."""
    if spec == "object":
        return object_length(result), "object"
    if spec == "domain":
        return domain_length(result), "domain"
    return float(spec), "given"


def probe_drag(result: PhysicsResult) -> tuple[str, float | None, float | None, float | None]:
    """(probe, C_d, drag N, A m^2) of the flow probe (the -x probe, else the first; the one L of Re is measured
    along): its time-mean drag over the second half of the run (:class:`nbv.physics.forces.ProbeForces`) and
    C_d = 2 F / (rho_0 U^2 A). C_d is None for the -y probe (no inflow speed); all three None when the probe's
    statistics hold no forces."""
    probe = _flow_probe(result)
    pf = result.forces.get(probe)
    if pf is None:
        return probe, None, None, None
    if not pf.reached:
        log.warning("probe %s: the fluid never reached the solid, so its drag and C_d are 0", probe)
    c = pf.coefficients()
    return probe, None if c is None else c["drag"], pf.parts()["drag"], pf.area


@dataclass(frozen=True)
class Calibration:
    """What one probe-step costs on this machine: ``step_s`` s per probe-step against the solid (steps and
    aggregation), ``empty_step_s`` s per probe-step of the empty scene (None when it was not run: then as
    ``step_s``), and ``run_s`` s per simulation besides its steps (the solid, the accumulator, the setup), all
    of the probe timed; ``weights``: per probe, its fluid particles over the timed probe's (a step costs about in
    proportion to them; empty: every probe costs as the timed one)."""

    step_s: float
    run_s: float
    steps: int
    empty_step_s: float | None = None
    weights: dict[str, float] = field(default_factory=dict)

    def probes_weight(self, directions: Sequence[str]) -> float:
        """Sum over ``directions`` of their weights: the probes of one speed, in units of the timed probe."""
        return float(sum(self.weights.get(d, 1.0) for d in directions))


def probe_steps(plan: Sequence[SweepStep], config: PhysicsConfig, other: bool = False) -> list[int]:
    """Probe-steps per speed: steps x probes x (2 with the empty scene) (+ steps x probes for OTHER)."""
    per_step = len(config.directions) * ((2 if config.empty_reference else 1) + (1 if other else 0))
    return [st.steps * per_step for st in plan]


def calibrate(gaussians, config: PhysicsConfig, steps: int = CALIBRATION_MAX_STEPS) -> Calibration:
    """Time the first probe at the base setting over its base run, at most ``steps`` steps (the solid built as the
    sweep builds it), after a 2-step run that compiles the kernels (compiling is paid once per sweep, not per
    speed)."""
    first = "-x" if "-x" in config.directions else config.directions[0]
    n = max(1, min(int(steps), config.steps))
    cfg = replace(config, directions=(first,), steps=n, empty_cache=False)  # timed as simulated, nothing stored
    simulate_gaussians(gaussians, replace(cfg, steps=min(2, n)), progress=False)
    res = simulate_gaussians(gaussians, cfg, progress=False)
    t = res.timings
    stepping = t["simulation"] + t["aggregation"]
    empty = t.get("empty_reference", 0.0) if config.empty_reference else 0.0
    counts = ProbePlan.of(res.solid, config).fluid_counts(config.directions)
    weights = {d: counts[d] / max(counts[first], 1) for d in config.directions}
    return Calibration(
        step_s=stepping / n,
        run_s=max(t["total"] - stepping - empty, 0.0),
        steps=n,
        empty_step_s=empty / n if config.empty_reference else None,
        weights=weights,
    )


def estimate(
    plan: Sequence[SweepStep], config: PhysicsConfig, calibration: Calibration, other: bool = False
) -> list[float]:
    """Seconds per speed: its probe-steps against a solid x ``calibration.step_s``, those of the empty scene x
    ``empty_step_s``, each probe weighted by its fluid particles (``calibration.weights``), plus ``run_s`` per
    simulation it runs."""
    runs = 1 + (1 if other else 0)
    probes = calibration.probes_weight(config.directions)
    empty_s = calibration.step_s if calibration.empty_step_s is None else calibration.empty_step_s
    out = []
    for st in plan:
        solid_steps = st.steps * probes * runs
        empty_steps = st.steps * probes if config.empty_reference else 0
        out.append(solid_steps * calibration.step_s + empty_steps * empty_s + runs * calibration.run_s)
    return out


def pinned(gaussians, config: PhysicsConfig) -> PhysicsConfig:
    """``config`` with an "auto" scale resolved on ``gaussians`` (so OTHER and every speed share it)."""
    if config.scale == "auto":
        return replace(config, scale=scene_transform(gaussians, config).scale)
    return config


def run_sweep(
    gaussians,
    config: PhysicsConfig,
    velocities: Sequence[float],
    other=None,
    progress: bool = True,
    re_length: str | float = "object",
) -> list[SweepPoint]:
    """D-bar (and D-bar of the empty scene, of ``other`` and the gap) at each speed, CFL-constant Delta t, same
    duration.

    Args:
        gaussians: GaussianSet (scene units). other: an optional second GaussianSet, simulated at the
            scale resolved on ``gaussians`` (without the empty scene, which is the same for both).
        config: the base settings (its dt and steps are the base at U_base = ``config.speed``); with
            ``config.empty_reference`` each speed also runs the empty scene.
        velocities: speeds, m/s.
        progress: a bar over the probe-steps (:func:`probe_steps`; updated as each speed ends) and the
            per-probe bars.
        re_length: L of Re (:func:`parse_re_length`).
    Returns:
        one SweepPoint per speed.
    """
    plan = schedule(velocities, config.dt, config.steps, u_base=config.speed)
    config = pinned(gaussians, config)
    work = probe_steps(plan, config, other is not None)
    points = []
    with tqdm(total=sum(work), desc="sweep", unit="probe-step", unit_scale=True, disable=not progress) as bar:
        for st, n in zip(plan, work, strict=True):
            cfg = replace(config, speed=st.speed, dt=st.dt, steps=st.steps)
            res = simulate_gaussians(gaussians, cfg, progress=progress)
            other_dbar = (
                simulate_gaussians(other, replace(cfg, empty_reference=False), progress=progress).dbar
                if other is not None
                else None
            )
            length, source = reynolds_length(res, re_length)
            re = reynolds(st.speed, length, config.rest_density, config.viscosity)
            probe, cd, drag, area = probe_drag(res)
            points.append(
                SweepPoint(
                    st.speed,
                    re,
                    st.dt,
                    st.steps,
                    res.dbar,
                    other_dbar,
                    length,
                    source,
                    res.dbar_empty,
                    drag_coefficient=cd,
                    drag=drag,
                    drag_probe=probe,
                    area=area,
                )
            )
            bar.update(n)
            log.info(
                "U = %g m/s: Re = %.4g (L = %.4g m, %s), dt = %.3g s, %d steps, D-bar = %.4g, C_d (%s) = %s",
                st.speed,
                re,
                length,
                source,
                st.dt,
                st.steps,
                res.dbar,
                probe,
                "n/a" if cd is None else f"{cd:.3g}",
            )
    return points


CSV_FIELDS = (
    "speed_m_s",
    "reynolds",
    "re_length_m",
    "re_length_from",
    "dt_s",
    "steps",
    "dbar_m4_s",
    "dbar_empty_m4_s",
    "dbar_other_m4_s",
    "gap_m4_s",
    "C_d",
    "drag_N",
    "drag_probe",
)


def write_csv(path: str | Path, points: Sequence[SweepPoint]) -> Path:
    """Write the sweep as CSV atomically (columns: :data:`CSV_FIELDS`, the drag's last so that readers of the older
    columns keep working; empty cells where no OTHER, no empty scene or no drag coefficient)."""
    p = Path(path)
    with atomic_output(p) as tmp, open(tmp, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(CSV_FIELDS)
        for pt in points:
            w.writerow(
                [
                    f"{pt.speed:g}",
                    f"{pt.reynolds:.6g}",
                    f"{pt.re_length:.6g}",
                    pt.re_length_from,
                    f"{pt.dt:.6g}",
                    pt.steps,
                    f"{pt.dbar:.6g}",
                    "" if pt.dbar_empty is None else f"{pt.dbar_empty:.6g}",
                    "" if pt.dbar_other is None else f"{pt.dbar_other:.6g}",
                    "" if pt.gap is None else f"{pt.gap:.6g}",
                    "" if pt.drag_coefficient is None else f"{pt.drag_coefficient:.3g}",
                    "" if pt.drag is None else f"{pt.drag:.3g}",
                    pt.drag_probe,
                ]
            )
    return p
