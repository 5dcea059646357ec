"""One thin Python wrapper per pass of the time step: the kernels' argument lists, in one place.

Each kernel takes its arrays one by one, up to 31 of them: explicit ``ti.types.ndarray`` arguments compile once per
dtype and never per simulation, and Taichi 1.7 offers no grouping of arrays that costs nothing. A
``ti.data_oriented`` class passed as ``ti.template()`` cannot hold ndarrays (only fields, which compile per
simulation); a ``ti.types.argpack`` can, but the velocity buffers swap every step, so a pack would be built anew
per launch (measured 0.30 ms against 0.08 ms for three plain arguments, CPU), and a kernel taking two packs failed
to compile; a ``ti.types.struct`` fixes its ``float`` members to f32 where it is declared, before ``ti.init`` picks
the precision. Inside the kernels, the per-pair work takes its inputs grouped (the neighbourhood pass's visitor
context in :mod:`fluidsim.neighbors`, bound at compile time, which costs nothing). The wrappers here take the
owners of those arrays instead, :class:`~fluidsim.particles.FluidParticles`,
:class:`~fluidsim.particles.BoundaryParticles`, :class:`~fluidsim.particles.Neighborhoods` and :class:`FluidGrid`,
and spell the argument lists out once (in the manner of gsplat's ``_wrapper.py``), so
:meth:`fluidsim.solver.DFSPHSolver.step` reads like Algorithm 1 of Bender & Koschier. They hold no state and add
one Python call per launch (well under a microsecond against a launch's ~45 us).

The equation numbers (E1)-(E10), (W1)-(W3) are those of :mod:`fluidsim.solver`'s docstring.
"""

from __future__ import annotations

import math

import numpy as np
import taichi as ti

from . import dfsph, estimator, grid, neighbors, viscosity
from .grid import GridSpec
from .particles import BoundaryParticles, FluidParticles, Neighborhoods, float_dtype


class FluidGrid:
    """The simulation grid as kernels take it, with the fluid's cell index that each step's counting sort rebuilds.

    Args:
        spec: the grid (:func:`fluidsim.grid.grid_for_box`).

    Attributes:
        spec: the grid. origin: vec3 f64, m. inv_cell: vec3 f64, 1 / cell size per axis, 1/m. dims: ivec3 cells.
        starts: (num_cells + 2,) i32, the first fluid slot of each cell after the sort.
        counts, block_sums: the sort's scratch (the counts are left zero for the next sort).
        serial: whether the sort's ranks and prefix sum run on the launching thread (CPU).
    """

    def __init__(self, spec: GridSpec):
        self.spec = spec
        self.origin = ti.Vector(list(spec.origin), ti.f64)
        self.inv_cell = ti.Vector(list(spec.inv_cell), ti.f64)
        self.dims = grid.ivec3(*spec.dims)
        self.counts = ti.ndarray(ti.i32, shape=spec.num_cells + 1)
        self.counts.fill(0)
        self.starts = ti.ndarray(ti.i32, shape=spec.num_cells + 2)
        self.block_sums = ti.ndarray(ti.i32, shape=grid.SCAN_BLOCKS)
        self.serial = grid.serial_sort()


# -- set-up -----------------------------------------------------------------------------------------
def boundary_volumes(boundary: BoundaryParticles, g: FluidGrid, h: float) -> None:
    """Akinci volumes V_b = 1 / sum_k W(x_b - x_k, h) into ``boundary.volume``
    (:func:`fluidsim.neighbors.compute_boundary_volumes`)."""
    neighbors.compute_boundary_volumes(
        boundary.x, boundary.cell_starts, boundary.count, g.origin, g.inv_cell, g.dims, h, boundary.volume
    )


def near_boundary(
    points: np.ndarray, boundary: BoundaryParticles, g: FluidGrid, radius: float, precision: str
) -> np.ndarray:
    """(K,) bool: which of the (K, 3) ``points`` (m) lie closer than ``radius`` (m, <= the x-y cell size) to a
    boundary particle (:func:`fluidsim.neighbors.flag_near_boundary`)."""
    fp = float_dtype(precision)
    tmp = ti.Vector.ndarray(3, fp, shape=len(points))
    tmp.from_numpy(points.astype(np.float64 if fp == ti.f64 else np.float32))
    flags = ti.ndarray(ti.i32, shape=len(points))
    neighbors.flag_near_boundary(
        len(points), tmp, boundary.x, boundary.cell_starts, g.origin, g.inv_cell, g.dims, radius, flags
    )
    return flags.to_numpy() != 0


# -- the time step ----------------------------------------------------------------------------------
def sort_fluid(fluid: FluidParticles, g: FluidGrid, retire_min, retire_max) -> int:
    """Counting sort of the active fluid by cell (``g.starts`` then indexes it) and the permutation of every
    persistent array; fluid outside [retire_min, retire_max] (vec3 f64, m) is retired to the tail.
    Returns the number of particles retired."""
    kept = grid.counting_sort(
        fluid.x,
        fluid.active,
        fluid.capacity,
        g.origin,
        g.inv_cell,
        g.dims,
        retire_min,
        retire_max,
        fluid.cell_ids,
        fluid.ranks,
        g.counts,
        g.starts,
        g.block_sums,
        fluid.order,
        g.serial,
    )
    fluid.permute()
    retired = fluid.active - int(kept)
    fluid.active = int(kept)
    return retired


