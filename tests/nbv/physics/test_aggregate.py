"""Per-Gaussian accumulation through the per-level cell lists against the O(N G) twin: sums, counts, distinct
particles, the numpy path and the solver path, the levels themselves, thread-count independence and memory."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fluidsim import DFSPHSolver, SolverConfig
from fluidsim.scene import lattice_in_box
from fluidsim.sources import sphere_particles, wall_particles
from nbv.physics import aggregate, aggregate_distinct, aggregate_levels
from nbv.physics.aggregate import GaussianAccumulator, GaussianLists
from nbv.physics.aggregate_kernels import VALUE_LIMIT, VALUE_SCALE
from nbv.physics.aggregate_levels import _ENTRY_SLACK, ENTRIES_PER_GAUSSIAN, plan_levels
from nbv.physics.aggregate_reference import accumulate_reference, within_reach_reference

from helpers.paths import REPO, TESTS

HERE = Path(__file__).resolve().parent  # the subprocess imports this module from here
DOMAIN_MIN = np.array([-1.2, -1.0, -1.1])
DOMAIN_MAX = np.array([1.1, 1.2, 1.0])


def random_gaussians(g: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Centres inside and around the domain, reaches over two decades, a few extreme ones."""
    rng = np.random.default_rng(seed)
    centers = rng.uniform(-1.3, 1.3, (g, 3))
    reach = np.exp(rng.uniform(np.log(0.01), np.log(0.8), g))
    reach[:3] = [5.0, 0.0, 2.0]  # huge (covering the domain), zero, large
    centers[3] = [3.0, 0.0, 0.0]  # outside the domain, reaching in
    reach[3] = 2.5
    return centers, reach


def quantized_sums(centers, reach, steps, *domain) -> np.ndarray:
    """The twin's sums of the values as the kernels add them: each rounded to 1 / VALUE_SCALE, summed exactly
    (integers in f64), so the accumulator must equal them bit for bit."""
    total = sum(
        accumulate_reference(centers, reach, pos, np.floor(np.asarray(val, np.float64) * VALUE_SCALE + 0.5), *domain)[0]
        for pos, val in steps
    )
    return total / VALUE_SCALE


def random_step(rng, n: int, pool: int):
    ids = rng.choice(pool, n, replace=False)
    return rng.uniform(-1.5, 1.5, (n, 3)), rng.normal(size=n), ids


def distinct_reference(centers, reach, steps, lo=DOMAIN_MIN, hi=DOMAIN_MAX) -> np.ndarray:
    seen: list[set] = [set() for _ in range(len(centers))]
    for pos, _, ids in steps:
        near = within_reach_reference(centers, reach, pos, lo, hi)
        for g, i in zip(*np.nonzero(near.T), strict=True):
            seen[g].add(int(ids[i]))
    return np.array([len(s) for s in seen])


def chunks(steps, size: int = 256):
    """The steps' particles in chunks (the twin holds a [P, G, 3] array)."""
    for p, v, *rest in steps:
        for i in range(0, len(p), size):
            yield (p[i : i + size], v[i : i + size], *[r[i : i + size] for r in rest])


def check_against_twin(acc: GaussianAccumulator, centers, reach, steps, lo=DOMAIN_MIN, hi=DOMAIN_MAX) -> np.ndarray:
    """Counts exactly, sums bit for bit (fixed point) and, when tracked, distinct counts exactly; returns counts."""
    counts = sum(accumulate_reference(centers, reach, p, v, lo, hi)[1] for p, v, *_ in chunks(steps))
    assert np.array_equal(acc.counts, counts)
    np.testing.assert_array_equal(
        acc.sums, quantized_sums(centers, reach, [(p, v) for p, v, *_ in chunks(steps)], lo, hi)
    )
    if acc.track_distinct:
        assert np.array_equal(acc.distinct_counts, distinct_reference(centers, reach, list(chunks(steps)), lo, hi))
    return counts


def test_accumulator_equals_brute_force_twin():
    centers, reach = random_gaussians(150, seed=0)
    rng = np.random.default_rng(1)
    acc = GaussianAccumulator.build(centers, reach, DOMAIN_MIN, DOMAIN_MAX)
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
    assert counts.min() == 0 and counts.max() > 100 and counts[1] == 0  # zero reach never counts
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


