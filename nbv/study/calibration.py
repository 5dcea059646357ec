"""Per-Gaussian calibration where the geometry is known: does a per-Gaussian signal point at wrong geometry?

On a dataset rendered from a mesh (``render-dataset`` keeps it as ``mesh.ply``, in the cameras' frame), the error of a
Gaussian is the distance of its centre to the mesh surface (scene units). A signal that marks wrong geometry ranks the
Gaussians by that distance. Uncertainty work on radiance fields measures this with the AUSE (FisherRF, Bayes' Rays):

- the *sparsification curve* of an uncertainty u: remove the fraction f of the Gaussians with the largest u and take
  the mean error of the rest, for f = 0, 1/S, ..., (S-1)/S;
- the *oracle curve*: the same with the error itself as u;
- AUSE = mean over f of (curve_u(f) - curve_oracle(f)) / mean error. It is 0 for a perfect ranking, near the area
  of the oracle curve below 1 for a random one, larger for an inverted one, and never negative.

The *missing geometry* is what no Gaussian covers: points sampled on the mesh (uniform by area) that lie outside the
2-sigma ellipsoid of every Gaussian (Mahalanobis distance > 2) above an opacity floor. Each candidate view counts the
missing samples it sees (inside its image, in front of it, not hidden by the mesh itself), so a rule that favours
views on the missing geometry correlates with that count.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch

from recon.camera import Camera
from recon.gaussians import GaussianSet


def _check_mesh(vertices, triangles) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices, np.float64)
    t = np.asarray(triangles, np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or t.ndim != 2 or t.shape[1] != 3 or len(t) == 0:
        raise ValueError(f"mesh: vertices must be [V, 3] and triangles [T, 3] with T >= 1, got {v.shape} and {t.shape}")
    if t.min() < 0 or t.max() >= len(v):
        raise ValueError(f"mesh: triangle indices must lie in 0..{len(v) - 1}")
    return v, t


def _raycasting_scene(vertices: np.ndarray, triangles: np.ndarray):
    import open3d as o3d  # noqa: PLC0415 - open3d takes a while to import; only the calibration needs it here

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)), o3d.core.Tensor(triangles.astype(np.uint32)))
    return scene


def surface_distance(points, vertices, triangles) -> np.ndarray:
    """Unsigned distance of every point to the triangle mesh (open3d ``RaycastingScene.compute_distance``).

    Args:
        points: [N, 3] scene units. vertices: [V, 3]. triangles: [T, 3] vertex indices.
    Returns:
        [N] float64 distances, scene units (float32 precision inside open3d).
    """
    v, t = _check_mesh(vertices, triangles)
    p = np.asarray(points, np.float64).reshape(-1, 3)
    if len(p) == 0:
        return np.zeros(0)
    import open3d as o3d  # noqa: PLC0415

    scene = _raycasting_scene(v, t)
    return scene.compute_distance(o3d.core.Tensor(p.astype(np.float32))).numpy().astype(np.float64)


def _closest_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Closest points on triangles (a, b, c) [T, 3] to one point p [3] (Ericson, Real-Time Collision Detection,
    Sec. 5.1.5)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(1), (ac * ap).sum(1)
    bp = p - b
    d3, d4 = (ab * bp).sum(1), (ac * bp).sum(1)
    cp = p - c
    d5, d6 = (ab * cp).sum(1), (ac * cp).sum(1)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    denom = va + vb + vc
    with np.errstate(divide="ignore", invalid="ignore"):
        v = vb / denom
        w = vc / denom
    out = a + ab * v[:, None] + ac * w[:, None]  # inside the face
    # edges and vertices, in the reverse order of precedence so that the earlier regions win
    with np.errstate(divide="ignore", invalid="ignore"):
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        t_ac = d2 / (d2 - d6)
        t_ab = d1 / (d1 - d3)
    regions = [
        ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), b + (c - b) * t_bc[:, None]),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + ac * t_ac[:, None]),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + ab * t_ab[:, None]),
        ((d6 >= 0) & (d5 <= d6), c),
        ((d3 >= 0) & (d4 <= d3), b),
        ((d1 <= 0) & (d2 <= 0), a),
    ]
    for mask, value in regions:
        out = np.where(mask[:, None], value, out)
    return out


def surface_distance_reference(points, vertices, triangles) -> np.ndarray:
    """Brute-force twin of :func:`surface_distance`: the exact closest point on every triangle, per point (float64)."""
    v, t = _check_mesh(vertices, triangles)
    p = np.asarray(points, np.float64).reshape(-1, 3)
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    return np.array([float(np.linalg.norm(_closest_on_triangles(x, a, b, c) - x, axis=1).min()) for x in p])


def area_weighted_corners(
    v: np.ndarray, t: np.ndarray, count: int, rng: np.random.Generator, what: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The corners a, b, c ([count, 3] each) of ``count`` triangles of the mesh (``v`` [V, 3], ``t`` [T, 3]) drawn
    from ``rng`` with probability proportional to their area; a mesh of zero area raises ValueError, named ``what``."""
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    if not area.sum() > 0:
        raise ValueError(f"{what}: the mesh has zero area")
    tri = rng.choice(len(t), size=count, p=area / area.sum())
    return a[tri], b[tri], c[tri]


