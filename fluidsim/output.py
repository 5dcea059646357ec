"""Outputs: the HDF5 file of a simulation, and the checks and atomic writes every output of the project uses.

Every writer writes a temporary file of one short pattern in the output's folder (:func:`temp_path`,
``.fgs-<8 hex>.tmp``), then renames it into place (:func:`atomic_output`). :func:`check_writable` tries that
very pattern before any work, and :func:`check_not_input` refuses an output that is one of the inputs.
An output the file system refuses raises :class:`OutputError` (exit code 4 of `fluidgs`).

Layout::

    /frames/<k>/x, /frames/<k>/v      (K, 3) fluid positions (m) and velocities (m/s), by particle id
    /frames/<k>/divergence            (K,) D_i of that step (paper Eq. 1), 1/s
    /frames/<k>/ids                   (K,) initial fluid indices of the active particles
                                      attributes: time (s), step
    /stats                            one row per step (see fluidsim.solver.StepStats)
    /divergence_sum, /divergence_count (N,) per initial fluid particle, over the whole run
    /boundary/x                       (M, 3) static boundary particles, m
    attributes: scene (the scene JSON), status ("complete", the fault, or "interrupted"), removed_inside_solid
"""

from __future__ import annotations

import json
import os
import uuid
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import astuple
from pathlib import Path

import h5py
import numpy as np

from .solver import STATS_FIELDS, StepStats

PathLike = str | os.PathLike
TEMP_PREFIX = ".fgs-"


class OutputError(OSError):
    """An output cannot be written: a full disk, a read-only or unwritable folder, a name too long, a parent
    that is a file, a folder where a file is wanted. The message names the path and the fix (`fluidgs`: exit 4)."""


def temp_path(path: PathLike, suffix: str = "") -> Path:
    """A fresh temporary name next to ``path``: ``.fgs-<8 hex>.tmp<suffix>`` in the same folder.

    Every atomic writer of the project uses this one pattern (``suffix`` keeps an extension that a library
    needs, e.g. ".png" for OpenCV). It is short whatever the output's name, so an output name the file
    system accepts always has a temporary name it accepts too, and :func:`check_writable` tries exactly it.
    """
    p = Path(path)
    return p.parent / f"{TEMP_PREFIX}{uuid.uuid4().hex[:8]}.tmp{suffix}"


@contextmanager
def output_errors(path: PathLike) -> Iterator[None]:
    """Turn an ``OSError`` raised while writing ``path`` into an :class:`OutputError` naming the path."""
    try:
        yield
    except OutputError:
        raise
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {exc}; free disk space or choose a writable output path") from exc


@contextmanager
def atomic_output(path: PathLike, suffix: str = "") -> Iterator[Path]:
    """Write ``path`` atomically: yields a :func:`temp_path` in the same folder, renamed onto ``path`` when the
    block ends normally and removed when it raises; an ``OSError`` becomes an :class:`OutputError`.

    Example:
        >>> with atomic_output("out.json") as tmp:          # doctest: +SKIP
        ...     tmp.write_text("{}")
    """
    tmp = temp_path(path, suffix)
    try:
        with output_errors(path):
            yield tmp
            os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def _first_existing(p: Path) -> Path:
    """``p`` or its nearest ancestor that exists."""
    p = p.absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def _check_name_lengths(p: Path, folder: Path) -> None:
    try:
        name_max = os.pathconf(folder, "PC_NAME_MAX")
        path_max = os.pathconf(folder, "PC_PATH_MAX")
    except (OSError, ValueError):
        name_max, path_max = 255, 4096
    for part in p.absolute().parts[1:]:
        if len(os.fsencode(part)) > name_max:
            raise OutputError(f"output path {p}: the name {part[:40]}... is {len(os.fsencode(part))} bytes, longer "
                              f"than the {name_max} bytes this file system allows; choose a shorter name")
    if len(os.fsencode(str(p.absolute()))) >= path_max:
        raise OutputError(f"output path {p} is longer than the {path_max} bytes this system allows; choose a "
                          "shorter path")


def check_writable(path: PathLike) -> Path:
    """Fail early, before any work, when ``path`` cannot be written as an output file.

    Creates the missing parent folders, checks the name lengths against the file system's limits, then
    creates and removes a temporary file of the writers' own pattern (:func:`temp_path`) in the folder, so
    that a read-only, full or unwritable folder is found now, not after the simulation.

    Raises:
        OutputError: naming the path and the fix (a parent is a file, the output is a folder, a name is too
            long, the folder cannot be created or written).
    """
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    blocker = _first_existing(parent)
    if not blocker.is_dir():
        raise OutputError(f"output path {p}: {blocker} is a file, not a folder; choose an output path whose "
                          "folders are folders")
    _check_name_lengths(p, blocker)
    if not parent.exists():
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OutputError(f"cannot create the output folder {parent}: {exc}; choose a writable path") from exc
    if p.is_dir():
        raise OutputError(f"output path {p} is a folder; give a file name such as {p / 'out.h5'}")
    probe = temp_path(p)
    try:
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except OSError as exc:
        raise OutputError(f"output folder {parent} is not writable ({exc.strerror}); choose another output "
                          "path") from exc
    os.close(fd)
    probe.unlink()
    return p


