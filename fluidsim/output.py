"""Outputs: the HDF5 file of a simulation.

The file is written atomically through :mod:`fluidsim.files` (a temporary ``.fgs-<8 hex>.tmp`` file in the
output's folder, renamed into place when the run ends), after :func:`fluidsim.files.check_writable` has tried that
folder before any work.
A full disk loses no frame already written. The writer holds the room its summary needs (:func:`summary_bytes`) in
a second temporary file, ``.fgs-<8 hex>.tmp.reserve``, from the start; before each frame it checks that the disk
still has room for that frame, and when it has not, :class:`DiskFull` is raised before anything is written. Frames
are written through a chunk cache of size zero and flushed, so a write the disk refuses anyway (another process
filled it) fails in :meth:`SimulationWriter.write_frame` itself, never later in a finalizer where the error would be
lost, and its partial frame is removed. Either way the reserve is released and the file finished with the frames
so far (status "disk full").
An output the file system refuses raises :class:`fluidsim.files.OutputError` (exit code 4 of `fluidgs`). The checks and
the atomic writes are re-exported here for the callers of the engine.

Layout::

    /frames/<k>/x, /frames/<k>/v      (K, 3) fluid positions (m) and velocities (m/s), by particle id
    /frames/<k>/divergence            (K,) D_i of that step (paper Eq. 1), 1/s
    /frames/<k>/ids                   (K,) initial fluid indices of the active particles
    /frames/<k>/density               (K,) rho_i / rho_0 of that step
                                      attributes: time (s), step
    /stats                            one row per step (see fluidsim.solver.StepStats)
    /forces/solid, /forces/walls      (S, 3) the fluid's force on the scene's solids (all together) and on the domain
                                      walls per step, N (fluidsim.forces); attributes: mean (3,) N, the time mean
                                      over the second half of the run; impulse (3,) N s
    /divergence_sum, /divergence_count (N,) per initial fluid particle, over the whole run
    /boundary/x                       (M, 3) static boundary particles, m
    attributes: scene (the scene JSON), status ("complete", the fault, "interrupted" or "disk full"),
                removed_inside_solid
"""

from __future__ import annotations

import errno
import json
import os
from dataclasses import astuple
from pathlib import Path

import h5py
import numpy as np

from fluidsim.files import (
    TEMP_PREFIX,
    OutputError,
    PendingFile,
    atomic_output,
    check_not_input,
    check_writable,
    output_errors,
    same_file,
    temp_path,
    track_temp,
    untrack_temp,
)
from fluidsim.files.atomic import PathLike

from .forces import force_history
from .solver import STATS_FIELDS, StepStats

__all__ = [
    "TEMP_PREFIX",
    "DiskFull",
    "OutputError",
    "SimulationWriter",
    "atomic_output",
    "check_not_input",
    "check_writable",
    "output_errors",
    "same_file",
    "stats_table",
    "summary_bytes",
    "temp_path",
]


FRAME_KEYS = ("x", "v", "divergence", "ids", "density")
# HDF5 metadata of one frame (a group, five datasets with their chunk indexes and attributes), with room to spare
FRAME_OVERHEAD_BYTES = 64 * 1024


class DiskFull(OutputError):
    """The file system of an output has no room left for the next frame (checked before writing it, so the file
    still holds every frame before it and can be finished). ``free`` and ``needed`` are in bytes."""

    def __init__(self, path: PathLike, free: int, needed: int):
        self.path, self.free, self.needed = Path(path), free, needed
        super().__init__(
            f"cannot write {path}: its disk has {free / 2**20:.1f} MiB free, the next frame needs "
            f"{needed / 2**20:.1f} MiB; free disk space or choose another output path"
        )
        self.errno = errno.ENOSPC


def free_bytes(folder: PathLike) -> int | None:
    """Bytes still free for this process in the file system of ``folder`` (None where the system cannot say)."""
    try:
        st = os.statvfs(folder)
    except (OSError, AttributeError):
        return None
    return st.f_bavail * st.f_frsize


