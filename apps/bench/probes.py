"""`fluidgs bench probes`: one probe run profiled, and stop rules judged against it (docs/performance.md).

Runs the five probes (``--quick`` setting by default: r = 0.035 m, 750 steps) and, unless ``--no-empty``, the five
empty-scene probes on one Gaussian set, all to the end, with the solver's stages timed
(:func:`nbv.bench.probe_profile.trace_probes`). Prints per probe: the fluid particles, the steps, the mean
density / divergence iterations, the seconds of the neighbourhood pass, the divergence and density solves, D_i, the
forces, the rest of the step and the per-Gaussian aggregation; the step from which the running D_g^(IC) stays within
1 % and 5 % of its final value; and the share of the slab that ever came within reach of a Gaussian.

Then it judges stop rules (``--tolerances``, ``--window``, ``--min-steps``; :mod:`nbv.physics.early_stop`) and fixed
shorter runs (``--fixed``) against the uncut run, with the kept-cut criteria: the view ranking (S(T) of
``--cameras`` orbit cameras, depth-tested) at Spearman >= 0.97, the per-Gaussian D_g at >= 0.9, and D-bar /
D-bar_empty moved by <= 5 %.
"""

from __future__ import annotations

import argparse
import logging
import resource
import time
from dataclasses import asdict
from pathlib import Path

from ..options.common import (
    AHMED_GAUSSIANS,
    add_gaussians_option,
    add_json_option,
    add_probe_size_options,
    add_up_option,
)
from ..options.numbers import int_in, positive_number, step_list, tolerance_list
from ..runtime import positive_int, thread_count


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_gaussians_option(p, f"Gaussian set (default: {AHMED_GAUSSIANS.name})")
    add_up_option(p, "the scene's up direction (COLMAP captures: -y)", alias=False)
    add_probe_size_options(
        p, "r in m (default: the --quick preset's)", "steps per probe (default: the --quick preset's)"
    )
    p.add_argument("--dt", type=positive_number, default=0.002, help="time step, s (default: 0.002)")
    p.add_argument("--no-empty", action="store_true", help="leave out the empty-scene probes")
    p.add_argument("--every", type=positive_int, default=25, help="record the running D_g every this many steps")
    p.add_argument("--cameras", type=positive_int, default=24, help="orbit cameras the view ranking is judged on")
    p.add_argument(
        "--tolerances",
        type=tolerance_list,
        default="0.005,0.01,0.02,0.03,0.05",
        help="stop-rule tolerances to judge (relative L1 change of the running D_g per window)",
    )
    p.add_argument("--window", type=positive_int, default=50, help="stop rule: steps between checks")
    p.add_argument("--min-steps", type=int, default=150, help="stop rule: no stop before this many steps")
    p.add_argument("--fixed", type=step_list, default="300,400,500,600", help="fixed shorter runs to judge (steps)")
    p.add_argument(
        "--replica",
        type=int,
        default=0,
        help="lay the solid lattice (and so the probes) at replica K's offset (nbv.physics.replicas): with --against "
        "the uncut run, the noise floor of the criteria (the same physics on a lattice shifted by a fraction of a "
        "spacing)",
    )
    p.add_argument(
        "--margin",
        type=float,
        default=None,
        help="how far the slabs span past the solid across the flow, as a fraction of the solid's largest extent "
        "(default: the probes' 0.15); with --against the uncut run, what trimming the slab changes",
    )
    p.add_argument(
        "--rounding",
        type=int_in(0, 100),
        default=0,
        help="run the uncut probes this many more times with the time step nudged by a millionth of itself (a few "
        "float32 ulps: the same physics, other roundings) and judge each cut against how far that alone moves the "
        "answer; each run costs as long as the first",
    )
    p.add_argument("--threads", type=thread_count, default=2, help="CPU threads")
    add_json_option(p)
    p.add_argument(
        "--save",
        type=Path,
        default=None,
        help="write the traces (running D_g per probe at every checkpoint, covariances, view scores) to this .npz",
    )
    p.add_argument(
        "--against",
        type=Path,
        default=None,
        help="judge this run's final answer against another run's --save .npz of the same Gaussians and cameras "
        "(another setting: step size, slab)",
    )


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def check_files(args: argparse.Namespace) -> None:
    """The outputs (--json, --save) and the saved run (--against), checked before any work: an unwritable output is
    exit 4, an output that is an input exit 2."""
    from fluidsim.files import check_input_file, check_not_input, check_writable
    from nbv.bench.probe_profile import npz_path

    from ..options import check_output_file

    if args.json is not None:
        check_output_file(args.json, (".json",))
    if args.save is not None:
        check_writable(npz_path(args.save))
    if args.against is not None:
        check_input_file(args.against, "--against", "pass the .npz that a --save run wrote")
    outputs = {"--json": args.json, "--save": None if args.save is None else npz_path(args.save)}
    check_not_input(outputs, {"--gaussians": args.gaussians, "--against": args.against})


