"""HDF5 output of a simulation, written atomically (a temporary file in the same folder, then rename).

Layout::

    /frames/<k>/x, /frames/<k>/v      (K, 3) fluid positions (m) and velocities (m/s), by particle id
    /frames/<k>/divergence            (K,) D_i of that step (paper Eq. 1), 1/s
    /frames/<k>/ids                   (K,) initial fluid indices of the active particles
                                      attributes: time (s), step
    /stats                            one row per step (see fluidsim.solver.StepStats)
    /divergence_sum, /divergence_count (N,) per initial fluid particle, over the whole run
    /boundary/x                       (M, 3) static boundary particles, m
    attributes: scene (the scene JSON), status ("complete" or the fault), removed_inside_solid
"""

from __future__ import annotations

import json
import os
from dataclasses import astuple
from pathlib import Path

import h5py
import numpy as np

from .solver import STATS_FIELDS, StepStats


def check_writable(path: str | Path) -> Path:
    """Fail early, before any work, when ``path`` cannot be written.

    Raises:
        OSError: naming the path and the fix.
    """
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.exists():
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OSError(f"cannot create the output folder {parent}: {exc}; choose a writable path") from exc
    if not os.access(parent, os.W_OK):
        raise OSError(f"output folder {parent} is not writable; choose another output path")
    if p.exists() and p.is_dir():
        raise OSError(f"output path {p} is a folder; give a file name such as {p / 'out.h5'}")
    return p


def stats_table(history: list[StepStats]) -> np.ndarray:
    """Step statistics as a structured array (one row per step)."""
    dtype = [(name, np.int64 if isinstance(getattr(history[0], name), int) else np.float64)
             for name in STATS_FIELDS] if history else [(name, np.float64) for name in STATS_FIELDS]
    return np.array([astuple(s) for s in history], dtype=dtype)


class SimulationWriter:
    """Writes frames as they come and the run summary at the end; the file appears only when closed.

    Example:
        >>> with SimulationWriter("out.h5", scene_dict) as w:      # doctest: +SKIP
        ...     w.write_frame(stats.step + 1, stats.time, solver.fluid_state())
        ...     w.finish(history, *solver.divergence_accumulation())
    """

    def __init__(self, path: str | Path, scene: dict):
        self.path = check_writable(path)
        self.tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
        self.file = h5py.File(self.tmp, "w")
        self.file.attrs["scene"] = json.dumps(scene)
        self.file.attrs["status"] = "running"
        self.frames = self.file.create_group("frames")
        self._closed = False

    def write_boundary(self, points: np.ndarray) -> None:
        self.file.create_dataset("boundary/x", data=np.asarray(points, np.float32), compression="gzip",
                                 compression_opts=1)

    def write_frame(self, step: int, time: float, state: dict[str, np.ndarray]) -> None:
        """One frame after ``step`` completed steps at simulated ``time`` (s); ``state`` from the solver."""
        g = self.frames.create_group(f"{step:06d}")
        for key in ("x", "v", "divergence", "ids"):
            g.create_dataset(key, data=state[key], compression="gzip", compression_opts=1)
        g.attrs["time"] = time
        g.attrs["step"] = step

    def finish(self, history: list[StepStats], divergence_sum: np.ndarray, divergence_count: np.ndarray,
               status: str = "complete", **attrs) -> Path:
        """Write the summary, close and move the file into place; returns the final path."""
        self.file.create_dataset("stats", data=stats_table(history))
        self.file.create_dataset("divergence_sum", data=divergence_sum)
        self.file.create_dataset("divergence_count", data=divergence_count)
        self.file.attrs["status"] = status
        for k, v in attrs.items():
            self.file.attrs[k] = v
        self.file.close()
        self._closed = True
        os.replace(self.tmp, self.path)
        return self.path

    def abort(self) -> None:
        """Drop the temporary file (used when the run failed before anything worth keeping)."""
        if not self._closed:
            self.file.close()
            self._closed = True
        self.tmp.unlink(missing_ok=True)

    def __enter__(self) -> SimulationWriter:
        return self

    def __exit__(self, *exc) -> None:
        if not self._closed:
            self.abort()