@pytest.mark.parametrize(
    "budget, storage", [(512 * 2**20, ("bits", "bits")), (1000, ("bits", "hash")), (64, ("hash", "hash"))]
)
def test_distinct_counts_are_exact(budget, storage):
    """Bit matrix (large budget), bit matrix grown then moved to the hash set (1000 B), hash set from the start."""
    centers, reach = random_gaussians(100, seed=2)
    rng = np.random.default_rng(3)
    acc = GaussianAccumulator.build(
        centers, reach, DOMAIN_MIN, DOMAIN_MAX, track_distinct=True, distinct_budget_bytes=budget
    )
    steps = []
    for pool in (40, 40, 300, 300):  # small ids first (the storage grows), repeated visits
        steps.append(random_step(rng, 35, pool))
        acc.add(*steps[-1])
        if len(steps) == 1:
            assert acc.distinct_storage == storage[0]
    assert acc.distinct_storage == storage[1]
    expected = distinct_reference(centers, reach, steps)
    assert np.array_equal(acc.distinct_counts, expected)
    assert (acc.counts >= expected).all() and (acc.counts > expected).any()  # repeats count once
    acc.reset()
    assert not acc.distinct_counts.any()


def test_distinct_particles_that_leave_and_return_count_once(monkeypatch):
    """A visit is recorded on its first step only; a particle that leaves a Gaussian and comes back, or steps outside
    the domain in between, must not count twice, and one that is never recorded near g must count. The hash set
    starts at 16 slots, so it grows (and a full set refuses inserts and the batch is recorded again) many times."""

    monkeypatch.setattr(aggregate_distinct, "_HASH_MIN_SLOTS", 16)
    centers = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.9, 0.9, 0.9]])
    reach = np.array([0.2, 0.2, 0.05])
    ids = np.arange(4)
    # particle 0: in g0, in neither, in g0 again; 1: in g0, outside the domain, in g0; 2: g0 -> g1 -> g0; 3: never near
    path = [
        np.array([[0.1, 0, 0], [0.1, 0, 0], [0.05, 0, 0], [0.6, 0.6, 0.6]]),
        np.array([[0.25, 0, 0], [5.0, 0, 0], [0.5, 0.05, 0], [0.6, 0.6, 0.6]]),
        np.array([[0.0, 0.05, 0], [0.0, 0.1, 0], [0.0, 0.0, 0.05], [0.6, 0.6, 0.6]]),
    ]
    steps = [(p, np.ones(4), ids) for p in path]
    for budget in (512 * 2**20, 0):
        acc = GaussianAccumulator.build(
            centers, reach, DOMAIN_MIN, DOMAIN_MAX, track_distinct=True, max_fluid=4, distinct_budget_bytes=budget
        )
        for p, v, i in steps:
            acc.add(p, v, i)
        assert acc.distinct_storage == ("bits" if budget else "hash")
        assert acc.distinct_counts.tolist() == [3, 1, 0]
        assert acc.counts.tolist() == [6, 1, 0]
    # many pairs into the 16-slot set: growth with refused inserts, pairs never lost nor doubled
    many, many_reach = random_gaussians(300, seed=11)
    rng = np.random.default_rng(12)
    acc = GaussianAccumulator.build(
        many, many_reach, DOMAIN_MIN, DOMAIN_MAX, track_distinct=True, distinct_budget_bytes=0
    )
    steps = [random_step(rng, 500, 600) for _ in range(3)]
    for p, v, i in steps:
        acc.add(p, v, i)
    assert acc.distinct_storage == "hash" and acc.distinct.pairs.hashes.shape[0] > 1024
    check_against_twin(acc, many, many_reach, steps)


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
    fast = GaussianAccumulator.build(*args, track_distinct=True, max_fluid=solver.fluid.capacity)
    ref = GaussianAccumulator.build(*args, track_distinct=True)
    counts = np.zeros(len(centers), np.int64)
    steps = []
    for _ in range(12):
        solver.step()
        fast.add_from_solver(solver)
        state = solver.fluid_state()
        ref.add(state["x"], state["divergence"], state["ids"])
        steps.append((state["x"], state["divergence"], state["ids"]))
        counts += accumulate_reference(centers, reach, state["x"], state["divergence"], *args[2:])[1]
    sums = quantized_sums(centers, reach, [s[:2] for s in steps], *args[2:])
    assert counts.sum() > 0 and np.abs(sums).max() > 1e-3  # the fluid has reached the sphere: D_i is not noise
    assert np.array_equal(fast.counts, counts) and np.array_equal(ref.counts, counts)
    np.testing.assert_array_equal(fast.sums, sums)
    np.testing.assert_array_equal(ref.sums, sums)
    distinct = distinct_reference(centers, reach, steps, *args[2:])
    assert np.array_equal(fast.distinct_counts, distinct) and np.array_equal(ref.distinct_counts, distinct)
    assert (fast.distinct_counts < fast.counts).any()


