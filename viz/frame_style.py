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
MAX_SIDE = 8192  # px: an 8K frame is 200 MB, drawn with several buffers of its size (H.264 itself stops at 16384)
MAX_POINT_SIZE = 24  # px: each dot is stamped (2 r + 1)^2 times, so the drawing time grows as r^2
MAX_FPS = 240  # FFmpeg writes an MP4 of 1000 frames per second or more as 0 fps
# field -> the (low, high) integers it may take
INT_RANGES = {
    "width": (MIN_WIDTH, MAX_SIDE),
    "height": (MIN_HEIGHT, MAX_SIDE),
    "point_size": (0, MAX_POINT_SIZE),
    "fps": (1, MAX_FPS),
}


@dataclass(frozen=True)
class FrameStyle:
    """How frames are drawn. Validated on construction.

    Attributes:
        color_by: "divergence" (|div v| [1/s]) or "speed" (|v| [m/s]).
        view: "front", "side", "top" or "iso"; see the module docstring for the axes.
        width, height: frame size [px], from 160 x 120 to 8192 x 8192; an .mp4 pads an odd size by one edge pixel.
        point_size: dot radius [px], at most 24; 0 draws single pixels.
        vmax: top of the colour scale [1/s or m/s]; None takes the 99th percentile over all frames.
        show_boundary: draw ``/boundary/x`` (the solid, and the walls as ``walls`` says) when the file has it.
        fps: frames per second of the .mp4 video, 1 to 240 (ignored for PNG output).
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
        for name, (low, high) in INT_RANGES.items():
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or not low <= value <= high:
                raise ValueError(f"FrameStyle.{name}={value!r} must be an int from {low} to {high}")
        if self.vmax is not None:
            if isinstance(self.vmax, bool) or not isinstance(self.vmax, (int, float)):
                raise ValueError(f"FrameStyle.vmax={self.vmax!r} must be a float or None")
            if not (math.isfinite(self.vmax) and self.vmax > 0):
                raise ValueError(f"FrameStyle.vmax={self.vmax!r} must be finite and > 0")
        if not isinstance(self.show_boundary, bool):
            raise ValueError(f"FrameStyle.show_boundary={self.show_boundary!r} must be a bool")
