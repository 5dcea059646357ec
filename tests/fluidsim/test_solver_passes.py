"""The solver's passes over the neighbour lists against numpy twins on a jittered block by a wall: the error
passes of both DFSPH solvers and the velocity update; the non-pressure pass (viscosity, gravity) and what
rides on it (Eq. 1, the density solver's warm-start push); and the warm starts that need no list pass,
which change the velocities as the numpy twin of the velocity update does with the same stiffness."""

import dataclasses

import numpy as np
import pytest

from fluidsim import neighbors, passes
from fluidsim.config import SolverConfig
from fluidsim.estimator import divergence_estimate_np
from fluidsim.kernels import cubic_grad_w_np
from fluidsim.neighbors import FREE_SURFACE_NEIGHBORS
from fluidsim.reductions import fixed_point_average_np
from fluidsim.scene import lattice_in_box
from fluidsim.solver import DFSPHSolver, WarmStart
from fluidsim.viscosity import non_pressure_np

INV_Q = 2.0**20 / 1e-4  # quanta per unit of the error averages (a density tolerance of 0.01 %)


def _solver(mu_b, kappa_divergence_max=0.0, neighborhoods=True, max_neighbors=64):
    rng = np.random.default_rng(3)
    cfg = SolverConfig(particle_radius=0.025, viscosity=4.0, boundary_viscosity=mu_b, max_neighbors=max_neighbors)
    x = lattice_in_box([0.3, 0.3, 0.3], [0.6, 0.6, 0.6], cfg.spacing) + rng.normal(0, 0.004, (216, 3))
    v = rng.normal(0, 1.0, x.shape)
    wall = lattice_in_box([0.3, 0.2, 0.3], [0.6, 0.3, 0.6], cfg.spacing) - [0, 0.002, 0]
    solver = DFSPHSolver(cfg, [0, 0, 0], [1, 1, 1], x, v, wall)
    solver.sort()
    if kappa_divergence_max:
        kappa = rng.uniform(0.0, kappa_divergence_max, solver.fluid.capacity)
        solver.fluid.kappa_divergence.from_numpy(kappa.astype(np.float32))
    if neighborhoods:
        solver.find_neighborhoods()
    return cfg, solver


def _gradients(solver):
    """Numpy V grad W per fluid pair (dict i -> (neighbour indices, (k, 3) gradients)) and sum_b V_b grad W_ib."""
    f, b, h = solver.fluid, solver.boundary, solver.config.support_radius
    xs = f.numpy("x").astype(np.float64)
    bx, bvol = b.x.to_numpy()[: b.count].astype(np.float64), b.volume.to_numpy()[: b.count]
    pairs, grad_b = {}, np.zeros((len(xs), 3))
    for i in range(len(xs)):
        r = xs[i] - xs
        near = np.nonzero((np.sum(r * r, 1) < h * h) & (np.arange(len(xs)) != i))[0]
        pairs[i] = near, solver.fluid_volume * cubic_grad_w_np(r[near], h)
        rb = xs[i] - bx
        nearb = np.sum(rb * rb, 1) < h * h
        grad_b[i] = (bvol[nearb, None] * cubic_grad_w_np(rb[nearb], h)).sum(0)
    return pairs, grad_b


def _forces_pass(solver, v0, warm, estimate=False):
    """Run the non-pressure pass from velocities ``v0`` (all slots) with the density warm start on or off;
    returns the velocities it predicts (the pass writes the spare buffer, which then becomes v)."""
    f = solver.fluid
    f.v.from_numpy(v0)
    solver.warm = WarmStart(divergence=True, density=warm)
    solver.non_pressure_forces(solver.config.dt, estimate=estimate)  # no error pass ran: it writes the records first
    return f.numpy("v").astype(np.float64)


