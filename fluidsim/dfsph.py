"""Divergence-free SPH (Bender & Koschier 2015, 2017): the solver passes and the time step.

All quantities are normalised by the rest density (as in SPlisHSPlasH): densities are rho / rho_0 and
neighbour weights are volumes V_j. With ``g_ij = V_j grad W(x_i - x_j, h) = c_ij (x_i - x_j)``, c_ij
stored by the neighbourhood pass (:mod:`fluidsim.neighbors`):

- velocity divergence source (B&K 2017, divergence-free solver):
  s_i = D(rho_i/rho_0)/Dt = sum_j (v_i - v_j) . g_ij + v_i . sum_b g_ib, clamped at 0 (the boundary is
  static, so its gradients enter only through their sum, stored once per step);
- predicted density (constant-density solver): rho*_i = rho_i + dt s_i, error max(rho*_i - 1, 0);
- stiffness k_i = kappa_i / rho_i = s_i factor_i / dt (divergence) or (rho*_i - 1) factor_i / dt^2;
- velocity update v_i -= dt (sum_j (k_i + k_j) g_ij + k_i sum_b g_ib).

Errors are averaged over the active fluid particles only. Both solvers warm-start from the summed
stiffness of the previous step (the divergence solver at half strength, as in SPlisHSPlasH), stored
independent of dt, where the particle is compressed: the divergence solver judges that from the source
measured by the neighbourhood pass, the density solver from the density predicted by the non-pressure
pass (:mod:`fluidsim.viscosity`), so neither start reads the neighbour lists.
"""

import taichi as ti

from .neighbors import FREE_SURFACE_NEIGHBORS, unpack_pair
from .reductions import ordered_sum

# Modes of the source passes.
ITERATE = 0  # stiffness from the current error
FIRST = 1  # as ITERATE, and reset the accumulated stiffness
WARM = 2  # stiffness from the previous step's value, where the particle is compressed now (start passes)


@ti.func
def velocity_divergence(i, x: ti.template(), v: ti.template(), fluid_count: ti.template(),
                        fluid_pairs: ti.template(), boundary_grad_sum: ti.template()):
    """s_i = sum_j (v_i - v_j) . V_j grad W_ij + v_i . sum_b V_b grad W_ib (1/s); boundary is at rest."""
    xi = x[i]
    vi = v[i]
    s = vi.dot(boundary_grad_sum[i])
    for k in range(fluid_count[i]):
        j, c = unpack_pair(fluid_pairs[i, k])
        s += c * (vi - v[j]).dot(xi - x[j])
    return s


@ti.kernel
def divergence_error(
    n: ti.i32,
    dt: float,
    x: ti.types.ndarray(ndim=1),
    v: ti.types.ndarray(ndim=1),
    fluid_count: ti.types.ndarray(dtype=ti.i32, ndim=1),
    fluid_pairs: ti.types.ndarray(ndim=2),
    boundary_count: ti.types.ndarray(dtype=ti.i32, ndim=1),
    boundary_grad_sum: ti.types.ndarray(ndim=1),
    factor: ti.types.ndarray(ndim=1),
    source: ti.types.ndarray(ndim=1),
    stiffness: ti.types.ndarray(ndim=1),
    partial: ti.types.ndarray(dtype=ti.f64, ndim=1),
) -> ti.f64:
    """Divergence-free solver, error pass (ITERATE): s_i and k_i; returns the average s_i over fluid (1/s).

    The solve starts with :func:`start_divergence` (the neighbourhood pass measured the first source),
    and a pass that may end the solve is :func:`fluidsim.viscosity.forces_and_divergence_error`, which
    computes the same s_i and k_i.
    """
    for i in range(n):
        s = velocity_divergence(i, x, v, fluid_count, fluid_pairs, boundary_grad_sum)
        if s < 0.0 or fluid_count[i] + boundary_count[i] < FREE_SURFACE_NEIGHBORS:
            s = 0.0
        source[i] = s
        stiffness[i] = s * factor[i] / dt
    return ordered_sum(source, n, partial) / ti.max(n, 1)


@ti.kernel
def start_divergence(
    n: ti.i32,
    dt: float,
    mode: ti.i32,
    warm_scale: float,
    source: ti.types.ndarray(ndim=1),
    factor: ti.types.ndarray(ndim=1),
    kappa: ti.types.ndarray(ndim=1),
    stiffness: ti.types.ndarray(ndim=1),
    stiffness_sum: ti.types.ndarray(ndim=1),
    partial: ti.types.ndarray(dtype=ti.f64, ndim=1),
) -> ti.f64:
    """Divergence-free solver, start (FIRST or WARM) from the source s_i of the neighbourhood pass.

    Returns the average s_i over fluid (1/s); resets the accumulated stiffness.
    """
    for i in range(n):
        s = source[i]
        k = s * factor[i] / dt
        if mode == WARM:
            k = 0.0
            if s > 0.0:
                k = warm_scale * kappa[i] / dt
        stiffness[i] = k
        stiffness_sum[i] = 0.0
    return ordered_sum(source, n, partial) / ti.max(n, 1)


