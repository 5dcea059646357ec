"""A disk cache of the empty scene's fluid (the reference of paper Sec. 3.3), so that it is simulated once.

The empty-scene probes run each probe's slab in its walled domain with no solid. Their fluid depends on the probe's
slab, domain and inflow (:class:`fluidsim.probes.ProbeSetup`), the solver settings, the number of steps and the
engine, never on the Gaussians: only the accumulation onto the Gaussians does (D_g^empty, paper Eq. 2-3). So the
cache keeps what the accumulator consumes, every accumulated step's active fluid particles as (x_i, D_i) in the
solver's own float type (:class:`EmptySamples`), and a later run accumulates them onto its own Gaussians. The
accumulator's sums are fixed-point integers (:mod:`nbv.physics.aggregate`), exact in any order, so the reference
D_g from the cache is the same bits as the one accumulated during the simulation.

- **Key**: SHA-256 of the setup (slab, domain, inflow velocity), every ``fluidsim.SolverConfig`` field (precision
  included), the wall layers, the steps and the accumulation stride, the Taichi arch and version, the format
  version and a digest of the engine's source (the ``fluidsim`` package and the probe runner), so that an engine
  change never reads an old trajectory. One entry per probe: the -y probe, which starts at rest, is shared by runs
  at different inflow speeds.
- **Folder**: ``$FLUIDGS_CACHE_DIR``, else ``$XDG_CACHE_HOME/fluidgs``, else ``~/.cache/fluidgs``
  (:func:`cache_folder`).
- **Bound**: ``$FLUIDGS_CACHE_MAX_GB`` GiB (default :data:`DEFAULT_MAX_GB`); after each write the least recently used
  entries (by modification time; a read touches its entry) go until the rest fits. An entry larger than the bound
  is not stored. At the paper's setting the 152k-Gaussian person capture's five probes take 0.58 GB (16 bytes per
  particle and step in f32), the quick preset's 0.19 GB.
- **Concurrent runs**: an entry is written to a temporary file and renamed into place
  (:func:`fluidsim.files.atomic_output`), so a reader sees a whole entry or none; a reader checks the magic, the
  key, the size and the SHA-256 of the payload, and an entry that fails (corrupt, truncated, foreign) is logged,
  removed and rebuilt, never read.
- **An unwritable folder** turns the cache off for the rest of the run with one warning.

File layout of an entry ``<key>.empty``: 8 bytes :data:`MAGIC`, a little-endian u64 header length, a JSON header
(format, key, float type, samples, steps, payload bytes, payload SHA-256), then the payload: the particles per step
[S] int64, the positions [N, 3] and the values [N] of the solver's float type.
"""

from __future__ import annotations

import functools
import hashlib
import json
import logging
import math
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from fluidsim.files import TEMP_NAME, atomic_output

log = logging.getLogger(__name__)

FORMAT_VERSION = 1
MAGIC = b"FGSEMPTY"
SUFFIX = ".empty"
CACHE_DIR_ENV = "FLUIDGS_CACHE_DIR"
CACHE_MAX_ENV = "FLUIDGS_CACHE_MAX_GB"
DEFAULT_MAX_GB = 4.0
# A temporary file older than this was left by a killed writer (a live writer's is younger): removed on eviction.
STALE_TEMP_S = 24 * 3600.0
_HEADER_LIMIT = 1 << 16
_FLOATS = {"f32": np.dtype("<f4"), "f64": np.dtype("<f8")}


@dataclass(frozen=True)
class EmptySamples:
    """The accumulated steps of one empty-scene probe: what :meth:`GaussianAccumulator.add_samples` consumes.

    Attributes:
        positions: [N, 3] float32 or float64 (the solver's precision) x_i after each accumulated step, m.
        values: [N] the same float type, D_i of that step, 1/s.
        step_counts: [S] int64 active particles per accumulated step (they sum to N).
    """

    positions: np.ndarray
    values: np.ndarray
    step_counts: np.ndarray

    @property
    def float_name(self) -> str:
        return "f64" if self.positions.dtype == np.float64 else "f32"

    @property
    def nbytes(self) -> int:
        return int(self.step_counts.nbytes + self.positions.nbytes + self.values.nbytes)


