"""Per-Gaussian accumulation of per-fluid-particle values through cell lists (paper Eq. 2-3, Sec. 3.3).

Fluid particle i contributes its divergence D_i (paper Eq. 1) to Gaussian g when |x_i - mu_g| < n r_g
(n = 3, r_g the largest principal radius of g):

    D_g = sum_{steps} sum_{i near g} D_i / #(i, step) pairs    (0 when no particle came near g),

and |P_g| is the number of distinct fluid particles that ever came within n r_g of g (the
function-critical regions). Accumulation never loops over all particles x all Gaussians, and its memory is
O(G + particles) with a fixed bound per Gaussian (:meth:`GaussianAccumulator.estimate_bytes`):

- **Levels** (:mod:`nbv.physics.aggregate_levels`: built once per run with the lists,
  :class:`~nbv.physics.aggregate_levels.GaussianLists`; each probe gets fresh sums, :class:`GaussianAccumulator`).
  The static Gaussians are sorted into classes by reach (a factor ``LEVEL_RATIO`` = 2 each), and adjacent classes
  are merged where a cost model says one level is cheaper than two (a particle's cell lookup on a level costs
  ``LOOKUP_COST`` Gaussian tests). A level is a uniform grid whose cell starts at
  ``CELL_FRACTION`` (1/2) of the level's largest reach; a Gaussian of that level is listed in every cell of it that
  its reach sphere touches, at most (2 / fraction + 1)^3 cells whatever the other Gaussians' reaches, so one huge
  Gaussian no longer multiplies the lists of all the others (a single grid at the small Gaussians' cell listed a
  1.07M-Gaussian capture in 8.6e8 cells and was refused). The list entries are capped at ``ENTRIES_PER_GAUSSIAN``
  (128) per Gaussian on average: within that budget the levels whose finer cells save the most tests per added
  entry refine (down to 1/16 of their reach), which gives the few large Gaussians, tested by many particles, fine
  cells; above it the largest lists coarsen. The cells of a level are capped at ``CELLS_PER_GAUSSIAN`` per Gaussian
  (or ``MIN_LEVEL_CELLS``). Gaussians that cannot reach the grid bounds (the union of the probes' domains) and zero
  reaches are dropped. The lists are built in two passes in which every cell gathers its own items from the
  Gaussians whose centre cell is near (the Gaussians being sorted by it): no atomics, sequential writes, items in
  ascending order, so the lists are the same on any thread count.
- **Per step**, each fluid particle inside the domain (and inside the levels' grids) tests, on every level, the
  Gaussians listed in its own cell: |x_i - mu_g|^2 < r_g^2 in f64, as the numpy twin does. A Gaussian that covers a
  cell (every point of it within reach, with a rounding margin) is listed before the cell's split and not tested:
  the particle adds its value once to the cell's own sum, which is spread onto the covering Gaussians on read
  (integer sums: exact, in any order). Large Gaussians, which many particles hit, then cost a test only in the cells
  their sphere's surface crosses (1.07M-Gaussian person capture, -x probe, step 150: 104 instead of 162 tests a
  particle).
  Internally the Gaussians are numbered by level and by the cell of their centre, so a cell's items sit together in
  memory. With distinct tracking every listed Gaussian is tested (each visit must be recorded).
- **Sums.** On a CPU each thread adds into its own row of sums and counts (row = ``ti.global_thread_idx()``; plain,
  branch-free adds, rows summed on read), on a GPU atomics do. The sums are fixed-point integers (values rounded to
  2^-24 = 6e-8, exact sums), so they are the same bits whatever the thread count or the order of the additions.
- **Staging.** A solver's steps are staged (positions, values and ids copied, a sequential 20 bytes per particle)
  and accumulated ``batch_steps`` (16) at a time: after a solver step the Gaussians' records, lists and sums are
  out of the caches, and one pass over many steps' particles pays the cold misses once. When those records, sums and
  lists exceed the caches (``INTERLEAVE_ABOVE_BYTES``, 32 MiB: a 152k-Gaussian capture and larger), the pass visits
  particle k of every staged step in a row: the solver keeps its particles sorted by cell, so they sit at about the
  same place and find the same lists in the caches (1.07M Gaussians: 0.5x the time of a flat pass). Without
  distinct tracking, probes under ``SERIAL_BELOW`` fluid particles are not staged: each step accumulates at once on
  the launching thread (a small step leaves the Gaussians cached, and the staging copy would cost a launch per
  step). Every read (sums, counts, means, distinct counts) accumulates what is staged first.
- **Distinct particles** |P_g| are exact (:mod:`nbv.physics.aggregate_distinct`). A pair (g, id) is recorded only on
  the first step of each visit: the staging copy hands each particle its previous sample (kept per id, O(particles)),
  and a hit whose previous sample was within reach of g too is not recorded again (it was recorded then); in the paper
  setting 1.5 % of the hits start a visit. The accumulation lists those pairs in a buffer, and a second kernel records
  them: one bit per (Gaussian, fluid id) (``atomic_or``) while that matrix fits ``distinct_budget_bytes`` (512 MiB by
  default: 20k Gaussians x 60k particles take 150 MB), else a lock-free open-addressing hash set of g * 2^32 + id keys
  (ordered linear probing with ``atomic_max``), at most half full: 16-32 bytes per distinct pair (a 1.07M-Gaussian
  capture's -x probe has 5.0M pairs, 4.7 per Gaussian), doubled by rehashing before it would fill beyond half.

:func:`nbv.physics.aggregate_reference.accumulate_reference` (and ``within_reach_reference``) are the O(N G) numpy
twins.
"""