def sample_surface(vertices, triangles, count: int, seed: int = 0) -> np.ndarray:
    """``count`` points uniform by area on the mesh surface (a numpy Generator seeded with ``seed``).

    Returns:
        [count, 3] float64.
    """
    v, t = _check_mesh(vertices, triangles)
    if count < 1:
        raise ValueError(f"sample_surface: count must be >= 1, got {count}")
    rng = np.random.default_rng(seed)
    a, b, c = area_weighted_corners(v, t, count, rng, "sample_surface")
    r1, r2 = rng.random(count), rng.random(count)
    s = np.sqrt(r1)
    return (1 - s)[:, None] * a + (s * (1 - r2))[:, None] * b + (s * r2)[:, None] * c


def missing_samples(
    samples, gaussians: GaussianSet, sigmas: float = 2.0, min_opacity: float = 0.0, chunk: int = 256
) -> np.ndarray:
    """Which surface samples lie outside the ``sigmas`` ellipsoid of every Gaussian with opacity >= ``min_opacity``.

    Args:
        samples: [S, 3] points (scene units).
        gaussians: N Gaussians.
        sigmas: Mahalanobis radius of a Gaussian's reach (2: the 2-sigma ellipsoid).
        min_opacity: Gaussians below it cover nothing.
        chunk: samples per batch.
    Returns:
        [S] bool, True where no Gaussian covers the sample.
    """
    g = gaussians.detach().to("cpu", torch.float64)
    keep = g.opacities >= min_opacity
    means, scales, rot = g.means[keep], g.scales[keep], g.rotations()[keep]
    x = torch.as_tensor(np.asarray(samples, np.float64)).reshape(-1, 3)
    out = torch.ones(len(x), dtype=torch.bool)
    if len(means) == 0:
        return out.numpy()
    reach = sigmas * scales.amax(dim=1)
    for start in range(0, len(x), chunk):
        xs = x[start : start + chunk]
        diff = xs[:, None, :] - means[None]  # [s, N, 3]
        near = diff.norm(dim=-1) <= reach[None]
        local = torch.einsum("snk,nkj->snj", diff, rot) / scales[None]  # coordinates along the principal axes / s
        inside = near & ((local**2).sum(-1) <= sigmas**2)
        out[start : start + chunk] = ~inside.any(dim=1)
    return out.numpy()


def visible_samples(samples, cameras: Sequence[Camera], vertices, triangles, tolerance: float = 1e-3) -> np.ndarray:
    """[C, S] bool: sample s is inside camera c's image, in front of it and not hidden by the mesh.

    A sample is unhidden when the ray from the camera centre towards it first hits the mesh no nearer than
    ``tolerance`` (relative to its distance) before it.
    """
    import open3d as o3d  # noqa: PLC0415

    v, t = _check_mesh(vertices, triangles)
    x = np.asarray(samples, np.float64).reshape(-1, 3)
    scene = _raycasting_scene(v, t)
    out = np.zeros((len(cameras), len(x)), dtype=bool)
    xt = torch.from_numpy(x)
    for i, cam in enumerate(cameras):
        uv, z = cam.project(xt)
        inside = (
            (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
        ).numpy()
        origin = cam.center.to(torch.float64).numpy()
        d = x - origin
        dist = np.linalg.norm(d, axis=1)
        rays = np.concatenate([np.broadcast_to(origin, x.shape), d / dist[:, None]], axis=1).astype(np.float32)
        hit = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().astype(np.float64)
        out[i] = inside & (hit >= dist * (1.0 - tolerance))
    return out


def sparsification_curve(uncertainty, error, steps: int = 100) -> np.ndarray:
    """Mean error of the Gaussians left after removing the fraction f of the most uncertain, f = k / steps.

    Ties in the uncertainty are broken by the error, the worse first removed last (so a constant uncertainty gives
    the worst curve, not a lucky one).

    Returns:
        [steps] float64.
    """
    u = np.asarray(uncertainty, np.float64).reshape(-1)
    e = np.asarray(error, np.float64).reshape(-1)
    if u.shape != e.shape or len(u) == 0:
        raise ValueError(f"sparsification_curve: {u.size} uncertainties against {e.size} errors (need >= 1 each)")
    order = np.lexsort((e, -u))  # by u descending, ties: the smaller error removed first
    tail = np.cumsum(e[order][::-1])[::-1]  # tail[i] = sum of the errors from position i on
    i = np.minimum(np.arange(steps) * len(u) // steps, len(u) - 1)  # the first kept position per fraction
    return tail[i] / (len(u) - i)


def ause(uncertainty, error, steps: int = 100) -> float:
    """Area under the sparsification error: mean of (curve_u - curve_oracle) / mean error (module docstring).

    Returns:
        >= 0; NaN when the mean error is 0.
    """
    e = np.asarray(error, np.float64).reshape(-1)
    mean = float(e.mean()) if e.size else 0.0
    if not mean > 0:
        return math.nan
    gap = sparsification_curve(uncertainty, e, steps) - sparsification_curve(e, e, steps)
    return float(gap.mean() / mean)