def summary_bytes(steps: int, particles: int) -> int:
    """An upper bound (bytes) of what :meth:`SimulationWriter.finish` adds to the file for a run of ``steps`` steps
    with ``particles`` fluid particles: the statistics and forces per step, the divergence sums per particle and
    the metadata written when the file is closed (1 MiB)."""
    per_step = 8 * len(STATS_FIELDS) + 2 * 3 * 8
    return int(steps) * per_step + 2 * 8 * int(particles) + 2**20


def stats_table(history: list[StepStats]) -> np.ndarray:
    """Step statistics as a structured array (one row per step)."""
    dtype = (
        [(name, np.int64 if isinstance(getattr(history[0], name), int) else np.float64) for name in STATS_FIELDS]
        if history
        else [(name, np.float64) for name in STATS_FIELDS]
    )
    return np.array([astuple(s) for s in history], dtype=dtype)


def is_complete_file(path: PathLike) -> bool:
    """Whether ``path`` is an OUT.h5 of a run that completed (status "complete"); False for anything else."""
    try:
        with h5py.File(path, "r") as f:
            return f.attrs.get("status") == "complete"
    except (OSError, ValueError, RuntimeError):
        return False


def unfinished_path(path: PathLike, status: str) -> Path:
    """Where an unfinished run's file goes when ``path`` holds a complete one: ``OUT.interrupted.h5`` for status
    "interrupted", ``OUT.disk-full.h5`` for "disk full", ``OUT.diverged.h5`` for a fault."""
    p = Path(path)
    tag = {"interrupted": "interrupted", "disk full": "disk-full"}.get(status, "diverged")
    return p.with_name(f"{p.stem}.{tag}{p.suffix}")


