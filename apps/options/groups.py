"""The option groups several commands share: the probes, the frame, the recording, the cameras, the runtime,
and the checks of their input and output files."""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from .fields import add_config_options, config_values

# ---- the probe options of simulate, score, sweep, critical, inspect and bench score (nbv.physics.PhysicsConfig) ----
PROBE_FIELDS = ("particle_radius", "steps", "dt", "speed", "viscosity", "directions", "accumulate_every",
                "opacity_threshold")
FRAME_FIELDS = ("up", "scale", "crop")
SOLID_FIELDS = ("fill_cavities",)
RUN_FIELDS = ("empty_reference", "max_memory_gb")


def probe_overrides(default_directions: str = "all five", cameras: bool = False) -> dict[str, dict]:
    """The command line's names and wording for the PhysicsConfig fields whose docstring speaks of the config
    (``cameras``: the command has cameras, so ``--up auto`` is offered)."""
    from fluidsim.directions import DIRECTIONS

    auto = ", or 'auto': the cameras' mean up vector (logged)" if cameras else ""
    return {
        "directions": {"help": f"comma list of probes out of {','.join(DIRECTIONS)}",
                       "default_text": default_directions},
        "up": {"flags": ("--up", "--up-axis"), "metavar": "UP",
               "help": "the scene's up direction, rotated to simulation +y: +x, -x, +y, -y, +z, -z or a vector such "
                       f"as 0,-1,0 (COLMAP captures are often -y){auto}"},
        "scale": {"help": "metres per scene unit, or 'auto': the robust object box's largest extent -> 2 m, the "
                          "paper's domain", "convert": _scale},
        "crop": {"metavar": "BOX", "default_text": "keep all",
                 "help": "keep only the Gaussians inside xmin,ymin,zmin,xmax,ymax,zmax (scene units), or 'auto': "
                         "the robust object box grown by 10 %% per side"},
        "fill_cavities": {"flags": ("--no-fill",), "dest": "no_fill", "negate": True, "default_text": "filled",
                          "help": "keep the solid hollow: do not fill what the Gaussians enclose"},
        "empty_reference": {"flags": ("--no-empty-reference",), "dest": "no_empty_reference", "negate": True,
                            "default_text": "run it", "help": "skip the empty-scene D-bar reference (halves the "
                                                              "run time)"},
    }


def _scale(text: str):
    if str(text).strip().lower() == "auto":
        return "auto"
    try:
        return float(text)
    except ValueError:
        raise ValueError(f"--scale must be 'auto' or a number of metres per scene unit, got {text!r}") from None


def physics_config_class():
    from nbv.physics import QUICK, PhysicsConfig

    return PhysicsConfig, QUICK


def add_frame_arguments(g, cameras: bool = False, scale: bool = True, crop: bool = True) -> None:
    """--up (alias --up-axis), --scale and --crop: the scene -> simulation frame (:mod:`nbv.physics.scene_frame`)."""
    config, _ = physics_config_class()
    names = ("up",) + (("scale",) if scale else ()) + (("crop",) if crop else ())
    add_config_options(g, config, names, probe_overrides(cameras=cameras))


def add_physics_arguments(p: argparse.ArgumentParser, track_distinct: bool = False,
                          empty_reference: bool = True, cameras: bool = False) -> None:
    """The probe options shared by simulate, score, sweep, critical and bench score, generated from
    :class:`nbv.physics.PhysicsConfig` (``empty_reference``: offer --no-empty-reference)."""
    config, quick = physics_config_class()
    over = probe_overrides("-x" if track_distinct else "all five", cameras)
    g = p.add_argument_group("probes")
    g.add_argument("--quick", action="store_true",
                   help=f"quick preset: r = {quick['particle_radius']} m and {quick['steps']} steps per probe (unless "
                        "given explicitly; default: the paper's)")
    add_config_options(g, config, PROBE_FIELDS, over, presets={"--quick": quick})
    add_config_options(g, config, FRAME_FIELDS + SOLID_FIELDS, over)
    g.add_argument("--fill-cavities", action="store_true",
                   help="accepted for old scripts and does nothing: filling is now the default (see --no-fill)")
    add_config_options(g, config, RUN_FIELDS if empty_reference else RUN_FIELDS[1:], over)
    add_runtime_arguments(p)


def add_runtime_arguments(p, threads_help: str = "CPU threads", device_help: str = "compute device") -> None:
    """--device (cpu or cuda; cuda falls back to cpu with a logged warning) and --threads (>= 1)."""
    from ..runtime import positive_int

    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                   help=f"{device_help}; cuda falls back to cpu with a logged warning when unavailable "
                        "(default: cpu)")
    p.add_argument("--threads", type=positive_int, default=None, help=f"{threads_help} (default: all cores)")


def physics_config_from_args(args: argparse.Namespace, track_distinct: bool = False, default_directions=None,
                             cameras=None, preset: Mapping[str, Any] | None = None, **extra):
    """A validated :class:`nbv.physics.PhysicsConfig` from the probe options (``cameras`` for ``--up auto``;
    ``preset``: values under the options', by default :data:`nbv.physics.QUICK` with ``--quick``; ``extra``: fields
    the command sets itself). Options the parser lacks keep the dataclass default."""
    from nbv.physics import parse_directions

    config, quick = physics_config_class()
    values = config_values(config, args, PROBE_FIELDS + FRAME_FIELDS + SOLID_FIELDS + RUN_FIELDS, probe_overrides())
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
    return config(**{**preset, **values, "track_distinct": track_distinct, **extra})


