"""Taichi kernels of :mod:`nbv.aggregate`: the cell -> Gaussian lists and the per-step accumulation.

A Gaussian g is listed in every grid cell whose box comes closer than its reach (n r_g) to mu_g, so a
fluid particle only tests the Gaussians listed in its own cell. The lists are built once per run
(counting pass, prefix sum on the host, fill pass) because the Gaussians do not move.
"""

import taichi as ti

ivec3 = ti.types.vector(3, ti.i32)
vec3d = ti.types.vector(3, ti.f64)

# Track modes of :func:`accumulate_tracked`: nothing, one bit per (Gaussian, particle id), or (g, id) keys.
TRACK_NONE = 0
TRACK_BITS = 1
TRACK_KEYS = 2


@ti.func
def cell_range(center, radius, origin, inv_cell, dims):
    """Inclusive range of grid cells overlapped by the box [center - radius, center + radius], clipped."""
    lo = ti.max(ti.floor((center - radius - origin) * inv_cell, ti.i32), 0)
    hi = ti.min(ti.floor((center + radius - origin) * inv_cell, ti.i32), dims - 1)
    return lo, hi


@ti.func
def box_distance2(center, c, origin, cell):
    """Squared distance from ``center`` to the box of cell ``c`` (0 inside)."""
    d2 = ti.cast(0.0, ti.f64)
    for a in ti.static(range(3)):
        lo = origin[a] + cell * c[a]
        hi = lo + cell
        e = ti.max(ti.max(lo - center[a], center[a] - hi), 0.0)
        d2 += e * e
    return d2


@ti.kernel
def list_gaussians(
    centers: ti.types.ndarray(dtype=vec3d, ndim=1),
    reach: ti.types.ndarray(dtype=ti.f64, ndim=1),
    origin: vec3d,
    cell: ti.f64,
    dims: ivec3,
    slack: ti.f64,
    fill: ti.i32,
    cell_counts: ti.types.ndarray(dtype=ti.i32, ndim=1),
    cell_starts: ti.types.ndarray(dtype=ti.i32, ndim=1),
    items: ti.types.ndarray(dtype=ti.i32, ndim=1),
):
    """Counting pass (``fill`` = 0: ``cell_counts[c]`` += 1 per listed Gaussian) or fill pass (``fill`` = 1:
    ``items[cell_starts[c] + k] = g``, with ``cell_counts`` zeroed by the caller and used as cursors).

    A Gaussian is listed in a cell when the cell's box is closer than ``reach[g] + slack`` to its centre;
    the slack (a tiny fraction of a cell) absorbs rounding in the particles' cell assignment.
    """
    inv_cell = 1.0 / cell
    for g in range(centers.shape[0]):
        c = centers[g]
        r = reach[g] + slack
        lo, hi = cell_range(c, r, origin, inv_cell, dims)
        for i, j, k in ti.ndrange((lo[0], hi[0] + 1), (lo[1], hi[1] + 1), (lo[2], hi[2] + 1)):
            if box_distance2(c, ti.Vector([i, j, k]), origin, cell) < r * r:
                lin = (i * dims[1] + j) * dims[2] + k
                slot = ti.atomic_add(cell_counts[lin], 1)
                if fill:
                    items[cell_starts[lin] + slot] = g


# Fixed-point sums: a value v is added as floor(v * VALUE_SCALE + 1/2) in an i64, clamped to +-VALUE_LIMIT quanta (NaN
# adds 0; both are counted as saturated in the extra Gaussian slot G). Integer sums are exact and do
# not depend on the order of the additions, so the per-thread rows give the same bits on any thread count.
VALUE_SCALE = float(2**24)  # quanta per unit of the value: 6e-8 (1/s for D_i)
VALUE_LIMIT = float(2**38)  # largest |v| = 16384 units; a Gaussian's sum holds 2^25 such samples


@ti.func
def fixed_point(v):
    """(quanta, saturated): floor(v * VALUE_SCALE + 1/2) as an i64, clamped to +-VALUE_LIMIT (NaN: 0), and
    saturated = 1 where it was clamped."""
    q = ti.cast(v, ti.f64) * VALUE_SCALE
    quanta = ti.i64(0)
    saturated = ti.i64(1)
    if ti.abs(q) <= VALUE_LIMIT:  # False for NaN
        quanta = ti.cast(ti.floor(q + 0.5), ti.i64)  # halves round up (f32 values below 0.5 can be ties)
        saturated = ti.i64(0)
    elif q > VALUE_LIMIT:
        quanta = ti.cast(VALUE_LIMIT, ti.i64)
    elif q < -VALUE_LIMIT:
        quanta = -ti.cast(VALUE_LIMIT, ti.i64)
    return quanta, saturated


