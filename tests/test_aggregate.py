"""Per-Gaussian accumulation through the grid against the O(N G) twin: sums, counts, distinct particles,
the numpy path and the solver path."""

import numpy as np
import pytest

from fluidsim import DFSPHSolver, SolverConfig
from fluidsim.scene import lattice_in_box
from fluidsim.sources import sphere_particles, wall_particles
from nbv.aggregate import GaussianAccumulator, accumulate_reference, within_reach_reference
from nbv.aggregate_kernels import VALUE_LIMIT, VALUE_SCALE

DOMAIN_MIN = np.array([-1.2, -1.0, -1.1])
DOMAIN_MAX = np.array([1.1, 1.2, 1.0])


def random_gaussians(g: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Centres inside and around the domain, reaches over two decades, a few extreme ones."""
    rng = np.random.default_rng(seed)
    centers = rng.uniform(-1.3, 1.3, (g, 3))
    reach = np.exp(rng.uniform(np.log(0.01), np.log(0.8), g))
    reach[:3] = [5.0, 0.0, 2.0]          # huge (clipped to the domain), zero, large
    centers[3] = [3.0, 0.0, 0.0]         # outside the domain, reaching in
    reach[3] = 2.5
    return centers, reach


def quantized_sums(centers, reach, steps, *domain) -> np.ndarray:
    """The twin's sums of the values as the kernels add them: each rounded to 1 / VALUE_SCALE, summed exactly
    (integers in f64), so the accumulator must equal them bit for bit."""
    total = sum(accumulate_reference(centers, reach, pos, np.floor(np.asarray(val, np.float64) * VALUE_SCALE + 0.5),
                                     *domain)[0] for pos, val in steps)
    return total / VALUE_SCALE


def random_step(rng, n: int, pool: int):
    ids = rng.choice(pool, n, replace=False)
    return rng.uniform(-1.5, 1.5, (n, 3)), rng.normal(size=n), ids


def test_accumulator_equals_brute_force_twin():
    centers, reach = random_gaussians(150, seed=0)
    rng = np.random.default_rng(1)
    acc = GaussianAccumulator(centers, reach, DOMAIN_MIN, DOMAIN_MAX)
    sums, counts = np.zeros(len(centers)), np.zeros(len(centers), np.int64)
    steps = []
    for _ in range(3):
        pos, val, _ = random_step(rng, 400, 1000)
        acc.add(pos, val)
        steps.append((pos, val))
        s, c = accumulate_reference(centers, reach, pos, val, DOMAIN_MIN, DOMAIN_MAX)
        sums += s
        counts += c
    assert np.array_equal(acc.counts, counts)
    assert counts.min() == 0 and counts.max() > 100 and counts[1] == 0     # zero reach never counts
    np.testing.assert_array_equal(acc.sums, quantized_sums(centers, reach, steps, DOMAIN_MIN, DOMAIN_MAX))
    # within half a quantum per sample of the unrounded sums
    assert np.all(np.abs(acc.sums - sums) <= 0.5 * counts / VALUE_SCALE + 1e-12 * np.abs(sums).max())
    expected = np.where(counts > 0, sums / np.maximum(counts, 1), 0.0)
    assert np.allclose(acc.means(), expected, rtol=1e-6, atol=1e-9)
    # Particles outside the domain are ignored; the twin without a domain does count them.
    free = accumulate_reference(centers, reach, pos, val)[1]
    assert free.sum() > accumulate_reference(centers, reach, pos, val, DOMAIN_MIN, DOMAIN_MAX)[1].sum()
    acc.reset()
    assert not acc.counts.any() and not acc.sums.any()


def distinct_reference(centers, reach, steps) -> np.ndarray:
    seen: list[set] = [set() for _ in range(len(centers))]
    for pos, _, ids in steps:
        near = within_reach_reference(centers, reach, pos, DOMAIN_MIN, DOMAIN_MAX)
        for g, i in zip(*np.nonzero(near.T), strict=True):
            seen[g].add(int(ids[i]))
    return np.array([len(s) for s in seen])


@pytest.mark.parametrize("budget, storage", [(512 * 2**20, ("bits", "bits")), (1000, ("bits", "keys")),
                                             (64, ("keys", "keys"))])
def test_distinct_counts_are_exact(budget, storage):
    """Bit matrix (large budget), bit matrix grown then converted to keys (1000 B), keys from the start (64 B)."""
    centers, reach = random_gaussians(100, seed=2)
    rng = np.random.default_rng(3)
    acc = GaussianAccumulator(centers, reach, DOMAIN_MIN, DOMAIN_MAX, track_distinct=True,
                              distinct_budget_bytes=budget)
    steps = []
    for pool in (40, 40, 300, 300):      # small ids first (the storage grows), repeated visits
        steps.append(random_step(rng, 35, pool))
        acc.add(*steps[-1])
        if len(steps) == 1:
            assert acc.distinct_storage == storage[0]
    assert acc.distinct_storage == storage[1]
    expected = distinct_reference(centers, reach, steps)
    assert np.array_equal(acc.distinct_counts, expected)
    assert (acc.counts >= expected).all() and (acc.counts > expected).any()   # repeats count once
    acc.reset()
    assert not acc.distinct_counts.any()


def tiny_probe_solver() -> DFSPHSolver:
    cfg = SolverConfig(particle_radius=0.05)
    sp = cfg.spacing
    lo, hi = np.array([-0.6, -0.6, -0.6]), np.array([0.9, 0.6, 0.6])
    solid = sphere_particles([0.0, 0.0, 0.0], 0.25, sp, fill=True)
    fluid = lattice_in_box([0.35, -0.4, -0.4], [0.75, 0.4, 0.4], sp)
    vel = np.tile([-3.0, 0.0, 0.0], (len(fluid), 1))
    boundary = np.concatenate([solid, wall_particles(lo, hi, sp, 2)])
    return DFSPHSolver(cfg, lo, hi, fluid, vel, boundary)


def test_add_from_solver_equals_numpy_path():
    solver = tiny_probe_solver()
    rng = np.random.default_rng(4)
    centers = np.concatenate([rng.normal(0.0, 0.2, (60, 3)), [[0.5, 0.0, 0.0]]])
    reach = 3.0 * np.exp(rng.uniform(np.log(0.01), np.log(0.08), len(centers)))
    args = (centers, reach, solver.domain_min, solver.domain_max)
    fast = GaussianAccumulator(*args, track_distinct=True, max_fluid=solver.fluid.capacity)
    ref = GaussianAccumulator(*args, track_distinct=True)
    counts = np.zeros(len(centers), np.int64)
    steps = []
    for _ in range(12):
        solver.step()
        fast.add_from_solver(solver)
        state = solver.fluid_state()
        ref.add(state["x"], state["divergence"], state["ids"])
        steps.append((state["x"], state["divergence"]))
        counts += accumulate_reference(centers, reach, state["x"], state["divergence"], *args[2:])[1]
    sums = quantized_sums(centers, reach, steps, *args[2:])
    assert counts.sum() > 0 and np.abs(sums).max() > 1e-3  # the fluid has reached the sphere: D_i is not noise
    assert np.array_equal(fast.counts, counts) and np.array_equal(ref.counts, counts)
    np.testing.assert_array_equal(fast.sums, sums)
    np.testing.assert_array_equal(ref.sums, sums)
    assert np.array_equal(fast.distinct_counts, ref.distinct_counts)
    assert (fast.distinct_counts < fast.counts).any()


def test_bad_inputs_name_the_argument():
    centers, reach = random_gaussians(5, seed=5)
    with pytest.raises(ValueError, match="reach"):
        GaussianAccumulator(centers, reach[:3], DOMAIN_MIN, DOMAIN_MAX)
    with pytest.raises(ValueError, match="reach"):
        GaussianAccumulator(centers, -reach, DOMAIN_MIN, DOMAIN_MAX)
    with pytest.raises(ValueError, match="domain_min"):
        GaussianAccumulator(centers, reach, DOMAIN_MAX, DOMAIN_MIN)
    with pytest.raises(ValueError, match="centers"):
        GaussianAccumulator(np.zeros((0, 3)), np.zeros(0), DOMAIN_MIN, DOMAIN_MAX)
    acc = GaussianAccumulator(centers, reach, DOMAIN_MIN, DOMAIN_MAX, track_distinct=True)
    with pytest.raises(ValueError, match="ids"):
        acc.add(np.zeros((2, 3)), np.zeros(2))
    with pytest.raises(ValueError, match="values"):
        acc.add(np.zeros((2, 3)), np.zeros(3), np.arange(2))
    with pytest.raises(ValueError, match="positions"):
        acc.add(np.full((2, 3), np.nan), np.zeros(2), np.arange(2))
    with pytest.raises(ValueError, match="track_distinct"):
        _ = GaussianAccumulator(centers, reach, DOMAIN_MIN, DOMAIN_MAX).distinct_counts


def test_degenerate_sets_match_the_twin():
    """One Gaussian, zero reaches, Gaussians wholly outside the domain: still exactly the twin."""
    rng = np.random.default_rng(6)
    pos, val, _ = random_step(rng, 500, 1000)
    cases = [(np.zeros((1, 3)), np.array([0.7])), (rng.uniform(-1, 1, (4, 3)), np.zeros(4)),
             (np.array([[5.0, 0.0, 0.0], [0.0, -4.0, 0.0]]), np.array([1.0, 3.5]))]
    for centers, reach in cases:
        acc = GaussianAccumulator(centers, reach, DOMAIN_MIN, DOMAIN_MAX)
        acc.add(pos, val)
        counts = accumulate_reference(centers, reach, pos, val, DOMAIN_MIN, DOMAIN_MAX)[1]
        assert np.array_equal(acc.counts, counts)
        np.testing.assert_array_equal(acc.sums, quantized_sums(centers, reach, [(pos, val)], DOMAIN_MIN, DOMAIN_MAX))
    assert acc.counts[1] > 0 and acc.counts[0] == 0       # the last case: one reaches in, one does not


def test_retarget_reuses_the_lists_for_a_domain_with_the_same_grid():
    """The next probe's domain: lists kept when they cover it, sums zeroed, new domain bounds applied; refused
    when the new domain needs cells the lists do not have."""
    rng = np.random.default_rng(5)
    centers = rng.uniform(-0.5, 0.5, (80, 3))
    reach = rng.uniform(0.05, 0.2, 80)
    acc = GaussianAccumulator(centers, reach, [-2.0, -2.0, -2.0], [2.0, 2.0, 2.0], track_distinct=True, max_fluid=500)
    pos, val, ids = random_step(rng, 300, 500)
    pos *= 0.5
    acc.add(pos, val, ids)
    assert acc.counts.sum() > 0
    lists = acc._lists.to_numpy().copy()
    # A smaller domain that still contains the Gaussians' reach box: same grid.
    new_min, new_max = np.full(3, -0.72), np.full(3, 0.72)  # the reach box is within +-0.7
    assert acc.retarget(new_min, new_max)
    assert not acc.counts.any() and not acc.sums.any() and not acc.distinct_counts.any()
    assert np.array_equal(acc._lists.to_numpy(), lists)
    acc.add(pos, val, ids)
    fresh = GaussianAccumulator(centers, reach, new_min, new_max, track_distinct=True, max_fluid=500)
    fresh.add(pos, val, ids)
    c = accumulate_reference(centers, reach, pos, val, new_min, new_max)[1]
    assert np.array_equal(acc.counts, c) and np.array_equal(fresh.counts, c)
    np.testing.assert_array_equal(acc.sums, quantized_sums(centers, reach, [(pos, val)], new_min, new_max))
    assert np.array_equal(acc.distinct_counts, fresh.distinct_counts)
    # A domain that clips the reach box differently is fine (the grid covers it; the kernel filters by the
    # domain); a domain that needs cells beyond the grid is refused and nothing changes.
    small = GaussianAccumulator(centers, reach, [-0.3] * 3, [0.3] * 3)
    assert not small.retarget([-2.0] * 3, [2.0] * 3)
    assert small.domain_max.tolist() == [0.3] * 3
    assert acc.retarget([-0.1, -2.0, -2.0], [2.0, 2.0, 2.0])
    acc.add(pos, val, ids)
    c = accumulate_reference(centers, reach, pos, val, [-0.1, -2.0, -2.0], [2.0, 2.0, 2.0])[1]
    assert np.array_equal(acc.counts, c)
    np.testing.assert_array_equal(acc.sums, quantized_sums(centers, reach, [(pos, val)], [-0.1, -2.0, -2.0],
                                                           [2.0, 2.0, 2.0]))
    # grid_bounds: lists built for a union of domains serve each of them exactly.
    union = GaussianAccumulator(centers, reach, [-0.3] * 3, [0.3] * 3, grid_bounds=([-2.0] * 3, [2.0] * 3))
    union.add(pos, val)
    assert np.array_equal(union.counts, accumulate_reference(centers, reach, pos, val, [-0.3] * 3, [0.3] * 3)[1])
    assert union.retarget([-2.0] * 3, [2.0] * 3)
    union.add(pos, val)
    assert np.array_equal(union.counts, accumulate_reference(centers, reach, pos, val, [-2.0] * 3, [2.0] * 3)[1])
    with pytest.raises(ValueError, match="domain_min"):
        acc.retarget([0.0, 0.0, 0.0], [0.0, 1.0, 1.0])


@pytest.mark.parametrize("rows, private, serial_below", [(1, False, 0), (1, True, 10**6), (3, True, 10**6),
                                                         (3, True, 0)])
def test_atomic_and_per_thread_row_paths_equal_the_twin(monkeypatch, rows, private, serial_below):
    # (1, False) is the GPU path (atomic adds), run here on the CPU; 3 rows is more rows than threads; the particles
    # run on the launching thread (serial_below above the particle count, or fewer rows than pool threads) or in
    # parallel, each thread adding into its own row
    import nbv.aggregate as aggregate

    monkeypatch.setattr(aggregate, "accumulation_rows", lambda g: (rows, private))
    centers, reach = random_gaussians(120, seed=5)
    rng = np.random.default_rng(6)
    steps = [random_step(rng, 300, 700) for _ in range(3)]

    def run(track: bool):
        acc = GaussianAccumulator(centers, reach, DOMAIN_MIN, DOMAIN_MAX, track_distinct=track, max_fluid=700)
        acc.serial_below = serial_below
        assert acc.rows == rows and acc._acc.shape == (rows, len(centers) + 1, 2)
        for pos, val, ids in steps:
            acc.add(pos, val, ids)
        return acc

    sums = quantized_sums(centers, reach, [(p, v) for p, v, _ in steps], DOMAIN_MIN, DOMAIN_MAX)
    counts = sum(accumulate_reference(centers, reach, p, v, DOMAIN_MIN, DOMAIN_MAX)[1] for p, v, _ in steps)
    assert counts.max() > 50
    for track in (False, True):  # the plain kernel, and the one that also records particle ids
        acc = run(track)
        assert np.array_equal(acc.counts, counts)
        np.testing.assert_array_equal(acc.sums, sums)  # fixed-point sums: the same bits on every path
        if track:
            assert np.array_equal(acc.distinct_counts, distinct_reference(centers, reach, steps))


def test_morton_order_is_a_z_curve_permutation():
    from nbv.aggregate import morton_order

    corners = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], float)  # Morton order
    shuffled = np.random.default_rng(0).permutation(8)
    assert np.array_equal(corners[shuffled][morton_order(corners[shuffled])], corners)
    pts = np.random.default_rng(1).uniform(-3, 5, (500, 3))
    order = morton_order(pts)
    assert np.array_equal(np.sort(order), np.arange(500))
    # consecutive points along the curve are much closer than random pairs
    step = np.linalg.norm(np.diff(pts[order], axis=0), axis=1).mean()
    assert step < 0.5 * np.linalg.norm(np.diff(pts, axis=0), axis=1).mean()


def test_staged_steps_equal_step_by_step_accumulation():
    """Steps staged ``batch_steps`` at a time give the per-step result; a read accumulates what is staged."""
    solver = tiny_probe_solver()
    rng = np.random.default_rng(5)
    centers = np.concatenate([rng.normal(0.0, 0.2, (80, 3)), [[0.5, 0.0, 0.0]]])
    reach = 3.0 * np.exp(rng.uniform(np.log(0.01), np.log(0.08), len(centers)))
    args = (centers, reach, solver.domain_min, solver.domain_max)
    batched = GaussianAccumulator(*args, batch_steps=3, track_distinct=True, max_fluid=solver.fluid.capacity)
    single = GaussianAccumulator(*args, batch_steps=1, track_distinct=True, max_fluid=solver.fluid.capacity)
    assert batched.batch_steps == 3
    unstaged = GaussianAccumulator(*args, batch_steps=3, track_distinct=True, max_fluid=solver.fluid.capacity)
    batched.serial_below = 0  # stage this small probe too (probes under SERIAL_BELOW particles are not staged)
    for step in range(5):
        solver.step()
        batched.add_from_solver(solver)
        single.add_from_solver(solver)
        unstaged.add_from_solver(solver)
        assert unstaged._staged == 0
        if step == 3:  # mid-batch (one step staged): the read includes it
            assert batched._staged > 0
            assert np.array_equal(batched.counts, single.counts)
            assert batched._staged == 0
    assert batched._staged > 0  # step 4 staged, not yet accumulated
    assert single.counts.sum() > 0
    assert np.array_equal(batched.counts, single.counts)
    np.testing.assert_allclose(batched.sums, single.sums, rtol=1e-12, atol=1e-12 * np.abs(single.sums).max())
    assert np.array_equal(batched.distinct_counts, single.distinct_counts)
    assert np.array_equal(unstaged.counts, single.counts)
    np.testing.assert_array_equal(unstaged.sums, single.sums)
    batched.reset()  # drops staged steps too
    assert batched._staged == 0 and batched.counts.sum() == 0
    with pytest.raises(ValueError, match="batch_steps"):
        GaussianAccumulator(*args, batch_steps=0)


def test_values_out_of_the_fixed_point_range_saturate_with_a_warning(caplog):
    centers, reach = np.zeros((1, 3)), np.array([0.5])
    acc = GaussianAccumulator(centers, reach, DOMAIN_MIN, DOMAIN_MAX)
    assert acc.rows >= 1 and acc._acc.dtype == ti_i64()
    pos = np.array([[0.1, 0.0, 0.0], [0.0, 0.1, 0.0], [0.0, 0.0, 0.1]])
    assert VALUE_LIMIT / VALUE_SCALE == 16384.0 < 1e9
    acc.add(pos, np.array([2.5, 1e9, -3e9]))  # the two are clamped to +-16384 (and cancel); all three are counted
    with caplog.at_level("WARNING", logger="nbv.aggregate"):
        assert acc.counts.tolist() == [3]
        assert acc.sums.tolist() == [2.5]
    assert "2 accumulated values were NaN or beyond" in caplog.text


def ti_i64():
    import taichi as ti

    return ti.i64


def test_thread_index_stays_below_the_pool_size():
    """The per-thread rows rely on Taichi's CPU thread index being below cpu_max_num_threads."""
    import taichi as ti

    from nbv.aggregate import accumulation_rows

    @ti.kernel
    def largest_thread_index(n: ti.i32) -> ti.i32:
        m = 0
        for _ in range(n):
            ti.atomic_max(m, ti.global_thread_idx())
        return m

    rows, private = accumulation_rows(100)
    assert private and rows == ti.lang.impl.current_cfg().cpu_max_num_threads
    assert max(largest_thread_index(100_000) for _ in range(20)) < rows
