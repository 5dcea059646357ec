"""EWA projection of 3D Gaussians to screen-space conics (Zwicker et al. 2001; Kerbl et al. 2023, Sec. 4).

With the world-to-camera rotation W, a camera-frame mean t = (t_x, t_y, t_z) and the Jacobian of the
pinhole map (u, v) = (f_x t_x / t_z + c_x, f_y t_y / t_z + c_y),

    J = [[f_x / t_z, 0, -f_x t_x / t_z^2], [0, f_y / t_z, -f_y t_y / t_z^2]],

the screen-space covariance is Sigma' = J W Sigma W^T J^T + 0.3 I (Kerbl et al. Eq. 5, plus the
reference rasterizer's 0.3 px^2 low-pass dilation). Conventions of the reference CUDA code
(diff-gaussian-rasterization, ``preprocessCUDA`` / ``computeCov2D``):

- a Gaussian is culled (radius 0) when t_z <= 0.2 (the near plane);
- inside J only, t_x / t_z and t_y / t_z are clamped to +-1.3 tan(fov / 2) (the frustum guard band), so
  Gaussians far outside the view do not get huge, ill-conditioned footprints;
- the conic is the inverse of Sigma', and the radius is r = ceil(3 sqrt(lambda_max(Sigma'))).

Deliberate differences from the reference, both small:

- lambda_max = mid + sqrt(max(mid^2 - det, 0)) exactly; the reference floors the discriminant at 0.1,
  which adds up to 0.32 px^2 to lambda_max of near-isotropic splats;
- the footprint is the set of pixels whose centres lie in the square [u - r, u + r] x [v - r, v + r]
  (pixel-granular), where the reference tests 16 x 16 tiles; a Gaussian whose square holds no pixel
  centre of the image is culled (radius 0).

Pixel centres are at integer + 0.5 (see :mod:`recon.camera`), so the projected mean equals
``Camera.project`` exactly, and ``cx = W / 2`` is the image centre.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from .camera import Camera
from .gaussians import GaussianSet

NEAR_PLANE = 0.2  # camera-frame depth below which a Gaussian is culled (reference: p_view.z <= 0.2)
GUARD_BAND = 1.3  # frustum guard band of the Jacobian, in units of tan(fov / 2)
DILATION = 0.3  # px^2 added to the diagonal of the 2-D covariance (anti-aliasing low-pass)
EXTENT_SIGMAS = 3.0  # footprint half-width in standard deviations
MAX_RADIUS = 2.0**30  # radii are clamped here so that they fit int32 (the boxes are clipped to the image anyway)


@dataclass
class Projection:
    """Screen-space Gaussians of one view.

    Attributes:
        means2d: [N, 2] projected centres in pixels (continuous; pixel i spans [i, i + 1)).
        conics: [N, 3] (A, B, C) of the inverse 2-D covariance [[A, B], [B, C]], 1/px^2.
        depths: [N] camera-frame depth t_z of the means (scene units).
        radii: [N] int32 footprint half-widths in pixels, ceil(3 sqrt(lambda_max)); 0 when culled.
        boxes: [N, 4] int32 (x0, y0, x1, y1) inclusive pixel ranges of the footprints clipped to the image
            (meaningless where radii == 0).
    """

    means2d: torch.Tensor
    conics: torch.Tensor
    depths: torch.Tensor
    radii: torch.Tensor
    boxes: torch.Tensor


def camera_tensors(camera: Camera, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """World-to-camera rotation [3, 3] and translation [3] on the device and in the dtype of ``like``."""
    w2c = camera.world_to_camera.to(device=like.device, dtype=like.dtype)
    return w2c[:3, :3], w2c[:3, 3]


def footprint_boxes(means2d: torch.Tensor, radii: torch.Tensor, width: int,
                    height: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Pixel boxes covered by the footprints, clipped to the image, and whether they hold any pixel.

    A pixel (i, j) is covered when its centre (i + 0.5, j + 0.5) lies in [u - r, u + r] x [v - r, v + r].

    Args:
        means2d: [N, 2] centres (u, v), pixels (no gradient is taken).
        radii: [N] integer radii, pixels.
        width, height: image size, pixels.
    Returns:
        boxes [N, 4] int32 (x0, y0, x1, y1), inclusive; nonempty [N] bool.
    """
    uv = means2d.detach()
    r = radii.to(uv.dtype)
    lo = torch.ceil(uv - r[:, None] - 0.5)
    hi = torch.floor(uv + r[:, None] - 0.5)
    limit = torch.tensor([width - 1, height - 1], dtype=uv.dtype, device=uv.device)
    nonempty = (hi >= 0).all(-1) & (lo <= hi).all(-1) & (lo <= limit).all(-1)
    lo = torch.minimum(torch.clamp_min(lo, 0.0), limit)
    hi_clipped = torch.minimum(torch.clamp_min(hi, 0.0), limit)
    boxes = torch.cat([lo, hi_clipped], -1).to(torch.int32)
    return boxes, nonempty


