"""The distinct fluid particles |P_g| near each Gaussian (the function-critical regions, paper Sec. 4): the store of
(Gaussian, particle id) pairs and each particle's previous sample, fresh per probe.

A pair is recorded only on the first step of each visit (:mod:`nbv.physics.aggregate`): the staging copy hands each
particle its previous sample (:class:`DistinctParticles.last`, per id), and the accumulation lists the pairs whose
previous sample was not within reach of g. The listed pairs go into one of two stores, a type each:

- :class:`BitPairs`: one bit per (Gaussian, fluid id) (``atomic_or``), while that matrix fits the budget
  (``DEFAULT_DISTINCT_BUDGET``, 512 MiB: 20k Gaussians x 60k particles take 150 MB);
- :class:`HashPairs`: a lock-free open-addressing hash set of g * 2^32 + id keys (ordered linear probing with
  ``atomic_max``), at most half full: 16-32 bytes per distinct pair, doubled by rehashing before it would fill beyond
  half (a 1.07M-Gaussian capture's -x probe has 5.0M pairs, 4.7 per Gaussian).

The counts are exact with either store; the numpy twin is the set of pairs in ``tests/nbv/physics/test_aggregate.py``.
"""

from __future__ import annotations

import logging

import numpy as np
import taichi as ti

from nbv.physics import aggregate_kernels as kernels

log = logging.getLogger(__name__)

# Largest distinct-particle bit matrix; beyond it the hash set of pairs is used.
DEFAULT_DISTINCT_BUDGET = 512 * 2**20
# Hash set of distinct pairs: doubled before an insert would fill it beyond _HASH_LOAD; the listed first steps of
# visits (the keys to insert) start in a buffer of _KEY_BUFFER keys, grown when a batch lists more.
_HASH_LOAD = 0.5
_HASH_MIN_SLOTS = 1 << 16
_KEY_BUFFER = 1 << 16
# Per-id records of the previous sample (24 bytes each): ids must stay below this.
MAX_PARTICLE_IDS = 1 << 27
# Distinct pairs per Gaussian of one probe assumed by the estimate. Measured in the paper setting (r = 0.025 m,
# 750 steps, the -x probe of `critical`): 4.7 per Gaussian on the 152,746-Gaussian person capture and on its 7 x
# jittered copy (1.07M Gaussians, 5.0M pairs); the bundled Ahmed asset (larger Gaussians, 17,952 of them) has about
# 60 per Gaussian after 200 steps, but a set that small keeps the bit matrix.
PAIRS_PER_GAUSSIAN = 16


def default_distinct_pairs(num_gaussians: int, max_fluid: int) -> int:
    """Distinct (Gaussian, particle) pairs of one probe assumed by
    :meth:`nbv.physics.aggregate.GaussianAccumulator.estimate_bytes` when none are given: ``PAIRS_PER_GAUSSIAN`` per
    Gaussian, at most G x max_fluid."""
    return int(min(PAIRS_PER_GAUSSIAN * num_gaussians, num_gaussians * max(max_fluid, 1)))


class BitPairs:
    """The pairs as a bit matrix [K, words] (bit id of row g: particle id came near Gaussian g)."""

    kind = "bits"

    def __init__(self, num_kept: int, width: int, old: BitPairs | None = None):
        rows = max(num_kept, 1)
        self.bits = ti.ndarray(ti.u32, shape=(rows, width))
        self.bits.fill(0)
        if old is not None:
            grown = np.zeros((rows, width), np.uint32)
            words = old.bits.to_numpy()
            grown[:, : words.shape[1]] = words
            self.bits.from_numpy(grown)

    @property
    def width(self) -> int:
        return int(self.bits.shape[1])

    def record(self, keys, n: int) -> None:
        """Record the pairs ``keys[:n]`` (a Taichi array of g * 2^32 + id)."""
        kernels.set_bits(n, keys, self.bits)

    def count(self, counts) -> None:
        """``counts[g]`` = the ids recorded for g."""
        kernels.count_bits(self.bits, counts)


