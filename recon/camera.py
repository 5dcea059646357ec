"""Pinhole cameras in the OpenCV convention (x right, y down, z forward), as the 3DGS rasterizer uses.

A :class:`Camera` holds the image size, the intrinsics (fx, fy, cx, cy in pixels) and the 4x4
world-to-camera transform. A camera-frame point (x, y, z) lands at (u, v) = (fx x/z + cx, fy y/z + cy);
pixel i covers [i, i + 1) and its centre is at i + 0.5, so cx = width / 2 is the image centre (this
matches the reference rasterizer, whose ndc-to-pixel map puts the centre at (W - 1) / 2 in pixel-index
coordinates). Blender / NeRF-synthetic files store OpenGL camera-to-world matrices
(y up, z backward); :meth:`Camera.from_opengl_c2w` converts them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import torch

# OpenGL camera axes (x right, y up, z back) -> OpenCV (x right, y down, z forward).
_GL_TO_CV = torch.diag(torch.tensor([1.0, -1.0, -1.0, 1.0], dtype=torch.float64))


# The largest image width or height, pixels: 8 times an 8K frame. A larger image cannot be rendered (65,536^2 pixels
# of float32 RGB are 48 GiB) and is a corrupt or mistyped camera file.
MAX_IMAGE_SIDE = 65536


@dataclass(frozen=True)
class Camera:
    """One pinhole view.

    Attributes:
        width, height: image size, pixels.
        fx, fy: focal lengths, pixels. cx, cy: principal point, pixels (image centre = width / 2).
        world_to_camera: [4, 4] rigid transform, world -> OpenCV camera frame (float64 on the CPU).
        name: an identifier (the image file stem in a dataset).
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    world_to_camera: torch.Tensor = field(repr=False)
    name: str = ""

    def __post_init__(self) -> None:
        for key in ("width", "height"):
            val = getattr(self, key)
            if int(val) != val or val <= 0:
                raise ValueError(f"Camera {self.name!r}: {key} must be a positive integer, got {val}")
            if val > MAX_IMAGE_SIDE:
                raise ValueError(
                    f"Camera {self.name!r}: {key} {int(val):,} pixels is more than {MAX_IMAGE_SIDE:,}, the largest "
                    "image side a camera may have (its image would not fit in memory, and every view's score would "
                    "tie); fix the camera's image size"
                )
            object.__setattr__(self, key, int(val))
        for key in ("fx", "fy", "cx", "cy"):
            val = float(getattr(self, key))
            if not math.isfinite(val) or (key in ("fx", "fy") and val <= 0):
                raise ValueError(
                    f"Camera {self.name!r}: {key} must be finite{' and > 0' if key[0] == 'f' else ''}, got {val}"
                )
            object.__setattr__(self, key, val)
        m = torch.as_tensor(self.world_to_camera, dtype=torch.float64).detach().cpu()
        if tuple(m.shape) != (4, 4) or not torch.isfinite(m).all():
            raise ValueError(
                f"Camera {self.name!r}: world_to_camera must be a finite (4, 4) matrix, got shape {tuple(m.shape)}"
            )
        rot = m[:3, :3]
        if not torch.allclose(rot @ rot.T, torch.eye(3, dtype=torch.float64), atol=1e-4):
            raise ValueError(f"Camera {self.name!r}: the rotation part of world_to_camera is not orthonormal")
        object.__setattr__(self, "world_to_camera", m)

    # ---- constructors ----------------------------------------------------------------------------
    @classmethod
    def from_opengl_c2w(cls, c2w, width: int, height: int, fov_x: float, name: str = "") -> Camera:
        """A camera from a Blender/NeRF camera-to-world matrix (OpenGL axes) and horizontal FOV (radians)."""
        c2w = (
            torch.as_tensor(c2w, dtype=torch.float64).reshape(4, 4)
            if torch.as_tensor(c2w).numel() == 16
            else torch.cat(
                [
                    torch.as_tensor(c2w, dtype=torch.float64).reshape(3, 4),
                    torch.tensor([[0, 0, 0, 1.0]], dtype=torch.float64),
                ]
            )
        )
        if not 0 < fov_x < math.pi:
            raise ValueError(f"camera_angle_x must be in (0, pi) radians, got {fov_x}")
        focal = 0.5 * width / math.tan(0.5 * fov_x)
        w2c = torch.linalg.inv(c2w @ _GL_TO_CV)
        return cls(width, height, focal, focal, width / 2.0, height / 2.0, w2c, name)

    @classmethod
    def look_at(cls, eye, target, up, width: int, height: int, fov_x: float, name: str = "") -> Camera:
        """A camera at ``eye`` looking at ``target`` with ``up`` roughly up in the image (fov_x in radians)."""
        eye, target, up = (torch.as_tensor(v, dtype=torch.float64).reshape(3) for v in (eye, target, up))
        forward = target - eye
        if forward.norm() == 0:
            raise ValueError(f"camera {name!r}: eye and target coincide")
        forward = forward / forward.norm()
        right = torch.linalg.cross(forward, up)
        if right.norm() < 1e-9:  # looking along up: pick any perpendicular
            alt = (
                torch.tensor([1.0, 0, 0], dtype=torch.float64)
                if abs(forward[0]) < 0.9
                else torch.tensor([0, 1.0, 0], dtype=torch.float64)
            )
            right = torch.linalg.cross(forward, alt)
        right = right / right.norm()
        down = torch.linalg.cross(forward, right)
        rot = torch.stack([right, down, forward])  # rows: camera axes in world coordinates
        w2c = torch.eye(4, dtype=torch.float64)
        w2c[:3, :3] = rot
        w2c[:3, 3] = -rot @ eye
        focal = 0.5 * width / math.tan(0.5 * fov_x)
        return cls(width, height, focal, focal, width / 2.0, height / 2.0, w2c, name)

    # ---- derived ----------------------------------------------------------------------------------
    @property
    def camera_to_world(self) -> torch.Tensor:
        """[4, 4] OpenCV camera -> world."""
        return torch.linalg.inv(self.world_to_camera)

    @property
    def center(self) -> torch.Tensor:
        """[3] camera position in world coordinates."""
        r, t = self.world_to_camera[:3, :3], self.world_to_camera[:3, 3]
        return -r.T @ t

    @property
    def fov_x(self) -> float:
        return 2.0 * math.atan(0.5 * self.width / self.fx)

    @property
    def fov_y(self) -> float:
        return 2.0 * math.atan(0.5 * self.height / self.fy)

    def intrinsics(self) -> torch.Tensor:
        """[3, 3] K (float64)."""
        return torch.tensor([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]], dtype=torch.float64)

    def opengl_c2w(self) -> torch.Tensor:
        """[4, 4] camera-to-world in the OpenGL axes of Blender / NeRF-synthetic files."""
        return self.camera_to_world @ _GL_TO_CV

    def scaled(self, factor: float) -> Camera:
        """The same view at ``factor`` times the resolution (e.g. 0.5 halves width and height)."""
        if not factor > 0:
            raise ValueError(f"scale factor must be > 0, got {factor}")
        w, h = max(1, round(self.width * factor)), max(1, round(self.height * factor))
        sx, sy = w / self.width, h / self.height
        return replace(self, width=w, height=h, fx=self.fx * sx, fy=self.fy * sy, cx=self.cx * sx, cy=self.cy * sy)

    def project(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Pixel coordinates and depths of world points.

        Args:
            points: [N, 3] world coordinates.
        Returns:
            uv [N, 2] pixels (continuous; pixel i spans [i, i + 1)), depth [N] along the optical axis.
        """
        w2c = self.world_to_camera.to(points)
        pc = points @ w2c[:3, :3].T + w2c[:3, 3]
        z = pc[:, 2]
        uv = torch.stack([self.fx * pc[:, 0] / z + self.cx, self.fy * pc[:, 1] / z + self.cy], -1)
        return uv, z
