"""A disk cache of the empty scene's fluid (the reference of paper Sec. 3.3), so that it is simulated once.

The empty-scene probes run each probe's slab in its walled domain with no solid. Their fluid depends on the probe's
setup, the solver settings, the steps and the engine, never on the Gaussians: only the accumulation onto them does
(D_g^empty, paper Eq. 2-3). So the cache keeps what the accumulator consumes, every accumulated step's active fluid
particles as (x_i, D_i) in the solver's own float type (:class:`EmptySamples`), and a later run accumulates them onto
its own Gaussians. The accumulator's sums are fixed-point integers (:mod:`nbv.physics.aggregate`), exact in any order,
so the reference D_g from the cache is the same bits as the one accumulated during the simulation.

- **Key** (:func:`cache_key`): one entry per probe, so the -y probe, which starts at rest, is shared by runs at
  different inflow speeds. It digests the source that makes the fluid (:func:`runner_sources`), so that an engine
  change never reads an old trajectory and an edit elsewhere (the probe run around it) keeps the entries.
- **Folder** (:func:`cache_folder`) and **bound** (:func:`max_bytes_from_env`): after each write the least recently
  used entries (by modification time; a read touches its entry) go until the rest fits. An entry larger than the
  bound is not stored. At the paper's setting the 152k-Gaussian person capture's five probes take 0.58 GB (16 bytes
  per particle and step in f32), the quick preset's 0.19 GB.
- **Concurrent runs**: an entry is written to a temporary file and renamed into place
  (:func:`fluidsim.files.atomic_output`), so a reader sees a whole entry or none; an entry that fails the reader's
  checks (magic, key, size, SHA-256 of the payload: corrupt, truncated, foreign) is logged, removed and rebuilt, never
  read. An unwritable folder turns the cache off for the rest of the run with one warning.
- **Trust**: the folder is untrusted input. An entry is read only as a bounded regular file (:func:`_read_entry`). The
  hash finds damage, not forgery (a writer of the folder can recompute it), so the reader also checks plausibility
  (:func:`_check_samples`, :meth:`EmptyCache._check_means`). docs/cli.md says what is left.

A second kind of entry keeps the means of those samples accumulated onto one set of Gaussians (:func:`means_key`; 8
bytes per Gaussian), so that a run on the same Gaussians skips the accumulation too. :class:`EmptyReference` is the
one owner of both kinds and of a run's memo of means, behind one lookup.

File layout of an entry ``<key>.empty``: 8 bytes :data:`MAGIC`, a little-endian u64 header length, a JSON header
(format, key, the arrays' names, types and shapes, payload bytes, payload SHA-256; a means entry also names its
samples' key), then the arrays: the particles per step [S] int64, the positions [N, 3] and the values [N] of the
solver's float type; or the means [G] float64.
"""

from __future__ import annotations

import ast
import contextlib
import errno
import hashlib
import json
import logging
import math
import os
import stat
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
_DTYPES = ("<f4", "<f8", "<i8")
_SAMPLE_ARRAYS = ("step_counts", "positions", "values")  # a fluid entry's arrays, in their order in the file


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


