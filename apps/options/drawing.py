"""The drawing options of :class:`viz.frame_style.FrameStyle` (``--color-by``, ``--view``, ``--walls``, ...), shared
by ``render-frames`` and ``simulate --video``."""

from __future__ import annotations

import argparse
import math

from viz.frame_style import COLOR_BY, FRAMES, INT_RANGES, VIEWS, WALLS, FrameStyle

from .fields import add_config_options, config_values
from .numbers import int_in

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
            "type": int_in(*INT_RANGES["width"]),
            "help": "frame width in pixels; an .mp4 pads an odd width by one pixel",
        },
        "height": {
            "type": int_in(*INT_RANGES["height"]),
            "help": "frame height in pixels; an .mp4 pads an odd height by one pixel",
        },
        "point_size": {"type": int_in(*INT_RANGES["point_size"]), "help": "dot radius in pixels, 0 = one pixel"},
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
        "fps": {"type": int_in(*INT_RANGES["fps"]), "help": "video frame rate in frames per second, .mp4 only"},
    }


def add_style_arguments(parser, defaults: str = "") -> None:
    """The drawing options of :class:`viz.frames.FrameStyle` (``--color-by``, ``--view``, ``--walls``, ...), shared
    by ``render-frames`` and ``simulate --video``; ``defaults`` is appended to the group's description."""
    group = parser.add_argument_group("drawing", "how the frames are drawn" + defaults)
    add_config_options(group, FrameStyle, STYLE_FIELDS, style_overrides())


def style_values(args: argparse.Namespace) -> dict:
    """The drawing options given on the command line, as FrameStyle fields (the others are left out)."""
    return config_values(FrameStyle, args, STYLE_FIELDS, style_overrides())


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be finite and > 0, got {text}")
    return value
