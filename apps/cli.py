"""The `fluidgs` command: one entry point, one subcommand per job."""

from __future__ import annotations

import argparse
import logging
import sys

from . import bench, demo, render_frames, sim

COMMANDS = {
    "sim": (sim, "run a scene JSON and write OUT.h5 (frames, per-step stats, divergence)"),
    "render-frames": (render_frames, "draw the frames of OUT.h5 as an MP4 or PNGs, coloured by divergence or speed"),
    "bench": (bench, "benchmarks: sim (DFSPH probe vs SPlisHSPlasH), and the others listed by `bench --help`"),
    "demo": (demo, "five fluid probes against the bundled solid: HDF5, summary.json and a video"),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="fluidgs", description="FluidGaussian: fluid probes for 3DGS geometry.")
    parser.add_argument("-v", "--verbose", action="store_true", help="log more (default: warnings and info)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (module, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text,
                           formatter_class=argparse.ArgumentDefaultsHelpFormatter)
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
