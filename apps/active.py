"""`fluidgs active DATASET -o RUN/`: the active-reconstruction loop (paper Sec. 3.5, 4.1).

Two biased initial views, one selection per round until the view budget (10), n_selected x 100 training iterations
before each selection, then training to the total (30k); ``--preset cpu-small`` shrinks everything to run on a
64 px dataset on a small CPU. See :mod:`nbv.active` for the modes, the run folder and resuming.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from .runtime import positive_int

log = logging.getLogger("fluidgs")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dataset", type=Path, help="dataset folder (Blender transforms_*.json or COLMAP); its train split "
                                              "is the candidate set")
    p.add_argument("-o", "--output", type=Path, required=True,
                   help="run folder (config.json, rounds.json, checkpoint.pt, gaussians.ply); an existing run with "
                        "the same options is resumed")
    p.add_argument("--method", default="fisher+fluid",
                   help="planner: random, fisher, variance, physics, fisher+fluid, variance+fluid, random+fluid, "
                        "or a control of the physics pick: fisher+area (coverage, no probes), fisher+shuffled "
                        "(D_g permuted), the same on variance and random")
    p.add_argument("--preset", choices=("paper", "cpu-small"), default="paper",
                   help="paper: native resolution, 30k iterations, 100 iterations per view, r = 0.025 m, 750 steps; "
                        "cpu-small: 64 px, 1000 iterations, 10 per view, at most 4000 Gaussians, r = 0.05 m, 150 steps")
    p.add_argument("--budget", type=int, default=10, help="view budget B (views)")
    p.add_argument("--initial-count", type=int, default=2, help="number of biased initial views")
    p.add_argument("--initial-views", default=None,
                   help="explicit initial train-split indices, e.g. 0,5 (default: the biased rule of nbv.active)")
    p.add_argument("--initial-direction", default=None,
                   help="anchor direction x,y,z of the biased rule (default: a unit vector drawn from --seed)")
    p.add_argument("--mode", choices=("continue", "reset"), default="continue",
                   help="continue: keep training the same Gaussians across rounds (the paper); reset: retrain from "
                        "the initial Gaussians after each selection")
    p.add_argument("--iters-per-view", type=int, default=None,
                   help="training iterations per selected view before each selection (default: the preset's)")
    p.add_argument("--iterations", type=int, default=None, help="total training iterations (default: the preset's)")
    p.add_argument("--res", type=int, default=None, help="image width in pixels (default: the preset's; 0: native)")
    p.add_argument("--seed", type=int, default=0, help="seed of training, initial views and planners")
    p.add_argument("--init-points", type=int, default=None, help="random initial Gaussians (default: the preset's)")
    p.add_argument("--sh-degree", type=int, choices=(0, 1, 2, 3), default=None,
                   help="largest SH degree (default: the preset's; 3 for paper)")
    p.add_argument("--max-gaussians", type=int, default=None,
                   help="cap on the number of Gaussians (default: the preset's; none for paper)")
    p.add_argument("--particle-radius", type=float, default=None,
                   help="probe particle radius r in m (default: the preset's)")
    p.add_argument("--probe-steps", type=int, default=None, help="time steps per probe (default: the preset's)")
    p.add_argument("--directions", default=None, help="probes, comma list of -x,+x,-z,+z,-y (default: all five)")
    p.add_argument("--up", "--up-axis", dest="up", default=None, metavar="UP",
                   help="the scene's up direction for the probes: +x, -x, +y, -y, +z, -z, a vector such as 0,-1,0, or "
                        "'auto': the training cameras' mean up vector (default: the dataset's up axis)")
    p.add_argument("--occlusion", action="store_true",
                   help="the physics planners count only Gaussians a coarse depth test finds unhidden (not in the "
                        "paper, whose visibility is frustum culling; default: off)")
    p.add_argument("--backend", choices=("auto", "torch", "gsplat"), default="auto", help="renderer backend")
    p.add_argument("--overwrite", action="store_true", help="discard an existing run in the output folder")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bars")
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                   help="compute device; cuda falls back to cpu with a logged warning when unavailable")
    p.add_argument("--threads", type=positive_int, default=None,
                   help="CPU threads for torch and Taichi (default: all cores)")


def parse_floats(text: str, count: int, option: str) -> tuple[float, ...]:
    """'1,0,0' -> (1.0, 0.0, 0.0); ValueError naming the option."""
    try:
        vals = tuple(float(t) for t in text.split(","))
    except ValueError:
        raise ValueError(f"{option} must be {count} comma-separated numbers, got {text!r}") from None
    if len(vals) != count:
        raise ValueError(f"{option} must be {count} comma-separated numbers, got {text!r}")
    return vals


def parse_ints(text: str, option: str) -> tuple[int, ...]:
    """'0,5' -> (0, 5); ValueError naming the option on an empty list, a non-integer, a negative or a repeat."""
    try:
        vals = tuple(int(t) for t in text.split(",") if t.strip())
    except ValueError:
        raise ValueError(f"{option} must be comma-separated integers such as 0,5, got {text!r}") from None
    if not vals:
        raise ValueError(f"{option} is empty; give indices such as 0,5")
    negative = [v for v in vals if v < 0]
    if negative:
        raise ValueError(f"{option} {negative}: indices start at 0")
    repeated = sorted({v for v in vals if vals.count(v) > 1})
    if repeated:
        raise ValueError(f"{option} {text!r} lists {repeated} more than once; list each view once")
    return vals


def count_candidates(dataset: Path) -> int | None:
    """The train (candidate) views of a dataset, counted from its cameras without reading an image; None when the
    folder cannot be read that way (the dataset loader then says what is wrong)."""
    import json
    import math

    from recon.colmap import find_colmap_sparse, read_colmap_model
    from recon.datasets import COLMAP_TEST_EVERY, dataset_format

    root = Path(dataset)
    root = root.parent if root.is_file() else root
    try:
        if dataset_format(root) == "blender":
            frames = json.loads((root / "transforms_train.json").read_text()).get("frames")
            return len(frames) if isinstance(frames, list) else None
        images = len(read_colmap_model(find_colmap_sparse(root)).images)
        return images - math.ceil(images / COLMAP_TEST_EVERY)  # images 0, 8, 16, ... are the test split
    except (ValueError, OSError, TypeError, AttributeError):
        return None


def check_plan(args: argparse.Namespace) -> None:
    """The command line's planner, budget and schedule checked against the registry and the dataset, in the
    terms of the options, before the config (whose own checks speak of its fields) and before any training.

    Raises:
        ValueError: an unknown --method; a --budget above the dataset's candidate views; selection rounds that
            need more training iterations than the run has (continue mode).
    """
    from nbv.active import PRESETS
    from nbv.planners import PLANNERS

    if args.method not in PLANNERS:
        raise ValueError(f"--method {args.method!r} is not a planner; choose one of {', '.join(sorted(PLANNERS))}")
    candidates = count_candidates(args.dataset)
    if candidates is not None and args.budget > candidates:
        raise ValueError(f"--budget {args.budget} is more than the {candidates} candidate (train) views of "
                         f"{args.dataset}: the budget counts the views a run ends with, the initial ones included; "
                         f"use --budget {candidates} or less, or add train views to the dataset")
    preset = PRESETS[args.preset]
    per_view = preset["iterations_per_view"] if args.iters_per_view is None else args.iters_per_view
    total = preset["total_iterations"] if args.iterations is None else args.iterations
    initial = args.initial_count if args.initial_views is None else len(parse_ints(args.initial_views,
                                                                                   "--initial-views"))
    needed = per_view * sum(range(initial, args.budget))
    if args.mode == "continue" and 0 < total < needed:
        raise ValueError(f"--budget {args.budget} means {args.budget - initial} selection rounds, trained for "
                         f"{needed:,} iterations in all before them (--iters-per-view {per_view} x the {initial} to "
                         f"{args.budget - 1} views selected so far), more than the run's {total:,} iterations "
                         f"(--iterations; preset {args.preset}); give --iterations {needed} or more, or lower "
                         "--iters-per-view or --budget")


def config_from_args(args: argparse.Namespace):
    """The validated ActiveConfig of the command line (preset values unless an option is given)."""
    from nbv.active import PRESETS, ActiveConfig
    from nbv.physics import parse_directions

    preset = PRESETS[args.preset]
    over: dict = {"method": args.method, "budget": args.budget, "initial_count": args.initial_count,
                  "mode": args.mode, "seed": args.seed, "backend": args.backend, "up": args.up,
                  "occlusion": args.occlusion}
    if args.initial_views is not None:
        over["initial_ids"] = parse_ints(args.initial_views, "--initial-views")
    if args.initial_direction is not None:
        over["initial_direction"] = parse_floats(args.initial_direction, 3, "--initial-direction")
    if args.iters_per_view is not None:
        over["iterations_per_view"] = args.iters_per_view
    if args.iterations is not None:
        over["total_iterations"] = args.iterations
    if args.res is not None:
        if args.res < 0:
            raise ValueError(f"--res must be a width in pixels >= 8 (or 0 for native), got {args.res}")
        over["resolution"] = args.res or None
    train = {k: v for k, v in (("init_points", args.init_points), ("sh_degree", args.sh_degree),
                               ("max_gaussians", args.max_gaussians)) if v is not None}
    physics = dict(preset["physics"])
    if args.particle_radius is not None:
        physics["particle_radius"] = args.particle_radius
    if args.probe_steps is not None:
        physics["steps"] = args.probe_steps
    if args.directions is not None:
        physics["directions"] = parse_directions(args.directions)
    return ActiveConfig.from_preset(args.preset, **over, train=train, physics=physics)


def setup_runtime(device: str, threads: int | None, precision: str) -> str:
    """torch threads, Taichi runtime; returns the torch device actually used."""
    import torch

    from .runtime import init_taichi
    from .train import select_device

    if threads is not None:
        if threads < 1:
            raise ValueError(f"--threads must be >= 1, got {threads}")
        torch.set_num_threads(threads)
    used = select_device(device)
    init_taichi(used, precision, threads)
    return used


def run_command(args: argparse.Namespace) -> int:
    from fluidsim.output import check_not_input
    from nbv.active import RUN_FILES, ActiveRun

    from .train import dataset_inputs

    check_plan(args)
    config = config_from_args(args)
    check_not_input([("-o (run file)", args.output / name) for name in RUN_FILES], dataset_inputs(args.dataset))
    device = setup_runtime(args.device, args.threads, config.physics.precision)
    run = ActiveRun(args.dataset, args.output, config, device=device, overwrite=args.overwrite,
                    progress=not args.no_progress)
    rounds = run.run()
    final = rounds.get("final", {})
    print(f"selected views: {rounds['selected']} ({', '.join(rounds['selected_names'])})")
    print(f"wrote {args.output / 'gaussians.ply'} ({final.get('num_gaussians')} Gaussians, "
          f"{final.get('iterations')} iterations) and {args.output / 'rounds.json'}")
    return 0
