"""`fluidgs critical GAUSSIANS.ply --cameras transforms.json`: function-critical views (paper Sec. 3.4).

One probe (-x by default) runs with distinct-particle tracking: |P_g| is the number of distinct fluid particles
that came within n r_g of Gaussian g. Each camera gets C(T) = sum_g w_g |P_g| (w_g of Eq. 5); the top
``--subset`` views (20 by default) form the critical subset. Prints the ranking, writes JSON. A subset that holds
half of the candidates or more is no selection: it is logged as a warning and stored as ``subset_warning``.
``--result`` reuses a RESULT.h5 with distinct-particle counts (one that ``critical --save-result`` wrote) instead of
simulating, as ``score --result`` does.
"""

from __future__ import annotations

import argparse
import logging
from dataclasses import replace
from pathlib import Path

import numpy as np

from .options import (
    add_camera_arguments,
    add_physics_arguments,
    check_output_file,
    load_gaussians_checked,
    physics_config_from_args,
)

log = logging.getLogger("fluidgs")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("gaussians", type=Path, help="Gaussians (.ply, .compressed.ply, .spz, .splat, .npz), scene units")
    add_camera_arguments(p)
    p.add_argument("-o", "--output", type=Path, default=Path("critical.json"),
                   help="JSON with C(T) per camera and the critical subset (written atomically)")
    p.add_argument("--subset", type=int, default=20, help="size of the critical subset (views)")
    p.add_argument("--top-k", type=int, default=None, help="print only the best K views (default: all)")
    p.add_argument("--result", type=Path, default=None,
                   help="RESULT.h5 with distinct-particle counts for these Gaussians, from critical --save-result "
                        "(default: simulate now)")
    p.add_argument("--save-result", type=Path, default=None, help="when simulating, also write RESULT.h5 here "
                                                                  "(default: none)")
    add_physics_arguments(p, track_distinct=True, cameras=True)


def subset_warning(subset: int, candidates: int) -> str | None:
    """The warning for a critical subset of ``subset`` views out of ``candidates``: None below half of them."""
    if 2 * subset < candidates:
        return None
    return (f"the critical subset holds {subset} of the {candidates} candidate views (half or more), so it selects "
            f"little; pass a smaller --subset (e.g. {max(1, candidates // 4)}) or more candidates")


def run_command(args: argparse.Namespace) -> int:
    import torch

    from fluidsim.files import check_not_input, write_json_atomic
    from nbv.physics import check_result_matches, load_result, save_result, simulate_gaussians
    from nbv.scores import critical_subset, projected_view_scores, rank
    from nbv.view_scoring import check_cameras_see, format_table, parse_candidates, render_size, torch_device
    from recon.datasets import load_cameras

    from .runtime import init_taichi

    # C(T) needs no empty-scene reference
    all_cams = load_cameras(args.cameras, args.res)
    config = replace(physics_config_from_args(args, track_distinct=True, default_directions=("-x",), cameras=all_cams),
                     empty_reference=False)
    output = check_output_file(args.output, (".json",))
    check_not_input({"-o": output, "--save-result": args.save_result},
                    {"GAUSSIANS": args.gaussians, "--cameras": args.cameras, "--result": args.result})
    if args.save_result is not None:
        if args.result is not None:
            raise ValueError("--save-result writes the RESULT.h5 of a fresh simulation; drop it with --result")
        check_output_file(args.save_result, (".h5", ".hdf5"))
    if args.subset < 1:
        raise ValueError(f"--subset must be >= 1 view, got {args.subset}")
    gaussians = load_gaussians_checked(args.gaussians)
    idx = parse_candidates(args.candidates, len(all_cams))
    cams = [render_size(all_cams[i], args.render_width) for i in idx]
    check_cameras_see(gaussians, cams, [c.name for c in cams])
    if args.result is not None:
        result = load_result(args.result)
        check_result_matches(result, gaussians, args.result)
        if result.per_probe_distinct is None:
            raise ValueError(f"--result {args.result} has no distinct-particle counts |P_g| (a simulate or score "
                             "result); write one with `fluidgs critical ... --save-result RESULT.h5`, or drop --result")
    else:
        init_taichi(args.device, config.precision, args.threads)
        result = simulate_gaussians(gaussians, config, progress=True, source=str(args.gaussians))
        if args.save_result is not None:
            save_result(args.save_result, result)
    distinct = result.distinct_counts()
    if not distinct.any():
        raise ValueError(f"{args.gaussians}: no probe fluid particle came within reach of any of the {len(distinct)} "
                         "Gaussians, so every view would score C(T) = 0; re-run with a smaller --dt, or check "
                         "--scale and --up")
    # C(T) = sum_g w_g |P_g| needs only the projection's radii and visibility (no render)
    scored = projected_view_scores(torch.from_numpy(distinct).to(torch.float64),
                                   gaussians.to(torch_device(args.device)), cams)
    c = scored.scores
    order = rank(c).tolist()
    subset = critical_subset(c, args.subset).tolist()
    rows = [{"rank": r + 1, "index": idx[k], "name": cams[k].name, "critical_score": float(c[k]),
             "visible": int(scored.counted[k])} for r, k in enumerate(order)]
    print(format_table(rows, args.top_k, value="critical_score"))
    print(f"critical subset ({len(subset)} views): {[idx[k] for k in subset]}")
    warning = subset_warning(len(subset), len(idx))
    if warning is not None:
        log.warning("%s", warning)
    write_json_atomic(output, {
        "cameras": str(args.cameras), "gaussians": str(args.gaussians), "directions": list(result.directions),
        "distinct_particles": {"total_over_gaussians": int(distinct.sum()),
                               "gaussians_reached": int((distinct > 0).sum()), "max": int(np.max(distinct))},
        "views": rows, "critical_subset": [idx[k] for k in subset], "subset_warning": warning,
        "result": None if args.result is None else str(args.result), "config": result.config.to_dict()})
    print(f"critical views: {output}")
    return 0