def _source_digest(files: list[tuple[str, Path]]) -> str:
    """SHA-256 of (name, bytes) pairs: a file is named relative to its package, so a copy of the tree digests alike."""
    h = hashlib.sha256()
    for name, f in files:
        h.update(name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def _fluidsim_imports(path: Path, fluidsim_root: Path) -> set[Path]:
    """The ``fluidsim`` modules that the file ``path`` imports (every import statement, function-level ones included),
    with the ``__init__.py`` of each package on the way."""
    top = fluidsim_root.parent
    package = list(path.parent.relative_to(top).parts) if path.is_relative_to(fluidsim_root) else None
    dotted = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            dotted += [a.name.split(".") for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            parts = node.module.split(".") if node.module else []
            if node.level and package is not None:  # relative, within fluidsim
                parts = package[: len(package) + 1 - node.level] + parts
            dotted += [parts] + [[*parts, a.name] for a in node.names]  # an imported name may be a module
    found = set()
    for parts in dotted:
        if parts[:1] == ["fluidsim"]:  # each package on the way runs its __init__
            prefixes = [top.joinpath(*parts[:k]) for k in range(1, len(parts) + 1)]
            found.update(m for p in prefixes for m in (p / "__init__.py", p.with_suffix(".py")) if m.is_file())
    return found


def runner_sources(physics: Path | None = None, fluidsim_root: Path | None = None) -> list[tuple[str, Path]]:
    """The source files that make the empty scene's fluid, as (name, path): the runner (``empty_scene.py``), this
    module and the ``fluidsim`` modules the runner imports, directly or through each other. Other modules (the probe
    run, the recording) leave the keys as they are.

    Args:
        physics: the folder of this module and the runner (default: this module's). fluidsim_root: the ``fluidsim``
            package folder (default: the imported one's); a copy of both trees gives the same names.
    """
    import fluidsim  # noqa: PLC0415 - its path only

    physics = Path(__file__).parent if physics is None else Path(physics)
    root = Path(fluidsim.__file__).parent if fluidsim_root is None else Path(fluidsim_root)
    mine = [physics / "empty_scene.py", physics / "empty_cache.py"]  # by path: the runner imports this module
    todo, seen = list(mine), set()
    while todo:
        for m in _fluidsim_imports(todo.pop(), root) - seen:
            seen.add(m)
            todo.append(m)
    named = [(f"nbv/physics/{m.name}", m) for m in mine]
    return named + [(m.relative_to(root.parent).as_posix(), m) for m in sorted(seen)]


def code_digest(sources: list[tuple[str, Path]] | None = None) -> str:
    """SHA-256 of the source that makes the empty scene's fluid (default: :func:`runner_sources`)."""
    return _source_digest(runner_sources() if sources is None else sources)


def accumulator_digest() -> str:
    """SHA-256 of the accumulator's source (``nbv/physics/aggregate*.py``): what turns samples into means."""
    return _source_digest([(f.name, f) for f in sorted(Path(__file__).parent.glob("aggregate*.py"))])


def means_key(samples_key: str, centers: np.ndarray, reach: np.ndarray, accumulator: str | None = None) -> str:
    """The entry of the means of the samples under ``samples_key`` accumulated onto these Gaussians ([G, 3] centres
    and [G] reach, sim metres). ``accumulator``: the :func:`accumulator_digest` (None: computed)."""
    accumulator = accumulator_digest() if accumulator is None else accumulator
    h = hashlib.sha256(f"{samples_key}:{accumulator}:means".encode())
    for a in (centers, reach):
        a = np.ascontiguousarray(a, np.float64)
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def cache_key(
    setup, solver_config, wall_layers: int, steps: int, accumulate_every: int, code: str | None = None
) -> str:
    """The entry of one empty-scene probe: SHA-256 hex (64 digits) of everything its fluid depends on, with the Taichi
    arch and version and the format version.

    Args:
        setup: the probe's ``fluidsim.probes.ProbeSetup`` (its direction name is left out: only the geometry counts).
        solver_config: ``fluidsim.SolverConfig`` (all fields, precision included).
        wall_layers: layers of wall particles. steps: solver steps. accumulate_every: the accumulated stride.
        code: the :func:`code_digest` (None: computed).
    """
    import taichi as ti  # noqa: PLC0415 - the runtime's arch and version

    geometry = {k: v for k, v in asdict(setup).items() if k != "direction"}
    record = {
        "format": FORMAT_VERSION,
        "code": code_digest() if code is None else code,
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
    try:
        gb = float(text or DEFAULT_MAX_GB)
    except ValueError:
        gb = math.nan
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
        """The fluid samples under ``key``, or None when there are none or the entry is damaged (logged, removed: it
        is rebuilt)."""
        arrays = self._read(key, _SAMPLE_ARRAYS, self.max_bytes, _check_samples)
        return None if arrays is None else EmptySamples(**{n: arrays[n] for n in _SAMPLE_ARRAYS})

    def load_means(self, key: str, num_gaussians: int, samples_key: str) -> np.ndarray | None:
        """The [G] float64 means under ``key`` (:func:`means_key` of the samples under ``samples_key``), or None as
        :meth:`load` (or when they fail :meth:`_check_means`)."""
        limit = 16 + _HEADER_LIMIT + 8 * int(num_gaussians)
        arrays = self._read(key, ("means",), limit, lambda a: self._check_means(a, num_gaussians, samples_key))
        return None if arrays is None else arrays["means"]

    def _read(self, key: str, names: tuple[str, ...], limit: int, check) -> dict | None:
        """The arrays ``names`` of the entry under ``key`` if it is at most ``limit`` bytes and passes ``check`` (which
        raises ValueError), else None."""
        if self.disabled:
            return None
        p = self.path(key)
        try:
            data = _read_entry(p, limit)
        except (FileNotFoundError, NotADirectoryError):
            return None  # not stored (or no folder yet)
        except ValueError as exc:  # a link, a FIFO, a device, an entry larger than any the cache writes
            log.warning("empty-scene cache entry %s %s; removed, the empty scene is simulated", p, exc)
            p.unlink(missing_ok=True)
            return None
        except OSError as exc:
            log.warning("empty-scene cache entry %s cannot be read (%s); the empty scene is simulated", p, exc)
            return None
        try:
            arrays = _decode(data, key, names)
            check(arrays)
        except ValueError as exc:
            log.warning(
                "empty-scene cache entry %s is damaged (%s); ignored, the empty scene is simulated again", p, exc
            )
            p.unlink(missing_ok=True)
            return None
        with contextlib.suppress(OSError):
            os.utime(p)  # the entry was used: the last to go
        return arrays

    def _check_means(self, arrays: dict, num_gaussians: int, source: str) -> None:
        """The means are plausible: one per Gaussian, finite, made from the samples ``source`` this reader keyed them on
        (never the file's word alone), which are stored and, as the means average their D_i, bound them."""
        means, named = arrays["means"], arrays.get("samples_key")
        if means.shape != (num_gaussians,):
            raise ValueError(f"{means.shape[0]} means for {num_gaussians} Gaussians")
        if not np.isfinite(means).all():
            raise ValueError("non-finite means")
        if named != source:
            raise ValueError(f"it names the samples {str(named)[:12]}..., not {source[:12]}...")
        samples = self.load(source)
        if samples is None:
            raise ValueError("its samples are not in the cache (the means cannot be checked)")
        largest = float(np.abs(samples.values).max(initial=0.0))
        biggest = float(np.abs(means).max(initial=0.0))
        if biggest > largest * (1 + 1e-6) + 1e-6:
            raise ValueError(
                f"a mean of {biggest:.4g} 1/s exceeds the largest |D_i| of its samples, "
                f"{largest:.4g} 1/s (not an average of them)"
            )

    # -- writing -----------------------------------------------------------------------------------
    def save(self, key: str, samples: EmptySamples) -> bool:
        """Store ``samples`` under ``key`` (atomically), then keep the folder within the bound. An unwritable folder
        turns this cache off with one warning. Returns whether the entry was stored."""
        return self._write(key, {n: getattr(samples, n) for n in _SAMPLE_ARRAYS})

    def save_means(self, key: str, means: np.ndarray, samples_key: str) -> bool:
        """Store [G] float64 means under ``key`` (naming their samples' ``samples_key``), as :meth:`save`."""
        return self._write(key, {"means": np.asarray(means, np.float64)}, samples_key)

    def _write(self, key: str, arrays: dict[str, np.ndarray], samples_key: str | None = None) -> bool:
        if self.disabled:
            return False
        parts = _encode(arrays, key, samples_key)
        size = sum(len(b) for b in parts)
        if size > self.max_bytes:
            log.info("empty-scene entry of %.3g GB exceeds the cache bound (%s); not stored", size / 1e9, CACHE_MAX_ENV)
            return False
        p = self.path(key)
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            with atomic_output(p) as tmp, open(tmp, "wb") as f:
                f.writelines(parts)
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
        return self._files(lambda name: name.endswith(SUFFIX))

    def _files(self, match) -> list[tuple[float, int, Path]]:
        """(modification time, bytes, path) of the folder's files whose names ``match``, oldest first."""
        out = []
        try:
            found = list(os.scandir(self.folder))
        except OSError:
            return out
        for e in filter(lambda e: match(e.name), found):
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
        for mtime, _, p in self._files(TEMP_NAME.match):
            if now - mtime > STALE_TEMP_S:
                with contextlib.suppress(OSError):
                    p.unlink(missing_ok=True)
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


@dataclass(frozen=True)
class EmptyFound:
    """What :meth:`EmptyReference.lookup` found for one probe on one set of Gaussians.

    Attributes:
        samples_key, means_key: the entries' keys (:func:`cache_key`, :func:`means_key`; None: nothing is stored).
        means: [G] float64, the reference itself (None: not found).
        samples: the probe's fluid, to accumulate onto the Gaussians (None: not found; simulate it).
        where: the entry the samples came from.
    """

    samples_key: str | None = None
    means_key: str | None = None
    means: np.ndarray | None = None
    samples: EmptySamples | None = None
    where: str = ""


class EmptyReference:
    """The one owner of the empty scene's reference: a probe's D_g^empty on a set of Gaussians, looked up in this run's
    memo of means, then the disk's means, then the disk's fluid samples (:class:`EmptyCache`), and put back into all
    of them once accumulated or simulated. The means' :func:`means_key` also keys the memo.

    Args:
        store: the disk cache (None: nothing is looked up or stored; every probe is simulated).
        memo_entries: the most means the memo keeps (least recently used go first).

    Example:
        >>> ref = EmptyReference.of(config)                                      # doctest: +SKIP
        >>> found = ref.lookup(plan.setups["-x"], config, centers, reach)        # doctest: +SKIP
    """

    MEMO_ENTRIES = 16

    def __init__(self, store: EmptyCache | None, memo_entries: int = MEMO_ENTRIES):
        self.store = store
        self.memo_entries = int(memo_entries)
        self._memo: dict[str, np.ndarray] = {}
        self._code = None if store is None else code_digest()
        self._accumulator = None if store is None else accumulator_digest()

    @classmethod
    def of(cls, config) -> EmptyReference:
        """The reference of a run of ``config`` (:class:`nbv.physics.config.PhysicsConfig`): the user's cache
        (:meth:`EmptyCache.from_environment`, its bound read now: ValueError on a bad one) when the run has an empty
        scene and ``config.empty_cache``, else none."""
        use = config.empty_reference and config.empty_cache
        return cls(EmptyCache.from_environment() if use else None)

    @property
    def stores(self) -> bool:
        """Whether a simulated probe's fluid is kept to be stored."""
        return self.store is not None

    def lookup(self, setup, config, centers: np.ndarray, reach: np.ndarray) -> EmptyFound:
        """The reference of the probe ``setup`` (``fluidsim.probes.ProbeSetup``) of ``config`` on these Gaussians
        ([G, 3] centres, [G] reach, sim metres): its means, else its fluid, else only its keys."""
        if self.store is None:
            return EmptyFound()
        samples_key, key = self._keys(setup, config, centers, reach)
        means = self._memo.pop(key, None)
        if means is None:
            means = self.store.load_means(key, len(centers), samples_key)
        if means is not None:
            self._remember(key, means)
            return EmptyFound(samples_key, key, means=means, where=str(self.store.path(key)))
        found = self.store.load(samples_key)
        return EmptyFound(samples_key, key, samples=found, where=str(self.store.path(samples_key)))

    def holds(self, setup, config, centers: np.ndarray, reach: np.ndarray) -> bool:
        """Whether :meth:`lookup` would find the probe's means or fluid (nothing is read but the memo and the folder's
        names; a damaged entry counts, and :meth:`lookup` then simulates it)."""
        if self.store is None:
            return False
        samples_key, key = self._keys(setup, config, centers, reach)
        return key in self._memo or self.store.path(key).exists() or self.store.path(samples_key).exists()

    def put(self, found: EmptyFound, means: np.ndarray, samples: EmptySamples | None = None) -> None:
        """Store the ``means`` of a probe looked up as ``found`` (and its simulated fluid ``samples``)."""
        if self.store is None or found.means_key is None:
            return
        if samples is not None:
            self.store.save(found.samples_key, samples)
        self.store.save_means(found.means_key, means, found.samples_key)
        self._remember(found.means_key, means)

    def _keys(self, setup, config, centers: np.ndarray, reach: np.ndarray) -> tuple[str, str]:
        """(the fluid's key, the means' key) of a probe on these Gaussians."""
        wall_layers = config.probe_config().wall_layers
        solver = config.solver_config()
        samples_key = cache_key(setup, solver, wall_layers, config.steps, config.accumulate_every, self._code)
        return samples_key, means_key(samples_key, centers, reach, self._accumulator)

    def _remember(self, key: str, means: np.ndarray) -> None:
        self._memo.pop(key, None)
        self._memo[key] = means  # the most recently used last
        while len(self._memo) > self.memo_entries:
            self._memo.pop(next(iter(self._memo)))


def _read_entry(path: Path, limit: int) -> bytes:
    """The bytes of an entry: a regular file (never through a symbolic link, never a FIFO or a device: opened without
    blocking and checked by its descriptor) of at most ``limit`` bytes. ValueError says what else it is."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise ValueError("is a symbolic link (entries are regular files)") from None
        raise
    with os.fdopen(fd, "rb") as fh:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise ValueError("is not a regular file (a FIFO, a device or a socket)")
        if st.st_size > limit:
            raise ValueError(f"holds {st.st_size} bytes, more than the {limit} an entry may hold")
        data = fh.read(st.st_size + 1)
    if len(data) != st.st_size:
        raise ValueError("changed size while it was read")
    return data


def _encode(arrays: dict[str, np.ndarray], key: str, samples_key: str | None = None) -> list[bytes]:
    """The header, then the arrays' bytes, of an entry holding ``arrays`` (little-endian f4, f8 or i8)."""
    parts, layout = [], []
    h = hashlib.sha256()
    for name, a in arrays.items():
        a = np.asarray(a)
        dtype = a.dtype.newbyteorder("<")
        if dtype.str not in _DTYPES:
            raise ValueError(f"{name}: dtype {a.dtype} is not one of {_DTYPES}")
        part = np.ascontiguousarray(a, dtype).tobytes()
        h.update(part)
        parts.append(part)
        layout.append([name, dtype.str, list(a.shape)])
    head = {
        "format": FORMAT_VERSION,
        "key": key,
        "arrays": layout,
        "payload_bytes": sum(len(p) for p in parts),
        "sha256": h.hexdigest(),
    }
    if samples_key is not None:
        head["samples_key"] = samples_key
    text = json.dumps(head, sort_keys=True).encode()
    return [MAGIC + len(text).to_bytes(8, "little") + text, *parts]


def _decode(data: bytes, key: str, names: tuple[str, ...]) -> dict[str, np.ndarray]:
    """The arrays ``names`` of an entry's bytes (read-only views), and the header's ``samples_key`` if any; ValueError
    naming what is wrong (magic, header, key, layout, size, hash)."""
    if len(data) < 16 or data[:8] != MAGIC:
        raise ValueError("not an empty-scene cache entry (wrong magic)")
    n_head = int.from_bytes(data[8:16], "little")
    if n_head > min(_HEADER_LIMIT, len(data) - 16):
        raise ValueError(f"header of {n_head} bytes in a file of {len(data)}")
    try:
        head = json.loads(data[16 : 16 + n_head])
        fmt, entry_key, digest = head["format"], head["key"], str(head["sha256"])
        n_payload = int(head["payload_bytes"])
        layout = [(str(n), str(d), tuple(int(k) for k in shape)) for n, d, shape in head["arrays"]]
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"unreadable header ({exc})") from None
    if fmt != FORMAT_VERSION:
        raise ValueError(f"format {fmt}, expected {FORMAT_VERSION}")
    if entry_key != key:
        raise ValueError(f"it holds key {str(entry_key)[:12]}..., not {key[:12]}... (a foreign entry)")
    if tuple(n for n, _, _ in layout) != names:
        raise ValueError(f"it holds {[n for n, _, _ in layout]}, not {list(names)}")
    if any(d not in _DTYPES or any(k < 0 for k in shape) for _, d, shape in layout):
        raise ValueError(f"bad array layout {layout}")
    sizes = [np.dtype(d).itemsize * math.prod(shape) for _, d, shape in layout]
    if n_payload != sum(sizes) or len(data) != 16 + n_head + n_payload:
        raise ValueError(f"{len(data)} bytes, expected {16 + n_head + sum(sizes)} (truncated or padded)")
    payload = memoryview(data)[16 + n_head :]
    if hashlib.sha256(payload).hexdigest() != digest:
        raise ValueError("the payload's SHA-256 differs from the header's")
    out, offset = {}, 0
    for (name, d, shape), size in zip(layout, sizes, strict=True):
        out[name] = np.frombuffer(payload, d, math.prod(shape), offset).reshape(shape)
        offset += size
    if "samples_key" in head:
        out["samples_key"] = str(head["samples_key"])
    return out


def _check_samples(arrays: dict[str, np.ndarray]) -> None:
    """A fluid entry's arrays are consistent: [N, 3] positions and [N] values of one float type, step counts >= 0
    summing to N, all finite; ValueError otherwise."""
    counts, pos, vals = (arrays[n] for n in _SAMPLE_ARRAYS)
    n = len(vals)
    if counts.ndim != 1 or pos.shape != (n, 3) or vals.ndim != 1 or pos.dtype != vals.dtype:
        raise ValueError(f"samples of shapes {pos.shape} and {vals.shape}")
    if pos.dtype.str not in ("<f4", "<f8") or (counts < 0).any() or int(counts.sum()) != n:
        raise ValueError(f"the steps' particle counts sum to {int(counts.sum())}, not {n}")
    if not (np.isfinite(pos).all() and np.isfinite(vals).all()):
        raise ValueError("non-finite positions or D_i")
