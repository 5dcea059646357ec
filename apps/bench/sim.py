"""`fluidgs bench sim`: the paper-scale probe, timed, and side by side with SPlisHSPlasH when installed.

Scene: a solid sphere of radius 1 m filled at spacing 0.05 (about 33k
particles), a 1 m thick slab flowing -x at 3 m/s (about 58k fluid particles), r = 0.025, dt = 0.002,
closed walls. It prints particle counts, the median ms per step over steps 2..N, a breakdown by
stage, solver iterations and peak memory. Quote ratios, not absolute times: machines are shared.
"""

from __future__ import annotations

import argparse
import resource
import statistics
import time
from pathlib import Path

import numpy as np

from ..options.common import add_device_option, add_json_option
from ..options.numbers import int_in, step_count
from ..runtime import thread_count


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--steps", type=step_count, default=100, help="time steps to time (default: 100)")
    p.add_argument("--threads", type=thread_count, default=2, help="CPU threads for both engines (default: 2)")
    add_device_option(p, "compute device (default: cpu)")
    p.add_argument(
        "--no-peer", action="store_true", help="skip the SPlisHSPlasH comparison even when pysplishsplash is installed"
    )
    p.add_argument(
        "--no-divergence-warm-start",
        action="store_true",
        help="our engine: start the divergence solver cold (solver.divergence_warm_start = false; one "
        "list pass fewer per step); SPlisHSPlasH always warm-starts (default: warm start)",
    )
    p.add_argument(
        "--rounds",
        type=int_in(1, 1000),
        default=1,
        help="run the engines this many times, alternating, and also print each round's ratio and the "
        "ratio of each engine's fastest round (shared, noisy machines; default: 1)",
    )
    add_json_option(p, type=str)


def run_ours(scene, steps: int, divergence_warm_start: bool = True) -> dict:
    """Time ``steps`` steps of this engine on the peer scene (:mod:`nbv.bench.splash`); figures in ms and MiB."""
    from nbv.bench.splash import peer_config, peer_particles, peer_solver

    cfg = peer_config(scene, divergence_warm_start)
    particles = peer_particles(scene, cfg.spacing)
    t0 = time.perf_counter()
    solver = peer_solver(scene, particles, cfg)
    setup_s = time.perf_counter() - t0
    times, hist = [], []
    solver.stage_times = {}
    for k in range(steps):
        if k == 1:
            solver.stage_times = {}
        t = time.perf_counter()
        hist.append(solver.step())
        times.append(time.perf_counter() - t)
    stages = {k: 1e3 * v / max(steps - 1, 1) for k, v in solver.stage_times.items()}
    return {
        "fluid_particles": solver.fluid.capacity,
        "solid_particles": len(particles.solid),
        "wall_particles": len(particles.walls),
        "steps": steps,
        "setup_s": setup_s,
        "first_step_ms": 1e3 * times[0],
        "median_ms_steps_2_to_n": 1e3 * statistics.median(times[1:]),
        "fluid_particle_steps_per_s": solver.fluid.capacity / statistics.median(times[1:]),
        "mean_ms_per_stage": stages,
        "density_iterations_mean": float(np.mean([h.density_iterations for h in hist[1:]])),
        "divergence_iterations_mean": float(np.mean([h.divergence_iterations for h in hist[1:]])),
        "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
    }


def _more_rounds(args: argparse.Namespace, scene, ours: dict, peer: dict, run_splash) -> list[dict]:
    """Rounds 2..N of both engines, alternating; prints each round's ratio and the ratio of the fastest rounds."""
    rounds = [{"ours_ms": ours["median_ms_steps_2_to_n"], "peer_ms": peer["median_ms_steps_2_to_n"]}]
    for k in range(2, args.rounds + 1):
        o = run_ours(scene, args.steps, divergence_warm_start=not args.no_divergence_warm_start)
        q = run_splash(scene)
        rounds.append({"ours_ms": o["median_ms_steps_2_to_n"], "peer_ms": q["median_ms_steps_2_to_n"]})
        print(
            f"round {k}: ours {rounds[-1]['ours_ms']:.1f} ms, SPlisHSPlasH {rounds[-1]['peer_ms']:.1f} ms, "
            f"ratio {rounds[-1]['ours_ms'] / rounds[-1]['peer_ms']:.2f}"
        )
    for r in rounds:
        r["ratio"] = r["ours_ms"] / r["peer_ms"]
    ratios = sorted(r["ratio"] for r in rounds)
    best = min(r["ours_ms"] for r in rounds) / min(r["peer_ms"] for r in rounds)
    print(
        f"over {len(rounds)} rounds: ratio {ratios[0]:.2f}-{ratios[-1]:.2f} "
        f"(median {statistics.median(ratios):.2f}); fastest round of each engine: {best:.2f}  "
        f"{target_verdict(statistics.median(ratios))}"
    )
    return rounds