class HashPairs:
    """The pairs as an exact hash set of g * 2^32 + id keys, at most ``_HASH_LOAD`` full."""

    kind = "hash"

    def __init__(self, slots: int | None = None):
        self.fill = ti.ndarray(ti.i64, shape=1)  # filled slots
        self._new(_HASH_MIN_SLOTS if slots is None else slots)

    def _new(self, slots: int) -> None:
        self.hashes = ti.ndarray(ti.i64, shape=slots)
        self.hashes.fill(kernels.EMPTY_KEY)
        self.fill.fill(0)

    @classmethod
    def from_bits(cls, bits: BitPairs) -> HashPairs:
        """A hash set of the pairs of a bit matrix (chunks of Gaussians, to bound the host memory)."""
        out = cls()
        words = bits.bits.to_numpy()
        chunk = max(1, (1 << 22) // max(words.shape[1], 1))
        for g0 in range(0, words.shape[0], chunk):
            block = np.unpackbits(
                np.ascontiguousarray(words[g0 : g0 + chunk]).view(np.uint8), axis=1, bitorder="little"
            )
            g, pid = np.nonzero(block)
            if len(g):
                keys = ((g + g0).astype(np.int64) << 32) + pid
                arr = ti.ndarray(ti.i64, shape=len(keys))
                arr.from_numpy(keys)
                out.record(arr, len(keys))
        return out

    def record(self, keys, n: int) -> None:
        """Insert ``keys[:n]`` (a Taichi array), the set doubled first while it would be over half full."""
        while int(self.fill.to_numpy()[0]) + n > _HASH_LOAD * self.hashes.shape[0]:
            self._grow()
        kernels.insert_keys(n, keys, self.hashes, self.fill)

    def _grow(self) -> None:
        """Double the set (rehash on the device)."""
        old = self.hashes
        self._new(2 * old.shape[0])
        kernels.insert_keys(old.shape[0], old, self.hashes, self.fill)
        log.debug(
            "distinct pairs: hash set grown to %d slots (%.0f MiB)",
            self.hashes.shape[0],
            8 * self.hashes.shape[0] / 2**20,
        )

    def count(self, counts) -> None:
        """``counts[g]`` += the keys of g in the set."""
        kernels.count_keys(self.hashes, counts)


class DistinctParticles:
    """One probe's distinct-particle records: the previous sample of each particle id and the store of pairs (a bit
    matrix while it fits ``budget_bytes``, else the hash set).

    Args:
        num_kept: K, the Gaussians listed (rows of the bit matrix).
        budget_bytes: largest bit matrix.

    Attributes:
        last: Taichi [ids] (3,) f64: each id's previous sample position (NaN: none yet; a placeholder before any id).
        pairs: :class:`BitPairs` or :class:`HashPairs` (None: no id seen yet).
        keys: the buffer of pairs listed by one accumulation pass.
    """

    def __init__(self, num_kept: int, budget_bytes: int):
        self.num_kept, self.budget_bytes = int(num_kept), int(budget_bytes)
        self.last = ti.Vector.ndarray(3, ti.f64, shape=1)
        self.id_capacity = 0
        self.pairs: BitPairs | HashPairs | None = None
        self.keys = ti.ndarray(ti.i64, shape=_KEY_BUFFER)

    @property
    def kind(self) -> str:
        """``"bits"`` or ``"hash"``: the store the pairs are in (bits until the matrix would exceed the budget)."""
        return "bits" if self.pairs is None else self.pairs.kind

    def ensure_ids(self, needed: int) -> None:
        """Make room for particle ids < ``needed``: the per-id previous samples, and the bit matrix while it fits the
        budget (else the hash set)."""
        if needed <= self.id_capacity:
            return
        cap = max(needed, (self.id_capacity * 5) // 4)
        if cap > MAX_PARTICLE_IDS:
            raise ValueError(
                f"particle ids up to {needed - 1} need {24 * cap / 2**30:.1f} GiB of per-id records "
                f"(ids must stay below {MAX_PARTICLE_IDS}); number the particles densely from 0"
            )
        old = None if self.id_capacity == 0 else self.last.to_numpy()
        self.last = ti.Vector.ndarray(3, ti.f64, shape=cap)
        self.last.fill(float("nan"))
        if old is not None:
            grown = np.full((cap, 3), np.nan)
            grown[: len(old)] = old
            self.last.from_numpy(grown)
        self.id_capacity = cap
        if not isinstance(self.pairs, HashPairs):
            self._widen((cap + 31) // 32)

    def _widen(self, width: int) -> None:
        kept = max(self.num_kept, 1)
        if kept * width * 4 > self.budget_bytes:
            log.info(
                "distinct-particle bit matrix of %d x %d words exceeds %.0f MiB: using an exact hash set of pairs",
                kept,
                width,
                self.budget_bytes / 2**20,
            )
            self.pairs = HashPairs() if self.pairs is None else HashPairs.from_bits(self.pairs)
            return
        self.pairs = BitPairs(self.num_kept, width, self.pairs)

    def grow_keys(self, emitted: int) -> None:
        """A larger buffer of listed pairs, for a pass that listed ``emitted``."""
        self.keys = ti.ndarray(ti.i64, shape=int(1.25 * emitted) + 1)

    def record(self, n: int) -> None:
        """Record the ``n`` pairs listed in ``keys``."""
        self.pairs.record(self.keys, n)

    def counts(self) -> np.ndarray:
        """[K] int64 |P_g| in the internal order."""
        counts = ti.ndarray(ti.i64, shape=max(self.num_kept, 1))
        counts.fill(0)
        if self.pairs is not None:
            self.pairs.count(counts)
        return counts.to_numpy()[: self.num_kept]
