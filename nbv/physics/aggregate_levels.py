"""The levels and cell lists of the per-Gaussian accumulation (paper Eq. 2-3): built once per probe run.

The static Gaussians are sorted into levels by reach (:func:`plan_levels`), each level a uniform grid whose cells
list the Gaussians that reach them (:class:`GaussianLists`); every probe of a run reuses them, and only its sums
(:class:`nbv.physics.aggregate.GaussianAccumulator`) are fresh. The cost model and the budgets are described in
:mod:`nbv.physics.aggregate`. No numpy twin here: the lists are checked through the accumulator against
:func:`nbv.physics.aggregate_reference.accumulate_reference`.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace

import numpy as np
import taichi as ti

from nbv.physics import aggregate_level_kernels as kernels

log = logging.getLogger(__name__)

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
        return _Group(
            self.members + other.members,
            self.count + other.count,
            max(self.reach, other.reach),
            np.minimum(self.lo, other.lo),
            np.maximum(self.hi, other.hi),
            self.moments + other.moments,
        )

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
        groups.append(
            _Group([idx], len(idx), float(r.max()), box_lo, box_hi, np.array([r.sum(), (r * r).sum(), (r**3).sum()]))
        )
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
    touched = (
        len(reach) * cell**3
        + 6 * cell * cell * reach.sum()
        + 3 * math.pi * cell * (reach * reach).sum()
        + 4.0 / 3.0 * math.pi * (reach**3).sum()
    )
    return float(touched - 4.0 / 3.0 * math.pi * (np.maximum(reach - 0.5 * math.sqrt(3.0) * cell, 0.0) ** 3).sum())


def _cell_boxes(
    centers: np.ndarray, reach: np.ndarray, origin: np.ndarray, cell: float, dims: np.ndarray
) -> np.ndarray:
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


def _fit_cells(
    groups: list[_Group], centers: list[np.ndarray], reach: list[np.ndarray], budget: int
) -> tuple[list[tuple[float, np.ndarray]], list[int]]:
    """The (cell, dims) of every level and its list-entry bound (:func:`_cell_boxes`), within ``budget`` entries.

    Every level starts at ``CELL_FRACTION`` of its largest reach; while the bounds exceed the budget, the level with
    the most entries coarsens (x 1.25). Then, while the budget allows, the level whose finer cell (/ 1.25, down to
    ``MIN_CELL_FRACTION``) saves the most tested volume (:func:`_tested`) per added entry refines: levels of few large
    Gaussians (which many particles test) get fine cells for little memory.
    """
    grids = [_level_grid(g, CELL_FRACTION * g.reach) for g in groups]
    boxes = [
        int(_cell_boxes(c, r, g.lo, *grid).sum()) for g, c, r, grid in zip(groups, centers, reach, grids, strict=True)
    ]
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
        return GaussianLevels(
            np.zeros(0, np.int64),
            np.zeros((0, kernels.TABLE_WIDTH)),
            np.zeros(1, np.int64),
            np.zeros(1, np.int64),
            0,
            (lo, hi),
        )
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
    return GaussianLevels(
        np.concatenate(orders),
        np.asarray(rows, np.float64),
        np.asarray(first, np.int64),
        centre_starts,
        sum(boxes),
        (lo, hi),
    )


# ---- the lists, built once per run -----------------------------------------------------------------
class GaussianLists:
    """The Gaussians' records and their per-level cell lists over a box, built once (what every probe of a run
    shares; the sums are per probe).

    Args:
        centers: [G, 3] Gaussian means, simulation metres.
        reach: [G] n r_g, simulation metres (>= 0); particle i is near g when |x_i - mu_g| < reach[g].
        bounds_min, bounds_max: [3] m, the box the particles may come from (e.g. the union of the probes' domains):
            Gaussians that cannot reach it are dropped.

    Attributes:
        num_gaussians: G. num_kept: K, the Gaussians listed. order: [K] the caller's index of internal Gaussian k.
        levels: the :class:`GaussianLevels` (their ``centre_starts`` emptied once the lists are built).
        list_entries, covered_entries: entries in all lists, and those that cover their cell.
        gauss: Taichi [max(K, 1)] (mu_g, reach_g^2) records. lists: Taichi int32 starts, splits and items.
    """

    def __init__(self, centers: np.ndarray, reach: np.ndarray, bounds_min, bounds_max):
        centers = _as_points("centers", centers)
        reach = np.asarray(reach, dtype=np.float64)
        if reach.shape != (len(centers),):
            raise ValueError(f"reach must have shape ({len(centers)},) like centers {centers.shape}, got {reach.shape}")
        if len(centers) == 0:
            raise ValueError("centers is empty: there are no Gaussians to accumulate onto")
        if not (np.isfinite(reach).all() and (reach >= 0).all()):
            raise ValueError("reach must be finite and >= 0 m; check the Gaussians' scales")
        bmin, bmax = _as_box("grid bounds", bounds_min, bounds_max)
        self.num_gaussians = len(centers)
        # Internally the kept Gaussians are numbered by level and by the cell of their centre (the Gaussians listed in
        # one cell sit close together in memory); every result is returned in the caller's order.
        self.levels = plan_levels(centers, reach, bmin, bmax)
        self.order = self.levels.order
        kept = len(self.order)
        self.num_kept = kept
        self.gauss = ti.Vector.ndarray(4, ti.f64, shape=max(kept, 1))  # (mu_g, reach_g^2)
        if kept:
            c, r = centers[self.order], reach[self.order]
            self.gauss.from_numpy(np.concatenate([c, (r * r)[:, None]], axis=1))
        self.items_offset = 2 * self.levels.num_cells + 1
        self._build(reach[self.order])

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(min [3], max [3]) m: the box the lists were built for."""
        return self.levels.bounds

    @property
    def covered_cells(self) -> bool:
        """Whether some Gaussian covers a cell (the accumulator then keeps per-cell sums)."""
        return bool(self.covered_entries)

    def table(self, domain_min: np.ndarray, domain_max: np.ndarray) -> np.ndarray:
        """The kernels' ``table`` argument for a probe's domain (see ``aggregate_level_kernels.TABLE_WIDTH``)."""
        head = np.zeros((1, kernels.TABLE_WIDTH))
        # Particles outside the levels' grids reach no Gaussian: the kernels' domain test also skips them (most of a
        # probe's fluid is away from the object), with every level lookup.
        table = self.levels.table.reshape(-1, kernels.TABLE_WIDTH)
        lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
        if len(table):
            lo = np.maximum(table[:, 0:3].min(0), domain_min)
            hi = np.minimum((table[:, 0:3] + table[:, 4:5] * table[:, 5:8]).max(0), domain_max)
        head[0, :6] = np.concatenate([lo, hi])
        head[0, kernels.ITEMS_OFFSET] = self.items_offset
        head[0, kernels.SPLITS_OFFSET] = self.levels.num_cells + 1
        return np.concatenate([head, table])

    def _build(self, reach: np.ndarray) -> None:
        """The cell lists of every level (counting pass, prefix sum, fill pass, each cell gathering its own items)
        in one ``lists`` array (``aggregate_level_kernels.TABLE_WIDTH``): the start of every cell's items (all levels'
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
        table = ti.ndarray(ti.f64, shape=(lv.num_levels + 1, kernels.TABLE_WIDTH))
        table.from_numpy(self.table(*lv.bounds))

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
                    kernels.scatter_cells(
                        first, last, level + 1, slack, fill, self.gauss, ti_reach, table, counts, covering, lists
                    )
                else:
                    kernels.list_cells(
                        level + 1,
                        reach_cells,
                        slack,
                        fill,
                        self.gauss,
                        ti_reach,
                        table,
                        centres,
                        counts,
                        covering,
                        lists,
                    )

        passes(False, counts)
        total_counts = counts.to_numpy()[:cells].astype(np.int64)
        starts = np.concatenate([[0], np.cumsum(total_counts)])
        splits = starts[:-1] + covering.to_numpy()[:cells]
        total = int(starts[-1])
        if total > lv.entries_bound:  # the bound decided the memory: it must hold
            raise RuntimeError(f"cell lists hold {total} entries, above their bound {lv.entries_bound}")
        self.lists = ti.ndarray(ti.i32, shape=self.items_offset + max(total, 1))
        head = ti.ndarray(ti.i32, shape=2 * cells + 1)
        head.from_numpy(np.concatenate([starts, splits]).astype(np.int32))
        kernels.copy_into(head, self.lists)
        del head
        counts.fill(0)  # the scattering levels' cursors
        covering.fill(0)
        passes(True, self.lists)
        self.covered_entries = int((splits - starts[:-1]).sum())
        self.levels = replace(lv, centre_starts=np.zeros(0, np.int64))  # only the build needs them
        self.list_entries = total
        log.debug(
            "Gaussian levels: %d of %d Gaussians kept in %d levels (%s), cells %s m, %d cells, %d list entries "
            "(%.1f per Gaussian, %d covering their cell)",
            self.num_kept,
            self.num_gaussians,
            lv.num_levels,
            lv.counts.tolist(),
            [float(f"{c:.3g}") for c in lv.cell_sizes],
            cells,
            total,
            total / max(self.num_kept, 1),
            self.covered_entries,
        )


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
