"""Non-pressure forces: gravity and viscosity with the dynamic viscosity mu of the paper (Table 2).

Viscosity operator: the SPH Laplacian of Monaghan (2005, "Smoothed particle hydrodynamics",
Rep. Prog. Phys. 68, the form of Cleary & Monaghan 1999), as presented in the SPH tutorial of
Koschier, Bender, Solenthaler & Teschner (Eurographics 2019) and used by SPlisHSPlasH's "Standard"
viscosity:

    lap(v)_i = 2 (d + 2) sum_j (m_j / rho_j) (v_ij . x_ij) / (|x_ij|^2 + 0.01 h^2) grad W_ij,  d = 3,

and a_i = g + (mu / rho_i) lap(v)_i. Fluid-boundary friction uses the same operator with the boundary
at rest, V_b in place of m_j / rho_j and its own dynamic viscosity mu_b.

The pass reads the velocities after the divergence solve and the stored neighbour gradients, which is
what paper Eq. 1 reads (:func:`fluidsim.estimator.divergence_estimate_from_gradients`) when
h_k = h <= h_r, so it computes D_i in the same sweep.

The pass also starts the constant-density solver: it sums that solver's warm-start push and writes the
predicted velocities v*_i = v_i + dt a_i - P_i / dt to a second buffer (:func:`predict_velocities`; the sweep
reads the neighbours' velocities, so it cannot update them in place), so the start costs no pass of its own.
:func:`non_pressure_np` is the numpy twin.
"""

import numpy as np
import taichi as ti

from .estimator import record_estimate
from .kernels import cubic_grad_w_np
from .launch import fast_kernel
from .neighbors import fluid_pair, unpack_pair

LAPLACIAN_FACTOR = 2.0 * (3 + 2)  # 2 (d + 2), d = 3
LAPLACIAN_EPS = 0.01  # times h^2, in the denominator of the Laplacian


@fast_kernel
def predict_velocities(
    n: ti.i32,
    capacity: ti.i32,
    dt: float,
    gravity: ti.types.vector(3, float),
    mu: float,
    mu_boundary: float,
    rest_density: float,
    h: float,
    x: ti.types.ndarray(ndim=1),
    v: ti.types.ndarray(ndim=1),
    density: ti.types.ndarray(ndim=1),
    density_record: ti.types.ndarray(ndim=1),
    bx: ti.types.ndarray(ndim=1),
    bsolid: ti.types.ndarray(dtype=ti.i32, ndim=1),
    fluid_count: ti.types.ndarray(dtype=ti.i32, ndim=1),
    fluid_pairs: ti.types.ndarray(ndim=2),
    fmt: ti.template(),
    inv_scale: float,
    boundary_count: ti.types.ndarray(dtype=ti.i32, ndim=1),
    boundary_pairs: ti.types.ndarray(ndim=2),
    boundary_grad_sum: ti.types.ndarray(ndim=1),
    grad_sum: ti.types.ndarray(ndim=1),
    estimate: ti.i32,
    divergence: ti.types.ndarray(ndim=1),
    divergence_sum: ti.types.ndarray(dtype=ti.f64, ndim=1),
    divergence_count: ti.types.ndarray(dtype=ti.i32, ndim=1),
    warm: ti.i32,
    stiffness_sum: ti.types.ndarray(ndim=1),
    v_out: ti.types.ndarray(ndim=1),
    boundary_viscous: ti.types.ndarray(ndim=1),
    solid_viscous: ti.types.ndarray(ndim=1),
):
    """Non-pressure forces and the constant-density solver's start, in one sweep over the lists
    (B&K 2017, Alg. 1 and 2):

    - the non-pressure acceleration a_i = g + (mu / rho_i) lap(v)_i (m/s^2);
    - with ``warm`` = 1, the warm-start push P_i = w_i (sum_j g_ij + sum_b g_ib) + sum_j w_j g_ij from the masked
      stiffness w of the records (x_j, w_j) (:func:`fluidsim.dfsph.density_warm_record`), and k_i = w_i / dt^2;
    - the predicted velocity v*_i = v_i + dt a_i - P_i / dt, written to ``v_out`` (the sweep reads the
      neighbours' v, so it cannot update v in place; the caller swaps the buffers), and the stiffness sum
      started at k_i (0 without ``warm``);
    - the viscous acceleration from the boundary, a_b,i = (mu_b / (rho_0 rho_i)) 2 (d + 2) sum_b (...), written to
      ``boundary_viscous``, and its part from the solid's particles (``bsolid``) to ``solid_viscous`` (the
      reaction -m a is the viscous force on the boundary, :mod:`fluidsim.forces`);
    - with ``estimate`` = 1, paper Eq. 1 from the stored gradients,
      D_i = |sum_j (v_j - v_i) . V_f grad W_ij / rho_j - v_i . sum_b V_b grad W_ib| (1/s), stored and added to
      the run sum and count.

    Reads v only: the velocities are those after the divergence solve. Slots ``n <= i < capacity`` (retired
    particles) copy their velocity, so ``v_out`` is whole.
    """
    eps = LAPLACIAN_EPS * h * h
    for i in range(n):
        xi = x[i]
        vi = v[i]
        lap_f = vi * 0.0
        pushed = vi * 0.0  # sum_j w_j g_ij
        d = -vi.dot(boundary_grad_sum[i])  # paper Eq. 1: sum_j (v_j - v_i) . g_ij / rho_j - v_i . sum_b g_ib
        for k in range(fluid_count[i]):
            j, c = fluid_pair(fluid_pairs, i, k, fmt, inv_scale)
            q = density_record[j]  # (x_j, w_j): one gather for both
            xij = xi - ti.Vector([q[0], q[1], q[2]])
            rho_j = density[j]
            vx = (vi - v[j]).dot(xij)
            lap_f += (vx * c / ((xij.dot(xij) + eps) * rho_j)) * xij
            d -= c * vx / rho_j
            if warm:
                pushed += (q[3] * c) * xij
        lap_b = vi * 0.0
        lap_s = vi * 0.0
        if mu_boundary != 0.0:  # free-slip boundaries (mu_b = 0) skip the boundary list
            for k in range(boundary_count[i]):
                b, c = unpack_pair(boundary_pairs[i, k])
                xib = xi - bx[b]
                term = (vi.dot(xib) * c / (xib.dot(xib) + eps)) * xib
                lap_b += term
                if bsolid[b]:
                    lap_s += term
        rho_i = density[i]
        a = gravity + LAPLACIAN_FACTOR * (mu * lap_f + mu_boundary * lap_b) / (rest_density * rho_i)
        to_acceleration = mu_boundary * LAPLACIAN_FACTOR / (rest_density * rho_i)  # the boundary's share of a
        boundary_viscous[i] = to_acceleration * lap_b
        solid_viscous[i] = to_acceleration * lap_s
        dv = dt * a
        ki = 0.0 * rho_i
        if warm:
            wi = density_record[i][3]
            dv -= (pushed + wi * grad_sum[i]) / dt
            ki = wi / (dt * dt)
        v_out[i] = vi + dv
        stiffness_sum[i] = ki
        if estimate:
            record_estimate(i, ti.abs(d), divergence, divergence_sum, divergence_count)
    ti.loop_config(serialize=True)  # usually empty; serial, so it costs no thread-pool wake-up
    for i in range(n, capacity):
        v_out[i] = v[i]