def up_from_args(args: argparse.Namespace, cameras=None):
    """``args.up`` resolved: an up spec for PhysicsConfig ('auto' -> the cameras' mean up vector, logged)."""
    import logging

    from nbv.physics.scene_frame import describe_auto_up, parse_up

    up = "+y" if args.up is None else args.up
    if str(up).strip().lower() != "auto":
        parse_up(up)  # the error names --up
        return up
    if not cameras:
        raise ValueError("--up auto takes the up direction from cameras, and this command has none; give the up "
                         "direction (--up -y for a y-down COLMAP capture, --up +z for a z-up scene)")
    from recon.frames import up_from_cameras

    vector = up_from_cameras(cameras)
    logging.getLogger("fluidgs").info("%s", describe_auto_up(vector))
    return tuple(float(c) for c in vector)


def add_record_arguments(p: argparse.ArgumentParser) -> None:
    """--record-probe, --record-every, --record-max-gb: keep probes' fluid in RESULT.h5 for `fluidgs view`."""
    g = p.add_argument_group("trajectories (for `fluidgs view`)")
    g.add_argument("--record-probe", default=None, metavar="DIRS",
                   help="record these probes' fluid (positions, D_i, speed) every --record-every steps into RESULT.h5, "
                        "to replay them in `fluidgs view`: a probe (-x) or a comma list (default: none; the file stays "
                        "small)")
    g.add_argument("--record-every", type=int, default=10, metavar="K",
                   help="steps between recorded frames (default: 10); each frame costs 24 bytes per fluid particle")
    g.add_argument("--record-max-gb", type=float, default=2.0,
                   help="refuse, before simulating, a recording larger than this in GiB (default: 2)")


def record_config_from_args(args: argparse.Namespace, config):
    """A :class:`~nbv.physics.trajectory.RecordConfig` from
    --record-probe (None without it), checked against the probes of
    ``config``."""
    if getattr(args, "record_probe", None) is None:
        return None
    from nbv.physics import parse_directions
    from nbv.physics.trajectory import RecordConfig

    try:
        dirs = parse_directions(args.record_probe)
    except ValueError as exc:
        raise ValueError(str(exc).replace("--directions", "--record-probe", 1)) from None
    if not (args.record_max_gb and args.record_max_gb > 0):
        raise ValueError(f"--record-max-gb must be > 0, got {args.record_max_gb}")
    record = RecordConfig(dirs, args.record_every, args.record_max_gb * 2**30)
    record.check_probes(config.directions, config.steps)
    return record


def add_camera_arguments(p: argparse.ArgumentParser) -> None:
    """--cameras, --res, --render-width and --candidates: the candidate views of score and critical."""
    p.add_argument("--cameras", type=Path, required=True,
                   help="Blender/NeRF transforms.json with the candidate cameras, in the Gaussians' frame")
    p.add_argument("--res", type=int, default=None,
                   help="image width in pixels when the cameras file gives no w/h and no images (height from the "
                        "aspect of w/h when known, else square)")
    p.add_argument("--render-width", type=int, default=320,
                   help="render (and weight) at most this width in pixels; the weights pi R^2/(HW) barely change "
                        "with resolution")
    p.add_argument("--candidates", default=None, help="comma list of camera indices to score (default: all)")


# ---- inputs and outputs named on the command line --------------------------------------------------------------
def load_gaussians_checked(path):
    """Load a Gaussian set of any supported format (recon.formats); ValueError naming the file when it is missing,
    a folder or unreadable."""
    from recon.formats import SUPPORTED, load_gaussians

    if not Path(path).exists():  # a folder exists: recon.formats says it is a folder
        raise ValueError(f"Gaussian file {path} does not exist; pass a Gaussian file ({SUPPORTED})")
    return load_gaussians(path).check(str(path))


def check_output_file(path, suffixes: tuple[str, ...]):
    """Fail before any work when ``path`` has the wrong suffix or its folder is not writable."""
    from fluidsim.files import check_writable

    if suffixes and Path(path).suffix.lower() not in suffixes:
        raise ValueError(f"output {path} must end with {' or '.join(suffixes)}")
    return check_writable(path)


# The files of a dataset folder that loading reads (cameras, points, normalisation), at the top, in sparse/ and in
# sparse/0/: no output may overwrite them. Images are left out: no command that reads a dataset writes images.
DATASET_FILES = ("transforms_*.json", "dataset.json", "mesh.ply", "cameras.txt", "cameras.bin", "images.txt",
                 "images.bin", "points3D.txt", "points3D.bin", "points3D.ply")


def dataset_inputs(dataset) -> list[tuple[str, Path]]:
    """("DATASET file", path) for each existing :data:`DATASET_FILES` file of a dataset folder (or the
    transforms_*.json given), for :func:`fluidsim.files.check_not_input`."""
    root = Path(dataset)
    if root.is_file():
        return [("DATASET file", root)]
    return [("DATASET file", f) for folder in (root, root / "sparse", root / "sparse" / "0") if folder.is_dir()
            for pattern in DATASET_FILES for f in sorted(folder.glob(pattern))]


def save_diverged(exc, path: Path | None) -> int:
    """A probe diverged (:class:`nbv.physics.ProbeDiverged`): save the probes completed before it to ``path``
    (RESULT.h5 with status "diverged"; nothing when None), log one line naming the probe and the step; returns 3."""
    import logging

    from nbv.physics import save_result

    log = logging.getLogger("fluidgs")
    if path is None:
        log.error("%s; nothing saved (pass --save-result to keep the completed probes)", exc)
        return 3
    save_result(path, exc.result)
    log.error("%s; the completed probes are saved to %s (status 'diverged'); reduce --dt or --speed", exc, path)
    return 3
