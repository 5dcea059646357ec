"""The option groups several commands share: the probes, the frame, the recording, the cameras, the runtime,
and the checks of their input and output files."""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from fluidsim.files import check_input_file

from .fields import add_config_options, config_values, option_names, options_named

# ---- the probe options of simulate, score, sweep, critical, inspect and bench score (nbv.physics.PhysicsConfig) ----
PROBE_FIELDS = (
    "particle_radius",
    "steps",
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
            "convert": _scale,
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
        help=f"quick preset: r = {quick['particle_radius']} m and {quick['steps']} steps per probe (unless "
        "given explicitly; default: the paper's)",
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

    p.add_argument(
        "--device",
        choices=("cpu", "cuda"),
        default="cpu",
        help=f"{device_help}; cuda falls back to cpu with a logged warning when unavailable (default: cpu)",
    )
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


def up_from_args(args: argparse.Namespace, cameras=None):
    """``args.up`` resolved: an up spec for PhysicsConfig ('auto' -> the cameras' mean up vector, logged)."""
    import logging

    from nbv.orbit import orbit_count
    from nbv.physics.scene_frame import describe_auto_up, parse_up

    up = "+y" if args.up is None else args.up
    if str(up).strip().lower() != "auto":
        parse_up(up)  # the error names --up
        return up
    if orbit_count(getattr(args, "cameras", None) or "") is not None:
        raise ValueError(
            "--up auto takes the up direction from a camera file, and --cameras orbit:N builds its "
            "cameras around --up; give the up direction (--up -y for a y-down COLMAP capture, --up +z "
            "for a z-up scene)"
        )
    if not cameras:
        raise ValueError(
            "--up auto takes the up direction from cameras, and this command has none; give the up "
            "direction (--up -y for a y-down COLMAP capture, --up +z for a z-up scene)"
        )
    from recon.frames import up_from_cameras

    vector = up_from_cameras(cameras)
    logging.getLogger("fluidgs").info("%s", describe_auto_up(vector))
    return tuple(float(c) for c in vector)


def add_record_arguments(p: argparse.ArgumentParser) -> None:
    """--record-probe, --record-every, --record-max-gb: keep probes' fluid in RESULT.h5 for `fluidgs view`."""
    g = p.add_argument_group("trajectories (for `fluidgs view`)")
    g.add_argument(
        "--record-probe",
        default=None,
        metavar="DIRS",
        help="record these probes' fluid (positions, D_i, speed) every --record-every steps into RESULT.h5, "
        "to replay them in `fluidgs view`: a probe (-x) or a comma list (default: none; the file stays "
        "small)",
    )
    g.add_argument(
        "--record-every",
        type=int,
        default=10,
        metavar="K",
        help="steps between recorded frames (default: 10); each frame costs 24 bytes per fluid particle",
    )
    g.add_argument(
        "--record-max-gb",
        type=float,
        default=2.0,
        help="refuse, before simulating, a recording larger than this in GiB (default: 2)",
    )


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


CAMERAS_HELP = (
    "candidate cameras, in the Gaussians' frame: orbit:N (N cameras on rings around the robust object "
    "box, looking at its centre with --up up; see --elevations), a transforms.json (Blender / NeRF / "
    "nerfstudio), a COLMAP model folder (sparse/0, or a folder holding it) or graphdeco's cameras.json"
)


def add_orbit_arguments(p) -> None:
    """--elevations and --orbit-fov: the rings of ``--cameras orbit:N`` (:class:`nbv.orbit.Orbit`)."""
    from recon.camera_paths import ORBIT_ELEVATIONS_DEG, ORBIT_FOV_X_DEG

    default = ",".join(f"{e:g}" for e in ORBIT_ELEVATIONS_DEG)
    p.add_argument(
        "--elevations",
        default=None,
        metavar="DEGREES",
        help="orbit:N only: comma list of ring elevations above the horizon, degrees in (-90, 90); the N "
        f"cameras are split over the rings (default: {default})",
    )
    p.add_argument(
        "--orbit-fov",
        type=float,
        default=None,
        metavar="DEGREES",
        help="orbit:N only: horizontal field of view in degrees; the cameras stand back until the object's "
        f"bounding sphere fills the narrower field of view (default: {ORBIT_FOV_X_DEG:g})",
    )


def add_camera_arguments(p: argparse.ArgumentParser) -> None:
    """--cameras, --elevations, --orbit-fov, --res, --render-width and --candidates: the candidate views of score
    and critical."""
    p.add_argument("--cameras", required=True, metavar="CAMERAS", help=f"{CAMERAS_HELP} (required)")
    add_orbit_arguments(p)
    p.add_argument(
        "--res",
        type=int,
        default=None,
        help="image width in pixels when the cameras file gives no w/h and no images (height from the "
        "aspect of w/h when known, else square)",
    )
    p.add_argument(
        "--render-width",
        type=int,
        default=320,
        help="render (and weight) at most this width in pixels; the weights pi R^2/(HW) barely change with resolution",
    )
    p.add_argument("--candidates", default=None, help="comma list of camera indices to score (default: all)")


def orbit_from_args(args: argparse.Namespace, width: int):
    """The :class:`nbv.orbit.Orbit` of ``--cameras orbit:N`` (None for a camera file), checked before any
    work; --elevations / --orbit-fov without an orbit are errors (they would be ignored)."""
    from nbv.orbit import Orbit, orbit_count

    from .fields import float_list

    count = orbit_count(args.cameras) if args.cameras is not None else None
    if count is None:
        given = [o for o, v in (("--elevations", args.elevations), ("--orbit-fov", args.orbit_fov)) if v is not None]
        if given:
            raise ValueError(
                f"{' and '.join(given)} shape the cameras of --cameras orbit:N, and --cameras is "
                f"{args.cameras or 'not given'}; drop {' and '.join(given)} or pass --cameras orbit:N"
            )
        return None
    values = {"width": width}
    if args.elevations is not None:
        values["elevations_deg"] = float_list(args.elevations, "--elevations")
    if args.orbit_fov is not None:
        values["fov_x_deg"] = args.orbit_fov
    return Orbit(count, **values)


def camera_file_from_args(args: argparse.Namespace):
    """The cameras of the camera file named by --cameras (any :mod:`recon.camera_files` kind), scaled to --res."""
    from recon.camera_files import load_camera_file

    return load_camera_file(args.cameras, getattr(args, "res", None))


def orbit_cameras_logged(gaussians, config, orbit):
    """:func:`nbv.orbit.orbit_cameras`, with one log line saying what was built."""
    import logging

    from nbv.orbit import orbit_cameras
    from nbv.physics.scene_frame import parse_up, up_label

    cams = orbit_cameras(gaussians, config, orbit)
    logging.getLogger("fluidgs").info(
        "cameras: %s around the robust object box, up %s (`fluidgs cameras` writes them as a transforms.json)",
        orbit.describe(),
        up_label(parse_up(config.up)),
    )
    return cams


# ---- frame hints ---------------------------------------------------------------------------------------------
UP_DISAGREES_DEG = 60.0  # warn when --up is further than this from the cameras' mean up


def frame_hint() -> str:
    """The one line said when --up is not given: the up assumed, and the usual fix for COLMAP captures."""
    return (
        "frame: no --up given, so the file's +y axis is taken as up (the top probe falls along -y); COLMAP "
        "captures are usually y-down: pass --up -y for them (`fluidgs inspect --png` shows which way is up)"
    )


def check_up_against_cameras(up, cameras, what: str = "the cameras") -> str | None:
    """A warning when the up direction ``up`` (anything :func:`nbv.physics.scene_frame.parse_up` takes) is more
    than :data:`UP_DISAGREES_DEG` from ``cameras``' mean up vector; None when they agree (or the cameras have no
    consistent up)."""
    from nbv.orbit import angle_to_camera_up
    from nbv.physics.scene_frame import nearest_axis, parse_up, up_label

    u = parse_up(up)
    found = angle_to_camera_up(u, cameras)
    if found is None or found[0] <= UP_DISAGREES_DEG:
        return None
    angle, mean = found
    axis, off = nearest_axis(mean)
    return (
        f"the up direction {up_label(u)} is {angle:.0f} deg from {what}' mean up ({up_label(mean)}, {off:.0f} deg "
        f"from {axis}): the capture would be simulated {'upside down' if angle > 120 else 'on its side'}; pass "
        f"--up {axis} (or --up auto to take the cameras' mean up)"
    )


def warn_frame(config, cameras=None, up_given: bool = True, what: str = "the cameras") -> None:
    """Log the frame hint when the up direction was not given (``up_given`` False), and the camera-up warning when
    ``cameras`` disagree with ``config.up``."""
    import logging

    log = logging.getLogger("fluidgs")
    if not up_given:
        log.info("%s", frame_hint())
    if cameras:
        warning = check_up_against_cameras(config.up, cameras, what)
        if warning:
            log.warning("%s", warning)


# ---- --result: the options it fixes -----------------------------------------------------------------------------
def result_overridden_options(args: argparse.Namespace) -> list[str]:
    """The probe, frame and solid options given on the command line (``"--up -y"``, ``"--quick"``): a RESULT.h5
    fixes all of them, so with ``--result`` they are ignored."""
    over = probe_overrides()
    given = ["--quick"] if getattr(args, "quick", False) else []
    for name in PROBE_FIELDS + FRAME_FIELDS + SOLID_FIELDS + RUN_FIELDS + REPLICA_FIELDS:
        o = over.get(name, {})
        dest = o.get("dest", name)
        value = getattr(args, dest, None)
        if value is None or value is False:
            continue
        flag = o.get("flags", ("--" + name.replace("_", "-"),))[0]
        given.append(flag if value is True else f"{flag} {value}")
    if getattr(args, "fill_cavities", False):
        given.append("--fill-cavities")
    return given


# ---- inputs and outputs named on the command line --------------------------------------------------------------
def add_gaussian_file_arguments(p: argparse.ArgumentParser) -> None:
    """--spz-frame, --colmap and --dataparser-transforms: what a Gaussian file's content cannot say
    (:class:`recon.formats.LoadOptions`)."""
    g = p.add_argument_group("Gaussian file")
    g.add_argument(
        "--spz-frame",
        choices=("auto", "rub", "ply"),
        default="auto",
        help="what an .spz stores: 'auto', decided from a file of the same capture in a .ply-frame format beside it "
        "(else 'rub', with a warning); 'rub', Niantic's right-up-back, turned half a turn about x to the .ply "
        "frame; or 'ply', the .ply frame as splat-transform and SuperSplat write it (default: auto)",
    )
    g.add_argument(
        "--colmap",
        type=Path,
        default=None,
        metavar="DIR",
        help="for a gsplat checkpoint: the COLMAP model it was trained on (sparse/0 or its parent); its "
        "normalisation is recomputed and undone, so sizes are in scene units (default: none, the "
        "trainer's normalised units, with a warning)",
    )
    g.add_argument(
        "--dataparser-transforms",
        type=Path,
        default=None,
        metavar="FILE",
        help="for a nerfstudio checkpoint: its dataparser_transforms.json, undone so sizes are in scene "
        "units (default: the one beside the run's config.yml)",
    )


def load_gaussians_checked(path, args=None):
    """Load a Gaussian set of any supported format (recon.formats); ValueError naming the file when it is missing,
    a folder or unreadable. With the parsed ``args`` of :func:`add_gaussian_file_arguments`, their options apply,
    the assumed frame is logged and ``args.source_frame`` receives its record (for RESULT.h5)."""
    import logging

    from recon.formats import SUPPORTED, LoadOptions, load_gaussians_framed

    # a folder passes: recon.formats says it is a folder
    check_input_file(path, "Gaussian file", f"pass a Gaussian file ({SUPPORTED})", folder_ok=True)
    options = LoadOptions(
        spz_frame=getattr(args, "spz_frame", None) or "auto",
        colmap=getattr(args, "colmap", None),
        dataparser_transforms=getattr(args, "dataparser_transforms", None),
    )
    gaussians, fmt, frame = load_gaussians_framed(path, options)
    if fmt in ("spz", "checkpoint") and frame.metric:
        logging.getLogger(__name__).info("%s", frame.description)
    if args is not None:
        args.source_frame = frame.to_json()
    return gaussians.check(str(path))


def check_output_file(path, suffixes: tuple[str, ...]):
    """Fail before any work when ``path`` has the wrong suffix or its folder is not writable."""
    from fluidsim.files import check_writable

    if suffixes and Path(path).suffix.lower() not in suffixes:
        raise ValueError(f"output {path} must end with {' or '.join(suffixes)}")
    return check_writable(path)


def check_output_folder(folder, where: str, own: tuple[str, ...] = ()) -> Path:
    """Fail before any work when the results folder ``folder`` cannot be made or written: an
    :class:`~fluidsim.files.OutputError` (exit 4) that starts with ``where`` (the option or config key that gave
    it), never the file system's bare errno text. With ``own`` (the names this command writes at the folder's top),
    an existing folder that holds other files and none of those (``"output": "/etc"``) is refused (ValueError, exit
    2): the command would write its results among someone else's files."""
    from fluidsim.files import OutputError, check_writable

    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise OutputError(f"{where} {folder} is a file, not a folder; give a results folder that is not a file")
    if own and folder.is_dir():
        names = sorted(p.name for p in folder.iterdir())
        if names and not set(names) & set(own):
            shown = ", ".join(names[:3]) + (", ..." if len(names) > 3 else "")
            raise ValueError(
                f"{where} {folder} already holds other files ({shown}) and no results of an earlier run; give a new "
                "or empty results folder"
            )
    try:
        check_writable(folder / "results.json")
    except OutputError as exc:
        raise OutputError(f"{where} {folder}: {exc}") from None
    return folder


# The files of a dataset folder that loading reads (cameras, points, normalisation), at the top, in sparse/ and in
# sparse/0/: no output may overwrite them. Images are left out: no command that reads a dataset writes images.
DATASET_FILES = (
    "transforms_*.json",
    "dataset.json",
    "mesh.ply",
    "cameras.txt",
    "cameras.bin",
    "images.txt",
    "images.bin",
    "points3D.txt",
    "points3D.bin",
    "points3D.ply",
)


def dataset_inputs(dataset) -> list[tuple[str, Path]]:
    """("DATASET file", path) for each existing :data:`DATASET_FILES` file of a dataset folder (or the
    transforms_*.json given), for :func:`fluidsim.files.check_not_input`."""
    root = Path(dataset)
    if root.is_file():
        return [("DATASET file", root)]
    return [
        ("DATASET file", f)
        for folder in (root, root / "sparse", root / "sparse" / "0")
        if folder.is_dir()
        for pattern in DATASET_FILES
        for f in sorted(folder.glob(pattern))
    ]


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


# ---- visibility of the Gaussians in a candidate view (score, critical, active) -----------------------------------
def add_visibility_arguments(p) -> None:
    """--frustum-only (the paper's visibility) and --occlusion (the depth test, now the default; kept for scripts)."""
    p.add_argument(
        "--frustum-only",
        action="store_true",
        help="count every Gaussian inside the view's frustum, hidden or not: the paper's visibility, for "
        "replication (default: off, the depth test counts only the Gaussians not hidden behind "
        "others: a coarse depth buffer of the projected centres; the active loop's paper preset "
        "keeps the frustum)",
    )
    p.add_argument(
        "--occlusion",
        action="store_true",
        help="count only the Gaussians the depth test finds unhidden; accepted for old scripts, as it is "
        "what happens without --frustum-only (default: on unless --frustum-only)",
    )


def check_visibility_arguments(args: argparse.Namespace) -> None:
    """ValueError (exit 2) for --frustum-only with --occlusion, which ask for two visibilities."""
    if getattr(args, "frustum_only", False) and getattr(args, "occlusion", False):
        raise ValueError(
            "--frustum-only (the paper's visibility) and --occlusion (the depth test) ask for two "
            "visibilities; drop --occlusion for the paper's, or --frustum-only for the depth test (the "
            "default)"
        )
