"""Uniform-grid neighbour search equals brute force exactly, including corner and edge cells."""

from typing import NamedTuple

import numpy as np
import pytest
import taichi as ti

from fluidsim import grid, neighbors, passes
from fluidsim.grid import brute_force_neighbors_np, cell_index_np, grid_for_box
from fluidsim.kernels import CUBIC_TABLE_SIZE, cubic_grad_w_np, cubic_table_np
from fluidsim.particles import BoundaryParticles, Neighborhoods
from fluidsim.solver import sort_points_by_cell


def _to_nd(a, dtype=ti.f32):
    arr = ti.Vector.ndarray(3, dtype, shape=len(a))
    arr.from_numpy(a.astype(np.float32))
    return arr


def _sorted_on_grid(points, spec, box_min, box_max, capacity=None, serial=False):
    n = len(points)
    capacity = n if capacity is None else capacity
    x = _to_nd(points)
    cell_ids = ti.ndarray(ti.i32, shape=n)
    ranks = ti.ndarray(ti.i32, shape=n)
    counts = ti.ndarray(ti.i32, shape=spec.num_cells + 1)
    starts = ti.ndarray(ti.i32, shape=spec.num_cells + 2)
    order = ti.ndarray(ti.i32, shape=capacity)
    args = (
        ti.Vector(list(spec.origin), ti.f64),
        ti.Vector(list(spec.inv_cell), ti.f64),
        grid.ivec3(*spec.dims),
        ti.Vector(list(box_min), ti.f64),
        ti.Vector(list(box_max), ti.f64),
        cell_ids,
        ranks,
        counts,
    )
    blocks = ti.ndarray(ti.i32, shape=grid.SCAN_BLOCKS)
    counts.fill(0)  # the sort counts into it from zero (its contract: zero on entry)
    kept = grid.counting_sort(x, n, capacity, *args, starts, blocks, order, serial)
    assert not counts.to_numpy().any()  # consumed: ready for the next sort, which clears nothing
    again = grid.counting_sort(x, n, capacity, *args, starts, blocks, order, serial)
    assert again == kept and not counts.to_numpy().any()
    return int(kept), order.to_numpy(), starts.to_numpy(), cell_ids.to_numpy()


@pytest.mark.parametrize("z_split", [1, 2])
def test_counting_sort_is_a_stable_sort_by_cell(z_split):
    rng = np.random.default_rng(0)
    spec = grid_for_box([0, 0, 0], [1, 0.7, 0.5], 0.1, 0.0, z_split)
    pts = rng.uniform([-0.05, 0, 0], [1.05, 0.7, 0.5], (3000, 3))  # a few outside the box -> retired
    kept, order, starts, cell_ids = _sorted_on_grid(pts, spec, [0, 0, 0], [1, 0.7, 0.5])
    ref = cell_index_np(pts, spec)
    np.testing.assert_array_equal(cell_ids, ref)
    expected = np.argsort(ref, kind="stable")
    assert kept == int((ref < spec.num_cells).sum())
    np.testing.assert_array_equal(order[:kept], expected[:kept])
    np.testing.assert_array_equal(np.diff(starts) >= 0, True)
    assert starts[-1] == len(pts)
    # the CPU path (serial ranks, scan and scatter) gives the GPU path's permutation of the kept particles and its
    # starts (slots past n: identity); the particles retired now are the same, in an order that depends on thread
    # timing in the parallel sort (nothing reads it)
    gpu = _sorted_on_grid(pts[:2900], spec, [0, 0, 0], [1, 0.7, 0.5], capacity=3000)
    cpu = _sorted_on_grid(pts[:2900], spec, [0, 0, 0], [1, 0.7, 0.5], capacity=3000, serial=True)
    kept2 = cpu[0]
    assert kept2 == gpu[0] and 0 < kept2 < 2900
    np.testing.assert_array_equal(cpu[1][:kept2], gpu[1][:kept2])
    np.testing.assert_array_equal(np.sort(cpu[1][kept2:2900]), np.sort(gpu[1][kept2:2900]))
    np.testing.assert_array_equal(cpu[2], gpu[2])
    np.testing.assert_array_equal(cpu[3], gpu[3])
    for one in (cpu, gpu):
        np.testing.assert_array_equal(one[1][2900:], np.arange(2900, 3000))
    assert grid.serial_sort()  # the tests run on a CPU backend


