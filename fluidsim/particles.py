"""Particle sets: the fluid (moving, re-sorted every step) and the boundary (static, sorted once).

Each set owns its per-particle arrays. :class:`FluidParticles` knows which arrays carry state from one
step to the next (``PERSISTENT``) and permutes exactly those when the grid sorts the particles, so
no caller keeps a hand-written list of buffers. Arrays are Taichi ndarrays, so kernels compile once
per dtype and never per simulation.
"""

from __future__ import annotations

import numpy as np
import taichi as ti

from .grid import gather_persistent
from .host_copy import rows_to_numpy
from .neighbors import NARROW, WIDE, pair_dtype, unpack_fluid_pairs_np, unpack_pairs_np


def float_dtype(precision: str):
    """Taichi float type for ``"f32"`` or ``"f64"``."""
    return ti.f64 if precision == "f64" else ti.f32


def _vec_ndarray(dtype, n: int):
    return ti.Vector.ndarray(3, dtype, shape=max(n, 1))


class FluidParticles:
    """Per-fluid-particle arrays (N = initial fluid count; retired particles stay at the tail).

    Attributes (Taichi ndarrays of length N):
        x, v: positions (m) and velocities (m/s), vec3.
        ids: the particle's index in the initial fluid set (stable across sorts).
        kappa_density, kappa_divergence: warm-start stiffness of the two DFSPH solvers.
        divergence_sum, divergence_count: run accumulation of D_i (paper Eq. 1).
        density: normalised density rho_i / rho_0. factor: DFSPH factor alpha_i / rho_i (m^2).
        position_stiffness: (x_i, k_i) vec4, the solver's current stiffness with the position it multiplies
            (one record per neighbour for the velocity update). density_record: (x_i, w_i) vec4 with the density
            solver's warm-start stiffness w_i (:func:`fluidsim.dfsph.density_warm_record`), read by the
            non-pressure pass. stiffness_sum, source: solver scratch.
        divergence: D_i of the current step (1/s).
        boundary_viscous, solid_viscous: the viscous acceleration of this step from all the boundary and from the
            solid alone (vec3, m/s^2; :func:`fluidsim.viscosity.predict_velocities`), read by :mod:`fluidsim.forces`.
        push_divergence: the divergence solver's warm-start push P_i of this step (vec3, 1/m times the units of
            kappa; :func:`fluidsim.neighbors.build_neighborhoods`).
        cell_ids, ranks, order: counting-sort scratch.

    The velocities are double-buffered: :meth:`velocity_scratch` is the buffer a pass that reads every
    neighbour's v writes its new velocities to, and :meth:`swap_velocity` makes it ``v``.
    """

    PERSISTENT = ("x", "v", "ids", "kappa_density", "kappa_divergence", "divergence_sum", "divergence_count")

    def __init__(self, positions: np.ndarray, velocities: np.ndarray, precision: str):
        positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        velocities = np.asarray(velocities, dtype=np.float64).reshape(-1, 3)
        if positions.shape != velocities.shape:
            raise ValueError(f"positions {positions.shape} and velocities {velocities.shape} differ in shape")
        fp = float_dtype(precision)
        n = positions.shape[0]
        self.capacity = n
        self.active = n
        self.dtype = fp
        self.x = _vec_ndarray(fp, n)
        self.v = _vec_ndarray(fp, n)
        self.ids = ti.ndarray(ti.i32, shape=max(n, 1))
        self.kappa_density = ti.ndarray(fp, shape=max(n, 1))
        self.kappa_divergence = ti.ndarray(fp, shape=max(n, 1))
        self.divergence_sum = ti.ndarray(ti.f64, shape=max(n, 1))
        self.divergence_count = ti.ndarray(ti.i32, shape=max(n, 1))
        for name in ("density", "factor", "stiffness_sum", "source", "divergence"):
            setattr(self, name, ti.ndarray(fp, shape=max(n, 1)))
        self.position_stiffness = ti.Vector.ndarray(4, fp, shape=max(n, 1))
        self.density_record = ti.Vector.ndarray(4, fp, shape=max(n, 1))
        self.push_divergence = _vec_ndarray(fp, n)
        self.boundary_viscous = _vec_ndarray(fp, n)
        self.solid_viscous = _vec_ndarray(fp, n)
        for name in ("cell_ids", "ranks", "order"):
            setattr(self, name, ti.ndarray(ti.i32, shape=max(n, 1)))
        self._spare = {name: _like(getattr(self, name)) for name in self.PERSISTENT}
        if n:
            self.x.from_numpy(positions.astype(_np_dtype(fp)))
            self.v.from_numpy(velocities.astype(_np_dtype(fp)))
            self.ids.from_numpy(np.arange(n, dtype=np.int32))
            self.order.from_numpy(np.arange(n, dtype=np.int32))

    def permute(self) -> None:
        """Apply ``self.order`` to every persistent array (double-buffered: swap, no copy back), in one kernel
        launch (:func:`gather_persistent`; a launch costs tens of microseconds of thread-pool wake-up)."""
        src = [getattr(self, name) for name in self.PERSISTENT]
        dst = [self._spare[name] for name in self.PERSISTENT]
        gather_persistent(self.order, self.capacity, *[a for pair in zip(src, dst, strict=True) for a in pair])
        for name, a, b in zip(self.PERSISTENT, src, dst, strict=True):
            setattr(self, name, b)
            self._spare[name] = a

    def velocity_scratch(self):
        """The spare velocity buffer (the permutation's target, free between sorts): (N,) vec3 to write."""
        return self._spare["v"]

    def swap_velocity(self) -> None:
        """Make the buffer of :meth:`velocity_scratch` the velocities ``v`` (the old ``v`` becomes the spare)."""
        self.v, self._spare["v"] = self._spare["v"], self.v

    def numpy(self, name: str, active_only: bool = True) -> np.ndarray:
        """A copy of one array as numpy, the active particles first (sorted order, not by id)."""
        return rows_to_numpy(getattr(self, name), self.active if active_only else self.capacity)


