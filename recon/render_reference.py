"""Slow reference twins of the renderer, for tests only (Kerbl et al. 2023, Eqs. 1-3, 5).

- :func:`project_gaussians_reference`: the EWA projection of :mod:`recon.projection`, one Gaussian at a
  time with explicit 3 x 3 matrices (J W Sigma W^T J^T + 0.3 I), written as in the paper.
- :func:`render_dense_reference`: every pixel x every Gaussian, composited sequentially in depth order
  with the reference rules (3-sigma box, alpha <= 0.99, skip alpha < 1/255, stop before T < 1e-4), in
  plain torch with autograd. It is O(H W N) and runs a Python loop over Gaussians: keep scenes tiny.
"""

from __future__ import annotations

import math

import torch

from .camera import Camera
from .gaussians import GaussianSet, quaternion_to_rotation
from .projection import DILATION, EXTENT_SIGMAS, GUARD_BAND, NEAR_PLANE, Projection
from .render import gaussian_colors
from .render_types import ALPHA_MAX, ALPHA_MIN, T_MIN, RenderOutput


def project_gaussians_reference(gaussians: GaussianSet, camera: Camera) -> Projection:
    """Per-Gaussian loop twin of :func:`recon.projection.project_gaussians` (same outputs, slowly)."""
    w2c = camera.world_to_camera.to(device=gaussians.device, dtype=gaussians.dtype)
    rot_w, trans = w2c[:3, :3], w2c[:3, 3]
    lim_x = GUARD_BAND * math.tan(0.5 * camera.fov_x)
    lim_y = GUARD_BAND * math.tan(0.5 * camera.fov_y)
    means2d, conics, depths, radii, boxes = [], [], [], [], []
    for i in range(gaussians.num):
        t = rot_w @ gaussians.means[i] + trans
        z = t[2]
        culled = bool(z <= NEAR_PLANE)
        if culled:
            z = torch.ones_like(z)
        u = camera.fx * t[0] / z + camera.cx
        v = camera.fy * t[1] / z + camera.cy
        tx = torch.clamp(t[0] / z, -lim_x, lim_x) * z
        ty = torch.clamp(t[1] / z, -lim_y, lim_y) * z
        jac = torch.stack(
            [
                torch.stack([camera.fx / z, torch.zeros_like(z), -camera.fx * tx / (z * z)]),
                torch.stack([torch.zeros_like(z), camera.fy / z, -camera.fy * ty / (z * z)]),
            ]
        )
        rot_g = quaternion_to_rotation(gaussians.quats[i : i + 1])[0]
        scale = torch.diag(torch.exp(gaussians.log_scales[i]))
        sigma = rot_g @ scale @ scale @ rot_g.T
        cov2d = jac @ rot_w @ sigma @ rot_w.T @ jac.T + DILATION * torch.eye(2, dtype=z.dtype, device=z.device)
        inv = torch.linalg.inv(cov2d)
        lam_max = float(torch.linalg.eigvalsh(cov2d.detach())[-1])
        r = 0 if culled else math.ceil(EXTENT_SIGMAS * math.sqrt(lam_max))
        # pixels whose centres x + 0.5 lie in [u - r, u + r], clipped to the image
        ud, vd = float(u.detach()), float(v.detach())
        x0 = max(math.ceil(ud - r - 0.5), 0)
        x1 = min(math.floor(ud + r - 0.5), camera.width - 1)
        y0 = max(math.ceil(vd - r - 0.5), 0)
        y1 = min(math.floor(vd + r - 0.5), camera.height - 1)
        if x0 > x1 or y0 > y1:
            r = 0
        means2d.append(torch.stack([u, v]))
        conics.append(torch.stack([inv[0, 0], inv[0, 1], inv[1, 1]]))
        depths.append(t[2])
        radii.append(r)
        boxes.append([x0, y0, x1, y1])
    dev, dt = gaussians.device, gaussians.dtype
    if gaussians.num == 0:
        ints = torch.zeros(0, dtype=torch.int32, device=dev)
        return Projection(
            torch.zeros(0, 2, dtype=dt, device=dev),
            torch.zeros(0, 3, dtype=dt, device=dev),
            torch.zeros(0, dtype=dt, device=dev),
            ints,
            ints.reshape(0, 4),
        )
    return Projection(
        torch.stack(means2d),
        torch.stack(conics),
        torch.stack(depths),
        torch.tensor(radii, dtype=torch.int32, device=dev),
        torch.tensor(boxes, dtype=torch.int32, device=dev),
    )


def render_dense_reference(
    gaussians: GaussianSet, camera: Camera, background: torch.Tensor | float | None = None, sh_degree: int | None = None
) -> RenderOutput:
    """Dense twin of :func:`recon.render.render` (torch backend): all pixels x all Gaussians, sequential in depth.

    Args and Returns as :func:`recon.render.render`; ``means2d`` retains its gradient.
    """
    dev, dt = gaussians.device, gaussians.dtype
    if background is None:
        background = 0.0
    bg = torch.as_tensor(background, dtype=dt, device=dev).expand(3)
    degree = gaussians.sh_degree if sh_degree is None else sh_degree
    proj = project_gaussians_reference(gaussians, camera)
    means2d = proj.means2d
    if means2d.requires_grad:
        means2d.retain_grad()
    colors = gaussian_colors(gaussians, camera, degree)
    opacities = gaussians.opacities
    w, h = camera.width, camera.height
    ys, xs = torch.meshgrid(
        torch.arange(h, dtype=dt, device=dev) + 0.5, torch.arange(w, dtype=dt, device=dev) + 0.5, indexing="ij"
    )
    px, py = xs.reshape(-1), ys.reshape(-1)
    trans = torch.ones(h * w, dtype=dt, device=dev)
    done = torch.zeros(h * w, dtype=torch.bool, device=dev)
    image = torch.zeros(h * w, 3, dtype=dt, device=dev)
    depth = torch.zeros(h * w, dtype=dt, device=dev)
    order = sorted((i for i in range(gaussians.num) if proj.radii[i] > 0), key=lambda i: float(proj.depths[i].detach()))
    for i in order:
        r = float(proj.radii[i])
        dx, dy = px - means2d[i, 0], py - means2d[i, 1]
        inside = (dx.abs() <= r) & (dy.abs() <= r)
        a, b, c = proj.conics[i]
        power = -0.5 * (a * dx * dx + c * dy * dy) - b * dx * dy
        alpha = torch.clamp_max(opacities[i] * torch.exp(power), ALPHA_MAX)
        valid = inside & (alpha >= ALPHA_MIN) & ~done
        test_t = trans * (1.0 - alpha)
        stop = valid & (test_t < T_MIN)
        done = done | stop
        use = valid & ~stop
        weight = torch.where(use, alpha * trans, torch.zeros_like(alpha))
        image = image + weight[:, None] * colors[i]
        depth = depth + weight * proj.depths[i]
        trans = torch.where(use, test_t, trans)
    image = image + trans[:, None] * bg
    return RenderOutput(
        image=image.reshape(h, w, 3),
        alpha=(1.0 - trans).reshape(h, w),
        depth=depth.reshape(h, w),
        radii=proj.radii,
        visible=proj.radii > 0,
        means2d=means2d,
    )