# Layout of the ``grid`` array of :func:`accumulate`: origin (3), 1 / cell, domain_min (3), domain_max (3),
# cell counts (3), offset of the items in ``lists`` (1). One small array, because every kernel argument costs
# launch time, which on small probes is a good part of the aggregation.
GRID_SIZE = 14
vec4d = ti.types.vector(4, ti.f64)


@ti.func
def visit_particle(i, row, xs: ti.template(), values: ti.template(), ids: ti.template(), grid: ti.template(),
                   lists: ti.template(), gauss: ti.template(), add_values: ti.template(), track: ti.template(),
                   private: ti.template(), acc: ti.template(), bits: ti.template(), keys: ti.template(),
                   key_count: ti.template()):
    """Paper Eq. 2-3 for fluid particle i: add ``values[i]`` (fixed point, :func:`fixed_point`) and 1 to row ``row``
    of every Gaussian within reach.

    With ``private`` the row belongs to one thread only: the adds are plain and branch-free (a select on the
    hit), which on a CPU is about twice as fast as an atomic add behind an unpredictable branch.
    """
    x = ti.cast(xs[i], ti.f64)
    inside = True
    for d in ti.static(range(3)):
        if not (grid[4 + d] <= x[d] <= grid[7 + d]):
            inside = False
    c = ti.Vector([0, 0, 0])
    dims = ti.Vector([ti.cast(grid[10], ti.i32), ti.cast(grid[11], ti.i32), ti.cast(grid[12], ti.i32)])
    for d in ti.static(range(3)):
        c[d] = ti.cast(ti.floor((x[d] - grid[d]) * grid[3]), ti.i32)
        if not (0 <= c[d] < dims[d]):
            inside = False
    if inside:
        lin = (c[0] * dims[1] + c[1]) * dims[2] + c[2]
        base = ti.cast(grid[13], ti.i32)
        q, saturated = fixed_point(values[i])
        if ti.static(add_values):
            if saturated:
                if ti.static(private):
                    acc[row, acc.shape[1] - 1, 0] += 1
                else:
                    ti.atomic_add(acc[0, acc.shape[1] - 1, 0], ti.i64(1))
        for s in range(lists[lin], lists[lin + 1]):
            g = lists[base + s]
            p = gauss[g]
            dx, dy, dz = x[0] - p[0], x[1] - p[1], x[2] - p[2]
            hit = dx * dx + dy * dy + dz * dz < p[3]
            if ti.static(add_values and private):
                acc[row, g, 0] = acc[row, g, 0] + ti.select(hit, q, ti.i64(0))
                acc[row, g, 1] = acc[row, g, 1] + ti.select(hit, ti.i64(1), ti.i64(0))
            if hit:
                if ti.static(add_values and not private):
                    ti.atomic_add(acc[0, g, 0], q)
                    ti.atomic_add(acc[0, g, 1], ti.i64(1))
                if ti.static(track == TRACK_BITS):
                    pid = ti.cast(ids[i], ti.i32)
                    ti.atomic_or(bits[g, pid >> 5], ti.cast(1, ti.u32) << ti.cast(pid & 31, ti.u32))
                if ti.static(track == TRACK_KEYS):
                    slot = ti.atomic_add(key_count[0], ti.cast(1, ti.i64))
                    if slot < keys.shape[0]:
                        keys[slot] = (ti.cast(g, ti.i64) << 32) + ti.cast(ids[i], ti.i64)


@ti.func
def visit_all(n, xs: ti.template(), values: ti.template(), ids: ti.template(), grid: ti.template(),
              lists: ti.template(), gauss: ti.template(), add_values: ti.template(), track: ti.template(),
              private: ti.template(), serial: ti.template(), acc: ti.template(), bits: ti.template(),
              keys: ti.template(), key_count: ti.template()):
    """All particles: on the launching thread into row 0 (``serial``), in parallel with each CPU thread adding into
    its own row (``private``: row = the thread's index, so the caller gives at least as many rows as threads),
    or in parallel with atomic adds into row 0 (GPUs)."""
    if ti.static(serial):
        ti.loop_config(serialize=True)
        for i in range(n):
            visit_particle(i, 0, xs, values, ids, grid, lists, gauss, add_values, track, private, acc, bits, keys,
                           key_count)
    else:
        for i in range(n):
            row = 0
            if ti.static(private):
                row = ti.global_thread_idx()
            visit_particle(i, row, xs, values, ids, grid, lists, gauss, add_values, track, private, acc, bits, keys,
                           key_count)


