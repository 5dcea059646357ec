"""Divergence-free SPH (Bender & Koschier 2015, 2017): the passes of both pressure solvers.

The divergence-free solver (correctDivergenceError of Algorithm 1, the step's ``divergence_solve``) drives the
velocity divergence to zero; it is not the divergence *estimate* D_i of the paper (:mod:`fluidsim.estimator`).
All quantities are normalised by the rest density (as in SPlisHSPlasH): densities are rho / rho_0 and
neighbour weights are volumes V_j. With ``g_ij = V_j grad W(x_i - x_j, h) = c_ij (x_i - x_j)``, c_ij
stored by the neighbourhood pass (:mod:`fluidsim.neighbors`), and the equation labels of :mod:`fluidsim.solver`:

- velocity divergence source (E3, divergence-free solver):
  s_i = D(rho_i/rho_0)/Dt = sum_j (v_i - v_j) . g_ij + v_i . sum_b g_ib, clamped at 0 (the boundary is
  static, so its gradients enter only through their sum, stored once per step);
- predicted density (E6, constant-density solver): rho*_i = rho_i + dt s_i, error max(rho*_i - 1, 0);
- stiffness (E4) k_i = kappa_i / rho_i = s_i factor_i / dt (divergence) or (rho*_i - 1) factor_i / dt^2;
- velocity update (E5) v_i -= dt (sum_j (k_i + k_j) g_ij + k_i sum_b g_ib).

Errors are averaged over the active fluid particles only, as fixed-point sums (:mod:`fluidsim.reductions`:
the same bits on any number of threads, summed inside the error pass). Each iteration is one error pass (the
average error, and the stiffness k_i of the Jacobi update) and one velocity update; the solve ends after
the update of the iteration whose measured error met the tolerance (with at least the minimum number of
iterations), so the last update is always applied, as in SPlisHSPlasH: its check reads the error before
that iteration's update, and the final state is at least that accurate.

Warm start (B&K 2017; W1-W3): both solvers start from the summed stiffness kappa of the previous step (stored
independent of dt, W3), applied as one velocity change -dt (k_i sum_k g_ik + sum_j k_j g_ij) that needs no
list pass of its own:
- divergence-free solver: k_i = kappa_i / (2 dt) for every particle (half strength, as SPlisHSPlasH's
  stiffness-based DFSPH). The change depends only on the positions and the stored kappa, so the
  neighbourhood pass sums it (the "push" P_i, :func:`fluidsim.neighbors.build_neighborhoods`) and applies
  it;
- constant-density solver: k_i = kappa_i / dt^2 where the particle is compressing after the divergence
  solve (:func:`density_warm_record`, written by the divergence solver's error pass), else 0, so the start is
  symmetric and moves no particle that is not pushed by a compressed neighbour (a start from every
  particle's kappa was measured to double the splash speeds). The non-pressure pass sums the push and
  applies it with the non-pressure forces, v*_i = v_i + dt a_i - P_i / dt
  (:func:`fluidsim.viscosity.predict_velocities`).
"""

import taichi as ti

from .launch import fast_kernel
from .neighbors import FREE_SURFACE_NEIGHBORS, fluid_pair
from .reductions import quanta_average, quantum_cap, to_quanta

DIVERGENCE_WARM_SCALE = 0.5  # the divergence solver warm-starts at half strength (SPlisHSPlasH)


@ti.func
def with_stiffness(x, k):
    """The record (x_0, x_1, x_2, k) the velocity update gathers per neighbour."""
    return ti.Vector([x[0], x[1], x[2], k])