def run_command(args: argparse.Namespace) -> int:
    from fluidsim.files import write_json_atomic
    from nbv.bench.probe_profile import (
        against_line,
        answer,
        cut_report,
        full_stops,
        judge_cuts,
        profile_report,
        rounding_floor,
        save_traces,
        trace_probes,
        trimmed_plan,
        view_scorer,
    )
    from nbv.orbit import Orbit, orbit_cameras
    from nbv.physics import QUICK, PhysicsConfig
    from nbv.physics.early_stop import StopRule
    from nbv.physics.plan import ProbePlan, RunFrame
    from nbv.physics.replicas import replica_offsets

    from ..options import load_gaussians_checked
    from ..runtime import init_taichi

    wall0, cpu0 = time.perf_counter(), _cpu()
    check_files(args)
    rules = [StopRule(tol, args.window, args.min_steps) for tol in args.tolerances]
    gaussians = load_gaussians_checked(args.gaussians)
    cfg = PhysicsConfig(
        particle_radius=args.particle_radius or QUICK["particle_radius"],
        steps=args.steps or QUICK["steps"],
        dt=args.dt,
        up=args.up,
    )
    init_taichi("cpu", cfg.precision, args.threads)
    frame = RunFrame.of(gaussians, cfg, str(args.gaussians))
    t0 = time.perf_counter()
    solid = frame.solidify(tuple(replica_offsets(args.replica + 1)[args.replica]) if args.replica else None)
    solidify_s = time.perf_counter() - t0
    plan = ProbePlan.of(solid.points, cfg)
    if args.margin is not None:  # the slabs trimmed (or grown) across the flow
        plan = trimmed_plan(plan, solid.points, cfg, args.margin)
    traces, setup_s = trace_probes(frame, plan, solid.points, every=args.every, empty=not args.no_empty)
    print(
        f"{args.gaussians.name} (up {args.up}): {frame.sim.num:,} Gaussians, solid {len(solid.points):,} particles, "
        f"r = {cfg.particle_radius} m, dt = {cfg.dt} s, {cfg.steps} steps; solidify {solidify_s:.1f} s, lists "
        f"{setup_s['lists']:.2f} s"
    )
    lines, rows = profile_report(traces)
    print("\n".join(lines))
    logging.getLogger("nbv.view_scoring").setLevel(logging.WARNING)  # one line per judged cut, not per scoring
    view_scores = view_scorer(gaussians, orbit_cameras(gaussians, cfg, Orbit(args.cameras)), frame.kept)
    d_g, ratio = answer(traces, full_stops(traces), frame.covariances)
    views = view_scores(d_g)
    uncut, empty = (d_g, ratio, views), not args.no_empty
    floor = rounding_floor(frame, plan, solid.points, uncut, args.rounding, view_scores, every=args.every, empty=empty)
    cuts = judge_cuts(traces, rules, args.fixed, frame.covariances, view_scores)
    lines, judged = cut_report(cuts, args.cameras, floor)
    print("\n".join(lines))
    if args.save is not None:
        save_traces(args.save, traces, frame.covariances, d_g, ratio, views, floor)
    if args.against is not None:
        print(against_line(args.against, d_g, ratio, views))
    print(f"whole command {time.perf_counter() - wall0:.1f} s wall, {_cpu() - cpu0:.1f} s CPU")
    if args.json is not None:
        write_json_atomic(
            args.json,
            {
                "source": str(args.gaussians),
                "up": args.up,
                "probes": rows,
                "cuts": judged,
                "particle_radius": cfg.particle_radius,
                "steps": cfg.steps,
                "dt": cfg.dt,
                "rounding_floor": None if floor is None else asdict(floor),
            },
        )
    return 0