@pytest.mark.parametrize("mu_b", [0.0, 2.5])  # free-slip walls skip the boundary list; no-slip walls read it
def test_forces_pass_matches_numpy_twins(mu_b):
    cfg, solver = _solver(mu_b)
    f, b = solver.fluid, solver.boundary
    dt = cfg.dt
    xs, vs, rho = f.numpy("x").astype(np.float64), f.numpy("v").astype(np.float64), f.numpy("density")
    bx, bvol = b.x.to_numpy()[: b.count].astype(np.float64), b.volume.to_numpy()[: b.count]
    rng = np.random.default_rng(5)
    f.kappa_density.from_numpy(rng.uniform(0.0, 1e-3, f.capacity).astype(np.float32))
    v_all = f.numpy("v", active_only=False)
    v_before = f.v
    v_cold = _forces_pass(solver, v_all, warm=False, estimate=True)
    assert f.v is not v_before  # the predicted velocities went to the other buffer, which is now v
    np.testing.assert_array_equal(f.numpy("stiffness_sum"), 0.0)  # a cold start: no stiffness yet
    acc = (v_cold - v_all[: f.active]) / dt

    ref = non_pressure_np(
        xs,
        vs,
        rho,
        solver.fluid_volume,
        bx,
        bvol,
        cfg.support_radius,
        cfg.viscosity,
        mu_b,
        cfg.rest_density,
        cfg.gravity,
    )
    visc = ref - np.asarray(cfg.gravity)
    assert np.abs(visc).max() > 1.0  # the viscous part is far from negligible here
    np.testing.assert_allclose(acc, ref, rtol=2e-3, atol=2e-3 * np.abs(visc).max())

    d_ref = divergence_estimate_np(xs, vs, solver.fluid_volume / rho, bx, bvol, 0.1, 0.1)
    np.testing.assert_allclose(f.numpy("divergence"), d_ref, rtol=2e-3, atol=2e-3 * d_ref.max())

    # the density solver's push P_i = w_i (sum_j g_ij + sum_b g_ib) + sum_j w_j g_ij, applied as v -= P / dt
    v_warm = _forces_pass(solver, v_all, warm=True)
    w = f.numpy("density_record")[:, 3].astype(np.float64)  # kappa where compressing (tested below)
    assert 0 < (w > 0).sum() < f.active
    pairs, grad_b = _gradients(solver)
    push_ref = np.array([w[i] * (g.sum(0) + grad_b[i]) + (w[j, None] * g).sum(0) for i, (j, g) in pairs.items()])
    assert np.abs(push_ref).max() > 0
    np.testing.assert_allclose(-dt * (v_warm - v_cold), push_ref, rtol=1e-3, atol=2e-3 * np.abs(push_ref).max())
    np.testing.assert_allclose(f.numpy("stiffness_sum"), w / dt**2, rtol=1e-6)


def test_forces_pass_copies_the_velocities_of_retired_slots():
    cfg, solver = _solver(0.0)
    f, nb, b = solver.fluid, solver.neighborhoods, solver.boundary
    f.active -= 5  # the last five slots as if retired
    n = f.active
    v0 = f.numpy("v", active_only=False)
    out = f.velocity_scratch()
    out.fill(7.0)
    passes.predict_velocities(
        f,
        b,
        nb,
        cfg.dt,
        solver.gravity,
        cfg.viscosity,
        cfg.wall_viscosity,
        cfg.rest_density,
        solver.h,
        warm=False,
        estimate=False,
    )
    assert f.v is out  # the pass wrote the spare buffer, which is now v
    new = out.to_numpy()
    np.testing.assert_array_equal(new[n:], v0[n:])
    assert np.all(new[:n] != 7.0)


