"""`fluidgs bench views`: view scores S(T) from the projection alone, timed and checked against full renders.

Two parts, both printed:

- **Ranking check** on the bundled asset (``assets/ahmed_gaussians.ply`` with its 40 candidate cameras, or
  ``--gaussians`` / ``--cameras``), at the width ``fluidgs score`` uses (``--render-width``): every candidate
  is rendered in full (what scoring did before) and scored both ways (:mod:`nbv.bench.score_agreement`). It prints the
  largest relative score difference, the Spearman rank correlation and whether the two orders are identical. With
  ``--occlusion`` the coarse depth buffer (:class:`nbv.scores.DepthBuffer`) is compared with the render-based depth
  test (:func:`nbv.scores.unoccluded`): the fraction of visible (view, Gaussian) pairs with the same verdict and
  the Spearman correlation of the two S(T). D_g comes from ``--result`` (a RESULT.h5 of these Gaussians);
  without it a seeded log-normal stand-in is used (the check is about radii and visibility, not physics).
- **Timing** (the targets: 200 candidate cameras on 1M Gaussians in <= 5 s on 2 cores without the depth test,
  <= 15 s with it, no PNGs): the set densified to ``--count`` Gaussians by jittered copies
  (:func:`nbv.bench.dense_sets.jittered_to_count`: each copy moved by N(0, r_g^2) per axis, r_g the largest principal
  standard deviation; D_g from ``--result`` repeated with them), scored from an orbit of ``--views`` cameras around it
  (``--cameras orbit:N``'s rings, 50 degree field of view, ``--width`` x 3/4 ``--width`` pixels) on ``--threads``
  threads. It prints the wall and CPU time, the time per view, the Gaussian-views (camera, Gaussian pairs) per
  second and the peak resident memory, for frustum culling and, with ``--occlusion``, the coarse depth test. The
  one-thread reference path (:func:`nbv.scores.projected_view_scores_reference`) then scores the first
  ``--reference-views`` cameras, and so does the fast path, one after the other: the ratio of their times and the
  largest relative difference of their scores.

A fixed reference workload (single-thread 512 x 512 float32 matmuls, as ``bench render``) and the load
average are printed next to the figures: machines are shared, quote ratios.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from fluidsim.files import write_json_atomic

from ..options.common import (
    AHMED_CAMERAS,
    add_device_option,
    add_gaussians_option,
    add_json_option,
    add_seed_option,
)
from ..options.numbers import camera_count, image_width, int_in
from ..runtime import thread_count

MAX_COUNT = 10_000_000  # as bench render's sets: 10^11 asked torch for 800 GB and ended in a traceback


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_gaussians_option(p, "Gaussian set (default: the bundled asset)")
    p.add_argument(
        "--cameras",
        type=Path,
        default=AHMED_CAMERAS,
        help="candidate cameras of the ranking check (default: the bundled asset's)",
    )
    p.add_argument(
        "--result",
        type=Path,
        default=None,
        help="RESULT.h5 of these Gaussians for D_g (default: a seeded log-normal stand-in)",
    )
    p.add_argument(
        "--render-width",
        type=image_width,
        default=320,
        help="width of the ranking check's views, as `fluidgs score` (default: %(default)s)",
    )
    p.add_argument(
        "--occlusion",
        action="store_true",
        help="also compare the coarse depth buffer with the render-based depth test, and time it",
    )
    p.add_argument("--no-ranking", action="store_true", help="skip the ranking check (no full renders)")
    p.add_argument(
        "--count",
        type=int_in(1, MAX_COUNT),
        default=1_000_000,
        help="Gaussians of the timing set (jittered copies of --gaussians; default: %(default)s)",
    )
    p.add_argument("--views", type=camera_count, default=200, help="cameras of the timing run (default: %(default)s)")
    p.add_argument(
        "--width",
        type=image_width,
        default=320,
        help="image width of the timing run's cameras, pixels (height 3/4 of it)",
    )
    p.add_argument(
        "--threads",
        type=thread_count,
        default=None,
        help="CPU threads scoring cameras side by side (default: torch's thread count, the cores)",
    )
    p.add_argument(
        "--reference-views",
        type=int_in(0, 10_000),
        default=20,
        help="cameras scored by the one-thread reference path too, for the speed-up and the score difference "
        "(0: none; default: %(default)s)",
    )
    add_device_option(p, "torch device; cuda falls back to cpu with a warning (default: %(default)s)")
    add_seed_option(p, "seed of the jitter, the cameras and the stand-in D_g")
    add_json_option(p)


def run_command(args: argparse.Namespace) -> int:
    import torch

    from nbv.bench.score_agreement import (
        compare_with_renders,
        load_divergence,
        ranking_lines,
        time_projected_scores,
        timing_lines,
    )
    from nbv.view_scoring import render_size
    from recon.datasets import load_cameras
    from recon.device import torch_device

    from ..options import check_output_file, load_gaussians_checked
    from .yardsticks import reference_ms

    if args.json is not None:
        check_output_file(args.json, (".json",))
    device = torch.device(torch_device(args.device))
    gaussians = load_gaussians_checked(args.gaussians)
    d, source = load_divergence(args.result, gaussians, args.seed)
    load = os.getloadavg()
    ref_before = reference_ms()
    report: dict = {"gaussians_file": str(args.gaussians), "metric": source, "device": str(device)}
    if not args.no_ranking:
        cams = [render_size(c, args.render_width) for c in load_cameras(args.cameras, None)]
        report["ranking"] = compare_with_renders(gaussians, cams, d, args.occlusion, device)
        print("\n".join(ranking_lines(report["ranking"], source)))
    report["timing"] = time_projected_scores(
        gaussians,
        d,
        args.count,
        args.views,
        args.width,
        args.seed,
        args.occlusion,
        device,
        threads=args.threads,
        reference_views=args.reference_views,
    )
    print("\n".join(timing_lines(report["timing"])))
    ref_after = reference_ms()
    print(
        f"machine load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}; reference workload (512^2 matmul, "
        f"1 thread) {ref_before:.1f} ms before, {ref_after:.1f} ms after; torch threads {torch.get_num_threads()}"
    )
    report.update(load_average=load, reference_ms=[ref_before, ref_after])
    if args.json is not None:
        write_json_atomic(args.json, report)
    return 0
