"""Per-Gaussian accumulation of per-fluid-particle values through cell lists (paper Eq. 2-3, Sec. 3.3).

Fluid particle i contributes its divergence D_i (paper Eq. 1) to Gaussian g when |x_i - mu_g| < n r_g
(n = 3, r_g the largest principal radius of g):

    D_g = sum_{steps} sum_{i near g} D_i / #(i, step) pairs    (0 when no particle came near g),

and |P_g| is the number of distinct fluid particles that ever came within n r_g of g (the
function-critical regions). Accumulation never loops over all particles x all Gaussians, and its memory is
O(G + particles) with a fixed bound per Gaussian (:meth:`GaussianAccumulator.estimate_bytes`):

- **Levels** (:func:`plan_levels`). The static Gaussians are sorted into classes by reach (a factor ``LEVEL_RATIO``
  = 2 each), and adjacent classes are merged where a cost model says one level is cheaper than two (a particle's
  cell lookup on a level costs ``LOOKUP_COST`` Gaussian tests). A level is a uniform grid whose cell starts at
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
- **Distinct particles** |P_g| are exact. A pair (g, id) is recorded only on the first step of each visit: the
  staging copy hands each particle its previous sample (kept per id, O(particles)), and a hit whose previous sample
  was within reach of g too is not recorded again (it was recorded then); in the paper setting 1.5 % of the hits
  start a visit. The accumulation lists those pairs in a buffer, and a second kernel records them: one bit per
  (Gaussian, fluid id) (``atomic_or``) while that matrix fits ``distinct_budget_bytes`` (512 MiB by default: 20k
  Gaussians x 60k particles take 150 MB), else a lock-free open-addressing hash set of g * 2^32 + id keys (ordered
  linear probing with ``atomic_max``), at most half full: 16-32 bytes per distinct pair (a 1.07M-Gaussian capture's
  -x probe has 5.0M pairs, 4.7 per Gaussian), doubled by rehashing before it would fill beyond half.

:func:`accumulate_reference` (and :func:`within_reach_reference`) are the O(N G) numpy twins.
"""

from __future__ import annotations

import logging
import math
import os
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
import taichi as ti

from nbv.physics import aggregate_kernels as kernels

if TYPE_CHECKING:
    from fluidsim import DFSPHSolver

log = logging.getLogger(__name__)

# Largest distinct-particle bit matrix; beyond it the hash set of pairs is used.
DEFAULT_DISTINCT_BUDGET = 512 * 2**20
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
# Levels: reach classes span a factor LEVEL_RATIO (at most MAX_LEVELS classes); a level's cell starts at CELL_FRACTION
# of its largest reach (refined down to MIN_CELL_FRACTION within the entry budget); the merge model weighs a
# particle's cell lookup on a level as LOOKUP_COST Gaussian tests (measured on recorded probes: 256 merges the bundled
# asset into 2 levels, 1.35 ms a step on one thread against 1.60 at 16 and 4 levels; the person capture and its 7 x
# copy keep 3 and 5 levels, within the noise of 16). The list entries are capped at ENTRIES_PER_GAUSSIAN per kept
# Gaussian on average plus _ENTRY_SLACK (16 MB for any set), the cells of a level at CELLS_PER_GAUSSIAN per
# Gaussian of the level (or MIN_LEVEL_CELLS).
LEVEL_RATIO = 2.0
MAX_LEVELS = 16
CELL_FRACTION = 0.5
MIN_CELL_FRACTION = 1.0 / 16
LOOKUP_COST = 256.0
ENTRIES_PER_GAUSSIAN = 128
CELLS_PER_GAUSSIAN = 8
MIN_LEVEL_CELLS = 1 << 16
_ENTRY_SLACK = 1 << 22
_MAX_LIST_ENTRIES = 1 << 30
# Cost of a scattered list entry (one thread, random writes) against a gathered row or test.
_SCATTER_COST = 8.0
# Hash set of distinct pairs: doubled before an insert would fill it beyond _HASH_LOAD; the listed first steps of
# visits (the keys to insert) start in a buffer of _KEY_BUFFER keys, grown when a batch lists more.
_HASH_LOAD = 0.5
_HASH_MIN_SLOTS = 1 << 16
_KEY_BUFFER = 1 << 16
# Per-id records of the previous sample (24 bytes each): ids must stay below this.
MAX_PARTICLE_IDS = 1 << 27
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


def _as_points(name: str, arr, dtype=np.float64) -> np.ndarray:
    a = np.asarray(arr, dtype=dtype)
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3), got {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"{name} holds NaN or Inf values; remove or repair them")
    return a


def _as_box(name: str, lo, hi) -> tuple[np.ndarray, np.ndarray]:
    lo = np.asarray(lo, dtype=np.float64).reshape(3)
    hi = np.asarray(hi, dtype=np.float64).reshape(3)
    if not (np.isfinite(lo).all() and np.isfinite(hi).all() and (lo < hi).all()):
        raise ValueError(f"{name}: {lo.tolist()} must be finite and below {hi.tolist()}")
    return lo, hi


