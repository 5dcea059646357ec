"""Space carving of a solid lattice from cameras and depth maps (the paper's Kaolin sampler, Sec. 3.2).

A lattice point (simulation metres) is *seen empty* by a camera when it projects into the image, lies in
front of the camera (view depth z > 0), and lies in front of the surface that the camera sees at that
pixel by more than a margin: z < depth[v, u] - margin. A point seen empty by at least one camera is
outside; every other lattice point is solid, and so is every point the Gaussians made solid (the depth
at a pixel is the nearest over its 3 x 3 neighbourhood, :func:`nearest_surface`, so that silhouettes do not
eat into the object):

    carved = occupancy OR NOT (seen empty by some camera).

The interior of a capture, which no camera sees, therefore becomes solid even where the surface has holes.
Points off every camera's image or behind every camera count as unseen (solid): carve with cameras that
surround the object.

Depth maps: :func:`surface_depths` renders, per pixel, the view depth of the Gaussian at which the
accumulated opacity first reaches ``level`` (0.5), front to back in the 3DGS compositing order of
:mod:`recon.render` (inf where it never does). The alpha-weighted mean depth that ``recon.render.render``
returns mixes the front and the back wall of a hollow capture and so lies inside the object, where carving
would cut into the body.

Conventions: cameras are ``recon.camera.Camera`` in the scene frame (world-to-camera, OpenCV axes: x right,
y down, z forward); pixel (u, v) = (fx x / z + cx, fy y / z + cy) lands in column floor(u), row floor(v);
depths are view depths in scene units.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch

from recon.projection import project_gaussians
from recon.render import ALPHA_MAX, build_pairs

# Lattice points projected per chunk (bounds the temporary arrays to ~100 MB).
_CHUNK = 1 << 21


def surface_depths(gaussians, cameras: Sequence, level: float = 0.5) -> list[np.ndarray]:
    """Per camera, the view depth where the Gaussians' accumulated opacity first reaches ``level``.

    Args:
        gaussians: a ``recon.gaussians.GaussianSet`` (scene units).
        cameras: ``recon.camera.Camera`` views.
        level: accumulated opacity 1 - T that marks the surface, in (0, 1).
    Returns:
        one [H, W] float64 array per camera: the depth (scene units) of the Gaussian whose compositing brings
        1 - T to ``level`` or above, inf where the pixel never gets there.
    """
    if not 0.0 < level < 1.0:
        raise ValueError(f"surface_depths: level must be in (0, 1) (an accumulated opacity), got {level}")
    out = []
    with torch.no_grad():
        g = gaussians.detach()
        for cam in cameras:
            proj = project_gaussians(g, cam)
            pairs = build_pairs(proj, g.opacities, cam.width, cam.height)
            n_pix = cam.width * cam.height
            depth = torch.full((n_pix,), math.inf, dtype=torch.float64)
            if pairs.num:
                log1m = torch.log1p(-pairs.alpha.clamp_max(ALPHA_MAX).to(torch.float64))
                csum = torch.cumsum(log1m, 0)
                pix = pairs.pixels.long()
                counts = torch.bincount(pix, minlength=n_pix)
                starts = torch.cumsum(counts, 0) - counts
                base = (csum - log1m).index_select(0, starts.clamp_max(pairs.num - 1))
                log_t = csum - base.index_select(0, pix)  # log T after each pair, within its pixel
                hit = torch.nonzero(log_t <= math.log1p(-level)).flatten()
                first = torch.full((n_pix,), pairs.num, dtype=torch.long)
                first.scatter_reduce_(0, pix.index_select(0, hit), hit, reduce="amin")
                has = first < pairs.num
                gid = pairs.gaussians.long().index_select(0, first[has])
                depth[has] = proj.depths.detach().to(torch.float64).index_select(0, gid)
            out.append(depth.reshape(cam.height, cam.width).numpy())
    return out


def _check_views(cameras: Sequence, depths: Sequence) -> list[np.ndarray]:
    cams, maps = list(cameras), [np.asarray(d, dtype=np.float64) for d in depths]
    if len(cams) != len(maps):
        raise ValueError(f"carving: {len(cams)} cameras but {len(maps)} depth maps; pass one depth map per camera")
    for cam, d in zip(cams, maps, strict=True):
        if d.shape != (cam.height, cam.width):
            raise ValueError(
                f"carving: the depth map of camera {cam.name!r} has shape {d.shape}, expected "
                f"({cam.height}, {cam.width}) (H, W)"
            )
        if np.isnan(d).any():
            raise ValueError(f"carving: the depth map of camera {cam.name!r} holds NaN; use inf for empty pixels")
    return maps


def nearest_surface(depth: np.ndarray) -> np.ndarray:
    """[H, W] the smallest depth over each pixel's 3 x 3 neighbourhood (inf off the image).

    A point projects anywhere inside its pixel, while a depth map holds the surface on the pixel's centre ray:
    next to a silhouette a point of the object can fall in a pixel whose centre ray misses it. Testing against
    the nearest surface around the pixel never carves such a point.
    """
    d = np.pad(np.asarray(depth, dtype=np.float64), 1, constant_values=np.inf)
    h, w = depth.shape
    return np.min([d[i : i + h, j : j + w] for i in range(3) for j in range(3)], axis=0)


def seen_empty(points_scene: np.ndarray, cameras: Sequence, depths: Sequence[np.ndarray], margin: float) -> np.ndarray:
    """[P] bool: some camera sees the point (scene units) in front of its depth map by more than ``margin``.

    ``depths`` are taken as they are; :func:`carve_outside` passes them through :func:`nearest_surface` first.
    """
    pts = np.asarray(points_scene, dtype=np.float64).reshape(-1, 3)
    seen = np.zeros(len(pts), dtype=bool)
    for cam, depth in zip(cameras, depths, strict=True):
        w2c = cam.world_to_camera.numpy()
        pc = pts @ w2c[:3, :3].T + w2c[:3, 3]
        z = pc[:, 2]
        front = z > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.floor(cam.fx * pc[:, 0] / z + cam.cx)
            v = np.floor(cam.fy * pc[:, 1] / z + cam.cy)
        ok = front & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        if not ok.any():
            continue
        rows, cols = v[ok].astype(np.int64), u[ok].astype(np.int64)
        seen[ok] |= z[ok] < depth[rows, cols] - margin
    return seen


def carve_outside(
    occupancy: np.ndarray,
    lattice_min: np.ndarray,
    spacing: float,
    cameras: Sequence,
    depths: Sequence[np.ndarray],
    transform,
    margin: float = 0.0,
) -> np.ndarray:
    """The carved solid: ``occupancy`` plus every lattice point that no camera sees empty.

    Args:
        occupancy: [X, Y, Z] bool, solid lattice points (point (i, j, k) is lattice_min + spacing (i, j, k), m).
        lattice_min: [3] simulation metres. spacing: m.
        cameras: ``recon.camera.Camera`` views in the scene frame.
        depths: one [H, W] depth map per camera, view depth in scene units (inf where the view is empty).
        transform: the scene -> simulation transform (``to_scene`` and ``scale``) of the lattice.
        margin: spacings in front of the depth within which a point is not carved.
    Returns:
        [X, Y, Z] bool.
    """
    occ = np.asarray(occupancy, dtype=bool)
    if not (math.isfinite(margin) and margin >= 0):
        raise ValueError(f"carving: margin must be a finite number >= 0 (spacings), got {margin}")
    maps = [nearest_surface(d) for d in _check_views(cameras, depths)]
    cams = list(cameras)
    out = occ.copy().reshape(-1)
    shape = occ.shape
    margin_scene = margin * spacing / float(transform.scale)
    for start in range(0, occ.size, _CHUNK):
        flat = np.arange(start, min(start + _CHUNK, occ.size), dtype=np.int64)
        idx = np.stack(np.unravel_index(flat, shape), axis=1)
        pts = transform.to_scene(np.asarray(lattice_min, np.float64) + spacing * idx)
        out[flat] |= ~seen_empty(pts, cams, maps, margin_scene)
    return out.reshape(shape)
