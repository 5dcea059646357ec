"""How :mod:`viz.frames` draws a simulation file: the colour quantity, the view, the frame size, the walls
(:class:`FrameStyle`, validated on construction), below :mod:`viz.frame_source`, which reads the file for it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from fluidsim.config import check_choices

# color_by -> (dataset in each frame group, colour-bar title, unit)
COLOR_BY = {
    "divergence": ("divergence", "|div v|", "1/s"),
    "speed": ("v", "speed |v|", "m/s"),
}
VIEWS = ("front", "side", "top", "iso")
WALLS = ("hidden", "faint", "shown")
FRAMES = ("object", "domain")
MIN_WIDTH, MIN_HEIGHT = 160, 120


@dataclass(frozen=True)
class FrameStyle:
    """How frames are drawn. Validated on construction.

    Attributes:
        color_by: "divergence" (|div v| [1/s]) or "speed" (|v| [m/s]).
        view: "front", "side", "top" or "iso"; see the module docstring for the axes.
        width, height: frame size [px], at least 160 x 120; an .mp4 pads an odd size by one edge pixel.
        point_size: dot radius [px]; 0 draws single pixels.
        vmax: top of the colour scale [1/s or m/s]; None takes the 99th percentile over all frames.
        show_boundary: draw ``/boundary/x`` (the solid, and the walls as ``walls`` says) when the file has it.
        fps: frames per second of the .mp4 video (ignored for PNG output).
        walls: "hidden", "faint" (dark grey, behind everything) or "shown" (grey).
        frame: "object" (the camera frames the solid, grown by 35 % of its size per side) or "domain" (the box).
    """

    color_by: str = "divergence"
    view: str = "front"
    width: int = 960
    height: int = 720
    point_size: int = 2
    vmax: float | None = None
    show_boundary: bool = True
    fps: int = 30
    walls: str = "hidden"
    frame: str = "object"

    def __post_init__(self) -> None:
        choices = {"color_by": sorted(COLOR_BY), "view": VIEWS, "walls": WALLS, "frame": FRAMES}
        check_choices(self, choices, "FrameStyle.")
        for name, low in (("width", MIN_WIDTH), ("height", MIN_HEIGHT), ("point_size", 0), ("fps", 1)):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < low:
                raise ValueError(f"FrameStyle.{name}={value!r} must be an int >= {low}")
        if self.vmax is not None:
            if isinstance(self.vmax, bool) or not isinstance(self.vmax, (int, float)):
                raise ValueError(f"FrameStyle.vmax={self.vmax!r} must be a float or None")
            if not (math.isfinite(self.vmax) and self.vmax > 0):
                raise ValueError(f"FrameStyle.vmax={self.vmax!r} must be finite and > 0")
        if not isinstance(self.show_boundary, bool):
            raise ValueError(f"FrameStyle.show_boundary={self.show_boundary!r} must be a bool")
