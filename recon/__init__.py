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

from .camera import Camera
from .datasets import load_cameras, load_dataset
from .formats import detect_format, load_gaussians
from .gaussians import GaussianSet
from .ply import save_gaussians
from .render import RenderOutput, render

__all__ = ["Camera", "GaussianSet", "RenderOutput", "detect_format", "load_cameras", "load_dataset",
           "load_gaussians", "render", "save_gaussians"]
