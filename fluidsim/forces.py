"""The force the fluid exerts on the static boundary: on the solid, and on the walls apart from it.

The boundary is modelled as in Akinci et al. (2012, "Versatile rigid-fluid coupling for incompressible SPH"): each
boundary particle b has a volume V_b and enters the fluid's sums through g_ib = V_b grad W(x_i - x_b, h). The
boundary is at rest, so every force it exerts on the fluid has an equal and opposite reaction on it (Newton's third
law, Akinci et al. Eq. 9-10; SPlisHSPlasH's ``BoundaryModel::addForce``), and the force on the boundary is the sum
of those reactions. Per fluid particle i of mass m = rho_0 V_f and per step (the equation labels of
:mod:`fluidsim.solver`):

- **pressure** (E5): both DFSPH solvers change v_i by -dt k_i sum_b g_ib through the boundary, summed over their
  iterations and warm starts (W1, W2). The positions are fixed inside a step, so the sum factors: the boundary's
  share of the step's velocity change is -dt K_i sum_b g_ib with K_i = kappa_i^div / dt + kappa_i^dens / dt^2, the
  summed stiffness the solvers store for their warm start (W3). The reaction on the boundary is m K_i sum_b g_ib;
- **viscosity** (E7): the boundary's share a_b,i of the non-pressure acceleration (:mod:`fluidsim.viscosity`, the
  fluid-boundary friction with mu_b = ``boundary_viscosity``), whose reaction is -m a_b,i.

    F_solid = sum_i m (K_i sum_{b in solid} g_ib - a_s,i),    F_walls = sum_i m (K_i sum_{b in walls} g_ib - a_w,i)

in newtons, in the simulation frame. Gravity acts on the fluid only, so over a step the momentum balance of the
fluid is sum_i m (v_i' - v_i) / dt = M g - F_solid - F_walls: the fluid-fluid terms cancel pairwise (both are
antisymmetric in i and j). The force is the step's mean force (its impulse over dt).

The sums are taken per block of :data:`BLOCK` particles, each block's serially in f64, and the blocks' partial sums
in numpy (:func:`boundary_forces`), so a run gives the same bits on any number of threads.
:func:`boundary_forces_np` is the O(N M) numpy twin from the positions.
"""

import numpy as np
import taichi as ti

from .host_copy import rows_to_numpy
from .kernels import cubic_grad_w_np
from .launch import fast_kernel
from .viscosity import LAPLACIAN_EPS, LAPLACIAN_FACTOR

BLOCK = 4096  # fluid particles per partial sum
vec6d = ti.types.vector(6, ti.f64)


@fast_kernel
def force_partials(
    n: ti.i32,
    block: ti.i32,
    inv_dt: ti.f64,
    inv_dt2: ti.f64,
    mass: ti.f64,
    kappa_divergence: ti.types.ndarray(ndim=1),
    kappa_density: ti.types.ndarray(ndim=1),
    boundary_grad_sum: ti.types.ndarray(ndim=1),
    solid_grad_sum: ti.types.ndarray(ndim=1),
    boundary_viscous: ti.types.ndarray(ndim=1),
    solid_viscous: ti.types.ndarray(ndim=1),
    partial: ti.types.ndarray(dtype=vec6d, ndim=1),
):
    """Per block of ``block`` fluid particles: (F on the solid, F on the whole boundary), N, summed in f64.

    ``inv_dt`` is 1 / dt when the divergence solver stored its kappa this step, else 0."""
    blocks = (n + block - 1) // block
    for b in range(blocks):
        fs = ti.Vector([0.0, 0.0, 0.0], ti.f64)
        fb = ti.Vector([0.0, 0.0, 0.0], ti.f64)
        for i in range(b * block, ti.min(n, (b + 1) * block)):
            k = ti.cast(kappa_divergence[i], ti.f64) * inv_dt + ti.cast(kappa_density[i], ti.f64) * inv_dt2
            fs += mass * (k * ti.cast(solid_grad_sum[i], ti.f64) - ti.cast(solid_viscous[i], ti.f64))
            fb += mass * (k * ti.cast(boundary_grad_sum[i], ti.f64) - ti.cast(boundary_viscous[i], ti.f64))
        partial[b] = vec6d(fs[0], fs[1], fs[2], fb[0], fb[1], fb[2])


