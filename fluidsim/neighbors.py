"""Neighbourhood pass on the uniform grid: neighbour lists, SPH density and the DFSPH factor.

For every active fluid particle i, one pass over the 27 grid cells around it:
- collects fluid neighbours j != i with |x_i - x_j| < h and boundary neighbours b, storing per pair the
  neighbour index and the scalar c_ij with ``V_j grad W_ij = c_ij (x_i - x_j)`` (V_j = m / rho_0 for fluid,
  the Akinci volume for boundary), packed in one 2-vector of integers (the index and the bits of c_ij,
  :func:`pack_pair`); positions do not move until the step's advection, so every later pass rebuilds the
  gradient from x_i - x_j, and reads 8 bytes per pair (f32) instead of 16;
- stores the sum ``sum_b V_b grad W_ib`` (the boundary is static, so every solver pass needs only this sum)
  and the whole sum G_i = sum_j V_j grad W_ij + sum_b V_b grad W_ib (the solver passes then take one term
  out of their per-pair work);
- sums the normalised density (E1) rho_i / rho_0 = V_f W(0) + sum_j V_f W_ij + sum_b V_b W_ib, with W and the
  gradient coefficient interpolated in a table over [0, h] (:func:`fluidsim.kernels.cubic_from_table`,
  within 4e-7 of the exact spline; no division or spline-piece branch per pair)
  (Akinci et al. 2012 boundary contribution, divided by rho_0);
- computes the DFSPH factor (E2) (Bender & Koschier 2017, the factor alpha_i / rho_i; rho_i cancels):
  factor_i = 1 / (|sum_j V_j grad W_ij + sum_b V_b grad W_ib|^2 + sum_j |V_j grad W_ij|^2).
- for a cold-started divergence-free solver, measures its first source (E3) (:mod:`fluidsim.dfsph`),
  s_i = D(rho_i/rho_0)/Dt = sum_j (v_i - v_j) . V_j grad W_ij + v_i . sum_b V_b grad W_ib, zero where
  negative or at the free surface, while the gradients are at hand; the solver then needs no pass of its
  own to start;
- with the warm start on, sums instead the divergence-free solver's warm-start push (W1) P_i = kappa_i sum_k g_ik
  + sum_j kappa_j g_ij (k over fluid and boundary, j over fluid) from the stiffness kappa stored at the
  previous step (it depends only on positions, which do not move until advection) and applies it: the
  warm start costs no pass and no launch of its own.

Akinci boundary volumes (Akinci et al. 2012): V_b = 1 / sum_k W(x_b - x_k) over boundary
particles k within h (k = b included).

The cells along z for fixed (x, y) offsets are contiguous in the sorted order, so each particle visits 9
runs of slots (3 cells each, or 5 half-height cells in the simulation's grid, :data:`fluidsim.grid.Z_SPLIT`).
Cells outside the grid are skipped, never clamped. One neighbour walk, :func:`for_each_neighbor`, does this
for every pass that searches the grid (the boundary volumes, the neighbourhood pass, the fluid-in-solid test
at set-up and Eq. 1 beyond h, :func:`fluidsim.estimator.divergence_estimate_from_grid`); each hands it a
visitor for the candidates. The equation labels (E1)-(E3), (W1) are those of :mod:`fluidsim.solver`.
"""

from typing import NamedTuple

import numpy as np
import taichi as ti
from taichi.lang import impl

from .grid import cell_coord, ivec3, z_reach
from .kernels import cubic_from_table, cubic_w
from .launch import fast_kernel

vec3d = ti.types.vector(3, ti.f64)
# Below this many neighbours a particle is at the free surface and takes no divergence correction
# (SPlisHSPlasH's heuristic for 3-D, Bender & Koschier 2017, Sec. 4.4).
FREE_SURFACE_NEIGHBORS = 20
FACTOR_EPS = 1.0e-5


def _wide() -> bool:
    """Whether the runtime's floats are f64 (pairs are then two i64, else two i32)."""
    return impl.get_runtime().default_fp == ti.f64


def pair_dtype(precision: str):
    """Integer type of the packed (index, c_ij bits) pairs for ``"f32"`` or ``"f64"``."""
    return ti.i64 if precision == "f64" else ti.i32


@ti.func
def pack_pair(j, c):
    """(neighbour index ``j``, gradient coefficient ``c``) as one integer 2-vector: j and the bits of c."""
    it = ti.i64 if ti.static(_wide()) else ti.i32
    ft = ti.f64 if ti.static(_wide()) else ti.f32
    return ti.Vector([ti.cast(j, it), ti.bit_cast(ti.cast(c, ft), it)])


