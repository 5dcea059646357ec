"""Running a simulation: building the solver from a scene, stepping it, and stopping on faults.

A run whose time step is too large for the particle spacing (CFL number above ``config.max_cfl``, from the
inflow speed and free fall: :func:`check_time_step`) is refused before its first step. A run stops with
:class:`SimulationDiverged`, naming the step, when a velocity becomes NaN or Inf,
when a fluid speed exceeds ``config.max_speed``, or when a solver hits ``max_iterations`` for
``config.max_capped_steps`` steps in a row. Whatever the caller saved before that stays saved.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from . import sources
from .config import SolverConfig
from .faults import SimulationDiverged
from .scene import Scene, lattice_in_box
from .solver import DFSPHSolver, StepStats

log = logging.getLogger(__name__)


def boundary_points_for_scene(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """All static boundary particles of a scene: domain walls and every solid.

    Returns:
        (points (M, 3) m, solid (M,) bool: the points of the solids, whose summed force the steps report).
    """
    spacing = scene.config.spacing
    parts = []
    if scene.domain.walls:
        parts.append(sources.wall_particles(scene.domain.min, scene.domain.max, spacing, scene.domain.wall_layers))
    walls = sum(len(p) for p in parts)
    for solid in scene.solids:
        parts.append(solid_points(solid, scene.base_dir, spacing))
    points = np.concatenate(parts) if parts else np.zeros((0, 3))
    return points, np.arange(len(points)) >= walls


def solid_points(solid, base_dir: str, spacing: float) -> np.ndarray:
    """Particles of one solid of a scene, (M, 3) m."""
    if solid.points is not None:
        return sources.load_points(Path(base_dir) / solid.points)
    return sources.mesh_particles(Path(base_dir) / solid.mesh, spacing, solid.fill)


def fluid_for_scene(scene: Scene) -> tuple[np.ndarray, np.ndarray, int]:
    """Fluid lattice of all blocks, minus points inside mesh solids.

    Returns:
        positions (N, 3) m, velocities (N, 3) m/s, number removed for lying inside a mesh solid.
    """
    xs, vs = [], []
    for block in scene.fluid_blocks:
        pts = lattice_in_box(block.min, block.max, scene.config.spacing)
        xs.append(pts)
        vs.append(np.broadcast_to(np.asarray(block.velocity, np.float64), pts.shape))
    x = np.concatenate(xs)
    v = np.concatenate(vs)
    removed = 0
    for solid in scene.solids:
        if solid.mesh is not None and len(x):
            inside = sources.points_inside_mesh(Path(scene.base_dir) / solid.mesh, x)
            removed += int(inside.sum())
            x, v = x[~inside], v[~inside]
    return x, np.ascontiguousarray(v), removed


def build_solver(scene: Scene) -> DFSPHSolver:
    """A ready solver for a validated scene (boundary sampled, fluid placed, overlaps removed).

    Raises:
        ValueError: when no fluid particle is left.
    """
    boundary, solid = boundary_points_for_scene(scene)
    x, v, removed = fluid_for_scene(scene)
    solver = DFSPHSolver(scene.config, scene.domain.min, scene.domain.max, x, v, boundary, solid)
    removed += solver.removed_inside_solid
    solver.removed_inside_solid = removed
    if removed:
        log.warning("removed %d fluid particles that started inside a solid", removed)
    if solver.fluid.capacity == 0:
        if removed == 0:
            raise ValueError(
                f"no fluid particle: the fluid blocks hold no lattice point (each must be at least the "
                f"particle spacing, {scene.config.spacing:.4g} m, on every axis)"
            )
        walls = " or the domain walls" if scene.domain.walls else ""
        raise ValueError(
            f"no fluid particle left: all {removed} fluid particles of the blocks start inside a solid "
            f"or closer than 0.9 particle spacings to a particle of a solid{walls}; move the blocks "
            "away from them"
        )
    return solver


def speed_bound(initial_speed: float, gravity: float, height: float, duration: float) -> float:
    """An upper bound of a fluid particle's speed during a run, m/s, from free fall.

    A particle that starts at ``initial_speed`` and falls freely reaches, by energy conservation,
    sqrt(v0^2 + 2 g H) after falling the whole height ``H`` it can fall in the domain, and v0 + g T after
    the run's ``duration`` T; the smaller of the two bounds both. Pressure and splashes redistribute this
    speed rather than add to it, which is why the check compares it with a CFL limit of about one.

    Args:
        initial_speed: v0, the fastest initial fluid speed, m/s.
        gravity: g = |gravity|, m/s^2.
        height: H, the domain's extent along gravity, m.
        duration: T, simulated seconds.
    """
    v0 = float(initial_speed)
    return min(math.sqrt(v0 * v0 + 2.0 * gravity * max(height, 0.0)), v0 + gravity * max(duration, 0.0))


def run_cfl(config: SolverConfig, initial_speed: float, domain_min, domain_max, steps: int) -> tuple[float, float]:
    """(the largest CFL number v dt / (2 r) the run can reach, the speed bound v in m/s).

    Fixed steps: v = :func:`speed_bound` over ``steps * dt``, so CFL = v dt / (2 r). Adaptive steps
    (``time_step`` "cfl"): the first step at the clamped initial dt, then cfl_factor, unless dt_min holds the
    step above it (v dt_min / 2 r) or dt_max below it.
    """
    g = float(np.linalg.norm(config.gravity))
    extent = np.subtract(np.asarray(domain_max, np.float64), np.asarray(domain_min, np.float64))
    height = float(np.abs(np.asarray(config.gravity)) @ extent / g) if g > 0 else 0.0
    sp = config.spacing
    if config.time_step == "fixed":
        v = speed_bound(initial_speed, g, height, steps * config.dt)
        return v * config.dt / sp, v
    dt0 = min(max(config.dt, config.dt_min), config.dt_max)
    v = speed_bound(initial_speed, g, height, steps * config.dt_max)
    first = speed_bound(initial_speed, g, height, dt0) * dt0 / sp
    later = max(min(config.cfl_factor, v * config.dt_max / sp), v * config.dt_min / sp)
    return max(first, later), v


def check_time_step(
    config: SolverConfig, initial_speed: float, domain_min, domain_max, steps: int, where: str = "the run"
) -> float:
    """Refuse, before the first step, a time step at which fluid could jump more than ``config.max_cfl``
    particle spacings per step (it would skip its neighbours, pass through walls and solids and leave the
    domain: a run that "completes" with no fluid left). Returns the run's CFL number (:func:`run_cfl`).

    Raises:
        ValueError: naming ``where``, the CFL number, the speed bound and the largest dt that passes.
    """
    cfl, v = run_cfl(config, initial_speed, domain_min, domain_max, steps)
    if cfl <= config.max_cfl:
        check_viscous_time_step(config, where)  # after the CFL check: a dt too large for both is named by it
        return cfl
    sp = config.spacing
    if config.time_step == "fixed":
        fix = (
            f"use dt <= {config.max_cfl * sp / v:.3g} s (and more steps for the same duration), a larger "
            "particle radius, or time_step 'cfl'"
        )
    else:
        fix = "lower cfl_factor, dt_min or the initial dt"
    raise ValueError(
        f"{where}: time step too large for the particle spacing: CFL number {cfl:.3g} > max_cfl {config.max_cfl:g} "
        f"(a fluid particle at the speed bound {v:.3g} m/s, the fastest initial speed {initial_speed:.3g} m/s plus "
        f"free fall through the domain, would move {cfl:.3g} spacings of {sp:g} m in one step of "
        f"{config.dt:g} s, past its neighbours and through walls and solids, out of the domain); {fix}"
    )


def viscous_dt_limit(config: SolverConfig, viscosity: float) -> float:
    """The largest time step at which the explicit viscosity step of dynamic viscosity ``viscosity`` (Pa s) is
    stable, s: dt <= 0.125 (h/2)^2 rho0 / mu, the diffusion limit dt <= 0.125 h'^2 / nu of Morris, Fox & Zhu
    (1997, J. Comput. Phys. 136, Eq. 22) with the smoothing length h' = h / 2 of the cubic kernel of support h and
    nu = mu / rho0 (measured at r = 0.05 m, dt = 0.002 s: the bound is 625 Pa s; 600 ran, 1000 diverged)."""
    if viscosity <= 0:
        return math.inf
    return VISCOUS_STABILITY * (config.support_radius / 2.0) ** 2 * config.rest_density / viscosity


VISCOUS_STABILITY = 0.125


def check_viscous_time_step(config: SolverConfig, where: str = "the run") -> None:
    """Refuse, before the first step, a viscosity whose explicit step diverges at the run's time step
    (:func:`viscous_dt_limit`; adaptive steps are checked at their smallest, ``dt_min``).

    Raises:
        ValueError: naming the viscosity (or boundary_viscosity), the limit and the fix.
    """
    dt = config.dt if config.time_step == "fixed" else config.dt_min
    named = {"viscosity": config.viscosity}
    if config.boundary_viscosity is not None:
        named["boundary_viscosity"] = config.boundary_viscosity
    for name, mu in named.items():
        limit = viscous_dt_limit(config, mu)
        if dt > limit:
            largest = mu * limit / dt
            raise ValueError(
                f"{where}: {name} {mu:g} Pa s is above the stability limit of the explicit viscosity step at dt "
                f"{dt:g} s: it is stable for dt <= 0.125 (h/2)^2 rho0 / mu = {limit:.3g} s (h = "
                f"{config.support_radius:g} m, rho0 = {config.rest_density:g} kg/m^3), so the run would diverge; "
                f"lower {name} to {largest:.3g} Pa s or less, or dt to {limit:.3g} s or less"
            )


def check_solver_time_step(solver: DFSPHSolver, steps: int, where: str = "the run") -> float:
    """:func:`check_time_step` for a built solver (its domain, its fluid's fastest speed now)."""
    v = solver.fluid.numpy("v") if solver.fluid.active else np.zeros((0, 3))
    v0 = float(np.sqrt((np.asarray(v, np.float64) ** 2).sum(1)).max()) if len(v) else 0.0
    return check_time_step(solver.config, v0, solver.domain_min, solver.domain_max, steps, where)


class FaultMonitor:
    """Judges each step's statistics and raises :class:`SimulationDiverged` on a fault."""

    def __init__(self, config: SolverConfig):
        self.config = config
        self._capped = 0

    def check(self, stats: StepStats) -> None:
        cfg = self.config
        if stats.nonfinite:
            raise SimulationDiverged(
                stats.step, f"{stats.nonfinite} fluid velocities are NaN or Inf; reduce dt or use time_step 'cfl'"
            )
        if stats.max_speed > cfg.max_speed:
            raise SimulationDiverged(
                stats.step,
                f"fluid speed {stats.max_speed:.3g} m/s exceeds max_speed "
                f"{cfg.max_speed:g} m/s; reduce dt or use time_step 'cfl'",
            )
        capped = stats.density_iterations >= cfg.max_iterations or stats.divergence_iterations >= cfg.max_iterations
        self._capped = self._capped + 1 if capped else 0
        if self._capped >= cfg.max_capped_steps:
            raise SimulationDiverged(
                stats.step,
                f"the pressure solver hit max_iterations={cfg.max_iterations} "
                f"for {self._capped} steps in a row; reduce dt or raise "
                "the tolerances",
            )


def run(
    solver: DFSPHSolver,
    steps: int,
    on_step: Callable[[DFSPHSolver, StepStats], None] | None = None,
    progress: Callable[[StepStats], None] | None = None,
    stop: Callable[[DFSPHSolver, StepStats], bool] | None = None,
) -> list[StepStats]:
    """Step ``solver`` at most ``steps`` times, checking each step for faults.

    Args:
        solver: a built solver.
        steps: the most steps to run.
        on_step: called after each checked step (save frames, accumulate metrics).
        progress: called after each step with its stats (a progress bar).
        stop: called after ``on_step``; True ends the run after that step (a converged metric, e.g.
            ``nbv.physics.early_stop``). None: run all ``steps``.
    Returns:
        the stats of every step run (fewer than ``steps`` when ``stop`` ended the run).
    Raises:
        ValueError: before the first step, when the time step is too large (:func:`check_solver_time_step`).
        SimulationDiverged: on a fault; ``on_step`` has seen every step before it.
    """
    check_solver_time_step(solver, steps)
    monitor = FaultMonitor(solver.config)
    history: list[StepStats] = []
    for _ in range(steps):
        stats = solver.step()
        history.append(stats)
        if progress is not None:
            progress(stats)
        try:
            monitor.check(stats)
        except SimulationDiverged as exc:
            exc.history = history
            raise
        if on_step is not None:
            on_step(solver, stats)
        if stop is not None and stop(solver, stats):
            break
    return history
