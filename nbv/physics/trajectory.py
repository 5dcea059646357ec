"""Probe trajectories: one probe's fluid positions, D_i and speed every k steps, for replaying it (``fluidgs view``).

No paper equation is implemented here: this records what the probes of :mod:`nbv.physics` already compute
(the positions after each step and D_i of paper Eq. 1) so that a viewer can replay them against the Gaussians.

A frame is taken after every k-th step (after steps k, 2k, ..., so T = steps // k frames). Each frame holds
every fluid particle of the probe, indexed by its id (its index in the probe's initial fluid set); a particle
that has left the walled domain (retired) reads NaN from then on. Sizes per (frame, particle): 24 bytes
(positions 3 x float32; D_i, speed, velocity 3 x and density float16), so a probe of F particles costs F T 24
bytes in memory while it runs and about as much in RESULT.h5 (gzip level 1 with the shuffle filter). Recording is
off unless asked for (``--record-probe``), so RESULT.h5 stays small by default; the size is checked against
``RecordConfig.max_bytes`` and the available memory before any probe runs.

HDF5 layout, under ``/probes/<dir>/trajectory`` (written by :func:`nbv.physics.save_result`)::

    x       (T, F, 3) float32  positions, sim metres (NaN: retired)
    D       (T, F) float16     D_i, 1/s (NaN: retired)
    speed   (T, F) float16     |v_i|, m/s (NaN: retired)
    v       (T, F, 3) float16  velocity, m/s (NaN: retired; absent in files written before it)
    density (T, F) float16     rho_i / rho_0 (NaN: retired; absent in files written before it)
    steps   (T,) int32         steps completed at each frame (k, 2k, ...); time = steps * dt
    attributes: every (k), fluid_particles (F)

Example:
    >>> record = RecordConfig(("-x",), every=10)
    >>> result = simulate_gaussians(gaussians, config, record=record)  # doctest: +SKIP
    >>> result.trajectories["-x"].x.shape  # doctest: +SKIP
    (75, 51234, 3)
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fluidsim.host import available_memory_bytes

log = logging.getLogger(__name__)

# bytes per recorded (frame, particle): x as 3 float32; D_i, speed, v (3) and density as float16
BYTES_PER_SAMPLE = 24
DEFAULT_MAX_BYTES = 2.0 * 2**30
GROUP = "trajectory"


@dataclass(frozen=True)
class RecordConfig:
    """Which probes to record, and how often.

    Attributes:
        directions: the probes to record (each must be one of the probes run).
        every: k, steps between frames (a frame after steps k, 2k, ...); k >= 1.
        max_bytes: refuse to record more than this (all recorded probes together), bytes.
    """

    directions: tuple[str, ...]
    every: int = 10
    max_bytes: float = DEFAULT_MAX_BYTES

    def __post_init__(self) -> None:
        dirs = tuple(self.directions)
        if not dirs or len(set(dirs)) != len(dirs):
            raise ValueError(f"RecordConfig.directions must be distinct probe names, got {dirs}")
        object.__setattr__(self, "directions", dirs)
        if isinstance(self.every, bool) or not isinstance(self.every, int) or self.every < 1:
            raise ValueError(f"--record-every must be an integer >= 1 step, got {self.every!r}")
        if not (isinstance(self.max_bytes, (int, float)) and math.isfinite(self.max_bytes) and self.max_bytes > 0):
            raise ValueError(f"--record-max-gb must be > 0, got {self.max_bytes!r} bytes")

    def frames(self, steps: int) -> int:
        """T = steps // every, the frames recorded in a probe of ``steps`` steps."""
        return int(steps) // self.every

    def check_probes(self, directions: Sequence[str], steps: int) -> None:
        """Raise ValueError when a recorded probe is not among ``directions`` (the probes run) or a probe of
        ``steps`` steps would record no frame."""
        missing = [d for d in self.directions if d not in tuple(directions)]
        if missing:
            raise ValueError(
                f"--record-probe {','.join(missing)}: not among the probes run "
                f"(--directions {','.join(directions)}); record one of those or add it to --directions"
            )
        if self.frames(steps) < 1:
            raise ValueError(
                f"--record-every {self.every} is more than the {steps} steps of a probe, so no frame "
                f"would be recorded; use --record-every {max(1, steps // 10)}"
            )


