"""Image and geometry metrics: PSNR, SSIM, LPIPS (when available offline) and the Chamfer distance.

- **PSNR** = 10 log10(max_val^2 / MSE), per image, the mean over pixels and channels (as in the 3DGS evaluation).
- **SSIM** (Wang et al. 2004, Eq. 13) with the choices of the reference 3DGS code (Kerbl et al. 2023,
  ``utils/loss_utils.py``): an 11-tap Gaussian window with sigma = 1.5, local statistics by convolution with
  zero padding of window // 2 ("same" size output, so border windows see zeros), C1 = (0.01 L)^2,
  C2 = (0.03 L)^2 with L = ``data_range``, and the mean of the SSIM map over pixels and channels. The
  convolution is separable (two 1-D passes, the same numbers as the 2-D window up to rounding). It is
  differentiable, for the 1 - SSIM term of the 3DGS loss. ``padding="valid"`` keeps only windows that lie
  inside the image.
- **LPIPS** (Zhang et al. 2018) only when the ``lpips`` package, its linear-layer weights and the torchvision
  backbone weights are all on disk; nothing here downloads. Otherwise :func:`lpips` raises
  :class:`MetricUnavailable` and :func:`lpips_unavailable_reason` says what is missing.
- **Chamfer distance** between point sets A and B: 0.5 (mean_a min_b |a - b| + mean_b min_a |b - a|), in the
  units of the points (the symmetric mean of nearest-neighbour Euclidean distances; ``squared=True`` averages
  squared distances instead, as some papers do). The README quotes the non-squared value, which reads as a
  distance. Nearest neighbours come from open3d's KD-tree; :func:`chamfer_distance_reference` is the chunked
  brute-force twin.

Images are float tensors [H, W, C] or [B, H, W, C] (channels last, C = 3 for colour) in [0, data_range].
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import open3d as o3d
import torch
import torch.nn.functional as F

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03
# torchvision's backbone checkpoints, as named in torch.hub's cache (torch.hub.get_dir()/checkpoints).
LPIPS_BACKBONES = {
    "alex": "alexnet-owt-7be5be79.pth",
    "vgg": "vgg16-397923af.pth",
    "squeeze": "squeezenet1_1-b8a52dc0.pth",
}


class MetricUnavailable(RuntimeError):
    """A metric cannot be computed on this machine (a package or weights file is missing)."""


def _image_pair(img: torch.Tensor, ref: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, bool]:
    """Validate two images and return them as [B, C, H, W] plus whether the input was batched."""
    for name, t in (("img", img), ("ref", ref)):
        if not isinstance(t, torch.Tensor):
            raise ValueError(f"{name} must be a torch.Tensor, got {type(t).__name__}")
        if t.dim() not in (3, 4) or not t.is_floating_point():
            raise ValueError(f"{name} must be a float tensor [H, W, C] or [B, H, W, C], got {tuple(t.shape)} {t.dtype}")
    if img.shape != ref.shape:
        raise ValueError(f"img and ref must have the same shape, got {tuple(img.shape)} and {tuple(ref.shape)}")
    if img.device != ref.device:
        raise ValueError(f"img and ref are on different devices ({img.device} and {ref.device}); move one")
    batched = img.dim() == 4
    if not batched:
        img, ref = img[None], ref[None]
    return img.permute(0, 3, 1, 2), ref.permute(0, 3, 1, 2), batched


def psnr(img: torch.Tensor, ref: torch.Tensor, max_val: float = 1.0) -> torch.Tensor:
    """Peak signal-to-noise ratio in dB.

    Args:
        img, ref: [H, W, C] or [B, H, W, C] float images in [0, max_val].
        max_val: the peak value (1 for images in [0, 1]).
    Returns:
        A scalar tensor for one image, [B] for a batch (one PSNR per image; +inf where the images are equal).

    Example:
        >>> psnr(torch.zeros(4, 4, 3), torch.full((4, 4, 3), 0.1))  # 20 dB
        tensor(20.)
    """
    if not max_val > 0:
        raise ValueError(f"max_val must be > 0, got {max_val}")
    x, y, batched = _image_pair(img, ref)
    mse = (x - y).square().mean(dim=(1, 2, 3))
    out = 10.0 * torch.log10(max_val**2 / mse)
    return out if batched else out[0]


def gaussian_window(
    size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA, dtype=torch.float32, device=None
) -> torch.Tensor:
    """The normalised 1-D Gaussian window [size] centred on tap size // 2 (the 2-D window is its outer product)."""
    if size < 1 or size % 2 == 0:
        raise ValueError(f"window size must be a positive odd number, got {size}")
    if not sigma > 0:
        raise ValueError(f"sigma must be > 0, got {sigma}")
    x = torch.arange(size, dtype=torch.float64) - size // 2
    w = torch.exp(-x.square() / (2.0 * sigma**2))
    return (w / w.sum()).to(dtype=dtype, device=device)


