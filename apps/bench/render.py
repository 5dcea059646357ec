"""`fluidgs bench render`: forward + backward time of the differentiable rasterizer (recon.render).

Scene: N seeded random Gaussians in the cube [-1, 1]^3 seen from 4 m by a
60-degree camera, SH degree 3, opacities sigmoid(N(0, 1.5)), per-axis scales log-normal around 2 cm.
Sizes are in world units, so the footprints average about 3 px of radius at 100 x 100 and about
5 px at 200 x 200 (a trained scene's scale: a few pixels; the command prints the measured mean).
The loss is a weighted sum of the image, alpha and depth maps; the figure is the median of forward +
backward over the repeats. A fixed reference workload (single-thread 512 x 512 float32 matmuls) is
timed next to it so that figures taken on a loaded machine can be judged: quote ratios, not absolute
times.
"""

from __future__ import annotations

import argparse
import logging
import os

import torch

from fluidsim.files import write_json_atomic

from ..options.common import add_device_option, add_json_option, add_seed_option
from ..options.numbers import int_in
from ..runtime import thread_count
from .yardsticks import reference_workload_ms

LOG = logging.getLogger("fluidgs.bench.render")
# (Gaussians, width, height) -> target ms for forward + backward on one thread (the rasterizer's targets)
TARGETS_MS = {(5000, 100, 100): 40.0, (20000, 200, 200): 450.0}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--threads",
        type=thread_count,
        default=1,
        help="torch CPU threads; the targets are for 1 (default: %(default)s)",
    )
    p.add_argument(
        "--repeats",
        type=int_in(1, 100_000),
        default=10,
        help="timed forward+backward passes per case, after one warm-up pass (default: %(default)s)",
    )
    p.add_argument(
        "--sizes",
        type=str,
        default="5000@100x100,20000@200x200",
        help="comma-separated N@WxH cases: N Gaussians, W x H pixels (default: %(default)s)",
    )
    add_device_option(p, "compute device; cuda falls back to cpu with a warning (default: %(default)s)")
    p.add_argument(
        "--backend",
        choices=("torch", "gsplat", "auto"),
        default="torch",
        help="renderer backend (default: %(default)s)",
    )
    add_seed_option(p, "random seed of the scene (default: %(default)s)")
    add_json_option(p, "also write the figures to this JSON file (default: %(default)s, no file)", type=str)


def parse_sizes(text: str) -> list[tuple[int, int, int]]:
    """Parse "N@WxH,..." into (N, W, H) tuples; ValueError naming the bad item."""
    cases = []
    for item in filter(None, (s.strip() for s in text.split(","))):
        try:
            n, res = item.split("@")
            w, h = res.lower().split("x")
            case = (int(n), int(w), int(h))
        except ValueError as exc:
            raise ValueError(f"--sizes item {item!r} is not N@WxH (e.g. 5000@100x100)") from exc
        if min(case) <= 0:
            raise ValueError(f"--sizes item {item!r}: N, W and H must be positive")
        if case[0] > 10_000_000 or max(case[1:]) > 8192:  # 10^9 Gaussians at 10^5 px was killed for memory
            raise ValueError(f"--sizes item {item!r}: at most 10,000,000 Gaussians and 8192 pixels a side")
        cases.append(case)
    if not cases:
        raise ValueError(f"--sizes {text!r} holds no case; give e.g. 5000@100x100")
    return cases


def run_command(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from recon.device import torch_device
    from recon.render_bench import time_case

    from ..options import check_output_file

    cases = parse_sizes(args.sizes)
    if args.json:
        check_output_file(args.json, (".json",))  # before the timings, as the other benchmarks check theirs
    device = torch.device(torch_device(args.device))
    previous_threads = torch.get_num_threads()
    torch.set_num_threads(args.threads)
    try:
        load = os.getloadavg()
        ref_before = reference_workload_ms(device)
        results = [
            time_case(n, w, h, args.seed, args.repeats, args.backend, device, TARGETS_MS.get((n, w, h)))
            for n, w, h in tqdm(cases, desc="bench render", unit="case")
        ]
        ref_after = reference_workload_ms(device)
    finally:  # the command also runs in-process (tests): leave the thread setting as it was
        torch.set_num_threads(previous_threads)
    print(
        f"recon.render ({args.backend} backend, {device}, {args.threads} thread(s)), forward + backward, "
        f"median of {args.repeats}"
    )
    print(
        f"  machine load average (1/5/15 min): {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}; reference workload "
        f"(10 x 512^2 matmul): {ref_before:.1f} ms before, {ref_after:.1f} ms after"
    )
    for r in results:
        target = "no target"
        if r["target_ms"]:
            verdict = "met" if r["forward_backward_ms"] <= r["target_ms"] else "MISSED"
            target = f"target <= {r['target_ms']:.0f} ms ({verdict})"
        print(
            f"  {r['gaussians']} Gaussians @ {r['width']}x{r['height']} ({r['pixels']} px): {r['visible']} visible, "
            f"mean radius {r['mean_radius_px']:.1f} px, {r['candidate_pairs']} pairs in boxes, {r['pairs']} "
            f"with alpha >= 1/255 ({r['stopped_pairs']} after an early stop)"
        )
        print(f"    forward {r['forward_ms']:.1f} ms, forward+backward {r['forward_backward_ms']:.1f} ms; {target}")
    if args.json:
        write_json_atomic(
            args.json,
            {
                "backend": args.backend,
                "device": str(device),
                "threads": args.threads,
                "load_average": load,
                "reference_workload_ms": [ref_before, ref_after],
                "cases": results,
            },
        )
    return 0