from __future__ import annotations

import logging
import math
import os
from typing import TYPE_CHECKING

import numpy as np
import taichi as ti

from nbv.physics import aggregate_kernels as kernels
from nbv.physics.aggregate_distinct import (
    _HASH_LOAD,
    _HASH_MIN_SLOTS,
    _KEY_BUFFER,
    DEFAULT_DISTINCT_BUDGET,
    DistinctParticles,
    default_distinct_pairs,
)
from nbv.physics.aggregate_level_kernels import TABLE_WIDTH
from nbv.physics.aggregate_levels import (
    _ENTRY_SLACK,
    CELLS_PER_GAUSSIAN,
    ENTRIES_PER_GAUSSIAN,
    MAX_LEVELS,
    MIN_LEVEL_CELLS,
    GaussianLevels,
    GaussianLists,
    _as_box,
    _as_points,
    plan_levels,
    reach_classes,
)

if TYPE_CHECKING:
    from fluidsim import DFSPHSolver

__all__ = [
    "GaussianAccumulator",
    "GaussianLevels",
    "GaussianLists",
    "accumulation_rows",
    "plan_levels",
    "reach_classes",
]

log = logging.getLogger(__name__)

# Below this many fluid particles a step's accumulation runs on the launching thread (CPU): waking the thread
# pool costs more than a second thread saves on a small probe.
SERIAL_BELOW = 4096
# Largest size of the per-thread rows of sums and counts (16 bytes per Gaussian and row) on a CPU.
_ROWS_BUDGET = 256 * 2**20
# Solver steps staged per accumulation pass, and the most bytes the staged particles may take. Above
# INTERLEAVE_ABOVE_BYTES of Gaussian records, sums and cell lists (beyond the caches) the staged steps are visited
# interleaved (particle k of every step in a row, :func:`nbv.physics.aggregate_kernels.visit_all`). Measured on recorded
# paper-setting probes (40 steps at the impact, 2 threads, interleaved rounds against 8 flat steps): the 1.07M-Gaussian
# capture (~400 MB) 0.50-0.56x the time with 8-16 interleaved steps, its 152k original (58 MB) 0.85x, the bundled
# asset (16 MB, in the caches) 0.97-1.14x, so it stays flat.
BATCH_STEPS = 16
INTERLEAVE_ABOVE_BYTES = 32 * 2**20
_STAGE_BUDGET = 64 * 2**20
# Bytes per Gaussian while the levels are planned (numpy temporaries: masks, gaps, cell indices, sort keys).
_PLAN_BYTES_PER_GAUSSIAN = 160