def test_density_warm_records_mask_the_particles_that_are_not_compressing():
    cfg, solver = _solver(0.0)
    f, nb = solver.fluid, solver.neighborhoods
    n, dt = f.active, cfg.dt
    rng = np.random.default_rng(7)
    kappa = rng.uniform(0.1, 1.0, n)
    f.kappa_density.from_numpy(np.pad(kappa, (0, f.capacity - n)).astype(np.float32))
    for warm in (0, 1):
        passes.density_warm_records(f, nb, dt, bool(warm), solver.gravity)
        if not warm:  # no warm start: w = 0 everywhere, and the record still carries x
            np.testing.assert_array_equal(f.numpy("density_record")[:, 3], 0.0)
    rho, src = f.numpy("density").astype(np.float64), f.numpy("source").astype(np.float64)
    grad_b = nb.boundary_grad_sum.to_numpy()[:n].astype(np.float64)
    compressing = rho + dt * (src + dt * grad_b @ np.asarray(cfg.gravity)) > 1.0
    assert 0 < compressing.sum() < n
    record = f.numpy("density_record")
    np.testing.assert_array_equal(record[:, :3], f.numpy("x"))
    np.testing.assert_allclose(record[:, 3], np.where(compressing, kappa, 0.0), rtol=1e-6)


def test_divergence_error_pass_writes_the_density_warm_records():
    """The records the divergence solver's error pass leaves are those of the pass of their own, from its source."""
    cfg, solver = _solver(0.0)
    f, nb = solver.fluid, solver.neighborhoods
    n, dt = f.active, cfg.dt
    f.kappa_density.from_numpy(np.random.default_rng(9).uniform(0.1, 1.0, f.capacity).astype(np.float32))
    f.density_record.fill(-1.0)
    passes.divergence_solve_error(f, nb, dt, INV_Q, True, solver.gravity)
    fused = f.numpy("density_record")
    assert 0 < (fused[:, 3] > 0).sum() < n
    passes.density_warm_records(f, nb, dt, True, solver.gravity)
    np.testing.assert_array_equal(fused, f.numpy("density_record"))
    # the step uses them: a step whose divergence solve ran an error pass does not recompute them
    calls = []
    solver.warm = WarmStart(divergence=True, density=True)
    original = passes.density_warm_records
    try:
        passes.density_warm_records = lambda *a: (calls.append(1), original(*a))
        solver.step()
        assert calls == []
        # a cold divergence solve that meets its tolerance at once runs no error pass: the records get their own
        _, still = _solver(0.0)
        still.warm = WarmStart(divergence=False, density=True)
        still.fluid.v.fill(0.0)
        stats = still.step()
        assert stats.divergence_iterations == 1 and calls == [1]
    finally:
        passes.density_warm_records = original


def _apply_with(solver, stiffness, dt):
    """Numpy twin of one list pass: v_i - dt (sum_j (k_i + k_j) g_ij + k_i sum_b g_ib), k in sorted order."""
    pairs, grad_b = _gradients(solver)
    v = solver.fluid.numpy("v").astype(np.float64)
    k = np.asarray(stiffness, np.float64)
    return np.array(
        [v[i] - dt * (((k[i] + k[j])[:, None] * g).sum(0) + k[i] * grad_b[i]) for i, (j, g) in pairs.items()]
    )


def _divergence_np(solver):
    """Numpy twin of s_i = sum_j (v_i - v_j) . g_ij + v_i . sum_b g_ib (unclamped), and the bound on what the
    stored coefficients' rounding can change in it: 2^-11 sum_j |v_j . g_ij| in NARROW lists (f16 c_ij; the
    pass evaluates v_i . G_i - sum_j c_ij v_j . (x_i - x_j) with G_i summed in f32), else 0."""
    pairs, grad_b = _gradients(solver)
    v = solver.fluid.numpy("v").astype(np.float64)
    s = np.array([np.sum((v[i] - v[j]) * g) + v[i] @ grad_b[i] for i, (j, g) in pairs.items()])
    bound = np.array([np.abs(np.sum(v[j] * g, axis=1)).sum() for i, (j, g) in pairs.items()])
    narrow = solver.neighborhoods.format == neighbors.NARROW
    return s, (2.0**-11 * bound if narrow else 0.0 * bound)


