"""The options of `fluidgs active`: the command line's names and wording for the ActiveConfig, TrainConfig and
PhysicsConfig fields, the config they give over the preset's, and the checks of the planner, budget and schedule in
the options' terms."""

from __future__ import annotations

import argparse

ACTIVE_FIELDS = (
    "method",
    "budget",
    "initial_count",
    "initial_ids",
    "initial_direction",
    "mode",
    "iterations_per_view",
    "total_iterations",
    "resolution",
    "seed",
)
TRAIN_FIELDS = ("init_points", "sh_degree", "max_gaussians")
PHYSICS_FIELDS = ("particle_radius", "steps", "directions", "replicas")


def overrides() -> dict[str, dict]:
    """The command line's names and wording for the ActiveConfig, TrainConfig and PhysicsConfig fields."""
    from fluidsim.directions import DIRECTIONS
    from nbv.plan.rules import describe_planners

    from .fields import float_list, index_list
    from .groups import probe_overrides

    return {
        "method": {"help": f"planner: {describe_planners()}"},
        "initial_ids": {
            "flags": ("--initial-views",),
            "dest": "initial_views",
            "default_text": "the biased rule",
            "help": "explicit initial train-split indices, e.g. 0,5",
            "convert": lambda text: index_list(text, "--initial-views"),
        },
        "initial_direction": {
            "convert": lambda text: float_list(text, "--initial-direction", size=3),
            "help": "anchor direction x,y,z of the biased rule",
            "default_text": "a unit vector drawn from --seed",
        },
        "mode": {
            "choices": ("continue", "reset"),
            "help": "continue: keep training the same Gaussians across rounds (the paper); reset: retrain from "
            "the initial Gaussians after each selection",
        },
        "iterations_per_view": {"flags": ("--iters-per-view",), "dest": "iters_per_view"},
        "total_iterations": {"flags": ("--iterations",), "dest": "iterations"},
        "resolution": {"flags": ("--res",), "help": "image width in pixels (0: native)", "convert": _resolution},
        "sh_degree": {"choices": (0, 1, 2, 3)},
        "particle_radius": {"help": "probe particle radius r, m"},
        "steps": {"flags": ("--probe-steps",), "dest": "probe_steps"},
        "directions": {"help": f"probes, comma list of {','.join(DIRECTIONS)}", "default_text": "all five"},
        "replicas": probe_overrides()["replicas"],
    }


def _resolution(width: int) -> int | None:
    if width < 0:
        raise ValueError(f"--res must be a width in pixels >= 8 (or 0 for native), got {width}")
    return width or None


def option_values(args: argparse.Namespace) -> tuple[dict, dict, dict]:
    """(ActiveConfig, TrainConfig, PhysicsConfig) values the command line gives, over the preset's."""
    from nbv.active import PRESETS, ActiveConfig
    from nbv.physics import PhysicsConfig, parse_directions
    from recon.train_config import TrainConfig

    from .cameras import check_visibility_arguments
    from .fields import config_values

    over = overrides()
    check_visibility_arguments(args)
    active = config_values(ActiveConfig, args, (*ACTIVE_FIELDS, "backend"), over)
    if args.frustum_only or args.occlusion:  # else the preset decides (paper: frustum; cpu-small: the depth test)
        active["occlusion"] = not args.frustum_only
    active["up"] = args.up
    train = config_values(TrainConfig, args, TRAIN_FIELDS, over)
    physics = {**PRESETS[args.preset]["physics"], **config_values(PhysicsConfig, args, PHYSICS_FIELDS, over)}
    if "directions" in physics:
        physics["directions"] = parse_directions(physics["directions"])
    return active, train, physics


def check_plan(args: argparse.Namespace) -> None:
    """The command line's planner, budget and schedule checked against the registry and the dataset, in the
    terms of the options, before the config (whose own checks speak of its fields) and before any training.

    Raises:
        ValueError: an unknown --method; a --budget above the dataset's candidate views; selection rounds that
            need more training iterations than the run has (continue mode).
    """
    from dataclasses import fields

    from nbv.active import PRESETS, ActiveConfig
    from nbv.plan import PLANNERS
    from recon.datasets import count_train_views

    defaults = {f.name: f.default for f in fields(ActiveConfig) if f.name in ACTIVE_FIELDS}
    given = option_values(args)[0]
    v = {**defaults, **{k: x for k, x in PRESETS[args.preset].items() if k in defaults}, **given}
    if v["method"] not in PLANNERS:
        raise ValueError(f"--method {v['method']!r} is not a planner; choose one of {', '.join(sorted(PLANNERS))}")
    budget = v["budget"]
    candidates = count_train_views(args.dataset)
    if candidates == 0:
        raise ValueError(f"{args.dataset} has no train (candidate) views; add train views to the dataset")
    if candidates is not None and budget > candidates:
        raise ValueError(
            f"--budget {budget} is more than the {candidates} candidate (train) views of "
            f"{args.dataset}: the budget counts the views a run ends with, the initial ones included; "
            f"use --budget {candidates} or less, or add train views to the dataset"
        )
    per_view, total = v["iterations_per_view"], v["total_iterations"]
    initial = v["initial_count"] if v["initial_ids"] is None else len(v["initial_ids"])
    needed = per_view * sum(range(initial, budget))
    if v["mode"] == "continue" and 0 < total < needed:
        raise ValueError(
            f"--budget {budget} means {budget - initial} selection rounds, trained for "
            f"{needed:,} iterations in all before them (--iters-per-view {per_view} x the {initial} to "
            f"{budget - 1} views selected so far), more than the run's {total:,} iterations "
            f"(--iterations; preset {args.preset}); give --iterations {needed} or more, or lower "
            "--iters-per-view or --budget"
        )


def config_from_args(args: argparse.Namespace):
    """The validated ActiveConfig of the command line (the preset's values unless an option is given)."""
    from nbv.active import ActiveConfig
    from nbv.physics import PhysicsConfig
    from recon.train_config import TrainConfig

    from .fields import option_names, options_named

    over = overrides()
    names = {
        **option_names(ActiveConfig, (*ACTIVE_FIELDS, "backend"), over),
        **option_names(TrainConfig, TRAIN_FIELDS, over),
        **option_names(PhysicsConfig, PHYSICS_FIELDS, over),
        "TrainConfig.iterations": "--iterations",
        "ActiveConfig.up": "--up",
    }
    active, train, physics = option_values(args)
    with options_named(names):
        return ActiveConfig.from_preset(args.preset, **active, train=train, physics=physics)
