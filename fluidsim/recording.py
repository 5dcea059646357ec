"""A built solver stepped to an OUT.h5 file (the format of :class:`fluidsim.output.SimulationWriter`): frames every
K steps, per-step statistics and the divergence sums, written whatever ends the run; a probe against a static solid
(:func:`probe_to_h5`), or every probe, one file each, with their summary (:func:`probes_to_h5`).

A diverging run still writes its file (frames so far, statistics, status naming the step) and re-raises. A stop
request (an object whose ``signum`` becomes a signal number, such as the SIGINT/SIGTERM handler of ``fluidgs sim``)
ends the run at the next step boundary: the file gets the current state as a last frame and status "interrupted",
and :class:`Interrupted` is raised. A full disk (a frame the file system refuses, or no room left for the next
one: :class:`fluidsim.output.DiskFull`) finishes the file with the frames written so far and status "disk full", then
raises :class:`FramesKept`, an :class:`~fluidsim.files.OutputError` (exit code 4). Never prints; the progress bar is
tqdm's, off with ``progress=False``.
"""

from __future__ import annotations

import logging
import os
import signal
from collections.abc import Callable
from pathlib import Path

import numpy as np
from tqdm import tqdm

from .config import SolverConfig
from .output import DiskFull, OutputError, SimulationWriter, summary_bytes
from .probes import ProbeConfig, build_probe_solver, probe_setups
from .simulation import SimulationDiverged, run

log = logging.getLogger(__name__)


class Interrupted(Exception):
    """The run was stopped by ``signum`` (SIGINT or SIGTERM) after ``step`` completed steps; its file is saved."""

    def __init__(self, signum: int, step: int, path: Path, kept: Path | None = None):
        self.signum, self.step, self.path = signum, step, path
        tail = f"; the complete {kept} of an earlier run is kept" if kept is not None else "; run again to overwrite it"
        super().__init__(
            f"{signal.Signals(signum).name} after step {step}; the frames so far are saved to {path} "
            f"(status 'interrupted'){tail}"
        )

    @property
    def exit_code(self) -> int:
        """128 + the signal number: 130 for SIGINT, 143 for SIGTERM (the shell's convention)."""
        return 128 + int(self.signum)


class FramesKept(OutputError):
    """The disk refused a frame after ``step`` completed steps; the file at ``path`` holds the frames written before
    it (the last after step ``last_frame``) with status "disk full"; ``errno`` is that of the refused write."""

    def __init__(self, cause: OutputError, step: int, last_frame: int, frames: int, path: Path):
        self.step, self.last_frame, self.path = step, last_frame, path
        if isinstance(cause, DiskFull):
            reason = f"{cause.free / 2**20:.1f} MiB free, {cause.needed / 2**20:.1f} MiB needed"
        else:
            reason = os.strerror(cause.errno) if cause.errno else str(cause.__cause__ or cause)
        super().__init__(
            f"cannot write the frame of step {step} to {path}: its disk is full ({reason}); the {frames} frames up "
            f"to step {last_frame} are saved there (status 'disk full'): free disk space or choose another -o, "
            "then run again"
        )
        self.errno = cause.errno


def simulate_to_h5(
    solver, scene_dict: dict, output: Path, steps: int, save_every: int, desc: str, progress: bool = True, stop=None
) -> tuple[Path, list]:
    """Step a built solver, writing frames every ``save_every`` steps; returns (path, stats history).

    Args:
        solver: a built :class:`fluidsim.DFSPHSolver`.
        scene_dict: the scene written into the file's attributes.
        output: the .h5 path (written under a temporary name, renamed at the end).
        steps: time steps to run; save_every: steps between frames (0: the first and last only).
        desc: the progress bar's label; progress: show it.
        stop: None, or an object whose ``signum`` is None until a signal asks to stop (module docstring).
    Raises:
        SimulationDiverged: after the file is written with the diverged status.
        Interrupted: after the file is written with status "interrupted".
        FramesKept: a full disk, after the file is written with the frames so far and status "disk full".
        OutputError: the file could not be written at all (nothing kept).
    """
    writer = SimulationWriter(output, scene_dict, reserve_bytes=summary_bytes(steps, solver.fluid.capacity))
    history: list = []
    frames = 0
    bar = tqdm(total=steps, desc=desc, unit="step", disable=not progress, leave=False)

    def on_step(s, st) -> None:
        last = st.step + 1 == steps
        nonlocal frames
        if (save_every and (st.step + 1) % save_every == 0) or last:
            writer.write_frame(st.step + 1, st.time, s.fluid_state())
            frames += 1
        if stop is not None and stop.signum is not None and not last:
            raise Interrupted(stop.signum, st.step + 1, writer.path)

    def on_progress(st) -> None:
        history.append(st)
        bar.update(1)
        bar.set_postfix(
            density_it=st.density_iterations,
            divergence_it=st.divergence_iterations,
            vmax=f"{st.max_speed:.2f}",
            fluid=st.active,
            refresh=False,
        )

    try:
        writer.write_boundary(solver.boundary.x.to_numpy()[: solver.boundary.count])
        writer.write_frame(0, 0.0, solver.fluid_state())
        frames = 1
        history = run(solver, steps, on_step=on_step, progress=on_progress)
    except SimulationDiverged as exc:
        bar.close()
        path = _finish(writer, solver, exc.history, status=str(exc))
        log.error("%s; frames so far saved to %s", exc, path)
        raise
    except Interrupted as exc:
        bar.close()
        if writer.last_frame_step != exc.step:
            writer.write_frame(exc.step, history[-1].time, solver.fluid_state())
        name = signal.Signals(exc.signum).name
        path = _finish(writer, solver, history, "interrupted", interrupted_by=name, interrupted_after_step=exc.step)
        if path != exc.path:
            raise Interrupted(exc.signum, exc.step, path, kept=exc.path) from None
        raise
    except OutputError as exc:
        bar.close()
        if not frames:  # nothing simulated yet: nothing to keep
            writer.abort()
            raise
        # an OutputError here (the disk still full for the summary) drops the file
        path = _finish(writer, solver, history, "disk full", disk_full_after_step=len(history))
        raise FramesKept(exc, len(history), writer.last_frame_step, frames, path) from exc
    except BaseException:
        bar.close()
        writer.abort()
        raise
    bar.close()
    return _finish(writer, solver, history), history


