"""The DFSPH time step (Bender & Koschier 2015, Alg. 1; 2017) on fluid and static boundary particles.

``DFSPHSolver.step()`` reads like the algorithm:

    grid sort -> neighbourhoods, density, factor -> divergence solve -> divergence estimate (paper Eq. 1)
    -> non-pressure forces, predict v* -> density solve -> advect (in the density solve's last pass)

The passes over the neighbour lists are fused where they read the same data: the neighbourhood pass
measures the divergence solver's first source (cold start) or sums and applies its warm-start push, the
divergence solver's error pass writes the density solver's warm-start records, and the non-pressure pass
sums the density solver's push, computes paper Eq. 1 with the default estimator radii and writes
v* = v + dt a - P / dt; no warm start reads the lists.
A step with both solvers at their minimum iterations reads the lists 7 times after the neighbourhood
pass: 2 (divergence), 1 (non-pressure forces), 4 (density), in 10 kernel launches.

It never prints; it returns :class:`StepStats`. Faults (NaN, runaway speed, a solver stuck at its
iteration cap) are judged by the caller (:mod:`fluidsim.simulation`), which knows the run.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

import numpy as np
import taichi as ti

from . import dfsph, divergence, grid, neighbors, viscosity
from .config import RETIRE_MARGIN_MAX, SolverConfig
from .grid import GridSpec
from .kernels import CUBIC_TABLE_SIZE, cubic_table_np, cubic_w_np
from .particles import BoundaryParticles, FluidParticles, Neighborhoods, float_dtype
from .reductions import inverse_quantum

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class StepStats:
    """What one step did.

    Attributes:
        step: index of the step (0-based). time: simulated time at its end, s. dt: s.
        density_iterations / divergence_iterations: solver iterations.
        density_error: final average density error, percent of rho_0.
        divergence_error: final average divergence error, percent of rho_0 over one dt.
        max_speed: largest fluid speed after the step, m/s.
        nonfinite: fluid particles with a NaN or Inf velocity.
        retired: fluid particles that left the domain (past the retire margin) in this step.
        active: fluid particles left.
        max_fluid_neighbors / max_boundary_neighbors: largest neighbour counts.
    """

    step: int
    time: float
    dt: float
    density_iterations: int
    density_error: float
    divergence_iterations: int
    divergence_error: float
    max_speed: float
    nonfinite: int
    retired: int
    active: int
    max_fluid_neighbors: int
    max_boundary_neighbors: int


STATS_FIELDS = tuple(StepStats.__dataclass_fields__)


def fluid_particle_volume(spacing: float, h: float) -> float:
    """V_f = m / rho_0 such that a particle inside a lattice of ``spacing`` has exactly rho_0.

    Args:
        spacing: lattice spacing 2 r, m. h: support radius, m.
    Returns:
        m^3 (a bit under spacing^3 for the cubic spline with h = 2 spacing).
    """
    pts = neighbors.lattice_offsets(spacing, h)
    return float(1.0 / cubic_w_np(np.linalg.norm(pts, axis=1), h).sum())


def sort_points_by_cell(points: np.ndarray, spec: GridSpec) -> tuple[np.ndarray, np.ndarray, int]:
    """Stable numpy sort of static points by grid cell.

    Returns:
        (points inside the grid in cell order (M,3), cell starts (num_cells + 1,), dropped count).
    """
    cells = grid.cell_index_np(points, spec)
    keep = cells < spec.num_cells
    order = np.argsort(cells[keep], kind="stable")
    pts = points[keep][order]
    counts = np.bincount(cells[keep], minlength=spec.num_cells)
    starts = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    return pts, starts, int((~keep).sum())


class DFSPHSolver:
    """DFSPH on one fluid set and one static boundary set inside an axis-aligned domain.

    Args:
        config: solver parameters.
        domain_min, domain_max: (3,) m; fluid farther than ``config.retire_margin`` spacings outside this
            box is retired.
        fluid_positions, fluid_velocities: (N, 3) m and m/s.
        boundary_points: (M, 3) m, static (walls and solids).
    """

    def __init__(self, config: SolverConfig, domain_min, domain_max, fluid_positions: np.ndarray,
                 fluid_velocities: np.ndarray, boundary_points: np.ndarray):
        runtime_fp = ti.lang.impl.get_runtime().default_fp
        if runtime_fp != float_dtype(config.precision):
            raise ValueError(
                f"precision {config.precision!r} differs from the Taichi runtime's default_fp {runtime_fp}; "
                f"initialise Taichi with default_fp={'ti.f64' if config.precision == 'f64' else 'ti.f32'}")
        self.config = config
        self.domain_min = np.asarray(domain_min, dtype=np.float64)
        self.domain_max = np.asarray(domain_max, dtype=np.float64)
        h = config.support_radius
        self.h = h
        # Walls sit up to a few spacings outside the domain; one more h keeps their neighbours inside.
        self.grid = grid.grid_for_box(self.domain_min, self.domain_max, h,
                                      pad=RETIRE_MARGIN_MAX * config.spacing + h, z_split=grid.Z_SPLIT)
        margin = config.retire_margin * config.spacing
        self._retire_min = ti.Vector(list(self.domain_min - margin), ti.f64)
        self._retire_max = ti.Vector(list(self.domain_max + margin), ti.f64)
        self.fluid_volume = fluid_particle_volume(config.spacing, h)
        g = self.grid
        self._origin = ti.Vector(list(g.origin), ti.f64)
        self._inv_cell = ti.Vector(list(g.inv_cell), ti.f64)
        self._dims = grid.ivec3(*g.dims)

        bpts, bstarts, dropped = sort_points_by_cell(np.asarray(boundary_points, np.float64).reshape(-1, 3), g)
        if dropped:
            log.info("dropped %d boundary particles outside the simulation grid", dropped)
        self.boundary = BoundaryParticles(bpts, bstarts, config.precision)
        neighbors.compute_boundary_volumes(self.boundary.x, self.boundary.cell_starts, self.boundary.count,
                                           self._origin, self._inv_cell, self._dims, h, self.boundary.volume)

        fx = np.asarray(fluid_positions, np.float64).reshape(-1, 3)
        fv = np.asarray(fluid_velocities, np.float64).reshape(-1, 3)
        self.removed_inside_solid = 0
        if len(fx) and self.boundary.count:
            keep = self._outside_boundary(fx)
            self.removed_inside_solid = int((~keep).sum())
            fx, fv = fx[keep], fv[keep]
        self._kernel_table = ti.Vector.ndarray(2, float_dtype(config.precision), shape=CUBIC_TABLE_SIZE + 2)
        self._kernel_table.from_numpy(cubic_table_np(h).astype(np.float64 if config.precision == "f64" else np.float32))
        self.fluid = FluidParticles(fx, fv, config.precision)
        n = self.fluid.capacity
        capacity = config.max_neighbors
        if capacity is None:
            capacity = neighbors.list_capacity(neighbors.lattice_neighbor_count(config.spacing, h))
        self.neighborhoods = Neighborhoods(n, capacity, config.precision, h,
                                           store_boundary=self._reads_boundary_lists())
        self._list_capacity: tuple[int, int] | None = None  # a smaller capacity for the next neighbourhood pass
        self._counts = ti.ndarray(ti.i32, shape=g.num_cells + 1)
        self._counts.fill(0)  # the counting sort leaves it zero for the next step
        self._serial_sort = grid.serial_sort()
        self._starts = ti.ndarray(ti.i32, shape=g.num_cells + 2)
        self._block_sums = ti.ndarray(ti.i32, shape=grid.SCAN_BLOCKS)
        self.time = 0.0
        self.step_index = 0
        self.stage_times: dict[str, float] | None = None  # set to {} to profile stages
        speeds = np.linalg.norm(fv, axis=1) if len(fv) else np.zeros(1)
        self._max_speed = float(speeds.max())
        self._gravity = ti.Vector(list(config.gravity))
        self._density_records = False  # this step's divergence error pass wrote the density warm-start records

    # -- setup helpers -------------------------------------------------------------------------
    def _outside_boundary(self, fx: np.ndarray) -> np.ndarray:
        """Mask of fluid positions not overlapping a boundary particle (closer than 0.9 spacing)."""
        fp = float_dtype(self.config.precision)
        tmp = ti.Vector.ndarray(3, fp, shape=len(fx))
        tmp.from_numpy(fx.astype(np.float64 if fp == ti.f64 else np.float32))
        flags = ti.ndarray(ti.i32, shape=len(fx))
        neighbors.flag_near_boundary(len(fx), tmp, self.boundary.x, self.boundary.cell_starts, self._origin,
                                     self._inv_cell, self._dims, 0.9 * self.config.spacing, flags)
        return flags.to_numpy() == 0

    # -- the time step -------------------------------------------------------------------------
    def step(self) -> StepStats:
        """Advance one time step and return its statistics."""
        stage = self._stage
        dt = self._time_step()
        self._density_records = False
        retired = stage("sort", self._sort)                              # grid: counting sort by cell
        max_f, max_b = stage("neighbors", self._neighborhoods, dt)       # density, factor, warm start
        div_it, div_err = stage("divergence_solve", self._divergence_solve, dt)  # B&K divergence-free
        fused = self._estimate_with_viscosity()
        if not fused:  # paper Eq. 1 with its own radii
            stage("divergence_estimate", self._estimate_divergence)      # paper Eq. 1
        # gravity, viscosity (and Eq. 1): v* = v + dt a, with the density solver's warm start
        stage("non_pressure", self._non_pressure_forces, dt, fused)
        # B&K constant density; its last velocity update also advects, x += dt v
        dens_it, dens_err, (max_speed, bad) = stage("density_solve", self._density_solve, dt)
        self._max_speed = max_speed
        self.time += dt
        stats = StepStats(
            step=self.step_index, time=self.time, dt=dt,
            density_iterations=dens_it, density_error=100.0 * dens_err,
            divergence_iterations=div_it, divergence_error=100.0 * div_err * dt,
            max_speed=max_speed, nonfinite=bad, retired=retired, active=self.fluid.active,
            max_fluid_neighbors=max_f, max_boundary_neighbors=max_b)
        self.step_index += 1
        return stats

    def _stage(self, name: str, fn, *args):
        """Run one stage; with ``stage_times`` set (a dict), add its wall time in seconds."""
        if self.stage_times is None:
            return fn(*args)
        ti.sync()
        t0 = time.perf_counter()
        out = fn(*args)
        ti.sync()
        self.stage_times[name] = self.stage_times.get(name, 0.0) + time.perf_counter() - t0
        return out

    def _time_step(self) -> float:
        cfg = self.config
        if cfg.time_step == "fixed":
            return cfg.dt
        if self.step_index == 0 or self._max_speed <= 0.0:
            return min(max(cfg.dt, cfg.dt_min), cfg.dt_max)
        return min(max(cfg.cfl_factor * cfg.spacing / self._max_speed, cfg.dt_min), cfg.dt_max)

    def _sort(self) -> int:
        f = self.fluid
        if f.active == 0:
            return 0
        kept = grid.counting_sort(f.x, f.active, f.capacity, self._origin, self._inv_cell, self._dims,
                                  self._retire_min, self._retire_max, f.cell_ids, f.ranks, self._counts,
                                  self._starts, self._block_sums, f.order, self._serial_sort)
        f.permute()
        retired = f.active - int(kept)
        f.active = int(kept)
        return retired

    def _warm(self) -> tuple[bool, bool]:
        """Whether the divergence and the density solver warm-start this step."""
        cfg = self.config
        divergence_warm = cfg.warm_start and cfg.divergence_warm_start and cfg.divergence_solver
        return divergence_warm, cfg.warm_start

    def _reads_boundary_lists(self) -> bool:
        """Whether a pass reads the boundary pairs: the fluid-boundary viscosity, or Eq. 1 walking the lists."""
        cfg = self.config
        return cfg.wall_viscosity != 0.0 or (not self._estimate_with_viscosity()
                                              and cfg.estimator_radius <= cfg.support_radius)

    def _neighborhoods(self, dt: float | None = None) -> tuple[int, int]:
        f, nb, b = self.fluid, self.neighborhoods, self.boundary
        dt = self.config.dt if dt is None else dt
        warm = self._warm()[0]
        if self._list_capacity is not None:  # shrink planned by the last pass (its lists were still in use)
            nb.resize(*self._list_capacity)
            self._list_capacity = None
        while True:
            counts = neighbors.build_neighborhoods(
                f.active, f.x, self._starts, b.x, b.volume, b.cell_starts, self._origin, self._inv_cell,
                self._dims, self.h, self.fluid_volume, nb.fluid_count, nb.fluid_pairs, nb.boundary_count,
                nb.boundary_pairs, nb.boundary_grad_sum, nb.grad_sum, f.density, f.factor,
                f.v, f.source, self._kernel_table, int(warm), f.kappa_divergence, f.push_divergence, nb.format,
                nb.coef_scale, dfsph.DIVERGENCE_WARM_SCALE, dt, f.stiffness_sum, nb.store_boundary)
            max_f, max_b = int(counts[0]), int(counts[1])
            need_b = max_b if nb.store_boundary else 0
            if not int(counts[2]) and max_f <= nb.fluid_capacity and need_b <= nb.boundary_capacity:
                self._plan_list_capacity(max_f, need_b)
                return max_f, max_b
            if warm:  # the pass applied the divergence warm start; the next run applies it again
                dfsph.undo_push(f.active, dfsph.DIVERGENCE_WARM_SCALE, f.push_divergence, f.v)
            if int(counts[2]):
                log.info("a neighbour's index is over %d from its particle's: the fluid lists switch to the wide "
                         "format (8 bytes per pair) for the rest of the run", neighbors.NARROW_MAX_OFFSET)
                nb.widen()
                continue
            grow_f = max(nb.fluid_capacity, neighbors.list_capacity(max_f))
            grow_b = max(nb.boundary_capacity, neighbors.list_capacity(need_b))
            log.debug("growing neighbour lists to %d fluid / %d boundary slots", grow_f, grow_b)
            nb.resize(grow_f, grow_b)

    def _plan_list_capacity(self, max_f: int, max_b: int) -> None:
        """Plan smaller lists for the next neighbourhood pass where the capacity is far above the largest count
        (:func:`fluidsim.neighbors.shrink_threshold`; padded rows cost every list pass memory traffic)."""
        nb = self.neighborhoods
        cap_f, cap_b = nb.fluid_capacity, nb.boundary_capacity
        if cap_f > neighbors.shrink_threshold(max_f):
            cap_f = neighbors.list_capacity(max_f)
        if nb.store_boundary and cap_b > neighbors.shrink_threshold(max_b):
            cap_b = neighbors.list_capacity(max_b)
        if (cap_f, cap_b) != (nb.fluid_capacity, nb.boundary_capacity):
            log.debug("neighbour lists shrink to %d fluid / %d boundary slots", cap_f, cap_b)
            self._list_capacity = (cap_f, cap_b)

    def _solve(self, error, start, kappa, dt: float, tolerance: float, store_scale: float,
               min_iterations: int, advect: bool = False) -> tuple[int, float, tuple[float, int]]:
        """The iteration shared by both DFSPH solvers; returns (iterations, last measured average error,
        (max speed, non-finite count) after advection when ``advect``, else (0, 0)).

        Each iteration measures the error (setting the stiffness of a Jacobi update) and applies the update;
        the solve ends after the iteration whose measured error is within ``tolerance``, once at least
        ``min_iterations`` ran, or after ``config.max_iterations`` (SPlisHSPlasH's loop). The last update also
        stores the warm-start memory and, with ``advect``, moves the particles (:func:`dfsph.finish_solve`).

        Args:
            error: ``error()`` runs an error pass and returns the average error.
            start: ``start()`` begins the solve (warm or cold) and returns the first average error when it is
                already known (the cold divergence solve reads it from the neighbourhood pass), else None.
            kappa: the warm-start memory the solve stores at its end (summed stiffness x ``store_scale``).
        """
        cfg, f, nb = self.config, self.fluid, self.neighborhoods
        n = f.active
        known = start()
        iterations = 0
        while True:
            err = known if known is not None else error()
            known = None
            iterations += 1
            if (err <= tolerance and iterations >= min_iterations) or iterations >= cfg.max_iterations:
                out = dfsph.finish_solve(n, dt, f.v, nb.fluid_count, nb.fluid_pairs, nb.format, nb.inv_scale,
                                         nb.grad_sum, f.position_stiffness, f.stiffness_sum, store_scale, kappa,
                                         int(advect), f.x)
                return iterations, float(err), (float(out[0]), int(out[1]))
            dfsph.apply_stiffness(n, dt, f.v, nb.fluid_count, nb.fluid_pairs, nb.format, nb.inv_scale, nb.grad_sum,
                                  f.position_stiffness, f.stiffness_sum)

    def _divergence_solve(self, dt: float) -> tuple[int, float]:
        if not self.config.divergence_solver or self.fluid.active == 0:
            return 0, 0.0
        # Tolerance on the average D(rho/rho_0)/Dt such that one dt changes the density by eta.
        tol = self.config.max_divergence_error * 0.01 / dt
        inv_quantum = inverse_quantum(tol)  # the error averages are fixed-point sums, exact to 2^-21 tol
        f, nb = self.fluid, self.neighborhoods
        warm = self._warm()[0]

        def start() -> float | None:  # a warm start happened in the neighbourhood pass
            if warm:
                return None
            return dfsph.start_divergence(f.active, dt, f.source, f.factor, f.x, f.position_stiffness,
                                          f.stiffness_sum, inv_quantum)

        def error() -> float:  # also writes the density solver's warm-start records from this source
            self._density_records = True
            return dfsph.divergence_error(f.active, dt, f.x, f.v, nb.fluid_count, nb.fluid_pairs, nb.format,
                                          nb.inv_scale, nb.boundary_count, nb.grad_sum, f.factor, f.source,
                                          f.position_stiffness, inv_quantum, int(self._warm()[1]),
                                          self._gravity, f.density, nb.boundary_grad_sum, f.kappa_density,
                                          f.density_record)

        iterations, err, _ = self._solve(error, start, f.kappa_divergence, dt, tol, dt,
                                         self.config.min_divergence_iterations)
        return iterations, err

    def _density_solve(self, dt: float) -> tuple[int, float, tuple[float, int]]:
        """The constant-density solve, ending with the advection x += dt v; returns (iterations, error,
        (max speed m/s, non-finite velocities))."""
        f, nb = self.fluid, self.neighborhoods
        if f.active == 0:
            return 0, 0.0, (0.0, 0)
        tol = self.config.max_density_error * 0.01
        inv_quantum = inverse_quantum(tol)

        def start() -> None:  # the non-pressure pass predicted v* and applied the warm start
            return None

        def error() -> float:
            return dfsph.density_error(f.active, dt, f.x, f.v, nb.fluid_count, nb.fluid_pairs, nb.format,
                                       nb.inv_scale, nb.grad_sum, f.density, f.factor, f.source,
                                       f.position_stiffness, inv_quantum)

        return self._solve(error, start, f.kappa_density, dt, tol, dt * dt, self.config.min_iterations, advect=True)

    def _estimate_with_viscosity(self) -> bool:
        """Whether paper Eq. 1 can use the stored gradients (h_k = h <= h_r), fused into the viscosity pass."""
        cfg = self.config
        return math.isclose(cfg.estimator_kernel_radius, self.h, rel_tol=1e-9) and cfg.estimator_radius >= self.h

    def _estimate_divergence(self) -> None:
        """Paper Eq. 1 as a pass of its own (the step fuses the stored-gradient case into the viscosity pass)."""
        cfg, f, nb, b = self.config, self.fluid, self.neighborhoods, self.boundary
        if f.active == 0:
            return
        if self._estimate_with_viscosity():
            # The default (h_r = h_k = h): the lists hold exactly the neighbours and their V_f grad W.
            divergence.estimate_divergence_from_gradients(
                f.active, f.x, f.v, f.density, nb.fluid_count, nb.fluid_pairs, nb.format, nb.inv_scale,
                nb.boundary_grad_sum,
                f.divergence, f.divergence_sum, f.divergence_count)
        elif cfg.estimator_radius <= self.h:
            divergence.estimate_divergence_from_lists(
                f.active, cfg.estimator_radius, cfg.estimator_kernel_radius, self.fluid_volume, f.x, f.v,
                f.density, b.x, b.volume, nb.fluid_count, nb.fluid_pairs, nb.format, nb.boundary_count,
                nb.boundary_pairs,
                f.divergence, f.divergence_sum, f.divergence_count)
        else:
            reach = int(math.ceil(cfg.estimator_radius / self.grid.cell_size))
            reach_z = int(math.ceil(cfg.estimator_radius / self.grid.cell_sizes[2]))
            divergence.estimate_divergence_from_grid(
                f.active, cfg.estimator_radius, cfg.estimator_kernel_radius, self.fluid_volume, reach, reach_z,
                self._origin, self._inv_cell, self._dims, f.x, f.v, f.density, self._starts, b.x, b.volume,
                b.cell_starts, f.divergence, f.divergence_sum, f.divergence_count)

    def _non_pressure_forces(self, dt: float, estimate: bool = False) -> None:
        """Gravity and viscosity, v*_i = v_i + dt a_i, with the density solver's warm start (and, with
        ``estimate``, paper Eq. 1 from the stored gradients) in one sweep
        (:func:`fluidsim.viscosity.predict_velocities`), into the spare velocity buffer, which then becomes v."""
        cfg, f, nb, b = self.config, self.fluid, self.neighborhoods, self.boundary
        if f.active == 0:
            return
        warm = self._warm()[1]
        if not self._density_records:  # no divergence error pass wrote them this step
            dfsph.density_warm_stiffness(f.active, dt, int(warm), self._gravity, f.x, f.density, f.source,
                                         nb.boundary_grad_sum, f.kappa_density, f.density_record)
        viscosity.predict_velocities(
            f.active, f.capacity, dt, self._gravity, cfg.viscosity, cfg.wall_viscosity, cfg.rest_density, self.h,
            f.x, f.v, f.density, f.density_record, b.x, nb.fluid_count, nb.fluid_pairs, nb.format, nb.inv_scale,
            nb.boundary_count, nb.boundary_pairs, nb.boundary_grad_sum, nb.grad_sum, int(estimate), f.divergence,
            f.divergence_sum, f.divergence_count, int(warm), f.stiffness_sum, f.velocity_scratch())
        f.swap_velocity()

    # -- read-back -----------------------------------------------------------------------------
    def fluid_state(self) -> dict[str, np.ndarray]:
        """Active fluid particles, ordered by their initial index.

        Returns:
            dict with ``ids`` (K,), ``x`` (K,3) m, ``v`` (K,3) m/s, ``divergence`` (K,) 1/s,
            ``density`` (K,) rho/rho_0.
        """
        f = self.fluid
        ids = f.numpy("ids")
        order = np.argsort(ids, kind="stable")
        return {"ids": ids[order], "x": f.numpy("x")[order], "v": f.numpy("v")[order],
                "divergence": f.numpy("divergence")[order], "density": f.numpy("density")[order]}

    def divergence_accumulation(self) -> tuple[np.ndarray, np.ndarray]:
        """Run sums and counts of D_i per initial fluid particle (retired particles included).

        Returns:
            (sum (N,) 1/s, count (N,) int), indexed by initial fluid index.
        """
        f = self.fluid
        ids = f.numpy("ids", active_only=False)
        total = np.zeros(f.capacity)
        count = np.zeros(f.capacity, dtype=np.int64)
        total[ids] = f.numpy("divergence_sum", active_only=False)
        count[ids] = f.numpy("divergence_count", active_only=False)
        return total, count