def ssim(
    img: torch.Tensor,
    ref: torch.Tensor,
    *,
    window_size: int = SSIM_WINDOW,
    sigma: float = SSIM_SIGMA,
    data_range: float = 1.0,
    padding: str = "same",
) -> torch.Tensor:
    """Structural similarity (Wang et al. 2004) as computed by the reference 3DGS code; differentiable.

    Args:
        img, ref: [H, W, C] or [B, H, W, C] float images in [0, data_range].
        window_size: taps of the Gaussian window (odd).
        sigma: standard deviation of the window, in pixels.
        data_range: L in C1 = (0.01 L)^2 and C2 = (0.03 L)^2.
        padding: "same" (zero padding of window_size // 2, the 3DGS choice) or "valid" (interior windows only).
    Returns:
        A scalar tensor for one image, [B] for a batch: the mean of the SSIM map over pixels and channels.

    Example:
        >>> x = torch.rand(32, 32, 3)
        >>> float(ssim(x, x))
        1.0
    """
    if padding not in ("same", "valid"):
        raise ValueError(f"padding must be 'same' or 'valid', got {padding!r}")
    x, y, batched = _image_pair(img, ref)
    b, c, h, w = x.shape
    if padding == "valid" and (h < window_size or w < window_size):
        raise ValueError(
            f"padding='valid' needs images of at least {window_size} x {window_size} pixels, "
            f"got {h} x {w}; use padding='same'"
        )
    win = gaussian_window(window_size, sigma, x.dtype, x.device)
    pad = window_size // 2 if padding == "same" else 0
    stats = torch.cat([x, y, x * x, y * y, x * y], 1)  # [B, 5C, H, W], blurred in one grouped convolution
    groups = stats.shape[1]
    stats = F.conv2d(stats, win.reshape(1, 1, 1, -1).expand(groups, 1, 1, window_size), padding=(0, pad), groups=groups)
    stats = F.conv2d(stats, win.reshape(1, 1, -1, 1).expand(groups, 1, window_size, 1), padding=(pad, 0), groups=groups)
    mu_x, mu_y, e_xx, e_yy, e_xy = stats.split(c, 1)
    var_x = e_xx - mu_x * mu_x
    var_y = e_yy - mu_y * mu_y
    cov = e_xy - mu_x * mu_y
    c1 = (SSIM_K1 * data_range) ** 2
    c2 = (SSIM_K2 * data_range) ** 2
    ssim_map = ((2 * mu_x * mu_y + c1) * (2 * cov + c2)) / ((mu_x * mu_x + mu_y * mu_y + c1) * (var_x + var_y + c2))
    out = ssim_map.mean(dim=(1, 2, 3))
    return out if batched else out[0]


# ---- LPIPS -----------------------------------------------------------------------------------------------------
def lpips_unavailable_reason(net: str = "alex") -> str | None:
    """Why LPIPS cannot run offline here, or None when the package and all its weights are on disk.

    Nothing is imported or downloaded: the checks look for the ``lpips`` and ``torchvision`` packages, the
    package's bundled linear weights (``lpips/weights/v0.1/<net>.pth``) and torchvision's backbone checkpoint
    in torch.hub's cache (``torch.hub.get_dir()/checkpoints``).
    """
    if net not in LPIPS_BACKBONES:
        raise ValueError(f"LPIPS net must be one of {sorted(LPIPS_BACKBONES)}, got {net!r}")
    for package in ("lpips", "torchvision"):
        if importlib.util.find_spec(package) is None:
            return f"the {package!r} package is not installed (pip install lpips torchvision, with their weights)"
    spec = importlib.util.find_spec("lpips")
    roots = list(spec.submodule_search_locations or [])
    linear = [Path(r) / "weights" / "v0.1" / f"{net}.pth" for r in roots]
    if not any(p.is_file() for p in linear):
        return f"the LPIPS linear weights are missing ({linear[0] if linear else 'lpips/weights/v0.1'})"
    backbone = Path(torch.hub.get_dir()) / "checkpoints" / LPIPS_BACKBONES[net]
    if not backbone.is_file():
        return (
            f"the torchvision backbone weights {backbone} are missing; copy them there from a machine "
            f"with internet access (this code never downloads)"
        )
    return None


def lpips_available(net: str = "alex") -> bool:
    """True when LPIPS can be computed without any download (see :func:`lpips_unavailable_reason`)."""
    return lpips_unavailable_reason(net) is None


