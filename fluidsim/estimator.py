"""The divergence estimate D_i of the paper (FluidGaussian, Eq. 1): what the probes measure.

Not to be confused with the DFSPH divergence-free *solver* (:mod:`fluidsim.dfsph`, the step's
``divergence_solve``), which drives the velocity divergence towards zero; this module only measures what is
left of it. For every active fluid particle i:

    D_i = | sum_{j in N_{h_r}(i)} V_j (v_j - v_i) . grad W(x_i - x_j, h_k) |,

over fluid neighbours (V_j = m / rho_j) and boundary neighbours (Akinci volume V_b, v_b = 0) within
h_r, j != i, with the cubic spline of support h_k. Non-fluid particles get no value (zero).
The estimate runs after each step's divergence solve, as in the authors' code, and each value is
also added to the particle's run sum and count (:func:`record_estimate`).

Three fast paths give the same result: when h_k = h <= h_r (the default, h = 0.1) the step's stored
neighbour gradient coefficients are reused (:func:`divergence_estimate_from_gradients`); when h_r <= h the
neighbour lists are filtered by distance and grad W(., h_k) recomputed (:func:`divergence_estimate_from_lists`);
otherwise the grid is walked with a cell range of ceil(h_r / cell) (:func:`divergence_estimate_from_grid`). In
a time step the first case is computed inside the non-pressure pass
(:func:`fluidsim.viscosity.predict_velocities`), which reads the same velocities, densities and gradients;
:func:`divergence_estimate_from_gradients` is its stand-alone twin. :func:`divergence_estimate_np` is the
O(N^2) numpy twin of all of them.
"""

import math
from typing import NamedTuple

import numpy as np
import taichi as ti

from .grid import ivec3
from .kernels import cubic_grad_w, cubic_grad_w_np
from .launch import fast_kernel
from .neighbors import fluid_pair, for_each_neighbor, unpack_pair

vec3d = ti.types.vector(3, ti.f64)

# The fast paths of Eq. 1 (:func:`estimate_path`).
FROM_GRADIENTS = "gradients"
FROM_LISTS = "lists"
FROM_GRID = "grid"


def estimate_path(h: float, h_r: float, h_k: float) -> str:
    """Which fast path computes Eq. 1 for the support radius ``h`` of the neighbour lists, the estimator radius
    ``h_r`` and its kernel radius ``h_k`` (all m): ``FROM_GRADIENTS`` when h_k = h <= h_r (the stored gradients,
    fused into the non-pressure pass in a time step), else ``FROM_LISTS`` when h_r <= h (the lists filtered to
    h_r), else ``FROM_GRID`` (the grid walked to h_r). The one place the choice is made.

    Example:
        >>> estimate_path(0.1, 0.1, 0.1), estimate_path(0.1, 0.05, 0.05), estimate_path(0.1, 0.2, 0.1)
        ('gradients', 'lists', 'grid')
    """
    if math.isclose(h_k, h, rel_tol=1e-9) and h_r >= h:
        return FROM_GRADIENTS
    if h_r <= h:
        return FROM_LISTS
    return FROM_GRID


@ti.func
def record_estimate(i, d, divergence: ti.template(), divergence_sum: ti.template(), divergence_count: ti.template()):
    """Stores D_i = ``d`` (1/s) and adds it to the particle's run sum (f64) and count."""
    divergence[i] = d
    divergence_sum[i] += ti.cast(d, ti.f64)
    divergence_count[i] += 1


@fast_kernel
def divergence_estimate_from_gradients(
    n: ti.i32,
    x: ti.types.ndarray(ndim=1),
    v: ti.types.ndarray(ndim=1),
    density: ti.types.ndarray(ndim=1),
    fluid_count: ti.types.ndarray(dtype=ti.i32, ndim=1),
    fluid_pairs: ti.types.ndarray(ndim=2),
    fmt: ti.template(),
    inv_scale: float,
    boundary_grad_sum: ti.types.ndarray(ndim=1),
    divergence: ti.types.ndarray(ndim=1),
    divergence_sum: ti.types.ndarray(dtype=ti.f64, ndim=1),
    divergence_count: ti.types.ndarray(dtype=ti.i32, ndim=1),
):
    """Paper Eq. 1 when h_k = h <= h_r: the stored V grad W of the step (fluid V_f, boundary sum of V_b)."""
    for i in range(n):
        xi = x[i]
        vi = v[i]
        s = -vi.dot(boundary_grad_sum[i])
        for k in range(fluid_count[i]):
            j, c = fluid_pair(fluid_pairs, i, k, fmt, inv_scale)
            s += c * (v[j] - vi).dot(xi - x[j]) / density[j]
        record_estimate(i, ti.abs(s), divergence, divergence_sum, divergence_count)


