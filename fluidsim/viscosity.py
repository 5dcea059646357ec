"""Non-pressure forces: gravity and viscosity with the dynamic viscosity mu of the paper (Table 2).

Viscosity operator: the SPH Laplacian of Monaghan (2005, "Smoothed particle hydrodynamics",
Rep. Prog. Phys. 68, the form of Cleary & Monaghan 1999), as presented in the SPH tutorial of
Koschier, Bender, Solenthaler & Teschner (Eurographics 2019) and used by SPlisHSPlasH's "Standard"
viscosity:

    lap(v)_i = 2 (d + 2) sum_j (m_j / rho_j) (v_ij . x_ij) / (|x_ij|^2 + 0.01 h^2) grad W_ij,  d = 3,

and a_i = (mu / rho_i) lap(v)_i. Fluid-boundary friction uses the same operator with the boundary at
rest, V_b in place of m_j / rho_j and its own dynamic viscosity mu_b.

The pass reads exactly what the divergence estimator of the paper (Eq. 1, :mod:`fluidsim.divergence`)
reads when h_k = h <= h_r: the velocities after the divergence solve, the neighbours' densities and the
stored gradients. With ``estimate`` set it also computes D_i (the stored-gradient estimator, fused here
to save a pass over the neighbour lists), equal to
:func:`fluidsim.divergence.estimate_divergence_from_gradients`.
"""

import taichi as ti


@ti.kernel
def apply_non_pressure_forces(
    n: ti.i32,
    dt: float,
    gravity: ti.types.vector(3, float),
    mu: float,
    mu_boundary: float,
    rest_density: float,
    h: float,
    x: ti.types.ndarray(ndim=1),
    v: ti.types.ndarray(ndim=1),
    density: ti.types.ndarray(ndim=1),
    bx: ti.types.ndarray(ndim=1),
    fluid_count: ti.types.ndarray(dtype=ti.i32, ndim=1),
    fluid_index: ti.types.ndarray(dtype=ti.i32, ndim=2),
    fluid_grad: ti.types.ndarray(ndim=2),
    boundary_count: ti.types.ndarray(dtype=ti.i32, ndim=1),
    boundary_index: ti.types.ndarray(dtype=ti.i32, ndim=2),
    boundary_grad: ti.types.ndarray(ndim=2),
    acceleration: ti.types.ndarray(ndim=1),
    estimate: ti.i32,
    boundary_grad_sum: ti.types.ndarray(ndim=1),
    divergence: ti.types.ndarray(ndim=1),
    divergence_sum: ti.types.ndarray(dtype=ti.f64, ndim=1),
    divergence_count: ti.types.ndarray(dtype=ti.i32, ndim=1),
):
    """a_i = g + (mu / rho_i) lap(v)_i, then v_i += dt a_i (two passes: all reads before any write).

    With ``estimate`` = 1, also D_i = |sum_j (v_j - v_i) . V_f grad W_ij / rho_j - v_i . sum_b V_b grad W_ib|
    (paper Eq. 1 with the stored gradients) from the velocities before the update, stored in
    ``divergence`` and added to the run sum and count.
    """
    eps = 0.01 * h * h
    for i in range(n):
        xi = x[i]
        vi = v[i]
        lap_f = vi * 0.0
        d = -vi.dot(boundary_grad_sum[i])
        for k in range(fluid_count[i]):
            j = fluid_index[i, k]
            xij = xi - x[j]
            lap_f += (vi - v[j]).dot(xij) / ((xij.dot(xij) + eps) * density[j]) * fluid_grad[i, k]
            d += (v[j] - vi).dot(fluid_grad[i, k]) / density[j]
        if estimate:
            divergence[i] = ti.abs(d)
            divergence_sum[i] += ti.cast(ti.abs(d), ti.f64)
            divergence_count[i] += 1
        lap_b = vi * 0.0
        if mu_boundary != 0.0:  # free-slip boundaries (mu_b = 0) skip the boundary list
            for k in range(boundary_count[i]):
                xib = xi - bx[boundary_index[i, k]]
                lap_b += vi.dot(xib) / (xib.dot(xib) + eps) * boundary_grad[i, k]
        rho_i = rest_density * density[i]
        acceleration[i] = gravity + 10.0 * (mu * lap_f + mu_boundary * lap_b) / rho_i
    for i in range(n):
        v[i] += dt * acceleration[i]