def _velocity_update_case(seed):
    """A solver whose records (x_i, k_i) hold a random stiffness k (sorted order) and whose stiffness sum is 1, with
    the numpy twin's updated velocities and their scale (the largest change): (solver, dt, k, expected, scale)."""
    cfg, solver = _solver(0.0)
    f = solver.fluid
    k = np.random.default_rng(seed).uniform(-50.0, 200.0, f.capacity)
    expected = _apply_with(solver, k, cfg.dt)
    scale = np.abs(expected - f.numpy("v")).max()
    assert scale > 1e-2
    xk = np.concatenate([f.numpy("x", active_only=False), k[:, None]], axis=1)
    f.position_stiffness.from_numpy(xk.astype(np.float32))
    f.stiffness_sum.fill(1.0)
    return solver, cfg.dt, k, expected, scale


def test_velocity_update_pass_matches_numpy_twin():
    solver, dt, k, expected, scale = _velocity_update_case(17)
    f = solver.fluid
    passes.velocity_update(f, solver.neighborhoods, dt)
    np.testing.assert_allclose(f.numpy("v"), expected, atol=1e-3 * scale)
    np.testing.assert_allclose(f.numpy("stiffness_sum"), 1.0 + k[: f.active], rtol=1e-6)


def test_last_velocity_update_stores_the_warm_start_memory_and_advects():
    solver, dt, k, expected, scale = _velocity_update_case(19)
    f, nb, n = solver.fluid, solver.neighborhoods, solver.fluid.active
    x0 = f.numpy("x").astype(np.float64)
    out = passes.finish_solve(f, nb, dt, 0.5, f.kappa_density, advect=True)
    v = f.numpy("v").astype(np.float64)
    np.testing.assert_allclose(v, expected, atol=1e-3 * scale)
    np.testing.assert_allclose(f.numpy("kappa_density"), 0.5 * (1.0 + k[:n]), rtol=1e-6)
    np.testing.assert_allclose(f.numpy("x"), x0 + dt * v, rtol=0, atol=1e-6)
    assert out[0] == pytest.approx(np.linalg.norm(v, axis=1).max(), rel=1e-5) and out[1] == 0
    # without advect: x stays, nothing is measured; a NaN velocity is counted when advecting
    x1 = f.numpy("x")
    out = passes.finish_solve(f, nb, dt, 0.5, f.kappa_density, advect=False)
    np.testing.assert_array_equal(f.numpy("x"), x1)
    assert out[0] == 0 and out[1] == 0
    vv = f.numpy("v", active_only=False)
    vv[3] = np.nan
    f.v.from_numpy(vv)
    out = passes.finish_solve(f, nb, dt, 0.5, f.kappa_density, advect=True)
    assert out[1] >= 1


def test_divergence_error_pass_matches_numpy_twin():
    cfg, solver = _solver(0.0)
    f, nb = solver.fluid, solver.neighborhoods
    n, dt = f.active, cfg.dt
    s_raw, bound = _divergence_np(solver)
    avg = passes.divergence_solve_error(f, nb, dt, INV_Q, False, solver.gravity)
    counts = nb.fluid_count.to_numpy()[:n] + nb.boundary_count.to_numpy()[:n]
    s_ref = np.where((s_raw < 0) | (counts < FREE_SURFACE_NEIGHBORS), 0.0, s_raw)
    assert 10 < (s_ref > 0).sum() < n - 10
    scale = np.abs(s_raw).max()
    assert np.all(np.abs(f.numpy("source") - s_ref) <= bound + 1e-5 * scale)
    xk = f.numpy("position_stiffness")
    np.testing.assert_array_equal(xk[:, :3], f.numpy("x"))
    np.testing.assert_allclose(xk[:, 3], f.numpy("source") * f.numpy("factor") / dt, rtol=1e-5)
    assert abs(avg - s_ref.mean()) <= bound.mean() + 1e-5 * scale
    assert avg == fixed_point_average_np(f.numpy("source"), INV_Q)  # summed as it went, bit for bit
    # the neighbourhood pass measures the same first source for a cold-started solve
    solver.warm = WarmStart(divergence=False, density=True)
    solver.find_neighborhoods()
    np.testing.assert_allclose(f.numpy("source"), s_ref, atol=1e-4 * scale)


