"""Gaussians -> solid particles: the static boundary the fluid probes flow against (paper Sec. 3.2).

A lattice is sampled at the fluid particle spacing, in simulation metres (Y-up). A lattice point x is
solid when the combined opacity of the Gaussians reaches the threshold tau (0.3, as in the paper):

    1 - prod_g (1 - o_g exp(-d_g(x)^2 / 2)) >= tau,    d_g(x)^2 = (x - mu_g)^T Sigma_g^-1 (x - mu_g),

where d_g is the Mahalanobis distance to Gaussian g. The product is accumulated as a sum of logarithms
(log-transmittance, each factor clamped to at least 1e-6 so the logarithm stays finite), and each
Gaussian visits only the lattice points inside the axis-aligned box of its 3-sigma ellipsoid
(half-extent 3 sqrt(Sigma_kk) along axis k). A point left out by the cut has d_g >= 3, so the cut
changes its log-transmittance by at most -log(1 - o_g e^-4.5) per Gaussian.

Optionally, empty regions enclosed by the solid are filled (a hollow shell becomes a solid ball): the
empty cells connected to the (padded) lattice border by 6-connectivity are outside, every other
empty cell is a cavity.

Sampling note: a Gaussian much thinner than the spacing may fall between lattice points and then
leaves no solid point; that is the resolution of the fluid, not an error.

The fast path is a Taichi kernel (:mod:`nbv.solid_kernels`); :func:`combined_opacity_reference` is its
brute-force numpy twin.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
import taichi as ti

from recon.gaussians import GaussianSet, quaternion_to_rotation

from . import solid_kernels

log = logging.getLogger(__name__)

# Largest o exp(-d^2/2) used in a logarithm: log(1 - 1e-6) stays finite.
MAX_ALPHA = 1.0 - 1e-6
# Peak bytes per lattice point during solidification: f32 log-transmittance and its f64 copy, bool
# occupancy, and the int64 run labels, flags and masks of the cavity fill.
BYTES_PER_POINT = 4 + 8 + 1 + 11
# Work items (Gaussian, lattice point) per kernel launch, so that the loop index fits in int32.
_WORK_CHUNK = 1 << 28
# Beyond this many work items per lattice point the Gaussians are mostly huge floaters.
_MAX_WORK_PER_POINT = 64

_Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


@dataclass(frozen=True)
class SceneTransform:
    """Scene units and axes -> simulation metres, Y-up.

    Attributes:
        up_axis: ``"y"`` or ``"z"``; z-up scenes are rotated so that +z -> +y: (x, y, z) -> (x, z, -y).
        scale: metres per scene unit (> 0).

    Example:
        >>> SceneTransform("z", 2.0).to_sim(np.array([[0.0, 0.0, 1.0]]))
        array([[0., 2., 0.]])
    """

    up_axis: str = "y"
    scale: float = 1.0

    def __post_init__(self) -> None:
        if self.up_axis not in ("y", "z"):
            raise ValueError(f"SceneTransform.up_axis must be 'y' or 'z', got {self.up_axis!r}")
        if not (isinstance(self.scale, (int, float)) and math.isfinite(self.scale) and self.scale > 0):
            raise ValueError(f"SceneTransform.scale must be a finite number > 0 (metres per scene unit), "
                             f"got {self.scale!r}")

    @property
    def rotation(self) -> np.ndarray:
        """[3, 3] rotation from scene axes to simulation axes."""
        return _Z_UP_TO_Y_UP.copy() if self.up_axis == "z" else np.eye(3)

    def to_sim(self, points: np.ndarray) -> np.ndarray:
        """Scene points [N, 3] -> simulation metres [N, 3] (float64)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return self.scale * (p @ self.rotation.T)

    def to_scene(self, points: np.ndarray) -> np.ndarray:
        """Simulation metres [N, 3] -> scene points [N, 3] (the inverse of :meth:`to_sim`)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return (p @ self.rotation) / self.scale

    def covariances_to_sim(self, covs: np.ndarray) -> np.ndarray:
        """Scene covariances [N, 3, 3] -> simulation covariances scale^2 M Sigma M^T [N, 3, 3] (m^2)."""
        c = np.asarray(covs, dtype=np.float64).reshape(-1, 3, 3)
        m = self.rotation
        return (self.scale ** 2) * (m @ c @ m.T)


@dataclass(frozen=True)
class SolidifyConfig:
    """How Gaussians become solid lattice points.

    Attributes:
        spacing: lattice spacing, simulation metres (= the fluid particle spacing 2 r).
        opacity_threshold: tau in (0, 1); a point is solid when the combined opacity is >= tau.
        sigma_cutoff: each Gaussian visits only the lattice points in its ``sigma_cutoff``-sigma box.
        fill_cavities: fill empty regions enclosed by the solid (a hollow shell becomes a solid).
        max_points: lattice-size guard, checked on an estimate before anything is allocated.
        bounds: optional ((3,), (3,)) min and max corners, simulation metres; the lattice is clipped to
            this box (to leave out floaters far from the object).
        min_points: fewer solid points than this is a degenerate solid (an error).
    """

    spacing: float
    opacity_threshold: float = 0.3
    sigma_cutoff: float = 3.0
    fill_cavities: bool = False
    max_points: int = 20_000_000
    bounds: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    min_points: int = 8

    def __post_init__(self) -> None:
        if not (math.isfinite(self.spacing) and self.spacing > 0):
            raise ValueError(f"SolidifyConfig.spacing must be a finite length > 0 m, got {self.spacing}")
        if not (0.0 < self.opacity_threshold < 1.0):
            raise ValueError(f"SolidifyConfig.opacity_threshold (tau) must be in (0, 1), got {self.opacity_threshold}")
        if not (math.isfinite(self.sigma_cutoff) and self.sigma_cutoff > 0):
            raise ValueError(f"SolidifyConfig.sigma_cutoff must be > 0 (in standard deviations), "
                             f"got {self.sigma_cutoff}")
        if int(self.max_points) < 1:
            raise ValueError(f"SolidifyConfig.max_points must be >= 1, got {self.max_points}")
        if int(self.min_points) < 1:
            raise ValueError(f"SolidifyConfig.min_points must be >= 1, got {self.min_points}")
        if self.bounds is not None:
            try:
                lo, hi = (np.asarray(b, dtype=np.float64).reshape(3) for b in self.bounds)
            except (TypeError, ValueError) as exc:
                raise ValueError(f"SolidifyConfig.bounds must be ((xmin, ymin, zmin), (xmax, ymax, zmax)) in m, "
                                 f"got {self.bounds!r}") from exc
            if not (np.isfinite(lo).all() and np.isfinite(hi).all() and (lo < hi).all()):
                raise ValueError(f"SolidifyConfig.bounds must be finite with min < max on every axis, "
                                 f"got {self.bounds!r}")
            object.__setattr__(self, "bounds", (tuple(lo.tolist()), tuple(hi.tolist())))


@dataclass(frozen=True)
class Solid:
    """Solid lattice points.

    Attributes:
        points: [M, 3] float64 simulation metres, the lattice points that are solid.
        lattice_min: [3] simulation metres, lattice point (0, 0, 0) (a multiple of the spacing).
        lattice_shape: (X, Y, Z) lattice points per axis.
        occupancy: [X, Y, Z] bool, solid points (after cavity filling).
    """

    points: np.ndarray
    lattice_min: np.ndarray
    lattice_shape: tuple[int, int, int]
    occupancy: np.ndarray


def _numpy64(t) -> np.ndarray:
    return t.detach().to("cpu").double().numpy()


def _rotations_in_sim(gaussians: GaussianSet, transform: SceneTransform) -> np.ndarray:
    """[N, 3, 3] principal axes in simulation axes, computed in float64 (orthogonal to rounding)."""
    rot = quaternion_to_rotation(gaussians.quats.detach().to("cpu").double()).numpy()
    return transform.rotation @ rot


def gaussian_arrays_in_sim(gaussians: GaussianSet,
                           transform: SceneTransform) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The Gaussians' geometry in simulation metres.

    Args:
        gaussians: N Gaussians in scene units.
        transform: scene -> simulation.
    Returns:
        means [N, 3] m, covariances [N, 3, 3] m^2, opacities [N], largest principal radii r_g [N] m,
        all float64.
    """
    means = transform.to_sim(_numpy64(gaussians.means))
    rot = _rotations_in_sim(gaussians, transform)
    scales = transform.scale * np.exp(_numpy64(gaussians.log_scales))
    m = rot * scales[:, None, :]
    covs = m @ np.swapaxes(m, -1, -2)
    return means, covs, _numpy64(gaussians.opacities), scales.max(axis=1)


