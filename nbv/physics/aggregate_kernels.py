"""Taichi kernels of :mod:`nbv.physics.aggregate`: the per-step accumulation (paper Eq. 2-3), the staging copy, the
set of (Gaussian, particle id) pairs behind the distinct counts |P_g|, and the read of the covered cells' sums.

A fluid particle finds its cell on every level (the levels and their cell lists are built once per run by
:mod:`nbv.physics.aggregate_level_kernels`), tests the Gaussians that only touch its own cell, |x - mu_g|^2 < r_g^2
in f64 as the numpy twin does, and adds its value once to the cell's sum for the covering ones (:func:`spread_cells`
hands those sums to them on read).
"""

from typing import NamedTuple

import taichi as ti

from fluidsim.launch import fast_kernel
from nbv.physics.aggregate_level_kernels import ITEMS_OFFSET, SPLITS_OFFSET

vec3d = ti.types.vector(3, ti.f64)
vec4d = ti.types.vector(4, ti.f64)

# An empty slot of the hash set (keys are g * 2^32 + id >= 0).
EMPTY_KEY = -1

# Fixed-point sums: a value v is added as floor(v * VALUE_SCALE + 1/2) in an i64, clamped to +-VALUE_LIMIT quanta (NaN
# adds 0; both are counted as saturated in the extra Gaussian slot G). Integer sums are exact and do
# not depend on the order of the additions, so the per-thread rows give the same bits on any thread count.
VALUE_SCALE = float(2**24)  # quanta per unit of the value: 6e-8 (1/s for D_i)
VALUE_LIMIT = float(2**38)  # largest |v| = 16384 units; a Gaussian's sum holds 2^25 such samples


@ti.func
def fixed_point(v):
    """(quanta, saturated): floor(v * VALUE_SCALE + 1/2) as an i64, clamped to +-VALUE_LIMIT (NaN: 0), and
    saturated = 1 where it was clamped."""
    q = ti.cast(v, ti.f64) * VALUE_SCALE
    quanta = ti.i64(0)
    saturated = ti.i64(1)
    if ti.abs(q) <= VALUE_LIMIT:  # False for NaN
        quanta = ti.cast(ti.floor(q + 0.5), ti.i64)  # halves round up (f32 values below 0.5 can be ties)
        saturated = ti.i64(0)
    elif q > VALUE_LIMIT:
        quanta = ti.cast(VALUE_LIMIT, ti.i64)
    elif q < -VALUE_LIMIT:
        quanta = -ti.cast(VALUE_LIMIT, ti.i64)
    return quanta, saturated


@ti.func
def inside_domain(table: ti.template(), x):
    """x within [domain_min, domain_max] (row 0 of ``table``), bounds included; False for NaN."""
    ok = True
    for d in ti.static(range(3)):
        if not (table[0, d] <= x[d] <= table[0, 3 + d]):
            ok = False
    return ok


@ti.func
def level_cell(table: ti.template(), lv, x):
    """(inside, index): the cell of x in level ``lv`` (row ``lv`` of ``table``) and its index in the cell starts; a
    cell outside the level's grid is never clamped (inside = False: no Gaussian of the level reaches there)."""
    inside = True
    lin = 0
    for d in ti.static(range(3)):
        f = ti.floor((x[d] - table[lv, d]) * table[lv, 3])
        if not (0.0 <= f < table[lv, 5 + d]):  # also False for NaN
            inside = False
        else:
            lin = lin * ti.cast(table[lv, 5 + d], ti.i32) + ti.cast(f, ti.i32)
    return inside, lin + ti.cast(table[lv, 8], ti.i32)


@ti.func
def hash_slot(key, mask):
    """Slot of ``key`` = g * 2^32 + id in a table of mask + 1 (a power of two) slots: Fibonacci hashing of the two
    32-bit halves (every product fits 64 bits, so Taichi's debug mode sees no overflow)."""
    k = ti.cast(key, ti.u64)
    u = (k & ti.u64(0xFFFFFFFF)) * ti.u64(0x9E3779B1) ^ (k >> ti.u64(32)) * ti.u64(0x85EBCA77)
    lo = (u ^ (u >> ti.u64(32))) & ti.u64(0xFFFFFFFF)
    h = lo * ti.u64(0x9E3779B1)
    return ti.cast((h ^ (h >> ti.u64(32))) & ti.cast(mask, ti.u64), ti.i64)


