"""Taichi kernels that build the accumulator's levels once per run (:mod:`nbv.physics.aggregate_levels`): the
per-level cell lists of the Gaussians, and the one ``table`` of the levels' grids that every kernel reads.

The static Gaussians are sorted into a few levels by reach (:func:`nbv.physics.aggregate_levels.plan_levels`); a
level is a uniform grid whose cell is a fraction of the level's largest reach, and a Gaussian of that level is
listed in every cell of it whose box comes closer than its reach to its centre (at most (2 / fraction + 1)^3 cells,
whatever the other levels hold), first the Gaussians that cover the cell, then the others. The lists are built once
per run (counting pass, prefix sum on the host, fill pass); :mod:`nbv.physics.aggregate_kernels` reads them per step
(paper Eq. 2-3).
"""

import taichi as ti

from fluidsim.launch import fast_kernel

vec4d = ti.types.vector(4, ti.f64)

# Layout of the ``table`` [L + 1, TABLE_WIDTH] f64 array. Row 0: domain_min (3), domain_max (3) (the probe's domain
# clipped to the levels' grids), offset of the items in ``lists``, offset of the cell splits in ``lists``. Row 1 + l,
# level l: origin (3), 1 / cell, cell (m), dims (3), offset of the level's first cell in the cell starts. One small
# array, because every kernel argument costs launch time, which on small probes is a good part of the aggregation.
# ``lists``: the start of every cell's items (all levels' cells, then the end), every cell's split, then the items;
# a cell's items are the Gaussians that cover it (every point of the cell within reach) up to its split, then the
# ones that only touch it, each part in ascending order.
TABLE_WIDTH = 9
ITEMS_OFFSET = 6
SPLITS_OFFSET = 7


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


@ti.func
def covers(center, c, origin, cell, slack, reach2):
    """Whether every point of cell ``c``'s box, grown by ``slack``, lies within reach of ``center`` (``reach2``: the
    squared reach the particles are tested against, with a relative margin of 1e-9): every particle that the kernels
    assign to the cell is then a hit, with no test."""
    d2 = ti.cast(0.0, ti.f64)
    for a in ti.static(range(3)):
        lo = origin[a] + cell * c[a] - slack
        hi = lo + cell + 2.0 * slack
        e = ti.max(ti.abs(center[a] - lo), ti.abs(hi - center[a]))
        d2 += e * e
    return d2 * (1.0 + 1e-9) < reach2