def load_lpips(net: str = "alex", device: str | torch.device = "cpu") -> torch.nn.Module:
    """The LPIPS network (eval mode, on ``device``), loaded from local files only.

    Raises:
        MetricUnavailable: the package or a weights file is missing (the message says which).
    """
    reason = lpips_unavailable_reason(net)
    if reason is not None:
        raise MetricUnavailable(f"LPIPS is unavailable: {reason}")
    import lpips as lpips_package  # noqa: PLC0415 - optional: LPIPS needs the lpips package

    return lpips_package.LPIPS(net=net, verbose=False).to(device).eval()


def lpips(img: torch.Tensor, ref: torch.Tensor, network: torch.nn.Module | None = None) -> torch.Tensor:
    """LPIPS distance (lower is more similar) of images in [0, 1].

    Args:
        img, ref: [H, W, 3] or [B, H, W, 3] float images in [0, 1].
        network: a network from :func:`load_lpips`; loaded (AlexNet) for this call when None, so pass one when
            evaluating many images.
    Returns:
        A scalar tensor for one image, [B] for a batch.
    Raises:
        MetricUnavailable: LPIPS cannot run offline on this machine.
    """
    x, y, batched = _image_pair(img, ref)
    if x.shape[1] != 3:
        raise ValueError(f"LPIPS needs 3-channel images, got {x.shape[1]} channels")
    if network is None:
        network = load_lpips(device=x.device)
    out = network(x, y, normalize=True).reshape(x.shape[0])  # normalize=True maps [0, 1] to [-1, 1]
    return out if batched else out[0]


# ---- Chamfer distance --------------------------------------------------------------------------------------------
def _points(p, name: str) -> np.ndarray:
    arr = p.detach().cpu().numpy() if isinstance(p, torch.Tensor) else np.asarray(p)
    if arr.ndim != 2 or arr.shape[1] != 3 or arr.shape[0] == 0:
        raise ValueError(f"point set {name} must have shape (N, 3) with N >= 1, got {arr.shape}")
    arr = arr.astype(np.float64)
    if not np.isfinite(arr).all():
        raise ValueError(f"point set {name} contains NaN or Inf; remove those points first")
    return arr


def nearest_distances(query, points) -> np.ndarray:
    """Euclidean distance from each query point to its nearest neighbour in ``points`` (open3d KD-tree).

    Args:
        query: [N, 3] array or tensor.
        points: [M, 3] array or tensor.
    Returns:
        [N] float64 distances, in the units of the points.
    """
    q, p = _points(query, "query"), _points(points, "points")
    cloud_q = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(q))
    cloud_p = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p))
    return np.asarray(cloud_q.compute_point_cloud_distance(cloud_p))


def nearest_distances_reference(query, points, chunk: int = 4096) -> np.ndarray:
    """Brute-force twin of :func:`nearest_distances`: chunked ``torch.cdist`` in float64, O(chunk^2) memory."""
    q = torch.from_numpy(_points(query, "query"))
    p = torch.from_numpy(_points(points, "points"))
    best = torch.full((q.shape[0],), float("inf"), dtype=torch.float64)
    for i in range(0, q.shape[0], chunk):
        for j in range(0, p.shape[0], chunk):
            d = torch.cdist(q[i : i + chunk], p[j : j + chunk]).min(dim=1).values
            best[i : i + chunk] = torch.minimum(best[i : i + chunk], d)
    return best.numpy()


def _chamfer(da: np.ndarray, db: np.ndarray, squared: bool) -> float:
    if squared:
        da, db = da * da, db * db
    return float(0.5 * (da.mean() + db.mean()))


def chamfer_distance(a, b, *, squared: bool = False) -> float:
    """Symmetric Chamfer distance 0.5 (mean_a min_b |a - b| + mean_b min_a |b - a|).

    Args:
        a: [N, 3] points (array or tensor).
        b: [M, 3] points.
        squared: average squared distances instead (units squared).
    Returns:
        The distance in the units of the points (0 for identical sets). Memory is O(N + M).

    Example:
        >>> chamfer_distance(np.zeros((1, 3)), np.ones((1, 3)))  # sqrt(3)
        1.7320508075688772
    """
    a, b = _points(a, "a"), _points(b, "b")
    return _chamfer(nearest_distances(a, b), nearest_distances(b, a), squared)


def chamfer_distance_reference(a, b, *, squared: bool = False) -> float:
    """Brute-force twin of :func:`chamfer_distance` (chunked cdist)."""
    a, b = _points(a, "a"), _points(b, "b")
    return _chamfer(nearest_distances_reference(a, b), nearest_distances_reference(b, a), squared)
