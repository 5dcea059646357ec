"""`fluidgs render-frames OUT.h5 -o frames.mp4`: the frames of a simulation (or a RESULT.h5 probe) as MP4 or PNGs.

The command line only: the renderer (orthographic views, depth-sorted dots, colour bar, H.264 video that browsers
play) is :mod:`viz.frames`, whose docstring gives the file layout, the views and the drawing model.
"""

from __future__ import annotations

import argparse
import logging
import math
from pathlib import Path

from viz.frame_style import COLOR_BY, FRAMES, MIN_HEIGHT, MIN_WIDTH, VIEWS, WALLS, FrameStyle
from viz.frames import output_is_video, render_frames

from .options import add_config_options, config_from_args, config_values

__all__ = ["FrameStyle", "add_arguments", "main", "output_is_video", "render_frames", "run"]


STYLE_FIELDS = ("color_by", "view", "frame", "walls", "width", "height", "point_size", "vmax", "show_boundary", "fps")


def style_overrides() -> dict[str, dict]:
    """The render-frames names, types and wording of the :class:`viz.frames.FrameStyle` fields."""
    return {
        "color_by": {
            "choices": sorted(COLOR_BY),
            "help": "particle colour: divergence |div v| in 1/s, or speed |v| in m/s",
        },
        "view": {
            "choices": VIEWS,
            "help": "orthographic camera: front looks along -z, side along +x, top along -y, "
            "iso from the (+x,+y,+z) corner",
        },
        "width": {
            "type": _int_at_least(MIN_WIDTH),
            "help": "frame width in pixels; an .mp4 pads an odd width by one pixel",
        },
        "height": {
            "type": _int_at_least(MIN_HEIGHT),
            "help": "frame height in pixels; an .mp4 pads an odd height by one pixel",
        },
        "point_size": {"type": _int_at_least(0), "help": "dot radius in pixels, 0 = one pixel"},
        "vmax": {
            "type": _positive_float,
            "default_text": "the 99th percentile over all frames",
            "help": "top of the colour scale in 1/s (divergence) or m/s (speed), fixed across frames",
        },
        "frame": {
            "choices": FRAMES,
            "help": "what the camera frames: object (the solid's box grown by 35 %% of its "
            "size per side) or domain (the whole box, its edges drawn)",
        },
        "walls": {
            "choices": WALLS,
            "help": "the wall particles: hidden, faint (dark grey) or shown (grey), always "
            "behind the solid and the fluid",
        },
        "show_boundary": {
            "flags": ("--no-boundary",),
            "dest": "no_boundary",
            "negate": True,
            "help": "draw neither the solid nor the walls of /boundary/x",
            "default_text": "the solid in ivory, the walls as --walls says",
        },
        "fps": {"type": _int_at_least(1), "help": "video frame rate in frames per second, .mp4 only"},
    }


def add_style_arguments(parser, defaults: str = "") -> None:
    """The drawing options of :class:`viz.frames.FrameStyle` (``--color-by``, ``--view``, ``--walls``, ...), shared
    by ``render-frames`` and ``simulate --video``; ``defaults`` is appended to the group's description."""
    group = parser.add_argument_group("drawing", "how the frames are drawn" + defaults)
    add_config_options(group, FrameStyle, STYLE_FIELDS, style_overrides())


def style_values(args: argparse.Namespace) -> dict:
    """The drawing options given on the command line, as FrameStyle fields (the others are left out)."""
    return config_values(FrameStyle, args, STYLE_FIELDS, style_overrides())


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ``render-frames`` arguments to a parser; :func:`run` consumes the parsed namespace."""
    parser.add_argument(
        "h5",
        type=Path,
        help="simulation output file (OUT.h5), or a RESULT.h5 with a recorded probe (simulate or score --record-probe)",
    )
    parser.add_argument(
        "-o",
        "--output",
        type=Path,
        required=True,
        help="a path ending in .mp4 writes one H.264 video (plays in browsers); a path without a suffix is a "
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


def _int_at_least(low: int):
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < low:
            raise argparse.ArgumentTypeError(f"must be >= {low}, got {value}")
        return value

    return parse


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be finite and > 0, got {text}")
    return value


if __name__ == "__main__":
    raise SystemExit(main())
