"""`fluidgs eval RUN/`: test PSNR/SSIM/LPIPS, D-bar (five probes) and its empty-scene reference, Chamfer distance to
the reference mesh, and PSNR / D-bar on the top-20 function-critical test views (see :mod:`nbv.study.evaluate`).
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from .options import add_config_options, add_runtime_arguments, config_from_args
from .options.common import add_probe_size_options

EVAL_FIELDS = ("critical_views", "chamfer_samples", "chamfer_opacity", "lpips")
EVAL_OVERRIDES = {
    "critical_views": {"help": "size of the function-critical subset, views"},
    "chamfer_opacity": {"help": "Gaussians above this opacity (0..1) enter the Chamfer distance"},
    "lpips": {
        "flags": ("--no-lpips",),
        "dest": "no_lpips",
        "negate": True,
        "default_text": "computed",
        "help": "skip LPIPS even when it is available",
    },
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run", type=Path, help="a finished `fluidgs active` run folder (writes RUN/eval.json, eval.md)")
    from nbv.study.evaluate import EvalConfig

    add_config_options(p, EvalConfig, EVAL_FIELDS, EVAL_OVERRIDES)
    add_probe_size_options(
        p,
        "probe particle radius r in m (default: the run's physics config)",
        "time steps per probe (default: the run's)",
        steps_flag="--probe-steps",
    )
    p.add_argument(
        "--directions",
        default=None,
        help="probes, comma list of -x,+x,-z,+z,-y (default: the run's; -x is added for C(T))",
    )
    p.add_argument("--no-progress", action="store_true", help="hide the probe progress bars")
    add_runtime_arguments(p, threads_help="CPU threads for torch and Taichi")


def run_command(args: argparse.Namespace) -> int:
    from nbv.active import ActiveConfig
    from nbv.active.run_dir import read_run_config
    from nbv.physics import parse_directions
    from nbv.study.evaluate import EvalConfig, evaluate_run
    from nbv.study.experiment_config import config_keys

    from .runtime import setup_runtime

    cfg_path = args.run / "config.json"
    if not cfg_path.is_file() or not (args.run / "gaussians.ply").is_file():
        raise ValueError(
            f"{args.run} is not a finished active run (needs config.json and gaussians.ply); "
            "run `fluidgs active DATASET -o RUN` first"
        )
    from fluidsim.files import check_writable

    check_writable(args.run / "eval.json")  # fail before the probes run, not after
    keys = {"ActiveConfig": "active.", "TrainConfig": "active.train.", "PhysicsConfig": "active.physics."}
    with config_keys(keys, f"the run's config {cfg_path}"):  # the keys the file holds, not the config classes
        physics = ActiveConfig.from_dict(read_run_config(args.run)["active"]).physics
    from .options.fields import options_named

    with options_named({"PhysicsConfig.particle_radius": "--particle-radius", "PhysicsConfig.steps": "--probe-steps"}):
        if args.particle_radius is not None:
            physics = replace(physics, particle_radius=args.particle_radius)
        if args.probe_steps is not None:
            physics = replace(physics, steps=args.probe_steps)
    if args.directions is not None:
        physics = replace(physics, directions=parse_directions(args.directions))
    config = config_from_args(EvalConfig, args, EVAL_FIELDS, EVAL_OVERRIDES, physics=physics)
    device = setup_runtime(args.device, args.threads, physics.precision)
    out = evaluate_run(args.run, config, device=device, progress=not args.no_progress)
    print((args.run / "eval.md").read_text(), end="")
    print(f"wrote {args.run / 'eval.json'} ({out['seconds']:.1f} s)")
    return 0