@fast_kernel
def list_cells(
    lv: ti.i32,
    reach_cells: ti.i32,
    slack: ti.f64,
    fill: ti.template(),
    gauss: ti.types.ndarray(dtype=vec4d, ndim=1),
    reach: ti.types.ndarray(dtype=ti.f64, ndim=1),
    table: ti.types.ndarray(dtype=ti.f64, ndim=2),
    centres: ti.types.ndarray(dtype=ti.i32, ndim=1),
    cell_counts: ti.types.ndarray(dtype=ti.i32, ndim=1),
    cover_counts: ti.types.ndarray(dtype=ti.i32, ndim=1),
    lists: ti.types.ndarray(dtype=ti.i32, ndim=1),
):
    """Counting pass (``fill`` False: ``cell_counts[c]`` = the Gaussians listed in cell c, ``cover_counts[c]`` = those
    that cover it) or fill pass (``fill`` True: the items of cell c, the cell starts and splits having been written to
    ``lists``) of level ``lv``.

    Each cell gathers its own items (no atomics, sequential writes, items in ascending order): the Gaussians whose
    centre cell lies within ``reach_cells`` cells along each axis (``centres``: the first internal Gaussian of each
    centre cell, the Gaussians being sorted by it), kept when the cell's box is closer than ``reach[g] + slack`` to
    the centre (:func:`covers` tells the covering ones). The slack (a tiny fraction of a cell) absorbs rounding in the
    particles' cell assignment. A centre outside the grid was clipped into it, which only brings its cell closer to
    every cell of the grid.
    """
    origin = ti.Vector([table[lv, 0], table[lv, 1], table[lv, 2]])
    cell = table[lv, 4]
    d0, d1, d2 = ti.cast(table[lv, 5], ti.i32), ti.cast(table[lv, 6], ti.i32), ti.cast(table[lv, 7], ti.i32)
    offset = ti.cast(table[lv, 8], ti.i32)
    items = ti.cast(table[0, ITEMS_OFFSET], ti.i32)
    splits = ti.cast(table[0, SPLITS_OFFSET], ti.i32)
    m = reach_cells
    for t in range(d0 * d1 * d2):
        tc = ti.Vector([t // (d1 * d2), (t // d2) % d1, t % d2])
        found, covering = 0, 0
        start, middle = 0, 0
        if ti.static(fill):
            start = items + lists[offset + t]
            middle = items + lists[splits + offset + t]
        for a in range(ti.max(tc[0] - m, 0), ti.min(tc[0] + m, d0 - 1) + 1):
            for b in range(ti.max(tc[1] - m, 0), ti.min(tc[1] + m, d1 - 1) + 1):
                row = offset + (a * d1 + b) * d2
                k0, k1 = ti.max(tc[2] - m, 0), ti.min(tc[2] + m, d2 - 1)
                for g in range(centres[row + k0], centres[row + k1 + 1]):
                    p = gauss[g]
                    centre = ti.Vector([p[0], p[1], p[2]])
                    r = reach[g] + slack
                    if box_distance2(centre, tc, origin, cell) < r * r:
                        if covers(centre, tc, origin, cell, slack, p[3]):
                            if ti.static(fill):
                                lists[start + covering] = g
                            covering += 1
                        else:
                            if ti.static(fill):
                                lists[middle + found - covering] = g
                        found += 1
        if ti.static(not fill):
            cell_counts[offset + t] = found
            cover_counts[offset + t] = covering


@fast_kernel
def copy_into(src: ti.types.ndarray(dtype=ti.i32, ndim=1), dst: ti.types.ndarray(dtype=ti.i32, ndim=1)):
    """``dst[:len(src)] = src``."""
    for c in range(src.shape[0]):
        dst[c] = src[c]


@fast_kernel
def scatter_cells(
    first: ti.i32,
    last: ti.i32,
    lv: ti.i32,
    slack: ti.f64,
    fill: ti.template(),
    gauss: ti.types.ndarray(dtype=vec4d, ndim=1),
    reach: ti.types.ndarray(dtype=ti.f64, ndim=1),
    table: ti.types.ndarray(dtype=ti.f64, ndim=2),
    cell_counts: ti.types.ndarray(dtype=ti.i32, ndim=1),
    cover_counts: ti.types.ndarray(dtype=ti.i32, ndim=1),
    lists: ti.types.ndarray(dtype=ti.i32, ndim=1),
):
    """:func:`list_cells` for a level of few Gaussians with fine cells (where every cell gathering from its
    neighbourhood would cost more than the Gaussians' own cells): each internal Gaussian first..last-1 of level
    ``lv``, in order on one thread, adds itself to the cells its reach sphere touches (counting pass: ``cell_counts``
    and ``cover_counts`` as in :func:`list_cells`; fill pass: both zeroed by the caller and used as the cursors of the
    partial and the covering part). The items come out in ascending order, the same lists as :func:`list_cells`.
    """
    origin = ti.Vector([table[lv, 0], table[lv, 1], table[lv, 2]])
    inv_cell, cell = table[lv, 3], table[lv, 4]
    dims = ti.Vector([ti.cast(table[lv, 5], ti.i32), ti.cast(table[lv, 6], ti.i32), ti.cast(table[lv, 7], ti.i32)])
    offset = ti.cast(table[lv, 8], ti.i32)
    items = ti.cast(table[0, ITEMS_OFFSET], ti.i32)
    splits = ti.cast(table[0, SPLITS_OFFSET], ti.i32)
    ti.loop_config(serialize=True)
    for g in range(first, last):
        p = gauss[g]
        c = ti.Vector([p[0], p[1], p[2]])
        r = reach[g] + slack
        lo = ti.max(ti.floor((c - r - origin) * inv_cell, ti.i32), 0)
        hi = ti.min(ti.floor((c + r - origin) * inv_cell, ti.i32), dims - 1)
        for i in range(lo[0], hi[0] + 1):
            for j in range(lo[1], hi[1] + 1):
                for k in range(lo[2], hi[2] + 1):
                    cijk = ti.Vector([i, j, k])
                    if box_distance2(c, cijk, origin, cell) < r * r:
                        t = offset + (i * dims[1] + j) * dims[2] + k
                        if covers(c, cijk, origin, cell, slack, p[3]):
                            if ti.static(fill):
                                lists[items + lists[t] + cover_counts[t]] = g
                            else:
                                cell_counts[t] += 1
                            cover_counts[t] += 1
                        else:
                            if ti.static(fill):
                                lists[items + lists[splits + t] + cell_counts[t]] = g
                            cell_counts[t] += 1