def _inverse_covariances(gaussians: GaussianSet, transform: SceneTransform) -> np.ndarray:
    """[N, 3, 3] Sigma^-1 = R diag(1 / s^2) R^T in simulation units (no matrix inversion: thin Gaussians stay exact)."""
    rot = _rotations_in_sim(gaussians, transform)
    inv_scales = 1.0 / (transform.scale * np.exp(_numpy64(gaussians.log_scales)))
    m = rot * inv_scales[:, None, :]
    return m @ np.swapaxes(m, -1, -2)


def _box_half_extents(covs: np.ndarray, sigma_cutoff: float) -> np.ndarray:
    """[N, 3] half-extents of the axis-aligned boxes of the sigma_cutoff ellipsoids, m."""
    return sigma_cutoff * np.sqrt(np.maximum(np.einsum("nkk->nk", covs), 0.0))


def _lattice_geometry(means: np.ndarray, covs: np.ndarray, config: SolidifyConfig) -> tuple[np.ndarray, np.ndarray]:
    """Lattice origin (snapped to a multiple of the spacing) and point counts per axis (float64, may be huge)."""
    ext = _box_half_extents(covs, config.sigma_cutoff)
    lo, hi = (means - ext).min(0), (means + ext).max(0)
    if config.bounds is not None:
        lo = np.maximum(lo, config.bounds[0])
        hi = np.minimum(hi, config.bounds[1])
        if (hi < lo).any():
            raise ValueError(f"SolidifyConfig.bounds {config.bounds} do not overlap the Gaussians' 3-sigma boxes "
                             f"[{lo.tolist()}, {hi.tolist()}] (sim metres); widen the bounds or check the scale")
    s = config.spacing
    lattice_min = np.floor(lo / s) * s
    dims = np.floor((hi - lattice_min) / s + 1e-9) + 1.0
    return lattice_min, np.maximum(dims, 1.0)