def test_density_error_pass_matches_numpy_twin():
    cfg, solver = _solver(0.0)
    f, nb = solver.fluid, solver.neighborhoods
    n, dt = f.active, cfg.dt
    rho = f.numpy("density").astype(np.float64)
    s_raw, bound = _divergence_np(solver)
    err_ref = np.maximum(rho + dt * s_raw - 1.0, 0.0)
    assert 10 < (err_ref > 0).sum() < n - 10
    avg = passes.density_solve_error(f, nb, dt, INV_Q)
    assert np.all(np.abs(f.numpy("source") - err_ref) <= dt * bound + 2e-6)
    xk = f.numpy("position_stiffness")
    np.testing.assert_array_equal(xk[:, :3], f.numpy("x"))
    np.testing.assert_allclose(xk[:, 3], f.numpy("source") * f.numpy("factor") / dt**2, rtol=1e-5)
    assert abs(avg - err_ref.mean()) <= dt * bound.mean() + 1e-7
    assert avg == fixed_point_average_np(f.numpy("source"), INV_Q)


@pytest.mark.parametrize("max_neighbors", [64, 8])  # 8: the lists overflow and the pass runs again
def test_divergence_warm_start_equals_the_list_pass(max_neighbors):
    """The neighbourhood pass moves every particle as a list pass with k_j = 0.5 kappa_j / dt would, once, even
    when it has to run again with grown lists (it takes its first push back)."""
    cfg, solver = _solver(0.0, kappa_divergence_max=2e-3, neighborhoods=False, max_neighbors=max_neighbors)
    f = solver.fluid
    n, dt = f.active, cfg.dt
    k = 0.5 * f.numpy("kappa_divergence", active_only=False).astype(np.float64) / dt  # sorted order
    expected = _apply_with(solver, k, dt)
    v0 = f.numpy("v")
    solver.find_neighborhoods(dt)
    assert solver.neighborhoods.fluid_capacity >= (64 if max_neighbors == 64 else 9)
    v = f.numpy("v")
    scale = np.abs(expected - v0).max()
    assert scale > 1e-3
    np.testing.assert_allclose(v, expected, atol=2e-3 * scale)
    np.testing.assert_allclose(f.numpy("stiffness_sum"), k[:n], rtol=1e-6)


def test_density_warm_start_equals_the_list_pass():
    """The push summed by the non-pressure pass moves every particle as a list pass with k_j = w_j / dt^2."""
    cfg, solver = _solver(0.0)
    f = solver.fluid
    n, dt = f.active, cfg.dt
    rng = np.random.default_rng(13)
    f.kappa_density.from_numpy(rng.uniform(0.0, 2e-6, f.capacity).astype(np.float32))
    v_all = f.numpy("v", active_only=False)
    v0 = v_all[:n].astype(np.float64)
    v_forces = _forces_pass(solver, v_all, warm=False)
    v_warm = _forces_pass(solver, v_all, warm=True)  # the masked stiffness w, the push, a and v*
    w = f.numpy("density_record", active_only=False)[:, 3].astype(np.float64)
    assert 0 < (w[:n] > 0).sum() < n
    f.v.from_numpy(v_all)
    expected = _apply_with(solver, w / dt**2, dt)  # the list pass on the velocities before the forces
    scale = np.abs(expected - v0).max()
    assert scale > 1e-3
    np.testing.assert_allclose(v_warm - v_forces, expected - v0, atol=2e-3 * scale)
    np.testing.assert_allclose(f.numpy("stiffness_sum"), w[:n] / dt**2, rtol=1e-6)