@ti.kernel
def density_error(
    n: ti.i32,
    dt: float,
    mode: ti.i32,
    x: ti.types.ndarray(ndim=1),
    v: ti.types.ndarray(ndim=1),
    fluid_count: ti.types.ndarray(dtype=ti.i32, ndim=1),
    fluid_pairs: ti.types.ndarray(ndim=2),
    boundary_grad_sum: ti.types.ndarray(ndim=1),
    density: ti.types.ndarray(ndim=1),
    factor: ti.types.ndarray(ndim=1),
    source: ti.types.ndarray(ndim=1),
    stiffness: ti.types.ndarray(ndim=1),
    stiffness_sum: ti.types.ndarray(ndim=1),
    partial: ti.types.ndarray(dtype=ti.f64, ndim=1),
) -> ti.f64:
    """Constant-density solver, error pass (ITERATE or FIRST): rho*_i - 1 and k_i; returns the average error.

    The warm start needs no pass of its own: :func:`start_density` reads the density predicted by the
    non-pressure pass.
    """
    for i in range(n):
        s = velocity_divergence(i, x, v, fluid_count, fluid_pairs, boundary_grad_sum)
        err = ti.max(density[i] + dt * s - 1.0, 0.0)
        source[i] = err
        stiffness[i] = err * factor[i] / (dt * dt)
        if mode != ITERATE:
            stiffness_sum[i] = 0.0
    return ordered_sum(source, n, partial) / ti.max(n, 1)


@ti.kernel
def start_density(
    n: ti.i32,
    dt: float,
    warm_scale: float,
    prediction: ti.types.ndarray(ndim=1),
    kappa: ti.types.ndarray(ndim=1),
    stiffness: ti.types.ndarray(ndim=1),
    stiffness_sum: ti.types.ndarray(ndim=1),
):
    """Constant-density solver, warm start: k_i = warm_scale kappa_i / dt^2 where the predicted density
    rho*_i (from :func:`fluidsim.viscosity.forces_and_divergence_error`) exceeds rest, else 0; resets the
    accumulated stiffness."""
    for i in range(n):
        k = 0.0
        if prediction[i] > 1.0:
            k = warm_scale * kappa[i] / (dt * dt)
        stiffness[i] = k
        stiffness_sum[i] = 0.0


@ti.kernel
def apply_stiffness(
    n: ti.i32,
    dt: float,
    x: ti.types.ndarray(ndim=1),
    v: ti.types.ndarray(ndim=1),
    fluid_count: ti.types.ndarray(dtype=ti.i32, ndim=1),
    fluid_pairs: ti.types.ndarray(ndim=2),
    boundary_grad_sum: ti.types.ndarray(ndim=1),
    stiffness: ti.types.ndarray(ndim=1),
    stiffness_sum: ti.types.ndarray(ndim=1),
):
    """Velocity update of both solvers: v_i -= dt (sum_j (k_i + k_j) g_ij + k_i sum_b g_ib)."""
    for i in range(n):
        xi = x[i]
        ki = stiffness[i]
        dv = ki * boundary_grad_sum[i]
        for k in range(fluid_count[i]):
            j, c = unpack_pair(fluid_pairs[i, k])
            dv += ((ki + stiffness[j]) * c) * (xi - x[j])
        v[i] -= dt * dv
        stiffness_sum[i] += ki


@ti.kernel
def store_stiffness(n: ti.i32, scale: float, stiffness_sum: ti.types.ndarray(ndim=1),
                    kappa: ti.types.ndarray(ndim=1)):
    """Warm-start memory: the step's summed stiffness times dt (divergence) or dt^2 (density)."""
    for i in range(n):
        kappa[i] = stiffness_sum[i] * scale


@ti.kernel
def advect(n: ti.i32, dt: float, x: ti.types.ndarray(ndim=1), v: ti.types.ndarray(ndim=1)) -> ti.types.vector(
        2, ti.f64):
    """x_i += dt v_i; returns (max speed in m/s, number of non-finite velocities)."""
    vmax = 0.0
    bad = 0
    for i in range(n):
        vi = v[i]
        sp = vi.norm()
        if not (sp <= 1.0e30):  # NaN or Inf
            bad += 1
        else:
            ti.atomic_max(vmax, sp)
        x[i] += dt * vi
    return ti.Vector([ti.cast(vmax, ti.f64), ti.cast(bad, ti.f64)])