def estimate_lattice_points(gaussians: GaussianSet, config: SolidifyConfig, transform: SceneTransform) -> int:
    """Number of lattice points :func:`gaussians_to_solid` would allocate (cheap; nothing large is allocated).

    Args:
        gaussians: N Gaussians, scene units. config: solidification parameters. transform: scene -> sim.
    Returns:
        X * Y * Z.
    """
    gaussians.check("gaussians")
    means, covs, _, _ = gaussian_arrays_in_sim(gaussians, transform)
    _, dims = _lattice_geometry(means, covs, config)
    return int(np.prod(dims))


def _box_index_ranges(means, covs, lattice_min, dims, config) -> tuple[np.ndarray, np.ndarray]:
    """First and last lattice index (inclusive, clipped to the lattice) of every Gaussian's sigma box."""
    ext = _box_half_extents(covs, config.sigma_cutoff)
    s = config.spacing
    first = np.ceil((means - ext - lattice_min) / s)
    last = np.floor((means + ext - lattice_min) / s)
    first = np.clip(first, 0, dims - 1).astype(np.int64)
    last = np.clip(last, -1, dims - 1).astype(np.int64)
    return first, last


def fill_enclosed(occupancy: np.ndarray) -> np.ndarray:
    """Mark empty cells not connected (6-connectivity) to the lattice border as solid.

    The lattice is padded by one empty layer so that the whole border is one connected outside. The
    outside is grown by sweeps along x, y and z: in each line, a run of empty cells between two solid
    cells is outside when any of its cells is; the sweeps repeat until nothing changes.

    Args:
        occupancy: [X, Y, Z] bool, solid cells.
    Returns:
        [X, Y, Z] bool, solid cells plus the enclosed cavities.
    """
    occupancy = np.asarray(occupancy, dtype=bool)
    if not occupancy.any():
        return occupancy.copy()
    # Cavities lie inside the bounding box of the solid cells: fill only there.
    slices = []
    for a in range(3):
        used = np.nonzero(occupancy.any(axis=tuple(b for b in range(3) if b != a)))[0]
        slices.append(slice(int(used[0]), int(used[-1]) + 1))
    box = tuple(slices)
    out = occupancy.copy()
    out[box] = _fill_enclosed_box(occupancy[box])
    return out