@ti.func
def set_insert(hashes: ti.template(), fill: ti.template(), key):
    """Insert ``key`` (>= 0) into the open-addressing set ``hashes`` (linear probing, lock-free); ``fill[0]`` counts
    the filled slots. The caller keeps the set at most half full, so a probe run ends soon.

    Every slot only grows (``atomic_max``), so the keys along a probe run stay in decreasing order from their home
    slot (an ordered hash table): a key meets either itself (a duplicate: done), an empty slot (placed: the fill
    grows by one), a larger key (probe on) or a smaller one, which it displaces and whose insertion it carries on.
    """
    mask = ti.cast(hashes.shape[0] - 1, ti.i64)
    slot = hash_slot(key, mask)
    k = key
    while True:
        old = ti.atomic_max(hashes[slot], k)
        if old == k:
            break
        if old == EMPTY_KEY:
            ti.atomic_add(fill[0], ti.i64(1))
            break
        if old < k:  # k took the slot: carry the displaced key on
            k = old
        slot = (slot + 1) & mask


class Samples(NamedTuple):
    """The particles a pass visits (kernel arguments, bound at compile time): positions ``xs`` (m), values
    ``values``, and for tracking the ids ``ids`` and each one's previous sample ``prevs`` (vec3 f64, m; NaN: none).
    An untracked pass hands any arrays as ``ids`` and ``prevs``: they are never read."""

    xs: object
    values: object
    ids: object
    prevs: object


class Levels(NamedTuple):
    """The levels built once per run (kernel arguments): ``table`` and ``lists`` (cell starts, splits and items;
    see ``nbv.physics.aggregate_level_kernels.TABLE_WIDTH``) and ``gauss`` (mu_g, r_g^2 as vec4 f64)."""

    table: object
    lists: object
    gauss: object


class Sums(NamedTuple):
    """What a pass adds into (kernel arguments): ``acc`` [rows, G + 1, 2] (quanta, hits), ``cell_sums`` [rows, cells,
    2] of the covered cells, and for tracking the listed keys ``keys`` and their count ``emitted[0]``. A pass that
    does not use one hands another array of the same kind: it is never written."""

    acc: object
    cell_sums: object
    keys: object
    emitted: object


class Mode(NamedTuple):
    """Compile-time switches of a pass: ``add_values`` (add the values and hits), ``track`` (list the (Gaussian,
    particle id) pairs) and ``private`` (each CPU thread adds into its own row without atomics; otherwise row 0,
    atomic)."""

    add_values: bool
    track: bool
    private: bool


@ti.func
def visit_gaussian(g, x, q, row, pid, prev, prev_ok, levels: ti.template(), mode: ti.template(), sums: ti.template()):
    """Paper Eq. 2-3 for one (particle, Gaussian) pair: when |x - mu_g|^2 < r_g^2 add the value (quanta q) and 1 to
    row ``row`` of g, and record the particle id ``pid`` unless the particle's previous sample ``prev`` (``prev_ok``:
    it was inside the domain) was within reach of g too, which recorded the pair then.

    With ``mode.private`` the row belongs to one thread only and the adds are plain; otherwise atomic (GPUs).
    """
    p = levels.gauss[g]
    acc = ti.static(sums.acc)
    dx, dy, dz = x[0] - p[0], x[1] - p[1], x[2] - p[2]
    hit = dx * dx + dy * dy + dz * dz < p[3]
    if ti.static(mode.add_values and mode.private):
        # branch-free: a plain add of 0 on a miss is cheaper than the mispredicted branch of an unpredictable test
        acc[row, g, 0] = acc[row, g, 0] + ti.select(hit, q, ti.i64(0))
        acc[row, g, 1] = acc[row, g, 1] + ti.select(hit, ti.i64(1), ti.i64(0))
    if ti.static(mode.add_values and not mode.private):
        if hit:
            ti.atomic_add(acc[0, g, 0], q)
            ti.atomic_add(acc[0, g, 1], ti.i64(1))
    if ti.static(mode.track):
        # the previous sample's test, computed branch-free: only the rare first step of a visit branches
        ex, ey, ez = prev[0] - p[0], prev[1] - p[1], prev[2] - p[2]
        seen = ti.select(prev_ok, ex * ex + ey * ey + ez * ez < p[3], False)
        if ti.select(seen, False, hit):  # listed here, recorded by another kernel: a lean inner loop
            slot = ti.atomic_add(sums.emitted[0], ti.i64(1))
            if slot < sums.keys.shape[0]:
                sums.keys[slot] = (ti.cast(g, ti.i64) << 32) + ti.cast(pid, ti.i64)