@dataclass(frozen=True)
class ProbeTrajectory:
    """One recorded probe.

    Attributes:
        steps: [T] int32 steps completed at each frame.
        x: [T, F, 3] float32 positions, sim metres (NaN: retired).
        divergence: [T, F] float16 D_i, 1/s (NaN: retired).
        speed: [T, F] float16 |v_i|, m/s (NaN: retired).
        every: k, steps between frames.
        velocity: [T, F, 3] float16 v_i, m/s (NaN: retired), or None in files written before it.
        density: [T, F] float16 rho_i / rho_0 (NaN: retired), or None in files written before it.
    """

    steps: np.ndarray
    x: np.ndarray
    divergence: np.ndarray
    speed: np.ndarray
    every: int
    velocity: np.ndarray | None = None
    density: np.ndarray | None = None

    @property
    def num_frames(self) -> int:
        return int(self.x.shape[0])

    @property
    def num_particles(self) -> int:
        return int(self.x.shape[1])

    @property
    def nbytes(self) -> int:
        return int(
            sum(a.nbytes for a in (self.x, self.divergence, self.speed, self.velocity, self.density) if a is not None)
        )


def trajectory_bytes(fluid_particles: int, frames: int) -> int:
    """F T 24 bytes: what recording ``frames`` frames of ``fluid_particles`` particles takes."""
    return int(fluid_particles) * int(frames) * BYTES_PER_SAMPLE


def check_record_size(fluid_counts: dict[str, int], steps: int, record: RecordConfig) -> int:
    """Raise ValueError, before any probe runs, when the recording would exceed ``record.max_bytes`` or the memory
    available; log the size otherwise.

    Args:
        fluid_counts: fluid particles F of each recorded probe.
        steps: steps per probe.
        record: what to record.
    Returns:
        the bytes the recording takes.
    """
    frames = max(record.frames(steps), 0)
    total = sum(trajectory_bytes(f, frames) for f in fluid_counts.values())
    limit = min(float(record.max_bytes), 0.5 * float(available_memory_bytes()))
    what = ", ".join(f"probe {d}: {f:,} particles" for d, f in fluid_counts.items())
    if total > limit:
        fewer = max(record.every + 1, math.ceil(record.every * total / limit))
        raise ValueError(
            f"recording {what} x {frames} frames (every {record.every} steps) x {BYTES_PER_SAMPLE} bytes "
            f"would take {total / 2**20:,.0f} MiB, over the limit of {limit / 2**20:,.0f} MiB "
            f"(--record-max-gb, at most half the available memory); use --record-every {fewer} or "
            "record fewer probes"
        )
    log.info(
        "recording %s x %d frames (every %d steps): %.1f MiB in memory and in RESULT.h5",
        what,
        frames,
        record.every,
        total / 2**20,
    )
    return total


