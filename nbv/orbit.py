"""Orbit cameras: candidate views on rings around the object, for a capture that comes without cameras.

No paper equation is implemented here. The paper scores views that a dataset provides; a capture downloaded or
exported on its own has none, so ``--cameras orbit:N`` builds N cameras on rings around the robust object box
(:func:`nbv.physics.config.object_box`: the box the auto scale fits, after the crop), looking at its centre with the
capture's up (``--up``) up in the image and framing the box's bounding sphere grown by :data:`FRAME_MARGIN`
(:func:`recon.camera_paths.orbit_rings`).
Azimuth 0 is the simulation frame's +z (the side the +z probe flows from), turned back into the scene frame.

The cameras' frame is the Gaussians' own (scene units); written out they are an OpenGL camera-to-world
transforms.json (:func:`recon.camera_files.transforms_json`).

Example:
    >>> cams = candidate_cameras("orbit:24", gaussians, config)  # doctest: +SKIP
"""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from nbv.physics.config import object_box
from nbv.physics.scene_frame import SceneTransform
from recon.camera_paths import ORBIT_ASPECT, ORBIT_ELEVATIONS_DEG, ORBIT_FOV_X_DEG, orbit_rings
from recon.frames import camera_up_vectors

log = logging.getLogger(__name__)
# The framed sphere's radius over the robust box's half diagonal: the Gaussians reach past their centres, and the
# robust box leaves out 0.5 % of them per side.
FRAME_MARGIN = 1.15
_ORBIT = re.compile(r"^orbit:(.*)$", re.IGNORECASE)
MAX_ORBIT_CAMERAS = 10_000  # a camera file may hold more; an orbit of more is a typo (orbit:10000000)


@dataclass(frozen=True)
class Orbit:
    """Rings of candidate cameras around the object.

    Attributes:
        count: number of cameras (>= 1).
        elevations_deg: one elevation per ring, degrees above the horizon, in (-90, 90).
        fov_x_deg: horizontal field of view, degrees in (0, 180).
        width: image width, pixels; the height is ``ORBIT_ASPECT`` times it.
    """

    count: int
    elevations_deg: tuple[float, ...] = ORBIT_ELEVATIONS_DEG
    fov_x_deg: float = ORBIT_FOV_X_DEG
    width: int = 320

    def __post_init__(self) -> None:
        if isinstance(self.count, bool) or int(self.count) != self.count or self.count < 1:
            raise ValueError(
                f"--cameras orbit:{self.count}: an orbit needs at least 1 camera; pass orbit:N with "
                "N >= 1, e.g. --cameras orbit:24"
            )
        if self.count > MAX_ORBIT_CAMERAS:  # each camera is rendered or projected: bounded before any work
            raise ValueError(
                f"--cameras orbit:{self.count}: at most {MAX_ORBIT_CAMERAS} cameras may be scored; pass orbit:N "
                "with fewer, e.g. --cameras orbit:24"
            )
        if not self.elevations_deg or not all(-90.0 < e < 90.0 for e in self.elevations_deg):
            raise ValueError(
                f"--elevations {','.join(f'{e:g}' for e in self.elevations_deg)}: each ring's elevation "
                "must be in (-90, 90) degrees, e.g. --elevations 15,45"
            )
        if not 0.0 < self.fov_x_deg < 180.0:
            raise ValueError(f"--orbit-fov {self.fov_x_deg:g} must be in (0, 180) degrees, e.g. 50")
        if int(self.width) != self.width or self.width < 1:
            raise ValueError(f"the image width must be a positive number of pixels, got {self.width}")

    @property
    def height(self) -> int:
        return max(1, round(ORBIT_ASPECT * self.width))

    def describe(self) -> str:
        """One line: count, rings, field of view and size."""
        return (
            f"an orbit of {self.count} cameras on rings at {', '.join(f'{e:g}' for e in self.elevations_deg)} "
            f"deg elevation, {self.fov_x_deg:g} deg horizontal field of view, {self.width}x{self.height} px"
        )


def orbit_count(spec) -> int | None:
    """``"orbit:N"`` -> N (any integer, checked by :class:`Orbit`); None for anything else (a camera file's path).

    Raises:
        ValueError: ``orbit:`` followed by something that is not an integer (the message names --cameras).
    """
    m = _ORBIT.match(str(spec).strip())
    if m is None:
        return None
    try:
        return int(m.group(1))
    except ValueError:
        raise ValueError(
            f"--cameras {spec}: orbit:N takes a whole number of cameras, e.g. --cameras orbit:24"
        ) from None


def object_sphere(gaussians, config, spec: str = "orbit") -> tuple[np.ndarray, float]:
    """(centre [3] in the scene frame, radius in scene units) of the sphere around the robust object box of
    ``gaussians`` under ``config`` (its up, crop and opacity threshold): the box's centre and half its diagonal
    times :data:`FRAME_MARGIN`.

    Raises:
        ValueError: the crop keeps no Gaussian, or the box has no extent (both name the option and the fix).
    """
    box = object_box(gaussians, config)
    radius = 0.0 if box is None else FRAME_MARGIN * 0.5 * float(np.linalg.norm(box[1] - box[0]))
    if not radius > 0:
        kept = "the Gaussians" if config.crop is None else f"the Gaussians inside --crop {config.crop}"
        raise ValueError(
            f"--cameras {spec}: {kept} have no extent to orbit around (fewer than two, or all at one "
            "point); widen --crop, or pass a camera file"
        )
    to_scene = SceneTransform(config.up, 1.0).rotation.T  # simulation axes -> scene axes
    return to_scene @ (0.5 * (box[0] + box[1])), radius


def orbit_cameras(gaussians, config, orbit: Orbit) -> list:
    """The :class:`Orbit` cameras around :func:`object_sphere`, in the Gaussians' frame: azimuth 0 on the
    simulation frame's +z side.

    Raises:
        ValueError: the crop keeps no Gaussian, or the box has no extent (both name the option and the fix).
    """
    centre, radius = object_sphere(gaussians, config, f"orbit:{orbit.count}")
    frame = SceneTransform(config.up, 1.0)
    front = frame.rotation.T @ np.array([0.0, 0.0, 1.0])
    return orbit_rings(
        orbit.count,
        centre,
        radius,
        np.asarray(frame.up),
        front,
        orbit.elevations_deg,
        orbit.width,
        orbit.height,
        math.radians(orbit.fov_x_deg),
    )


def angle_to_camera_up(up: Sequence[float], cameras) -> tuple[float, np.ndarray] | None:
    """(angle in degrees between ``up`` and the cameras' mean up vector, that mean as a unit vector), or None when
    the cameras' up vectors cancel out (rolled every way)."""
    mean = camera_up_vectors(cameras).mean(axis=0)
    norm = float(np.linalg.norm(mean))
    if norm < 1e-6:
        return None
    u = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    mean = mean / norm
    return float(np.degrees(np.arccos(np.clip(u @ mean, -1.0, 1.0)))), mean
