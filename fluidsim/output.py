"""Outputs: the HDF5 file of a simulation.

The file is written atomically through :mod:`fluidsim.files` (a temporary ``.fgs-<8 hex>.tmp`` file in the
output's folder, renamed into place when the run ends), after :func:`fluidsim.files.check_writable` has tried that
folder before any work.
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
    attributes: scene (the scene JSON), status ("complete", the fault, or "interrupted"), removed_inside_solid
"""

from __future__ import annotations

import json
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
)
from fluidsim.files.atomic import PathLike

from .forces import force_history
from .solver import STATS_FIELDS, StepStats

__all__ = [
    "TEMP_PREFIX",
    "OutputError",
    "SimulationWriter",
    "atomic_output",
    "check_not_input",
    "check_writable",
    "output_errors",
    "same_file",
    "stats_table",
    "temp_path",
]


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
    "interrupted", ``OUT.diverged.h5`` for a fault."""
    p = Path(path)
    tag = "interrupted" if status == "interrupted" else "diverged"
    return p.with_name(f"{p.stem}.{tag}{p.suffix}")


class SimulationWriter:
    """Writes frames as they come and the run summary at the end; the file appears only when closed.

    The file is written under a :func:`fluidsim.files.temp_path` name (a :class:`fluidsim.files.PendingFile`) and
    renamed onto ``path`` by :meth:`finish`, whatever the status ("complete", a divergence, "interrupted");
    :meth:`abort` drops it. Every ``OSError`` while writing becomes an :class:`OutputError` naming ``path``.

    Example:
        >>> with SimulationWriter("out.h5", scene_dict) as w:      # doctest: +SKIP
        ...     w.write_frame(stats.step + 1, stats.time, solver.fluid_state())
        ...     w.finish(history, *solver.divergence_accumulation())
    """

    def __init__(self, path: PathLike, scene: dict):
        self.path = check_writable(path)
        self._pending = PendingFile(self.path)
        self.tmp = self._pending.tmp
        with output_errors(self.path):
            self.file = h5py.File(self.tmp, "w")
        self.file.attrs["scene"] = json.dumps(scene)
        self.file.attrs["status"] = "running"
        self.frames = self.file.create_group("frames")
        self._closed = False
        self.last_frame_step: int | None = None

    def write_boundary(self, points: np.ndarray) -> None:
        with output_errors(self.path):
            self.file.create_dataset(
                "boundary/x", data=np.asarray(points, np.float32), compression="gzip", compression_opts=1
            )

    def write_frame(self, step: int, time: float, state: dict[str, np.ndarray]) -> None:
        """One frame after ``step`` completed steps at simulated ``time`` (s); ``state`` from the solver."""
        with output_errors(self.path):
            g = self.frames.create_group(f"{step:06d}")
            for key in ("x", "v", "divergence", "ids", "density"):
                g.create_dataset(key, data=state[key], compression="gzip", compression_opts=1)
            g.attrs["time"] = time
            g.attrs["step"] = step
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
