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

import importlib

_EXPORTS = {"Camera": "camera", "load_cameras": "datasets", "load_dataset": "datasets", "detect_format": "formats",
            "load_gaussians": "formats", "GaussianSet": "gaussians", "save_gaussians": "ply",
            "RenderOutput": "render", "render": "render"}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    """PEP 562: load a public name's module on first use, so ``recon.train_config`` alone loads no torch."""
    module = _EXPORTS.get(name)
    if module is None:
        try:  # a submodule reached as an attribute (``recon.train``) after ``import recon``
            return importlib.import_module(f"{__name__}.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"{__name__}.{name}":
                raise
            raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_EXPORTS})
