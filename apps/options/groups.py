"""The probe options several commands share (nbv.physics.PhysicsConfig), and the runtime options (--device,
--threads). The frame (:mod:`.frame`), the cameras (:mod:`.cameras`), RESULT.h5 (:mod:`.results`) and the files
(:mod:`.files`) have their own modules."""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from typing import Any

from .fields import add_config_options, config_values, option_names, options_named
from .frame import scale_value, up_from_args

# ---- the probe options of simulate, score, sweep, critical, inspect and bench score (nbv.physics.PhysicsConfig) ----
PROBE_FIELDS = (
    "particle_radius",
    "steps",
    "stop_tolerance",
    "dt",
    "speed",
    "viscosity",
    "directions",
    "accumulate_every",
    "opacity_threshold",
)
FRAME_FIELDS = ("up", "scale", "crop")
SOLID_FIELDS = ("fill_cavities",)
RUN_FIELDS = ("empty_reference", "empty_cache", "max_memory_gb")
EMPTY_FIELDS = ("empty_reference", "empty_cache")  # offered only where the empty scene runs
REPLICA_FIELDS = ("replicas",)  # simulate, score and critical (add_physics_arguments(replicas=True))


def probe_overrides(default_directions: str = "all five", cameras: bool = False) -> dict[str, dict]:
    """The command line's names and wording for the PhysicsConfig fields whose docstring speaks of the config
    (``cameras``: the command has cameras, so ``--up auto`` is offered)."""
    from fluidsim.directions import DIRECTIONS

    auto = ", or 'auto': the cameras' mean up vector (logged)" if cameras else ""
    return {
        "directions": {
            "help": f"comma list of probes out of {','.join(DIRECTIONS)}",
            "default_text": default_directions,
        },
        "up": {
            "flags": ("--up", "--up-axis"),
            "metavar": "UP",
            "help": "the scene's up direction, rotated to simulation +y: +x, -x, +y, -y, +z, -z or a vector such "
            f"as 0,-1,0 (COLMAP captures are often -y){auto}",
        },
        "scale": {
            "help": "metres per scene unit, or 'auto': the robust object box's largest extent -> 2 m, the "
            "paper's domain",
            "convert": scale_value,
        },
        "crop": {
            "metavar": "BOX",
            "default_text": "keep all",
            "help": "keep only the Gaussians inside xmin,ymin,zmin,xmax,ymax,zmax (scene units), or 'auto': "
            "the robust object box grown by 10 %% per side",
        },
        "fill_cavities": {
            "flags": ("--no-fill",),
            "dest": "no_fill",
            "negate": True,
            "default_text": "filled",
            "help": "keep the solid hollow: do not fill what the Gaussians enclose",
        },
        "empty_reference": {
            "flags": ("--no-empty-reference",),
            "dest": "no_empty_reference",
            "negate": True,
            "default_text": "run it",
            "help": "skip the empty-scene D-bar reference (halves the run time)",
        },
        "replicas": {
            "metavar": "N",
            "help": "run the probes N times, the solid lattice and the fluid slab shifted by a fraction of a "
            "spacing each time (Halton offsets; the first unshifted), average D_g over them and report how far "
            "they agree; costs N times the probe time",
            "convert": replica_count,
        },
        "empty_cache": {
            "flags": ("--no-cache",),
            "dest": "no_cache",
            "negate": True,
            "default_text": "use the cache: $FLUIDGS_CACHE_DIR, else $XDG_CACHE_HOME/fluidgs or ~/.cache/fluidgs, "
            "at most $FLUIDGS_CACHE_MAX_GB GiB, 4 unless set",
            "help": "simulate the empty-scene reference afresh instead of accumulating its cached fluid (bit-identical "
            "either way), and store nothing",
        },
    }


