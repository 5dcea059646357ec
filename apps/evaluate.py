"""`fluidgs eval RUN/`: test PSNR/SSIM/LPIPS, D-bar (five probes) and its empty-scene reference, Chamfer distance to
the reference mesh, and PSNR / D-bar on the top-20 function-critical test views (see :mod:`nbv.evaluate`).
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from .runtime import positive_int


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run", type=Path, help="a finished `fluidgs active` run folder (writes RUN/eval.json, eval.md)")
    p.add_argument("--critical-views", type=int, default=20, help="size of the function-critical subset (views)")
    p.add_argument("--chamfer-samples", type=int, default=20000, help="points sampled on the reference mesh")
    p.add_argument("--chamfer-opacity", type=float, default=0.5,
                   help="Gaussians above this opacity (0..1) enter the Chamfer distance")
    p.add_argument("--particle-radius", type=float, default=None,
                   help="probe particle radius r in m (default: the run's physics config)")
    p.add_argument("--probe-steps", type=int, default=None, help="time steps per probe (default: the run's)")
    p.add_argument("--directions", default=None,
                   help="probes, comma list of -x,+x,-z,+z,-y (default: the run's; -x is added for C(T))")
    p.add_argument("--no-lpips", action="store_true", help="skip LPIPS even when it is available")
    p.add_argument("--no-progress", action="store_true", help="hide the probe progress bars")
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                   help="compute device; cuda falls back to cpu with a logged warning when unavailable")
    p.add_argument("--threads", type=positive_int, default=None,
                   help="CPU threads for torch and Taichi (default: all cores)")


def run_command(args: argparse.Namespace) -> int:
    import json

    from nbv.active import ActiveConfig
    from nbv.evaluate import EvalConfig, evaluate_run
    from nbv.physics import parse_directions

    from .active import setup_runtime

    cfg_path = args.run / "config.json"
    if not cfg_path.is_file() or not (args.run / "gaussians.ply").is_file():
        raise ValueError(f"{args.run} is not a finished active run (needs config.json and gaussians.ply); "
                         "run `fluidgs active DATASET -o RUN` first")
    from fluidsim.output import check_writable

    check_writable(args.run / "eval.json")  # fail before the probes run, not after
    physics = ActiveConfig.from_dict(json.loads(cfg_path.read_text())["active"]).physics
    if args.particle_radius is not None:
        physics = replace(physics, particle_radius=args.particle_radius)
    if args.probe_steps is not None:
        physics = replace(physics, steps=args.probe_steps)
    if args.directions is not None:
        physics = replace(physics, directions=parse_directions(args.directions))
    config = EvalConfig(physics=physics, critical_views=args.critical_views, chamfer_samples=args.chamfer_samples,
                        chamfer_opacity=args.chamfer_opacity, lpips=not args.no_lpips)
    device = setup_runtime(args.device, args.threads, physics.precision)
    out = evaluate_run(args.run, config, device=device, progress=not args.no_progress)
    print((args.run / "eval.md").read_text(), end="")
    print(f"wrote {args.run / 'eval.json'} ({out['seconds']:.1f} s)")
    return 0