class SimulationWriter:
    """Writes frames as they come and the run summary at the end; the file appears only when closed.

    The file is written under a :func:`fluidsim.files.temp_path` name (a :class:`fluidsim.files.PendingFile`) and
    renamed onto ``path`` by :meth:`finish`, whatever the status ("complete", a divergence, "interrupted",
    "disk full"); :meth:`abort` drops it. Every ``OSError`` while writing becomes an :class:`OutputError` naming
    ``path``. ``reserve_bytes`` (:func:`summary_bytes`) are held on the disk for :meth:`finish` from the start, in
    a temporary file released when the file is finished or dropped; a frame the disk has no room for raises
    :class:`DiskFull` before it is written.

    Example:
        >>> with SimulationWriter("out.h5", scene_dict) as w:      # doctest: +SKIP
        ...     w.write_frame(stats.step + 1, stats.time, solver.fluid_state())
        ...     w.finish(history, *solver.divergence_accumulation())
    """

    def __init__(self, path: PathLike, scene: dict, reserve_bytes: int = 0):
        self.path = check_writable(path)
        self._pending = PendingFile(self.path)
        self.tmp = self._pending.tmp
        self._reserve = self._hold(int(reserve_bytes)) if reserve_bytes > 0 else None
        try:
            with output_errors(self.path):
                self.file = h5py.File(self.tmp, "w", rdcc_nbytes=0)  # no chunk cache: a refused write fails at once
        except BaseException:
            self._release()
            self._pending.discard()
            raise
        self.file.attrs["scene"] = json.dumps(scene)
        self.file.attrs["status"] = "running"
        self.frames = self.file.create_group("frames")
        self._closed = False
        self.last_frame_step: int | None = None

    def _hold(self, size: int) -> Path:
        """Take ``size`` bytes of the output's disk in a temporary file (released by :meth:`_release`)."""
        reserve = track_temp(temp_path(self.path, ".reserve"))
        try:
            with output_errors(self.path):
                fd = os.open(reserve, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
                try:
                    if hasattr(os, "posix_fallocate"):
                        os.posix_fallocate(fd, 0, size)
                    else:  # no fallocate (macOS): zeros take the room too
                        os.write(fd, bytes(size))
                finally:
                    os.close(fd)
        except BaseException:
            reserve.unlink(missing_ok=True)
            untrack_temp(reserve)
            raise
        return reserve

    def _release(self) -> None:
        """Give the reserved room back to the disk (before the summary is written, or when the file is dropped)."""
        if self._reserve is not None:
            self._reserve.unlink(missing_ok=True)
            untrack_temp(self._reserve)
            self._reserve = None

    def write_boundary(self, points: np.ndarray) -> None:
        with output_errors(self.path):
            self.file.create_dataset(
                "boundary/x", data=np.asarray(points, np.float32), compression="gzip", compression_opts=1
            )

    def write_frame(self, step: int, time: float, state: dict[str, np.ndarray]) -> None:
        """One frame after ``step`` completed steps at simulated ``time`` (s); ``state`` from the solver.

        Raises:
            DiskFull: before writing, when the disk has no room for this frame.
            OutputError: a write the file system refused; the frame's part already written is removed, so the
                file holds the earlier frames only and can still be finished.
        """
        needed = sum(np.asarray(state[k]).nbytes for k in FRAME_KEYS) + FRAME_OVERHEAD_BYTES
        free = free_bytes(self.tmp.parent)
        if free is not None and free < needed:
            raise DiskFull(self.path, free, needed)
        name = f"{step:06d}"
        try:
            with output_errors(self.path):
                g = self.frames.create_group(name)
                for key in FRAME_KEYS:
                    g.create_dataset(key, data=state[key], compression="gzip", compression_opts=1)
                g.attrs["time"] = time
                g.attrs["step"] = step
                self.file.flush()  # the frame's metadata reaches the disk now, so a refusal is raised here
        except OutputError:
            try:
                if name in self.frames:
                    del self.frames[name]
            except (OSError, RuntimeError, KeyError):  # the file is finished without it either way, or dropped
                pass
            raise
        self.last_frame_step = step

    def finish(
        self,
        history: list[StepStats],
        divergence_sum: np.ndarray,
        divergence_count: np.ndarray,
        status: str = "complete",
        **attrs,
    ) -> Path:
        """Write the summary, close and move the file into place; returns the final path.

        ``status``: "complete", the fault of a diverged run, or "interrupted" (by SIGINT or SIGTERM). An unfinished
        run never replaces a complete file of an earlier run at ``path``: it is written beside it
        (:func:`unfinished_path`, ``OUT.interrupted.h5``), and that is the path returned."""
        if status != "complete" and is_complete_file(self.path):
            self._pending.path = unfinished_path(self.path, status)
        self._release()
        try:
            with output_errors(self._pending.path):
                self.file.create_dataset("stats", data=stats_table(history))
                for part, f in force_history(history).items():
                    ds = self.file.create_dataset(f"forces/{part}", data=f["series"])
                    ds.attrs["mean"], ds.attrs["impulse"] = f["mean"], f["impulse"]
                self.file.create_dataset("divergence_sum", data=divergence_sum)
                self.file.create_dataset("divergence_count", data=divergence_count)
                self.file.attrs["status"] = status
                for k, v in attrs.items():
                    self.file.attrs[k] = v
            try:
                self.file.close()  # the last buffers reach the disk here: a full disk fails now
            except (OSError, RuntimeError) as exc:
                err = OutputError(
                    f"cannot write {self._pending.path}: closing it failed ({exc}); free disk space or "
                    "choose a writable output path"
                )
                err.errno = getattr(exc, "errno", None)
                raise err from exc
            finally:
                self._closed = True
            self._pending.commit()
        except BaseException:
            self.abort()
            raise
        return self._pending.path

    def abort(self) -> None:
        """Drop the temporary file (used when the run failed before anything worth keeping)."""
        self._release()
        if not self._closed:
            try:
                self.file.close()
            except (OSError, RuntimeError):  # a full disk can fail the close too; the file goes anyway
                pass
            self._closed = True
        self._pending.discard()

    def __enter__(self) -> SimulationWriter:
        return self

    def __exit__(self, *exc) -> None:
        if not self._closed:
            self.abort()