def neighborhood_pass(
    fluid: FluidParticles,
    boundary: BoundaryParticles,
    lists: Neighborhoods,
    g: FluidGrid,
    kernel_table,
    h: float,
    fluid_volume: float,
    dt: float,
    warm: bool,
) -> tuple[int, int, int]:
    """N_i, rho_i (E1), alpha_i (E2), G_i and the divergence solver's cold source s_i (E3), or with ``warm`` its
    warm start (W1) (:func:`fluidsim.neighbors.build_neighborhoods`). Returns (max fluid, max boundary
    neighbour count, 1 if a NARROW list met an offset beyond 16 bits)."""
    counts = neighbors.build_neighborhoods(
        fluid.active,
        fluid.x,
        g.starts,
        boundary.x,
        boundary.volume,
        boundary.solid,
        boundary.cell_starts,
        g.origin,
        g.inv_cell,
        g.dims,
        h,
        fluid_volume,
        lists.fluid_count,
        lists.fluid_pairs,
        lists.boundary_count,
        lists.boundary_pairs,
        lists.boundary_grad_sum,
        lists.solid_grad_sum,
        lists.grad_sum,
        fluid.density,
        fluid.factor,
        fluid.v,
        fluid.source,
        kernel_table,
        int(warm),
        fluid.kappa_divergence,
        fluid.push_divergence,
        lists.format,
        lists.coef_scale,
        dfsph.DIVERGENCE_WARM_SCALE,
        dt,
        fluid.stiffness_sum,
        lists.store_boundary,
    )
    return int(counts[0]), int(counts[1]), int(counts[2])


def undo_divergence_warm_start(fluid: FluidParticles) -> None:
    """Takes back the push (W1) of a neighbourhood pass that must run again (:func:`fluidsim.dfsph.undo_push`)."""
    dfsph.undo_push(fluid.active, dfsph.DIVERGENCE_WARM_SCALE, fluid.push_divergence, fluid.v)


def divergence_solve_cold_start(fluid: FluidParticles, dt: float, inv_quantum: float) -> float:
    """The divergence solver's first k_i (E4) from the neighbourhood pass's s_i; returns the average s_i, 1/s
    (:func:`fluidsim.dfsph.divergence_solve_cold_start`)."""
    return dfsph.divergence_solve_cold_start(
        fluid.active,
        dt,
        fluid.source,
        fluid.factor,
        fluid.x,
        fluid.position_stiffness,
        fluid.stiffness_sum,
        inv_quantum,
    )


def divergence_solve_error(
    fluid: FluidParticles, lists: Neighborhoods, dt: float, inv_quantum: float, warm_density: bool, gravity
) -> float:
    """Divergence solver error pass: s_i (E3) and k_i (E4), and the density solver's warm-start records (W2);
    returns the average s_i, 1/s (:func:`fluidsim.dfsph.divergence_solve_error`)."""
    return dfsph.divergence_solve_error(
        fluid.active,
        dt,
        fluid.x,
        fluid.v,
        lists.fluid_count,
        lists.fluid_pairs,
        lists.format,
        lists.inv_scale,
        lists.boundary_count,
        lists.grad_sum,
        fluid.factor,
        fluid.source,
        fluid.position_stiffness,
        inv_quantum,
        int(warm_density),
        gravity,
        fluid.density,
        lists.boundary_grad_sum,
        fluid.kappa_density,
        fluid.density_record,
    )


def density_solve_error(fluid: FluidParticles, lists: Neighborhoods, dt: float, inv_quantum: float) -> float:
    """Density solver error pass: rho*_i (E6) and k_i (E4); returns the average max(rho*_i - 1, 0)
    (:func:`fluidsim.dfsph.density_solve_error`)."""
    return dfsph.density_solve_error(
        fluid.active,
        dt,
        fluid.x,
        fluid.v,
        lists.fluid_count,
        lists.fluid_pairs,
        lists.format,
        lists.inv_scale,
        lists.grad_sum,
        fluid.density,
        fluid.factor,
        fluid.source,
        fluid.position_stiffness,
        inv_quantum,
    )


def velocity_update(fluid: FluidParticles, lists: Neighborhoods, dt: float) -> None:
    """v_i -= dt (k_i G_i + sum_j k_j g_ij) (E5), summing k_i (:func:`fluidsim.dfsph.apply_stiffness`)."""
    dfsph.apply_stiffness(
        fluid.active,
        dt,
        fluid.v,
        lists.fluid_count,
        lists.fluid_pairs,
        lists.format,
        lists.inv_scale,
        lists.grad_sum,
        fluid.position_stiffness,
        fluid.stiffness_sum,
    )