# ---- the levels ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class GaussianLevels:
    """The plan of the per-level cell lists (see :func:`plan_levels`); the lists themselves are built by the
    accumulator.

    Attributes:
        order: [K] int64, the caller's index of internal Gaussian k (the kept Gaussians, sorted by level and by the
            cell of their centre).
        table: [L, kernels.TABLE_WIDTH] f64, one row per level: origin (3, m), 1 / cell, cell (m), dims (3), offset
            of its first cell in the cell starts.
        first: [L + 1] int64, level l holds the internal Gaussians first[l]..first[l + 1] - 1.
        centre_starts: [cells + 1] int64, the first internal Gaussian whose centre lies in each cell (all levels'
            cells in a row; centres outside a level's grid are clipped into it); emptied once the lists are built.
        entries_bound: an upper bound of the list entries (every Gaussian's clipped cell box).
        bounds: (min [3], max [3]) m, the box the particles may come from (Gaussians that cannot reach it are not
            kept).
    """

    order: np.ndarray
    table: np.ndarray
    first: np.ndarray
    centre_starts: np.ndarray
    entries_bound: int
    bounds: tuple[np.ndarray, np.ndarray]

    @property
    def num_levels(self) -> int:
        return int(self.table.shape[0])

    @property
    def counts(self) -> np.ndarray:
        """[L] Gaussians per level."""
        return np.diff(self.first)

    @property
    def cell_sizes(self) -> np.ndarray:
        """[L] cell edge of each level, m."""
        return self.table[:, 4].copy()

    @property
    def num_cells(self) -> int:
        return int(np.prod(self.table[:, 5:8], axis=1).sum())


@dataclass
class _Group:
    """A class of Gaussians by reach while the levels are merged: members, their largest reach, their reach box
    and the sums of r, r^2, r^3 (for the tested volume)."""

    members: list[np.ndarray]
    count: int
    reach: float
    lo: np.ndarray
    hi: np.ndarray
    moments: np.ndarray

    def merged(self, other: _Group) -> _Group:
        return _Group(self.members + other.members, self.count + other.count, max(self.reach, other.reach),
                      np.minimum(self.lo, other.lo), np.maximum(self.hi, other.hi), self.moments + other.moments)

    def tested(self, cell: float) -> float:
        """The volume (m^3) where particles test this group's Gaussians with cells of edge C: a Gaussian of reach r
        is tested in the cells its sphere touches, the sphere dilated by a cell, C^3 + 6 C^2 r + 3 pi C r^2 +
        4/3 pi r^3 (per unit particle density: the tests)."""
        s1, s2, s3 = self.moments
        return self.count * cell**3 + 6 * cell * cell * s1 + 3 * math.pi * cell * s2 + 4.0 / 3.0 * math.pi * s3

    def cost(self) -> float:
        """Cost of this group as one level per unit particle density, in units of one Gaussian test: a lookup
        (``LOOKUP_COST``) per particle in its box, plus the tests at ``CELL_FRACTION``."""
        return LOOKUP_COST * float(np.prod(self.hi - self.lo)) + self.tested(CELL_FRACTION * self.reach)


