"""`fluidgs sim`: run a scene file and write the HDF5 result (frames, per-step stats, divergence sums).

The file is complete whatever ends the run: a divergence (status names the step, exit 3), SIGINT (Ctrl-C, exit
130) or SIGTERM (``kill``, ``timeout``, batch schedulers; exit 143) close it at the next step boundary with the
frames so far, a last frame of the current state and status "interrupted", then rename it into place. A second
signal stops at once and drops the unfinished file. A full disk keeps the frames written before it: the file is
finished with them and status "disk full", and the command ends with one line naming it and the fix (exit 4).
"""

from __future__ import annotations

import argparse
import logging
import signal
import threading
from dataclasses import replace
from pathlib import Path

from .options.common import add_device_option, add_output_option
from .runtime import thread_count
from .signals import Stopped, handled_signals, note_signal

log = logging.getLogger("fluidgs")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", type=Path, help="scene JSON file (format in README.md)")
    add_output_option(p, "output HDF5 file (written atomically)")
    p.add_argument("--steps", type=int, default=None, help="number of time steps (default: the scene's 'steps')")
    p.add_argument(
        "--save-every", type=int, default=10, help="write a frame every K steps (default: 10; 0 = first and last only)"
    )
    add_device_option(p, "compute device (default: cpu); cuda falls back to cpu with a notice")
    p.add_argument(
        "--precision",
        choices=("f32", "f64"),
        default=None,
        help="float precision of the particle arrays (default: the scene's solver.precision, f32)",
    )
    p.add_argument("--threads", type=thread_count, default=None, help="CPU threads (default: all cores)")
    p.add_argument(
        "--max-memory-gb",
        type=float,
        default=None,
        help="refuse to start above this estimated memory in GiB (default: the available memory)",
    )


class StopRequest:
    """While entered (main thread only), SIGINT, SIGTERM and SIGHUP set ``signum`` instead of stopping the process, so
    the step loop can stop at a step boundary with a readable file. A second signal raises
    :class:`apps.signals.Stopped` with the first signal (exit 130 or 143); the unfinished file is then removed."""

    def __init__(self) -> None:
        self.signum: int | None = None
        self._old: dict[int, object] = {}

    def _handle(self, signum: int, frame) -> None:
        note_signal(signum)
        if self.signum is not None:  # asked twice: stop now, with the first signal's exit code
            self._restore()
            raise Stopped(self.signum)
        self.signum = signum
        log.warning(
            "%s received: stopping after this step and saving the frames so far (send it again to stop "
            "at once without saving)",
            signal.Signals(signum).name,
        )

    def _restore(self) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)
        self._old.clear()

    def __enter__(self) -> StopRequest:
        if threading.current_thread() is threading.main_thread():
            self._old = {sig: signal.signal(sig, self._handle) for sig in handled_signals()}
        return self

    def __exit__(self, *exc) -> None:
        self._restore()


def scene_inputs(scene, scene_path: Path) -> dict[str, Path]:
    """The files a scene run reads: the scene JSON and each solid's points or mesh file (for the output check)."""
    inputs = {"SCENE": Path(scene_path)}
    for i, solid in enumerate(scene.solids):
        name = solid.points if solid.points is not None else solid.mesh
        inputs[f"solids[{i}] of {scene_path}"] = Path(scene.base_dir) / name
    return inputs


def run_command(args: argparse.Namespace) -> int:
    from fluidsim.config import MAX_STEPS
    from fluidsim.files import check_not_input, check_writable
    from fluidsim.memory import check_scene_memory
    from fluidsim.recording import FramesKept, Interrupted, simulate_to_h5
    from fluidsim.scene import load_scene

    from .exit_codes import EXIT_OUTPUT
    from .runtime import init_taichi

    scene = load_scene(args.scene)  # validated before any kernel runs
    if args.steps is not None:
        if args.steps < 1:  # the option, not the scene key it overrides
            raise ValueError(f"--steps must be an integer >= 1 time step, got {args.steps}")
        if args.steps > MAX_STEPS:
            raise ValueError(f"--steps must be at most {MAX_STEPS:,} time steps (the paper's 750), got {args.steps}")
        scene = scene.with_steps(args.steps)
    if args.save_every < 0:
        raise ValueError(f"--save-every must be >= 0, got {args.save_every}")
    if args.precision:
        scene = replace(scene, config=replace(scene.config, precision=args.precision))
    check_scene_memory(scene, args.max_memory_gb, where=f"scene {args.scene}")  # before any particle is made
    check_not_input({"-o": args.output}, scene_inputs(scene, args.scene))
    check_writable(args.output)
    init_taichi(args.device, scene.config.precision, args.threads)
    from fluidsim.simulation import SimulationDiverged, build_solver, check_solver_time_step

    solver = build_solver(scene)
    check_solver_time_step(solver, scene.steps, where=f"scene {args.scene}")
    log.info(
        "%d fluid particles (%d removed inside solids), %d boundary particles",
        solver.fluid.capacity,
        solver.removed_inside_solid,
        solver.boundary.count,
    )
    try:
        with StopRequest() as stop:
            path, history = simulate_to_h5(
                solver, scene.to_dict(), args.output, scene.steps, args.save_every, desc=args.scene.name, stop=stop
            )
    except SimulationDiverged:
        return 3
    except Interrupted as exc:
        log.error("stopped by %s", exc)
        return exc.exit_code
    except FramesKept as exc:
        log.error("%s", exc)
        return EXIT_OUTPUT
    if stop.signum is not None:  # the signal came during the last step or the final write: the file is complete
        log.error("stopped by %s after the last step; %s is complete", signal.Signals(stop.signum).name, path)
        return 128 + stop.signum
    last = history[-1]
    print(
        f"wrote {path}: {len(history)} steps, t = {last.time:.3f} s, {last.active} fluid particles active, "
        f"{sum(s.retired for s in history)} retired, {solver.removed_inside_solid} removed inside solids"
    )
    if solver.boundary.solid_count:
        from fluidsim.forces import force_history

        f = force_history(history)["solid"]
        mean, imp = f["mean"], f["impulse"]
        print(
            f"force on the solids (N, simulation frame, time mean over steps {len(history) // 2}-{len(history)}): "
            f"({mean[0]:.3g}, {mean[1]:.3g}, {mean[2]:.3g}); impulse ({imp[0]:.3g}, {imp[1]:.3g}, {imp[2]:.3g}) N s"
        )
        if not f["series"].any():
            print("  WARNING: the fluid never reached the solids: their force is 0")
    return 0
