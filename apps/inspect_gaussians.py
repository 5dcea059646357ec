"""`fluidgs inspect GAUSSIANS`: what the fluid will see, in a few seconds (no simulation).

Prints the file format, count, SH degree, raw and robust boxes, opacity and scale quantiles, the share of
Gaussians outside the robust box, the scene -> simulation transform and the solid particle count at the
probes' spacing; ``--png`` draws front, side and top views of the centres with the solid over them
(:func:`nbv.inspection.inspection_views`), ``--json`` writes the figures.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from .runtime import positive_int
from .simulate import add_frame_arguments, check_output_file, physics_config_from_args


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("gaussians", type=Path,
                   help="Gaussians: 3DGS .ply, SuperSplat compressed .ply, .spz, .splat or .npz (scene units)")
    g = p.add_argument_group("frame and solid")
    add_frame_arguments(g)
    g.add_argument("--quick", action="store_true", help="the quick preset's spacing: r = 0.05 m (default: 0.025 m)")
    g.add_argument("--particle-radius", type=float, default=None,
                   help="fluid particle radius r in m; the solid lattice spacing is 2 r (default: 0.025, the paper's)")
    g.add_argument("--opacity-threshold", type=float, default=0.3,
                   help="tau: opacity at or above which Gaussians make solid (unitless, 0..1; default: 0.3)")
    g.add_argument("--no-fill", action="store_true",
                   help="keep the solid a shell: do not fill what a closed surface encloses (default: filled)")
    g.add_argument("--fill-cavities", action="store_true",
                   help="accepted for old scripts and does nothing: filling is the default (see --no-fill)")
    p.add_argument("--png", type=Path, default=None, help="write the three orthographic views here (.png)")
    p.add_argument("--json", type=Path, default=None, help="write the figures here (.json)")
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                   help="compute device for the solid; cuda falls back to cpu with a logged warning (default: cpu)")
    p.add_argument("--threads", type=positive_int, default=None, help="CPU threads (default: all cores)")


def run_command(args: argparse.Namespace) -> int:
    import cv2

    from nbv.active import write_atomic, write_json_atomic
    from nbv.inspection import describe, inspect_gaussians, inspection_views
    from recon.formats import load_gaussians_with_format

    from .runtime import init_taichi

    for path, suffix in ((args.png, ".png"), (args.json, ".json")):
        if path is not None:
            check_output_file(path, (suffix,))
    from fluidsim.output import check_not_input

    check_not_input({"--png": args.png, "--json": args.json}, {"GAUSSIANS": args.gaussians})
    # the probe options the config needs but inspect does not offer
    args.steps, args.dt, args.speed, args.viscosity, args.directions = 1, 0.002, 3.0, 10.0, None
    args.accumulate_every, args.max_memory_gb = 1, None
    config = physics_config_from_args(args)
    if not Path(args.gaussians).exists():
        raise ValueError(f"Gaussian file {args.gaussians} does not exist")
    gaussians, fmt = load_gaussians_with_format(args.gaussians)
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
        write_atomic(args.png, lambda tmp: _write_png(tmp, image, cv2))
        print(f"png: {args.png}")
    return 0


def _write_png(path: Path, image, cv2) -> None:
    ok, data = cv2.imencode(".png", image)
    if not ok:
        raise OSError(f"cannot encode the PNG for {path}")
    Path(path).write_bytes(data.tobytes())
