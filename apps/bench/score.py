"""`fluidgs bench score`: time the probes on Gaussians, simulation and per-Gaussian aggregation separately.

By default the ``--quick`` preset (r = 0.05 m, 300 steps) runs the five probes on the bundled asset
(``assets/ahmed_gaussians.ply``; 4,000 Gaussians sampled on the Ahmed body mesh when it is not there) and
prints particle counts, steps per second, solver iterations, the aggregation's share of the step time
(target < 10 %), the five-probe total (target < 60 s on the 2-core CPU) and the peak resident memory. ``--paper``
uses r = 0.025 m and 750 steps (add ``--directions -x`` for one probe). Machines are shared: quote ratios.

``--densify K`` also runs a K x denser set of the same object, in the same process after the set itself: K - 1
jittered copies of every Gaussian (its mean moved by ``--jitter`` standard deviations along its own axes, all other
attributes kept) added to the original; the ratio of the two runs' times is printed (``--densify-only`` skips the
original's run, so that the peak memory is the dense set's alone; :func:`nbv.bench.dense_sets.jittered_copies`).
"""

from __future__ import annotations

import argparse

from ..options.common import (
    AHMED_GAUSSIANS,
    add_device_option,
    add_gaussians_option,
    add_json_option,
    add_probe_size_options,
    add_seed_option,
    add_up_option,
)
from ..runtime import positive_int, thread_count


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_gaussians_option(
        p,
        f"Gaussian set (default: {AHMED_GAUSSIANS.name} when present, else 4,000 Gaussians on the Ahmed body surface)",
        default=None,
    )
    p.add_argument("--paper", action="store_true", help="paper setting: r = 0.025 m, 750 steps (default: quick preset)")
    add_probe_size_options(
        p,
        "particle radius r in m (default: 0.05, or 0.025 with --paper)",
        "steps per probe (default: 300, or 750 with --paper)",
    )
    p.add_argument("--directions", default="-x,+x,-z,+z,-y", help="comma list of probes")
    p.add_argument("--empty-reference", action="store_true", help="also time the empty-scene reference runs")
    p.add_argument("--no-fill", action="store_true", help="keep the solid hollow (filling is the default)")
    p.add_argument("--threads", type=thread_count, default=2, help="CPU threads")
    add_device_option(p)
    add_json_option(p)
    add_up_option(p)
    p.add_argument(
        "--densify",
        type=positive_int,
        default=None,
        metavar="K",
        help="also time a K x denser copy of the set (K - 1 jittered copies added), same object",
    )
    p.add_argument(
        "--jitter",
        type=float,
        default=0.5,
        help="--densify: each copy's means move by this many standard deviations along the Gaussian's "
        "axes (default: 0.5)",
    )
    p.add_argument(
        "--densify-only", action="store_true", help="--densify: time only the dense set (its peak memory alone)"
    )
    add_seed_option(p, "--densify: random seed of the jitter")


def _time_set(gaussians, cfg, paper: bool, source: str) -> dict:
    """Run the probes on one set, print its figures and return them (timings, share, peak memory)."""
    from nbv.bench.probe_timing import set_report
    from nbv.physics import simulate_gaussians

    from .yardsticks import peak_rss_bytes

    res = simulate_gaussians(gaussians, cfg, progress=True, source=source)
    lines, figures = set_report(res, cfg, paper, source, peak_rss_bytes())
    print("\n".join(lines))
    return figures


def run_command(args: argparse.Namespace) -> int:
    from fluidsim.files import check_not_input
    from fluidsim.files import write_json_atomic as write_json
    from nbv.bench.dense_sets import jittered_copies
    from nbv.physics import QUICK, PhysicsConfig, parse_directions
    from recon.ahmed import ahmed_surface_gaussians

    from ..options import check_output_file, load_gaussians_checked
    from ..runtime import init_taichi

    if args.json is not None:
        check_output_file(args.json, (".json",))
        check_not_input({"--json": args.json}, {"--gaussians": args.gaussians})
    if args.densify_only and args.densify is None:
        raise ValueError("--densify-only needs --densify K")
    path = args.gaussians or (AHMED_GAUSSIANS if AHMED_GAUSSIANS.is_file() else None)
    gaussians = load_gaussians_checked(path) if path is not None else ahmed_surface_gaussians()
    dense = None if args.densify is None else jittered_copies(gaussians, args.densify, args.jitter, args.seed)
    radius = args.particle_radius or (0.025 if args.paper else QUICK["particle_radius"])
    steps = args.steps or (750 if args.paper else QUICK["steps"])
    cfg = PhysicsConfig(
        particle_radius=radius,
        steps=steps,
        directions=parse_directions(args.directions),
        empty_reference=args.empty_reference,
        empty_cache=False,  # a benchmark times the empty scene simulated
        fill_cavities=not args.no_fill,
        up=args.up,
    )
    init_taichi(args.device, cfg.precision, args.threads)
    source = str(path or "Ahmed body surface samples")
    figures = {"steps": steps, "particle_radius": radius, "directions": list(cfg.directions)}
    if not args.densify_only:
        figures.update(_time_set(gaussians, cfg, args.paper, source))
    if dense is not None:
        del gaussians
        figures["dense"] = _time_set(dense, cfg, args.paper, f"{source}, {args.densify} x jittered copies")
        if not args.densify_only:
            ratio = figures["dense"]["total"] / max(figures["total"], 1e-12)
            figures["dense_time_ratio"] = ratio
            print(
                f"{args.densify} x denser set: {figures['dense']['gaussians']} Gaussians, {ratio:.2f} x the time of "
                f"the {figures['gaussians']} Gaussians (same run)"
            )
    if args.json is not None:
        write_json(args.json, figures)
    return 0