class SampleRecorder:
    """Keeps the active fluid's (x_i, D_i) of every accumulated step of a solver run (``on_step`` callback)."""

    def __init__(self, accumulate_every: int):
        self.accumulate_every = int(accumulate_every)
        self._x: list[np.ndarray] = []
        self._v: list[np.ndarray] = []

    def step(self, solver, stats) -> None:
        """After ``solver.step()``: the step's positions and D_i, on the steps the accumulator adds."""
        if (stats.step + 1) % self.accumulate_every:
            return
        self._x.append(solver.fluid.numpy("x"))
        self._v.append(solver.fluid.numpy("divergence"))

    def samples(self) -> EmptySamples:
        counts = np.asarray([len(v) for v in self._v], np.int64)
        x = np.concatenate(self._x).reshape(-1, 3) if self._x else np.zeros((0, 3), np.float32)
        v = np.concatenate(self._v) if self._v else np.zeros(0, x.dtype)
        return EmptySamples(np.ascontiguousarray(x), np.ascontiguousarray(v), counts)


@functools.cache
def code_digest() -> str:
    """SHA-256 of the source that makes the empty scene's fluid: the ``fluidsim`` package, the probe runner and this
    module (an engine change gives new keys)."""
    import fluidsim  # noqa: PLC0415 - its path only
    from nbv.physics import run  # noqa: PLC0415 - run imports this module

    files = sorted(Path(fluidsim.__file__).parent.rglob("*.py")) + [Path(run.__file__), Path(__file__)]
    h = hashlib.sha256()
    for f in files:
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def cache_key(setup, solver_config, wall_layers: int, steps: int, accumulate_every: int) -> str:
    """The entry of one empty-scene probe: SHA-256 hex of everything its fluid depends on.

    Args:
        setup: the probe's ``fluidsim.probes.ProbeSetup`` (its direction name is left out: only the geometry counts).
        solver_config: ``fluidsim.SolverConfig`` (all fields, precision included).
        wall_layers: layers of wall particles. steps: solver steps. accumulate_every: the accumulated stride.
    Returns:
        64 hex digits.
    """
    import taichi as ti  # noqa: PLC0415 - the runtime's arch and version

    geometry = {k: v for k, v in asdict(setup).items() if k != "direction"}
    record = {
        "format": FORMAT_VERSION,
        "code": code_digest(),
        "taichi": ".".join(str(p) for p in ti.__version__),
        "arch": ti.lang.impl.current_cfg().arch.name,
        "setup": geometry,
        "solver": asdict(solver_config),
        "wall_layers": int(wall_layers),
        "steps": int(steps),
        "accumulate_every": int(accumulate_every),
    }
    text = json.dumps(record, sort_keys=True, default=repr)
    return hashlib.sha256(text.encode()).hexdigest()


def cache_folder() -> Path:
    """``$FLUIDGS_CACHE_DIR``, else ``$XDG_CACHE_HOME/fluidgs``, else ``~/.cache/fluidgs``."""
    given = os.environ.get(CACHE_DIR_ENV, "").strip()
    if given:
        return Path(given).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME", "").strip()
    return (Path(xdg).expanduser() if xdg else Path.home() / ".cache") / "fluidgs"


def max_bytes_from_env() -> int:
    """The bound in bytes from ``$FLUIDGS_CACHE_MAX_GB`` (GiB, >= 0; default :data:`DEFAULT_MAX_GB`).

    Raises:
        ValueError: the variable is not a finite number >= 0.
    """
    text = os.environ.get(CACHE_MAX_ENV, "").strip()
    if not text:
        return int(DEFAULT_MAX_GB * 2**30)
    try:
        gb = float(text)
    except ValueError:
        gb = float("nan")
    if not math.isfinite(gb) or gb < 0:
        raise ValueError(
            f"{CACHE_MAX_ENV}={text!r}: give the empty-scene cache's bound in GiB, a number >= 0 (0 stores nothing; "
            f"default {DEFAULT_MAX_GB:g}), or unset it"
        )
    return int(gb * 2**30)