def test_forces_pass_adds_eq1_to_the_run_sums_once():
    cfg, solver = _solver(0.0)
    f = solver.fluid
    _forces_pass(solver, f.numpy("v", active_only=False), warm=False, estimate=True)
    sums, counts = solver.divergence_accumulation()
    assert counts.min() == 1 and counts.max() == 1
    np.testing.assert_allclose(sums[counts > 0], f.numpy("divergence")[np.argsort(f.numpy("ids"))], rtol=1e-6)


def test_error_averages_are_fixed_point_sums_independent_of_order():
    """The solvers' averages: within 2^-21 tolerances of the exact mean, the same bits for any order of the
    values (integer sums), and +Inf (never a small error) for NaN or a value past the representable range."""
    cfg, solver = _solver(0.0)
    f = solver.fluid
    n, dt = f.active, cfg.dt
    tol = 1e-4
    inv_q = 2.0**20 / tol

    def average(values):
        f.source.from_numpy(np.pad(values, (0, f.capacity - n)).astype(np.float32))
        return passes.divergence_solve_cold_start(f, dt, inv_q)

    values = np.random.default_rng(21).exponential(3e-4, n).astype(np.float32)
    avg = average(values)
    assert avg == fixed_point_average_np(values, inv_q)
    assert abs(avg - values.astype(np.float64).mean()) <= tol * 2.0**-21
    assert average(values[::-1].copy()) == avg
    assert average(np.roll(values, 17)) == avg
    bad = values.copy()
    bad[5] = np.nan
    assert average(bad) == np.inf
    huge = values.copy()
    huge[7] = tol * 2.0**42 / n * 1.01  # past 2^62 / n quanta
    assert average(huge) == np.inf == fixed_point_average_np(huge, inv_q)
    huge[7] = tol * 2.0**42 / n * 0.5
    assert np.isfinite(average(huge))


def test_neighbour_lists_follow_the_largest_count():
    """Capacity starts from the rest lattice, shrinks (at the next pass) when far above the largest count, grows
    at once when below it; the lists stay exact either way."""
    assert neighbors.lattice_neighbor_count(0.05, 0.1) == 32  # h = 2 spacings: 32 lattice neighbours
    default = SolverConfig(particle_radius=0.025)
    lone = DFSPHSolver(default, [0, 0, 0], [1, 1, 1], np.array([[0.5, 0.5, 0.5]]), np.zeros((1, 3)), np.zeros((0, 3)))
    assert lone.neighborhoods.fluid_capacity == neighbors.list_capacity(32) == 38
    cfg, solver = _solver(2.5, max_neighbors=64)  # a no-slip wall: the boundary lists are stored too
    nb = solver.neighborhoods
    max_f = int(nb.fluid_count.to_numpy()[: solver.fluid.active].max())
    max_b = int(nb.boundary_count.to_numpy()[: solver.fluid.active].max())
    assert nb.fluid_capacity == 64 and neighbors.shrink_threshold(max_f) < 64  # smaller lists are planned
    solver.find_neighborhoods()
    assert nb.fluid_capacity == neighbors.list_capacity(max_f) < 64
    assert nb.boundary_capacity == neighbors.list_capacity(max_b) < 64
    pairs, _ = _gradients(solver)
    count, index, _ = nb.lists("fluid")
    for i, (j, _) in pairs.items():
        np.testing.assert_array_equal(np.sort(index[i, : count[i]]), j)
    # a count past the capacity grows the lists at once (and the pass runs again)
    nb.resize(8, 8)
    solver.find_neighborhoods()
    assert nb.fluid_capacity >= max_f and nb.boundary_capacity >= max_b
    count, index, _ = nb.lists("fluid")
    assert all(np.array_equal(np.sort(index[i, : count[i]]), j) for i, (j, _) in pairs.items())