class BoundaryParticles:
    """Static boundary particles, sorted by grid cell once, with Akinci et al. 2012 volumes.

    Attributes:
        x: (M,) vec3 positions, metres, in cell order.
        volume: (M,) Akinci volumes V_b = 1 / sum_k W(x_b - x_k), m^3 (filled by the solver setup).
        cell_starts: (num_cells + 1,) first slot of each cell.
        solid: (M,) i32, 1 for a particle of the solid (whose force :mod:`fluidsim.forces` reports), 0 for a wall.
        solid_count: how many are solid.
    """

    def __init__(
        self,
        positions_sorted: np.ndarray,
        cell_starts: np.ndarray,
        precision: str,
        solid_sorted: np.ndarray | None = None,
    ):
        fp = float_dtype(precision)
        m = positions_sorted.shape[0]
        self.count = m
        self.x = _vec_ndarray(fp, m)
        self.volume = ti.ndarray(fp, shape=max(m, 1))
        self.cell_starts = ti.ndarray(ti.i32, shape=cell_starts.shape[0])
        self.solid = ti.ndarray(ti.i32, shape=max(m, 1))
        flags = np.zeros(max(m, 1), np.int32)
        if solid_sorted is not None:
            if len(solid_sorted) != m:
                raise ValueError(f"solid flags ({len(solid_sorted)},) differ from the boundary particles ({m},)")
            flags[:m] = np.asarray(solid_sorted, bool)
        self.solid.from_numpy(flags)
        self.solid_count = int(flags[:m].sum())
        if m:
            self.x.from_numpy(positions_sorted.astype(_np_dtype(fp)))
        self.cell_starts.from_numpy(cell_starts.astype(np.int32))


