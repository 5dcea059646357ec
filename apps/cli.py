"""The `fluidgs` command: one entry point, one subcommand per job."""

from __future__ import annotations

import argparse
import logging
import sys

from . import (
    active,
    bench,
    critical,
    demo,
    evaluate,
    experiment,
    make_ahmed,
    make_assets,
    render_dataset,
    render_frames,
    score,
    sim,
    simulate,
    sweep,
    train,
)
from .help_format import HelpFormatter

COMMANDS = {
    "sim": (sim, "run a scene JSON and write OUT.h5 (frames, per-step stats, divergence)"),
    "render-frames": (render_frames, "draw the frames of OUT.h5 as an MP4 or PNGs, coloured by divergence or speed"),
    "bench": (bench, "benchmarks: sim (DFSPH probe vs SPlisHSPlasH), and the others listed by `bench --help`"),
    "demo": (demo, "the main job on the bundled Ahmed Gaussians: five quick probes, D_g, view scores, PNGs, video"),
    "render-dataset": (render_dataset, "render an .obj/.stl/.ply mesh into a Blender-format dataset"),
    "train": (train, "train 3D Gaussians on a dataset: OUT.ply plus OUT.json (config, timings, test PSNR/SSIM)"),
    "make-assets": (make_assets, "regenerate the bundled trained Ahmed-body Gaussians and candidate cameras"),
    "simulate": (simulate, "five probes against a Gaussian set: per-Gaussian D_g, D-bar -> RESULT.h5, coloured .ply"),
    "score": (score, "rank candidate cameras by the view score S(T) of D_g (paper Eq. 4-5); JSON, table, PNGs"),
    "sweep": (sweep, "D-bar against inflow speed U and Reynolds number (CFL-constant dt): CSV and PNG plot"),
    "critical": (critical, "function-critical views: C(T) from distinct particle counts, top-20 subset"),
    "ahmed": (make_ahmed, "write the procedural Ahmed body (Ahmed et al. 1984, slant 0-40 deg) as .obj/.stl/.ply"),
    "active": (active, "active reconstruction: biased initial views, one planner pick per round up to the budget"),
    "eval": (evaluate, "evaluate an active run: test PSNR/SSIM/LPIPS, D-bar, Chamfer, critical-view PSNR and D-bar"),
    "experiment": (experiment, "methods x scenes x seeds of active + eval; paper-shaped tables and plots"),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="fluidgs", description="FluidGaussian: fluid probes for 3DGS geometry.")
    parser.add_argument("-v", "--verbose", action="store_true", help="log more (default: warnings and info)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (module, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text,
                           formatter_class=HelpFormatter)
        module.add_arguments(p)
        p.set_defaults(_module=module)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(levelname)s %(name)s: %(message)s")
    module = args._module
    runner = getattr(module, "run_command", None) or module.run
    try:
        return int(runner(args) or 0)
    except (ValueError, OSError, FileNotFoundError) as exc:
        logging.getLogger("fluidgs").error("%s", exc)
        return 2


if __name__ == "__main__":
    sys.exit(main())