def _finish(writer, solver, history: list, status: str = "complete", **attributes) -> Path:
    """Write the run's summary (statistics, D_i accumulation, status) and move the file into place."""
    sums, counts = solver.divergence_accumulation()
    return writer.finish(history, sums, counts, status, removed_inside_solid=solver.removed_inside_solid, **attributes)


def probe_to_h5(
    solid: np.ndarray,
    direction: str,
    config: SolverConfig,
    probe: ProbeConfig,
    steps: int,
    path: str | Path,
    save_every: int = 10,
    progress: bool = True,
):
    """One probe (:mod:`fluidsim.probes`) against the static ``solid`` [N, 3] (m), stepped to an OUT.h5 at ``path``
    with its domain, inflow velocity, walls and time step in the file's scene attributes.

    Returns:
        (path, the per-step statistics, the solver after the run: its divergence sums are the file's).
    """
    setup = probe_setups(solid, probe, config.spacing, (direction,))[direction]
    solver = build_probe_solver(solid, setup, config, probe)
    scene = {
        "probe": direction,
        "velocity": list(setup.velocity),
        "domain": {"min": list(setup.domain_min), "max": list(setup.domain_max), "walls": probe.walls},
        "particle_radius": config.particle_radius,
        "dt": config.dt,
        "steps": steps,
    }
    out, history = simulate_to_h5(
        solver, scene, Path(path), steps, save_every, desc=f"probe {direction}", progress=progress
    )
    return out, history, solver


def probe_file_summary(path: Path, history: list, solver) -> dict:
    """A JSON-able summary of one :func:`probe_to_h5` run: particle counts, retired fluid, mean solver iterations
    and the mean and 95th percentile of the particles' mean divergence D_i (paper Eq. 1, 1/s)."""
    sums, counts = solver.divergence_accumulation()
    mean_d = np.where(counts > 0, sums / np.maximum(counts, 1), 0.0)
    return {
        "file": Path(path).name,
        "fluid_particles": solver.fluid.capacity,
        "boundary_particles": solver.boundary.count,
        "retired": int(sum(h.retired for h in history)),
        "mean_density_iterations": float(np.mean([h.density_iterations for h in history])),
        "mean_divergence_iterations": float(np.mean([h.divergence_iterations for h in history])),
        "mean_particle_divergence": float(mean_d.mean()),
        "p95_particle_divergence": float(np.percentile(mean_d, 95)),
    }


def probes_to_h5(
    solid: np.ndarray,
    config: SolverConfig,
    probe: ProbeConfig,
    steps: int,
    folder: str | Path,
    source: str = "",
    on_probe: Callable[[str, dict], None] | None = None,
) -> dict:
    """Every probe of ``probe`` against the static ``solid`` [N, 3] (m), each stepped to ``folder/probe_<d>.h5`` by
    :func:`probe_to_h5`, in the probe's order.

    Args:
        solid, config, probe, steps: as for :func:`probe_to_h5`. folder: the output folder (it must exist).
        source: what the solid was sampled from (a mesh file), recorded as ``solid``.
        on_probe: called with (direction, that probe's :func:`probe_file_summary`) as each probe ends.
    Returns:
        A JSON-able summary: ``solid`` (``source``), ``solid_particles``, ``particle_radius`` (m), ``steps``, ``dt``
        (s) and ``probes``: per direction its :func:`probe_file_summary`.
    """
    folder = Path(folder)
    summary = {
        "solid": source,
        "solid_particles": len(solid),
        "particle_radius": config.particle_radius,
        "steps": steps,
        "dt": config.dt,
        "probes": {},
    }
    for d in probe.directions:
        s = summary["probes"][d] = probe_file_summary(
            *probe_to_h5(solid, d, config, probe, steps, folder / f"probe_{d}.h5")
        )
        if on_probe is not None:
            on_probe(d, s)
    return summary
