"""`fluidgs score GAUSSIANS.ply --cameras transforms.json -o scores.json`: rank candidate views by S(T) (Eq. 4-5).

S(T) = sum over the Gaussians visible in view T of w_g D_g, with w_g = clamp(pi R_g^2 / (H W), 0, 1) from the
renderer's screen-space radii R_g. D_g comes from RESULT.h5 (``--result``) or from a fresh probe run.
Prints a ranked table and writes scores.json (per candidate: index, name, score, rank, visible count; and
the settings) and, per view, a PNG with the render beside a D_g heat-map of the same view (the Gaussians
re-coloured by D_g on the TURBO map, rendered with the same camera), rank and score written on it.

Cameras: a Blender / NeRF-synthetic ``transforms.json`` (``camera_angle_x`` or ``fl_x``, frames with
``transform_matrix``); the image size from ``w``/``h`` keys, else the frame's image file, else ``--res``.
The cameras' frame must be the Gaussians' frame (scene units).
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from fluidsim.directions import DIRECTIONS
from fluidsim.files import write_json_atomic

from .export import add_solid_export_arguments, solid_export_outputs, write_solid_export
from .options import (
    add_camera_arguments,
    add_physics_arguments,
    add_record_arguments,
    check_output_file,
    load_gaussians_checked,
    physics_config_from_args,
    record_config_from_args,
    save_diverged,
)

log = logging.getLogger("fluidgs")
METRICS = ("max", "mean", *DIRECTIONS)  # --metric: nbv.view_scoring.metric_values
PNG_TOP = 5  # views rendered to PNG by default (the scores themselves need no render)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("gaussians", type=Path, help="Gaussians (.ply, .compressed.ply, .spz, .splat, .npz), scene units")
    add_camera_arguments(p)
    p.add_argument("-o", "--output", type=Path, required=True, help="scores JSON file (written atomically)")
    p.add_argument("--result", type=Path, default=None,
                   help="RESULT.h5 of `fluidgs simulate` for these Gaussians (default: simulate now)")
    p.add_argument("--save-result", type=Path, default=None, help="when simulating, also write RESULT.h5 here")
    p.add_argument("--top-k", type=int, default=None, help="print only the best K views (default: all)")
    p.add_argument("--metric", choices=METRICS, default="max",
                   help="per-Gaussian metric: D_g max over probes, mean over probes, or one probe's D_g (1/s)")
    p.add_argument("--unweighted", action="store_true", help="sum D_g over visible Gaussians without Eq. 5 weights")
    p.add_argument("--occlusion", action="store_true",
                   help="count only Gaussians not hidden behind the others (a coarse depth buffer of the projected "
                        "centres, composited front to back in cells of about one footprint radius; not in the "
                        "paper, whose visibility is frustum culling)")
    p.add_argument("--png-dir", type=Path, default=None,
                   help="folder for the per-view PNGs (default: next to the output, <stem>_views)")
    p.add_argument("--no-png", action="store_true", help="skip the per-view PNGs")
    p.add_argument("--png-top", type=int, default=PNG_TOP,
                   help="render PNGs of the best N views only (scores need no render; default: %(default)s)")
    p.add_argument("--png-all", action="store_true", help="render a PNG of every candidate view")
    add_record_arguments(p)
    add_solid_export_arguments(p)
    add_physics_arguments(p, cameras=True)


def obtain_result(args, gaussians, config, record=None):
    """PhysicsResult from --result, or a fresh simulation (then saved to --save-result when given; ``record``: the
    probes to record, :class:`nbv.physics.trajectory.RecordConfig`)."""
    from nbv.physics import check_result_matches, load_result, save_result, simulate_gaussians

    from .runtime import init_taichi

    if args.result is not None:
        result = load_result(args.result)
        check_result_matches(result, gaussians, args.result)
        for d, notes in result.warnings.items():  # a fresh simulation logs them as its probes end
            for note in notes:
                log.warning("%s, probe %s: %s", args.result, d, note)
        return result
    init_taichi(args.device, config.precision, args.threads)
    result = simulate_gaussians(gaussians, config, progress=True, source=str(args.gaussians), record=record)
    if args.save_result is not None:
        save_result(args.save_result, result)
    return result


def run_command(args: argparse.Namespace) -> int:
    from fluidsim.files import check_not_input
    from nbv.physics import ProbeDiverged
    from nbv.view_scoring import (
        check_cameras_see,
        check_some_divergence,
        format_table,
        parse_candidates,
        render_size,
        score_views,
    )
    from recon.datasets import load_cameras

    all_cams = load_cameras(args.cameras, args.res)
    config = physics_config_from_args(args, cameras=all_cams)
    output = check_output_file(args.output, (".json",))
    if args.top_k is not None and args.top_k < 1:
        raise ValueError(f"--top-k must be >= 1, got {args.top_k}")
    if args.png_top < 1:
        raise ValueError(f"--png-top must be >= 1 view, got {args.png_top}; use --no-png for no PNGs")
    png_dir = None if args.no_png else (args.png_dir or output.with_name(output.stem + "_views"))
    check_not_input({"-o": output, "--save-result": args.save_result, "--png-dir": png_dir,
                     **solid_export_outputs(args.export_solid)},
                    {"GAUSSIANS": args.gaussians, "--cameras": args.cameras, "--result": args.result})
    if png_dir is not None:
        check_output_file(png_dir / "view.png", (".png",))
    if args.save_result is not None:
        check_output_file(args.save_result, (".h5", ".hdf5"))
    if args.result is None and args.metric not in ("max", "mean") and args.metric not in config.directions:
        raise ValueError(f"--metric {args.metric} needs that probe in --directions ({','.join(config.directions)})")
    record = record_config_from_args(args, config)
    if record is not None and (args.result is not None or args.save_result is None):
        raise ValueError("--record-probe records into the RESULT.h5 of a fresh simulation: pass --save-result "
                         "RESULT.h5" + (" and drop --result" if args.result is not None else ""))
    gaussians = load_gaussians_checked(args.gaussians)
    idx = parse_candidates(args.candidates, len(all_cams))
    cams = [render_size(all_cams[i], args.render_width) for i in idx]
    visible_centres = check_cameras_see(gaussians, cams, [c.name for c in cams])
    try:
        result = obtain_result(args, gaussians, config, record)
    except ProbeDiverged as exc:
        return save_diverged(exc, args.save_result)
    check_some_divergence(result, args.metric, args.result or args.gaussians)
    rows = score_views(gaussians, cams, idx, result, args.metric, png_dir, weighted=not args.unweighted,
                       occlusion=args.occlusion, device=args.device, visible_centres=visible_centres,
                       png_top=None if args.png_all else args.png_top)
    print(format_table(rows, args.top_k))
    write_json_atomic(output, {"cameras": str(args.cameras), "gaussians": str(args.gaussians), "metric": args.metric,
                        "weighted": not args.unweighted, "occlusion": args.occlusion, "dbar_m4_s": result.dbar,
                        "dbar_empty_m4_s": result.dbar_empty, "views": rows, "config": result.config.to_dict()})
    print(f"scores: {output}" + (f"\nviews: {png_dir}" if png_dir is not None else ""))
    write_solid_export(args.export_solid, result, args.export_frame)
    h5 = args.result or args.save_result
    if h5 is not None:
        print(f"see them in a browser: fluidgs view {h5} --gaussians {args.gaussians} --scores {output}")
    return 0
