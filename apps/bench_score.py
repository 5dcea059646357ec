"""`fluidgs bench score`: time the probes on Gaussians, simulation and per-Gaussian aggregation separately.

By default the ``--quick`` preset (r = 0.05 m, 300 steps) runs the five probes on the bundled asset
(``assets/ahmed_gaussians.ply``; 4,000 Gaussians sampled on the Ahmed body mesh when it is not there) and
prints particle counts, steps per second, solver iterations, the aggregation's share of the step time
(target < 10 %) and the five-probe total (target < 60 s on the 2-core CPU). ``--paper`` uses r = 0.025 m
and 750 steps (add ``--directions -x`` for one probe). Machines are shared: quote ratios.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from .runtime import positive_int

ASSET = Path(__file__).resolve().parent.parent / "assets" / "ahmed_gaussians.ply"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--gaussians", type=Path, default=None,
                   help=f"Gaussian set (default: {ASSET.name} when present, else 4,000 Gaussians on the Ahmed body "
                        "surface)")
    p.add_argument("--paper", action="store_true", help="paper setting: r = 0.025 m, 750 steps (default: quick preset)")
    p.add_argument("--particle-radius", type=float, default=None,
                   help="particle radius r in m (default: 0.05, or 0.025 with --paper)")
    p.add_argument("--steps", type=int, default=None, help="steps per probe (default: 300, or 750 with --paper)")
    p.add_argument("--directions", default="-x,+x,-z,+z,-y", help="comma list of probes")
    p.add_argument("--empty-reference", action="store_true", help="also time the empty-scene reference runs")
    p.add_argument("--no-fill", action="store_true", help="keep the solid hollow (filling is the default)")
    p.add_argument("--fill-cavities", action="store_true",
                   help="accepted for old scripts and does nothing: filling is now the default (see --no-fill)")
    p.add_argument("--threads", type=positive_int, default=2, help="CPU threads")
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                   help="compute device; cuda falls back to cpu with a logged warning")
    p.add_argument("--json", type=Path, default=None, help="also write the figures to this JSON file")


def run_command(args: argparse.Namespace) -> int:
    from fluidsim.output import check_not_input
    from nbv.physics import QUICK, PhysicsConfig, parse_directions, simulate_gaussians

    from .demo import ahmed_surface_gaussians
    from .runtime import init_taichi
    from .simulate import check_output_file, load_gaussians_checked, write_json

    if args.json is not None:
        check_output_file(args.json, (".json",))
        check_not_input({"--json": args.json}, {"--gaussians": args.gaussians})
    path = args.gaussians or (ASSET if ASSET.is_file() else None)
    gaussians = load_gaussians_checked(path) if path is not None else ahmed_surface_gaussians()
    radius = args.particle_radius or (0.025 if args.paper else QUICK["particle_radius"])
    steps = args.steps or (750 if args.paper else QUICK["steps"])
    cfg = PhysicsConfig(particle_radius=radius, steps=steps, directions=parse_directions(args.directions),
                        empty_reference=args.empty_reference, fill_cavities=not args.no_fill)
    init_taichi(args.device, cfg.precision, args.threads)
    res = simulate_gaussians(gaussians, cfg, progress=True, source=str(path or "Ahmed body surface samples"))
    t = res.timings
    total_steps = steps * len(cfg.directions)
    share = t["aggregation"] / max(t["simulation"], 1e-12)
    print(f"Gaussians: {res.num_gaussians} ({path or 'Ahmed body surface samples'}), solid particles {len(res.solid)}, "
          f"r = {radius} m, {steps} steps x {len(cfg.directions)} probes")
    for d in cfg.directions:
        st = res.stats[d]
        print(f"  probe {d:>3}: {int(st['active'][0])} fluid particles, density/divergence iterations "
              f"{np.mean(st['density_iterations']):.2f}/{np.mean(st['divergence_iterations']):.2f}")
    print(f"simulation {t['simulation']:.2f} s ({total_steps / max(t['simulation'], 1e-12):.1f} steps/s), "
          f"aggregation {t['aggregation']:.3f} s (+{t['accumulator_setup']:.3f} s grid set-up), "
          f"solidify {t['solidify']:.2f} s")
    print(f"aggregation share of the step time: {100 * share:.1f} % (target < 10 %): "
          f"{'met' if share < 0.10 else 'NOT met'}")
    total = t["total"] - t["empty_reference"]
    label = "paper-setting" if args.paper else "quick"
    print(f"{label} total for {len(cfg.directions)} probes: {total:.1f} s"
          + ("" if args.paper else f" (target < 60 s for five probes): {'met' if total < 60 else 'NOT met'}"))
    if args.empty_reference:
        print(f"empty-scene reference: {t['empty_reference']:.1f} s more")
    if args.json is not None:
        write_json(args.json, {"timings": t, "aggregation_share": share, "steps": steps, "particle_radius": radius,
                               "directions": list(cfg.directions), "gaussians": res.num_gaussians,
                               "solid": len(res.solid)})
    return 0