def finish_solve(
    fluid: FluidParticles, lists: Neighborhoods, dt: float, store_scale: float, kappa, advect: bool
) -> tuple[float, int]:
    """A solve's last velocity update (E5), its warm-start memory kappa = (sum k_i) ``store_scale`` (W3) and, with
    ``advect``, x_i += dt v_i (E9) (:func:`fluidsim.dfsph.finish_solve`). Returns (max speed m/s, non-finite
    velocities) with ``advect``, else (0, 0)."""
    out = dfsph.finish_solve(
        fluid.active,
        dt,
        fluid.v,
        lists.fluid_count,
        lists.fluid_pairs,
        lists.format,
        lists.inv_scale,
        lists.grad_sum,
        fluid.position_stiffness,
        fluid.stiffness_sum,
        store_scale,
        kappa,
        int(advect),
        fluid.x,
    )
    return float(out[0]), int(out[1])


def density_warm_records(fluid: FluidParticles, lists: Neighborhoods, dt: float, warm: bool, gravity) -> None:
    """The density solver's warm-start records (x_i, w_i) (W2) as a pass of their own, for a step whose divergence
    solve ran no error pass (:func:`fluidsim.dfsph.density_warm_stiffness`)."""
    dfsph.density_warm_stiffness(
        fluid.active,
        dt,
        int(warm),
        gravity,
        fluid.x,
        fluid.density,
        fluid.source,
        lists.boundary_grad_sum,
        fluid.kappa_density,
        fluid.density_record,
    )


def predict_velocities(
    fluid: FluidParticles,
    boundary: BoundaryParticles,
    lists: Neighborhoods,
    dt: float,
    gravity,
    mu: float,
    mu_boundary: float,
    rest_density: float,
    h: float,
    warm: bool,
    estimate: bool,
) -> None:
    """a_i (E7), v*_i = v_i + dt a_i (E8) with the density warm start (W2) and, with ``estimate``, paper Eq. 1, in
    one sweep (:func:`fluidsim.viscosity.predict_velocities`) into the spare velocity buffer, which then
    becomes ``fluid.v``."""
    viscosity.predict_velocities(
        fluid.active,
        fluid.capacity,
        dt,
        gravity,
        mu,
        mu_boundary,
        rest_density,
        h,
        fluid.x,
        fluid.v,
        fluid.density,
        fluid.density_record,
        boundary.x,
        boundary.solid,
        lists.fluid_count,
        lists.fluid_pairs,
        lists.format,
        lists.inv_scale,
        lists.boundary_count,
        lists.boundary_pairs,
        lists.boundary_grad_sum,
        lists.grad_sum,
        int(estimate),
        fluid.divergence,
        fluid.divergence_sum,
        fluid.divergence_count,
        int(warm),
        fluid.stiffness_sum,
        fluid.velocity_scratch(),
        fluid.boundary_viscous,
        fluid.solid_viscous,
    )
    fluid.swap_velocity()


def divergence_estimate(
    fluid: FluidParticles,
    boundary: BoundaryParticles,
    lists: Neighborhoods,
    g: FluidGrid,
    h: float,
    h_r: float,
    h_k: float,
    fluid_volume: float,
) -> None:
    """Paper Eq. 1 as a pass of its own (:mod:`fluidsim.estimator`), by the path its radii allow: the stored
    gradients (h_k = h <= h_r), the lists filtered to h_r (h_r <= h), or the grid walked to h_r."""
    path = estimator.estimate_path(h, h_r, h_k)
    if path == estimator.FROM_GRADIENTS:
        estimator.divergence_estimate_from_gradients(
            fluid.active,
            fluid.x,
            fluid.v,
            fluid.density,
            lists.fluid_count,
            lists.fluid_pairs,
            lists.format,
            lists.inv_scale,
            lists.boundary_grad_sum,
            fluid.divergence,
            fluid.divergence_sum,
            fluid.divergence_count,
        )
    elif path == estimator.FROM_LISTS:
        estimator.divergence_estimate_from_lists(
            fluid.active,
            h_r,
            h_k,
            fluid_volume,
            fluid.x,
            fluid.v,
            fluid.density,
            boundary.x,
            boundary.volume,
            lists.fluid_count,
            lists.fluid_pairs,
            lists.format,
            lists.boundary_count,
            lists.boundary_pairs,
            fluid.divergence,
            fluid.divergence_sum,
            fluid.divergence_count,
        )
    else:
        reach = int(math.ceil(h_r / g.spec.cell_size))
        reach_z = int(math.ceil(h_r / g.spec.cell_sizes[2]))
        estimator.divergence_estimate_from_grid(
            fluid.active,
            h_r,
            h_k,
            fluid_volume,
            reach,
            reach_z,
            g.origin,
            g.inv_cell,
            g.dims,
            fluid.x,
            fluid.v,
            fluid.density,
            g.starts,
            boundary.x,
            boundary.volume,
            boundary.cell_starts,
            fluid.divergence,
            fluid.divergence_sum,
            fluid.divergence_count,
        )