@ti.func
def visit_level(lv, x, q, row, pid, prev, prev_ok, levels: ti.template(), mode: ti.template(), sums: ti.template()):
    """The Gaussians of level ``lv`` listed in the cell of x: those that only touch the cell are tested; those that
    cover it are hits without a test, and the value goes once into the cell's own sum (``sums.cell_sums``), spread
    onto them on read (:func:`spread_cells`). With ``mode.track`` every listed Gaussian is tested (each visit is
    recorded)."""
    table, lists = ti.static(levels.table, levels.lists)
    inside, c = level_cell(table, lv, x)
    if inside:
        items = ti.cast(table[0, ITEMS_OFFSET], ti.i32)
        begin, middle, end = lists[c], lists[ti.cast(table[0, SPLITS_OFFSET], ti.i32) + c], lists[c + 1]
        first = middle
        if ti.static(mode.track):
            first = begin
        for s in range(first, end):
            visit_gaussian(lists[items + s], x, q, row, pid, prev, prev_ok, levels, mode, sums)
        if ti.static(mode.add_values and not mode.track):
            if middle > begin:
                if ti.static(mode.private):
                    sums.cell_sums[row, c, 0] += q
                    sums.cell_sums[row, c, 1] += 1
                else:
                    ti.atomic_add(sums.cell_sums[0, c, 0], q)
                    ti.atomic_add(sums.cell_sums[0, c, 1], ti.i64(1))


@ti.func
def visit_particle(i, row, samples: ti.template(), levels: ti.template(), mode: ti.template(), sums: ti.template()):
    """Paper Eq. 2-3 for fluid particle i inside the domain: every level (:func:`visit_level`); a saturated value
    (:func:`fixed_point`) is counted in the extra slot G."""
    table, acc = ti.static(levels.table, sums.acc)
    x = ti.cast(samples.xs[i], ti.f64)
    if inside_domain(table, x):
        q, saturated = fixed_point(samples.values[i])
        if ti.static(mode.add_values):
            if saturated:
                if ti.static(mode.private):
                    acc[row, acc.shape[1] - 1, 0] += 1
                else:
                    ti.atomic_add(acc[0, acc.shape[1] - 1, 0], ti.i64(1))
        prev = ti.Vector([0.0, 0.0, 0.0], ti.f64)
        prev_ok = False
        pid = 0
        if ti.static(mode.track):
            prev = samples.prevs[i]
            prev_ok = inside_domain(table, prev)
            pid = ti.cast(samples.ids[i], ti.i32)
        for lv in range(1, table.shape[0]):
            visit_level(lv, x, q, row, pid, prev, prev_ok, levels, mode, sums)


@ti.func
def visit_all(
    n,
    steps: ti.template(),
    samples: ti.template(),
    levels: ti.template(),
    mode: ti.template(),
    sums: ti.template(),
    serial: ti.template(),
):
    """All particles of the staged steps (``steps``: B + 1 offsets, step s holds particles steps[s]..steps[s+1]-1),
    interleaved: iteration k (of n, the longest step) visits particle k of every step. The solver keeps its
    particles sorted by cell, so particle k of consecutive steps sits at about the same place, and its cell lists,
    Gaussians and sums are still in the caches for the next step's. On the launching thread into row 0
    (``serial``), in parallel with each CPU thread adding into its own row (``mode.private``: row = the thread's
    index, so the caller gives at least as many rows as threads), or in parallel with atomic adds into row 0
    (GPUs). The sums are integers, so the order does not change them."""
    b = steps.shape[0] - 1
    if ti.static(serial):
        ti.loop_config(serialize=True)
        for k in range(n):
            for s in range(b):
                i = steps[s] + k
                if i < steps[s + 1]:
                    visit_particle(i, 0, samples, levels, mode, sums)
    else:
        for k in range(n):
            row = 0
            if ti.static(mode.private):
                row = ti.global_thread_idx()
            for s in range(b):
                i = steps[s] + k
                if i < steps[s + 1]:
                    visit_particle(i, row, samples, levels, mode, sums)


