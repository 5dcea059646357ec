"""`fluidgs critical GAUSSIANS.ply --cameras CAMERAS`: function-critical views (paper Sec. 3.4).

One probe (-x by default) runs with distinct-particle tracking: |P_g| is the number of distinct fluid particles
that came within n r_g of Gaussian g. Each camera gets C(T) = sum_g w_g |P_g| (w_g of Eq. 5) over the Gaussians it
counts (the depth test by default; ``--frustum-only``: the paper's frustum culling); the top ``--subset`` views (20
by default) form the critical subset. Prints what the probe reached (D-bar / D-bar_empty first, the share of the
Gaussians reached, the leaks), the ranking with its parts (the coverage A(T) and C(T) / A(T)) and one line on how far
coverage decides it (:mod:`nbv.coverage`); writes JSON.
A subset that holds half of the candidates or more is no selection: it is logged as a warning and stored as
``subset_warning``. ``--result`` reuses a RESULT.h5 with distinct-particle counts (one that ``critical --save-result``
wrote) instead of simulating, as ``score --result`` does.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from .options import (
    add_camera_arguments,
    add_gaussians_input,
    add_physics_arguments,
    add_visibility_arguments,
    check_output_file,
    check_visibility_arguments,
    gaussian_file_inputs,
    load_gaussians_checked,
    physics_config_from_args,
    warn_frame,
)
from .options.cameras import candidate_cameras_from_args, orbit_cameras_logged, write_orbit_cameras
from .options.common import add_output_option
from .options.scoring import obtain_result
from .runtime import positive_int

log = logging.getLogger("fluidgs")


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_gaussians_input(p)
    add_camera_arguments(p)
    add_output_option(
        p, "JSON with C(T) per camera and the critical subset (written atomically)", default=Path("critical.json")
    )
    p.add_argument("--subset", type=int, default=20, help="size of the critical subset (views)")
    p.add_argument("--top-k", type=positive_int, default=None, help="print only the best K views (default: all)")
    add_visibility_arguments(p)
    p.add_argument(
        "--result",
        type=Path,
        default=None,
        help="RESULT.h5 with distinct-particle counts for these Gaussians, from critical --save-result "
        "(default: simulate now)",
    )
    p.add_argument(
        "--save-result", type=Path, default=None, help="when simulating, also write RESULT.h5 here (default: none)"
    )
    add_physics_arguments(p, track_distinct=True, cameras=True, replicas=True)


def run_command(args: argparse.Namespace) -> int:
    from fluidsim.files import check_not_input, write_json_atomic
    from nbv.critical_views import critical_record, rank_critical_views, subset_warning
    from nbv.view_scoring import check_cameras_see, parse_candidates, render_size

    check_visibility_arguments(args)
    if args.subset < 1:
        raise ValueError(f"--subset must be >= 1 view, got {args.subset}")
    orbit, file_cams = candidate_cameras_from_args(args, args.render_width)
    config = physics_config_from_args(args, track_distinct=True, default_directions=("-x",), cameras=file_cams)
    output = check_output_file(args.output, (".json",))
    orbit_file = output.with_name(output.stem + "_cameras.json") if orbit is not None else None
    check_not_input(
        {"-o": output, "-o (orbit cameras)": orbit_file, "--save-result": args.save_result},
        [*gaussian_file_inputs(args), ("--cameras", None if orbit else args.cameras), ("--result", args.result)],
    )
    if args.save_result is not None:
        if args.result is not None:
            raise ValueError("--save-result writes the RESULT.h5 of a fresh simulation; drop it with --result")
        check_output_file(args.save_result, (".h5", ".hdf5"))
    gaussians = load_gaussians_checked(args.gaussians, args)
    result = None if args.result is None else counted_result(args, gaussians)
    if result is not None:  # the result fixes the frame (up, crop) that the cameras use
        config = result.config
    warn_frame(config, file_cams, up_given=args.up is not None or args.result is not None)
    all_cams = file_cams if orbit is None else orbit_cameras_logged(gaussians, config, orbit)
    idx = parse_candidates(args.candidates, len(all_cams))
    cams = [render_size(all_cams[i], args.render_width) for i in idx]
    check_cameras_see(gaussians, cams, [c.name for c in cams])
    if result is None:
        result = obtain_result(args, gaussians, config)
    distinct = result.distinct_counts()
    if not distinct.any():
        raise ValueError(
            f"{args.gaussians}: no probe fluid particle came within reach of any of the {len(distinct)} "
            "Gaussians, so every view would score C(T) = 0; re-run with a smaller --dt, or check "
            "--scale and --up"
        )
    # C(T) = sum_g w_g |P_g| needs only the projection's radii and visibility (no render)
    occlusion = not args.frustum_only
    views = rank_critical_views(distinct, gaussians, cams, idx, result, args.subset, occlusion, args.device)
    print_critical(result, distinct, views, idx, args.top_k)
    too_many = subset_warning(len(views.subset), len(idx))
    if too_many is not None:
        log.warning("%s", too_many)
    cameras = orbit_file or args.cameras
    record = critical_record(views, distinct, idx, result, cameras, args.gaussians, occlusion, args.result, too_many)
    # the orbit cameras with their record, not before the probes: a run that fails leaves an earlier run's pair as is
    write_orbit_cameras(orbit_file, all_cams, "critical", args.cameras, orbit)
    write_json_atomic(output, record)
    print(f"critical views: {output}" + (f"\ncameras: {orbit_file} ({orbit.describe()})" if orbit_file else ""))
    return 0


def counted_result(args: argparse.Namespace, gaussians):
    """The RESULT.h5 of --result, checked against the Gaussians and for its distinct-particle counts |P_g|."""
    from nbv.physics import check_result_matches, load_result

    result = load_result(args.result)
    check_result_matches(result, gaussians, args.result)
    if result.per_probe_distinct is None:
        raise ValueError(
            f"--result {args.result} has no distinct-particle counts |P_g| (a simulate or score "
            "result); write one with `fluidgs critical ... --save-result RESULT.h5`, or drop --result"
        )
    return result


def print_critical(result, distinct, views, idx: list[int], top_k: int | None) -> None:
    """What the probe reached, the ranking by C(T), how far coverage decides it, and the critical subset."""
    from nbv.coverage import agreement_lines, one_run_line
    from nbv.view_scoring import format_table, probe_lines, reach_warning

    print("\n".join(probe_lines(result)))
    warning = reach_warning(distinct, views.scored.seen, result.config, "fluid particle", "C")
    if warning is not None:
        log.warning("%s", warning)
    print(format_table(views.rows, top_k, value="critical_score"))
    print("\n".join(agreement_lines(views.agreement, "fluid-particle count", "C")))
    if result.replicas is None:
        print(one_run_line("C"))
    print(f"critical subset ({len(views.subset)} views): {[idx[k] for k in views.subset]}")