class TrajectoryRecorder:
    """Callbacks, driven by :class:`nbv.physics.recorder.ProbeRecorder`, that fill one :class:`ProbeTrajectory` per
    recorded probe. ``results`` holds the probes completed."""

    def __init__(self, record: RecordConfig, steps: int):
        self.record, self.steps = record, int(steps)
        self.results: dict[str, ProbeTrajectory] = {}
        self._direction: str | None = None
        self._run = 0  # the steps the recorded probe ran
        self._buffers: tuple[np.ndarray, ...] | None = None

    def start(self, direction: str, solver) -> None:
        """Allocate the frames of ``direction`` (NaN-filled) when it is recorded; otherwise record nothing."""
        if direction not in self.record.directions:
            self._direction, self._buffers = None, None
            return
        frames, fluid = self.record.frames(self.steps), int(solver.fluid.capacity)
        self._direction, self._run = direction, 0
        self._buffers = (
            np.full((frames, fluid, 3), np.nan, np.float32),
            np.full((frames, fluid), np.nan, np.float16),
            np.full((frames, fluid), np.nan, np.float16),
            np.arange(1, frames + 1, dtype=np.int32) * self.record.every,
            np.full((frames, fluid, 3), np.nan, np.float16),
            np.full((frames, fluid), np.nan, np.float16),
        )

    def step(self, direction: str, solver, step: int) -> None:
        """After step ``step`` (0-based): take a frame when ``step + 1`` is a multiple of k."""
        if direction == self._direction:
            self._run = max(self._run, step + 1)
        if direction != self._direction or self._buffers is None or (step + 1) % self.record.every:
            return
        frame = (step + 1) // self.record.every - 1
        x, divergence, speed, _, velocity, density = self._buffers
        if frame >= len(x):
            return
        f = solver.fluid
        if f.active == 0:
            return
        ids = f.numpy("ids").astype(np.int64)
        x[frame, ids] = f.numpy("x")
        divergence[frame, ids] = f.numpy("divergence")
        v = f.numpy("v")
        speed[frame, ids] = np.linalg.norm(v.astype(np.float64), axis=1)
        velocity[frame, ids] = v
        density[frame, ids] = f.numpy("density")

    def end(self, direction: str) -> None:
        """Keep the frames of ``direction`` in ``results``."""
        if direction != self._direction or self._buffers is None:
            return
        # a probe stopped early (nbv.physics.early_stop) keeps the frames of the steps it ran
        kept = int(np.searchsorted(self._buffers[3], self._run, side="right"))
        x, divergence, speed, steps, velocity, density = (b[:kept] for b in self._buffers)
        self.results[direction] = ProbeTrajectory(
            steps=steps,
            x=x,
            divergence=divergence,
            speed=speed,
            every=self.record.every,
            velocity=velocity,
            density=density,
        )
        self._direction, self._buffers = None, None


def write_trajectory(group, trajectory: ProbeTrajectory) -> None:
    """Write ``trajectory`` under an h5py group ``/probes/<dir>`` (layout in the module docstring)."""
    t, f = trajectory.num_frames, trajectory.num_particles
    g = group.create_group(GROUP)
    opts = dict(compression="gzip", compression_opts=1, shuffle=True)
    g.create_dataset("x", data=trajectory.x, chunks=(1, max(f, 1), 3) if t and f else None, **opts)
    g.create_dataset("D", data=trajectory.divergence, chunks=(1, max(f, 1)) if t and f else None, **opts)
    g.create_dataset("speed", data=trajectory.speed, chunks=(1, max(f, 1)) if t and f else None, **opts)
    if trajectory.velocity is not None:
        g.create_dataset("v", data=trajectory.velocity, chunks=(1, max(f, 1), 3) if t and f else None, **opts)
    if trajectory.density is not None:
        g.create_dataset("density", data=trajectory.density, chunks=(1, max(f, 1)) if t and f else None, **opts)
    g.create_dataset("steps", data=np.asarray(trajectory.steps, np.int32))
    g.attrs["every"], g.attrs["fluid_particles"] = int(trajectory.every), int(f)


def read_trajectory(group) -> ProbeTrajectory:
    """Inverse of :func:`write_trajectory` (``group`` is ``/probes/<dir>``; it must hold a trajectory)."""
    g = group[GROUP]
    return ProbeTrajectory(
        steps=g["steps"][()],
        x=g["x"][()],
        divergence=g["D"][()],
        speed=g["speed"][()],
        every=int(g.attrs["every"]),
        velocity=g["v"][()] if "v" in g else None,
        density=g["density"][()] if "density" in g else None,
    )
