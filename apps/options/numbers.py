"""argparse types of bounded numbers: a count, a step count, a seed, an image width and a comma list of numbers,
each refused at parse time (a usage error, exit 2, naming the option) before anything is loaded or allocated.

The bounds are the library's own: :data:`fluidsim.config.MAX_STEPS` time steps, :data:`recon.train_config.MAX_SEED`
for a seed, :data:`recon.camera.MAX_IMAGE_SIDE` pixels a side. They are read when an option is parsed, so building
the parsers (``fluidgs --help``) imports none of those packages.

Example::

    p.add_argument("--steps", type=step_count, default=100)
    p.add_argument("--count", type=int_in(1, 10_000_000), default=1_000_000)
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable


def _integer(text: str, low: int, high: int) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer from {low:,} to {high:,}, got {text!r}") from None
    if not low <= value <= high:
        raise argparse.ArgumentTypeError(f"must be an integer from {low:,} to {high:,}, got {value:,}")
    return value


def int_in(low: int, high: int) -> Callable[[str], int]:
    """The argparse type of an integer from ``low`` to ``high`` (both included)."""

    def parse(text: str) -> int:
        return _integer(text, low, high)

    parse.__name__ = f"int_in_{low}_{high}"
    return parse


def step_count(text: str) -> int:
    """Time steps: an integer from 1 to :data:`fluidsim.config.MAX_STEPS` (the paper's probe runs 750)."""
    from fluidsim.config import MAX_STEPS

    return _integer(text, 1, MAX_STEPS)


def seed(text: str) -> int:
    """A random seed: an integer from 0 to :data:`recon.train_config.MAX_SEED` (a 32-bit seed)."""
    from recon.train_config import MAX_SEED

    return _integer(text, 0, MAX_SEED)


def image_width(text: str) -> int:
    """An image side in pixels: an integer from 1 to :data:`recon.camera.MAX_IMAGE_SIDE`."""
    from recon.camera import MAX_IMAGE_SIDE

    return _integer(text, 1, MAX_IMAGE_SIDE)


def positive_number(text: str) -> float:
    """A finite number > 0 (a particle radius in m, a time step in s)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text!r}")
    return value


def camera_count(text: str) -> int:
    """Cameras of an orbit: an integer from 1 to :data:`nbv.orbit.MAX_ORBIT_CAMERAS`."""
    from nbv.orbit import MAX_ORBIT_CAMERAS

    return _integer(text, 1, MAX_ORBIT_CAMERAS)


def tolerance_list(text: str) -> tuple[float, ...]:
    """A comma list of finite numbers >= 0 (``"0.01,0.02"``), at least one."""
    try:
        values = tuple(float(s) for s in text.split(",") if s.strip())
    except ValueError:
        values = ()
    if not values or not all(math.isfinite(v) and v >= 0 for v in values):
        raise argparse.ArgumentTypeError(f"must be a comma list of finite numbers >= 0 such as 0.01,0.02, got {text!r}")
    return values


def step_list(text: str) -> tuple[int, ...]:
    """A comma list of step counts (``"300,400"``; empty: none), each from 1 to :data:`fluidsim.config.MAX_STEPS`."""
    return tuple(step_count(s.strip()) for s in text.split(",") if s.strip())
