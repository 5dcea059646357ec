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
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..options.common import (
    AHMED_GAUSSIANS,
    add_gaussians_option,
    add_json_option,
    add_probe_size_options,
    add_up_option,
)
from ..options.numbers import positive_number, step_list, tolerance_list
from ..runtime import positive_int, thread_count

STAGES = ("neighbors", "divergence_solve", "density_solve", "divergence_estimate", "forces")


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


def print_profile(traces) -> list[dict]:
    """Print one line per probe (fluid, steps, iterations, seconds per stage, convergence, reach) and the shares of
    all probes; returns the rows for the JSON."""
    from nbv.bench.probe_profile import converged_step

    head = "probe       fluid steps  it d/v   nbhd  divS  densS  D_i  force  rest  aggr  total  D_g 1%/5%  reached"
    print(head)
    rows = []
    for t in traces:
        st = t.stage_s
        rest = sum(st.values()) - sum(st.get(k, 0.0) for k in STAGES)
        name = ("empty " if t.empty else "") + t.direction
        c1, c5 = converged_step(t, 0.01), converged_step(t, 0.05)
        print(
            f"{name:<9} {t.fluid:>7} {t.steps:>5} {t.density_iterations:4.2f}/{t.divergence_iterations:4.2f} "
            + " ".join(f"{st.get(k, 0.0):5.1f}" for k in STAGES)
            + f" {rest:5.1f} {t.aggregation_s:5.1f} {t.wall_s:6.1f}  {c1:>4}/{c5:<4}  {100 * t.reached:5.1f} %"
        )
        rows.append(
            {
                "probe": name,
                "fluid": t.fluid,
                "steps": t.steps,
                "density_iterations": t.density_iterations,
                "divergence_iterations": t.divergence_iterations,
                "stage_s": st,
                "aggregation_s": t.aggregation_s,
                "wall_s": t.wall_s,
                "converged_1pct": c1,
                "converged_5pct": c5,
                "reached": t.reached,
                "reached_by": t.reached_by,
                "touched": t.touched,
            }
        )
    total = sum(t.wall_s for t in traces)
    agg = sum(t.aggregation_s for t in traces)
    stage_tot = {k: sum(t.stage_s.get(k, 0.0) for t in traces) for k in STAGES}
    print(
        f"all probes {total:.1f} s: "
        + ", ".join(f"{k} {100 * v / total:.0f} %" for k, v in stage_tot.items())
        + f", aggregation {100 * agg / total:.0f} %"
    )

    return rows


def print_cuts(args: argparse.Namespace, traces, cov, view_scores) -> list[dict]:
    """Judge each stop rule and fixed length against the uncut run; print one line per cut and return the rows."""
    from nbv.bench.probe_profile import judge_rule, judge_stops
    from nbv.physics.early_stop import StopRule

    print(
        f"judged against the uncut run on {args.cameras} orbit cameras (depth test); kept when views >= 0.97, "
        "D_g >= 0.9, ratio move <= 5 %"
    )
    print("cut                      stops (per probe)               steps run  views  D_g    ratio   kept")
    judged = []
    cuts = [
        (f"rule tol {tol:g}", judge_rule(traces, StopRule(tol, args.window, args.min_steps), cov, view_scores))
        for tol in args.tolerances
    ]
    for n in args.fixed:
        stops = {t.direction: n for t in traces if not t.empty}
        cuts.append((f"fixed {n}", judge_stops(traces, stops, cov, view_scores)))
    for name, j in cuts:
        stops = " ".join(f"{d}:{s}" for d, s in j.stops.items())
        print(
            f"{name:<18} {stops:<38} {100 * j.step_share:5.1f} %  {j.view_spearman:.3f}  {j.dg_spearman:.3f}  "
            f"{100 * j.ratio_move:5.2f} %  {'yes' if j.kept else 'no'}"
        )
        judged.append(
            {
                "cut": name,
                "stops": j.stops,
                "step_share": j.step_share,
                "view_spearman": j.view_spearman,
                "dg_spearman": j.dg_spearman,
                "ratio_move": j.ratio_move,
                "kept": j.kept,
            }
        )
    return judged


def save_and_compare(args: argparse.Namespace, traces, cov, d_g, ratio, views) -> None:
    """``--save``: this run's answer and running means as .npz; ``--against``: its agreement with a saved one."""
    from nbv.ranking import spearman

    if args.save is not None:
        np.savez(
            args.save,
            covariances=cov,
            d_g=d_g,
            ratio=ratio,
            views=views,
            **{f"{'empty' if t.empty else 'solid'}{t.direction}": np.stack(t.means) for t in traces},
            **{f"steps{'empty' if t.empty else 'solid'}{t.direction}": np.asarray(t.checkpoints) for t in traces},
        )
    if args.against is not None:
        other = np.load(args.against)
        print(
            f"against {args.against.name}: views Spearman {spearman(views, other['views']):.3f}, D_g Spearman "
            f"{spearman(d_g, other['d_g']):.3f}, D-bar / D-bar_empty {ratio:.4g} against {float(other['ratio']):.4g} "
            f"(moved {100 * abs(ratio / float(other['ratio']) - 1):.2f} %)"
        )


def run_command(args: argparse.Namespace) -> int:
    from fluidsim.files import write_json_atomic
    from fluidsim.probes import probe_setups
    from nbv.bench.probe_profile import answer, trace_probes
    from nbv.orbit import Orbit, orbit_cameras
    from nbv.physics import QUICK, PhysicsConfig
    from nbv.physics.plan import ProbePlan, RunFrame
    from nbv.physics.replicas import replica_offsets
    from nbv.view_scoring import project_scores

    from ..options import load_gaussians_checked
    from ..runtime import init_taichi

    wall0, cpu0 = time.perf_counter(), _cpu()
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
        extent = float(np.ptp(solid.points, axis=0).max() + 2 * cfg.particle_radius)
        probe = replace(cfg.probe_config(), margin=args.margin * extent)
        plan = ProbePlan(probe_setups(solid.points, probe, plan.spacing, cfg.directions), plan.spacing)
    traces, setup_s = trace_probes(frame, plan, solid.points, every=args.every, empty=not args.no_empty)
    print(
        f"{args.gaussians.name} (up {args.up}): {frame.sim.num:,} Gaussians, solid {len(solid.points):,} particles, "
        f"r = {cfg.particle_radius} m, dt = {cfg.dt} s, {cfg.steps} steps; solidify {solidify_s:.1f} s, lists "
        f"{setup_s['lists']:.2f} s"
    )
    rows = print_profile(traces)
    logging.getLogger("nbv.view_scoring").setLevel(logging.WARNING)  # one line per judged cut, not per scoring
    cams = orbit_cameras(gaussians, cfg, Orbit(args.cameras))
    kept = frame.kept

    def view_scores(values: np.ndarray) -> np.ndarray:
        full = values if kept is None else np.zeros(len(kept))
        if kept is not None:
            full[kept] = values
        return project_scores(gaussians, cams, full, occlusion=True).scores.numpy()

    judged = print_cuts(args, traces, frame.covariances, view_scores)
    final = {t.direction: t.checkpoints[-1] for t in traces}
    cov = frame.covariances
    d_g, ratio = answer(traces, final, cov)
    views = view_scores(d_g)
    save_and_compare(args, traces, cov, d_g, ratio, views)
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
            },
        )
    return 0