class EmptyCache:
    """The empty-scene entries in one folder, at most ``max_bytes`` in all (least recently used go first).

    Args:
        folder: the cache folder (created on the first write).
        max_bytes: the bound, bytes (0: nothing is stored).

    Example:
        >>> cache = EmptyCache.from_environment()                                         # doctest: +SKIP
        >>> key = cache_key(setup, config.solver_config(), 2, config.steps, 1)             # doctest: +SKIP
        >>> samples = cache.load(key)  # None: not there (or damaged, then removed)        # doctest: +SKIP
    """

    def __init__(self, folder: str | os.PathLike, max_bytes: int):
        if int(max_bytes) < 0:
            raise ValueError(f"max_bytes must be >= 0, got {max_bytes}")
        self.folder = Path(folder)
        self.max_bytes = int(max_bytes)
        self.disabled = False

    @classmethod
    def from_environment(cls) -> EmptyCache:
        """The user's cache: :func:`cache_folder`, bounded by :func:`max_bytes_from_env` (ValueError on a bad bound)."""
        return cls(cache_folder(), max_bytes_from_env())

    def path(self, key: str) -> Path:
        return self.folder / f"{key}{SUFFIX}"

    # -- reading -----------------------------------------------------------------------------------
    def load(self, key: str) -> EmptySamples | None:
        """The entry of ``key``, or None when there is none or it is damaged (logged, removed: it is rebuilt)."""
        if self.disabled:
            return None
        p = self.path(key)
        try:
            data = p.read_bytes()
        except (FileNotFoundError, NotADirectoryError):
            return None  # not stored (or no folder yet)
        except OSError as exc:
            log.warning("empty-scene cache entry %s cannot be read (%s); the empty scene is simulated", p, exc)
            return None
        try:
            samples = _decode(data, key)
        except ValueError as exc:
            log.warning(
                "empty-scene cache entry %s is damaged (%s); ignored, the empty scene is simulated again", p, exc
            )
            p.unlink(missing_ok=True)
            return None
        try:
            os.utime(p)  # the entry was used: the last to go
        except OSError:
            pass
        return samples

    # -- writing -----------------------------------------------------------------------------------
    def save(self, key: str, samples: EmptySamples) -> bool:
        """Store ``samples`` under ``key`` (atomically), then keep the folder within the bound. An unwritable folder
        turns this cache off with one warning. Returns whether the entry was stored."""
        if self.disabled:
            return False
        header, payload_parts = _encode(samples, key)
        size = len(header) + sum(len(b) for b in payload_parts)
        if size > self.max_bytes:
            log.info("empty-scene entry of %.3g GB exceeds the cache bound (%s); not stored", size / 1e9, CACHE_MAX_ENV)
            return False
        p = self.path(key)
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            with atomic_output(p) as tmp, open(tmp, "wb") as f:
                f.write(header)
                for part in payload_parts:
                    f.write(part)
        except OSError as exc:
            self.disabled = True
            log.warning(
                "empty-scene cache folder %s cannot be written (%s); running without the cache (set %s to a "
                "writable folder)",
                self.folder,
                exc,
                CACHE_DIR_ENV,
            )
            return False
        self.evict(keep=p)
        return True

    def entries(self) -> list[tuple[float, int, Path]]:
        """(modification time, bytes, path) of every entry, oldest first."""
        out = []
        try:
            found = list(os.scandir(self.folder))
        except OSError:
            return out
        for e in found:
            if not e.name.endswith(SUFFIX):
                continue
            try:
                st = e.stat(follow_symlinks=False)
            except OSError:
                continue  # removed by another run meanwhile
            out.append((st.st_mtime, st.st_size, Path(e.path)))
        return sorted(out)

    def evict(self, keep: Path | None = None) -> list[Path]:
        """Remove the least recently used entries until the rest fits the bound (``keep`` last), and temporary files
        that killed writers left more than :data:`STALE_TEMP_S` ago. Returns the removed entries."""
        now = time.time()
        try:
            for e in os.scandir(self.folder):
                if TEMP_NAME.match(e.name) and now - e.stat(follow_symlinks=False).st_mtime > STALE_TEMP_S:
                    Path(e.path).unlink(missing_ok=True)
        except OSError:
            pass
        entries = self.entries()
        total = sum(size for _, size, _ in entries)
        removed = []
        for _, size, p in sorted(entries, key=lambda e: (e[2] == keep, e[0])):
            if total <= self.max_bytes:
                break
            try:
                p.unlink()
            except FileNotFoundError:
                pass  # another run removed it
            except OSError:
                continue
            total -= size
            removed.append(p)
        if removed:
            log.info(
                "empty-scene cache: %d least recently used entries removed (bound %s)", len(removed), CACHE_MAX_ENV
            )
        return removed