def test_points_outside_the_grid_are_retired_not_clamped():
    spec = grid_for_box([0, 0, 0], [1, 1, 1], 0.25, 0.0)
    pts = np.array([[0.5, 0.5, 0.5], [1.2, 0.5, 0.5], [-0.01, 0.2, 0.2], [0.99, 0.99, 0.99]])
    ids = cell_index_np(pts, spec)
    assert ids[1] == spec.num_cells and ids[2] == spec.num_cells
    kept, order, _, _ = _sorted_on_grid(pts, spec, [0, 0, 0], [1, 1, 1])
    assert kept == 2
    assert set(order[:2]) == {0, 3}


@pytest.mark.parametrize("fmt", [neighbors.NARROW, neighbors.WIDE])
@pytest.mark.parametrize("z_split", [1, 2])  # 2: the simulation's grid, half-height cells along z
def test_neighbour_lists_equal_brute_force_with_corner_cells(fmt, z_split):
    rng = np.random.default_rng(3)
    h = 0.1
    lo, hi = np.zeros(3), np.array([0.5, 0.4, 0.3])
    spec = grid_for_box(lo, hi, h, 0.0, z_split)  # tight grid: particles fill the corner and edge cells
    assert spec.dims[2] == 3 * z_split
    fluid = rng.uniform(lo, hi, (1500, 3))
    corners = np.array(
        [
            [x, y, z]
            for x in (lo[0] + 1e-4, hi[0] - 1e-4)
            for y in (lo[1] + 1e-4, hi[1] - 1e-4)
            for z in (lo[2] + 1e-4, hi[2] - 1e-4)
        ]
    )
    fluid = np.concatenate([fluid, corners])
    bpts = rng.uniform(lo, hi, (700, 3))
    n = len(fluid)
    kept, order, starts, _ = _sorted_on_grid(fluid, spec, lo, hi)
    assert kept == n
    xs = fluid[order]
    bcells = cell_index_np(bpts, spec)
    border = np.argsort(bcells, kind="stable")
    bx = bpts[border]
    bstarts = np.concatenate([[0], np.cumsum(np.bincount(bcells, minlength=spec.num_cells))])
    nb = Neighborhoods(n, 16, "f32", h)  # deliberately small: the caller must grow and retry
    if fmt == neighbors.WIDE:
        nb.widen()
    assert nb.format == fmt
    x_nd, bx_nd = _to_nd(xs), _to_nd(bx)
    bvol = ti.ndarray(ti.f32, shape=len(bx))
    bvol.fill(1.0e-4)
    bst = ti.ndarray(ti.i32, shape=len(bstarts))
    bst.from_numpy(bstarts.astype(np.int32))
    solid = (np.arange(len(bx)) % 3 == 0).astype(np.int32)  # a third of the boundary is "the solid"
    bsolid = ti.ndarray(ti.i32, shape=len(bx))
    bsolid.from_numpy(solid)
    st = ti.ndarray(ti.i32, shape=len(starts))
    st.from_numpy(starts.astype(np.int32))
    dens, fac = ti.ndarray(ti.f32, shape=n), ti.ndarray(ti.f32, shape=n)
    bsum, gsum = ti.Vector.ndarray(3, ti.f32, shape=n), ti.Vector.ndarray(3, ti.f32, shape=n)
    solid_sum = ti.Vector.ndarray(3, ti.f32, shape=n)
    vel = rng.normal(0.0, 1.0, (n, 3)).astype(np.float32)
    v_nd, src = _to_nd(vel), ti.ndarray(ti.f32, shape=n)
    args = (
        ti.Vector(list(spec.origin), ti.f64),
        ti.Vector(list(spec.inv_cell), ti.f64),
        grid.ivec3(*spec.dims),
        h,
        1.0e-4,
    )
    table = ti.Vector.ndarray(2, ti.f32, shape=CUBIC_TABLE_SIZE + 2)
    table.from_numpy(cubic_table_np(h).astype(np.float32))
    kappa = rng.uniform(0.0, 2.0, n).astype(np.float32)  # the divergence solver's stored stiffness
    kappa_nd = ti.ndarray(ti.f32, shape=n)
    kappa_nd.from_numpy(kappa)
    push = ti.Vector.ndarray(3, ti.f32, shape=n)
    ssum = ti.ndarray(ti.f32, shape=n)

    def build(warm: int):  # the kernel's argument list, spelt out once
        return neighbors.build_neighborhoods(
            n,
            x_nd,
            st,
            bx_nd,
            bvol,
            bsolid,
            bst,
            *args,
            nb.fluid_count,
            nb.fluid_pairs,
            nb.boundary_count,
            nb.boundary_pairs,
            bsum,
            solid_sum,
            gsum,
            dens,
            fac,
            v_nd,
            src,
            table,
            warm,
            kappa_nd,
            push,
            nb.format,
            nb.coef_scale,
            0.5,
            0.002,
            ssum,
            True,
        )

    while True:
        m = build(0)
        assert m[2] == 0  # no offset beyond 16 bits among 1,508 particles
        if m[0] <= nb.fluid_capacity and m[1] <= nb.boundary_capacity:
            break
        nb.resize(int(m[0]), int(m[1]))
    fc, fi, fcoef = nb.lists("fluid")
    bc, bi, bcoef = nb.lists("boundary")
    x32 = xs.astype(np.float32).astype(np.float64)
    b32 = bx.astype(np.float32).astype(np.float64)
    ref_f = brute_force_neighbors_np(x32, x32, h, exclude_self=True)
    ref_b = brute_force_neighbors_np(x32, b32, h, exclude_self=False)
    for i in range(n):
        np.testing.assert_array_equal(np.sort(fi[i, : fc[i]]), ref_f[i], err_msg=f"fluid neighbours of {i}")
        np.testing.assert_array_equal(np.sort(bi[i, : bc[i]]), ref_b[i], err_msg=f"boundary neighbours of {i}")
    # the stored coefficients give V grad W: c_ij (x_i - x_j) = V cubic_grad_w(x_i - x_j)
    # (to f32 precision, or to the f16's 11 significant bits in NARROW fluid lists)
    for i in range(0, n, 7):
        for lists, pts, coef in ((fi, x32, fcoef), (bi, b32, bcoef)):
            cnt = fc[i] if lists is fi else bc[i]
            r = x32[i] - pts[lists[i, :cnt]]
            rtol = 5e-4 if lists is fi and fmt == neighbors.NARROW else 1e-4
            np.testing.assert_allclose(
                coef[i, :cnt, None] * r,
                1.0e-4 * cubic_grad_w_np(r, h),
                rtol=rtol,
                atol=1e-6 * 1.0e-4 * 48 / np.pi / h**4,
            )
    # the stored boundary gradient sum = the numpy sum of V_b grad W over the brute-force neighbours
    ref_sum = np.array([1.0e-4 * cubic_grad_w_np(x32[i] - b32[ref_b[i]], h).sum(0) for i in range(n)])
    assert np.abs(ref_sum).max() > 0  # some particles do see the boundary
    np.testing.assert_allclose(bsum.to_numpy(), ref_sum, rtol=1e-4, atol=1e-5 * np.abs(ref_sum).max())
    # ... and over the solid's particles alone (the force on the solid, fluidsim.forces)
    ref_solid = np.array(
        [1.0e-4 * cubic_grad_w_np(x32[i] - b32[ref_b[i][solid[ref_b[i]] == 1]], h).sum(0) for i in range(n)]
    )
    assert 0 < np.abs(ref_solid).max() and np.abs(ref_solid - ref_sum).max() > 0
    np.testing.assert_allclose(solid_sum.to_numpy(), ref_solid, rtol=1e-4, atol=1e-5 * np.abs(ref_sum).max())
    # the divergence source: sum_j (v_i - v_j) . V_f grad W_ij + v_i . sum_b V_b grad W_ib, zero where
    # negative or with fewer than FREE_SURFACE_NEIGHBORS neighbours
    v64 = vel.astype(np.float64)
    ref_src = np.zeros(n)
    for i in range(n):
        g = 1.0e-4 * cubic_grad_w_np(x32[i] - x32[ref_f[i]], h)
        s = np.sum((v64[i] - v64[ref_f[i]]) * g) + v64[i] @ ref_sum[i]
        if s > 0 and len(ref_f[i]) + len(ref_b[i]) >= neighbors.FREE_SURFACE_NEIGHBORS:
            ref_src[i] = s
    assert (ref_src > 0).sum() > n // 4
    np.testing.assert_allclose(src.to_numpy(), ref_src, rtol=1e-3, atol=1e-5 * np.abs(ref_src).max())
    # warm (1): the divergence solver's warm-start push P_i = kappa_i (sum_j g_ij + sum_b g_ib)
    # + sum_j kappa_j g_ij instead of the source; lists, density and factor bit for bit the same
    before = [a.to_numpy() for a in (nb.fluid_pairs, dens, fac, gsum)]
    build(1)
    for a, b in zip(before, (nb.fluid_pairs, dens, fac, gsum), strict=True):
        np.testing.assert_array_equal(a, b.to_numpy())
    k = kappa.astype(np.float64)
    ref_push, ref_gsum = np.zeros((n, 3)), np.zeros((n, 3))
    for i in range(n):
        g = 1.0e-4 * cubic_grad_w_np(x32[i] - x32[ref_f[i]], h)
        ref_gsum[i] = g.sum(0) + ref_sum[i]
        ref_push[i] = k[i] * ref_gsum[i] + (k[ref_f[i], None] * g).sum(0)
    # G_i = sum_j V_f grad W_ij + sum_b V_b grad W_ib (its scale: one neighbour's gradient)
    np.testing.assert_allclose(gsum.to_numpy(), ref_gsum, atol=1e-5 * 1.0e-4 * 48 / np.pi / h**4)
    np.testing.assert_allclose(push.to_numpy(), ref_push, rtol=1e-3, atol=1e-4 * np.abs(ref_push).max())
    # ... and applied: v_i -= 0.5 P_i, the stiffness sum starts at 0.5 kappa_i / dt
    np.testing.assert_allclose(v_nd.to_numpy(), vel - 0.5 * push.to_numpy(), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(ssum.to_numpy(), 0.5 * kappa / 0.002, rtol=1e-6)
    # the relation is symmetric, and so are the stored coefficients, bit for bit (antisymmetric forces)
    pairs = {(i, j): fcoef[i, k] for i in range(n) for k, j in enumerate(fi[i, : fc[i]])}
    assert all(pairs.get((j, i)) == c for (i, j), c in pairs.items())


class _Walked(NamedTuple):
    i: object
    r2: object
    count_f: object
    sum_f: object
    count_b: object
    sum_b: object


@ti.func
def _count_within(s: ti.template(), j, r, ctx: ti.template()):
    if r.dot(r) < ctx.r2:
        if ti.static(s == 0):
            if j != ctx.i:
                ctx.count_f += 1
                ctx.sum_f += j
        else:
            ctx.count_b += 1
            ctx.sum_b += j


@ti.kernel
def _walk_counts(
    n: ti.i32,
    x: ti.types.ndarray(ndim=1),
    starts: ti.types.ndarray(dtype=ti.i32, ndim=1),
    bx: ti.types.ndarray(ndim=1),
    bstarts: ti.types.ndarray(dtype=ti.i32, ndim=1),
    origin: ti.types.vector(3, ti.f64),
    inv_cell: ti.types.vector(3, ti.f64),
    dims: grid.ivec3,
    reach: ti.i32,
    reach_z: ti.i32,
    radius: float,
    out: ti.types.ndarray(dtype=ti.i32, ndim=2),
):
    for i in range(n):
        count_f, sum_f, count_b, sum_b = 0, 0, 0, 0
        neighbors.for_each_neighbor(
            x[i],
            origin,
            inv_cell,
            dims,
            reach,
            reach_z,
            ((x, starts), (bx, bstarts)),
            _count_within,
            ti.static(_Walked(i, radius * radius, count_f, sum_f, count_b, sum_b)),
        )
        out[i, 0] = count_f
        out[i, 1] = sum_f
        out[i, 2] = count_b
        out[i, 3] = sum_b


@pytest.mark.parametrize("radius_cells", [1.0, 1.7])  # 1.7: the walk reaches 2 columns (and 4 half-cells) out
def test_neighbour_walk_visits_each_candidate_once(radius_cells):
    """for_each_neighbor over two point sets, with a wider reach and at the grid's faces and corners: the
    candidates within the radius are exactly the brute-force ones (count and index sum; a clamped cell would
    count a candidate twice), and the fluid-in-solid test built on it equals brute force."""
    rng = np.random.default_rng(4)
    cell = 0.1
    spec = grid_for_box([0, 0, 0], [0.6, 0.5, 0.4], cell, 0.0, 2)
    radius = radius_cells * cell
    pts = rng.uniform([0, 0, 0], [0.6, 0.5, 0.4], (700, 3))
    pts[:8] = [
        [0, 0, 0],
        [0.6 - 1e-6, 0.5 - 1e-6, 0.4 - 1e-6],
        [0, 0.5 - 1e-6, 0],
        [0.3, 0.0, 0.4 - 1e-6],
        [0.6 - 1e-6, 0, 0],
        [0, 0, 0.2],
        [0.3, 0.25, 0.2],
        [0.3, 0.25, 0.2001],
    ]
    bpts = rng.uniform([0, 0, 0], [0.6, 0.5, 0.4], (300, 3))
    fx, fstarts, dropped, _ = sort_points_by_cell(pts, spec)
    bx, bstarts, bdropped, _ = sort_points_by_cell(bpts, spec)
    assert dropped == bdropped == 0
    st, bst = ti.ndarray(ti.i32, shape=len(fstarts)), ti.ndarray(ti.i32, shape=len(bstarts))
    st.from_numpy(fstarts.astype(np.int32))
    bst.from_numpy(bstarts.astype(np.int32))
    out = ti.ndarray(ti.i32, shape=(len(fx), 4))
    reach = int(np.ceil(radius / spec.cell_size))
    reach_z = int(np.ceil(radius / spec.cell_sizes[2]))
    assert (reach, reach_z) == ((1, 2) if radius_cells == 1.0 else (2, 4))
    _walk_counts(
        len(fx),
        _to_nd(fx),
        st,
        _to_nd(bx),
        bst,
        ti.Vector(list(spec.origin), ti.f64),
        ti.Vector(list(spec.inv_cell), ti.f64),
        grid.ivec3(*spec.dims),
        reach,
        reach_z,
        radius,
        out,
    )
    got = out.to_numpy()
    x32, b32 = fx.astype(np.float32).astype(np.float64), bx.astype(np.float32).astype(np.float64)
    ref_f = brute_force_neighbors_np(x32, x32, radius, exclude_self=True)
    ref_b = brute_force_neighbors_np(x32, b32, radius, exclude_self=False)
    np.testing.assert_array_equal(got[:, 0], [len(r) for r in ref_f])
    np.testing.assert_array_equal(got[:, 1], [int(np.sum(r)) for r in ref_f])
    np.testing.assert_array_equal(got[:, 2], [len(r) for r in ref_b])
    np.testing.assert_array_equal(got[:, 3], [int(np.sum(r)) for r in ref_b])
    assert got[:, 0].min() > 0 and got[:, 2].max() > 3
    if radius_cells == 1.0:  # the overlap test (radius <= the x-y cell) walks the same way
        boundary = BoundaryParticles(bx, bstarts, "f32")
        near = passes.near_boundary(fx, boundary, passes.FluidGrid(spec), 0.6 * cell, "f32")
        np.testing.assert_array_equal(near, [len(r) > 0 for r in brute_force_neighbors_np(x32, b32, 0.6 * cell, False)])
        assert 0 < near.sum() < len(fx)
