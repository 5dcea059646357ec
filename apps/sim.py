"""`fluidgs sim`: run a scene file and write the HDF5 result (frames, per-step stats, divergence sums)."""

from __future__ import annotations

import argparse
import logging
from dataclasses import replace
from pathlib import Path

from tqdm import tqdm

log = logging.getLogger("fluidgs")


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
    p.add_argument("--threads", type=int, default=None, help="CPU threads (default: all cores)")


def simulate_to_h5(solver, scene_dict: dict, output: Path, steps: int, save_every: int, desc: str,
                   progress: bool = True) -> tuple[Path, list]:
    """Step a built solver, writing frames every ``save_every`` steps; returns (path, stats history).

    A diverging run still writes its file (frames so far, stats, status naming the step) and re-raises.
    """
    from fluidsim.output import SimulationWriter
    from fluidsim.simulation import SimulationDiverged, run

    writer = SimulationWriter(output, scene_dict)
    writer.write_boundary(solver.boundary.x.to_numpy()[: solver.boundary.count])
    writer.write_frame(0, 0.0, solver.fluid_state())
    bar = tqdm(total=steps, desc=desc, unit="step", disable=not progress, leave=False)

    def on_step(s, st) -> None:
        last = st.step + 1 == steps
        if (save_every and (st.step + 1) % save_every == 0) or last:
            writer.write_frame(st.step + 1, st.time, s.fluid_state())

    def on_progress(st) -> None:
        bar.update(1)
        bar.set_postfix(density_it=st.density_iterations, divergence_it=st.divergence_iterations,
                        vmax=f"{st.max_speed:.2f}", fluid=st.active, refresh=False)

    try:
        history = run(solver, steps, on_step=on_step, progress=on_progress)
    except SimulationDiverged as exc:
        bar.close()
        sums, counts = solver.divergence_accumulation()
        path = writer.finish(exc.history, sums, counts, status=str(exc),
                             removed_inside_solid=solver.removed_inside_solid)
        log.error("%s; frames so far saved to %s", exc, path)
        raise
    except BaseException:
        bar.close()
        writer.abort()
        raise
    bar.close()
    sums, counts = solver.divergence_accumulation()
    path = writer.finish(history, sums, counts, removed_inside_solid=solver.removed_inside_solid)
    return path, history


def run_command(args: argparse.Namespace) -> int:
    from fluidsim.output import check_writable
    from fluidsim.scene import load_scene

    from .runtime import init_taichi

    scene = load_scene(args.scene)  # validated before any kernel runs
    if args.steps is not None:
        scene = scene.with_steps(args.steps)
    if args.save_every < 0:
        raise ValueError(f"--save-every must be >= 0, got {args.save_every}")
    if args.precision:
        scene = replace(scene, config=replace(scene.config, precision=args.precision))
    check_writable(args.output)
    init_taichi(args.device, scene.config.precision, args.threads)
    from fluidsim.simulation import SimulationDiverged, build_solver

    solver = build_solver(scene)
    log.info("%d fluid particles (%d removed inside solids), %d boundary particles", solver.fluid.capacity,
             solver.removed_inside_solid, solver.boundary.count)
    try:
        path, history = simulate_to_h5(solver, scene.to_dict(), args.output, scene.steps, args.save_every,
                                       desc=args.scene.name)
    except SimulationDiverged:
        return 3
    last = history[-1]
    print(f"wrote {path}: {len(history)} steps, t = {last.time:.3f} s, {last.active} fluid particles active, "
          f"{sum(s.retired for s in history)} retired, {solver.removed_inside_solid} removed inside solids")
    return 0