def _encode(samples: EmptySamples, key: str) -> tuple[bytes, list[bytes]]:
    dtype = _FLOATS[samples.float_name]
    parts = [
        np.ascontiguousarray(samples.step_counts, "<i8").tobytes(),
        np.ascontiguousarray(samples.positions, dtype).tobytes(),
        np.ascontiguousarray(samples.values, dtype).tobytes(),
    ]
    h = hashlib.sha256()
    for part in parts:
        h.update(part)
    head = {
        "format": FORMAT_VERSION,
        "key": key,
        "float": samples.float_name,
        "samples": len(samples.values),
        "steps": len(samples.step_counts),
        "payload_bytes": sum(len(p) for p in parts),
        "sha256": h.hexdigest(),
    }
    text = json.dumps(head, sort_keys=True).encode()
    return MAGIC + len(text).to_bytes(8, "little") + text, parts


def _decode(data: bytes, key: str) -> EmptySamples:
    """The samples of an entry's bytes; ValueError naming what is wrong (magic, header, key, size, hash)."""
    if len(data) < 16 or data[:8] != MAGIC:
        raise ValueError("not an empty-scene cache entry (wrong magic)")
    n_head = int.from_bytes(data[8:16], "little")
    if n_head > min(_HEADER_LIMIT, len(data) - 16):
        raise ValueError(f"header of {n_head} bytes in a file of {len(data)}")
    try:
        head = json.loads(data[16 : 16 + n_head])
        fmt, entry_key, name = head["format"], head["key"], head["float"]
        n, steps, n_payload, digest = (
            int(head["samples"]),
            int(head["steps"]),
            int(head["payload_bytes"]),
            str(head["sha256"]),
        )
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"unreadable header ({exc})") from None
    if fmt != FORMAT_VERSION:
        raise ValueError(f"format {fmt}, expected {FORMAT_VERSION}")
    if entry_key != key:
        raise ValueError(f"it holds key {str(entry_key)[:12]}..., not {key[:12]}... (a foreign entry)")
    if name not in _FLOATS or n < 0 or steps < 0:
        raise ValueError(f"float type {name!r}, {n} samples, {steps} steps")
    dtype = _FLOATS[name]
    expected = 8 * steps + 4 * dtype.itemsize * n
    if n_payload != expected or len(data) != 16 + n_head + n_payload:
        raise ValueError(f"{len(data)} bytes, expected {16 + n_head + expected} (truncated or padded)")
    payload = memoryview(data)[16 + n_head :]
    if hashlib.sha256(payload).hexdigest() != digest:
        raise ValueError("the payload's SHA-256 differs from the header's")
    counts = np.frombuffer(payload, "<i8", steps, 0)
    positions = np.frombuffer(payload, dtype, 3 * n, 8 * steps).reshape(n, 3)
    values = np.frombuffer(payload, dtype, n, 8 * steps + 3 * n * dtype.itemsize)
    if int(counts.sum()) != n or (counts < 0).any():
        raise ValueError(f"the steps' particle counts sum to {int(counts.sum())}, not {n}")
    return EmptySamples(positions, values, counts)