def test_boundary_pairs_are_stored_only_where_a_pass_reads_them():
    _, slip = _solver(0.0)  # free-slip walls, Eq. 1 from the stored gradients: nothing reads boundary pairs
    _, no_slip = _solver(2.5)
    assert not slip.neighborhoods.store_boundary and no_slip.neighborhoods.store_boundary
    assert slip.neighborhoods.boundary_pairs.shape[1] == 1
    with pytest.raises(ValueError, match="boundary counts only"):
        slip.neighborhoods.lists("boundary")
    # the counts are full either way (the free-surface test reads them)
    n = slip.fluid.active
    np.testing.assert_array_equal(
        slip.neighborhoods.boundary_count.to_numpy()[:n], no_slip.neighborhoods.boundary_count.to_numpy()[:n]
    )
    assert slip.neighborhoods.boundary_count.to_numpy()[:n].max() > 8
    cfg = SolverConfig(particle_radius=0.025, boundary_viscosity=0.0, estimator_radius=0.08)  # Eq. 1 walks lists
    x = lattice_in_box([0.3, 0.3, 0.3], [0.6, 0.6, 0.6], cfg.spacing)
    assert DFSPHSolver(cfg, [0, 0, 0], [1, 1, 1], x, np.zeros_like(x), x[:5] - 0.3).neighborhoods.store_boundary


def test_warm_starts_are_named_and_follow_the_config():
    assert WarmStart.of(SolverConfig()) == WarmStart(divergence=True, density=True)
    assert WarmStart.of(SolverConfig(divergence_warm_start=False)) == WarmStart(divergence=False, density=True)
    assert WarmStart.of(SolverConfig(divergence_solver=False)) == WarmStart(divergence=False, density=True)
    assert WarmStart.of(SolverConfig(warm_start=False)) == WarmStart(divergence=False, density=False)
    with pytest.raises(dataclasses.FrozenInstanceError):
        WarmStart(True, True).density = False


@pytest.mark.parametrize("h_r", [0.1, 0.13])  # 0.13 > h: Eq. 1 is a stage of its own
def test_step_runs_the_stages_in_the_order_of_algorithm_1(h_r):
    cfg = SolverConfig(particle_radius=0.025, estimator_radius=h_r, estimator_kernel_radius=h_r)
    x = lattice_in_box([0.3, 0.3, 0.3], [0.6, 0.6, 0.6], cfg.spacing)
    solver = DFSPHSolver(cfg, [0, 0, 0], [1, 1, 1], x, np.zeros_like(x), x[:40] - [0, 0.3, 0])
    solver.stage_times = {}
    stats = solver.step()
    own = ["divergence_estimate"] if h_r > cfg.support_radius else []
    assert list(solver.stage_times) == [
        "sort",
        "neighbors",
        "divergence_solve",
        *own,
        "non_pressure",
        "density_solve",
        "forces",
    ]
    assert stats.divergence_iterations >= 1 and stats.density_iterations >= cfg.min_iterations
    _, counts = solver.divergence_accumulation()
    assert counts.max() == 1  # Eq. 1 ran once, in one stage or the other


def test_one_owner_chooses_the_path_of_eq1():
    from fluidsim.estimator import FROM_GRADIENTS, FROM_GRID, FROM_LISTS, estimate_path

    h = 0.1
    assert estimate_path(h, h, h * (1 + 1e-12)) == FROM_GRADIENTS  # h_k = h (to rounding), h_r >= h
    assert estimate_path(h, 2 * h, h) == FROM_GRADIENTS
    assert estimate_path(h, h, 0.8 * h) == FROM_LISTS  # another kernel radius: the lists, filtered
    assert estimate_path(h, 0.5 * h, h) == FROM_LISTS
    assert estimate_path(h, 1.5 * h, 0.8 * h) == FROM_GRID  # beyond the lists with another kernel
