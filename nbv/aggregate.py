"""Per-Gaussian accumulation of per-fluid-particle values through a grid (paper Eq. 2-3, Sec. 3.3).

Fluid particle i contributes its divergence D_i (paper Eq. 1) to Gaussian g when |x_i - mu_g| < n r_g
(n = 3, r_g the largest principal radius of g):

    D_g = sum_{steps} sum_{i near g} D_i / #(i, step) pairs    (0 when no particle came near g),

and |P_g| is the number of distinct fluid particles that ever came within n r_g of g (the
function-critical regions). Accumulation never loops over all particles x all Gaussians: the static
Gaussians are listed once per probe in the cells of a uniform grid (CSR: counting pass, prefix sum,
fill pass); at every step each active fluid particle walks the list of its own cell. On a CPU each thread
adds into its own row of sums and counts (no atomics; rows summed on read), on a GPU atomics do. The sums are
fixed-point integers (values rounded to 6e-8, exact sums), so they are the same bits whatever the thread
count or the order of the additions.

A solver's steps are staged (positions, values and ids copied, a sequential 20 bytes per particle) and
accumulated ``batch_steps`` at a time: after a solver step the Gaussians' records, lists and sums are out
of the caches, and a list entry then costs a memory round trip (about 100 ns, against a few ns warm),
so one pass over eight steps' particles pays that once instead of eight times. Probes under
``SERIAL_BELOW`` fluid particles are not staged: each step accumulates at once on the launching thread
(a small step leaves the Gaussians cached, and the staging copy would cost a launch per step). Every read (sums,
counts, means, distinct counts) accumulates what is staged first.

Distinct particles are tracked exactly, with one bit per (Gaussian, fluid particle id) (``atomic_or``)
while that matrix fits ``distinct_budget_bytes`` (512 MiB by default: 20k Gaussians x 60k particles
take 150 MB); beyond, (g, id) keys are collected per step, deduplicated and merged in chunks (exact,
memory proportional to the distinct pairs, slower).

:func:`accumulate_reference` (and :func:`within_reach_reference`) are the O(N G) numpy twins.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import numpy as np
import taichi as ti

from . import aggregate_kernels as kernels

if TYPE_CHECKING:
    from fluidsim import DFSPHSolver

log = logging.getLogger(__name__)

DEFAULT_DISTINCT_BUDGET = 512 * 2**20
# Grid limits: cells, and Gaussian entries in all cell lists.
_MAX_CELLS = 1 << 23
_MAX_ITEMS = 1 << 28
# Keys collected per step before a merge into the sorted unique set.
_KEY_CHUNK = 1 << 24
# Below this many fluid particles a step's accumulation runs on the launching thread (CPU): waking the thread
# pool costs more than a second thread saves on a small probe.
SERIAL_BELOW = 4096
# Largest size of the per-thread rows of sums and counts (16 bytes per Gaussian and row) on a CPU.
_ROWS_BUDGET = 256 * 2**20
# Solver steps staged per accumulation pass, and the most bytes the staged particles may take.
BATCH_STEPS = 8
_STAGE_BUDGET = 64 * 2**20


def accumulation_rows(num_gaussians: int) -> tuple[int, bool]:
    """(rows, private) of the sums and counts for the current Taichi runtime.

    On a CPU every thread of the pool gets its own row of sums and counts (plain, branch-free adds, summed on
    read; about 2x faster than atomic adds behind the unpredictable within-reach branch), while the rows fit
    ``_ROWS_BUDGET`` bytes. Otherwise (GPUs, or too many Gaussians) one row with atomic adds.
    """
    cfg = ti.lang.impl.current_cfg()
    threads = max(int(cfg.cpu_max_num_threads or 0), 1)
    if cfg.arch not in (ti.x64, ti.arm64) or threads * 16 * (max(num_gaussians, 1) + 1) > _ROWS_BUDGET:
        return 1, False
    return threads, True


def _as_points(name: str, arr, dtype=np.float64) -> np.ndarray:
    a = np.asarray(arr, dtype=dtype)
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3), got {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"{name} holds NaN or Inf values; remove or repair them")
    return a


class GaussianAccumulator:
    """Sums, counts and distinct particle counts of per-particle values near each Gaussian.

    Args:
        centers: [G, 3] Gaussian means, simulation metres.
        reach: [G] n r_g, simulation metres (>= 0); particle i is near g when |x_i - mu_g| < reach[g].
        domain_min, domain_max: [3] simulation domain, m; particles outside it (retired fluid) are ignored,
            and Gaussians reaching out of it are clipped to it.
        track_distinct: also count the distinct particle ids near each Gaussian (|P_g|).
        max_fluid: number of fluid particle ids expected (ids < max_fluid), to size the distinct-id
            bit matrix up front; 0 = size it on first use (it grows when needed).
        distinct_budget_bytes: largest bit matrix; beyond it the exact key-set fallback is used.
        grid_bounds: (min [3], max [3]) m that the cell lists cover (with the domain), e.g. the union of all
            probes' domains so that :meth:`retarget` can reuse the lists for each of them; default the domain.
        batch_steps: solver steps staged per accumulation pass (:meth:`add_from_solver`); 1 = accumulate each
            step at once. Results are the same up to the order of float additions.

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
        dmin = np.asarray(domain_min, dtype=np.float64).reshape(3)
        dmax = np.asarray(domain_max, dtype=np.float64).reshape(3)
        if not (np.isfinite(dmin).all() and np.isfinite(dmax).all() and (dmin < dmax).all()):
            raise ValueError(f"domain_min {dmin.tolist()} must be finite and below domain_max {dmax.tolist()}")
        if int(max_fluid) < 0:
            raise ValueError(f"max_fluid must be >= 0, got {max_fluid}")
        if int(batch_steps) < 1:
            raise ValueError(f"batch_steps must be >= 1 (1: accumulate every step at once), got {batch_steps}")
        self.batch_steps = int(batch_steps)
        self._stage_x = self._stage_values = self._stage_ids = None
        self._stage_capacity = 0
        self._staged = 0
        self._staged_steps = 0
        self.num_gaussians = len(centers)
        self.domain_min, self.domain_max = dmin, dmax
        self.track_distinct = bool(track_distinct)
        self.distinct_budget_bytes = int(distinct_budget_bytes)
        # Internally the Gaussians are numbered along a Morton curve, so that the Gaussians listed in one cell sit
        # close together in memory (fewer cache misses when the lists are cold after a solver step); every result
        # is returned in the caller's order.
        self._order = morton_order(centers)
        centers, reach = centers[self._order], reach[self._order]
        self._centers_np, self._reach_np = centers, reach
        self._grid_bounds = (dmin, dmax)
        if grid_bounds is not None:
            gmin, gmax = (np.asarray(b, dtype=np.float64).reshape(3) for b in grid_bounds)
            if not (np.isfinite(gmin).all() and np.isfinite(gmax).all() and (gmin < gmax).all()):
                raise ValueError(f"grid_bounds {gmin.tolist()}, {gmax.tolist()} must be finite with min < max")
            self._grid_bounds = (np.minimum(gmin, dmin), np.maximum(gmax, dmax))
        self._gauss = ti.Vector.ndarray(4, ti.f64, shape=self.num_gaussians)  # (mu_g, reach_g^2)
        self._gauss.from_numpy(np.concatenate([centers, (reach * reach)[:, None]], axis=1))
        self._build_lists(centers, reach)
        self.rows, self._private = accumulation_rows(self.num_gaussians)
        self._pool_threads = max(int(ti.lang.impl.current_cfg().cpu_max_num_threads or 0), 1)
        self.serial_below = SERIAL_BELOW
        # per row: fixed-point sum and count of each Gaussian, and in slot G the count of saturated values
        self._acc = ti.ndarray(ti.i64, shape=(self.rows, self.num_gaussians + 1, 2))
        self._saturation_logged = False
        self._no_bits = ti.ndarray(ti.u32, shape=(1, 1))
        self._no_keys = ti.ndarray(ti.i64, shape=1)
        self._key_count = ti.ndarray(ti.i64, shape=1)
        self._bits = None
        self._bit_width = 0
        self._keys = None
        self._unique_keys = np.zeros(0, np.int64)
        self._pending: list[np.ndarray] = []
        self._pending_size = 0
        self.reset()
        if self.track_distinct and max_fluid:
            self._ensure_ids(int(max_fluid))

    # -- the static lists --------------------------------------------------------------------
    def _geometry(self, dmin: np.ndarray, dmax: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
        """(origin, cell size, dims) of the list grid: the Gaussians' reach box clipped to the domain."""
        centers, reach = self._centers_np, self._reach_np
        lo = np.maximum((centers - reach[:, None]).min(0), dmin)
        hi = np.minimum((centers + reach[:, None]).max(0), dmax)
        extent = np.maximum(hi - lo, 0.0)
        positive = reach[reach > 0]
        cell = 0.5 * float(np.median(positive)) if len(positive) else 0.0
        cell = max(cell, float(extent.max()) / 1024.0, 1e-9)
        while np.prod(np.maximum(np.ceil(extent / cell), 1.0)) > _MAX_CELLS:
            cell *= 1.25
        dims = np.maximum(np.ceil(extent / cell), 1).astype(np.int64)
        return lo, cell, dims

    def retarget(self, domain_min, domain_max) -> bool:
        """Reuse this accumulator for another domain (e.g. the next probe).

        When the list grid covers the Gaussians' reach box clipped to the new domain, switch the domain (the
        kernel filters particles by it), zero the sums, counts and distinct records and return True: nothing is
        rebuilt. Otherwise change nothing and return False (build a new accumulator).
        """
        dmin = np.asarray(domain_min, dtype=np.float64).reshape(3)
        dmax = np.asarray(domain_max, dtype=np.float64).reshape(3)
        if not (np.isfinite(dmin).all() and np.isfinite(dmax).all() and (dmin < dmax).all()):
            raise ValueError(f"domain_min {dmin.tolist()} must be finite and below domain_max {dmax.tolist()}")
        centers, reach = self._centers_np, self._reach_np
        need_lo = np.maximum((centers - reach[:, None]).min(0), dmin)
        need_hi = np.minimum((centers + reach[:, None]).max(0), dmax)
        grid_hi = self.origin + self.cell_size * np.asarray(self.dims, np.float64)
        if not ((need_lo >= self.origin).all() and (need_hi <= grid_hi).all()):
            return False
        self.domain_min, self.domain_max = dmin, dmax
        self._grid.from_numpy(self._grid_array())
        self.reset()
        return True

    def _build_lists(self, centers: np.ndarray, reach: np.ndarray) -> None:
        lo, cell, dims = self._geometry(*self._grid_bounds)
        self.origin = lo
        self.cell_size = cell
        self.dims = tuple(int(d) for d in dims)
        # Upper bound of the list entries (whole clipped boxes), checked before anything is allocated.
        first = np.clip(np.floor((centers - reach[:, None] - lo) / cell), 0, dims - 1)
        last = np.clip(np.floor((centers + reach[:, None] - lo) / cell), -1, dims - 1)
        bound = float(np.prod(np.maximum(last - first + 1, 0), axis=1).sum())
        if bound > _MAX_ITEMS:
            raise ValueError(f"the Gaussians' reach spheres would fill {bound:.3g} cell-list entries (> {_MAX_ITEMS}); "
                             f"the set holds many huge Gaussians: prune floaters or lower the reach factor n")
        num_cells = int(np.prod(dims))
        counts = ti.ndarray(ti.i32, shape=num_cells)
        counts.fill(0)
        starts = ti.ndarray(ti.i32, shape=num_cells + 1)
        ti_centers = ti.Vector.ndarray(3, ti.f64, shape=self.num_gaussians)
        ti_centers.from_numpy(centers)
        args = (ti_centers, self._ti_reach(reach), ti.Vector(lo.tolist(), ti.f64), cell,
                kernels.ivec3(*self.dims), 1e-6 * cell)
        dummy = ti.ndarray(ti.i32, shape=1)
        kernels.list_gaussians(*args, 0, counts, starts, dummy)
        c = counts.to_numpy()
        s = np.concatenate([[0], np.cumsum(c, dtype=np.int64)])
        total = int(s[-1])
        starts.from_numpy(s.astype(np.int32))
        items = ti.ndarray(ti.i32, shape=max(total, 1))
        counts.fill(0)
        kernels.list_gaussians(*args, 1, counts, starts, items)
        # one array: the cell starts, then the items (the kernel finds them at grid[13])
        self._lists = ti.ndarray(ti.i32, shape=num_cells + 1 + max(total, 1))
        self._lists.from_numpy(np.concatenate([s.astype(np.int32), items.to_numpy()]))
        self._grid = ti.ndarray(ti.f64, shape=kernels.GRID_SIZE)
        self._grid.from_numpy(self._grid_array())
        self.list_entries = total
        log.debug("Gaussian cell lists: %s cells of %.4g m, %d entries (%.1f per Gaussian)", self.dims, cell,
                  total, total / self.num_gaussians)

    def _grid_array(self) -> np.ndarray:
        """The ``grid`` argument of the kernels (see ``aggregate_kernels.GRID_SIZE``)."""
        num_cells = int(np.prod(self.dims))
        return np.concatenate([self.origin, [1.0 / self.cell_size], self.domain_min, self.domain_max,
                               np.asarray(self.dims, np.float64), [num_cells + 1]])

    def _ti_reach(self, reach: np.ndarray):
        arr = ti.ndarray(ti.f64, shape=len(reach))
        arr.from_numpy(reach)
        return arr

    # -- distinct-id storage -----------------------------------------------------------------
    def _ensure_ids(self, needed: int) -> None:
        """Make room for particle ids < ``needed`` (bit matrix while it fits the budget, else keys)."""
        if self._keys is not None:
            return
        width = (needed + 31) // 32
        if width <= self._bit_width:
            return
        width = max(width, (self._bit_width * 5) // 4)
        if self.num_gaussians * width * 4 > self.distinct_budget_bytes:
            log.info("distinct-particle bit matrix of %d x %d words exceeds %.0f MiB: using exact key sets",
                     self.num_gaussians, width, self.distinct_budget_bytes / 2**20)
            old = self._bit_rows()
            self._bits, self._bit_width = None, 0
            self._keys = ti.ndarray(ti.i64, shape=1 << 20)
            if old is not None:
                g, pid = np.nonzero(old)
                self._unique_keys = (g.astype(np.int64) << 32) + pid
            return
        old = None if self._bits is None else self._bits.to_numpy()
        self._bits = ti.ndarray(ti.u32, shape=(self.num_gaussians, width))
        self._bits.fill(0)
        if old is not None:
            grown = np.zeros((self.num_gaussians, width), np.uint32)
            grown[:, : old.shape[1]] = old
            self._bits.from_numpy(grown)
        self._bit_width = width

    @property
    def distinct_storage(self) -> str:
        """How distinct particles are recorded: ``"none"``, ``"bits"`` (bit matrix) or ``"keys"`` (key sets)."""
        if not self.track_distinct:
            return "none"
        return "keys" if self._keys is not None else "bits"

    def _bit_rows(self) -> np.ndarray | None:
        """[G, 32 * words] bool, bit ``id`` of row g set when particle ``id`` came near g."""
        if self._bits is None:
            return None
        words = np.ascontiguousarray(self._bits.to_numpy(), dtype=np.uint32)
        return np.unpackbits(words.view(np.uint8), axis=1, bitorder="little").astype(bool)

    # -- accumulation --------------------------------------------------------------------------
    def _run(self, n: int, xs, values, ids) -> None:
        track = kernels.TRACK_NONE
        bits = self._no_bits
        if self.track_distinct:
            track = kernels.TRACK_BITS if self._keys is None else kernels.TRACK_KEYS
            bits = self._bits if self._keys is None else self._no_bits
        # CPU: small batches on the launching thread; parallel rows need a row per pool thread (fewer rows, a
        # caller's choice, also run on the launching thread)
        serial = self._private and (n < self.serial_below or self.rows < self._pool_threads)
        if track == kernels.TRACK_NONE:
            kernels.accumulate(n, xs, values, self._grid, self._lists, self._gauss, self._private, serial, self._acc)
            return
        common = (n, xs, values, ids, self._grid, self._lists, self._gauss)
        if track != kernels.TRACK_KEYS:
            kernels.accumulate_tracked(*common, True, track, self._private, serial, self._acc, bits, self._no_keys,
                                       self._key_count)
            return
        kernels.accumulate(n, xs, values, self._grid, self._lists, self._gauss, self._private, serial, self._acc)
        while True:
            self._key_count.fill(0)
            kernels.accumulate_tracked(*common, False, track, self._private, serial, self._acc, bits, self._keys,
                                       self._key_count)
            emitted = int(self._key_count.to_numpy()[0])
            if emitted <= self._keys.shape[0]:
                break
            self._keys = ti.ndarray(ti.i64, shape=int(emitted * 1.25) + 1)
        if emitted:
            self._add_keys(np.unique(self._keys.to_numpy()[:emitted]))

    def _add_keys(self, keys: np.ndarray) -> None:
        self._pending.append(keys)
        self._pending_size += len(keys)
        if self._pending_size > max(_KEY_CHUNK, len(self._unique_keys)):
            self._merge_keys()

    def _merge_keys(self) -> None:
        if self._pending:
            self._unique_keys = np.unique(np.concatenate([self._unique_keys, *self._pending]))
            self._pending, self._pending_size = [], 0

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
        if self.track_distinct:
            self._ensure_ids(f.capacity)
        if self.batch_steps == 1 or f.active < self.serial_below:
            # Small probes: their steps leave the Gaussians in the caches, so staging buys nothing and its copy
            # launch costs more than the accumulation (quick preset: 0.55 -> 0.42 s for five probes).
            self.flush()
            self._run(f.active, f.x, f.divergence, f.ids)
            return
        self._stage(f.active, f.capacity, f.x, f.divergence, f.ids)

    def _stage(self, n: int, capacity: int, xs, values, ids) -> None:
        """Copy one step's n particles to the staging arrays; accumulate when ``batch_steps`` are staged."""
        same_type = self._stage_x is not None and self._stage_x.dtype == xs.dtype
        if not same_type or self._staged + n > self._stage_capacity:
            self.flush()
            if not same_type or n > self._stage_capacity:
                fp_bytes = 8 if xs.dtype == ti.f64 else 4
                per_particle = 4 * fp_bytes + 4
                cap = max(n, min(max(n, capacity) * self.batch_steps, _STAGE_BUDGET // per_particle))
                self._stage_x = ti.Vector.ndarray(3, xs.dtype, shape=cap)
                self._stage_values = ti.ndarray(values.dtype, shape=cap)
                self._stage_ids = ti.ndarray(ti.i32, shape=cap)
                self._stage_capacity = cap
        kernels.stage_particles(n, self._staged, xs, values, ids, self._stage_x, self._stage_values, self._stage_ids)
        self._staged += n
        self._staged_steps += 1
        if self._staged_steps >= self.batch_steps:
            self.flush()

    def flush(self) -> None:
        """Accumulate the staged steps now (every read does this first)."""
        if self._staged:
            n, self._staged, self._staged_steps = self._staged, 0, 0
            self._run(n, self._stage_x, self._stage_values, self._stage_ids)

    def add(self, positions: np.ndarray, values: np.ndarray, ids: np.ndarray | None = None) -> None:
        """Numpy path: add ``values`` of particles at ``positions``.

        Args:
            positions: [P, 3] simulation metres.
            values: [P] per-particle values (e.g. D_i, 1/s).
            ids: [P] non-negative integer particle ids (< 2^31), required with ``track_distinct``.
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
        if self.track_distinct:
            self._ensure_ids(int(pid.max()) + 1)
        xs = ti.Vector.ndarray(3, ti.f64, shape=len(pos))
        xs.from_numpy(pos)
        v = ti.ndarray(ti.f64, shape=len(pos))
        v.from_numpy(vals)
        i = ti.ndarray(ti.i32, shape=len(pos))
        i.from_numpy(pid)
        self._run(len(pos), xs, v, i)

    def reset(self) -> None:
        """Zero the sums, counts and distinct-particle records and drop staged steps (the cell lists stay)."""
        self._staged = self._staged_steps = 0
        self._acc.fill(0)
        if self._bits is not None:
            self._bits.fill(0)
        self._unique_keys = np.zeros(0, np.int64)
        self._pending, self._pending_size = [], 0

    def _caller_order(self, internal: np.ndarray) -> np.ndarray:
        out = np.empty_like(internal)
        out[self._order] = internal
        return out

    def _totals(self) -> np.ndarray:
        """[G + 1, 2] int64: the rows summed (exact integers); warns once about saturated values."""
        self.flush()
        total = self._acc.to_numpy().sum(axis=0)
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
        if self._keys is None:
            if self._bits is None:
                return np.zeros(self.num_gaussians, np.int64)
            words = np.ascontiguousarray(self._bits.to_numpy(), dtype=np.uint32).view(np.uint8)
            return self._caller_order(np.unpackbits(words, axis=1).sum(axis=1, dtype=np.int64))
        self._merge_keys()
        return self._caller_order(np.bincount(self._unique_keys >> 32, minlength=self.num_gaussians).astype(np.int64))

    def means(self) -> np.ndarray:
        """[G] sum / count (D_g of paper Eq. 3), 0 where the count is 0."""
        counts = self.counts
        return np.where(counts > 0, self.sums / np.maximum(counts, 1), 0.0)


def morton_order(points: np.ndarray, bits: int = 10) -> np.ndarray:
    """[N] int64 permutation that sorts ``points`` [N, 3] along a Morton (Z-order) curve of their bounding box
    (``bits`` per axis)."""
    p = np.asarray(points, np.float64)
    extent = float(np.ptp(p, axis=0).max()) if len(p) else 0.0
    q = np.floor((p - p.min(axis=0)) / max(extent, 1e-300) * ((1 << bits) - 1)).astype(np.uint64)
    code = np.zeros(len(p), np.uint64)
    for b in range(bits):
        for a in range(3):
            code |= ((q[:, a] >> np.uint64(b)) & np.uint64(1)) << np.uint64(3 * b + a)
    return np.argsort(code, kind="stable")


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

