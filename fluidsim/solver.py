"""The DFSPH time step (Bender & Koschier 2015, Algorithm 1; 2017) on fluid and static boundary particles.

Densities are normalised by rho_0 (as in SPlisHSPlasH) and every neighbour weight is a volume V_j, so with
g_ij = V_j grad W(x_i - x_j, h) = c_ij (x_i - x_j) (c_ij stored per pair by the neighbourhood pass) and
G_i = sum_j g_ij + sum_b g_ib (j over fluid, b over boundary; the boundary is at rest) the step computes:

=====  ===============================================================================================
(E1)   density            rho_i / rho_0 = V_f W(0) + sum_j V_f W_ij + sum_b V_b W_ib  (Akinci 2012 boundary)
(E2)   factor             alpha_i / rho_i = 1 / (|G_i|^2 + sum_j |g_ij|^2)   (``factor``; 0 when tiny)
(E3)   divergence source  s_i = D(rho_i / rho_0)/Dt = sum_j (v_i - v_j) . g_ij + v_i . sum_b g_ib,
                          clamped at 0, and 0 at the free surface (< 20 neighbours)
(E4)   stiffness          k_i = kappa_i / rho_i = s_i alpha_i / dt (divergence solver),
                          (rho*_i - 1) alpha_i / dt^2 (density solver)
(E5)   velocity update    v_i -= dt (sum_j (k_i + k_j) g_ij + k_i sum_b g_ib) = dt (k_i G_i + sum_j k_j g_ij)
(E6)   predicted density  rho*_i = rho_i + dt s_i; error max(rho*_i - 1, 0)
(E7)   non-pressure       a_i = g + (mu / rho_i) lap(v)_i  (Monaghan 2005 Laplacian, :mod:`fluidsim.viscosity`)
(E8)   predicted velocity v*_i = v_i + dt a_i
(E9)   advection          x_i += dt v_i
(E10)  time step          dt = cfl_factor 2 r / max_i |v_i|, clamped to [dt_min, dt_max] (or a fixed dt)
(W1)   divergence warm    P_i = kappa_i G_i + sum_j kappa_j g_ij; v_i -= P_i / 2  (k_i = kappa_i / (2 dt))
(W2)   density warm       w_i = kappa_i where rho_i + dt (s_i + dt g . sum_b g_ib) > 1, else 0;
                          v*_i -= (w_i G_i + sum_j w_j g_ij) / dt  (k_i = w_i / dt^2)
(W3)   warm memory        kappa_i = (sum over the solve's iterations of k_i) x dt (divergence), x dt^2 (density)
Eq. 1  D_i (FluidGaussian) | sum_j V_j (v_j - v_i) . grad W(x_i - x_j, h_k) |  over j within h_r
=====  ===============================================================================================

The equation labels are this docstring's own; B&K's (2015 SCA, 2017 TVCG) number theirs differently.
(E1)-(E6) and (W1)-(W3) are their constant-density and divergence-free solvers in SPlisHSPlasH's
stiffness form, with V_j in place of m_j / rho_0.

Algorithm 1 of Bender & Koschier, and the pass that computes each line:

==========================================  =====================  ===========================================
Algorithm 1 (B&K 2015)                      equations              pass (kernel) -- :meth:`DFSPHSolver.step`
==========================================  =====================  ===========================================
adapt time step dt (CFL)                    (E10)                  ``time_step`` (Python, from the last max |v|)
find neighborhoods N_i                      grid sort, c_ij, G_i   ``grid.counting_sort`` (``sort``), then
                                                                   ``neighbors.build_neighborhoods``
compute densities rho_i                     (E1)                   ``neighbors.build_neighborhoods``
compute factors alpha_i                     (E2)                   ``neighbors.build_neighborhoods``
correctDivergenceError(alpha, v)            (E3), (E4), (E5), (W1) ``divergence_solve``: warm start (W1) or the
  (divergence-free solver: D rho/Dt -> 0)   (W3)                   first s_i in ``build_neighborhoods``;
                                                                   ``dfsph.divergence_solve_cold_start``;
                                                                   per iteration ``dfsph.divergence_solve_error``
                                                                   and ``dfsph.apply_stiffness``; the last
                                                                   update ``dfsph.finish_solve`` (W3)
D_i (FluidGaussian Eq. 1; after the         Eq. 1                  fused into ``viscosity.predict_velocities``
  divergence solve, as the authors' code)                          (h_k = h <= h_r) or
                                                                   ``estimator.divergence_estimate_from_*``
compute non-pressure forces F_adv           (E7)                   ``viscosity.predict_velocities``
predict velocities v*                       (E8), (W2)             ``viscosity.predict_velocities`` (records w_i
                                                                   from ``divergence_solve_error`` or
                                                                   ``dfsph.density_warm_stiffness``)
correctDensityError(alpha, v*)              (E6), (E4), (E5), (W3) ``density_solve``: per iteration
  (constant-density solver: rho* -> rho_0)                         ``dfsph.density_solve_error`` and
                                                                   ``dfsph.apply_stiffness``; the last update
                                                                   ``dfsph.finish_solve``
update positions x                          (E9)                   ``dfsph.finish_solve`` (the density solve's
                                                                   last update)
==========================================  =====================  ===========================================

The loop is Algorithm 1's rotated to begin at the neighbourhood search (as SPlisHSPlasH's): a step is sort ->
neighbourhoods, density, factor -> divergence solve -> Eq. 1 -> non-pressure forces, v* -> density solve ->
advect, so the divergence solve of Algorithm 1's step n is the first solve of our step n + 1 (with v*
already v). The passes over the neighbour lists are fused where they read the same data: the
neighbourhood pass measures the divergence solver's first source (cold start) or sums and applies its
warm-start push (W1), the divergence solver's error pass writes the density solver's warm-start records
(W2), and the non-pressure pass sums the density solver's push, computes Eq. 1 with the default radii and
writes v* = v + dt a - P / dt; no warm start reads the lists. A step with both solvers at their minimum
iterations reads the lists 7 times after the neighbourhood pass: 2 (divergence), 1 (non-pressure forces),
4 (density), in 10 kernel launches. Each pass's argument list is spelt out once, in :mod:`fluidsim.passes`.

It never prints; it returns :class:`StepStats`. Faults (NaN, runaway speed, a solver stuck at its
iteration cap) are judged by the caller (:mod:`fluidsim.simulation`), which knows the run.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import taichi as ti

from . import estimator, forces, neighbors, passes
from .config import RETIRE_MARGIN_MAX, SolverConfig
from .grid import Z_SPLIT, GridSpec, cell_index_np, grid_for_box
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
        solid_force_x/y/z: the step's mean force of the fluid on the solid, N, simulation frame
            (:mod:`fluidsim.forces`; pressure and boundary viscosity).
        wall_force_x/y/z: the same on the walls (every boundary particle not of the solid), N.
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
    solid_force_x: float = 0.0
    solid_force_y: float = 0.0
    solid_force_z: float = 0.0
    wall_force_x: float = 0.0
    wall_force_y: float = 0.0
    wall_force_z: float = 0.0

    @property
    def solid_force(self) -> np.ndarray:
        """(3,) N, the force on the solid."""
        return np.array([self.solid_force_x, self.solid_force_y, self.solid_force_z])

    @property
    def wall_force(self) -> np.ndarray:
        """(3,) N, the force on the walls."""
        return np.array([self.wall_force_x, self.wall_force_y, self.wall_force_z])


STATS_FIELDS = tuple(StepStats.__dataclass_fields__)


@dataclass(frozen=True)
class WarmStart:
    """Which DFSPH solver starts from the stiffness kappa it stored at the previous step (B&K 2017).

    Attributes:
        divergence: the divergence-free solver (W1: half strength, applied by the neighbourhood pass); needs
            ``warm_start``, ``divergence_warm_start`` and ``divergence_solver``.
        density: the constant-density solver (W2: the compressing particles' kappa, applied by the non-pressure
            pass); ``warm_start``.
    """

    divergence: bool
    density: bool

    @classmethod
    def of(cls, config: SolverConfig) -> WarmStart:
        """The warm starts a configuration asks for."""
        return cls(
            divergence=bool(config.warm_start and config.divergence_warm_start and config.divergence_solver),
            density=bool(config.warm_start),
        )


class NeighborCounts(NamedTuple):
    """The largest neighbour counts of a neighbourhood pass (fluid, boundary)."""

    fluid: int
    boundary: int


class SolveResult(NamedTuple):
    """What one DFSPH solve did.

    Attributes:
        iterations: solver iterations. error: the last measured average error (1/s for the divergence solver, a
            fraction of rho_0 for the density solver). max_speed, nonfinite: of the advected velocities (m/s,
            count; the density solve only, else 0). error_passes: error passes run (one per iteration, less the
            first of a cold divergence solve, whose error the neighbourhood pass measured).
    """

    iterations: int
    error: float
    max_speed: float = 0.0
    nonfinite: int = 0
    error_passes: int = 0


def fluid_particle_volume(spacing: float, h: float) -> float:
    """V_f = m / rho_0 such that a particle inside a lattice of ``spacing`` has exactly rho_0.

    Args:
        spacing: lattice spacing 2 r, m. h: support radius, m.
    Returns:
        m^3 (a bit under spacing^3 for the cubic spline with h = 2 spacing).
    """
    pts = neighbors.lattice_offsets(spacing, h)
    return float(1.0 / cubic_w_np(np.linalg.norm(pts, axis=1), h).sum())


def sort_points_by_cell(
    points: np.ndarray, spec: GridSpec, labels: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, int, np.ndarray | None]:
    """Stable numpy sort of static points by grid cell.

    Args:
        points: (M, 3) m. spec: the grid. labels: (M,) per-point values carried along (e.g. the solid flags).
    Returns:
        (points inside the grid in cell order (M',3), cell starts (num_cells + 1,), dropped count, their labels
        (M',) or None).
    """
    cells = cell_index_np(points, spec)
    keep = cells < spec.num_cells
    order = np.argsort(cells[keep], kind="stable")
    pts = points[keep][order]
    counts = np.bincount(cells[keep], minlength=spec.num_cells)
    starts = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    sorted_labels = None if labels is None else np.asarray(labels)[keep][order]
    return pts, starts, int((~keep).sum()), sorted_labels


class DFSPHSolver:
    """DFSPH on one fluid set and one static boundary set inside an axis-aligned domain.

    Args:
        config: solver parameters.
        domain_min, domain_max: (3,) m; fluid farther than ``config.retire_margin`` spacings outside this
            box is retired.
        fluid_positions, fluid_velocities: (N, 3) m and m/s.
        boundary_points: (M, 3) m, static (walls and solids).
        solid: (M,) bool, which boundary points are the solid whose force :class:`StepStats` reports (the rest are
            walls); None: none.

    The stages of :meth:`step` are public (:meth:`sort`, :meth:`find_neighborhoods`, :meth:`divergence_solve`,
    :meth:`divergence_estimate`, :meth:`non_pressure_forces`, :meth:`density_solve`), so tests can run and check
    each one; ``warm`` (a :class:`WarmStart`) says which solver warm-starts.
    """

    def __init__(
        self,
        config: SolverConfig,
        domain_min,
        domain_max,
        fluid_positions: np.ndarray,
        fluid_velocities: np.ndarray,
        boundary_points: np.ndarray,
        solid: np.ndarray | None = None,
    ):
        runtime_fp = ti.lang.impl.get_runtime().default_fp
        if runtime_fp != float_dtype(config.precision):
            raise ValueError(
                f"precision {config.precision!r} differs from the Taichi runtime's default_fp {runtime_fp}; "
                f"initialise Taichi with default_fp={'ti.f64' if config.precision == 'f64' else 'ti.f32'}"
            )
        self.config = config
        self.warm = WarmStart.of(config)
        self.domain_min = np.asarray(domain_min, dtype=np.float64)
        self.domain_max = np.asarray(domain_max, dtype=np.float64)
        h = config.support_radius
        self.h = h
        # Walls sit up to a few spacings outside the domain; one more h keeps their neighbours inside.
        self.grid = grid_for_box(
            self.domain_min, self.domain_max, h, pad=RETIRE_MARGIN_MAX * config.spacing + h, z_split=Z_SPLIT
        )
        self.cells = passes.FluidGrid(self.grid)
        margin = config.retire_margin * config.spacing
        self._retire_min = ti.Vector(list(self.domain_min - margin), ti.f64)
        self._retire_max = ti.Vector(list(self.domain_max + margin), ti.f64)
        self.fluid_volume = fluid_particle_volume(config.spacing, h)

        bpts = np.asarray(boundary_points, np.float64).reshape(-1, 3)
        if solid is not None and np.shape(solid) != (len(bpts),):
            raise ValueError(f"solid flags {np.shape(solid)} differ from the boundary points ({len(bpts)}, 3)")
        bpts, bstarts, dropped, solid_sorted = sort_points_by_cell(bpts, self.grid, solid)
        if dropped:
            log.info("dropped %d boundary particles outside the simulation grid", dropped)
        self.boundary = BoundaryParticles(bpts, bstarts, config.precision, solid_sorted)
        passes.boundary_volumes(self.boundary, self.cells, h)

        fx = np.asarray(fluid_positions, np.float64).reshape(-1, 3)
        fv = np.asarray(fluid_velocities, np.float64).reshape(-1, 3)
        self.removed_inside_solid = 0
        if len(fx) and self.boundary.count:
            # fluid overlapping a boundary particle (closer than 0.9 spacing) is removed
            keep = ~passes.near_boundary(fx, self.boundary, self.cells, 0.9 * config.spacing, config.precision)
            self.removed_inside_solid = int((~keep).sum())
            fx, fv = fx[keep], fv[keep]
        self._kernel_table = ti.Vector.ndarray(2, float_dtype(config.precision), shape=CUBIC_TABLE_SIZE + 2)
        self._kernel_table.from_numpy(cubic_table_np(h).astype(np.float64 if config.precision == "f64" else np.float32))
        self.fluid = FluidParticles(fx, fv, config.precision)
        self.fluid_mass = config.rest_density * self.fluid_volume  # m = rho_0 V_f, kg
        self._forces = forces.BoundaryForces(self.fluid.capacity)
        capacity = config.max_neighbors
        if capacity is None:
            capacity = neighbors.list_capacity(neighbors.lattice_neighbor_count(config.spacing, h))
        self.neighborhoods = Neighborhoods(
            self.fluid.capacity, capacity, config.precision, h, store_boundary=self._reads_boundary_lists()
        )
        self._list_capacity: tuple[int, int] | None = None  # a smaller capacity for the next neighbourhood pass
        self.time = 0.0
        self.step_index = 0
        self.stage_times: dict[str, float] | None = None  # set to {} to profile stages
        speeds = np.linalg.norm(fv, axis=1) if len(fv) else np.zeros(1)
        self._max_speed = float(speeds.max())
        self.gravity = ti.Vector(list(config.gravity))

    # -- the time step -------------------------------------------------------------------------
    def step(self) -> StepStats:
        """Advance one time step (Algorithm 1; equations as numbered in the module docstring)."""
        stage = self._stage
        fused = self.estimate_in_non_pressure_pass
        dt = self.time_step()  # adapt dt (E10)
        retired = stage("sort", self.sort)  # find N_i: sort by cell
        counts = stage("neighbors", self.find_neighborhoods, dt)  # N_i, rho (E1), alpha (E2); s (E3) or (W1)
        div = stage("divergence_solve", self.divergence_solve, dt)  # correctDivergenceError: (E3)-(E5), (W3)
        if not fused:
            stage("divergence_estimate", self.divergence_estimate)  # D_i, paper Eq. 1 (its own radii)
        stage(
            "non_pressure",
            self.non_pressure_forces,
            dt,
            fused,  # a (E7), v* (E8), warm start (W2),
            div.error_passes > 0,
        )  # [D_i, Eq. 1]; (W2) records written?
        dens = stage("density_solve", self.density_solve, dt)  # correctDensityError: (E6), (E4), (E5),
        self._max_speed = dens.max_speed  # (W3); x += dt v (E9)
        on_solid, on_walls = stage("forces", self.boundary_forces, dt, div.iterations > 0)  # reactions
        self.time += dt
        stats = StepStats(
            step=self.step_index,
            time=self.time,
            dt=dt,
            density_iterations=dens.iterations,
            density_error=100.0 * dens.error,
            divergence_iterations=div.iterations,
            divergence_error=100.0 * div.error * dt,
            max_speed=dens.max_speed,
            nonfinite=dens.nonfinite,
            retired=retired,
            active=self.fluid.active,
            max_fluid_neighbors=counts.fluid,
            max_boundary_neighbors=counts.boundary,
            solid_force_x=float(on_solid[0]),
            solid_force_y=float(on_solid[1]),
            solid_force_z=float(on_solid[2]),
            wall_force_x=float(on_walls[0]),
            wall_force_y=float(on_walls[1]),
            wall_force_z=float(on_walls[2]),
        )
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

    def time_step(self) -> float:
        """This step's dt, s: ``config.dt``, or (E10) from the fastest speed at the end of the last step."""
        cfg = self.config
        if cfg.time_step == "fixed":
            return cfg.dt
        if self.step_index == 0 or self._max_speed <= 0.0:
            return min(max(cfg.dt, cfg.dt_min), cfg.dt_max)
        return min(max(cfg.cfl_factor * cfg.spacing / self._max_speed, cfg.dt_min), cfg.dt_max)

    def sort(self) -> int:
        """The grid stage: the counting sort of the active fluid by cell; returns the particles retired."""
        if self.fluid.active == 0:
            return 0
        return passes.sort_fluid(self.fluid, self.cells, self._retire_min, self._retire_max)

    @property
    def estimate_in_non_pressure_pass(self) -> bool:
        """Whether paper Eq. 1 can use the stored gradients (h_k = h <= h_r), fused into the non-pressure pass."""
        return self._estimate_path() == estimator.FROM_GRADIENTS

    def _estimate_path(self) -> str:
        """The fast path of paper Eq. 1 (:func:`fluidsim.estimator.estimate_path`)."""
        cfg = self.config
        return estimator.estimate_path(self.h, cfg.estimator_radius, cfg.estimator_kernel_radius)

    def _reads_boundary_lists(self) -> bool:
        """Whether a pass reads the boundary pairs: the fluid-boundary viscosity, or Eq. 1 walking the lists."""
        return self.config.wall_viscosity != 0.0 or self._estimate_path() == estimator.FROM_LISTS

    def find_neighborhoods(self, dt: float | None = None) -> NeighborCounts:
        """Neighbour lists, rho_i (E1), alpha_i (E2) and the divergence solver's cold source (E3) or warm start (W1),
        growing the lists (and running the pass again) until every neighbour fits; ``dt`` defaults to
        ``config.dt``. Returns the largest counts."""
        f, nb = self.fluid, self.neighborhoods
        dt = self.config.dt if dt is None else dt
        warm = self.warm.divergence
        if self._list_capacity is not None:  # shrink planned by the last pass (its lists were still in use)
            nb.resize(*self._list_capacity)
            self._list_capacity = None
        while True:
            max_f, max_b, too_far = passes.neighborhood_pass(
                f, self.boundary, nb, self.cells, self._kernel_table, self.h, self.fluid_volume, dt, warm
            )
            need_b = max_b if nb.store_boundary else 0
            if not too_far and max_f <= nb.fluid_capacity and need_b <= nb.boundary_capacity:
                self._plan_list_capacity(max_f, need_b)
                return NeighborCounts(max_f, max_b)
            if warm:  # the pass applied the divergence warm start; the next run applies it again
                passes.undo_divergence_warm_start(f)
            if too_far:
                log.info(
                    "a neighbour's index is over %d from its particle's: the fluid lists switch to the wide "
                    "format (8 bytes per pair) for the rest of the run",
                    neighbors.NARROW_MAX_OFFSET,
                )
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

    def _solve(
        self,
        error,
        known: float | None,
        kappa,
        dt: float,
        tolerance: float,
        store_scale: float,
        min_iterations: int,
        advect: bool = False,
    ) -> SolveResult:
        """The iteration shared by both DFSPH solvers (SPlisHSPlasH's loop).

        Each iteration measures the error (setting the stiffness k_i of a Jacobi update, (E4)) and applies the
        update (E5); the solve ends after the iteration whose measured error is within ``tolerance``, once at
        least ``min_iterations`` ran, or after ``config.max_iterations``. The last update also stores the
        warm-start memory (W3) and, with ``advect``, moves the particles (E9) (:func:`fluidsim.passes.finish_solve`).

        Args:
            error: ``error()`` runs an error pass and returns the average error.
            known: the first average error when the start already measured it (the cold divergence solve reads it
                from the neighbourhood pass), else None.
            kappa: the warm-start memory the solve stores at its end (summed stiffness x ``store_scale``).
        """
        f, nb = self.fluid, self.neighborhoods
        iterations = error_passes = 0
        while True:
            if known is None:
                err = error()
                error_passes += 1
            else:
                err, known = known, None
            iterations += 1
            if (err <= tolerance and iterations >= min_iterations) or iterations >= self.config.max_iterations:
                max_speed, bad = passes.finish_solve(f, nb, dt, store_scale, kappa, advect)
                return SolveResult(iterations, float(err), max_speed, bad, error_passes)
            passes.velocity_update(f, nb, dt)

    def divergence_solve(self, dt: float) -> SolveResult:
        """correctDivergenceError: the divergence-free solver, D(rho/rho_0)/Dt -> 0 ((E3)-(E5), (W3)); its error is
        the average s_i, 1/s."""
        if not self.config.divergence_solver or self.fluid.active == 0:
            return SolveResult(0, 0.0)
        # Tolerance on the average D(rho/rho_0)/Dt such that one dt changes the density by eta.
        tol = self.config.max_divergence_error * 0.01 / dt
        inv_quantum = inverse_quantum(tol)  # the error averages are fixed-point sums, exact to 2^-21 tol
        f, nb = self.fluid, self.neighborhoods
        # A warm start (W1) happened in the neighbourhood pass; a cold one takes its first s_i from there.
        known = None if self.warm.divergence else passes.divergence_solve_cold_start(f, dt, inv_quantum)

        def error() -> float:  # also writes the density solver's warm-start records (W2) from this source
            return passes.divergence_solve_error(f, nb, dt, inv_quantum, self.warm.density, self.gravity)

        return self._solve(error, known, f.kappa_divergence, dt, tol, dt, self.config.min_divergence_iterations)

    def density_solve(self, dt: float) -> SolveResult:
        """correctDensityError: the constant-density solver, rho* -> rho_0 ((E6), (E4), (E5), (W3)), ending with the
        advection x += dt v (E9); its error is the average max(rho*_i - 1, 0). The non-pressure pass predicted v*
        and applied the warm start (W2)."""
        f, nb = self.fluid, self.neighborhoods
        if f.active == 0:
            return SolveResult(0, 0.0)
        tol = self.config.max_density_error * 0.01
        inv_quantum = inverse_quantum(tol)
        return self._solve(
            lambda: passes.density_solve_error(f, nb, dt, inv_quantum),
            None,
            f.kappa_density,
            dt,
            tol,
            dt * dt,
            self.config.min_iterations,
            advect=True,
        )

    def boundary_forces(self, dt: float, divergence_ran: bool) -> tuple[np.ndarray, np.ndarray]:
        """The step's force of the fluid on the solid and on the walls, N ((3,), (3,); :mod:`fluidsim.forces`),
        from the stiffness both solvers stored this step and the non-pressure pass's boundary viscosity."""
        return forces.boundary_forces(self.fluid, self.neighborhoods, self._forces, dt, self.fluid_mass, divergence_ran)

    def divergence_estimate(self) -> None:
        """Paper Eq. 1 as a pass of its own (:func:`fluidsim.passes.divergence_estimate`; the step fuses the
        stored-gradient case into the non-pressure pass)."""
        cfg, f = self.config, self.fluid
        if f.active == 0:
            return
        passes.divergence_estimate(
            f,
            self.boundary,
            self.neighborhoods,
            self.cells,
            self.h,
            cfg.estimator_radius,
            cfg.estimator_kernel_radius,
            self.fluid_volume,
        )

    def non_pressure_forces(self, dt: float, estimate: bool = False, records_written: bool = False) -> None:
        """Gravity and viscosity (E7), v*_i = v_i + dt a_i (E8), with the density solver's warm start (W2) (and, with
        ``estimate``, paper Eq. 1 from the stored gradients) in one sweep
        (:func:`fluidsim.passes.predict_velocities`).

        Args:
            dt: s. estimate: compute paper Eq. 1 in the same sweep (valid when
                :attr:`estimate_in_non_pressure_pass`).
            records_written: this step's divergence error passes already wrote the warm-start records (x_i, w_i) of
                (W2) from their source; otherwise a pass of their own writes them first.
        """
        cfg, f, nb = self.config, self.fluid, self.neighborhoods
        if f.active == 0:
            return
        warm = self.warm.density
        if not records_written:
            passes.density_warm_records(f, nb, dt, warm, self.gravity)
        passes.predict_velocities(
            f,
            self.boundary,
            nb,
            dt,
            self.gravity,
            cfg.viscosity,
            cfg.wall_viscosity,
            cfg.rest_density,
            self.h,
            warm,
            estimate,
        )

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
        return {
            "ids": ids[order],
            "x": f.numpy("x")[order],
            "v": f.numpy("v")[order],
            "divergence": f.numpy("divergence")[order],
            "density": f.numpy("density")[order],
        }

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
