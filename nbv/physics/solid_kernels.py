"""Taichi kernels of :mod:`nbv.physics.solidify` (splatting Gaussians onto the lattice points and edges as
log-transmittance), and the device-side :class:`LeakCounter` of :mod:`nbv.physics.leaks` (fluid particles deep inside
the solid at every step).

The splats' work is flattened: every (Gaussian, lattice point of its sigma box) pair is one work item, so a
few large Gaussians do not leave all but one thread idle. A work item finds its Gaussian by binary
search in the exclusive prefix sum of the box sizes.
"""

import numpy as np
import taichi as ti

from fluidsim.launch import fast_kernel
from nbv.physics.leaks import ProbeLeaks, deep_interior


@fast_kernel
def splat_log_transmittance(
    work_start: ti.i64,
    work_count: ti.i32,
    offsets: ti.types.ndarray(dtype=ti.i64, ndim=1),
    box_lo: ti.types.ndarray(dtype=ti.i32, ndim=2),
    box_dims: ti.types.ndarray(dtype=ti.i32, ndim=2),
    means: ti.types.ndarray(dtype=ti.f64, ndim=2),
    inv_covs: ti.types.ndarray(dtype=ti.f64, ndim=3),
    opacities: ti.types.ndarray(dtype=ti.f64, ndim=1),
    lattice_min: ti.types.vector(3, ti.f64),
    spacing: ti.f64,
    max_alpha: ti.f64,
    log_transmittance: ti.types.ndarray(dtype=ti.f32, ndim=3),
):
    """Add log(1 - o_g exp(-d_g^2 / 2)) of each Gaussian to the lattice points of its sigma box.

    Args:
        work_start, work_count: the range of flattened work items of this call.
        offsets: (G + 1,) exclusive prefix sum of the box sizes (strictly increasing: empty boxes removed).
        box_lo: (G, 3) first lattice index of each box. box_dims: (G, 3) box size in lattice points.
        means: (G, 3) m. inv_covs: (G, 3, 3) inverse covariances, 1/m^2. opacities: (G,).
        lattice_min: lattice point (0, 0, 0), m. spacing: m.
        max_alpha: clamp of o exp(-d^2/2), so that the logarithm stays finite.
        log_transmittance: (X, Y, Z) accumulated sum of logs (atomic adds).
    """
    num_g = offsets.shape[0] - 1
    for t in range(work_count):
        w = work_start + ti.cast(t, ti.i64)
        lo = 0
        hi = num_g
        while hi - lo > 1:  # invariant: offsets[lo] <= w < offsets[hi]
            mid = (lo + hi) // 2
            if offsets[mid] <= w:
                lo = mid
            else:
                hi = mid
        g = lo
        local = w - offsets[g]
        nz = ti.cast(box_dims[g, 2], ti.i64)
        ny = ti.cast(box_dims[g, 1], ti.i64)
        k = ti.cast(local % nz, ti.i32) + box_lo[g, 2]
        rest = local // nz
        j = ti.cast(rest % ny, ti.i32) + box_lo[g, 1]
        i = ti.cast(rest // ny, ti.i32) + box_lo[g, 0]
        d = ti.Vector(
            [
                lattice_min[0] + spacing * i - means[g, 0],
                lattice_min[1] + spacing * j - means[g, 1],
                lattice_min[2] + spacing * k - means[g, 2],
            ],
            ti.f64,
        )
        d2 = ti.cast(0.0, ti.f64)
        for a in ti.static(range(3)):
            for b in ti.static(range(3)):
                d2 += d[a] * inv_covs[g, a, b] * d[b]
        alpha = ti.min(opacities[g] * ti.exp(-0.5 * d2), max_alpha)
        log_transmittance[i, j, k] += ti.cast(ti.log(1.0 - alpha), ti.f32)


@fast_kernel
def splat_edge_log_transmittance(
    work_start: ti.i64,
    work_count: ti.i32,
    axis: ti.i32,
    offsets: ti.types.ndarray(dtype=ti.i64, ndim=1),
    box_lo: ti.types.ndarray(dtype=ti.i32, ndim=2),
    box_dims: ti.types.ndarray(dtype=ti.i32, ndim=2),
    means: ti.types.ndarray(dtype=ti.f64, ndim=2),
    inv_covs: ti.types.ndarray(dtype=ti.f64, ndim=3),
    opacities: ti.types.ndarray(dtype=ti.f64, ndim=1),
    lattice_min: ti.types.vector(3, ti.f64),
    spacing: ti.f64,
    max_alpha: ti.f64,
    edge_log_transmittance: ti.types.ndarray(dtype=ti.f32, ndim=4),
):
    """Add log(1 - o_g max_t exp(-d_g(x(t))^2 / 2)) of each Gaussian to the lattice edges along ``axis`` in its box.

    The edge from point p to p + spacing e_axis is the segment x(t) = p + t spacing e_axis, t in [0, 1]. Along
    it d_g^2 is a convex quadratic in t, smallest at t* = clamp(-(A d)_axis / (spacing A_axis,axis), 0, 1) with
    A = Sigma_g^-1 and d = p - mu_g, so the Gaussian's peak on the edge is exact: o_g exp(-d_g(x(t*))^2 / 2).

    Args:
        work_start, work_count: the range of flattened (Gaussian, edge start point) work items of this call.
        axis: 0, 1 or 2, the direction of the edges.
        offsets: (G + 1,) exclusive prefix sum of the boxes' sizes (strictly increasing).
        box_lo: (G, 3) first edge start point of each box. box_dims: (G, 3) box size in lattice points.
        means: (G, 3) m. inv_covs: (G, 3, 3) 1/m^2. opacities: (G,).
        lattice_min: lattice point (0, 0, 0), m. spacing: m.
        max_alpha: clamp of the peak, so that the logarithm stays finite.
        edge_log_transmittance: (3, X, Y, Z) accumulated sums (atomic adds) per edge start point and axis.
    """
    num_g = offsets.shape[0] - 1
    for t in range(work_count):
        w = work_start + ti.cast(t, ti.i64)
        lo = 0
        hi = num_g
        while hi - lo > 1:  # invariant: offsets[lo] <= w < offsets[hi]
            mid = (lo + hi) // 2
            if offsets[mid] <= w:
                lo = mid
            else:
                hi = mid
        g = lo
        local = w - offsets[g]
        nz = ti.cast(box_dims[g, 2], ti.i64)
        ny = ti.cast(box_dims[g, 1], ti.i64)
        k = ti.cast(local % nz, ti.i32) + box_lo[g, 2]
        rest = local // nz
        j = ti.cast(rest % ny, ti.i32) + box_lo[g, 1]
        i = ti.cast(rest // ny, ti.i32) + box_lo[g, 0]
        d = ti.Vector(
            [
                lattice_min[0] + spacing * i - means[g, 0],
                lattice_min[1] + spacing * j - means[g, 1],
                lattice_min[2] + spacing * k - means[g, 2],
            ],
            ti.f64,
        )
        ad = ti.cast(0.0, ti.f64)
        for b in ti.static(range(3)):
            ad += inv_covs[g, axis, b] * d[b]
        t_star = ti.min(ti.max(-ad / (spacing * inv_covs[g, axis, axis]), 0.0), 1.0)
        for a in ti.static(range(3)):
            if a == axis:
                d[a] += t_star * spacing
        q = ti.cast(0.0, ti.f64)
        for a in ti.static(range(3)):
            for b in ti.static(range(3)):
                q += d[a] * inv_covs[g, a, b] * d[b]
        alpha = ti.min(opacities[g] * ti.exp(-0.5 * q), max_alpha)
        edge_log_transmittance[axis, i, j, k] += ti.cast(ti.log(1.0 - alpha), ti.f32)


@fast_kernel
def flag_deep_inside(
    n: ti.i32,
    x: ti.types.ndarray(ndim=1),
    deep: ti.types.ndarray(dtype=ti.u8, ndim=3),
    lattice_min: ti.types.vector(3, ti.f64),
    inv_spacing: ti.f64,
    slot: ti.i32,
    flags: ti.types.ndarray(dtype=ti.i32, ndim=1),
    counts: ti.types.ndarray(dtype=ti.i32, ndim=1),
):
    """flags[p] = 1 when fluid particle p's nearest lattice point is a deep-interior point of the solid.

    The nearest lattice point is floor((x - lattice_min) / spacing + 1/2) per axis (in float64); points off the
    lattice are not inside. When ``slot`` >= 0 the number of flagged particles is added to ``counts[slot]``.

    Args:
        n: the active fluid particles (the first n of ``x``).
        x: (N,) vec3 positions, m (f32 or f64). deep: (X, Y, Z) 1 at the deep-interior lattice points.
        lattice_min: lattice point (0, 0, 0), m. inv_spacing: 1 / spacing, 1/m.
        slot: index into ``counts`` (the step), or -1 to only write the flags.
        flags: (N,) i32 output. counts: (S,) i32, atomically incremented.
    """
    for p in range(n):
        inside = 0
        i = ti.cast(ti.floor((ti.cast(x[p][0], ti.f64) - lattice_min[0]) * inv_spacing + 0.5), ti.i32)
        j = ti.cast(ti.floor((ti.cast(x[p][1], ti.f64) - lattice_min[1]) * inv_spacing + 0.5), ti.i32)
        k = ti.cast(ti.floor((ti.cast(x[p][2], ti.f64) - lattice_min[2]) * inv_spacing + 0.5), ti.i32)
        if 0 <= i < deep.shape[0] and 0 <= j < deep.shape[1] and 0 <= k < deep.shape[2]:
            inside = ti.cast(deep[i, j, k], ti.i32)
        flags[p] = inside
        if inside != 0 and slot >= 0:
            ti.atomic_add(counts[slot], 1)


class LeakCounter:
    """Counts the fluid particles deep inside a solid lattice at every step of a probe (device-side).

    Args:
        occupancy: [X, Y, Z] bool, the solid lattice (point (i, j, k) at lattice_min + spacing (i, j, k)).
        lattice_min: [3] m. spacing: m.

    Example:
        >>> counter = LeakCounter(solid.occupancy, solid.lattice_min, solid.spacing)
        >>> counter.start(steps)
        >>> run(solver, steps, on_step=lambda s, st: counter.count(s, st.step))
        >>> leaks = counter.finish(solver)
    """

    def __init__(self, occupancy: np.ndarray, lattice_min: np.ndarray, spacing: float):
        occ = np.asarray(occupancy, dtype=bool)
        if occ.ndim != 3 or not occ.size:
            raise ValueError(f"LeakCounter: occupancy must be a non-empty [X, Y, Z] lattice, got shape {occ.shape}")
        if not (np.isfinite(spacing) and spacing > 0):
            raise ValueError(f"LeakCounter: spacing must be > 0 m, got {spacing}")
        self.deep = ti.ndarray(ti.u8, shape=occ.shape)  # one byte per lattice point, held while the probes run
        self.deep.from_numpy(deep_interior(occ).astype(np.uint8))
        self.lattice_min = np.asarray(lattice_min, dtype=np.float64).reshape(3)
        self.spacing = float(spacing)
        self._origin = ti.Vector(self.lattice_min.tolist(), ti.f64)
        self._flags = None
        self._counts = None
        self._steps = self._run = 0

    def start(self, steps: int) -> None:
        """Zero the per-step counters of a probe of ``steps`` steps."""
        self._steps = int(steps)
        self._run = 0  # the steps counted: fewer than ``steps`` when the probe stopped early (nbv.physics.early_stop)
        self._counts = ti.ndarray(ti.i32, shape=max(self._steps, 1))
        self._counts.fill(0)

    def _ensure_flags(self, capacity: int) -> None:
        if self._flags is None or self._flags.shape[0] < capacity:
            self._flags = ti.ndarray(ti.i32, shape=max(capacity, 1))

    def count(self, solver, step: int) -> None:
        """Count the active fluid particles of ``solver`` inside the solid after step ``step`` (0-based)."""
        f = solver.fluid
        if 0 <= step < self._steps:
            self._run = max(self._run, int(step) + 1)
        if f.active == 0 or not 0 <= step < self._steps:
            return
        self._ensure_flags(f.capacity)
        flag_deep_inside(
            f.active, f.x, self.deep, self._origin, 1.0 / self.spacing, int(step), self._flags, self._counts
        )

    def finish(self, solver) -> ProbeLeaks:
        """The final positions and ids, the particles inside at the end, and the per-step counts."""
        if self._counts is None:
            self.start(0)
        f = solver.fluid
        state = solver.fluid_state()
        ids = np.asarray(state["ids"], np.int32)
        x = np.asarray(state["x"], np.float32).reshape(-1, 3)
        leaked = np.zeros(0, np.int32)
        if f.active:
            self._ensure_flags(f.capacity)
            flag_deep_inside(f.active, f.x, self.deep, self._origin, 1.0 / self.spacing, -1, self._flags, self._counts)
            flags = self._flags.to_numpy()[: f.active].astype(bool)
            leaked = np.sort(f.numpy("ids")[flags]).astype(np.int32)
        per_step = self._counts.to_numpy()[: self._run].astype(np.int32)  # the steps the probe ran
        return ProbeLeaks(x_final=x, ids_final=ids, leaked_ids=leaked, per_step=per_step)
