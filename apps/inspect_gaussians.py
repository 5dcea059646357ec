"""`fluidgs inspect GAUSSIANS`: what the fluid will see, in a few seconds (no simulation).

Prints the file format, count, SH degree, raw and robust boxes, opacity and scale quantiles, the share of
Gaussians outside the robust box, the scene -> simulation transform and the solid particle count at the
probes' spacing; ``--png`` draws front, side and top views of the centres with the solid over them
(:func:`nbv.inspection.inspection_views`), ``--json`` writes the figures.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from fluidsim.files import check_input_file

from .options import (
    add_config_options,
    add_frame_arguments,
    add_gaussians_input,
    check_output_file,
    gaussian_file_inputs,
    physics_config_class,
    physics_config_from_args,
    probe_overrides,
    warn_frame,
)
from .options.common import add_device_option, add_json_option
from .runtime import thread_count


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_gaussians_input(p)
    g = p.add_argument_group("frame and solid")
    add_frame_arguments(g)
    config, quick = physics_config_class()
    g.add_argument(
        "--quick",
        action="store_true",
        help=f"the quick preset's spacing: r = {quick['particle_radius']} m (default: the paper's, "
        f"{config.particle_radius} m)",
    )
    over = probe_overrides()
    add_config_options(
        g,
        config,
        ("particle_radius", "opacity_threshold", "fill_cavities"),
        over,
        presets={"--quick": {"particle_radius": quick["particle_radius"]}},
    )
    p.add_argument("--png", type=Path, default=None, help="write the three orthographic views here (.png)")
    add_json_option(p, "write the figures here (.json)")
    add_device_option(p, "compute device for the solid; cuda falls back to cpu with a logged warning (default: cpu)")
    p.add_argument("--threads", type=thread_count, default=None, help="CPU threads (default: all cores)")


def run_command(args: argparse.Namespace) -> int:
    from nbv.inspection import describe, inspect_gaussians, inspection_views
    from nbv.io import check_not_input, write_json_atomic, write_png_atomic
    from recon.formats import LoadOptions, load_gaussians_framed

    from .runtime import init_taichi

    for path, suffix in ((args.png, ".png"), (args.json, ".json")):
        if path is not None:
            check_output_file(path, (suffix,))
    check_not_input({"--png": args.png, "--json": args.json}, gaussian_file_inputs(args))
    config = physics_config_from_args(args, steps=1)  # inspect runs no probe; the other fields keep their defaults
    check_input_file(args.gaussians, "Gaussian file", folder_ok=True)
    gaussians, fmt, frame = load_gaussians_framed(
        args.gaussians, LoadOptions(args.spz_frame, args.colmap, args.dataparser_transforms)
    )
    print(f"frame: {frame.description}")
    warn_frame(config, up_given=args.up is not None)
    init_taichi(args.device, config.precision, args.threads)
    inspection = inspect_gaussians(gaussians, config, fmt)
    summary = {"file": str(args.gaussians), **inspection.summary}
    for line in describe(summary):
        print(line)
    if args.json is not None:
        write_json_atomic(args.json, summary)
        print(f"json: {args.json}")
    if args.png is not None:
        image = inspection_views(inspection)
        write_png_atomic(args.png, image)
        print(f"png: {args.png}")
    return 0