def project_gaussians(gaussians: GaussianSet, camera: Camera, near_plane: float = NEAR_PLANE) -> Projection:
    """Project Gaussians to screen-space conics (differentiable w.r.t. means, quats and log_scales).

    Args:
        gaussians: N Gaussians (float32 or float64, any device).
        camera: the view.
        near_plane: culling depth, scene units (default 0.2, the reference's).
    Returns:
        :class:`Projection`; culled Gaussians get radius 0 and finite (unused) values elsewhere.

    Example:
        >>> cam = Camera.look_at((0, 0, -2.0), (0, 0, 0), (0, -1, 0), 64, 64, 1.0)
        >>> project_gaussians(GaussianSet.from_points(torch.zeros(1, 3), scale=0.05), cam).means2d
        tensor([[32., 32.]])
    """
    means = gaussians.means
    rot, trans = camera_tensors(camera, means)
    t = means @ rot.T + trans
    tz_raw = t[:, 2]
    in_front = tz_raw > near_plane
    tz = torch.where(in_front, tz_raw, torch.ones_like(tz_raw))  # keeps culled rows finite (and their grads 0)
    inv_z = 1.0 / tz
    xz, yz = t[:, 0] * inv_z, t[:, 1] * inv_z
    means2d = torch.stack([camera.fx * xz + camera.cx, camera.fy * yz + camera.cy], -1)

    lim_x = GUARD_BAND * 0.5 * camera.width / camera.fx
    lim_y = GUARD_BAND * 0.5 * camera.height / camera.fy
    xz_c, yz_c = xz.clamp(-lim_x, lim_x), yz.clamp(-lim_y, lim_y)
    zero = torch.zeros_like(tz)
    jac = torch.stack([camera.fx * inv_z, zero, -camera.fx * xz_c * inv_z,
                       zero, camera.fy * inv_z, -camera.fy * yz_c * inv_z], -1).reshape(-1, 2, 3)
    jw = jac @ rot  # [N, 2, 3]
    m = gaussians.rotations() * gaussians.scales[:, None, :]  # Sigma = M M^T
    jwm = jw @ m  # [N, 2, 3]
    cov2d = (jwm @ jwm.transpose(1, 2)).reshape(-1, 4)  # J W Sigma W^T J^T
    a, b, c = cov2d[:, 0] + DILATION, cov2d[:, 1], cov2d[:, 3] + DILATION
    det = a * c - b * b
    conics = torch.stack([c / det, -b / det, a / det], -1)

    with torch.no_grad():
        mid = 0.5 * (a + c)
        lam_max = mid + torch.sqrt(torch.clamp_min(mid * mid - det, 0.0))
        radii = torch.ceil(EXTENT_SIGMAS * torch.sqrt(lam_max)).clamp_max(MAX_RADIUS)
        radii = torch.where(in_front & torch.isfinite(radii), radii, torch.zeros_like(radii)).to(torch.int32)
        boxes, nonempty = footprint_boxes(means2d, radii, camera.width, camera.height)
        radii = torch.where(nonempty, radii, torch.zeros_like(radii))
    return Projection(means2d, conics, tz_raw, radii, boxes)


def view_directions(gaussians: GaussianSet, camera: Camera) -> torch.Tensor:
    """[N, 3] unit directions from the camera centre to the means (the SH view direction of 3DGS)."""
    center = camera.center.to(device=gaussians.device, dtype=gaussians.dtype)
    d = gaussians.means - center
    return d / d.norm(dim=-1, keepdim=True).clamp_min(1e-12)