def accumulation_rows(num_gaussians: int) -> tuple[int, bool]:
    """(rows, private) of the sums and counts for the current Taichi runtime.

    On a CPU every thread of the pool gets its own row of sums and counts (plain adds without atomics, summed on
    read), while the rows fit ``_ROWS_BUDGET`` bytes. Otherwise (GPUs, or too many Gaussians) one row with atomic
    adds.
    """
    if ti.lang.impl.get_runtime().prog is None:  # not initialised yet (a memory estimate): every core's row
        cpu, threads = True, max(os.cpu_count() or 1, 1)
    else:
        cfg = ti.lang.impl.current_cfg()
        cpu, threads = cfg.arch in (ti.x64, ti.arm64), max(int(cfg.cpu_max_num_threads or 0), 1)
    if not cpu or threads * 16 * (max(num_gaussians, 1) + 1) > _ROWS_BUDGET:
        return 1, False
    return threads, True


# ---- the accumulator: one probe's sums -----------------------------------------------------------
class GaussianAccumulator:
    """Sums, counts and distinct particle counts of one probe's per-particle values near each Gaussian, on lists
    built once per run.

    Args:
        lists: the Gaussians' cell lists (:class:`nbv.physics.aggregate_levels.GaussianLists`), shared by the probes
            of a run; ``domain_min``/``domain_max`` must lie within their bounds.
        domain_min, domain_max: [3] simulation domain, m; particles outside it (retired fluid) are ignored.
        track_distinct: also count the distinct particle ids near each Gaussian (|P_g|).
        max_fluid: number of fluid particle ids expected (ids < max_fluid), to size the per-id records (and the
            bit matrix) up front; 0 = size them on first use (they grow when needed).
        distinct_budget_bytes: largest bit matrix; beyond it the exact hash set of pairs is used.
        batch_steps: solver steps staged per accumulation pass (:meth:`add_from_solver`); 1 = accumulate each
            step at once. The sums are the same bits either way.

    Example:
        >>> lists = GaussianLists(means, 3.0 * radii, *plan.bounds)           # once per run
        >>> acc = GaussianAccumulator(lists, setup.domain_min, setup.domain_max)  # per probe
        >>> run(solver, steps, on_step=lambda s, st: acc.add_from_solver(s))
        >>> divergence_per_gaussian = acc.means()
    """

    def __init__(
        self,
        lists: GaussianLists,
        domain_min,
        domain_max,
        *,
        track_distinct: bool = False,
        max_fluid: int = 0,
        distinct_budget_bytes: int = DEFAULT_DISTINCT_BUDGET,
        batch_steps: int = BATCH_STEPS,
    ):
        dmin, dmax = _as_box("domain_min/domain_max", domain_min, domain_max)
        if int(max_fluid) < 0:
            raise ValueError(f"max_fluid must be >= 0, got {max_fluid}")
        if int(batch_steps) < 1:
            raise ValueError(f"batch_steps must be >= 1 (1: accumulate every step at once), got {batch_steps}")
        bmin, bmax = lists.bounds
        if not ((dmin >= bmin).all() and (dmax <= bmax).all()):
            raise ValueError(
                f"domain_min/domain_max {dmin.tolist()} - {dmax.tolist()} reach beyond the bounds the "
                f"lists were built for, {bmin.tolist()} - {bmax.tolist()}; build the lists over the union "
                "of the probes' domains"
            )
        self.lists = lists
        self.domain_min, self.domain_max = dmin, dmax
        self.batch_steps = int(batch_steps)
        self.serial_below = SERIAL_BELOW
        kept = lists.num_kept
        self._table = ti.ndarray(ti.f64, shape=(lists.levels.num_levels + 1, TABLE_WIDTH))
        self._table.from_numpy(lists.table(dmin, dmax))
        self.rows, self._private = accumulation_rows(kept)
        self._pool_threads = max(int(ti.lang.impl.current_cfg().cpu_max_num_threads or 0), 1)
        # per row: fixed-point sum and count of each Gaussian, and in slot K the count of saturated values; and of each
        # cell that Gaussians cover (spread onto them on read)
        self._acc = ti.ndarray(ti.i64, shape=(self.rows, kept + 1, 2))
        self._acc.fill(0)
        cell_rows = (self.rows, lists.levels.num_cells, 2) if lists.covered_cells else (1, 1, 2)
        self._cell_sums = ti.ndarray(ti.i64, shape=cell_rows)
        self._cell_sums.fill(0)
        self._saturation_logged = False
        self._stage_x = self._stage_values = self._stage_ids = None
        self._stage_capacity = self._staged = self._staged_steps = 0
        self._offsets = [0]  # the staged steps' offsets in the staging arrays
        # what a step's particles read and write: Gaussian records, rows of sums, cell lists and starts
        footprint = kept * (32 + 16 * self.rows) + 4 * lists.list_entries + 8 * lists.levels.num_cells
        self._interleave = footprint > INTERLEAVE_ABOVE_BYTES
        self._steps_arrays: dict = {}
        self._no_prev = ti.Vector.ndarray(3, ti.f64, shape=1)
        self._emitted = ti.ndarray(ti.i64, shape=1)  # keys listed by the last launch
        self._stage_prev = self._no_prev
        self.distinct = DistinctParticles(kept, distinct_budget_bytes) if track_distinct else None
        if self.distinct is not None and max_fluid:
            self.distinct.ensure_ids(int(max_fluid))

    @classmethod
    def build(
        cls, centers: np.ndarray, reach: np.ndarray, domain_min, domain_max, *, grid_bounds=None, **kwargs
    ) -> GaussianAccumulator:
        """Lists and sums at once, for one probe: the lists over ``domain_min``/``domain_max`` and ``grid_bounds``
        ((min [3], max [3]) m, e.g. the union of all probes' domains; default the domain). ``centers`` [G, 3] and
        ``reach`` [G] as :class:`nbv.physics.aggregate_levels.GaussianLists`; ``kwargs`` as the constructor."""
        centers = _as_points("centers", centers)
        dmin, dmax = _as_box("domain_min/domain_max", domain_min, domain_max)
        bmin, bmax = dmin, dmax
        if grid_bounds is not None:
            gmin, gmax = _as_box("grid_bounds", *grid_bounds)
            bmin, bmax = np.minimum(gmin, dmin), np.maximum(gmax, dmax)
        return cls(GaussianLists(centers, reach, bmin, bmax), dmin, dmax, **kwargs)

    # what the lists hold
    @property
    def levels(self) -> GaussianLevels:
        return self.lists.levels

    @property
    def num_gaussians(self) -> int:
        return self.lists.num_gaussians

    @property
    def num_kept(self) -> int:
        return self.lists.num_kept

    @property
    def list_entries(self) -> int:
        return self.lists.list_entries

    @property
    def covered_entries(self) -> int:
        return self.lists.covered_entries

    @property
    def track_distinct(self) -> bool:
        return self.distinct is not None

    @property
    def distinct_storage(self) -> str:
        """How distinct particles are recorded: ``"none"``, ``"bits"`` (bit matrix) or ``"hash"`` (hash set)."""
        return "none" if self.distinct is None else self.distinct.kind

    # -- memory ---------------------------------------------------------------------------------
    @staticmethod
    def estimate_bytes(
        num_gaussians: int,
        max_fluid: int,
        track_distinct: bool = False,
        *,
        distinct_pairs: int | None = None,
        threads: int | None = None,
        batch_steps: int = BATCH_STEPS,
        distinct_budget_bytes: int = DEFAULT_DISTINCT_BUDGET,
        float_bytes: int = 4,
        num_levels: int | None = None,
    ) -> int:
        """An upper estimate of the bytes an accumulator takes at its peak, before anything is allocated.

        Args:
            num_gaussians: G.
            max_fluid: fluid particles of the largest probe (ids < max_fluid).
            track_distinct: with the distinct-particle records (|P_g|).
            distinct_pairs: expected distinct (Gaussian, particle) pairs of one probe, for the hash set (used when
                the bit matrix G x max_fluid exceeds ``distinct_budget_bytes``); default
                :func:`default_distinct_pairs`.
            threads: CPU threads (rows of sums); default the current Taichi runtime's (1 row on GPUs).
            batch_steps: staged steps. float_bytes: 4 (f32 solver) or 8.
            num_levels: an upper bound of the levels (e.g. :func:`reach_classes`); default ``MAX_LEVELS`` (at most
                one per Gaussian).
        Returns:
            bytes: the Gaussian records (32 B), the permutation (8 B), the cell lists (entries at most
            ``ENTRIES_PER_GAUSSIAN`` per Gaussian, cells at most ``CELLS_PER_GAUSSIAN`` per Gaussian or
            ``MIN_LEVEL_CELLS`` per level, 4 B per entry, 8 B per cell), the rows of sums (16 B per Gaussian and per
            cell, and row), the staging, and
            the largest of the temporaries (the plan's numpy arrays, the build's per-cell arrays, the read-back of
            the sums); with distinct tracking the per-id previous samples (24 B per particle id) and the bit matrix,
            or the hash set at up to 48 B per pair while it grows (a half-full set and its double) and the buffer of
            listed pairs (64 per staged particle).
        """
        g, f = int(num_gaussians), int(max_fluid)
        if threads is None:
            rows, _ = accumulation_rows(g)
        else:
            rows = max(int(threads), 1) if 16 * max(int(threads), 1) * (g + 1) <= _ROWS_BUDGET else 1
        levels = min(MAX_LEVELS if num_levels is None else max(int(num_levels), 1), max(g, 1))
        cells = CELLS_PER_GAUSSIAN * g + levels * MIN_LEVEL_CELLS
        entries = ENTRIES_PER_GAUSSIAN * g + _ENTRY_SLACK
        sums = 16 * rows * (g + 1 + cells)  # per Gaussian and per covered cell
        persistent = 40 * g + 4 * (2 * cells + 1 + entries) + sums
        temporaries = max(_PLAN_BYTES_PER_GAUSSIAN * g + 8 * cells, 8 * g + 40 * cells, 16 * rows * (g + 1) + 64 * g)
        per_staged = 4 * float_bytes + 4 + (24 if track_distinct else 0)
        staged = min(f * batch_steps, max(f, _STAGE_BUDGET // per_staged)) * per_staged
        distinct = 0
        if track_distinct:
            bits = g * ((f + 31) // 32) * 4
            if bits <= distinct_budget_bytes:
                distinct = bits
            else:
                pairs = default_distinct_pairs(g, f) if distinct_pairs is None else int(distinct_pairs)
                slots = 1 << max(int(math.ceil(math.log2(max(pairs / _HASH_LOAD, _HASH_MIN_SLOTS)))), 0)
                distinct = 12 * slots  # the last doubling holds the old set and the new one
            # previous samples, the distinct counts read back, the largest buffer of listed pairs of a batch
            distinct += 24 * f + 16 * g + 8 * max(_KEY_BUFFER, 64 * min(f * batch_steps, _STAGE_BUDGET // per_staged))
        return int(persistent + temporaries + staged + distinct)

    # -- accumulation --------------------------------------------------------------------------
    def _step_array(self, offsets: list[int]):
        """The kernels' ``steps`` argument: the offsets of the staged steps (a Taichi array per batch size)."""
        arr = self._steps_arrays.get(len(offsets))
        if arr is None:
            arr = self._steps_arrays[len(offsets)] = ti.ndarray(ti.i32, shape=len(offsets))
        arr.from_numpy(np.asarray(offsets, np.int32))
        return arr

    def _run(self, n: int, xs, values, ids, prevs, offsets: list[int] | None = None) -> None:
        """Accumulate particles 0..n-1 of ``xs`` (``offsets``: the staged steps' B + 1 offsets, interleaved by the
        kernels; None: one step)."""
        offsets = [0, n] if offsets is None or not self._interleave else offsets
        longest = int(np.diff(offsets).max())
        # CPU: small batches on the launching thread; parallel rows need a row per pool thread (fewer rows, a
        # caller's choice, also run on the launching thread)
        serial = self._private and (n < self.serial_below or self.rows < self._pool_threads)
        geometry = (self._table, self.lists.lists, self.lists.gauss)
        steps = self._step_array(offsets)
        distinct = self.distinct
        if distinct is None:
            kernels.accumulate(longest, steps, xs, values, *geometry, self._private, serial, self._acc, self._cell_sums)
            return
        add_values = True
        while True:  # a full key buffer: grow it and list the batch's pairs again (without adding the values again)
            self._emitted.fill(0)
            kernels.accumulate_tracked(
                longest,
                steps,
                xs,
                values,
                ids,
                prevs,
                *geometry,
                add_values,
                True,
                self._private,
                serial,
                self._acc,
                distinct.keys,
                self._emitted,
            )
            add_values = False
            emitted = int(self._emitted.to_numpy()[0])
            if emitted <= distinct.keys.shape[0]:
                break
            distinct.grow_keys(emitted)
        if emitted:
            distinct.record(emitted)

    def add_from_solver(self, solver: DFSPHSolver) -> None:
        """Add this step's D_i of the solver's active fluid particles (device-side copies to the staging
        arrays, accumulated every ``batch_steps`` steps and before any read).

        Call it after ``solver.step()``: positions are the advected ones, D_i those of the step, as in
        ``solver.fluid_state()``.

        Args:
            solver: a ``fluidsim.DFSPHSolver``.
        """
        f = solver.fluid
        if f.active == 0:
            return
        small = self.batch_steps == 1 or f.active < self.serial_below
        if self.distinct is not None:
            self.distinct.ensure_ids(f.capacity)
        elif small:
            # Small probes: their steps leave the Gaussians in the caches, so staging buys nothing and its copy
            # launch costs more than the accumulation (quick preset: 0.55 -> 0.42 s for five probes).
            self.flush()
            self._run(f.active, f.x, f.divergence, f.ids, self._no_prev)
            return
        # with distinct tracking every step is staged: the copy also hands each particle its previous sample
        self._stage(f.active, f.capacity, f.x, f.divergence, f.ids, serial=False)
        if small:
            self.flush()

    def add_samples(self, positions: np.ndarray, values: np.ndarray, step_counts: np.ndarray) -> None:
        """Add recorded solver steps (e.g. the empty scene's, :mod:`nbv.physics.empty_cache`): the same sums and counts,
        bit for bit, as :meth:`add_from_solver` after each of those steps (integer sums do not depend on the order).

        Args:
            positions: [N, 3] float32 or float64 (the solver's type) positions of the steps' active particles, m.
            values: [N] the same float type, their D_i.
            step_counts: [S] particles per step (they sum to N); batches of ``batch_steps`` whole steps are visited
                as the staged steps are.
        Raises:
            ValueError: with distinct tracking (recorded steps carry no ids), or mismatched shapes or types.
        """
        if self.distinct is not None:
            raise ValueError("add_samples cannot track distinct particles; use add_from_solver or add with ids")
        pos, vals = np.asarray(positions), np.asarray(values)
        counts = np.asarray(step_counts, np.int64).reshape(-1)
        if pos.dtype not in (np.float32, np.float64) or pos.ndim != 2 or pos.shape[1] != 3:
            raise ValueError(f"positions must be [N, 3] float32 or float64, got {pos.shape} {pos.dtype}")
        if vals.shape != (len(pos),) or vals.dtype != pos.dtype:
            raise ValueError(f"values must be [{len(pos)}] {pos.dtype} like positions, got {vals.shape} {vals.dtype}")
        if (counts < 0).any() or int(counts.sum()) != len(pos):
            raise ValueError(f"step_counts must be >= 0 and sum to {len(pos)} positions, got {int(counts.sum())}")
        self.flush()
        counts = counts[counts > 0]  # a step without active fluid adds nothing (add_from_solver skips it)
        fp = ti.f64 if pos.dtype == np.float64 else ti.f32
        budget = max(int(counts.max(initial=1)), _STAGE_BUDGET // (4 * pos.itemsize))
        ends = np.cumsum(counts)
        s = start = 0
        while s < len(counts):
            e = s + 1  # whole steps, at most batch_steps of them within the staging budget
            while e < len(counts) and e - s < self.batch_steps and ends[e] - start <= budget:
                e += 1
            stop = int(ends[e - 1])
            if stop > start:
                xs = ti.Vector.ndarray(3, fp, shape=stop - start)
                xs.from_numpy(np.ascontiguousarray(pos[start:stop]))
                v = ti.ndarray(fp, shape=stop - start)
                v.from_numpy(np.ascontiguousarray(vals[start:stop]))
                offsets = [0, *(int(c) - start for c in ends[s:e])]
                self._run(stop - start, xs, v, v, self._no_prev, offsets)
            s, start = e, stop

    def _last_samples(self):
        """Each particle id's previous sample (the kernels' ``last``; a placeholder without distinct tracking)."""
        return self._no_prev if self.distinct is None else self.distinct.last

    def _stage(self, n: int, capacity: int, xs, values, ids, serial: bool) -> None:
        """Copy one step's n particles to the staging arrays; accumulate when ``batch_steps`` are staged."""
        same_type = self._stage_x is not None and self._stage_x.dtype == xs.dtype
        if not same_type or self._staged + n > self._stage_capacity:
            self.flush()
            if not same_type or n > self._stage_capacity:
                self._allocate_stage(n, capacity, xs.dtype, values.dtype)
        kernels.stage_particles(
            n,
            self._staged,
            xs,
            values,
            ids,
            self._stage_x,
            self._stage_values,
            self._stage_ids,
            self._last_samples(),
            self._stage_prev,
            self.track_distinct,
            serial,
        )
        self._staged += n
        self._staged_steps += 1
        self._offsets.append(self._staged)
        if self._staged_steps >= self.batch_steps:
            self.flush()

    def _allocate_stage(self, n: int, capacity: int, x_dtype, value_dtype) -> None:
        fp_bytes = 8 if x_dtype == ti.f64 else 4
        per_particle = 4 * fp_bytes + 4 + (24 if self.track_distinct else 0)
        cap = max(n, min(max(n, capacity) * self.batch_steps, _STAGE_BUDGET // per_particle))
        self._stage_x = ti.Vector.ndarray(3, x_dtype, shape=cap)
        self._stage_values = ti.ndarray(value_dtype, shape=cap)
        self._stage_ids = ti.ndarray(ti.i32, shape=cap)
        self._stage_prev = ti.Vector.ndarray(3, ti.f64, shape=cap) if self.track_distinct else self._no_prev
        self._stage_capacity = cap

    def flush(self) -> None:
        """Accumulate the staged steps now (every read does this first)."""
        if self._staged:
            n, offsets = self._staged, self._offsets
            self._staged, self._staged_steps, self._offsets = 0, 0, [0]
            self._run(n, self._stage_x, self._stage_values, self._stage_ids, self._stage_prev, offsets)

    def add(self, positions: np.ndarray, values: np.ndarray, ids: np.ndarray | None = None) -> None:
        """Numpy path: add ``values`` of particles at ``positions`` (one step; with distinct tracking, a particle
        whose id repeats within a call sees its earlier row as its previous sample).

        Args:
            positions: [P, 3] simulation metres.
            values: [P] per-particle values (e.g. D_i, 1/s).
            ids: [P] non-negative integer particle ids (< ``MAX_PARTICLE_IDS``), required with ``track_distinct``.
        """
        pos = _as_points("positions", positions)
        vals = np.asarray(values, dtype=np.float64)
        if vals.shape != (len(pos),):
            raise ValueError(f"values must have shape ({len(pos)},) like positions {pos.shape}, got {vals.shape}")
        if not np.isfinite(vals).all():
            raise ValueError("values holds NaN or Inf; check the simulation output")
        if self.track_distinct and ids is None:
            raise ValueError("ids are required when the accumulator tracks distinct particles (track_distinct=True)")
        pid = np.zeros(len(pos), np.int32)
        if ids is not None:
            raw = np.asarray(ids)
            if raw.shape != (len(pos),) or (len(raw) and (raw.min() < 0 or raw.max() >= 2**31)):
                raise ValueError(f"ids must be {len(pos)} integers in [0, 2^31), got shape {raw.shape}")
            pid = raw.astype(np.int32)
        if len(pos) == 0:
            return
        self.flush()  # keep the order of additions
        xs = ti.Vector.ndarray(3, ti.f64, shape=len(pos))
        xs.from_numpy(pos)
        v = ti.ndarray(ti.f64, shape=len(pos))
        v.from_numpy(vals)
        i = ti.ndarray(ti.i32, shape=len(pos))
        i.from_numpy(pid)
        if not self.track_distinct:
            self._run(len(pos), xs, v, i, self._no_prev)
            return
        self.distinct.ensure_ids(int(pid.max()) + 1)
        self._stage(len(pos), len(pos), xs, v, i, serial=True)
        self.flush()

    def reset(self) -> None:
        """Zero the sums and counts and drop staged steps (numpy path: a new series of steps on the same probe; a new
        probe gets a new accumulator). The distinct-particle records start afresh too."""
        self._staged = self._staged_steps = 0
        self._offsets = [0]
        self._acc.fill(0)
        self._cell_sums.fill(0)
        if self.distinct is not None:
            capacity = self.distinct.id_capacity
            self.distinct = DistinctParticles(self.num_kept, self.distinct.budget_bytes)
            self.distinct.ensure_ids(capacity)

    # -- results ---------------------------------------------------------------------------------
    def _caller_order(self, internal: np.ndarray) -> np.ndarray:
        out = np.zeros(self.num_gaussians, internal.dtype)
        out[self.lists.order] = internal
        return out

    def _totals(self) -> np.ndarray:
        """[K + 1, 2] int64: the rows summed (exact integers); warns once about saturated values."""
        self.flush()
        total = self._acc.to_numpy().sum(axis=0)
        if self.lists.covered_cells:
            spread = ti.ndarray(ti.i64, shape=(self.num_kept + 1, 2))
            spread.fill(0)
            kernels.spread_cells(self._table, self.lists.lists, self._cell_sums, spread)
            total += spread.to_numpy()
        if total[-1, 0] and not self._saturation_logged:
            self._saturation_logged = True
            log.warning(
                "%d accumulated values were NaN or beyond +-%g and were clamped (NaN: 0)",
                total[-1, 0],
                kernels.VALUE_LIMIT / kernels.VALUE_SCALE,
            )
        return total

    @property
    def sums(self) -> np.ndarray:
        """[G] float64 sum of the values added near each Gaussian: each value rounded to a multiple of
        1 / ``aggregate_kernels.VALUE_SCALE`` (6e-8) and the sums exact, so they are the same bits on any
        thread count."""
        return self._caller_order(self._totals()[:-1, 0].astype(np.float64) / kernels.VALUE_SCALE)

    @property
    def counts(self) -> np.ndarray:
        """[G] int64 number of (particle, step) samples near each Gaussian (the per-thread rows summed)."""
        return self._caller_order(self._totals()[:-1, 1].astype(np.int64))

    @property
    def distinct_counts(self) -> np.ndarray:
        """[G] int64 |P_g|: distinct particle ids that came within reach of each Gaussian."""
        if not self.track_distinct:
            raise ValueError("distinct_counts needs GaussianAccumulator(..., track_distinct=True)")
        self.flush()
        return self._caller_order(self.distinct.counts())

    def means(self) -> np.ndarray:
        """[G] sum / count (D_g of paper Eq. 3), 0 where the count is 0."""
        counts = self.counts
        return np.where(counts > 0, self.sums / np.maximum(counts, 1), 0.0)
