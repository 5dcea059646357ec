"""`fluidgs active DATASET -o RUN/`: the active-reconstruction loop (paper Sec. 3.5, 4.1).

Two biased initial views, one selection per round until the view budget (10), n_selected x 100 training iterations
before each selection, then training to the total (30k); ``--preset cpu-small`` shrinks everything to run on a
64 px dataset on a small CPU. See :mod:`nbv.active` for the modes, the run folder and resuming.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from .options.active import ACTIVE_FIELDS, PHYSICS_FIELDS, TRAIN_FIELDS, check_plan, config_from_args, overrides
from .options.common import add_output_option

log = logging.getLogger("fluidgs")


def add_arguments(p: argparse.ArgumentParser) -> None:
    from nbv.active import PRESETS, ActiveConfig
    from nbv.physics import PhysicsConfig
    from recon.train_config import TrainConfig

    from .options import add_config_options, add_runtime_arguments, add_visibility_arguments

    p.add_argument(
        "dataset",
        type=Path,
        help="dataset folder (Blender transforms_*.json or COLMAP); its train split is the candidate set",
    )
    add_output_option(
        p,
        "run folder (config.json, rounds.json, checkpoint.pt, gaussians.ply); an existing run with "
        "the same options is resumed",
    )
    p.add_argument(
        "--preset",
        choices=tuple(PRESETS),
        default="paper",
        help="paper: the paper's settings; cpu-small: sized for a 64 px dataset on a small CPU (each "
        "option below shows its cpu-small value; default: paper)",
    )
    small = PRESETS["cpu-small"]
    label = "--preset cpu-small"
    over = overrides()
    add_config_options(p, ActiveConfig, ACTIVE_FIELDS, over, presets={label: small})
    add_config_options(p, TrainConfig, TRAIN_FIELDS, over, presets={label: small["train"]})
    add_config_options(p, PhysicsConfig, PHYSICS_FIELDS, over, presets={label: small["physics"]})
    p.add_argument(
        "--up",
        "--up-axis",
        dest="up",
        default=None,
        metavar="UP",
        help="the scene's up direction for the probes: +x, -x, +y, -y, +z, -z, a vector such as 0,-1,0, or "
        "'auto': the training cameras' mean up vector (default: the dataset's up axis)",
    )
    add_config_options(
        p, ActiveConfig, ("backend",), {"backend": {"choices": ("auto", "torch", "gsplat"), "help": "renderer backend"}}
    )
    add_visibility_arguments(p)
    p.add_argument("--overwrite", action="store_true", help="discard an existing run in the output folder")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bars")
    add_runtime_arguments(p, threads_help="CPU threads for torch and Taichi")


def run_command(args: argparse.Namespace) -> int:
    from fluidsim.files import check_not_input
    from nbv.active import RUN_FILES, ActiveRun, timing_line, visual_name

    from .options import check_output_folder, check_outside_dataset, dataset_inputs
    from .runtime import setup_runtime

    check_plan(args)
    config = config_from_args(args)
    check_not_input([("-o (run file)", args.output / name) for name in RUN_FILES], dataset_inputs(args.dataset))
    check_outside_dataset(args.output, args.dataset)
    check_output_folder(args.output, "-o")
    device = setup_runtime(args.device, args.threads, config.physics.precision)
    run = ActiveRun(
        args.dataset, args.output, config, device=device, overwrite=args.overwrite, progress=not args.no_progress
    )
    rounds = run.run()
    final = rounds.get("final", {})
    print(f"selected views: {rounds['selected']} ({', '.join(rounds['selected_names'])})")
    if "timing" in final:
        print(timing_line(final["timing"], visual_name(config.method)))
    print(
        f"wrote {args.output / 'gaussians.ply'} ({final.get('num_gaussians')} Gaussians, "
        f"{final.get('iterations')} iterations) and {args.output / 'rounds.json'}"
    )
    return 0
