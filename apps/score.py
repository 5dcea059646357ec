"""`fluidgs score GAUSSIANS.ply --cameras CAMERAS -o scores.json`: rank candidate views by S(T) (Eq. 4-5).

S(T) = sum over the Gaussians visible in view T of w_g D_g, with w_g = clamp(pi R_g^2 / (H W), 0, 1) from the
renderer's screen-space radii R_g. D_g comes from RESULT.h5 (``--result``) or from a fresh probe run.
Visibility: the coarse depth test by default (a Gaussian hidden behind the others does not count); ``--frustum-only``
is the paper's frustum culling.

Prints what each probe reached, a ranked table with the parts of S(T) = A(T) P(T) (the coverage A(T) = sum of w_g
over the same counted Gaussians, and the physics part P(T) = S / A) and one line on how far coverage decides the
ranking (:mod:`nbv.coverage`); writes scores.json (per candidate: index, name, score, coverage, physics_mean, their
ranks, visible count; the top-level ``agreement``; and the settings) and, per view, a PNG with the render beside a
D_g heat-map of the same view (the Gaussians re-coloured by D_g on the TURBO map, rendered with the same camera, "+"
where clipped), rank and parts written on it; with ``--uncertainty-images`` also the per-pixel composited D_g.

Cameras: ``orbit:N`` (N cameras on rings around the robust object box, :mod:`nbv.orbit`; written beside the
scores as ``<stem>_cameras.json``), or any camera file of :func:`recon.camera_files.load_camera_file`: a Blender /
NeRF / nerfstudio ``transforms.json`` (the image size from ``w``/``h`` keys, else the frame's image file, else
``--res``), a COLMAP model folder, or graphdeco's ``cameras.json``. The cameras' frame must be the Gaussians' frame
(scene units).
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from fluidsim.directions import DIRECTIONS
from fluidsim.files import write_json_atomic

from .options import (
    add_camera_arguments,
    add_gaussians_input,
    add_physics_arguments,
    add_record_arguments,
    add_visibility_arguments,
    camera_file_from_args,
    load_gaussians_checked,
    orbit_cameras_logged,
    orbit_from_args,
    physics_config_from_args,
    result_overridden_options,
    save_diverged,
    warn_frame,
)
from .options.scoring import (
    add_view_image_arguments,
    check_score_arguments,
    obtain_result,
    score_outputs,
    write_orbit_cameras,
)
from .options.solid_export import add_solid_export_arguments, write_solid_export

log = logging.getLogger("fluidgs")
METRICS = ("max", "mean", *DIRECTIONS)  # --metric: nbv.view_scoring.metric_values


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_gaussians_input(p)
    add_camera_arguments(p)
    p.add_argument("-o", "--output", type=Path, required=True, help="scores JSON file (written atomically)")
    p.add_argument(
        "--result",
        type=Path,
        default=None,
        help="RESULT.h5 of `fluidgs simulate` for these Gaussians (default: simulate now)",
    )
    p.add_argument("--save-result", type=Path, default=None, help="when simulating, also write RESULT.h5 here")
    p.add_argument("--top-k", type=int, default=None, help="print only the best K views (default: all)")
    p.add_argument(
        "--metric",
        choices=METRICS,
        default="max",
        help="per-Gaussian metric: D_g max over probes, mean over probes, or one probe's D_g (1/s)",
    )
    p.add_argument("--unweighted", action="store_true", help="sum D_g over visible Gaussians without Eq. 5 weights")
    add_visibility_arguments(p)
    add_view_image_arguments(p)
    add_record_arguments(p)
    add_solid_export_arguments(p)
    add_physics_arguments(p, cameras=True, replicas=True)


def run_command(args: argparse.Namespace) -> int:
    from nbv.physics import ProbeDiverged
    from nbv.view_scoring import (
        ScoreSettings,
        check_cameras_see,
        check_some_divergence,
        parse_candidates,
        rank_views,
        render_size,
        scores_record,
        write_views_folder,
    )

    check_score_arguments(args)
    settings = ScoreSettings(args.metric, not args.unweighted, not args.frustum_only, args.device)
    orbit = orbit_from_args(args, args.render_width)
    file_cams = None if orbit is not None else camera_file_from_args(args)
    config = physics_config_from_args(args, cameras=file_cams)
    output, png_dir, orbit_file, record = score_outputs(args, config, orbit)
    gaussians = load_gaussians_checked(args.gaussians, args)
    result = None
    if args.result is not None:  # the result fixes the frame (up, crop) that the cameras and the scores use
        ignored = result_overridden_options(args) + ([f"--save-result {args.save_result}"] if args.save_result else [])
        if ignored:
            log.warning("--result %s fixes the probes and the frame: ignored %s", args.result, ", ".join(ignored))
        result = obtain_result(args, gaussians, config)
        config = result.config
    warn_frame(config, file_cams, up_given=args.up is not None or args.result is not None)
    all_cams = file_cams if orbit is None else orbit_cameras_logged(gaussians, config, orbit)
    idx = parse_candidates(args.candidates, len(all_cams))
    cams = [render_size(all_cams[i], args.render_width) for i in idx]
    check_cameras_see(gaussians, cams, [c.name for c in cams], at_most=1)  # the counts come with the scores
    if result is None:
        try:
            result = obtain_result(args, gaussians, config, record)
        except ProbeDiverged as exc:
            return save_diverged(exc, args.save_result)
    values = check_some_divergence(result, args.metric, args.result or args.gaussians)
    scored, rows, agreement = rank_views(gaussians, cams, idx, result, values, settings, centres=True)
    print_ranking(result, values, scored.seen, rows, agreement, args.top_k)
    top = None if args.png_all else args.png_top
    images, stale = write_views_folder(
        gaussians,
        cams,
        scored,
        rows,
        values,
        settings,
        png_dir,
        top=top,
        uncertainty=args.uncertainty_images,
        reached=result.reached,
    )
    if stale:
        log.info("removed %d view images of an earlier run from %s", len(stale), stale[0].parent)
    cameras = orbit_file if orbit_file is not None else args.cameras
    scores = scores_record(rows, agreement, result, settings, cameras, args.gaussians, images, png_dir)
    # the orbit cameras with their scores, not before the probes: a run that fails leaves an earlier run's pair as is
    write_orbit_cameras(orbit_file, all_cams, "score", args.cameras, orbit)
    write_json_atomic(output, scores)
    print(
        f"scores: {output}"
        + (f"\ncameras: {orbit_file} ({orbit.describe()})" if orbit_file is not None else "")
        + (f"\nviews: {png_dir}" if png_dir is not None else "")
    )
    write_solid_export(args.export_solid, result, args.export_frame)
    h5 = args.result or args.save_result
    if h5 is not None:
        print(f"see them in a browser: fluidgs view {h5} --gaussians {args.gaussians} --scores {output}")
    return 0


def print_ranking(result, values, seen, rows: list[dict], agreement: dict, top_k: int | None) -> None:
    """What the probes reached, the ranked table and how far coverage decides the ranking."""
    from nbv.coverage import agreement_lines, one_run_line
    from nbv.physics.forces import force_lines
    from nbv.view_scoring import format_table, probe_lines, reach_warning

    print("\n".join(probe_lines(result) + force_lines(result.forces)))
    warning = reach_warning(values, seen, result.config)
    if warning is not None:
        log.warning("%s", warning)
    print(format_table(rows, top_k))
    print("\n".join(agreement_lines(agreement)))
    if result.replicas is None:
        print(one_run_line())
