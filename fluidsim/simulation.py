"""Running a simulation: building the solver from a scene, stepping it, and stopping on faults.

A run stops with :class:`SimulationDiverged`, naming the step, when a velocity becomes NaN or Inf,
when a fluid speed exceeds ``config.max_speed``, or when a solver hits ``max_iterations`` for
``config.max_capped_steps`` steps in a row. Whatever the caller saved before that stays saved.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

import numpy as np

from . import sources
from .config import SolverConfig
from .scene import Scene, lattice_in_box
from .solver import DFSPHSolver, StepStats

log = logging.getLogger(__name__)


class SimulationDiverged(RuntimeError):
    """The simulation became unphysical at ``step``; the message says why and what to change."""

    def __init__(self, step: int, reason: str):
        super().__init__(f"simulation diverged at step {step}: {reason}")
        self.step = step
        self.reason = reason
        self.history: list[StepStats] = []


def boundary_points_for_scene(scene: Scene) -> np.ndarray:
    """All static boundary particles of a scene: domain walls and every solid, (M, 3) m."""
    spacing = scene.config.spacing
    parts = []
    if scene.domain.walls:
        parts.append(sources.wall_particles(scene.domain.min, scene.domain.max, spacing, scene.domain.wall_layers))
    for solid in scene.solids:
        parts.append(solid_points(solid, scene.base_dir, spacing))
    return np.concatenate(parts) if parts else np.zeros((0, 3))


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
    boundary = boundary_points_for_scene(scene)
    x, v, removed = fluid_for_scene(scene)
    solver = DFSPHSolver(scene.config, scene.domain.min, scene.domain.max, x, v, boundary)
    removed += solver.removed_inside_solid
    solver.removed_inside_solid = removed
    if removed:
        log.warning("removed %d fluid particles that started inside a solid", removed)
    if solver.fluid.capacity == 0:
        raise ValueError("no fluid particle left: every fluid block lies inside a solid; move the blocks")
    return solver


class FaultMonitor:
    """Judges each step's statistics and raises :class:`SimulationDiverged` on a fault."""

    def __init__(self, config: SolverConfig):
        self.config = config
        self._capped = 0

    def check(self, stats: StepStats) -> None:
        cfg = self.config
        if stats.nonfinite:
            raise SimulationDiverged(stats.step, f"{stats.nonfinite} fluid velocities are NaN or Inf; "
                                                 "reduce dt or use time_step 'cfl'")
        if stats.max_speed > cfg.max_speed:
            raise SimulationDiverged(stats.step, f"fluid speed {stats.max_speed:.3g} m/s exceeds max_speed "
                                                 f"{cfg.max_speed:g} m/s; reduce dt or use time_step 'cfl'")
        capped = (stats.density_iterations >= cfg.max_iterations
                  or stats.divergence_iterations >= cfg.max_iterations)
        self._capped = self._capped + 1 if capped else 0
        if self._capped >= cfg.max_capped_steps:
            raise SimulationDiverged(stats.step, f"the pressure solver hit max_iterations={cfg.max_iterations} "
                                                 f"for {self._capped} steps in a row; reduce dt or raise "
                                                 "the tolerances")


def run(solver: DFSPHSolver, steps: int, on_step: Callable[[DFSPHSolver, StepStats], None] | None = None,
        progress: Callable[[StepStats], None] | None = None) -> list[StepStats]:
    """Step ``solver`` ``steps`` times, checking each step for faults.

    Args:
        solver: a built solver.
        steps: number of steps.
        on_step: called after each checked step (save frames, accumulate metrics).
        progress: called after each step with its stats (a progress bar).
    Returns:
        the stats of every step.
    Raises:
        SimulationDiverged: on a fault; ``on_step`` has seen every step before it.
    """
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
    return history
