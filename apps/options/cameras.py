"""The candidate cameras of score, critical and demo on the command line: ``--cameras`` (orbit:N or a camera
file), the orbit's rings, and the visibility of the Gaussians in a view (--frustum-only, --occlusion)."""

from __future__ import annotations

import argparse
from pathlib import Path

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


def candidate_cameras_from_args(args: argparse.Namespace, width: int) -> tuple:
    """``(orbit, file_cameras)`` of --cameras, checked before any work: the :class:`nbv.orbit.Orbit` of ``orbit:N``
    and None (:func:`orbit_from_args`), or None and the cameras of the file (:func:`camera_file_from_args`)."""
    orbit = orbit_from_args(args, width)
    return orbit, (None if orbit is not None else camera_file_from_args(args))


def write_orbit_cameras(path: Path | None, cameras, command: str, spec: str, orbit) -> None:
    """Write the orbit cameras of ``--cameras orbit:N`` to ``path`` as a transforms.json (nothing when None)."""
    if path is None:
        return
    from fluidsim.files import write_json_atomic
    from recon.camera_files import transforms_json

    write_json_atomic(path, transforms_json(cameras, f"fluidgs {command} --cameras {spec}: {orbit.describe()}"))


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