@ti.func
def velocity_divergence(
    i,
    x: ti.template(),
    v: ti.template(),
    fluid_count: ti.template(),
    fluid_pairs: ti.template(),
    grad_sum: ti.template(),
    fmt: ti.template(),
    inv_scale,
):
    """s_i = sum_j (v_i - v_j) . V_j grad W_ij + v_i . sum_b V_b grad W_ib (1/s); boundary is at rest.

    Evaluated as v_i . G_i - sum_j c_ij v_j . (x_i - x_j) with the stored G_i = sum_j g_ij + sum_b g_ib,
    three operations fewer per pair.
    """
    xi = x[i]
    s = v[i].dot(grad_sum[i])
    for k in range(fluid_count[i]):
        j, c = fluid_pair(fluid_pairs, i, k, fmt, inv_scale)
        s -= c * v[j].dot(xi - x[j])
    return s


@ti.func
def density_warm_record(
    i,
    dt,
    warm,
    gravity,
    x: ti.template(),
    density: ti.template(),
    source: ti.template(),
    boundary_grad_sum: ti.template(),
    kappa: ti.template(),
):
    """The record (x_i, w_i) of the constant-density solver's warm start: w_i = kappa_i where the particle is
    compressing after the divergence solve, rho_i + dt (s_i + dt g . sum_b g_ib) > 1 (s_i the last divergence
    source measured, clamped at 0), else 0 (and 0 everywhere without ``warm``)."""
    w = 0.0 * kappa[i]
    if warm and density[i] + dt * (source[i] + dt * gravity.dot(boundary_grad_sum[i])) > 1.0:
        w = kappa[i]
    return with_stiffness(x[i], w)


@fast_kernel
def divergence_solve_error(
    n: ti.i32,
    dt: float,
    x: ti.types.ndarray(ndim=1),
    v: ti.types.ndarray(ndim=1),
    fluid_count: ti.types.ndarray(dtype=ti.i32, ndim=1),
    fluid_pairs: ti.types.ndarray(ndim=2),
    fmt: ti.template(),
    inv_scale: float,
    boundary_count: ti.types.ndarray(dtype=ti.i32, ndim=1),
    grad_sum: ti.types.ndarray(ndim=1),
    factor: ti.types.ndarray(ndim=1),
    source: ti.types.ndarray(ndim=1),
    position_stiffness: ti.types.ndarray(ndim=1),
    inv_quantum: ti.f64,
    warm_density: ti.i32,
    gravity: ti.types.vector(3, float),
    density: ti.types.ndarray(ndim=1),
    boundary_grad_sum: ti.types.ndarray(ndim=1),
    kappa_density: ti.types.ndarray(ndim=1),
    density_record: ti.types.ndarray(ndim=1),
) -> ti.f64:
    """Divergence-free solver, error pass: s_i (clamped at 0, and 0 at the free surface) and k_i; returns
    the average s_i over fluid (1/s). A cold start takes its first s_i from the neighbourhood pass instead
    (:func:`divergence_solve_cold_start`).

    Also writes the constant-density solver's warm-start record from this s_i (:func:`density_warm_record`,
    ``warm_density`` = 1 for a warm start): the last error pass of the divergence solve leaves the records the
    non-pressure pass reads, so they cost no pass and no launch of their own (:func:`density_warm_stiffness`
    writes them when no error pass ran).
    """
    cap = quantum_cap(n)
    total = ti.i64(0)
    over = ti.i64(0)
    for i in range(n):
        s = velocity_divergence(i, x, v, fluid_count, fluid_pairs, grad_sum, fmt, inv_scale)
        if s < 0.0 or fluid_count[i] + boundary_count[i] < FREE_SURFACE_NEIGHBORS:
            s = 0.0
        source[i] = s
        q, o = to_quanta(s, inv_quantum, cap)
        total += q
        over += o
        position_stiffness[i] = with_stiffness(x[i], s * factor[i] / dt)
        density_record[i] = density_warm_record(
            i, dt, warm_density, gravity, x, density, source, boundary_grad_sum, kappa_density
        )
    return quanta_average(total, over, n, inv_quantum)