def replica_count(value: int) -> int:
    """--replicas: an integer >= 1 (ValueError naming the option)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(
            f"--replicas must be a whole number of runs >= 1, got {value!r}; use 1 for one run, 2 or more to "
            "average D_g over shifted lattices"
        )
    return value


def physics_config_class():
    from nbv.physics import QUICK, PhysicsConfig

    return PhysicsConfig, QUICK


def add_frame_arguments(g, cameras: bool = False, scale: bool = True, crop: bool = True) -> None:
    """--up (alias --up-axis), --scale and --crop: the scene -> simulation frame (:mod:`nbv.physics.scene_frame`)."""
    config, _ = physics_config_class()
    names = ("up",) + (("scale",) if scale else ()) + (("crop",) if crop else ())
    add_config_options(g, config, names, probe_overrides(cameras=cameras))


def add_physics_arguments(
    p: argparse.ArgumentParser,
    track_distinct: bool = False,
    empty_reference: bool = True,
    cameras: bool = False,
    replicas: bool = False,
) -> None:
    """The probe options shared by simulate, score, sweep, critical and bench score, generated from
    :class:`nbv.physics.PhysicsConfig` (``empty_reference``: offer --no-empty-reference; ``replicas``: offer
    --replicas)."""
    config, quick = physics_config_class()
    over = probe_overrides("-x" if track_distinct else "all five", cameras)
    g = p.add_argument_group("probes")
    g.add_argument(
        "--quick",
        action="store_true",
        help=f"quick preset: r = {quick['particle_radius']} m and {quick['steps']} steps per probe, each probe "
        f"stopped once 50 steps move its D_g by <= {quick['stop_tolerance']:g} (unless given explicitly; default: the "
        "paper's)",
    )
    add_config_options(g, config, PROBE_FIELDS, over, presets={"--quick": quick})
    add_config_options(g, config, FRAME_FIELDS + SOLID_FIELDS, over)
    add_config_options(g, config, tuple(f for f in RUN_FIELDS if empty_reference or f not in EMPTY_FIELDS), over)
    if replicas:
        add_config_options(g, config, REPLICA_FIELDS, over)
    add_runtime_arguments(p)


def add_runtime_arguments(p, threads_help: str = "CPU threads", device_help: str = "compute device") -> None:
    """--device (cpu or cuda; cuda falls back to cpu with a logged warning) and --threads (>= 1)."""
    from ..runtime import thread_count
    from .common import add_device_option

    add_device_option(p, f"{device_help}; cuda falls back to cpu with a logged warning when unavailable (default: cpu)")
    p.add_argument("--threads", type=thread_count, default=None, help=f"{threads_help} (default: all cores)")


def physics_config_from_args(
    args: argparse.Namespace,
    track_distinct: bool = False,
    default_directions=None,
    cameras=None,
    preset: Mapping[str, Any] | None = None,
    **extra,
):
    """A validated :class:`nbv.physics.PhysicsConfig` from the probe options (``cameras`` for ``--up auto``;
    ``preset``: values under the options', by default :data:`nbv.physics.QUICK` with ``--quick``; ``extra``: fields
    the command sets itself). Options the parser lacks keep the dataclass default."""
    from nbv.physics import parse_directions

    config, quick = physics_config_class()
    names = PROBE_FIELDS + FRAME_FIELDS + SOLID_FIELDS + RUN_FIELDS + REPLICA_FIELDS
    values = config_values(config, args, names, probe_overrides())
    if "directions" in values:
        values["directions"] = parse_directions(values["directions"])
    elif default_directions:
        values["directions"] = tuple(default_directions)
    if hasattr(args, "up"):
        values["up"] = up_from_args(args, cameras)
    if not hasattr(args, "no_empty_reference"):
        values["empty_reference"] = False  # commands without the option never run the empty scene
    if preset is None:
        preset = quick if getattr(args, "quick", False) else {}
    with options_named(option_names(config, names, probe_overrides())):
        physics = config(**{**preset, **values, "track_distinct": track_distinct, **extra})
        physics.check_inflow()
    if physics.empty_reference and physics.empty_cache:
        from nbv.physics.empty_cache import max_bytes_from_env

        max_bytes_from_env()  # a bad FLUIDGS_CACHE_MAX_GB is exit 2 before Taichi starts
    return physics