def _fill_enclosed_box(occupancy: np.ndarray) -> np.ndarray:
    """:func:`fill_enclosed` on a lattice cropped to its solid cells."""
    empty = ~np.pad(occupancy, 1, constant_values=False)
    outside = np.zeros_like(empty)
    outside[0], outside[-1] = True, True
    outside[:, 0], outside[:, -1] = True, True
    outside[:, :, 0], outside[:, :, -1] = True, True
    outside &= empty
    stable_axes = 0
    axis = 0
    while stable_axes < 3:
        grown = _grow_along(empty, outside, axis)
        if np.array_equal(grown, outside):
            stable_axes += 1
        else:
            stable_axes = 1
            outside = grown
        axis = (axis + 1) % 3
    filled = ~outside
    return filled[1:-1, 1:-1, 1:-1]


def _grow_along(empty: np.ndarray, outside: np.ndarray, axis: int) -> np.ndarray:
    """One sweep of :func:`fill_enclosed` along ``axis``."""
    e = np.moveaxis(empty, axis, -1)
    o = np.moveaxis(outside, axis, -1)
    length = e.shape[-1]
    e2 = e.reshape(-1, length)
    # Cells of a line share a run label while no solid cell separates them.
    labels = np.cumsum(~e2, axis=1, dtype=np.int64)
    labels += (np.arange(e2.shape[0], dtype=np.int64) * (length + 1))[:, None]
    flagged = np.zeros(e2.shape[0] * (length + 1), dtype=bool)
    flagged[labels[o.reshape(-1, length)]] = True
    grown = (e2 & flagged[labels]).reshape(e.shape)
    return np.ascontiguousarray(np.moveaxis(grown, -1, axis))


def lattice_log_transmittance(gaussians: GaussianSet, config: SolidifyConfig,
                              transform: SceneTransform) -> tuple[np.ndarray, np.ndarray]:
    """The fast path: log-transmittance sum_g log(1 - o_g exp(-d_g^2 / 2)) at every lattice point.

    Args:
        gaussians: N Gaussians, scene units (checked for NaN/Inf and zero quaternions first).
        config: lattice spacing (sim m), sigma cut-off, size guard, bounds.
        transform: scene -> simulation metres, Y-up.
    Returns:
        lattice_min [3] m (point (i, j, k) is lattice_min + spacing (i, j, k)), log-transmittance [X, Y, Z]
        float32 (the combined opacity is 1 - exp of it).
    Raises:
        ValueError: the lattice would exceed ``config.max_points`` (with the estimate and the fix).
    """
    gaussians.check("gaussians")
    means, covs, opacities, _ = gaussian_arrays_in_sim(gaussians, transform)
    lattice_min, dims_f = _lattice_geometry(means, covs, config)
    estimate = float(np.prod(dims_f))
    if estimate > config.max_points:
        raise ValueError(
            f"the solid lattice would have about {estimate:.3g} points ({dims_f.astype(np.int64).tolist()}, "
            f"~{estimate * BYTES_PER_POINT / 2**20:.0f} MiB) > max_points = {config.max_points}; use a larger "
            f"spacing (now {config.spacing} m), a smaller scene scale (now {transform.scale} m per unit), prune "
            f"large or far-away floater Gaussians, or set SolidifyConfig.bounds around the object")
    dims = dims_f.astype(np.int64)
    first, last = _box_index_ranges(means, covs, lattice_min, dims, config)
    sizes = np.prod(np.maximum(last - first + 1, 0), axis=1)
    keep = np.nonzero(sizes > 0)[0]
    total = int(sizes.sum())
    if total > _MAX_WORK_PER_POINT * max(estimate, 1.0):
        raise ValueError(
            f"the Gaussians' {config.sigma_cutoff}-sigma boxes cover {total:.3g} lattice points in all, "
            f"{total / estimate:.0f} per lattice point: the set holds many huge Gaussians; prune floaters or "
            f"set SolidifyConfig.bounds")
    log_t = ti.ndarray(ti.f32, shape=tuple(int(d) for d in dims))
    log_t.fill(0.0)
    if total:
        offsets = np.concatenate([[0], np.cumsum(sizes[keep])]).astype(np.int64)
        args = _ndarrays(
            offsets=(offsets, ti.i64), box_lo=(first[keep].astype(np.int32), ti.i32),
            box_dims=((last[keep] - first[keep] + 1).astype(np.int32), ti.i32),
            means=(means[keep], ti.f64), inv_covs=(_inverse_covariances(gaussians, transform)[keep], ti.f64),
            opacities=(opacities[keep], ti.f64))
        for start in range(0, total, _WORK_CHUNK):
            solid_kernels.splat_log_transmittance(
                start, min(_WORK_CHUNK, total - start), args["offsets"], args["box_lo"], args["box_dims"],
                args["means"], args["inv_covs"], args["opacities"], ti.Vector(lattice_min.tolist(), ti.f64),
                float(config.spacing), MAX_ALPHA, log_t)
    return lattice_min, log_t.to_numpy()