# The engine's target: at most a quarter of SPlisHSPlasH's step time on the bench scene (about 3 M fluid
# particle-steps/s on 2 cores). The release of 2026-11-23 met 0.5; docs/performance.md has the history.
RATIO_TARGET = 0.25


def target_verdict(ratio: float) -> str:
    """``(target <= 0.25: met)`` or ``(... not met)`` for a ratio of step times, ours / SPlisHSPlasH's."""
    return f"(target <= {RATIO_TARGET}: {'met' if ratio <= RATIO_TARGET else 'not met'})"


def run_command(args: argparse.Namespace) -> int:
    from fluidsim.files import write_json_atomic
    from nbv.bench.splash import PeerScene, run_splash, splash_available

    from ..options import check_output_file
    from ..runtime import init_taichi

    if args.json:
        check_output_file(Path(args.json), (".json",))
    if args.steps < 2:
        raise ValueError(f"--steps must be >= 2, got {args.steps}")
    device = init_taichi(args.device, "f32", args.threads)
    scene = PeerScene(steps=args.steps, threads=args.threads)
    ours = run_ours(scene, args.steps, divergence_warm_start=not args.no_divergence_warm_start)
    report = {
        "device": device,
        "threads": args.threads,
        "fluidgaussian": ours,
        "divergence_warm_start": not args.no_divergence_warm_start,
    }
    cold = ", divergence solver not warm-started" if args.no_divergence_warm_start else ""
    print(f"FluidGaussian DFSPH ({device}, {args.threads} threads{cold})")
    print(
        f"  particles: {ours['fluid_particles']} fluid, {ours['solid_particles']} solid, {ours['wall_particles']} wall"
    )
    print(f"  first step (JIT compile or cache load): {ours['first_step_ms']:.0f} ms")
    print(
        f"  median over steps 2..{args.steps}: {ours['median_ms_steps_2_to_n']:.1f} ms/step "
        f"({1e3 / ours['median_ms_steps_2_to_n']:.2f} steps/s, "
        f"{ours['fluid_particle_steps_per_s'] / 1e6:.2g} M fluid particle-steps/s)"
    )
    print("  stages (mean ms/step): " + ", ".join(f"{k} {v:.1f}" for k, v in ours["mean_ms_per_stage"].items()))
    print(
        f"  solver iterations (mean): density {ours['density_iterations_mean']:.2f}, "
        f"divergence {ours['divergence_iterations_mean']:.2f}"
    )
    print(f"  peak memory: {ours['peak_rss_mib']:.0f} MiB")
    if not args.no_peer:
        if splash_available():
            peer = run_splash(scene)
            report["splishsplash"] = {k: v for k, v in peer.items() if k != "ms_per_step"}
            ratio = ours["median_ms_steps_2_to_n"] / peer["median_ms_steps_2_to_n"]
            report["ratio_ours_over_splishsplash"] = ratio
            print(f"SPlisHSPlasH {peer.get('version', '?')} DFSPH ({args.threads} threads)")
            print(f"  particles: {peer['fluid_particles']} fluid, {peer['boundary_particles']} boundary")
            print(f"  median over steps 2..{args.steps}: {peer['median_ms_steps_2_to_n']:.1f} ms/step")
            print(f"ratio (ours / SPlisHSPlasH step time): {ratio:.2f}  {target_verdict(ratio)}")
            if args.rounds > 1:
                report["rounds"] = _more_rounds(args, scene, ours, peer, run_splash)
        else:
            print("SPlisHSPlasH: pysplishsplash not installed (pip install '.[bench]'); no comparison")
    if args.json:
        write_json_atomic(Path(args.json), report)
    return 0