# ---- outputs must not be inputs -------------------------------------------------------------------------
def same_file(a: PathLike, b: PathLike) -> bool:
    """Whether two paths name the same file: the same inode on the same device (symbolic and hard links,
    ``..`` and relative spellings included), or, for a path that does not exist yet, the same real path."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.realpath(a) == os.path.realpath(b)


def _inside(path: PathLike, folder: PathLike) -> bool:
    real, top = os.path.realpath(path), os.path.realpath(folder)
    return real == top or real.startswith(top.rstrip(os.sep) + os.sep)


Labelled = Mapping[str, PathLike | None] | Iterable[tuple[str, PathLike | None]]


def _pairs(paths: Labelled | None) -> list[tuple[str, Path]]:
    items = (paths or {}).items() if isinstance(paths, Mapping) or paths is None else paths
    return [(k, Path(v)) for k, v in items if v is not None]


def check_not_input(outputs: Labelled, inputs: Labelled, replaced: Labelled | None = None) -> None:
    """Refuse, before any work, an output that would overwrite an input.

    Each argument is a mapping label -> path or (label, path) pairs (several paths may share a label); None
    paths are skipped.

    Args:
        outputs: label (the option, e.g. "--ply") -> a path the command writes.
        inputs: label (e.g. "GAUSSIANS") -> a file the command reads.
        replaced: label -> an output folder the command replaces or empties as a whole (``--overwrite``): no
            input may lie inside it.
    Raises:
        ValueError: naming both paths and the fix (the outputs resolve to an input: same real path, a
            symbolic link or a hard link to it).
    """
    ins = _pairs(inputs)
    for olabel, out in _pairs(outputs):
        for ilabel, inp in ins:
            if same_file(out, inp):
                how = (" (a hard link to the same file)" if os.path.realpath(out) != os.path.realpath(inp) else
                       " (through a symbolic link)" if os.path.abspath(out) != os.path.abspath(inp) else "")
                raise ValueError(f"{olabel} {out} is the input {ilabel} {inp}{how}: writing it would destroy the "
                                 f"input; choose another output path for {olabel}")
    for olabel, folder in _pairs(replaced):
        for ilabel, inp in ins:
            if _inside(inp, folder):
                raise ValueError(f"{olabel} {folder} would be replaced, but the input {ilabel} {inp} lies inside "
                                 f"it; choose another output folder for {olabel} or move the input out")


def stats_table(history: list[StepStats]) -> np.ndarray:
    """Step statistics as a structured array (one row per step)."""
    dtype = [(name, np.int64 if isinstance(getattr(history[0], name), int) else np.float64)
             for name in STATS_FIELDS] if history else [(name, np.float64) for name in STATS_FIELDS]
    return np.array([astuple(s) for s in history], dtype=dtype)


class SimulationWriter:
    """Writes frames as they come and the run summary at the end; the file appears only when closed.

    The file is written under a :func:`temp_path` name and renamed onto ``path`` by :meth:`finish`, whatever
    the status ("complete", a divergence, "interrupted"); :meth:`abort` drops it. Every ``OSError`` while
    writing becomes an :class:`OutputError` naming ``path``.

    Example:
        >>> with SimulationWriter("out.h5", scene_dict) as w:      # doctest: +SKIP
        ...     w.write_frame(stats.step + 1, stats.time, solver.fluid_state())
        ...     w.finish(history, *solver.divergence_accumulation())
    """

    def __init__(self, path: PathLike, scene: dict):
        self.path = check_writable(path)
        self.tmp = temp_path(self.path)
        with output_errors(self.path):
            self.file = h5py.File(self.tmp, "w")
        self.file.attrs["scene"] = json.dumps(scene)
        self.file.attrs["status"] = "running"
        self.frames = self.file.create_group("frames")
        self._closed = False
        self.last_frame_step: int | None = None

    def write_boundary(self, points: np.ndarray) -> None:
        with output_errors(self.path):
            self.file.create_dataset("boundary/x", data=np.asarray(points, np.float32), compression="gzip",
                                     compression_opts=1)

    def write_frame(self, step: int, time: float, state: dict[str, np.ndarray]) -> None:
        """One frame after ``step`` completed steps at simulated ``time`` (s); ``state`` from the solver."""
        with output_errors(self.path):
            g = self.frames.create_group(f"{step:06d}")
            for key in ("x", "v", "divergence", "ids"):
                g.create_dataset(key, data=state[key], compression="gzip", compression_opts=1)
            g.attrs["time"] = time
            g.attrs["step"] = step
        self.last_frame_step = step

    def finish(self, history: list[StepStats], divergence_sum: np.ndarray, divergence_count: np.ndarray,
               status: str = "complete", **attrs) -> Path:
        """Write the summary, close and move the file into place; returns the final path.

        ``status``: "complete", the fault of a diverged run, or "interrupted" (by SIGINT or SIGTERM)."""
        try:
            with output_errors(self.path):
                self.file.create_dataset("stats", data=stats_table(history))
                self.file.create_dataset("divergence_sum", data=divergence_sum)
                self.file.create_dataset("divergence_count", data=divergence_count)
                self.file.attrs["status"] = status
                for k, v in attrs.items():
                    self.file.attrs[k] = v
                self.file.close()
                self._closed = True
                os.replace(self.tmp, self.path)
        except BaseException:
            self.abort()
            raise
        return self.path

    def abort(self) -> None:
        """Drop the temporary file (used when the run failed before anything worth keeping)."""
        if not self._closed:
            try:
                self.file.close()
            except (OSError, RuntimeError):  # a full disk can fail the close too; the file goes anyway
                pass
            self._closed = True
        self.tmp.unlink(missing_ok=True)

    def __enter__(self) -> SimulationWriter:
        return self

    def __exit__(self, *exc) -> None:
        if not self._closed:
            self.abort()