@fast_kernel
def divergence_estimate_from_lists(
    n: ti.i32,
    h_r: float,
    h_k: float,
    fluid_volume: float,
    x: ti.types.ndarray(ndim=1),
    v: ti.types.ndarray(ndim=1),
    density: ti.types.ndarray(ndim=1),
    bx: ti.types.ndarray(ndim=1),
    bvolume: ti.types.ndarray(ndim=1),
    fluid_count: ti.types.ndarray(dtype=ti.i32, ndim=1),
    fluid_pairs: ti.types.ndarray(ndim=2),
    fmt: ti.template(),
    boundary_count: ti.types.ndarray(dtype=ti.i32, ndim=1),
    boundary_pairs: ti.types.ndarray(ndim=2),
    divergence: ti.types.ndarray(ndim=1),
    divergence_sum: ti.types.ndarray(dtype=ti.f64, ndim=1),
    divergence_count: ti.types.ndarray(dtype=ti.i32, ndim=1),
):
    """Paper Eq. 1 over the step's neighbour lists (valid when h_r <= h)."""
    hr2 = h_r * h_r
    for i in range(n):
        xi = x[i]
        vi = v[i]
        s = 0.0 * vi[0]
        for k in range(fluid_count[i]):
            j, _ = fluid_pair(fluid_pairs, i, k, fmt, 1.0)
            r = xi - x[j]
            if r.dot(r) <= hr2:
                s += fluid_volume / density[j] * (v[j] - vi).dot(cubic_grad_w(r, h_k))
        for k in range(boundary_count[i]):
            b, _ = unpack_pair(boundary_pairs[i, k])
            r = xi - bx[b]
            if r.dot(r) <= hr2:
                s -= bvolume[b] * vi.dot(cubic_grad_w(r, h_k))
        record_estimate(i, ti.abs(s), divergence, divergence_sum, divergence_count)


class _Estimate(NamedTuple):
    """What :func:`_estimate_pair` reads and sums into (references, bound at compile time)."""

    i: object
    vi: object
    hr2: object
    h_k: object
    fluid_volume: object
    v: object
    density: object
    bvolume: object
    total: object


@ti.func
def _estimate_pair(s: ti.template(), j, r, ctx: ti.template()):
    """One candidate of the grid path (set 0 fluid, 1 boundary at rest): its term of Eq. 1 within h_r."""
    if ti.static(s == 0):
        if r.dot(r) <= ctx.hr2 and j != ctx.i:
            ctx.total += ctx.fluid_volume / ctx.density[j] * (ctx.v[j] - ctx.vi).dot(cubic_grad_w(r, ctx.h_k))
    else:
        if r.dot(r) <= ctx.hr2:
            ctx.total -= ctx.bvolume[j] * ctx.vi.dot(cubic_grad_w(r, ctx.h_k))


@fast_kernel
def divergence_estimate_from_grid(
    n: ti.i32,
    h_r: float,
    h_k: float,
    fluid_volume: float,
    reach: ti.i32,
    reach_z: ti.i32,
    origin: vec3d,
    inv_cell: vec3d,
    dims: ivec3,
    x: ti.types.ndarray(ndim=1),
    v: ti.types.ndarray(ndim=1),
    density: ti.types.ndarray(ndim=1),
    fluid_starts: ti.types.ndarray(dtype=ti.i32, ndim=1),
    bx: ti.types.ndarray(ndim=1),
    bvolume: ti.types.ndarray(ndim=1),
    boundary_starts: ti.types.ndarray(dtype=ti.i32, ndim=1),
    divergence: ti.types.ndarray(ndim=1),
    divergence_sum: ti.types.ndarray(dtype=ti.f64, ndim=1),
    divergence_count: ti.types.ndarray(dtype=ti.i32, ndim=1),
):
    """Paper Eq. 1 walking ``reach`` cells along x and y and ``reach_z`` along z in each direction (any h_r)."""
    hr2 = h_r * h_r
    for i in range(n):
        xi = x[i]
        vi = v[i]
        total = 0.0 * vi[0]
        for_each_neighbor(
            xi,
            origin,
            inv_cell,
            dims,
            reach,
            reach_z,
            ((x, fluid_starts), (bx, boundary_starts)),
            _estimate_pair,
            ti.static(_Estimate(i, vi, hr2, h_k, fluid_volume, v, density, bvolume, total)),
        )
        record_estimate(i, ti.abs(total), divergence, divergence_sum, divergence_count)


def divergence_estimate_np(
    x: np.ndarray,
    v: np.ndarray,
    volumes: np.ndarray,
    boundary_x: np.ndarray,
    boundary_volumes: np.ndarray,
    h_r: float,
    h_k: float,
) -> np.ndarray:
    """O(N^2) numpy twin of paper Eq. 1.

    Args:
        x: (N, 3) fluid positions, m. v: (N, 3) fluid velocities, m/s.
        volumes: (N,) fluid volumes V_j = m / rho_j, m^3.
        boundary_x: (M, 3) boundary positions (at rest), m. boundary_volumes: (M,) m^3.
        h_r: neighbour radius, m. h_k: kernel support, m.
    Returns:
        (N,) D_i, 1/s.
    Example:
        >>> divergence_estimate_np(np.zeros((1, 3)), np.zeros((1, 3)), np.ones(1), np.zeros((0, 3)), np.zeros(0),
        ...                        0.1, 0.1).tolist()
        [0.0]
    """
    x = np.asarray(x, np.float64)
    v = np.asarray(v, np.float64)
    out = np.zeros(len(x))
    for i in range(len(x)):
        r = x[i] - x
        near = np.sum(r * r, axis=1) <= h_r * h_r
        near[i] = False
        g = cubic_grad_w_np(r[near], h_k)
        s = np.sum(volumes[near] * np.sum((v[near] - v[i]) * g, axis=1))
        if len(boundary_x):
            rb = x[i] - np.asarray(boundary_x, np.float64)
            nb = np.sum(rb * rb, axis=1) <= h_r * h_r
            gb = cubic_grad_w_np(rb[nb], h_k)
            s -= np.sum(np.asarray(boundary_volumes)[nb] * (gb @ v[i]))
        out[i] = abs(s)
    return out
