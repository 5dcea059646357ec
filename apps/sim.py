"""`fluidgs sim`: run a scene file and write the HDF5 result (frames, per-step stats, divergence sums).

The file is complete whatever ends the run: a divergence (status names the step, exit 3), SIGINT (Ctrl-C, exit
130) or SIGTERM (``kill``, ``timeout``, batch schedulers; exit 143) close it at the next step boundary with the
frames so far, a last frame of the current state and status "interrupted", then rename it into place. A second
signal stops at once and drops the unfinished file.
"""

from __future__ import annotations

import argparse
import logging
import signal
import threading
from dataclasses import replace
from pathlib import Path

from tqdm import tqdm

from .runtime import positive_int

log = logging.getLogger("fluidgs")
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", type=Path, help="scene JSON file (format in README.md)")
    p.add_argument("-o", "--output", type=Path, required=True, help="output HDF5 file (written atomically)")
    p.add_argument("--steps", type=int, default=None, help="number of time steps (default: the scene's 'steps')")
    p.add_argument("--save-every", type=int, default=10,
                   help="write a frame every K steps (default: 10; 0 = first and last only)")
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                   help="compute device (default: cpu); cuda falls back to cpu with a notice")
    p.add_argument("--precision", choices=("f32", "f64"), default=None,
                   help="float precision of the particle arrays (default: the scene's solver.precision, f32)")
    p.add_argument("--threads", type=positive_int, default=None, help="CPU threads (default: all cores)")
    p.add_argument("--max-memory-gb", type=float, default=None,
                   help="refuse to start above this estimated memory in GiB (default: the available memory)")


class Interrupted(Exception):
    """The run was stopped by ``signum`` (SIGINT or SIGTERM) after ``step`` completed steps; its file is saved."""

    def __init__(self, signum: int, step: int, path: Path):
        self.signum, self.step, self.path = signum, step, path
        super().__init__(f"{signal.Signals(signum).name} after step {step}; the frames so far are saved to {path} "
                         "(status 'interrupted'); run again to overwrite it")

    @property
    def exit_code(self) -> int:
        """128 + the signal number: 130 for SIGINT, 143 for SIGTERM (the shell's convention)."""
        return 128 + int(self.signum)


class StopRequest:
    """While entered (main thread only), SIGINT and SIGTERM set ``signum`` instead of stopping the process, so
    the step loop can stop at a step boundary with a readable file. A second signal raises KeyboardInterrupt."""

    def __init__(self) -> None:
        self.signum: int | None = None
        self._old: dict[int, object] = {}

    def _handle(self, signum: int, frame) -> None:
        if self.signum is not None:  # asked twice: stop now
            self._restore()
            raise KeyboardInterrupt
        self.signum = signum
        log.warning("%s received: stopping after this step and saving the frames so far (send it again to stop "
                    "at once without saving)", signal.Signals(signum).name)

    def _restore(self) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)
        self._old.clear()

    def __enter__(self) -> StopRequest:
        if threading.current_thread() is threading.main_thread():
            self._old = {sig: signal.signal(sig, self._handle) for sig in STOP_SIGNALS}
        return self

    def __exit__(self, *exc) -> None:
        self._restore()


def simulate_to_h5(solver, scene_dict: dict, output: Path, steps: int, save_every: int, desc: str,
                   progress: bool = True, stop: StopRequest | None = None) -> tuple[Path, list]:
    """Step a built solver, writing frames every ``save_every`` steps; returns (path, stats history).

    A diverging run still writes its file (frames so far, stats, status naming the step) and re-raises. With
    ``stop`` (a :class:`StopRequest` entered by the caller), a signal ends the run at the next step boundary: the
    file gets the current state as a last frame, status "interrupted", and :class:`Interrupted` is raised.
    """
    from fluidsim.output import SimulationWriter
    from fluidsim.simulation import SimulationDiverged, run

    writer = SimulationWriter(output, scene_dict)
    history: list = []
    bar = tqdm(total=steps, desc=desc, unit="step", disable=not progress, leave=False)

    def on_step(s, st) -> None:
        last = st.step + 1 == steps
        if (save_every and (st.step + 1) % save_every == 0) or last:
            writer.write_frame(st.step + 1, st.time, s.fluid_state())
        if stop is not None and stop.signum is not None and not last:
            raise Interrupted(stop.signum, st.step + 1, writer.path)

    def on_progress(st) -> None:
        history.append(st)
        bar.update(1)
        bar.set_postfix(density_it=st.density_iterations, divergence_it=st.divergence_iterations,
                        vmax=f"{st.max_speed:.2f}", fluid=st.active, refresh=False)

    try:
        writer.write_boundary(solver.boundary.x.to_numpy()[: solver.boundary.count])
        writer.write_frame(0, 0.0, solver.fluid_state())
        history = run(solver, steps, on_step=on_step, progress=on_progress)
    except SimulationDiverged as exc:
        bar.close()
        sums, counts = solver.divergence_accumulation()
        path = writer.finish(exc.history, sums, counts, status=str(exc),
                             removed_inside_solid=solver.removed_inside_solid)
        log.error("%s; frames so far saved to %s", exc, path)
        raise
    except Interrupted as exc:
        bar.close()
        if writer.last_frame_step != exc.step:
            writer.write_frame(exc.step, history[-1].time, solver.fluid_state())
        sums, counts = solver.divergence_accumulation()
        writer.finish(history, sums, counts, status="interrupted", removed_inside_solid=solver.removed_inside_solid,
                      interrupted_by=signal.Signals(exc.signum).name, interrupted_after_step=exc.step)
        raise
    except BaseException:
        bar.close()
        writer.abort()
        raise
    bar.close()
    sums, counts = solver.divergence_accumulation()
    path = writer.finish(history, sums, counts, removed_inside_solid=solver.removed_inside_solid)
    return path, history


def scene_inputs(scene, scene_path: Path) -> dict[str, Path]:
    """The files a scene run reads: the scene JSON and each solid's points or mesh file (for the output check)."""
    inputs = {"SCENE": Path(scene_path)}
    for i, solid in enumerate(scene.solids):
        name = solid.points if solid.points is not None else solid.mesh
        inputs[f"solids[{i}] of {scene_path}"] = Path(scene.base_dir) / name
    return inputs


def run_command(args: argparse.Namespace) -> int:
    from fluidsim.memory import check_scene_memory
    from fluidsim.output import check_not_input, check_writable
    from fluidsim.scene import load_scene

    from .runtime import init_taichi

    scene = load_scene(args.scene)  # validated before any kernel runs
    if args.steps is not None:
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
    log.info("%d fluid particles (%d removed inside solids), %d boundary particles", solver.fluid.capacity,
             solver.removed_inside_solid, solver.boundary.count)
    try:
        with StopRequest() as stop:
            path, history = simulate_to_h5(solver, scene.to_dict(), args.output, scene.steps, args.save_every,
                                           desc=args.scene.name, stop=stop)
    except SimulationDiverged:
        return 3
    except Interrupted as exc:
        log.error("stopped by %s", exc)
        return exc.exit_code
    last = history[-1]
    print(f"wrote {path}: {len(history)} steps, t = {last.time:.3f} s, {last.active} fluid particles active, "
          f"{sum(s.retired for s in history)} retired, {solver.removed_inside_solid} removed inside solids")
    return 0