def non_pressure_np(
    x: np.ndarray,
    v: np.ndarray,
    density: np.ndarray,
    fluid_volume: float,
    boundary_x: np.ndarray,
    boundary_volumes: np.ndarray,
    h: float,
    mu: float,
    mu_boundary: float,
    rest_density: float,
    gravity,
) -> np.ndarray:
    """O(N^2) numpy twin of the acceleration a_i of :func:`predict_velocities`.

    Args:
        x, v: (N, 3) fluid positions (m) and velocities (m/s). density: (N,) rho_i / rho_0.
        fluid_volume: V_f = m / rho_0, m^3. boundary_x: (M, 3) m, at rest. boundary_volumes: (M,) m^3.
        h: support radius, m. mu, mu_boundary: dynamic viscosities, Pa s. rest_density: kg/m^3.
        gravity: (3,) m/s^2.
    Returns:
        (N, 3) a_i, m/s^2.
    Example:
        >>> non_pressure_np(np.zeros((1, 3)), np.zeros((1, 3)), np.ones(1), 1e-3, np.zeros((0, 3)),
        ...                 np.zeros(0), 0.1, 0.01, 0.0, 1000.0, (0, -9.81, 0)).tolist()
        [[0.0, -9.81, 0.0]]
    """
    x = np.asarray(x, np.float64)
    v = np.asarray(v, np.float64)
    bx = np.asarray(boundary_x, np.float64).reshape(-1, 3)
    eps = LAPLACIAN_EPS * h * h
    out = np.zeros_like(x)
    for i in range(len(x)):
        r = x[i] - x
        near = np.sum(r * r, axis=1) < h * h
        near[i] = False
        g = fluid_volume * cubic_grad_w_np(r[near], h)
        w = np.sum((v[i] - v[near]) * r[near], axis=1) / ((np.sum(r[near] ** 2, axis=1) + eps) * density[near])
        lap = (w[:, None] * g).sum(0)
        lap_b = np.zeros(3)
        if len(bx):
            rb = x[i] - bx
            nb = np.sum(rb * rb, axis=1) < h * h
            gb = np.asarray(boundary_volumes)[nb, None] * cubic_grad_w_np(rb[nb], h)
            wb = (rb[nb] @ v[i]) / (np.sum(rb[nb] ** 2, axis=1) + eps)
            lap_b = (wb[:, None] * gb).sum(0)
        out[i] = np.asarray(gravity, np.float64) + LAPLACIAN_FACTOR * (mu * lap + mu_boundary * lap_b) / (
            rest_density * density[i]
        )
    return out