def test_bad_inputs_name_the_argument():
    centers, reach = random_gaussians(5, seed=5)
    with pytest.raises(ValueError, match="reach"):
        GaussianAccumulator.build(centers, reach[:3], DOMAIN_MIN, DOMAIN_MAX)
    with pytest.raises(ValueError, match="reach"):
        GaussianAccumulator.build(centers, -reach, DOMAIN_MIN, DOMAIN_MAX)
    with pytest.raises(ValueError, match="domain_min"):
        GaussianAccumulator.build(centers, reach, DOMAIN_MAX, DOMAIN_MIN)
    with pytest.raises(ValueError, match="centers"):
        GaussianAccumulator.build(np.zeros((0, 3)), np.zeros(0), DOMAIN_MIN, DOMAIN_MAX)
    acc = GaussianAccumulator.build(centers, reach, DOMAIN_MIN, DOMAIN_MAX, track_distinct=True)
    with pytest.raises(ValueError, match="ids"):
        acc.add(np.zeros((2, 3)), np.zeros(2))
    with pytest.raises(ValueError, match="values"):
        acc.add(np.zeros((2, 3)), np.zeros(3), np.arange(2))
    with pytest.raises(ValueError, match="positions"):
        acc.add(np.full((2, 3), np.nan), np.zeros(2), np.arange(2))
    with pytest.raises(ValueError, match="densely"):
        acc.add(np.zeros((1, 3)), np.zeros(1), np.array([2**30]))
    with pytest.raises(ValueError, match="track_distinct"):
        _ = GaussianAccumulator.build(centers, reach, DOMAIN_MIN, DOMAIN_MAX).distinct_counts


def test_degenerate_sets_match_the_twin():
    """One Gaussian, zero reaches, Gaussians wholly outside the domain: still exactly the twin."""
    rng = np.random.default_rng(6)
    pos, val, _ = random_step(rng, 500, 1000)
    cases = [
        (np.zeros((1, 3)), np.array([0.7])),
        (rng.uniform(-1, 1, (4, 3)), np.zeros(4)),
        (np.array([[5.0, 0.0, 0.0], [0.0, -4.0, 0.0]]), np.array([1.0, 3.5])),
    ]
    for centers, reach in cases:
        acc = GaussianAccumulator.build(centers, reach, DOMAIN_MIN, DOMAIN_MAX)
        acc.add(pos, val)
        check_against_twin(acc, centers, reach, [(pos, val)])
    assert acc.counts[1] > 0 and acc.counts[0] == 0  # the last case: one reaches in, one does not
    assert acc.num_kept == 1  # and the other one is not even kept


def test_probes_share_the_lists_and_get_fresh_sums():
    """The lists are built once over a box (the union of a run's probe domains); every probe's accumulator on them,
    for any domain within the box, equals the twin, with sums and distinct records of its own. A domain beyond the
    box is refused."""
    rng = np.random.default_rng(5)
    centers = rng.uniform(-0.5, 0.5, (80, 3))
    reach = rng.uniform(0.05, 0.2, 80)
    lists = GaussianLists(centers, reach, [-2.0] * 3, [2.0] * 3)
    built = lists.lists.to_numpy().copy()
    pos, val, ids = random_step(rng, 300, 500)
    pos *= 0.5
    first = GaussianAccumulator(lists, [-2.0] * 3, [2.0] * 3, track_distinct=True, max_fluid=500)
    first.add(pos, val, ids)
    check_against_twin(first, centers, reach, [(pos, val, ids)], [-2.0] * 3, [2.0] * 3)
    for lo, hi in ((np.full(3, -0.72), np.full(3, 0.72)), ([-0.1, -2.0, -2.0], [2.0, 2.0, 2.0])):
        acc = GaussianAccumulator(lists, lo, hi, track_distinct=True, max_fluid=500)
        assert not acc.counts.any() and not acc.sums.any() and not acc.distinct_counts.any()
        acc.add(pos, val, ids)
        check_against_twin(acc, centers, reach, [(pos, val, ids)], lo, hi)
        fresh = GaussianAccumulator.build(centers, reach, lo, hi, track_distinct=True, max_fluid=500)
        fresh.add(pos, val, ids)
        np.testing.assert_array_equal(acc.sums, fresh.sums)
        np.testing.assert_array_equal(acc.distinct_counts, fresh.distinct_counts)
    assert np.array_equal(lists.lists.to_numpy(), built)  # the lists are never rebuilt nor changed
    check_against_twin(first, centers, reach, [(pos, val, ids)], [-2.0] * 3, [2.0] * 3)  # nor the first probe's
    small = GaussianLists(centers, reach, [-0.3] * 3, [0.3] * 3)
    with pytest.raises(ValueError, match="beyond the bounds"):
        GaussianAccumulator(small, [-2.0] * 3, [2.0] * 3)
    with pytest.raises(ValueError, match="domain_min"):
        GaussianAccumulator(lists, [0.0, 0.0, 0.0], [0.0, 1.0, 1.0])


