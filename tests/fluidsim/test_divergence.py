"""Paper Eq. 1: the divergence of a linear field is tr(A); every fast path (the stand-alone passes and the
one fused into the viscosity pass) equals the numpy twin."""

import numpy as np
import pytest

from fluidsim.config import SolverConfig
from fluidsim.estimator import divergence_estimate_np
from fluidsim.kernels import cubic_grad_w_np
from fluidsim.scene import lattice_in_box
from fluidsim.solver import DFSPHSolver, fluid_particle_volume

A = np.array([[0.7, 0.2, -0.1], [0.3, -0.4, 0.5], [0.1, 0.2, 0.9]])  # tr(A) = 1.2


def solver_volume(cfg):
    return fluid_particle_volume(cfg.spacing, cfg.support_radius)


def _estimate(config, x, v, boundary=None, fused=False):
    """D_i by the stand-alone estimator pass, or (``fused``) by the viscosity pass of a time step."""
    boundary = np.zeros((0, 3)) if boundary is None else boundary
    solver = DFSPHSolver(config, [0, 0, 0], [1, 1, 1], x, v, boundary)
    solver.sort()
    solver.find_neighborhoods()
    f = solver.fluid
    vs = f.numpy("v")
    if fused:
        assert solver.estimate_in_non_pressure_pass
        solver.non_pressure_forces(config.dt, estimate=True)
    else:
        solver.divergence_estimate()
    # (the fused pass also adds D_i to the run sums)
    return solver, f.numpy("x"), vs, f.numpy("density"), f.numpy("divergence")


@pytest.mark.parametrize("h_r", [0.1, 0.13])  # 0.1: stored-gradient path; 0.13 > h: grid path
def test_linear_field_gives_trace_at_interior_particles(h_r):
    cfg = SolverConfig(particle_radius=0.025, estimator_radius=h_r, estimator_kernel_radius=h_r)
    x = lattice_in_box([0.2, 0.2, 0.2], [0.8, 0.8, 0.8], cfg.spacing)
    v = x @ A.T
    _, xs, _, _, d = _estimate(cfg, x, v)
    interior = np.all((xs > 0.2 + 1.5 * h_r) & (xs < 0.8 - 1.5 * h_r), axis=1)
    assert interior.sum() > 20
    # Stated tolerance: 2.5 % of tr(A). The lattice sum of the cubic spline at h = 2 spacings is
    # sum_j V (x_j - x_i) (x) grad W = c I with c about 1.02; beyond that only f32 round-off remains.
    np.testing.assert_allclose(d[interior], abs(np.trace(A)), rtol=0.025)
    ax = np.arange(-4, 5) * cfg.spacing
    offs = np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), -1).reshape(-1, 3)
    offs = offs[(np.linalg.norm(offs, axis=1) <= h_r) & (np.linalg.norm(offs, axis=1) > 0)]
    c = np.sum(solver_volume(cfg) * offs[:, 0] * cubic_grad_w_np(-offs, h_r)[:, 0])
    np.testing.assert_allclose(d[interior], c * abs(np.trace(A)), rtol=1e-4)


@pytest.mark.parametrize(
    "h_r,h_k,fused",
    [
        (0.1, 0.1, False),
        (0.1, 0.1, True),
        (0.12, 0.1, True),
        (0.08, 0.1, False),
        (0.15, 0.12, False),
        (0.12, 0.1, False),
    ],
)
def test_fast_paths_match_numpy_twin(h_r, h_k, fused):
    rng = np.random.default_rng(7)
    cfg = SolverConfig(particle_radius=0.025, estimator_radius=h_r, estimator_kernel_radius=h_k)
    x = lattice_in_box([0.3, 0.3, 0.3], [0.6, 0.6, 0.6], cfg.spacing) + rng.normal(0, 0.004, (216, 3))
    v = rng.normal(0, 1.0, x.shape)
    wall = lattice_in_box([0.3, 0.2, 0.3], [0.6, 0.3, 0.6], cfg.spacing)[:, :] - [0, 0.002, 0]
    solver, xs, vs, rho, d = _estimate(cfg, x, v, wall, fused)
    b = solver.boundary
    ref = divergence_estimate_np(
        xs, vs, solver.fluid_volume / rho, b.x.to_numpy()[: b.count], b.volume.to_numpy()[: b.count], h_r, h_k
    )
    np.testing.assert_allclose(d, ref, rtol=2e-3, atol=2e-3 * ref.max())
    sums, counts = solver.divergence_accumulation()
    assert counts.min() == 1 and counts.max() == 1
    np.testing.assert_allclose(np.sort(sums), np.sort(d), rtol=1e-6)