def gaussians_to_solid(gaussians: GaussianSet, config: SolidifyConfig, transform: SceneTransform) -> Solid:
    """Solid lattice points of a Gaussian set (combined opacity >= tau, optionally cavities filled).

    Args:
        gaussians: N Gaussians, scene units (checked for NaN/Inf and zero quaternions first).
        config: lattice spacing (sim m), tau, sigma cut-off, cavity filling, size guard, bounds.
        transform: scene -> simulation metres, Y-up.
    Returns:
        Solid.
    Raises:
        ValueError: the lattice would exceed ``config.max_points`` (with the estimate and the fix), or the
            solid is empty or degenerate (suggesting a lower tau, a smaller spacing or another scale).
    Example:
        >>> solid = gaussians_to_solid(g, SolidifyConfig(spacing=0.05), SceneTransform("z", 1.0))
        >>> solid.points.shape  # (M, 3) metres, Y-up
    """
    lattice_min, log_t = lattice_log_transmittance(gaussians, config, transform)
    occupancy = log_t.astype(np.float64) <= math.log1p(-config.opacity_threshold)
    solid_before_fill = int(occupancy.sum())
    if config.fill_cavities and solid_before_fill:
        occupancy = fill_enclosed(occupancy)
        log.info("cavity filling added %d lattice points", int(occupancy.sum()) - solid_before_fill)
    count = int(occupancy.sum())
    if count < config.min_points:
        what = "empty" if count == 0 else f"degenerate ({count} points < min_points = {config.min_points})"
        raise ValueError(
            f"the solid is {what}: too few lattice points reach the combined opacity tau = "
            f"{config.opacity_threshold} at spacing {config.spacing} m over {gaussians.num} Gaussians; use a lower "
            f"opacity_threshold (tau), a smaller spacing, or check the scene scale ({transform.scale} m per unit)")
    points = lattice_min + config.spacing * np.argwhere(occupancy).astype(np.float64)
    log.info("solid: %d of %d lattice points (%s at %.4g m)", count, occupancy.size, list(occupancy.shape),
             config.spacing)
    return Solid(points=points, lattice_min=lattice_min, lattice_shape=tuple(int(d) for d in occupancy.shape),
                 occupancy=occupancy)


def _ndarrays(**arrays) -> dict:
    """Taichi ndarrays from (numpy array, Taichi dtype) pairs."""
    out = {}
    for name, (arr, dtype) in arrays.items():
        nd = ti.ndarray(dtype, shape=arr.shape)
        nd.from_numpy(np.ascontiguousarray(arr))
        out[name] = nd
    return out


def combined_opacity_reference(points: np.ndarray, means: np.ndarray, covs: np.ndarray, opacities: np.ndarray, *,
                               sigma_cutoff: float | None = None) -> np.ndarray:
    """Brute-force twin: 1 - prod_g (1 - min(o_g exp(-d_g^2 / 2), 1 - 1e-6)) at every point, every Gaussian.

    Args:
        points: [P, 3] m. means: [G, 3] m. covs: [G, 3, 3] m^2. opacities: [G].
        sigma_cutoff: None (no cut) or the box cut of the fast path (|x_k - mu_k| <= c sqrt(Sigma_kk)).
    Returns:
        [P] combined opacity, float64.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    log_t = np.zeros(len(pts))
    inv = np.linalg.inv(np.asarray(covs, dtype=np.float64))
    ext = None if sigma_cutoff is None else _box_half_extents(np.asarray(covs, np.float64), sigma_cutoff)
    for g, (mu, o) in enumerate(zip(np.asarray(means, np.float64), np.asarray(opacities, np.float64), strict=True)):
        d = pts - mu
        d2 = np.einsum("pi,ij,pj->p", d, inv[g], d)
        term = np.log1p(-np.minimum(o * np.exp(-0.5 * d2), MAX_ALPHA))
        if ext is not None:
            term = np.where(np.all(np.abs(d) <= ext[g], axis=1), term, 0.0)
        log_t += term
    return 1.0 - np.exp(log_t)