@fast_kernel
def accumulate(
    n: ti.i32,
    steps: ti.types.ndarray(dtype=ti.i32, ndim=1),
    xs: ti.types.ndarray(ndim=1),
    values: ti.types.ndarray(ndim=1),
    table: ti.types.ndarray(dtype=ti.f64, ndim=2),
    lists: ti.types.ndarray(dtype=ti.i32, ndim=1),
    gauss: ti.types.ndarray(dtype=vec4d, ndim=1),
    private: ti.template(),
    serial: ti.template(),
    acc: ti.types.ndarray(dtype=ti.i64, ndim=3),
    cell_sums: ti.types.ndarray(dtype=ti.i64, ndim=3),
):
    """Paper Eq. 2-3: each particle i inside the domain adds ``values[i]`` (in quanta of 1 / VALUE_SCALE) to
    ``acc[row, g, 0]`` and 1 to ``acc[row, g, 1]`` for every Gaussian g with |x_i - mu_g|^2 < r_g^2
    (``gauss[g]`` = (mu_g, (n r_g)^2)); ``acc[row, G, 0]`` counts saturated values. The domain in ``table`` is the
    probe's domain clipped to the levels' grids (no Gaussian reaches beyond them).

    ``n``, ``steps``: the longest staged step and the staged steps' offsets of :func:`visit_all` (one step: n
    particles, steps = [0, n]).
    ``table``, ``lists``: see ``aggregate_level_kernels.TABLE_WIDTH``. A particle in a cell that Gaussians cover
    adds its value once to ``cell_sums[row, c]`` (:func:`visit_level`).
    ``private`` (CPUs): ``acc`` has a row per thread of the pool, each thread adds into its own row without
    atomics, and the caller sums the rows; the sums are integers, so the result is bitwise the same for any
    thread count or schedule. Otherwise (GPUs) one row and atomic adds.
    ``serial``: the particles run on the launching thread (row 0), which on small probes costs less than
    waking the thread pool.
    """
    visit_all(
        n,
        steps,
        ti.static(Samples(xs, values, values, xs)),
        ti.static(Levels(table, lists, gauss)),
        ti.static(Mode(True, False, private)),
        ti.static(Sums(acc, cell_sums, acc, acc)),
        serial,
    )


@fast_kernel
def accumulate_tracked(
    n: ti.i32,
    steps: ti.types.ndarray(dtype=ti.i32, ndim=1),
    xs: ti.types.ndarray(ndim=1),
    values: ti.types.ndarray(ndim=1),
    ids: ti.types.ndarray(dtype=ti.i32, ndim=1),
    prevs: ti.types.ndarray(dtype=vec3d, ndim=1),
    table: ti.types.ndarray(dtype=ti.f64, ndim=2),
    lists: ti.types.ndarray(dtype=ti.i32, ndim=1),
    gauss: ti.types.ndarray(dtype=vec4d, ndim=1),
    add_values: ti.template(),
    track: ti.template(),
    private: ti.template(),
    serial: ti.template(),
    acc: ti.types.ndarray(dtype=ti.i64, ndim=3),
    keys: ti.types.ndarray(dtype=ti.i64, ndim=1),
    emitted: ti.types.ndarray(dtype=ti.i64, ndim=1),
):
    """:func:`accumulate` (when ``add_values``) that also records the ids of the particles that come within reach of
    each Gaussian (``track``, True). A pair is listed when particle ``ids[i]`` is within reach of g now and its
    previous sample ``prevs[i]`` was not (or was outside the domain, or there is none: NaN), since every visit starts
    with such a step: the set of pairs is the same, at the cost of one record per visit instead of one per step.
    The key g * 2^32 + ids[i] goes to ``keys`` (slot from ``emitted[0]``; slots past the end are counted but not
    written, so the caller can grow ``keys`` and list the batch again), and :func:`set_bits` or :func:`insert_keys`
    records the listed keys.

    ``serial``: as in :func:`accumulate`.
    """
    visit_all(
        n,
        steps,
        ti.static(Samples(xs, values, ids, prevs)),
        ti.static(Levels(table, lists, gauss)),
        ti.static(Mode(add_values, track, private)),
        ti.static(Sums(acc, acc, keys, emitted)),
        serial,
    )


@ti.func
def stage_one(
    i,
    offset,
    xs: ti.template(),
    values: ti.template(),
    ids: ti.template(),
    staged_x: ti.template(),
    staged_values: ti.template(),
    staged_ids: ti.template(),
    last: ti.template(),
    staged_prev: ti.template(),
    track: ti.template(),
):
    staged_x[offset + i] = xs[i]
    staged_values[offset + i] = values[i]
    staged_ids[offset + i] = ids[i]
    if ti.static(track):
        pid = ids[i]
        staged_prev[offset + i] = last[pid]
        last[pid] = ti.cast(xs[i], ti.f64)