class Neighborhoods:
    """Fixed-capacity neighbour lists per fluid particle, grown when a particle overflows them.

    A fluid pair stores the neighbour and the scalar c_ij with ``V_j grad W(x_i - x_j, h) = c_ij (x_i - x_j)``
    in one of two formats (:mod:`fluidsim.neighbors`): NARROW, one i32 with the offset j - i and c_ij h^2 as an
    f16 (f32 runs: 4 bytes per pair and pass; c_ij to 11 significant bits, the same for (i, j) and (j, i),
    so the pressure forces stay antisymmetric), or WIDE, an integer 2-vector of the index and the bits of
    c_ij (f64 runs, and f32 runs whose offsets outgrow 16 bits: the solver switches once and logs it).
    Boundary pairs are always WIDE (b, V_b-weighted c_ib). ``boundary_grad_sum`` (vec3 per particle) holds
    sum_b V_b grad W_ib, all the pressure solvers need of the boundary, ``solid_grad_sum`` the same sum over the
    solid's particles alone (for the force on the solid, :mod:`fluidsim.forces`), and ``grad_sum`` the whole
    sum_j V_j grad W_ij + sum_b V_b grad W_ib.

    Attributes:
        fluid_count, boundary_count: (N,) i32 pairs per particle (capped at the capacity).
        fluid_pairs: (N, fluid_capacity) i32 (NARROW) or 2-vectors of i32 / i64 (WIDE).
        boundary_pairs: (N, boundary_capacity) 2-vectors of i32 (f32 runs) or i64 (f64 runs); one unused column
            when ``store_boundary`` is False (no pass reads them; the counts are still kept).
        format: NARROW or WIDE. coef_scale / inv_scale: the factor c_ij is stored with and its inverse.

    The capacities follow the largest counts (:func:`fluidsim.neighbors.list_capacity`): the rows are padded to
    the capacity, and every list pass streams them, so a generous capacity costs time in every pass (64 slots
    against 40 for at most 38 neighbours: a fifth of the step on the bench scene).
    """

    def __init__(self, n: int, capacity: int, precision: str, support_radius: float = 1.0, store_boundary: bool = True):
        self.n = max(n, 1)
        self.store_boundary = bool(store_boundary)
        self.fp = float_dtype(precision)
        self.pair_int = pair_dtype(precision)
        self.format = NARROW if precision == "f32" else WIDE
        self._h2 = float(support_radius) ** 2
        self.fluid_count = ti.ndarray(ti.i32, shape=self.n)
        self.boundary_count = ti.ndarray(ti.i32, shape=self.n)
        self.boundary_grad_sum = ti.Vector.ndarray(3, self.fp, shape=self.n)
        self.grad_sum = ti.Vector.ndarray(3, self.fp, shape=self.n)
        self.solid_grad_sum = ti.Vector.ndarray(3, self.fp, shape=self.n)
        self.fluid_capacity = 0
        self.boundary_capacity = 0
        self.resize(capacity, capacity)

    @property
    def coef_scale(self) -> float:
        return self._h2 if self.format == NARROW else 1.0

    @property
    def inv_scale(self) -> float:
        return 1.0 / self.coef_scale

    def widen(self) -> None:
        """Switch the fluid lists to the WIDE format (offsets beyond 16 bits)."""
        if self.format != WIDE:
            self.format = WIDE
            self._alloc_fluid()

    def _alloc_fluid(self) -> None:
        shape = (self.n, self.fluid_capacity)
        if self.format == NARROW:
            self.fluid_pairs = ti.ndarray(ti.i32, shape=shape)
        else:
            self.fluid_pairs = ti.Vector.ndarray(2, self.pair_int, shape=shape)

    def resize(self, fluid_capacity: int, boundary_capacity: int) -> None:
        if fluid_capacity != self.fluid_capacity:
            self.fluid_capacity = fluid_capacity
            self._alloc_fluid()
        if not self.store_boundary:  # counted, never stored (:func:`fluidsim.neighbors.build_neighborhoods`)
            boundary_capacity = 1
        if boundary_capacity != self.boundary_capacity:
            self.boundary_capacity = boundary_capacity
            self.boundary_pairs = ti.Vector.ndarray(2, self.pair_int, shape=(self.n, boundary_capacity))

    def lists(self, kind: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Decoded lists as numpy, for tests and inspection.

        Args:
            kind: ``"fluid"`` or ``"boundary"``.
        Returns:
            (count (N,), index (N, cap), c (N, cap)); slots past a particle's count are unspecified.
        """
        if kind == "boundary" and not self.store_boundary:
            raise ValueError(
                "these lists keep boundary counts only (no pass reads the pairs: the boundary viscosity "
                "is 0 and Eq. 1 does not walk the lists); use store_boundary=True to keep them"
            )
        count = getattr(self, f"{kind}_count").to_numpy()
        if kind == "fluid":
            index, coef = unpack_fluid_pairs_np(self.fluid_pairs.to_numpy(), self.format, self.inv_scale)
        else:
            index, coef = unpack_pairs_np(self.boundary_pairs.to_numpy())
        return count, index, coef


def _like(arr):
    if isinstance(arr, ti.lang.matrix.VectorNdarray):
        return ti.Vector.ndarray(arr.n, arr.dtype, shape=arr.shape)
    return ti.ndarray(arr.dtype, shape=arr.shape)


def _np_dtype(fp) -> type:
    return np.float64 if fp == ti.f64 else np.float32
