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

import numpy as np

from .options import (
    add_camera_arguments,
    add_gaussian_file_arguments,
    add_physics_arguments,
    add_visibility_arguments,
    camera_file_from_args,
    check_output_file,
    check_visibility_arguments,
    load_gaussians_checked,
    orbit_cameras_logged,
    orbit_from_args,
    physics_config_from_args,
    warn_frame,
)

log = logging.getLogger("fluidgs")


def add_arguments(p: argparse.ArgumentParser) -> None:
    from recon.formats import gaussians_help  # noqa: PLC0415 - the readers load torch: only when building the options

    p.add_argument(
        "gaussians",
        type=Path,
        help=gaussians_help(),
    )
    add_gaussian_file_arguments(p)
    add_camera_arguments(p)
    p.add_argument(
        "-o",
        "--output",
        type=Path,
        default=Path("critical.json"),
        help="JSON with C(T) per camera and the critical subset (written atomically)",
    )
    p.add_argument("--subset", type=int, default=20, help="size of the critical subset (views)")
    p.add_argument("--top-k", type=int, default=None, help="print only the best K views (default: all)")
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


log = logging.getLogger("fluidgs")


def subset_warning(subset: int, candidates: int) -> str | None:
    """The warning for a critical subset of ``subset`` views out of ``candidates``: None below half of them."""
    if 2 * subset < candidates:
        return None
    return (
        f"the critical subset holds {subset} of the {candidates} candidate views (half or more), so it selects "
        f"little; pass a smaller --subset (e.g. {max(1, candidates // 4)}) or more candidates"
    )


def run_command(args: argparse.Namespace) -> int:
    import torch

    from fluidsim.files import check_not_input, write_json_atomic
    from nbv.coverage import agreement_lines, one_run_line
    from nbv.physics import check_result_matches, load_result, save_result, simulate_gaussians
    from nbv.scores import DepthBuffer, critical_subset, projected_view_scores
    from nbv.view_scoring import (
        check_cameras_see,
        format_table,
        parse_candidates,
        probe_lines,
        ranked_rows,
        reach_warning,
        render_size,
        replicas_view_agreement,
        rows_agreement,
    )
    from recon.device import torch_device

    from .runtime import init_taichi

    check_visibility_arguments(args)
    if args.subset < 1:
        raise ValueError(f"--subset must be >= 1 view, got {args.subset}")
    orbit = orbit_from_args(args, args.render_width)
    file_cams = None if orbit is not None else camera_file_from_args(args)
    config = physics_config_from_args(args, track_distinct=True, default_directions=("-x",), cameras=file_cams)
    output = check_output_file(args.output, (".json",))
    orbit_file = output.with_name(output.stem + "_cameras.json") if orbit is not None else None
    check_not_input(
        {"-o": output, "-o (orbit cameras)": orbit_file, "--save-result": args.save_result},
        {"GAUSSIANS": args.gaussians, "--cameras": None if orbit else args.cameras, "--result": args.result},
    )
    if args.save_result is not None:
        if args.result is not None:
            raise ValueError("--save-result writes the RESULT.h5 of a fresh simulation; drop it with --result")
        check_output_file(args.save_result, (".h5", ".hdf5"))
    gaussians = load_gaussians_checked(args.gaussians, args)
    result = None
    if args.result is not None:  # the result fixes the frame (up, crop) that the cameras use
        result = load_result(args.result)
        check_result_matches(result, gaussians, args.result)
        if result.per_probe_distinct is None:
            raise ValueError(
                f"--result {args.result} has no distinct-particle counts |P_g| (a simulate or score "
                "result); write one with `fluidgs critical ... --save-result RESULT.h5`, or drop --result"
            )
        config = result.config
    warn_frame(config, file_cams, up_given=args.up is not None or args.result is not None)
    all_cams = file_cams if orbit is None else orbit_cameras_logged(gaussians, config, orbit)
    if orbit_file is not None:
        from recon.camera_files import transforms_json

        write_json_atomic(
            orbit_file, transforms_json(all_cams, f"fluidgs critical --cameras {args.cameras}: {orbit.describe()}")
        )
    idx = parse_candidates(args.candidates, len(all_cams))
    cams = [render_size(all_cams[i], args.render_width) for i in idx]
    check_cameras_see(gaussians, cams, [c.name for c in cams])
    if result is None:
        init_taichi(args.device, config.precision, args.threads)
        result = simulate_gaussians(
            gaussians, config, progress=True, source=str(args.gaussians), source_frame=getattr(args, "source_frame", "")
        )
        if args.save_result is not None:
            save_result(args.save_result, result)
    distinct = result.distinct_counts()
    if not distinct.any():
        raise ValueError(
            f"{args.gaussians}: no probe fluid particle came within reach of any of the {len(distinct)} "
            "Gaussians, so every view would score C(T) = 0; re-run with a smaller --dt, or check "
            "--scale and --up"
        )
    # C(T) = sum_g w_g |P_g| needs only the projection's radii and visibility (no render)
    occlusion = not args.frustum_only
    scored = projected_view_scores(
        torch.from_numpy(distinct).to(torch.float64),
        gaussians.to(torch_device(args.device)),
        cams,
        depth_buffer=DepthBuffer() if occlusion else None,
    )
    subset = critical_subset(scored.scores, args.subset).tolist()
    rows = ranked_rows(scored, cams, idx, value="critical_score")
    agreement = rows_agreement(rows, "critical_score")
    if result.replicas is not None:  # each replica's own ranking by its |P_g|, against the others
        agreement["replicas"] = replicas_view_agreement(
            result.replicas,
            result.replicas.distinct_counts(),
            gaussians,
            cams,
            idx,
            occlusion=occlusion,
            device=args.device,
        )
    print("\n".join(probe_lines(result)))
    warning = reach_warning(distinct, scored.seen, result.config, "fluid particle", "C")
    if warning is not None:
        log.warning("%s", warning)
    print(format_table(rows, args.top_k, value="critical_score"))
    print("\n".join(agreement_lines(agreement, "fluid-particle count", "C")))
    if result.replicas is None:
        print(one_run_line("C"))
    print(f"critical subset ({len(subset)} views): {[idx[k] for k in subset]}")
    too_many = subset_warning(len(subset), len(idx))
    if too_many is not None:
        log.warning("%s", too_many)
    write_json_atomic(
        output,
        {
            "cameras": str(orbit_file or args.cameras),
            "gaussians": str(args.gaussians),
            "directions": list(result.directions),
            "occlusion": occlusion,
            "dbar_m4_s": result.dbar,
            "dbar_empty_m4_s": result.dbar_empty,
            "distinct_particles": {
                "total_over_gaussians": int(distinct.sum()),
                "gaussians_reached": int((distinct > 0).sum()),
                "max": int(np.max(distinct)),
            },
            "agreement": agreement,
            "views": rows,
            "critical_subset": [idx[k] for k in subset],
            "subset_warning": too_many,
            "result": None if args.result is None else str(args.result),
            "config": result.config.to_dict(),
        },
    )
    print(f"critical views: {output}" + (f"\ncameras: {orbit_file} ({orbit.describe()})" if orbit_file else ""))
    return 0