@fast_kernel
def divergence_solve_cold_start(
    n: ti.i32,
    dt: float,
    source: ti.types.ndarray(ndim=1),
    factor: ti.types.ndarray(ndim=1),
    x: ti.types.ndarray(ndim=1),
    position_stiffness: ti.types.ndarray(ndim=1),
    stiffness_sum: ti.types.ndarray(ndim=1),
    inv_quantum: ti.f64,
) -> ti.f64:
    """Divergence-free solver, cold start: the first stiffness k_i = s_i factor_i / dt from the source of the
    neighbourhood pass (whose average, returned in 1/s, is then the first error, known without a pass) and an
    empty stiffness sum. The warm start happens in the neighbourhood pass
    (:func:`fluidsim.neighbors.build_neighborhoods`)."""
    cap = quantum_cap(n)
    total = ti.i64(0)
    over = ti.i64(0)
    for i in range(n):
        position_stiffness[i] = with_stiffness(x[i], source[i] * factor[i] / dt)
        stiffness_sum[i] = 0.0
        q, o = to_quanta(source[i], inv_quantum, cap)
        total += q
        over += o
    return quanta_average(total, over, n, inv_quantum)


@fast_kernel
def undo_push(n: ti.i32, warm_scale: float, push: ti.types.ndarray(ndim=1), v: ti.types.ndarray(ndim=1)):
    """v_i += warm_scale P_i: takes back the divergence warm start of a neighbourhood pass that must run again."""
    for i in range(n):
        v[i] += warm_scale * push[i]


@fast_kernel
def density_solve_error(
    n: ti.i32,
    dt: float,
    x: ti.types.ndarray(ndim=1),
    v: ti.types.ndarray(ndim=1),
    fluid_count: ti.types.ndarray(dtype=ti.i32, ndim=1),
    fluid_pairs: ti.types.ndarray(ndim=2),
    fmt: ti.template(),
    inv_scale: float,
    grad_sum: ti.types.ndarray(ndim=1),
    density: ti.types.ndarray(ndim=1),
    factor: ti.types.ndarray(ndim=1),
    source: ti.types.ndarray(ndim=1),
    position_stiffness: ti.types.ndarray(ndim=1),
    inv_quantum: ti.f64,
) -> ti.f64:
    """Constant-density solver, error pass: rho*_i - 1 (clamped at 0) and k_i; returns the average error."""
    cap = quantum_cap(n)
    total = ti.i64(0)
    over = ti.i64(0)
    for i in range(n):
        s = velocity_divergence(i, x, v, fluid_count, fluid_pairs, grad_sum, fmt, inv_scale)
        err = ti.max(density[i] + dt * s - 1.0, 0.0)
        source[i] = err
        q, o = to_quanta(err, inv_quantum, cap)
        total += q
        over += o
        position_stiffness[i] = with_stiffness(x[i], err * factor[i] / (dt * dt))
    return quanta_average(total, over, n, inv_quantum)


@fast_kernel
def density_warm_stiffness(
    n: ti.i32,
    dt: float,
    warm: ti.i32,
    gravity: ti.types.vector(3, float),
    x: ti.types.ndarray(ndim=1),
    density: ti.types.ndarray(ndim=1),
    source: ti.types.ndarray(ndim=1),
    boundary_grad_sum: ti.types.ndarray(ndim=1),
    kappa: ti.types.ndarray(ndim=1),
    density_record: ti.types.ndarray(ndim=1),
):
    """Constant-density solver, warm-start records (:func:`density_warm_record`) as a pass of its own: for the
    steps whose divergence solve ran no error pass (a cold start that met its tolerance at once, or no
    divergence solver); otherwise :func:`divergence_solve_error` writes them."""
    for i in range(n):
        density_record[i] = density_warm_record(i, dt, warm, gravity, x, density, source, boundary_grad_sum, kappa)