@pytest.mark.parametrize(
    "rows, private, serial_below", [(1, False, 0), (1, True, 10**6), (3, True, 10**6), (3, True, 0)]
)
def test_atomic_and_per_thread_row_paths_equal_the_twin(monkeypatch, rows, private, serial_below):
    # (1, False) is the GPU path (atomic adds), run here on the CPU; 3 rows is more rows than threads; the particles
    # run on the launching thread (serial_below above the particle count, or fewer rows than pool threads) or in
    # parallel, each thread adding into its own row
    import nbv.physics.aggregate as aggregate

    monkeypatch.setattr(aggregate, "accumulation_rows", lambda g: (rows, private))
    centers, reach = random_gaussians(120, seed=5)
    rng = np.random.default_rng(6)
    steps = [random_step(rng, 300, 700) for _ in range(3)]
    for track in (False, True):  # the plain kernel, and the one that also records particle ids
        acc = GaussianAccumulator.build(centers, reach, DOMAIN_MIN, DOMAIN_MAX, track_distinct=track, max_fluid=700)
        acc.serial_below = serial_below
        assert acc.rows == rows and acc._acc.shape == (rows, acc.num_kept + 1, 2)
        for pos, val, ids in steps:
            acc.add(pos, val, ids)
        assert check_against_twin(acc, centers, reach, steps).max() > 50


@pytest.mark.parametrize("interleave_above", [aggregate.INTERLEAVE_ABOVE_BYTES, 0])
def test_staged_steps_equal_step_by_step_accumulation(monkeypatch, interleave_above):
    """Steps staged ``batch_steps`` at a time give the per-step result, visited flat or interleaved (the working
    set of large sets); a read accumulates what is staged."""
    monkeypatch.setattr(aggregate, "INTERLEAVE_ABOVE_BYTES", interleave_above)
    solver = tiny_probe_solver()
    rng = np.random.default_rng(5)
    centers = np.concatenate([rng.normal(0.0, 0.2, (80, 3)), [[0.5, 0.0, 0.0]]])
    reach = 3.0 * np.exp(rng.uniform(np.log(0.01), np.log(0.08), len(centers)))
    args = (centers, reach, solver.domain_min, solver.domain_max)
    batched = GaussianAccumulator.build(*args, batch_steps=3, track_distinct=True, max_fluid=solver.fluid.capacity)
    single = GaussianAccumulator.build(*args, batch_steps=1, track_distinct=True, max_fluid=solver.fluid.capacity)
    assert batched.batch_steps == 3 and batched._interleave == (interleave_above == 0)
    unstaged = GaussianAccumulator.build(*args, batch_steps=3, max_fluid=solver.fluid.capacity)
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
    np.testing.assert_array_equal(batched.sums, single.sums)  # fixed point: the same bits, whatever the batching
    assert np.array_equal(batched.distinct_counts, single.distinct_counts)
    assert np.array_equal(unstaged.counts, single.counts)
    np.testing.assert_array_equal(unstaged.sums, single.sums)
    batched.reset()  # drops staged steps too
    assert batched._staged == 0 and batched.counts.sum() == 0
    with pytest.raises(ValueError, match="batch_steps"):
        GaussianAccumulator.build(*args, batch_steps=0)


def test_values_out_of_the_fixed_point_range_saturate_with_a_warning(caplog):
    centers, reach = np.zeros((1, 3)), np.array([0.5])
    acc = GaussianAccumulator.build(centers, reach, DOMAIN_MIN, DOMAIN_MAX)
    assert acc.rows >= 1 and acc._acc.dtype == ti_i64()
    pos = np.array([[0.1, 0.0, 0.0], [0.0, 0.1, 0.0], [0.0, 0.0, 0.1]])
    assert VALUE_LIMIT / VALUE_SCALE == 16384.0 < 1e9
    acc.add(pos, np.array([2.5, 1e9, -3e9]))  # the two are clamped to +-16384 (and cancel); all three are counted
    with caplog.at_level("WARNING", logger="nbv.physics.aggregate"):
        assert acc.counts.tolist() == [3]
        assert acc.sums.tolist() == [2.5]
    assert "2 accumulated values were NaN or beyond" in caplog.text