class BoundaryForces:
    """The scratch of :func:`boundary_forces` for one fluid set (the partial sums, allocated once)."""

    def __init__(self, capacity: int):
        self.partial = ti.ndarray(vec6d, shape=max((capacity + BLOCK - 1) // BLOCK, 1))


def boundary_forces(fluid, lists, scratch: BoundaryForces, dt: float, mass: float, divergence_ran: bool):
    """The step's force on the solid and on the walls, N (module docstring).

    Args:
        fluid: :class:`~fluidsim.particles.FluidParticles` after the density solve (kappas of this step).
        lists: :class:`~fluidsim.particles.Neighborhoods` of this step (the boundary gradient sums).
        scratch: the partial sums. dt: this step's time step, s. mass: m = rho_0 V_f, kg.
        divergence_ran: whether the divergence solver stored kappa this step.
    Returns:
        (solid (3,), walls (3,)) float64, N.
    """
    n = fluid.active
    if n == 0:
        return np.zeros(3), np.zeros(3)
    force_partials(
        n,
        BLOCK,
        1.0 / dt if divergence_ran else 0.0,
        1.0 / (dt * dt),
        mass,
        fluid.kappa_divergence,
        fluid.kappa_density,
        lists.boundary_grad_sum,
        lists.solid_grad_sum,
        fluid.boundary_viscous,
        fluid.solid_viscous,
        scratch.partial,
    )
    blocks = (n + BLOCK - 1) // BLOCK
    total = rows_to_numpy(scratch.partial, blocks).sum(0)
    return total[:3], total[3:] - total[:3]


def boundary_forces_np(
    x: np.ndarray,
    v: np.ndarray,
    stiffness: np.ndarray,
    density: np.ndarray,
    boundary_x: np.ndarray,
    boundary_volumes: np.ndarray,
    solid: np.ndarray,
    h: float,
    mass: float,
    mu_boundary: float,
    rest_density: float,
) -> tuple[np.ndarray, np.ndarray]:
    """O(N M) numpy twin of :func:`boundary_forces`, from the positions.

    Args:
        x, v: (N, 3) fluid positions (m, at the step's neighbourhood pass) and the velocities the non-pressure pass
            read (m/s). stiffness: (N,) K_i, the step's summed stiffness of both solvers, m^2/s^2.
        density: (N,) rho_i / rho_0. boundary_x: (M, 3) m. boundary_volumes: (M,) V_b, m^3. solid: (M,) bool.
        h: support radius, m. mass: m = rho_0 V_f, kg. mu_boundary: Pa s. rest_density: kg/m^3.
    Returns:
        (F on the solid (3,), F on the walls (3,)), N.
    Example:
        >>> boundary_forces_np(np.zeros((1, 3)), np.zeros((1, 3)), np.ones(1), np.ones(1), np.array([[0.05, 0, 0]]),
        ...                    np.ones(1) * 1e-4, np.ones(1, bool), 0.1, 0.1, 0.0, 1000.0)[0][0] > 0
        True
    """
    x = np.asarray(x, np.float64)
    bx = np.asarray(boundary_x, np.float64).reshape(-1, 3)
    vol = np.asarray(boundary_volumes, np.float64)
    solid = np.asarray(solid, bool)
    eps = LAPLACIAN_EPS * h * h
    out = {True: np.zeros(3), False: np.zeros(3)}
    for i in range(len(x)):
        r = x[i] - bx
        near = np.sum(r * r, axis=1) < h * h
        if not near.any():
            continue
        g = vol[near, None] * cubic_grad_w_np(r[near], h)
        lap = ((r[near] @ np.asarray(v[i], np.float64)) / (np.sum(r[near] ** 2, axis=1) + eps))[:, None] * g
        f = mass * stiffness[i] * g - mass * mu_boundary * LAPLACIAN_FACTOR * lap / (rest_density * density[i])
        for part in (True, False):
            out[part] += f[solid[near] == part].sum(0)
    return out[True], out[False]


def force_history(history) -> dict[str, dict[str, np.ndarray]]:
    """The forces of a run's step statistics: per part ("solid", "walls"), the series (S, 3) N, its dt-weighted
    time mean over the second half of the run (3,) N, and the impulse over the whole run (3,) N s."""
    dt = np.array([s.dt for s in history], np.float64)
    half = len(history) // 2
    out = {}
    for part, attr in (("solid", "solid_force"), ("walls", "wall_force")):
        series = np.array([getattr(s, attr) for s in history], np.float64).reshape(-1, 3)
        w = dt[half:]
        mean = (series[half:] * w[:, None]).sum(0) / w.sum() if w.sum() > 0 else np.zeros(3)
        out[part] = {"series": series, "mean": mean, "impulse": (series * dt[:, None]).sum(0)}
    return out