@ti.func
def velocity_update(
    i,
    fluid_count: ti.template(),
    fluid_pairs: ti.template(),
    fmt: ti.template(),
    inv_scale,
    grad_sum: ti.template(),
    position_stiffness: ti.template(),
):
    """(dv, k_i) with dv = sum_j (k_i + k_j) g_ij + k_i sum_b g_ib = k_i G_i + sum_j k_j c_ij (x_i - x_j) (G_i the
    stored sum_j g_ij + sum_b g_ib); (x_j, k_j) come as one 16-byte record (``position_stiffness``, written by
    the error passes): one gather per pair instead of two, a third less time per pass on the bench scene."""
    qi = position_stiffness[i]
    xi = ti.Vector([qi[0], qi[1], qi[2]])
    ki = qi[3]
    dv = ki * grad_sum[i]
    for k in range(fluid_count[i]):
        j, c = fluid_pair(fluid_pairs, i, k, fmt, inv_scale)
        q = position_stiffness[j]
        dv += (q[3] * c) * (xi - ti.Vector([q[0], q[1], q[2]]))
    return dv, ki


@fast_kernel
def apply_stiffness(
    n: ti.i32,
    dt: float,
    v: ti.types.ndarray(ndim=1),
    fluid_count: ti.types.ndarray(dtype=ti.i32, ndim=1),
    fluid_pairs: ti.types.ndarray(ndim=2),
    fmt: ti.template(),
    inv_scale: float,
    grad_sum: ti.types.ndarray(ndim=1),
    position_stiffness: ti.types.ndarray(ndim=1),
    stiffness_sum: ti.types.ndarray(ndim=1),
):
    """Velocity update of both solvers: v_i -= dt (sum_j (k_i + k_j) g_ij + k_i sum_b g_ib)
    (:func:`velocity_update`); adds k_i to the step's stiffness sum."""
    for i in range(n):
        dv, ki = velocity_update(i, fluid_count, fluid_pairs, fmt, inv_scale, grad_sum, position_stiffness)
        v[i] -= dt * dv
        stiffness_sum[i] += ki


@fast_kernel
def finish_solve(
    n: ti.i32,
    dt: float,
    v: ti.types.ndarray(ndim=1),
    fluid_count: ti.types.ndarray(dtype=ti.i32, ndim=1),
    fluid_pairs: ti.types.ndarray(ndim=2),
    fmt: ti.template(),
    inv_scale: float,
    grad_sum: ti.types.ndarray(ndim=1),
    position_stiffness: ti.types.ndarray(ndim=1),
    stiffness_sum: ti.types.ndarray(ndim=1),
    store_scale: float,
    kappa: ti.types.ndarray(ndim=1),
    advect: ti.i32,
    x: ti.types.ndarray(ndim=1),
) -> ti.types.vector(2, ti.f64):
    """A solve's last velocity update (:func:`apply_stiffness`) with what follows it per particle, in one launch:
    the warm-start memory kappa_i = (summed stiffness) x ``store_scale`` (dt for the divergence solver, dt^2 for
    the density solver) and, with ``advect`` = 1 (the density solver), x_i += dt v_i. Returns (max speed in
    m/s, number of non-finite velocities) of the updated velocities with ``advect``, else zeros. Writing x_i
    here is safe: the update reads positions from the records, never from x.
    """
    vmax = 0.0
    bad = 0
    for i in range(n):
        dv, ki = velocity_update(i, fluid_count, fluid_pairs, fmt, inv_scale, grad_sum, position_stiffness)
        vi = v[i] - dt * dv
        v[i] = vi
        kappa[i] = (stiffness_sum[i] + ki) * store_scale
        if advect:
            sp = vi.norm()
            if not (sp <= 1.0e30):  # NaN or Inf
                bad += 1
            else:
                ti.atomic_max(vmax, sp)
            x[i] += dt * vi
    return ti.Vector([ti.cast(vmax, ti.f64), ti.cast(bad, ti.f64)])