@fast_kernel
def stage_particles(
    n: ti.i32,
    offset: ti.i32,
    xs: ti.types.ndarray(ndim=1),
    values: ti.types.ndarray(ndim=1),
    ids: ti.types.ndarray(dtype=ti.i32, ndim=1),
    staged_x: ti.types.ndarray(ndim=1),
    staged_values: ti.types.ndarray(ndim=1),
    staged_ids: ti.types.ndarray(dtype=ti.i32, ndim=1),
    last: ti.types.ndarray(dtype=vec3d, ndim=1),
    staged_prev: ti.types.ndarray(dtype=vec3d, ndim=1),
    track: ti.template(),
    serial: ti.template(),
):
    """Copy particles 0..n-1 (positions, values, ids) to slots offset..offset+n-1 of the staging arrays; with
    ``track``, also each particle's previous sample ``last[id]`` (NaN: none), and make this one the last.

    ``serial`` keeps the particles' order (ids may repeat within one call of the numpy path: each then sees the one
    before it as its previous sample); the solver's ids are distinct within a step.
    """
    if ti.static(serial):
        ti.loop_config(serialize=True)
        for i in range(n):
            stage_one(i, offset, xs, values, ids, staged_x, staged_values, staged_ids, last, staged_prev, track)
    else:
        for i in range(n):
            stage_one(i, offset, xs, values, ids, staged_x, staged_values, staged_ids, last, staged_prev, track)


@fast_kernel
def insert_keys(
    n: ti.i32,
    keys: ti.types.ndarray(dtype=ti.i64, ndim=1),
    hashes: ti.types.ndarray(dtype=ti.i64, ndim=1),
    fill: ti.types.ndarray(dtype=ti.i64, ndim=1),
):
    """Insert the keys >= 0 among ``keys[:n]`` (listed pairs, or another set's slots) into the set ``hashes``."""
    for i in range(n):
        if keys[i] != EMPTY_KEY:
            set_insert(hashes, fill, keys[i])


@fast_kernel
def set_bits(n: ti.i32, keys: ti.types.ndarray(dtype=ti.i64, ndim=1), bits: ti.types.ndarray(dtype=ti.u32, ndim=2)):
    """Set bit id of row g of ``bits`` [G, words] for every key g * 2^32 + id among ``keys[:n]`` (atomic or)."""
    for i in range(n):
        g = ti.cast(keys[i] >> 32, ti.i32)
        pid = ti.cast(keys[i] & ti.i64(0xFFFFFFFF), ti.i32)
        ti.atomic_or(bits[g, pid >> 5], ti.cast(1, ti.u32) << ti.cast(pid & 31, ti.u32))


@fast_kernel
def count_keys(hashes: ti.types.ndarray(dtype=ti.i64, ndim=1), counts: ti.types.ndarray(dtype=ti.i64, ndim=1)):
    """``counts[g]`` += the number of keys g * 2^32 + id in the set (the distinct ids recorded for g)."""
    for s in range(hashes.shape[0]):
        key = hashes[s]
        if key != EMPTY_KEY:
            ti.atomic_add(counts[ti.cast(key >> 32, ti.i32)], ti.i64(1))


@fast_kernel
def count_bits(bits: ti.types.ndarray(dtype=ti.u32, ndim=2), counts: ti.types.ndarray(dtype=ti.i64, ndim=1)):
    """``counts[g]`` = the bits set in row g of ``bits`` (the distinct ids recorded for g)."""
    for g in range(bits.shape[0]):
        total = ti.i64(0)
        for w in range(bits.shape[1]):
            total += ti.cast(ti.math.popcnt(bits[g, w]), ti.i64)
        counts[g] = total


@fast_kernel
def spread_cells(
    table: ti.types.ndarray(dtype=ti.f64, ndim=2),
    lists: ti.types.ndarray(dtype=ti.i32, ndim=1),
    cell_sums: ti.types.ndarray(dtype=ti.i64, ndim=3),
    out: ti.types.ndarray(dtype=ti.i64, ndim=2),
):
    """``out[g]`` += the sums and counts that particles left in the cells g covers (``cell_sums`` [rows, cells, 2],
    the rows summed): integer adds, so the result is the same in any order."""
    items = ti.cast(table[0, ITEMS_OFFSET], ti.i32)
    splits = ti.cast(table[0, SPLITS_OFFSET], ti.i32)
    for c in range(splits - 1):
        begin, middle = lists[c], lists[splits + c]
        if middle > begin:
            total, count = ti.i64(0), ti.i64(0)
            for row in range(cell_sums.shape[0]):
                total += cell_sums[row, c, 0]
                count += cell_sums[row, c, 1]
            if count > 0:
                for s in range(begin, middle):
                    g = lists[items + s]
                    ti.atomic_add(out[g, 0], total)
                    ti.atomic_add(out[g, 1], count)
