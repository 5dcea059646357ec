"""`fluidgs render-frames OUT.h5 -o frames.mp4`: the frames of a simulation (or a RESULT.h5 probe) as MP4 or PNGs.

The command line only: the renderer (orthographic views, depth-sorted dots, colour bar, H.264 video that browsers
play) is :mod:`viz.frames`, whose docstring gives the file layout, the views and the drawing model.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from viz.frame_style import FrameStyle
from viz.frames import output_is_video, render_frames

from .options import add_config_options, config_from_args
from .options.common import add_output_option
from .options.drawing import STYLE_FIELDS, style_overrides

__all__ = ["FrameStyle", "add_arguments", "main", "output_is_video", "render_frames", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ``render-frames`` arguments to a parser; :func:`run` consumes the parsed namespace."""
    parser.add_argument(
        "h5",
        type=Path,
        help="simulation output file (OUT.h5), or a RESULT.h5 with a recorded probe (simulate or score --record-probe)",
    )
    add_output_option(
        parser,
        "a path ending in .mp4 writes one H.264 video (plays in browsers); a path without a suffix is a "
        "directory of frame_NNNNNN.png (other suffixes are an error)",
    )
    parser.add_argument(
        "--png",
        action="store_true",
        help="write PNG frames into the directory -o whatever its name (e.g. a folder named run.v2)",
    )
    probe_help = "for a RESULT.h5: the recorded probe to draw, -x, +x, -z, +z or -y (default: the first recorded)"
    parser.add_argument("--probe", default=None, metavar="DIR", help=probe_help)
    add_config_options(parser, FrameStyle, STYLE_FIELDS, style_overrides())


def run(args: argparse.Namespace) -> int:
    """Run ``render-frames`` on the namespace built by :func:`add_arguments`. Returns the exit code 0."""
    style = config_from_args(FrameStyle, args, STYLE_FIELDS, style_overrides())
    from fluidsim.files import check_not_input

    check_not_input({"-o": args.output}, {"H5": args.h5})
    paths = render_frames(args.h5, args.output, style, png=args.png, probe=args.probe)
    where = paths[0] if len(paths) == 1 else args.output
    print(f"wrote {len(paths)} file(s) to {where}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Standalone entry point: ``python -m apps.render_frames OUT.h5 -o frames.mp4``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_arguments(parser)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    return run(args)


if __name__ == "__main__":
    raise SystemExit(main())
