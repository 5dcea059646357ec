"""recon: a thin torch 3D Gaussian Splatting module (Kerbl et al. 2023): Gaussians, cameras, rendering, training.

Never imports taichi. The public names:

- :class:`GaussianSet`: N Gaussians as plain tensors (means, quats, log_scales, opacity_logits, sh).
- :class:`Camera`: a pinhole camera (world-to-camera in OpenCV axes).
- :func:`render`: ``render(gaussians, camera, background) -> RenderOutput(image, alpha, depth, radii, visible, ...)``.
- :func:`load_gaussians` / :func:`save_gaussians`: every splat format in use in, the standard 3DGS ``.ply`` (or
  ``.npz``) out (:mod:`recon.formats`).
- :func:`load_dataset`: Blender/NeRF-synthetic ``transforms_*.json`` or COLMAP (binary or text) datasets;
  :func:`load_cameras`: the cameras of a ``transforms.json``.

Example:
    >>> import recon
    >>> g = recon.load_gaussians("assets/ahmed_gaussians.ply")  # doctest: +SKIP
    >>> cams = recon.load_cameras("assets/ahmed_cameras.json")  # doctest: +SKIP
    >>> recon.render(g, cams[0]).image.shape  # doctest: +SKIP
    torch.Size([64, 64, 3])
"""

from fluidsim.lazy import lazy_exports

_EXPORTS = {
    "Camera": "camera",
    "load_cameras": "datasets",
    "load_dataset": "datasets",
    "detect_format": "formats",
    "load_gaussians": "formats",
    "GaussianSet": "gaussians",
    "save_gaussians": "formats.ply",
    "RenderOutput": "render",
    "render": "render",
}
__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals())