def ti_i64():
    import taichi as ti

    return ti.i64


def test_thread_index_stays_below_the_pool_size():
    """The per-thread rows rely on Taichi's CPU thread index being below cpu_max_num_threads."""
    import taichi as ti

    from nbv.physics.aggregate import accumulation_rows

    @ti.kernel
    def largest_thread_index(n: ti.i32) -> ti.i32:
        m = 0
        for _ in range(n):
            ti.atomic_max(m, ti.global_thread_idx())
        return m

    rows, private = accumulation_rows(100)
    assert private and rows == ti.lang.impl.current_cfg().cpu_max_num_threads
    assert max(largest_thread_index(100_000) for _ in range(20)) < rows


# ---- the levels --------------------------------------------------------------------------------------------------
def multi_level_set(g: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Gaussians on a sphere-like shell (a surface, as real captures are) with reaches spanning 100x."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(g, 3))
    centers = 0.6 * d / np.linalg.norm(d, axis=1, keepdims=True) + rng.normal(0.0, 0.02, (g, 3))
    reach = np.exp(rng.uniform(np.log(0.006), np.log(0.6), g))
    return centers, reach


def near_surface_steps(rng, centers, steps: int, n: int, pool: int):
    """Particles near the Gaussians (most within reach of some) and a few far away, ids reused across steps."""
    out = []
    for _ in range(steps):
        pick = rng.integers(0, len(centers), n)
        pos = centers[pick] + rng.normal(0.0, 0.08, (n, 3))
        pos[: n // 10] = rng.uniform(-1.5, 1.5, (n // 10, 3))
        out.append((pos, rng.normal(size=n), rng.choice(pool, n, replace=False)))
    return out


def listed_reference(levels, centers, reach, lists: np.ndarray, rng, sample: int = 3000) -> None:
    """Brute force over cells of every level (all the non-empty ones up to ``sample``, and as many random ones): the
    listed Gaussians are exactly those whose reach sphere (plus the listing slack) comes closer to the cell's box,
    first those that cover the cell (every point of the box grown by the slack within reach, with a relative margin
    of 1e-9), then the others, each part in ascending internal order."""
    order = levels.order
    c, r = centers[order], reach[order]
    cells = levels.num_cells
    for lv, row in enumerate(levels.table):
        origin, cell, dims, offset = row[0:3], row[4], row[5:8].astype(int), int(row[8])
        first, last = levels.first[lv], levels.first[lv + 1]
        count = int(np.prod(dims))
        sizes = lists[offset + 1 : offset + count + 1] - lists[offset : offset + count]
        busy = np.nonzero(sizes)[0]
        picked = np.unique(np.concatenate([rng.permutation(busy)[:sample], rng.integers(0, count, sample)]))
        ijk = np.stack([picked // (dims[1] * dims[2]), (picked // dims[2]) % dims[1], picked % dims[2]], -1)
        slack = 1e-6 * cell
        for t, box in zip(picked, origin + ijk * cell, strict=True):
            gap = np.maximum(np.maximum(box - c[first:last], c[first:last] - box - cell), 0.0)
            touch = (gap**2).sum(-1) < (r[first:last] + slack) ** 2
            far = np.maximum(np.abs(c[first:last] - (box - slack)), np.abs(box + cell + slack - c[first:last]))
            cover = touch & ((far**2).sum(-1) * (1 + 1e-9) < r[first:last] ** 2)
            begin, split, end = lists[offset + t], lists[cells + 1 + offset + t], lists[offset + t + 1]
            items = lists[2 * cells + 1 + begin : 2 * cells + 1 + end]
            expected = first + np.concatenate([np.nonzero(cover)[0], np.nonzero(touch & ~cover)[0]])
            assert np.array_equal(items, expected) and split - begin == cover.sum()


@pytest.mark.parametrize("lookup_cost, levels", [(16.0, 2), (0.0, 6)])
def test_levels_of_a_set_with_reaches_spanning_100x_are_exact(monkeypatch, lookup_cost, levels):
    """Several levels (reach classes of a factor 2, merged by cost; a cheap lookup keeps more of them apart); every
    Gaussian listed exactly in the cells its sphere touches (brute force over the cells), the entries within their
    bound; sums, counts and distinct counts exactly the twin's."""

    monkeypatch.setattr(aggregate_levels, "LOOKUP_COST", lookup_cost)
    centers, reach = multi_level_set(3000, seed=21)
    rng = np.random.default_rng(22)
    acc = GaussianAccumulator.build(centers, reach, DOMAIN_MIN, DOMAIN_MAX, track_distinct=True, max_fluid=2000)
    lv = acc.levels
    assert lv.num_levels >= levels and acc.num_kept == len(centers) and acc.covered_entries > 0
    assert np.array_equal(np.sort(lv.order), np.arange(len(centers)))  # each Gaussian in exactly one level
    assert (np.diff(lv.cell_sizes) <= 0).all()  # largest reaches first
    for level in range(lv.num_levels):
        members = reach[lv.order[lv.first[level] : lv.first[level + 1]]]
        assert members.max() / members.min() > 1.2  # a class, not a single reach
    assert acc.list_entries <= lv.entries_bound <= ENTRIES_PER_GAUSSIAN * len(centers) + _ENTRY_SLACK
    listed_reference(lv, centers, reach, acc.lists.lists.to_numpy(), rng)
    steps = near_surface_steps(rng, centers, 4, 1500, 2000)
    plain = GaussianAccumulator.build(centers, reach, DOMAIN_MIN, DOMAIN_MAX)  # covered cells summed per cell, no test
    for pos, val, ids in steps:
        acc.add(pos, val, ids)
        plain.add(pos, val)
    counts = check_against_twin(acc, centers, reach, steps)
    assert np.array_equal(check_against_twin(plain, centers, reach, steps), counts)
    assert (counts > 0).mean() > 0.5


def test_gathered_and_scattered_lists_are_the_same(monkeypatch):
    """Each cell gathering its items, or each Gaussian scattering itself (chosen per level by cost): the same lists,
    item for item, and the brute-force ones."""

    centers, reach = multi_level_set(2000, seed=25)
    built = []
    for cost in (0.0, 1e12):  # always scatter, always gather
        monkeypatch.setattr(aggregate_levels, "_SCATTER_COST", cost)
        acc = GaussianAccumulator.build(centers, reach, DOMAIN_MIN, DOMAIN_MAX)
        built.append(acc.lists.lists.to_numpy())
    assert np.array_equal(built[0], built[1])
    listed_reference(acc.levels, centers, reach, built[1], np.random.default_rng(26), sample=500)


def test_gaussians_on_level_and_cell_boundaries_are_exact(monkeypatch):
    """Reaches exactly at the class boundaries r_max / 2^k and one ulp either side, centres exactly on cell faces,
    particles exactly on cell faces and one ulp inside and outside the reach: the twin's results.

    Anchors (two Gaussians of every reach, just outside the domain's corners) clip every level's box to the
    domain, so that the grids do not move when the other centres are moved onto their cell faces."""

    monkeypatch.setattr(aggregate_levels, "LOOKUP_COST", 0.0)  # no merges: one level per reach class
    lo, hi = np.full(3, -0.5), np.full(3, 0.5)
    bounds = 0.4 / 2.0 ** np.arange(5)
    reach = np.concatenate([bounds, np.nextafter(bounds, 0), np.nextafter(bounds, 1)])
    anchors = np.concatenate([lo - 0.5 * reach[:, None], hi + 0.5 * reach[:, None]])
    reach = np.concatenate([reach, reach, reach])
    rng = np.random.default_rng(31)
    free = rng.uniform(-0.45, 0.45, (len(reach) // 3, 3))
    first = GaussianAccumulator.build(np.concatenate([free, anchors]), reach, lo, hi)
    lv = first.levels
    assert lv.num_levels >= 4 and (lv.table[:, 0:3] == lo).all()
    level_of = np.empty(len(reach), int)
    for level in range(lv.num_levels):
        level_of[lv.order[lv.first[level] : lv.first[level + 1]]] = level
    cell = lv.table[level_of[: len(free)], 4][:, None]
    free = lo + np.round((free - lo) / cell) * cell  # onto the faces of their level's cells
    centers = np.concatenate([free, anchors])
    acc = GaussianAccumulator.build(centers, reach, lo, hi)
    assert np.array_equal(acc.levels.table, lv.table)  # the same grids
    pts = [free + s * reach[: len(free), None] * e for e in np.eye(3) for s in (1.0, -1.0)]  # at the reach
    for f in (1 - 1e-15, 1 + 1e-15, 1 - 1e-12, 0.5):
        pts.append(free + f * reach[: len(free), None] * np.array([1.0, 0.0, 0.0]))
    faces = lo + lv.table[:, 4][:, None, None] * rng.integers(0, 8, (lv.num_levels, 60, 3))
    pts.append(faces.reshape(-1, 3))  # on cell faces of every level
    pos = np.concatenate(pts)
    steps = [(pos, rng.normal(size=len(pos)))]
    acc.add(*steps[0])
    counts = check_against_twin(acc, centers, reach, steps, lo, hi)
    assert counts[: len(free)].min() > 0


def test_a_set_the_old_cell_lists_refused_fits_in_bounded_memory():
    """A few Gaussians reaching across the whole domain among many tiny ones (a single grid at the tiny ones' cell
    would list the big ones in millions of cells): the entries stay within ENTRIES_PER_GAUSSIAN per Gaussian."""
    rng = np.random.default_rng(41)
    centers = rng.uniform(-1.0, 1.0, (5000, 3))
    reach = np.full(5000, 0.004)
    reach[:40] = 2.0
    acc = GaussianAccumulator.build(centers, reach, DOMAIN_MIN, DOMAIN_MAX)
    assert acc.levels.num_levels == 2
    assert acc.list_entries <= ENTRIES_PER_GAUSSIAN * len(centers) + _ENTRY_SLACK
    pos, val, _ = random_step(rng, 2000, 2000)
    pos[:1000] = centers[40:1040] + rng.normal(0.0, 0.002, (1000, 3))  # within reach of the tiny ones
    acc.add(pos, val)
    assert acc.covered_entries > 0.5 * acc.list_entries  # the big ones cover most of their cells: no test there
    counts = check_against_twin(acc, centers, reach, [(pos, val)])
    assert counts[:40].min() > 500 and (counts[40:] > 0).sum() > 500


def test_plan_levels_drops_what_no_particle_can_reach():
    centers = np.array([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [1.5, 0.0, 0.0], [0.2, 0.1, 0.0]])
    reach = np.array([0.1, 0.5, 0.6, 0.0])
    lv = plan_levels(centers, reach, [-1.0] * 3, [1.0] * 3)
    assert sorted(lv.order.tolist()) == [0, 2]  # 1 is 2 m away with a 0.5 m reach; 3 has no reach
    empty = plan_levels(centers[1:2], reach[1:2], [-1.0] * 3, [1.0] * 3)
    assert empty.num_levels == 0 and len(empty.order) == 0


THREADS_SCRIPT = """
import json, sys
import numpy as np
import taichi as ti
ti.init(arch=ti.cpu, cpu_max_num_threads=int(sys.argv[1]), default_fp=ti.f32, offline_cache=True, log_level=ti.ERROR)
sys.path[:0] = sys.argv[2:4]  # this test module's folder, and tests/ (for helpers)
from test_aggregate import multi_level_set, near_surface_steps, DOMAIN_MIN, DOMAIN_MAX
from nbv.physics.aggregate import GaussianAccumulator
centers, reach = multi_level_set(2000, seed=51)
steps = near_surface_steps(np.random.default_rng(52), centers, 3, 6000, 8000)
out = []
for track, budget in ((True, 512 * 2**20), (True, 0), (False, 0)):
    acc = GaussianAccumulator.build(centers, reach, DOMAIN_MIN, DOMAIN_MAX, track_distinct=track, max_fluid=8000,
                              distinct_budget_bytes=budget)
    acc.serial_below = 0
    for p, v, i in steps:
        acc.add(p, v, i)
    out.append({"rows": acc.rows, "sums": acc.sums.tobytes().hex(), "counts": acc.counts.tolist(),
                "distinct": acc.distinct_counts.tolist() if track else None, "storage": acc.distinct_storage,
                "covered": acc.covered_entries})
print(json.dumps(out))
"""


def test_results_are_the_same_bits_on_any_thread_count():
    """One, two and three CPU threads (a row of sums each, the particles split differently): the same bits of the
    sums, the same counts and distinct counts (bit matrix and hash set)."""
    runs = []
    for threads in (1, 2, 3):
        out = subprocess.run(
            [sys.executable, "-c", THREADS_SCRIPT, str(threads), str(HERE), str(TESTS)],
            capture_output=True,
            text=True,
            cwd=REPO,
            timeout=300,
            check=True,
        )
        runs.append(json.loads(out.stdout.strip().splitlines()[-1]))
    assert [[r["rows"] for r in run] for run in runs] == [[1, 1, 1], [2, 2, 2], [3, 3, 3]]
    assert [r["storage"] for r in runs[0]] == ["bits", "hash", "none"]
    assert sum(runs[0][0]["counts"]) > 10000 and runs[0][2]["covered"] > 0  # the cell sums of covered cells too
    for run in runs:
        for r in run:
            assert r["sums"] == runs[0][0]["sums"] and r["counts"] == runs[0][0]["counts"]
            assert r["distinct"] in (None, runs[0][0]["distinct"])


# ---- memory ------------------------------------------------------------------------------------------------------
def allocated_bytes(acc: GaussianAccumulator) -> int:
    """Bytes of the accumulator's Taichi arrays."""
    import taichi as ti

    total = 0
    parts = [acc, acc.lists] + ([] if acc.distinct is None else [acc.distinct, acc.distinct.pairs])
    for value in (v for part in parts if part is not None for v in vars(part).values()):
        if isinstance(value, ti.lang._ndarray.Ndarray):
            itemsize = 8 if value.dtype in (ti.f64, ti.i64) else 4
            lanes = int(np.prod(getattr(value, "element_shape", ()) or (1,)))
            total += int(np.prod(value.shape)) * lanes * itemsize
    return total


def test_estimate_bytes_bounds_what_is_allocated():
    centers, reach = multi_level_set(20000, seed=61)
    rng = np.random.default_rng(62)
    for track, budget in ((False, 512 * 2**20), (True, 512 * 2**20), (True, 0)):
        acc = GaussianAccumulator.build(
            centers, reach, DOMAIN_MIN, DOMAIN_MAX, track_distinct=track, max_fluid=3000, distinct_budget_bytes=budget
        )
        for p, v, i in near_surface_steps(rng, centers, 3, 3000, 3000):
            acc.add(p, v, i)
        pairs = int(acc.distinct_counts.sum()) if track else None
        estimate = GaussianAccumulator.estimate_bytes(
            len(centers), 3000, track, distinct_pairs=pairs, distinct_budget_bytes=budget
        )
        assert allocated_bytes(acc) <= estimate
    # the scale the bit matrix cannot reach: 1M Gaussians x 100k particles (12.5 GB of bits) -> the hash set, sized
    # by the pairs (5.0M measured on a 1.07M-Gaussian capture's -x probe)
    plain = GaussianAccumulator.estimate_bytes(10**6, 10**5, False, threads=2)
    tracked = GaussianAccumulator.estimate_bytes(10**6, 10**5, True, distinct_pairs=5 * 10**6, threads=2)
    assert plain < 1.5 * 2**30 and tracked < plain + 2**30
    assert GaussianAccumulator.estimate_bytes(5 * 10**6, 3 * 10**5, True, threads=2) < 16 * 2**30


def test_jittered_copies_make_a_denser_set_of_the_same_object():
    """`bench score --densify K`: the original first, then K - 1 copies whose means move by about jitter sigma along
    each Gaussian's own axes (a flat Gaussian's copies stay in its plane), everything else kept."""
    import torch

    from nbv.bench.dense_sets import jittered_copies
    from recon.gaussians import GaussianSet, quaternion_to_rotation

    rng = np.random.default_rng(71)
    n = 400
    means = torch.tensor(rng.uniform(-1, 1, (n, 3)), dtype=torch.float32)
    quats = torch.tensor(rng.normal(size=(n, 4)), dtype=torch.float32)
    log_scales = torch.log(torch.tensor([[0.05, 0.02, 1e-4]], dtype=torch.float32)).repeat(n, 1)  # flat
    base = GaussianSet(means, quats, log_scales, torch.zeros(n), torch.zeros(n, 1, 3))
    dense = jittered_copies(base, 4, 0.5, seed=3)
    assert dense.num == 4 * n and torch.equal(dense.means[:n], base.means)
    assert torch.equal(dense.log_scales, base.log_scales.repeat(4, 1))
    assert torch.equal(dense.quats, base.quats.repeat(4, 1))
    rot = quaternion_to_rotation(base.quats.double())
    offsets = dense.means[n:].double().reshape(3, n, 3) - base.means.double()
    local = torch.einsum("nji,knj->kni", rot, offsets)
    ratio = local / base.log_scales.double().exp()  # offsets in standard deviations per axis
    assert 0.4 < float(ratio[..., :2].std()) < 0.6  # jitter 0.5 sigma along the two long axes
    assert float(local[..., 2].abs().max()) < 1e-3  # and within 0.5 sigma (5e-5) of the plane: f32 noise
    with pytest.raises(ValueError, match="densify"):
        jittered_copies(base, 0, 0.5)
