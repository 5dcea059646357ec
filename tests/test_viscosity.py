"""The non-pressure pass (viscosity, gravity) and what rides on it: its acceleration equals the numpy twin,
its divergence error equals the solver's stand-alone error pass, its Eq. 1 equals the numpy twin, and the
density prediction is rho_i + dt (s_i + dt a_i . sum_b V_b grad W_ib)."""

import numpy as np
import pytest

from fluidsim import dfsph
from fluidsim.config import SolverConfig
from fluidsim.divergence import divergence_np
from fluidsim.kernels import cubic_grad_w_np
from fluidsim.neighbors import FREE_SURFACE_NEIGHBORS
from fluidsim.scene import lattice_in_box
from fluidsim.solver import DFSPHSolver
from fluidsim.viscosity import non_pressure_np


def _solver(mu_b):
    rng = np.random.default_rng(3)
    cfg = SolverConfig(particle_radius=0.025, viscosity=4.0, boundary_viscosity=mu_b)
    x = lattice_in_box([0.3, 0.3, 0.3], [0.6, 0.6, 0.6], cfg.spacing) + rng.normal(0, 0.004, (216, 3))
    v = rng.normal(0, 1.0, x.shape)
    wall = lattice_in_box([0.3, 0.2, 0.3], [0.6, 0.3, 0.6], cfg.spacing) - [0, 0.002, 0]
    solver = DFSPHSolver(cfg, [0, 0, 0], [1, 1, 1], x, v, wall)
    solver._sort()
    solver._neighborhoods()
    return cfg, solver


@pytest.mark.parametrize("mu_b", [0.0, 2.5])  # free-slip walls skip the boundary list; no-slip walls read it
def test_forces_pass_matches_numpy_twins(mu_b):
    cfg, solver = _solver(mu_b)
    f, b, nb = solver.fluid, solver.boundary, solver.neighborhoods
    dt = cfg.dt
    xs, vs, rho = f.numpy("x").astype(np.float64), f.numpy("v").astype(np.float64), f.numpy("density")
    bx, bvol = b.x.to_numpy()[: b.count].astype(np.float64), b.volume.to_numpy()[: b.count]
    avg = solver._forces_pass(dt, True)
    np.testing.assert_array_equal(f.numpy("v"), vs.astype(np.float32))  # the pass reads v, never writes it

    acc = f.numpy("acceleration")
    ref = non_pressure_np(xs, vs, rho, solver.fluid_volume, bx, bvol, cfg.support_radius, cfg.viscosity, mu_b,
                          cfg.rest_density, cfg.gravity)
    visc = ref - np.asarray(cfg.gravity)
    assert np.abs(visc).max() > 1.0  # the viscous part is far from negligible here
    np.testing.assert_allclose(acc, ref, rtol=2e-3, atol=2e-3 * np.abs(visc).max())

    d_ref = divergence_np(xs, vs, solver.fluid_volume / rho, bx, bvol, 0.1, 0.1)
    np.testing.assert_allclose(f.numpy("divergence"), d_ref, rtol=2e-3, atol=2e-3 * d_ref.max())

    # s_i (B&K) by numpy, clamped like the solver, and the density prediction
    h = cfg.support_radius
    s_raw, grad_b = np.zeros(len(xs)), np.zeros((len(xs), 3))
    for i in range(len(xs)):
        r = xs[i] - xs
        near = (np.sum(r * r, 1) < h * h) & (np.arange(len(xs)) != i)
        rb = xs[i] - bx
        nearb = np.sum(rb * rb, 1) < h * h
        grad_b[i] = (bvol[nearb, None] * cubic_grad_w_np(rb[nearb], h)).sum(0)
        s_raw[i] = np.sum((vs[i] - vs[near]) * solver.fluid_volume * cubic_grad_w_np(r[near], h)) + vs[i] @ grad_b[i]
    counts = nb.fluid_count.to_numpy()[: f.active] + nb.boundary_count.to_numpy()[: f.active]
    s_ref = np.where((s_raw < 0) | (counts < FREE_SURFACE_NEIGHBORS), 0.0, s_raw)
    scale = np.abs(s_raw).max()
    np.testing.assert_allclose(f.numpy("source"), s_ref, atol=2e-3 * scale)
    np.testing.assert_allclose(avg, s_ref.mean(), rtol=5e-3)
    pred_ref = rho + dt * (s_raw + dt * np.sum(ref * grad_b, axis=1))
    np.testing.assert_allclose(f.numpy("prediction"), pred_ref, atol=2e-3 * dt * scale)
    assert (f.numpy("prediction") > 1.0).any() and (f.numpy("prediction") < 1.0).any()


def test_forces_pass_is_the_divergence_solvers_error_pass():
    cfg, solver = _solver(0.0)
    f, nb = solver.fluid, solver.neighborhoods
    dt = cfg.dt
    stand_alone = dfsph.divergence_error(f.active, dt, f.x, f.v, nb.fluid_count, nb.fluid_pairs,
                                         nb.boundary_count, nb.boundary_grad_sum, f.factor, f.source, f.stiffness,
                                         solver._partial)
    src, k = f.numpy("source"), f.numpy("stiffness")
    assert (src > 0).sum() > 10
    fused = solver._forces_pass(dt, False)
    assert fused == pytest.approx(stand_alone, rel=1e-6)
    np.testing.assert_allclose(f.numpy("source"), src, rtol=1e-5, atol=1e-6 * src.max())
    np.testing.assert_allclose(f.numpy("stiffness"), k, rtol=1e-5, atol=1e-6 * np.abs(k).max())


def test_commit_applies_the_stored_forces_once():
    cfg, solver = _solver(0.0)
    f = solver.fluid
    v0 = f.numpy("v").astype(np.float64)
    solver._non_pressure_forces(cfg.dt, estimate=True)
    acc = f.numpy("acceleration")
    np.testing.assert_allclose(f.numpy("v"), v0 + cfg.dt * acc, rtol=1e-6, atol=1e-6)
    sums, counts = solver.divergence_accumulation()
    assert counts.min() == 1 and counts.max() == 1