def _reach_groups(centers: np.ndarray, reach: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> list[_Group]:
    """The kept Gaussians in classes of reach (r_max / LEVEL_RATIO^(k+1), r_max / LEVEL_RATIO^k] (the last class
    holds all smaller ones), smallest first, adjacent classes merged while one level costs less than two."""
    top = float(reach.max())
    k = np.floor(np.log(top / reach) / math.log(LEVEL_RATIO)).astype(np.int64).clip(0, MAX_LEVELS - 1)
    groups = []
    for cls in np.unique(k)[::-1]:
        idx = np.nonzero(k == cls)[0]
        c, r = centers[idx], reach[idx]
        box_lo = np.maximum((c - r[:, None]).min(0), lo)
        box_hi = np.minimum((c + r[:, None]).max(0), hi)
        groups.append(_Group([idx], len(idx), float(r.max()), box_lo, box_hi,
                             np.array([r.sum(), (r * r).sum(), (r**3).sum()])))
    merged = [groups[0]]
    for g in groups[1:]:
        both = merged[-1].merged(g)
        if both.cost() < merged[-1].cost() + g.cost():
            merged[-1] = both
        else:
            merged.append(g)
    return merged[::-1]


def _tested(reach: np.ndarray, cell: float) -> float:
    """The volume (m^3) where particles test Gaussians of these reaches with cells of edge C (per unit particle
    density: the tests): the cells a sphere touches (the sphere dilated by a cell, C^3 + 6 C^2 r + 3 pi C r^2 +
    4/3 pi r^3) less the cells it covers, which take no test (about the sphere eroded by half a cell diagonal)."""
    touched = len(reach) * cell**3 + 6 * cell * cell * reach.sum() + 3 * math.pi * cell * (reach * reach).sum() \
        + 4.0 / 3.0 * math.pi * (reach**3).sum()
    return float(touched - 4.0 / 3.0 * math.pi * (np.maximum(reach - 0.5 * math.sqrt(3.0) * cell, 0.0) ** 3).sum())


def _cell_boxes(centers: np.ndarray, reach: np.ndarray, origin: np.ndarray, cell: float,
                dims: np.ndarray) -> np.ndarray:
    """[N] int64 cells in each Gaussian's clipped cell box (an upper bound of the cells it is listed in)."""
    first = np.clip(np.floor((centers - reach[:, None] - origin) / cell), 0, dims - 1)
    last = np.clip(np.floor((centers + reach[:, None] - origin) / cell), -1, dims - 1)
    return np.prod(np.maximum(last - first + 1, 0), axis=1).astype(np.int64)


def _level_grid(group: _Group, cell: float) -> tuple[float, np.ndarray]:
    """(cell, dims) of a level over its reach box: at least ``cell``, enlarged until the cells fit the cap (a larger
    cell is still exact, it only tests more Gaussians). dims = floor(extent / cell) + 1, so the box's far faces lie
    inside the grid."""
    extent = group.hi - group.lo
    scale = max(float(np.abs(np.concatenate([group.lo, group.hi])).max()), float(extent.max()), 1e-3)
    cell = max(cell, 1e-7 * scale)  # rounding stays far below the listing slack
    limit = max(CELLS_PER_GAUSSIAN * group.count, MIN_LEVEL_CELLS)
    while True:
        dims = np.floor(extent / cell).astype(np.int64) + 1
        if int(np.prod(dims)) <= limit:
            return cell, dims
        cell *= 1.25


def _fit_cells(groups: list[_Group], centers: list[np.ndarray], reach: list[np.ndarray],
               budget: int) -> tuple[list[tuple[float, np.ndarray]], list[int]]:
    """The (cell, dims) of every level and its list-entry bound (:func:`_cell_boxes`), within ``budget`` entries.

    Every level starts at ``CELL_FRACTION`` of its largest reach; while the bounds exceed the budget, the level with
    the most entries coarsens (x 1.25). Then, while the budget allows, the level whose finer cell (/ 1.25, down to
    ``MIN_CELL_FRACTION``) saves the most tested volume (:func:`_tested`) per added entry refines: levels of few large
    Gaussians (which many particles test) get fine cells for little memory.
    """
    grids = [_level_grid(g, CELL_FRACTION * g.reach) for g in groups]
    boxes = [int(_cell_boxes(c, r, g.lo, *grid).sum()) for g, c, r, grid in zip(groups, centers, reach, grids,
                                                                               strict=True)]
    while sum(boxes) > budget:
        w = int(np.argmax(boxes))
        grids[w] = _level_grid(groups[w], 1.25 * grids[w][0])
        boxes[w] = int(_cell_boxes(centers[w], reach[w], groups[w].lo, *grids[w]).sum())

    def finer(w: int):
        cell = grids[w][0] / 1.25
        if cell < MIN_CELL_FRACTION * groups[w].reach:
            return None
        grid = _level_grid(groups[w], cell)
        if grid[0] >= grids[w][0]:  # the cell cap holds it
            return None
        box = int(_cell_boxes(centers[w], reach[w], groups[w].lo, *grid).sum())
        saved = _tested(reach[w], grids[w][0]) - _tested(reach[w], grid[0])
        return saved / max(box - boxes[w], 1), grid, box

    options = [finer(w) for w in range(len(groups))]
    while True:
        fitting = [(o[0], w) for w, o in enumerate(options) if o is not None and sum(boxes) - boxes[w] + o[2] <= budget]
        if not fitting:
            return grids, boxes
        w = max(fitting)[1]
        _, grids[w], boxes[w] = options[w]
        options[w] = finer(w)


def plan_levels(centers: np.ndarray, reach: np.ndarray, bounds_min, bounds_max) -> GaussianLevels:
    """Sort the Gaussians into levels by reach and lay out each level's grid (numpy; nothing is listed yet).

    Args:
        centers: [G, 3] m. reach: [G] m (>= 0).
        bounds_min, bounds_max: [3] m, the box the particles come from; Gaussians whose reach sphere cannot touch
            it, and zero reaches, are dropped.
    Returns:
        GaussianLevels. The list entries stay below ``ENTRIES_PER_GAUSSIAN`` per kept Gaussian (plus a constant, and
        at most 2^30 in all), see :func:`_fit_cells`.
    """
    lo, hi = _as_box("plan_levels bounds", bounds_min, bounds_max)
    gap = np.maximum(np.maximum(lo - centers, centers - hi), 0.0)
    # generous by a rounding margin: a kept Gaussian that no particle reaches costs nothing but a slot
    keep = (reach > 0) & ((gap * gap).sum(1) < reach * reach * (1 + 1e-9) + 1e-300)
    kept = np.nonzero(keep)[0]
    if len(kept) == 0:
        return GaussianLevels(np.zeros(0, np.int64), np.zeros((0, kernels.TABLE_WIDTH)), np.zeros(1, np.int64),
                              np.zeros(1, np.int64), 0, (lo, hi))
    c_kept, r_kept = centers[kept], reach[kept]
    groups = _reach_groups(c_kept, r_kept, lo, hi)
    members = [np.sort(np.concatenate(g.members)) for g in groups]
    budget = min(ENTRIES_PER_GAUSSIAN * len(kept) + _ENTRY_SLACK, _MAX_LIST_ENTRIES)  # int32 list offsets
    grids, boxes = _fit_cells(groups, [c_kept[m] for m in members], [r_kept[m] for m in members], budget)
    orders, rows, first, centre_counts = [], [], [0], []
    offset = 0
    for g, m, (cell, dims) in zip(groups, members, grids, strict=True):
        ijk = np.clip(np.floor((c_kept[m] - g.lo) / cell).astype(np.int64), 0, dims - 1)
        lin = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
        orders.append(kept[m[np.argsort(lin, kind="stable")]])
        centre_counts.append(np.bincount(lin, minlength=int(np.prod(dims))))
        rows.append([*g.lo, 1.0 / cell, cell, *dims.astype(np.float64), offset])
        first.append(first[-1] + len(m))
        offset += int(np.prod(dims))
    centre_starts = np.concatenate([[0], np.cumsum(np.concatenate(centre_counts), dtype=np.int64)])
    return GaussianLevels(np.concatenate(orders), np.asarray(rows, np.float64), np.asarray(first, np.int64),
                          centre_starts, sum(boxes), (lo, hi))


# ---- the accumulator ----------------------------------------------------------------------------
class GaussianAccumulator:
    """Sums, counts and distinct particle counts of per-particle values near each Gaussian.

    Args:
        centers: [G, 3] Gaussian means, simulation metres.
        reach: [G] n r_g, simulation metres (>= 0); particle i is near g when |x_i - mu_g| < reach[g].
        domain_min, domain_max: [3] simulation domain, m; particles outside it (retired fluid) are ignored.
        track_distinct: also count the distinct particle ids near each Gaussian (|P_g|).
        max_fluid: number of fluid particle ids expected (ids < max_fluid), to size the per-id records (and the
            bit matrix) up front; 0 = size them on first use (they grow when needed).
        distinct_budget_bytes: largest bit matrix; beyond it the exact hash set of pairs is used.
        grid_bounds: (min [3], max [3]) m that the levels cover (with the domain), e.g. the union of all probes'
            domains so that :meth:`retarget` can reuse them for each of them; default the domain.
        batch_steps: solver steps staged per accumulation pass (:meth:`add_from_solver`); 1 = accumulate each
            step at once. The sums are the same bits either way.

    Example:
        >>> acc = GaussianAccumulator(means, 3.0 * radii, setup.domain_min, setup.domain_max)
        >>> run(solver, steps, on_step=lambda s, st: acc.add_from_solver(s))
        >>> divergence_per_gaussian = acc.means()
    """

    def __init__(self, centers: np.ndarray, reach: np.ndarray, domain_min, domain_max, *,
                 track_distinct: bool = False, max_fluid: int = 0,
                 distinct_budget_bytes: int = DEFAULT_DISTINCT_BUDGET, grid_bounds=None,
                 batch_steps: int = BATCH_STEPS):
        centers = _as_points("centers", centers)
        reach = np.asarray(reach, dtype=np.float64)
        if reach.shape != (len(centers),):
            raise ValueError(f"reach must have shape ({len(centers)},) like centers {centers.shape}, got {reach.shape}")
        if len(centers) == 0:
            raise ValueError("centers is empty: there are no Gaussians to accumulate onto")
        if not (np.isfinite(reach).all() and (reach >= 0).all()):
            raise ValueError("reach must be finite and >= 0 m; check the Gaussians' scales")
        dmin, dmax = _as_box("domain_min/domain_max", domain_min, domain_max)
        if int(max_fluid) < 0:
            raise ValueError(f"max_fluid must be >= 0, got {max_fluid}")
        if int(batch_steps) < 1:
            raise ValueError(f"batch_steps must be >= 1 (1: accumulate every step at once), got {batch_steps}")
        bmin, bmax = dmin, dmax
        if grid_bounds is not None:
            gmin, gmax = _as_box("grid_bounds", *grid_bounds)
            bmin, bmax = np.minimum(gmin, dmin), np.maximum(gmax, dmax)
        self.num_gaussians = len(centers)
        self.domain_min, self.domain_max = dmin, dmax
        self.track_distinct = bool(track_distinct)
        self.distinct_budget_bytes = int(distinct_budget_bytes)
        self.batch_steps = int(batch_steps)
        self.serial_below = SERIAL_BELOW
        # Internally the kept Gaussians are numbered by level and by the cell of their centre (the Gaussians listed in
        # one cell sit close together in memory); every result is returned in the caller's order.
        self.levels = plan_levels(centers, reach, bmin, bmax)
        self._order = self.levels.order
        kept = len(self._order)
        self.num_kept = kept
        self._gauss = ti.Vector.ndarray(4, ti.f64, shape=max(kept, 1))  # (mu_g, reach_g^2)
        if kept:
            c, r = centers[self._order], reach[self._order]
            self._gauss.from_numpy(np.concatenate([c, (r * r)[:, None]], axis=1))
        self._table = ti.ndarray(ti.f64, shape=(self.levels.num_levels + 1, kernels.TABLE_WIDTH))
        self._items_offset = 2 * self.levels.num_cells + 1
        self._table.from_numpy(self._table_array())
        self._build_lists(reach[self._order])
        self.rows, self._private = accumulation_rows(kept)
        self._pool_threads = max(int(ti.lang.impl.current_cfg().cpu_max_num_threads or 0), 1)
        # per row: fixed-point sum and count of each Gaussian, and in slot K the count of saturated values; and of each
        # cell that Gaussians cover (spread onto them on read)
        self._acc = ti.ndarray(ti.i64, shape=(self.rows, kept + 1, 2))
        cell_rows = (self.rows, self.levels.num_cells, 2) if self._covered_cells else (1, 1, 2)
        self._cell_sums = ti.ndarray(ti.i64, shape=cell_rows)
        self._saturation_logged = False
        self._stage_x = self._stage_values = self._stage_ids = None
        self._stage_capacity = self._staged = self._staged_steps = 0
        self._offsets = [0]  # the staged steps' offsets in the staging arrays
        # what a step's particles read and write: Gaussian records, rows of sums, cell lists and starts
        footprint = kept * (32 + 16 * self.rows) + 4 * self.list_entries + 8 * self.levels.num_cells
        self._interleave = footprint > INTERLEAVE_ABOVE_BYTES
        self._steps_arrays: dict = {}
        self._no_keys = ti.ndarray(ti.i64, shape=1)
        self._no_prev = ti.Vector.ndarray(3, ti.f64, shape=1)
        self._hash_fill = ti.ndarray(ti.i64, shape=1)  # filled slots of the hash set
        self._emitted = ti.ndarray(ti.i64, shape=1)    # keys listed by the last launch
        self._keys = self._no_keys
        self._storage = "bits" if self.track_distinct else "none"
        self._bits = None
        self._bit_width = 0
        self._hashes = None
        self._last = self._no_prev  # per particle id: the previous sample's position (NaN: none)
        self._stage_prev = self._no_prev
        self._id_capacity = 0
        self.reset()
        if self.track_distinct and max_fluid:
            self._ensure_ids(int(max_fluid))

    def _build_lists(self, reach: np.ndarray) -> None:
        """The cell lists of every level (counting pass, prefix sum, fill pass, each cell gathering its own items)
        in one ``lists`` array (``aggregate_kernels.TABLE_WIDTH``): the start of every cell's items (all levels'
        cells, then the end), every cell's split (the covering Gaussians before it), then the items."""
        lv = self.levels
        cells = lv.num_cells
        centres = ti.ndarray(ti.i32, shape=cells + 1)
        centres.from_numpy(lv.centre_starts.astype(np.int32))
        ti_reach = ti.ndarray(ti.f64, shape=max(len(reach), 1))
        if len(reach):
            ti_reach.from_numpy(reach)
        counts = ti.ndarray(ti.i32, shape=max(cells, 1))
        covering = ti.ndarray(ti.i32, shape=max(cells, 1))

        def passes(fill: bool, lists) -> None:
            for level in range(lv.num_levels):
                first, last = int(lv.first[level]), int(lv.first[level + 1])
                cell = float(lv.table[level, 4])
                slack = 1e-6 * cell
                reach_cells = int(math.floor((float(reach[first:last].max()) + slack) / cell)) + 1
                span = 2 * reach_cells + 1
                # every cell gathering from its neighbourhood (rows of centre cells, then Gaussians), or, for a few
                # Gaussians in fine cells, each Gaussian scattering itself on one thread (a random write costs more)
                gather = float(np.prod(lv.table[level, 5:8])) * span**2 + (last - first) * span**3
                if _SCATTER_COST * (last - first) * span**3 < gather:
                    kernels.scatter_cells(first, last, level + 1, slack, fill, self._gauss, ti_reach, self._table,
                                          counts, covering, lists)
                else:
                    kernels.list_cells(level + 1, reach_cells, slack, fill, self._gauss, ti_reach, self._table,
                                       centres, counts, covering, lists)

        passes(False, counts)
        total_counts = counts.to_numpy()[:cells].astype(np.int64)
        starts = np.concatenate([[0], np.cumsum(total_counts)])
        splits = starts[:-1] + covering.to_numpy()[:cells]
        total = int(starts[-1])
        if total > lv.entries_bound:  # the bound decided the memory: it must hold
            raise RuntimeError(f"cell lists hold {total} entries, above their bound {lv.entries_bound}")
        self._lists = ti.ndarray(ti.i32, shape=self._items_offset + max(total, 1))
        head = ti.ndarray(ti.i32, shape=2 * cells + 1)
        head.from_numpy(np.concatenate([starts, splits]).astype(np.int32))
        kernels.copy_into(head, self._lists)
        del head
        counts.fill(0)  # the scattering levels' cursors
        covering.fill(0)
        passes(True, self._lists)
        self.covered_entries = int((splits - starts[:-1]).sum())
        self._covered_cells = bool(self.covered_entries)
        self.levels = replace(lv, centre_starts=np.zeros(0, np.int64))  # only the build needs them
        self.list_entries = total
        log.debug("Gaussian levels: %d of %d Gaussians kept in %d levels (%s), cells %s m, %d cells, %d list entries "
                  "(%.1f per Gaussian, %d covering their cell)", self.num_kept, self.num_gaussians, lv.num_levels,
                  lv.counts.tolist(), [float(f"{c:.3g}") for c in lv.cell_sizes], cells, total,
                  total / max(self.num_kept, 1), self.covered_entries)

    def _table_array(self) -> np.ndarray:
        """The ``table`` argument of the kernels (see ``aggregate_kernels.TABLE_WIDTH``)."""
        head = np.zeros((1, kernels.TABLE_WIDTH))
        # Particles outside the levels' grids reach no Gaussian: the kernels' domain test also skips them (most of a
        # probe's fluid is away from the object), with every level lookup.
        table = self.levels.table.reshape(-1, kernels.TABLE_WIDTH)
        lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
        if len(table):
            lo = np.maximum(table[:, 0:3].min(0), self.domain_min)
            hi = np.minimum((table[:, 0:3] + table[:, 4:5] * table[:, 5:8]).max(0), self.domain_max)
        head[0, :6] = np.concatenate([lo, hi])
        head[0, kernels.ITEMS_OFFSET] = self._items_offset
        head[0, kernels.SPLITS_OFFSET] = self.levels.num_cells + 1
        return np.concatenate([head, table])

    def retarget(self, domain_min, domain_max) -> bool:
        """Reuse this accumulator for another domain (e.g. the next probe).

        When the new domain lies within the box the levels were built for (the grid bounds and the first domain),
        switch the domain (the kernel filters particles by it), zero the sums, counts and distinct records and
        return True: nothing is rebuilt. Otherwise change nothing and return False (build a new accumulator).
        """
        dmin, dmax = _as_box("domain_min/domain_max", domain_min, domain_max)
        bmin, bmax = self.levels.bounds
        if not ((dmin >= bmin).all() and (dmax <= bmax).all()):
            return False
        self.domain_min, self.domain_max = dmin, dmax
        self._table.from_numpy(self._table_array())
        self.reset()
        return True

    def drop_distinct(self) -> None:
        """Stop counting distinct particles (free their records) and zero the sums; the levels and lists stay, so a
        run that needs no |P_g| (the empty-scene reference) can reuse an accumulator built for one that does."""
        if not self.track_distinct:
            return
        self.flush()
        self.track_distinct = False
        self._storage = "none"
        self._bits = self._hashes = None
        self._bit_width = self._id_capacity = 0
        self._last = self._stage_prev = self._no_prev
        self._keys = self._no_keys
        self._stage_x = self._stage_values = self._stage_ids = None  # re-staged without the previous samples
        self._stage_capacity = 0
        self.reset()

    # -- memory ---------------------------------------------------------------------------------
    @staticmethod
    def estimate_bytes(num_gaussians: int, max_fluid: int, track_distinct: bool = False, *,
                       distinct_pairs: int | None = None, threads: int | None = None,
                       batch_steps: int = BATCH_STEPS, distinct_budget_bytes: int = DEFAULT_DISTINCT_BUDGET,
                       float_bytes: int = 4, num_levels: int | None = None) -> int:
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

    # -- distinct-id storage ----------------------------------------------------------------------
    def _ensure_ids(self, needed: int) -> None:
        """Make room for particle ids < ``needed``: the per-id previous samples, and the bit matrix while it fits the
        budget (else the hash set)."""
        if needed <= self._id_capacity:
            return
        cap = max(needed, (self._id_capacity * 5) // 4)
        if cap > MAX_PARTICLE_IDS:
            raise ValueError(f"particle ids up to {needed - 1} need {24 * cap / 2**30:.1f} GiB of per-id records "
                             f"(ids must stay below {MAX_PARTICLE_IDS}); number the particles densely from 0")
        old = None if self._id_capacity == 0 else self._last.to_numpy()
        self._last = ti.Vector.ndarray(3, ti.f64, shape=cap)
        self._last.fill(float("nan"))
        if old is not None:
            grown = np.full((cap, 3), np.nan)
            grown[: len(old)] = old
            self._last.from_numpy(grown)
        self._id_capacity = cap
        if self._storage == "bits":
            self._grow_bits((cap + 31) // 32)

    def _grow_bits(self, width: int) -> None:
        kept = max(self.num_kept, 1)
        if kept * width * 4 > self.distinct_budget_bytes:
            log.info("distinct-particle bit matrix of %d x %d words exceeds %.0f MiB: using an exact hash set of pairs",
                     kept, width, self.distinct_budget_bytes / 2**20)
            old = self._bits
            self._bits, self._bit_width, self._storage = None, 0, "hash"
            self._new_hash(_HASH_MIN_SLOTS)
            if old is not None:
                self._insert_bit_rows(old)
            return
        old = None if self._bits is None else self._bits.to_numpy()
        self._bits = ti.ndarray(ti.u32, shape=(kept, width))
        self._bits.fill(0)
        if old is not None:
            grown = np.zeros((kept, width), np.uint32)
            grown[:, : old.shape[1]] = old
            self._bits.from_numpy(grown)
        self._bit_width = width

    def _insert_bit_rows(self, bits) -> None:
        """Move the pairs of a bit matrix into the hash set (chunks of Gaussians, to bound the host memory)."""
        words = bits.to_numpy()
        chunk = max(1, (1 << 22) // max(words.shape[1], 1))
        for g0 in range(0, words.shape[0], chunk):
            block = np.unpackbits(np.ascontiguousarray(words[g0: g0 + chunk]).view(np.uint8), axis=1,
                                  bitorder="little")
            g, pid = np.nonzero(block)
            if len(g):
                self._insert_keys(((g + g0).astype(np.int64) << 32) + pid)

    def _new_hash(self, slots: int) -> None:
        self._hashes = ti.ndarray(ti.i64, shape=slots)
        self._hashes.fill(kernels.EMPTY_KEY)
        self._hash_fill.fill(0)

    def _insert_keys(self, keys: np.ndarray) -> None:
        arr = ti.ndarray(ti.i64, shape=len(keys))
        arr.from_numpy(keys)
        self._insert_listed(arr, len(keys))

    def _insert_listed(self, keys, n: int) -> None:
        """Insert ``keys[:n]`` (a Taichi array) into the hash set, doubled first while it would be over half full."""
        while int(self._hash_fill.to_numpy()[0]) + n > _HASH_LOAD * self._hashes.shape[0]:
            self._grow_hash()
        kernels.insert_keys(n, keys, self._hashes, self._hash_fill)

    def _grow_hash(self) -> None:
        """Double the hash set (rehash on the device)."""
        old = self._hashes
        self._new_hash(2 * old.shape[0])
        kernels.insert_keys(old.shape[0], old, self._hashes, self._hash_fill)
        log.debug("distinct pairs: hash set grown to %d slots (%.0f MiB)", self._hashes.shape[0],
                  8 * self._hashes.shape[0] / 2**20)

    @property
    def distinct_storage(self) -> str:
        """How distinct particles are recorded: ``"none"``, ``"bits"`` (bit matrix) or ``"hash"`` (hash set)."""
        return self._storage

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
        geometry = (self._table, self._lists, self._gauss)
        steps = self._step_array(offsets)
        if self._storage == "none":
            kernels.accumulate(longest, steps, xs, values, *geometry, self._private, serial, self._acc,
                               self._cell_sums)
            return
        if self._keys.shape[0] < _KEY_BUFFER:
            self._keys = ti.ndarray(ti.i64, shape=_KEY_BUFFER)
        add_values = True
        while True:  # a full key buffer: grow it and list the batch's pairs again (without adding the values again)
            self._emitted.fill(0)
            kernels.accumulate_tracked(longest, steps, xs, values, ids, prevs, *geometry, add_values, True,
                                       self._private, serial, self._acc, self._keys, self._emitted)
            add_values = False
            emitted = int(self._emitted.to_numpy()[0])
            if emitted <= self._keys.shape[0]:
                break
            self._keys = ti.ndarray(ti.i64, shape=int(1.25 * emitted) + 1)
        if not emitted:
            return
        if self._storage == "bits":
            kernels.set_bits(emitted, self._keys, self._bits)
        else:
            self._insert_listed(self._keys, emitted)

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
        if self.track_distinct:
            self._ensure_ids(f.capacity)
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

    def _stage(self, n: int, capacity: int, xs, values, ids, serial: bool) -> None:
        """Copy one step's n particles to the staging arrays; accumulate when ``batch_steps`` are staged."""
        same_type = self._stage_x is not None and self._stage_x.dtype == xs.dtype
        if not same_type or self._staged + n > self._stage_capacity:
            self.flush()
            if not same_type or n > self._stage_capacity:
                self._allocate_stage(n, capacity, xs.dtype, values.dtype)
        kernels.stage_particles(n, self._staged, xs, values, ids, self._stage_x, self._stage_values, self._stage_ids,
                                self._last, self._stage_prev, self.track_distinct, serial)
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
        self._ensure_ids(int(pid.max()) + 1)
        self._stage(len(pos), len(pos), xs, v, i, serial=True)
        self.flush()

    def reset(self) -> None:
        """Zero the sums, counts and distinct-particle records and drop staged steps (the levels stay)."""
        self._staged = self._staged_steps = 0
        self._offsets = [0]
        self._acc.fill(0)
        self._cell_sums.fill(0)
        if self._bits is not None:
            self._bits.fill(0)
        if self._hashes is not None:
            self._hashes.fill(kernels.EMPTY_KEY)
            self._hash_fill.fill(0)
        if self._id_capacity:
            self._last.fill(float("nan"))

    # -- results ---------------------------------------------------------------------------------
    def _caller_order(self, internal: np.ndarray) -> np.ndarray:
        out = np.zeros(self.num_gaussians, internal.dtype)
        out[self._order] = internal
        return out

    def _totals(self) -> np.ndarray:
        """[K + 1, 2] int64: the rows summed (exact integers); warns once about saturated values."""
        self.flush()
        total = self._acc.to_numpy().sum(axis=0)
        if self._covered_cells:
            spread = ti.ndarray(ti.i64, shape=(self.num_kept + 1, 2))
            spread.fill(0)
            kernels.spread_cells(self._table, self._lists, self._cell_sums, spread)
            total += spread.to_numpy()
        if total[-1, 0] and not self._saturation_logged:
            self._saturation_logged = True
            log.warning("%d accumulated values were NaN or beyond +-%g and were clamped (NaN: 0)", total[-1, 0],
                        kernels.VALUE_LIMIT / kernels.VALUE_SCALE)
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
        counts = ti.ndarray(ti.i64, shape=max(self.num_kept, 1))
        counts.fill(0)
        if self._storage == "hash":
            kernels.count_keys(self._hashes, counts)
        elif self._bits is not None:
            kernels.count_bits(self._bits, counts)
        return self._caller_order(counts.to_numpy()[: self.num_kept])

    def means(self) -> np.ndarray:
        """[G] sum / count (D_g of paper Eq. 3), 0 where the count is 0."""
        counts = self.counts
        return np.where(counts > 0, self.sums / np.maximum(counts, 1), 0.0)


def reach_classes(reach: np.ndarray) -> int:
    """An upper bound of the levels :func:`plan_levels` makes of these reaches [G] or of any subset of them (the
    kept Gaussians): classes span a factor ``LEVEL_RATIO`` from the largest kept reach down, so reaches spanning a
    factor F fill at most floor(log_ratio F) + 1 of them (at most ``MAX_LEVELS``; classes only merge). It depends on
    the reaches' ratios alone, so any common scale may be left out."""
    r = np.asarray(reach, np.float64).reshape(-1)
    r = r[r > 0]
    if len(r) == 0:
        return 1
    span = math.log(float(r.max()) / float(r.min())) / math.log(LEVEL_RATIO)
    return int(min(MAX_LEVELS, math.floor(span * (1 + 1e-12)) + 1))


def default_distinct_pairs(num_gaussians: int, max_fluid: int) -> int:
    """Distinct (Gaussian, particle) pairs of one probe assumed by :meth:`GaussianAccumulator.estimate_bytes` when
    none are given: ``PAIRS_PER_GAUSSIAN`` per Gaussian, at most G x max_fluid."""
    return int(min(PAIRS_PER_GAUSSIAN * num_gaussians, num_gaussians * max(max_fluid, 1)))


# Distinct pairs per Gaussian of one probe assumed by the estimate. Measured in the paper setting (r = 0.025 m,
# 750 steps, the -x probe of `critical`): 4.7 per Gaussian on the 152,746-Gaussian person capture and on its 7 x
# jittered copy (1.07M Gaussians, 5.0M pairs); the bundled Ahmed asset (larger Gaussians, 17,952 of them) has about
# 60 per Gaussian after 200 steps, but a set that small keeps the bit matrix.
PAIRS_PER_GAUSSIAN = 16


def within_reach_reference(centers: np.ndarray, reach: np.ndarray, positions: np.ndarray,
                           domain_min=None, domain_max=None) -> np.ndarray:
    """O(P G) twin of the grid test: [P, G] bool, |x_i - mu_g|^2 < reach_g^2 (and x_i inside the domain, if given)."""
    c = np.asarray(centers, np.float64).reshape(-1, 3)
    r = np.asarray(reach, np.float64).reshape(-1)
    p = np.asarray(positions, np.float64).reshape(-1, 3)
    d = p[:, None, :] - c[None, :, :]
    near = (d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1] + d[..., 2] * d[..., 2]) < (r * r)[None, :]
    if domain_min is not None and domain_max is not None:
        lo = np.asarray(domain_min, np.float64).reshape(3)
        hi = np.asarray(domain_max, np.float64).reshape(3)
        near &= np.all((p >= lo) & (p <= hi), axis=1)[:, None]
    return near


def accumulate_reference(centers: np.ndarray, reach: np.ndarray, positions: np.ndarray, values: np.ndarray,
                         domain_min=None, domain_max=None) -> tuple[np.ndarray, np.ndarray]:
    """O(P G) twin of :class:`GaussianAccumulator`: every particle against every Gaussian.

    Args:
        centers: [G, 3] m. reach: [G] m. positions: [P, 3] m. values: [P].
        domain_min, domain_max: optional [3] m; particles outside are ignored (as the accumulator does).
    Returns:
        (sums [G] float64, counts [G] int64).
    """
    near = within_reach_reference(centers, reach, positions, domain_min, domain_max)
    vals = np.asarray(values, np.float64).reshape(-1)
    return near.T.astype(np.float64) @ vals, near.sum(axis=0).astype(np.int64)