@ti.kernel
def stage_particles(
    n: ti.i32,
    offset: ti.i32,
    xs: ti.types.ndarray(ndim=1),
    values: ti.types.ndarray(ndim=1),
    ids: ti.types.ndarray(dtype=ti.i32, ndim=1),
    staged_x: ti.types.ndarray(ndim=1),
    staged_values: ti.types.ndarray(ndim=1),
    staged_ids: ti.types.ndarray(dtype=ti.i32, ndim=1),
):
    """Copy particles 0..n-1 (positions, values, ids) to slots offset..offset+n-1 of the staging arrays."""
    for i in range(n):
        staged_x[offset + i] = xs[i]
        staged_values[offset + i] = values[i]
        staged_ids[offset + i] = ids[i]


@ti.kernel
def accumulate(
    n: ti.i32,
    xs: ti.types.ndarray(ndim=1),
    values: ti.types.ndarray(ndim=1),
    grid: ti.types.ndarray(dtype=ti.f64, ndim=1),
    lists: ti.types.ndarray(dtype=ti.i32, ndim=1),
    gauss: ti.types.ndarray(dtype=vec4d, ndim=1),
    private: ti.template(),
    serial: ti.template(),
    acc: ti.types.ndarray(dtype=ti.i64, ndim=3),
):
    """Paper Eq. 2-3: each particle i inside the domain adds ``values[i]`` (in quanta of 1 / VALUE_SCALE) to
    ``acc[row, g, 0]`` and 1 to ``acc[row, g, 1]`` for every Gaussian g with |x_i - mu_g|^2 < r_g'^2
    (``gauss[g]`` = (mu_g, (n r_g)^2)); ``acc[row, G, 0]`` counts saturated values.

    ``grid``: see ``GRID_SIZE``. ``lists``: cell starts (cells + 1), then the Gaussian ids of all cells.
    ``private`` (CPUs): ``acc`` has a row per thread of the pool, each thread adds into its own row without
    atomics, and the caller sums the rows; the sums are integers, so the result is bitwise the same for any
    thread count or schedule. Otherwise (GPUs) one row and atomic adds.
    ``serial``: the particles run on the launching thread (row 0), which on small probes costs less than
    waking the thread pool.
    """
    visit_all(n, xs, values, values, grid, lists, gauss, True, TRACK_NONE, private, serial, acc, acc, acc, acc)


@ti.kernel
def accumulate_tracked(
    n: ti.i32,
    xs: ti.types.ndarray(ndim=1),
    values: ti.types.ndarray(ndim=1),
    ids: ti.types.ndarray(ndim=1),
    grid: ti.types.ndarray(dtype=ti.f64, ndim=1),
    lists: ti.types.ndarray(dtype=ti.i32, ndim=1),
    gauss: ti.types.ndarray(dtype=vec4d, ndim=1),
    add_values: ti.template(),
    track: ti.template(),
    private: ti.template(),
    serial: ti.template(),
    acc: ti.types.ndarray(dtype=ti.i64, ndim=3),
    bits: ti.types.ndarray(dtype=ti.u32, ndim=2),
    keys: ti.types.ndarray(dtype=ti.i64, ndim=1),
    key_count: ti.types.ndarray(dtype=ti.i64, ndim=1),
):
    """:func:`accumulate` (when ``add_values``) that also records the ids of the particles near each Gaussian:

    - ``track`` = TRACK_BITS: sets bit ``ids[i]`` of row g of ``bits`` [G, words] (atomic or);
    - ``track`` = TRACK_KEYS: appends ``g * 2^32 + ids[i]`` to ``keys`` (slot from ``key_count[0]``; slots past
      the end are counted but not written, so the caller can grow ``keys`` and run again).

    ``serial``: as in :func:`accumulate`.
    """
    visit_all(n, xs, values, ids, grid, lists, gauss, add_values, track, private, serial, acc, bits, keys,
              key_count)
