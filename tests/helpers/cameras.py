"""The candidate cameras the app tests share: a ring around the origin, written as a ``transforms.json``."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from recon.camera import Camera

FOV = math.radians(50)


def ring_cameras(count: int) -> list[Camera]:
    """``count`` 48x40 cameras (fov 50 degrees) on a ring of radius 2.5 m, 0.3 m up, looking at the origin."""
    return [
        Camera.look_at((2.5 * math.cos(a), 0.3, 2.5 * math.sin(a)), (0, 0, 0), (0, 1, 0), 48, 40, FOV, name=f"cam{k}")
        for k, a in enumerate(np.arange(count) * math.pi / (count / 2))
    ]


def write_transforms(path: Path, cams: list[Camera], width: int = 48, height: int = 40, fov: float = FOV) -> Path:
    """``cams`` as a ``transforms.json`` at ``path`` (the image size and fov as given); the path."""
    frames = [{"file_path": f"./{c.name}", "transform_matrix": c.opengl_c2w().tolist()} for c in cams]
    path.write_text(json.dumps({"camera_angle_x": fov, "w": width, "h": height, "frames": frames}))
    return path