@ti.func
def unpack_pair(e):
    """Inverse of :func:`pack_pair`: (index j, c with V_j grad W_ij = c (x_i - x_j))."""
    ft = ti.f64 if ti.static(_wide()) else ti.f32
    return ti.cast(e[0], ti.i32), ti.bit_cast(e[1], ft)


def unpack_pairs_np(pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Numpy twin of :func:`unpack_pair` on a whole list array [N, cap, 2] -> (index [N, cap], c [N, cap])."""
    ints = np.ascontiguousarray(pairs)
    floats = ints.view(np.float64 if ints.dtype == np.int64 else np.float32)
    return ints[..., 0].astype(np.int64), floats[..., 1].astype(np.float64)


# Formats of the fluid pair lists (a compile-time argument of every pass that reads them).
WIDE = 0  # (j, c_ij) as an integer 2-vector (:func:`pack_pair`): i32 in f32 runs, i64 in f64 runs; 8 / 16 bytes
NARROW = 1  # one i32 (f32 runs): the offset j - i in the low 16 bits, c_ij h^2 as an f16 in the high 16; 4 bytes
NARROW_MAX_OFFSET = 32767


@ti.func
def pack_narrow_pair(i, j, c, coef_scale):
    """Fluid pair (i, j, c_ij) in the NARROW format (WIDE lists use :func:`pack_pair`); ``coef_scale`` = h^2
    (|c| h^2 <= 8 / s^3 * 12 * 8 / pi for support factor s, so the f16 never overflows and keeps 11 significant
    bits)."""
    half = ti.bit_cast(ti.cast(c * coef_scale, ti.f16), ti.u16)
    bits = ti.cast((j - i) & 0xFFFF, ti.u32) | (ti.cast(half, ti.u32) << ti.u32(16))
    return ti.bit_cast(bits, ti.i32)


@ti.func
def fluid_pair(pairs: ti.template(), i, k, fmt: ti.template(), inv_scale):
    """The k-th fluid pair of particle i in format ``fmt``: (j, c_ij) with V_j grad W_ij = c_ij (x_i - x_j)."""
    j = 0
    c = 0.0
    if ti.static(fmt == NARROW):
        e = pairs[i, k]
        j = i + ti.cast(ti.cast(e & 0xFFFF, ti.i16), ti.i32)
        c = ti.cast(ti.bit_cast(ti.cast((e >> 16) & 0xFFFF, ti.u16), ti.f16), float) * inv_scale
    else:
        j, c = unpack_pair(pairs[i, k])
    return j, c


def unpack_fluid_pairs_np(pairs: np.ndarray, fmt: int, inv_scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Numpy twin of :func:`fluid_pair` on a whole list array -> (index [N, cap], c [N, cap])."""
    if fmt == WIDE:
        return unpack_pairs_np(pairs)
    ints = np.ascontiguousarray(pairs).astype(np.int32)
    offset = (ints & 0xFFFF).astype(np.uint16).view(np.int16).astype(np.int64)
    half = ((ints >> 16) & 0xFFFF).astype(np.uint16).view(np.float16).astype(np.float64)
    return offset + np.arange(ints.shape[0])[:, None], half * inv_scale


MIN_LIST_CAPACITY = 8


def list_capacity(count: int) -> int:
    """Slots per particle for lists whose largest count is ``count``: an eighth more, plus two (at least 8)."""
    return max(MIN_LIST_CAPACITY, int(count) + int(count) // 8 + 2)


def shrink_threshold(count: int) -> int:
    """Capacity above which lists with largest count ``count`` are reallocated smaller (half again more, plus
    four: hysteresis, so a count that moves a little never reallocates)."""
    return max(MIN_LIST_CAPACITY, int(count) + int(count) // 2 + 4)


def lattice_offsets(spacing: float, h: float) -> np.ndarray:
    """(K, 3) offsets, m, of the points of a cubic lattice of ``spacing`` in the cube of half-width >= h around
    one of them (itself included)."""
    reach = int(np.ceil(h / spacing))
    ax = np.arange(-reach, reach + 1) * spacing
    return np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), -1).reshape(-1, 3)


def lattice_neighbor_count(spacing: float, h: float) -> int:
    """Lattice points within h (those at exactly h included: the slightest compression brings them in) of a point
    of a cubic lattice of ``spacing``, itself excluded: the neighbour count of a fluid at rest."""
    pts = lattice_offsets(spacing, h)
    return int((np.sum(pts * pts, axis=1) <= h * h * (1.0 + 1e-9)).sum()) - 1


@ti.func
def for_each_neighbor(
    xi,
    origin,
    inv_cell,
    dims,
    reach: ti.template(),
    reach_z,
    sets: ti.template(),
    visit: ti.template(),
    ctx: ti.template(),
):
    """The neighbour walk on the uniform grid: every candidate of each point set in the cells around ``xi``.

    The cells along z for fixed (x, y) are contiguous in the sorted order, so the walk visits the
    (2 reach + 1)^2 columns of cells around x_i's cell, each as one run of slots from z0 to z1 (2 reach_z + 1
    cells; :func:`fluidsim.grid.z_reach`). Columns outside the grid are skipped, never clamped, so no candidate
    is visited twice. In each column it walks the point sets of ``sets`` in their order and calls, for every
    slot j of the run,

        visit(s, j, xi - points_s[j], ctx)

    with s the set's index in ``sets`` (a compile-time constant) and r = x_i - x_j. The visitor applies its own
    radius test (and j != i where the set is the particle's own).

    Args:
        xi: the query point, vec3 m. origin, inv_cell, dims: the grid (vec3 f64 m, vec3 f64 1/m, ivec3).
        reach: columns on each side along x and y (1 when the cell is >= the radius; a compile-time int or a
            kernel scalar). reach_z: cells on each side along z.
        sets: a tuple of (points (M,) vec3 m, cell starts (num_cells + 1,) i32) pairs.
        visit: a ``@ti.func`` (s: ti.template(), j, r, ctx: ti.template()).
        ctx: what the visitor reads and sums into, as a tuple built inside ``ti.static(...)``: kernel arguments
            and local variables by reference (Taichi functions take ti.template() arguments by reference and are
            inlined, so the walk compiles to the loops it replaces).
    """
    c = cell_coord(ti.cast(xi, ti.f64), origin, inv_cell)
    z0 = ti.max(c[2] - reach_z, 0)
    z1 = ti.min(c[2] + reach_z, dims[2] - 1)
    for dx, dy in ti.ndrange((-reach, reach + 1), (-reach, reach + 1)):
        cx = c[0] + dx
        cy = c[1] + dy
        if 0 <= cx < dims[0] and 0 <= cy < dims[1] and z0 <= z1:
            base = (cx * dims[1] + cy) * dims[2]
            for s in ti.static(range(len(sets))):
                points, starts = ti.static(sets[s])
                for j in range(starts[base + z0], starts[base + z1 + 1]):
                    visit(s, j, xi - points[j], ctx)


class _VolumeSum(NamedTuple):
    """What :func:`_add_weight` reads and sums into (references, bound at compile time)."""

    h: object
    total: object


@ti.func
def _add_weight(s: ti.template(), k, r, ctx: ti.template()):
    """sum_k W(x_b - x_k, h) over the boundary neighbours k (b itself included: r = 0 is within h)."""
    ctx.total += cubic_w(r.norm(), ctx.h)


@fast_kernel
def compute_boundary_volumes(
    bx: ti.types.ndarray(ndim=1),
    starts: ti.types.ndarray(dtype=ti.i32, ndim=1),
    m: ti.i32,
    origin: vec3d,
    inv_cell: vec3d,
    dims: ivec3,
    h: float,
    volume: ti.types.ndarray(ndim=1),
):
    """Akinci et al. 2012: V_b = 1 / sum_k W(x_b - x_k, h) over boundary neighbours (self included)."""
    zr = z_reach(inv_cell)
    for b in range(m):
        total = 0.0
        for_each_neighbor(
            bx[b], origin, inv_cell, dims, 1, zr, ((bx, starts),), _add_weight, ti.static(_VolumeSum(h, total))
        )
        volume[b] = 1.0 / total


class _Gather(NamedTuple):
    """The neighbourhood pass's inputs and per-particle sums, handed to :func:`_gather_pair` by the walk."""

    i: object
    vi: object
    h2: object
    scale: object
    table: object
    fluid_volume: object
    v: object
    warm: object
    kappa: object
    fluid_pairs: object
    cap_f: object
    fmt: int
    coef_scale: object
    too_far: object
    bvolume: object
    bsolid: object
    boundary_pairs: object
    cap_b: object
    store_boundary: bool
    rho: object  # the sums (local variables)
    grad_sum: object
    sq_sum: object
    div: object
    push_v: object
    nf: object
    grad_sum_b: object
    grad_sum_s: object
    nb: object


@ti.func
def _gather_pair(s: ti.template(), j, r, ctx: ti.template()):
    """One candidate of the neighbourhood pass (set 0 fluid, 1 boundary): within h, it adds its terms to the
    density, the gradient sums, the factor's sum of squares and the source or warm-start push, and is stored."""
    r2 = r.dot(r)
    if ti.static(s == 0):
        if r2 < ctx.h2 and j != ctx.i:
            w, cg = cubic_from_table(ti.sqrt(r2), ctx.scale, ctx.table)
            ctx.rho += ctx.fluid_volume * w
            cg *= ctx.fluid_volume
            g = cg * r
            ctx.grad_sum += g
            ctx.sq_sum += g.dot(g)
            if not ctx.warm:  # a warm-started solve measures its first source after the push
                ctx.div += (ctx.vi - ctx.v[j]).dot(g)
            if ctx.warm:
                ctx.push_v += ctx.kappa[j] * g
            if ctx.nf < ctx.cap_f:
                if ti.static(ctx.fmt == NARROW):
                    ctx.fluid_pairs[ctx.i, ctx.nf] = pack_narrow_pair(ctx.i, j, cg, ctx.coef_scale)
                    if ti.abs(j - ctx.i) > NARROW_MAX_OFFSET:
                        ti.atomic_max(ctx.too_far, 1)
                else:
                    ctx.fluid_pairs[ctx.i, ctx.nf] = pack_pair(j, cg)
            ctx.nf += 1
    else:
        if r2 < ctx.h2:
            vb = ctx.bvolume[j]
            w, cg = cubic_from_table(ti.sqrt(r2), ctx.scale, ctx.table)
            ctx.rho += vb * w
            cg *= vb
            ctx.grad_sum_b += cg * r
            if ctx.bsolid[j]:
                ctx.grad_sum_s += cg * r
            if ti.static(ctx.store_boundary):
                if ctx.nb < ctx.cap_b:
                    ctx.boundary_pairs[ctx.i, ctx.nb] = pack_pair(j, cg)
            ctx.nb += 1


@fast_kernel
def build_neighborhoods(
    n: ti.i32,
    x: ti.types.ndarray(ndim=1),
    fluid_starts: ti.types.ndarray(dtype=ti.i32, ndim=1),
    bx: ti.types.ndarray(ndim=1),
    bvolume: ti.types.ndarray(ndim=1),
    bsolid: ti.types.ndarray(dtype=ti.i32, ndim=1),
    boundary_starts: ti.types.ndarray(dtype=ti.i32, ndim=1),
    origin: vec3d,
    inv_cell: vec3d,
    dims: ivec3,
    h: float,
    fluid_volume: float,
    fluid_count: ti.types.ndarray(dtype=ti.i32, ndim=1),
    fluid_pairs: ti.types.ndarray(ndim=2),
    boundary_count: ti.types.ndarray(dtype=ti.i32, ndim=1),
    boundary_pairs: ti.types.ndarray(ndim=2),
    boundary_grad_sum: ti.types.ndarray(ndim=1),
    solid_grad_sum: ti.types.ndarray(ndim=1),
    grad_sum_out: ti.types.ndarray(ndim=1),
    density: ti.types.ndarray(ndim=1),
    factor: ti.types.ndarray(ndim=1),
    v: ti.types.ndarray(ndim=1),
    source: ti.types.ndarray(ndim=1),
    kernel_table: ti.types.ndarray(ndim=1),
    warm: ti.i32,
    kappa: ti.types.ndarray(ndim=1),
    push: ti.types.ndarray(ndim=1),
    fmt: ti.template(),
    coef_scale: float,
    warm_scale: float,
    dt: float,
    stiffness_sum: ti.types.ndarray(ndim=1),
    store_boundary: ti.template(),
) -> ivec3:
    """Neighbour lists, normalised density, DFSPH factor, divergence source (1/s) and warm-start pushes.

    Returns (max fluid, max boundary neighbour counts, 1 if a NARROW list met an offset |j - i| beyond
    NARROW_MAX_OFFSET, else 0); the caller then switches to WIDE lists and runs the pass again.

    With ``warm`` = 1, the divergence-free solver's warm start (B&K 2017, Alg. 2) instead of the source:
    the push P_i = kappa_i (sum_j g_ij + sum_b g_ib) + sum_j kappa_j g_ij from its stored stiffness kappa
    (kappa's units per metre; stored in ``push``), applied at once as v_i -= warm_scale P_i (the stiffness
    k_i = warm_scale kappa_i / dt of every particle; the pass reads no neighbour's velocity then), and the
    solver's stiffness sum set to k_i. The solver measures the source after the push. A caller that runs the
    pass again (grown lists) first undoes the push (:func:`fluidsim.dfsph.undo_push`).

    A particle whose neighbours exceed the list capacity still gets its full density and factor; the
    caller sees the returned maxima, grows the lists and runs the pass again.

    With ``store_boundary`` = False the boundary pairs are counted (``boundary_count`` is the full count) but not
    stored: no pass reads them when the boundary viscosity is 0 and Eq. 1 does not walk the lists.
    """
    cap_f = fluid_pairs.shape[1]
    cap_b = boundary_pairs.shape[1]
    h2 = h * h
    w0 = cubic_w(0.0, h)
    scale = (kernel_table.shape[0] - 2) / h  # table samples per metre (fluidsim.kernels.cubic_table_np)
    max_f = 0
    max_b = 0
    too_far = 0
    zr = z_reach(inv_cell)
    for i in range(n):
        xi = x[i]
        vi = v[i]
        push_v = xi * 0.0
        rho = fluid_volume * w0
        div = 0.0 * rho
        grad_sum = xi * 0.0
        grad_sum_b = xi * 0.0
        grad_sum_s = xi * 0.0
        sq_sum = 0.0
        nf = 0
        nb = 0
        for_each_neighbor(
            xi,
            origin,
            inv_cell,
            dims,
            1,
            zr,
            ((x, fluid_starts), (bx, boundary_starts)),
            _gather_pair,
            ti.static(
                _Gather(
                    i,
                    vi,
                    h2,
                    scale,
                    kernel_table,
                    fluid_volume,
                    v,
                    warm,
                    kappa,
                    fluid_pairs,
                    cap_f,
                    fmt,
                    coef_scale,
                    too_far,
                    bvolume,
                    bsolid,
                    boundary_pairs,
                    cap_b,
                    store_boundary,
                    rho,
                    grad_sum,
                    sq_sum,
                    div,
                    push_v,
                    nf,
                    grad_sum_b,
                    grad_sum_s,
                    nb,
                )
            ),
        )
        density[i] = rho
        boundary_grad_sum[i] = grad_sum_b
        solid_grad_sum[i] = grad_sum_s
        div += vi.dot(grad_sum_b)
        if div < 0.0 or nf + nb < FREE_SURFACE_NEIGHBORS:
            div = 0.0
        source[i] = div
        grad_sum += grad_sum_b
        grad_sum_out[i] = grad_sum
        if warm:
            p = push_v + kappa[i] * grad_sum
            push[i] = p
            v[i] = vi - warm_scale * p
            stiffness_sum[i] = warm_scale * kappa[i] / dt
        denom = grad_sum.dot(grad_sum) + sq_sum
        f = 0.0
        if denom > FACTOR_EPS:
            f = 1.0 / denom
        factor[i] = f
        fluid_count[i] = ti.min(nf, cap_f)
        if ti.static(store_boundary):
            boundary_count[i] = ti.min(nb, cap_b)
        else:
            boundary_count[i] = nb
        ti.atomic_max(max_f, nf)
        ti.atomic_max(max_b, nb)
    return ivec3(max_f, max_b, too_far)


@fast_kernel
def flag_near_boundary(
    n: ti.i32,
    x: ti.types.ndarray(ndim=1),
    bx: ti.types.ndarray(ndim=1),
    boundary_starts: ti.types.ndarray(dtype=ti.i32, ndim=1),
    origin: vec3d,
    inv_cell: vec3d,
    dims: ivec3,
    radius: float,
    flags: ti.types.ndarray(dtype=ti.i32, ndim=1),
):
    """flags[i] = 1 where a boundary particle lies closer than ``radius`` (<= h, the x-y cell size) to x_i."""
    r2max = radius * radius
    zr = z_reach(inv_cell)
    for i in range(n):
        hit = 0
        for_each_neighbor(
            x[i], origin, inv_cell, dims, 1, zr, ((bx, boundary_starts),), _flag_near, ti.static(_Near(r2max, hit))
        )
        flags[i] = hit


class _Near(NamedTuple):
    """What :func:`_flag_near` reads and sets (references, bound at compile time)."""

    r2max: object
    hit: object


@ti.func
def _flag_near(s: ti.template(), b, r, ctx: ti.template()):
    """Sets the flag when the boundary candidate b is closer than the radius."""
    if r.dot(r) < ctx.r2max:
        ctx.hit = 1
