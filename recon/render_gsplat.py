"""The gsplat backend of :func:`recon.render.render` (CUDA only; gsplat v1.x ``rasterization`` API).

gsplat (Ye et al. 2024, "gsplat: An Open-Source Library for Gaussian Splatting") implements the same
EWA splatting as the 3DGS reference (Kerbl et al. 2023). It is called with the reference settings:
near plane 0.2, 0.3 px^2 dilation (``eps2d``), classic (not anti-aliased) rasterization, SH colours
with the +0.5 offset, and ``render_mode="RGB+D"`` (accumulated depth sum w_i z_i, the depth of the
torch path). Known small differences from the torch path: gsplat clamps alpha at 0.999 (not 0.99)
and bounds footprints by 16 x 16 tiles, so pixels just outside the 3-sigma box can receive alpha >=
1/255; the tests compare the two with a tolerance. gsplat >= 1.5 returns per-axis radii [N, 2];
their maximum is reported.
"""

from __future__ import annotations

import importlib.util

import torch

from .camera import Camera
from .gaussians import GaussianSet
from .projection import NEAR_PLANE
from .render_types import RenderOutput


def gsplat_available() -> bool:
    """True when the gsplat package is importable and a CUDA device is usable."""
    return torch.cuda.is_available() and importlib.util.find_spec("gsplat") is not None


def render_gsplat(gaussians: GaussianSet, camera: Camera, background: torch.Tensor, sh_degree: int):
    """Render with ``gsplat.rasterization`` (float32, on the Gaussians' CUDA device).

    Args:
        gaussians: N Gaussians on a CUDA device.
        camera: the view.
        background: [3] RGB on the Gaussians' device.
        sh_degree: SH bands to use (0 .. stored degree).
    Returns:
        :class:`recon.render_types.RenderOutput` (float32 maps; ``means2d`` is a leaf whose ``.grad`` is filled by
        a hook on gsplat's screen-space means during backward).
    """
    if not gsplat_available():
        raise ValueError(
            "backend='gsplat' needs the gsplat package and a CUDA device; install gsplat "
            "(pip install gsplat) on a CUDA machine or use backend='torch'"
        )
    if gaussians.device.type != "cuda":
        raise ValueError(
            f"backend='gsplat' needs the Gaussians on a CUDA device, they are on {gaussians.device}; "
            "move them with .to('cuda') or use backend='torch'"
        )
    from gsplat import rasterization  # noqa: PLC0415 - optional: gsplat, CUDA only

    dev, f32 = gaussians.device, torch.float32
    k = (sh_degree + 1) ** 2
    viewmats = camera.world_to_camera.to(device=dev, dtype=f32)[None]
    ks = camera.intrinsics().to(device=dev, dtype=f32)[None]
    colors, alphas, meta = rasterization(
        gaussians.means.to(f32),
        gaussians.quats.to(f32),
        gaussians.scales.to(f32),
        gaussians.opacities.to(f32),
        gaussians.sh[:, :k].to(f32),
        viewmats,
        ks,
        camera.width,
        camera.height,
        near_plane=NEAR_PLANE,
        eps2d=0.3,
        sh_degree=sh_degree,
        packed=False,
        backgrounds=background.to(f32)[None],
        render_mode="RGB+D",
        rasterize_mode="classic",
    )
    radii = meta["radii"][0]
    if radii.dim() == 2:
        radii = radii.max(-1).values
    radii = radii.to(torch.int32)
    screen_means = meta["means2d"]
    means2d = screen_means[0].detach().clone()
    if screen_means.requires_grad:
        means2d.requires_grad_(True)

        def _store(grad: torch.Tensor) -> None:
            means2d.grad = grad[0].detach().clone() if means2d.grad is None else means2d.grad + grad[0]

        screen_means.register_hook(_store)
    return RenderOutput(
        image=colors[0, ..., :3],
        alpha=alphas[0, ..., 0],
        depth=colors[0, ..., 3],
        radii=radii,
        visible=radii > 0,
        means2d=means2d,
    )
