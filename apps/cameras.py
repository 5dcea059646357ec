"""`fluidgs cameras GAUSSIANS --orbit N --up -y -o cams.json`: candidate cameras for a capture that has none.

The cameras of ``--cameras orbit:N`` (:mod:`nbv.orbit`): N cameras on rings around the robust object box
(after ``--crop``), looking at its centre with ``--up`` up in the image, standing back until the box's bounding
sphere fills the narrower field of view. Written as a transforms.json (OpenGL camera-to-world, docs/formats.md),
or with ``--format`` as graphdeco's cameras.json or a COLMAP text model (a folder), all in the Gaussians' frame.
Any of them is a valid ``--cameras`` for score and critical, and a file to edit by hand.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from .options import (
    add_config_options,
    add_frame_arguments,
    add_gaussian_file_arguments,
    add_orbit_arguments,
    check_output_file,
    gaussian_file_inputs,
    load_gaussians_checked,
    physics_config_class,
    physics_config_from_args,
    probe_overrides,
    warn_frame,
)
from .options.common import add_output_option

FORMATS = ("transforms", "graphdeco", "colmap")


def add_arguments(p: argparse.ArgumentParser) -> None:
    from recon.formats import gaussians_help  # noqa: PLC0415 - the readers load torch: only when building the options

    p.add_argument("gaussians", type=Path, help=gaussians_help())
    p.add_argument(
        "--orbit", type=int, required=True, metavar="N", help="number of cameras (>= 1), split over the rings"
    )
    add_output_option(p, "the cameras file: a .json (transforms, graphdeco), or a folder (colmap); written atomically")
    p.add_argument(
        "--format",
        choices=FORMATS,
        default="transforms",
        help="transforms: a Blender / NeRF / nerfstudio transforms.json; graphdeco: a cameras.json as the "
        "3DGS trainer writes; colmap: cameras.txt, images.txt and an empty points3D.txt in a folder",
    )
    p.add_argument("--width", type=int, default=320, help="image width in pixels; the height is 3/4 of it")
    g = p.add_argument_group("frame")
    add_frame_arguments(g, scale=False)
    config, _ = physics_config_class()
    add_config_options(g, config, ("opacity_threshold",), probe_overrides())
    add_orbit_arguments(p)
    add_gaussian_file_arguments(p)


NO_POINTS = "# 3D point list: none (cameras only)\n"


def check_colmap_folder(out: Path) -> None:
    """Refuse a folder that holds a reconstruction: its points3D.txt would be replaced by none (one written here holds
    only :data:`NO_POINTS`), and beside .bin model files, which readers take before .txt, the cameras written here
    would be ignored."""
    from recon.colmap import BINARY_FILES

    found = [name for name in BINARY_FILES if (out / name).is_file()]
    if (out / "points3D.txt").is_file():
        with open(out / "points3D.txt", encoding="utf-8", errors="replace") as fh:
            found += [] if fh.read(len(NO_POINTS)) == NO_POINTS else ["points3D.txt"]
    if found:
        raise ValueError(
            f"-o {out} holds a COLMAP model ({', '.join(found)}) that --format colmap would replace or hide; "
            "write the cameras into a new folder"
        )


def run_command(args: argparse.Namespace) -> int:
    from fluidsim.files import atomic_files, check_not_input, write_json_atomic
    from nbv.orbit import MAX_ORBIT_CAMERAS, object_sphere
    from nbv.physics.scene_frame import parse_up, up_label
    from recon.camera import MAX_IMAGE_SIDE
    from recon.camera_files import colmap_text, graphdeco_json, transforms_json
    from recon.camera_paths import framing_distance

    from .options import orbit_cameras_logged, orbit_from_args

    if not 1 <= args.orbit <= MAX_ORBIT_CAMERAS:  # this command's option, not the --cameras orbit:N it stands for
        raise ValueError(f"--orbit must be a number of cameras from 1 to {MAX_ORBIT_CAMERAS:,}, got {args.orbit}")
    if not 1 <= args.width <= MAX_IMAGE_SIDE:
        raise ValueError(f"--width must be a positive number of pixels, at most {MAX_IMAGE_SIDE:,}, got {args.width}")
    orbit = orbit_from_args(argparse.Namespace(**{**vars(args), "cameras": f"orbit:{args.orbit}"}), args.width)
    config = physics_config_from_args(args, steps=1)
    out = Path(args.output)
    if args.format == "colmap":
        if out.suffix:
            raise ValueError(
                f"-o {out}: --format colmap writes a folder (cameras.txt, images.txt, points3D.txt); "
                "pass a folder name such as sparse/0"
            )
        files = {name: out / name for name in ("cameras.txt", "images.txt", "points3D.txt")}
        for f in files.values():
            check_output_file(f, (".txt",))
    else:
        check_output_file(out, (".json",))
        files = {out.name: out}
    check_not_input([("-o", f) for f in files.values()], gaussian_file_inputs(args))
    if args.format == "colmap":
        check_colmap_folder(out)
    gaussians = load_gaussians_checked(args.gaussians, args)
    warn_frame(config, up_given=args.up is not None)
    cams = orbit_cameras_logged(gaussians, config, orbit)
    note = (
        f"fluidgs cameras {args.gaussians} --orbit {args.orbit} --up {up_label(parse_up(config.up))}: "
        f"{orbit.describe()}"
    )
    if args.format == "transforms":
        write_json_atomic(out, transforms_json(cams, note))
    elif args.format == "graphdeco":
        write_json_atomic(out, graphdeco_json(cams))
    else:
        out.mkdir(parents=True, exist_ok=True)
        cameras_txt, images_txt = colmap_text(cams)
        with atomic_files(out) as tmp:  # the three together: never one new file beside two of an earlier run
            for name, text in (("cameras.txt", cameras_txt), ("images.txt", images_txt), ("points3D.txt", NO_POINTS)):
                (tmp / name).write_bytes(text.encode("utf-8"))
    centre, radius = object_sphere(gaussians, config, f"orbit:{args.orbit}")
    distance = framing_distance(radius, math.radians(orbit.fov_x_deg), orbit.width, orbit.height)
    print(
        f"{len(cams)} cameras ({orbit.describe()}) looking at ({', '.join(f'{c:.4g}' for c in centre)}), "
        f"{distance:.4g} scene units away (object sphere radius {radius:.4g}) -> {out} ({args.format})"
    )
    return 0
