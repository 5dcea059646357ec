"""Gaussians -> solid particles: the static boundary the fluid probes flow against (paper Sec. 3.2).

A lattice is laid at the fluid particle spacing s, in simulation metres (Y-up). Three tests decide which
lattice points are solid:

1. *Combined opacity at the point* (overlapping faint Gaussians add up), with tau = 0.3 as in the paper:

       1 - prod_g (1 - o_g exp(-d_g(p)^2 / 2)) >= tau,    d_g(x)^2 = (x - mu_g)^T Sigma_g^-1 (x - mu_g).

   The product is accumulated as a sum of logarithms (log-transmittance, each factor clamped to at least
   1e-6), each Gaussian visiting only the lattice points in the axis-aligned box of its 3-sigma ellipsoid
   (half-extent 3 sqrt(Sigma_kk)): a point left out has d_g >= 3, a change of at most
   -log(1 - o_g e^-4.5) per Gaussian.
2. *Cut edges* (``SolidifyConfig.thin``): the lattice edge e between two neighbouring points is cut when
   the opacity that a ray along it accumulates reaches tau,

       1 - prod_g (1 - o_g max_{x in e} exp(-d_g(x)^2 / 2)) >= tau,

   each Gaussian entering with its peak over the segment, as 3D Gaussian splatting composites a Gaussian's
   peak along a pixel's ray. d_g^2 is a convex quadratic along the segment, so the peak is exact, and one
   Gaussian with o_g >= tau cuts exactly the edges that meet its tau-level ellipsoid d_g^2 <= 2 ln(o_g / tau).
   Real captures are thin surface elements (normal sigma 1 mm - 1 cm at simulation scale against s = 5 cm,
   median opacity ~0.2, opaque only where several overlap): they fall between lattice points and leave
   test 1 empty, but a closed surface of them cuts every lattice path that crosses it. The same sigma-box
   cut as test 1 applies (per edge, the same bound).
3. *Filling* (``SolidifyConfig.fill_cavities``, the default): the points reachable from the (padded)
   lattice border through uncut edges and points not solid by test 1 are outside; every other point is
   solid. A closed shell becomes a filled body whose solid points are the lattice points it encloses, so
   its volume is sampled at the points (unbiased) instead of inflated to every cell the shell touches.
   Sheets that enclose nothing at lattice resolution (open surfaces, a capture with holes, plates thinner
   than s) must still stop the fluid: of each cut edge whose two ends are outside, the end with the larger
   combined opacity becomes solid (ties: the lower index), one layer of points along the sheet. Without
   filling the same holds for every cut edge that no point of test 1 ends, which leaves a closed,
   one-point-thick shell (no 6-connected lattice path crosses it).

A Gaussian with o_g >= tau that leaves no solid point within one spacing of its centre (a speck smaller than
the spacing that cuts no edge) makes the lattice point nearest its centre solid.

Why edges rather than whole cells: the fill travels along lattice edges, so a peak test along every edge is
exactly what stops it at a Gaussian. Marking every cell (cube of side s) that a tau-ellipsoid touches is as
watertight but grows a body by the cube's support, s/2 on a flat axis-aligned face and 3s/4 on average over
directions: +11 % volume for a 2 m sphere at s = 5 cm, +19 % for a 2 m x 0.75 m x 0.56 m box.

Optional space carving (:func:`nbv.physics.carve.carve_outside`, as the paper's Kaolin sampler): with cameras and
depth maps, the points some camera sees in front of the surface are outside and all others are solid, which
also closes captures with holes.

The fast paths are Taichi kernels (:mod:`nbv.physics.solid_kernels`); :func:`combined_opacity_reference` and
:func:`edge_log_transmittance_reference` are their brute-force numpy twins. The outside region is found in numpy
(:mod:`nbv.physics.fill`): 0.5 s for 10^7 points (3 s for the worst case measured, 30 % random solid points; the old
line sweeps took 62 s on a lattice of nested shells whose outside winds through every one).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
import taichi as ti

from nbv.physics import solid_kernels
from nbv.physics.carve import carve_outside, surface_depths
from nbv.physics.fill import below, occupancy_from_fields, speck_points
from nbv.physics.lattice import Lattice, box_half_extents, box_index_ranges, checked_lattice
from nbv.physics.scene_frame import SceneTransform, SimGaussians, as_sim
from nbv.physics.solidify_config import SolidifyConfig
from recon.gaussians import GaussianSet

log = logging.getLogger(__name__)

# Largest o exp(-d^2/2) used in a logarithm: log(1 - 1e-6) stays finite.
MAX_ALPHA = 1.0 - 1e-6
# Work items (Gaussian, lattice point) per kernel launch, so that the loop index fits in int32.
_WORK_CHUNK = 1 << 28


@dataclass(frozen=True)
class SolidLattice:
    """Solid lattice points.

    Attributes:
        points: [M, 3] float64 simulation metres, the lattice points that are solid.
        lattice_min: [3] simulation metres, lattice point (0, 0, 0) (a multiple of the spacing, plus the
            config's ``lattice_offset`` spacings).
        lattice_shape: (X, Y, Z) lattice points per axis.
        occupancy: [X, Y, Z] bool, the solid points (point (i, j, k) is lattice_min + spacing (i, j, k)).
        spacing: the lattice spacing, m.
        counts: lattice points per test: ``opacity`` (test 1), ``thin`` (one per cut edge), ``enclosed`` (added
            by the fill), ``specks``, ``carved`` (added by space carving), ``total``.
    """

    points: np.ndarray
    lattice_min: np.ndarray
    lattice_shape: tuple[int, int, int]
    occupancy: np.ndarray
    spacing: float = 0.0
    counts: dict[str, int] = field(default_factory=dict)


def _splat_boxes(splat, lead: tuple, first, last, sim, inv_covs, lattice_min, spacing: float, out) -> None:
    """Run the Taichi kernel ``splat`` over every lattice point (or edge) of each Gaussian's box [first, last],
    ``_WORK_CHUNK`` work items per launch, adding into ``out``; ``lead``: the kernel's arguments between the chunk
    and the boxes (the edge axis)."""
    sizes = np.prod(np.maximum(last - first + 1, 0), axis=1)
    keep = np.nonzero(sizes > 0)[0]  # the non-empty boxes
    offsets = np.concatenate([[0], np.cumsum(sizes[keep])]).astype(np.int64)  # exclusive prefix sum, (G' + 1,)
    total = int(offsets[-1])
    if not total:
        return
    boxes = []
    for arr, dtype in (
        (offsets, ti.i64),
        (first[keep].astype(np.int32), ti.i32),
        ((last[keep] - first[keep] + 1).astype(np.int32), ti.i32),
        (sim.means[keep], ti.f64),
        (inv_covs[keep], ti.f64),
        (sim.opacities[keep], ti.f64),
    ):
        boxes.append(ti.ndarray(dtype, shape=arr.shape))
        boxes[-1].from_numpy(np.ascontiguousarray(arr))
    origin = ti.Vector(lattice_min.tolist(), ti.f64)
    for start in range(0, total, _WORK_CHUNK):
        splat(start, min(_WORK_CHUNK, total - start), *lead, *boxes, origin, float(spacing), MAX_ALPHA, out)


def _on_lattice(gaussians, config: SolidifyConfig, transform: SceneTransform, lattice=None, **tests) -> tuple:
    """(sim, lattice_min, dims): the Gaussians in the simulation frame, and the origin and point counts of ``lattice``
    (None: theirs) once its guards (:func:`nbv.physics.lattice.checked_lattice`; ``tests``: the tests that will run)
    passed."""
    sim = as_sim(gaussians, transform)
    if lattice is None:
        lattice = Lattice.of(sim.means, sim.covariances, sim.opacities, config)
    origin, dims, _ = checked_lattice(lattice, sim.means, sim.covariances, config, transform, sim.opacities, **tests)
    return sim, origin, dims


def _log_transmittance(sim: SimGaussians, inv_covs, lattice_min, dims, config) -> np.ndarray:
    """Test 1's field: [X, Y, Z] float32 sum_g log(1 - o_g exp(-d_g^2 / 2)) (Taichi)."""
    first, last = box_index_ranges(sim.means, sim.covariances, lattice_min, dims, config)
    log_t = ti.ndarray(ti.f32, shape=tuple(int(d) for d in dims))
    log_t.fill(0.0)
    splat = solid_kernels.splat_log_transmittance
    _splat_boxes(splat, (), first, last, sim, inv_covs, lattice_min, config.spacing, log_t)
    return log_t.to_numpy()


def lattice_log_transmittance(
    gaussians: GaussianSet | SimGaussians, config: SolidifyConfig, transform: SceneTransform
) -> tuple[np.ndarray, np.ndarray]:
    """Test 1's fast path: log-transmittance sum_g log(1 - o_g exp(-d_g^2 / 2)) at every lattice point.

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
    sim, lattice_min, dims = _on_lattice(gaussians, config, transform, edges=False)
    return lattice_min, _log_transmittance(sim, sim.inverse_covariances(), lattice_min, dims, config)


def _edge_boxes(means, covs, lattice_min, dims, config: SolidifyConfig, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """First and last start point (inclusive, clipped) of the edges along ``axis`` that meet each sigma box.

    The box has half-extents c sqrt(Sigma_kk) (c = ``sigma_cutoff``); an edge from p to p + s e_axis meets it
    when p's other coordinates lie in it and [p_axis, p_axis + s] overlaps it.
    """
    s = config.spacing
    half = box_half_extents(covs, config.sigma_cutoff)
    first = np.ceil((means - half - lattice_min) / s)
    last = np.floor((means + half - lattice_min) / s)
    first[:, axis] -= 1.0
    top = (dims - 1).astype(np.float64)
    top[axis] -= 1.0  # the last point along the axis starts no edge
    first = np.clip(first, 0, np.maximum(top, 0)).astype(np.int64)
    last = np.clip(last, -1, top).astype(np.int64)
    return first, last


def _edge_log_transmittance(sim: SimGaussians, inv_covs, lattice_min, dims, config) -> np.ndarray:
    """Test 2's field: [3, X, Y, Z] float32 sum_g log(1 - o_g max_{x in e} exp(-d_g(x)^2 / 2)) per edge (Taichi)."""
    edges = ti.ndarray(ti.f32, shape=(3, *(int(d) for d in dims)))
    edges.fill(0.0)
    for axis in range(3):
        if dims[axis] < 2:
            continue
        first, last = _edge_boxes(sim.means, sim.covariances, lattice_min, dims, config, axis)
        splat = solid_kernels.splat_edge_log_transmittance
        _splat_boxes(splat, (axis,), first, last, sim, inv_covs, lattice_min, config.spacing, edges)
    return edges.to_numpy()


def lattice_edge_log_transmittance(
    gaussians: GaussianSet | SimGaussians, config: SolidifyConfig, transform: SceneTransform
) -> tuple[np.ndarray, np.ndarray]:
    """Test 2's fast path: the log-transmittance of every lattice edge (each Gaussian at its peak on the edge).

    Args:
        gaussians: N Gaussians, scene units. config: spacing, sigma cut-off, size guard, bounds.
        transform: scene -> sim.
    Returns:
        lattice_min [3] m (the lattice of :func:`lattice_log_transmittance`), [3, X, Y, Z] float32: entry
        [a, i, j, k] belongs to the edge from point (i, j, k) to its neighbour along axis a (0 on the last layer,
        which starts no edge). The edge is cut where it is <= log(1 - tau) (:func:`lattice_cut_edges`).
    """
    sim, lattice_min, dims = _on_lattice(gaussians, config, transform, points=False)
    return lattice_min, _edge_log_transmittance(sim, sim.inverse_covariances(), lattice_min, dims, config)


def lattice_cut_edges(
    gaussians: GaussianSet | SimGaussians, config: SolidifyConfig, transform: SceneTransform
) -> tuple[np.ndarray, np.ndarray]:
    """Test 2: lattice_min [3] m and cut [3, X, Y, Z] bool, the edges whose accumulated opacity reaches tau."""
    lattice_min, edge_log_t = lattice_edge_log_transmittance(gaussians, config, transform)
    return lattice_min, below(edge_log_t, config.opacity_threshold)


def edge_log_transmittance_reference(
    lattice_min: np.ndarray,
    shape: tuple[int, int, int],
    spacing: float,
    means: np.ndarray,
    covs: np.ndarray,
    inv_covs: np.ndarray,
    opacities: np.ndarray,
    *,
    sigma_cutoff: float | None = None,
) -> np.ndarray:
    """Brute-force twin of :func:`lattice_edge_log_transmittance`: every edge against every Gaussian (float64).

    Args:
        lattice_min: [3] m. shape: (X, Y, Z). spacing: m. means: [G, 3] m. covs: [G, 3, 3] m^2 (for the box cut).
        inv_covs: [G, 3, 3] 1/m^2. opacities: [G].
        sigma_cutoff: None (no cut) or the fast path's box cut (the edge meets |x_k - mu_k| <= c sqrt(Sigma_kk)).
    Returns:
        [3, X, Y, Z] float64 (0 on the last layer along each axis).
    """
    idx = np.stack(np.meshgrid(*[np.arange(d) for d in shape], indexing="ij"), -1).reshape(-1, 3)
    pts = np.asarray(lattice_min, np.float64) + spacing * idx
    out = np.zeros((3, len(pts)))
    ext = None if sigma_cutoff is None else box_half_extents(np.asarray(covs, np.float64), sigma_cutoff)
    for g in range(len(means)):
        a_mat = np.asarray(inv_covs[g], np.float64)
        d = pts - np.asarray(means[g], np.float64)
        for axis in range(3):
            ad = d[:, 0] * a_mat[axis, 0] + d[:, 1] * a_mat[axis, 1] + d[:, 2] * a_mat[axis, 2]
            t = np.clip(-ad / (spacing * a_mat[axis, axis]), 0.0, 1.0)
            y = d.copy()
            y[:, axis] += t * spacing
            q = np.einsum("pa,ab,pb->p", y, a_mat, y)
            term = np.log1p(-np.minimum(opacities[g] * np.exp(-0.5 * q), MAX_ALPHA))
            if ext is not None:  # the segment [d, d + s e_axis] against the box [-ext, ext]
                hi = d.copy()
                hi[:, axis] += spacing
                term = np.where(np.all((hi >= -ext[g]) & (d <= ext[g]), axis=1), term, 0.0)
            out[axis] += term
    out = out.reshape(3, *shape)
    for axis in range(3):
        out[(axis, *[slice(None)] * axis, -1)] = 0.0  # the last layer starts no edge
    return out


def gaussians_to_solid(
    gaussians: GaussianSet | SimGaussians,
    config: SolidifyConfig,
    transform: SceneTransform,
    *,
    cameras=None,
    depths=None,
) -> SolidLattice:
    """Solid lattice points of a Gaussian set (the module docstring's tests 1-3, specks, optional carving).

    Args:
        gaussians: N Gaussians, scene units (checked for NaN/Inf and zero quaternions first).
        config: lattice spacing (sim m), tau, sigma cut-off, filling, thin test, size guard, bounds.
        transform: scene -> simulation metres, Y-up.
        cameras: optional ``recon.camera.Camera`` list (scene frame, world-to-camera OpenCV): carve the space
            they see empty (:func:`nbv.physics.carve.carve_outside`).
        depths: with ``cameras``, one [H, W] depth map per camera (scene units, inf where empty); None renders
            them from the Gaussians (:func:`nbv.physics.carve.surface_depths`).
    Returns:
        SolidLattice.
    Raises:
        ValueError: the lattice would exceed ``config.max_points`` (with the estimate and the fix), or the
            solid is empty or degenerate (suggesting a lower tau, a smaller spacing or another scale).
    Example:
        >>> solid = gaussians_to_solid(g, SolidifyConfig(spacing=0.05), SceneTransform("z", 1.0))
        >>> solid.points.shape  # (M, 3) metres, Y-up
    """
    return _solid(gaussians, None, config, transform, cameras, depths)


def solid_on_lattice(
    sim: SimGaussians, lattice: Lattice, config: SolidifyConfig, transform: SceneTransform
) -> SolidLattice:
    """:func:`gaussians_to_solid` (with no carving) on a lattice already sized for ``sim`` under ``config`` (a run's,
    sized once: :attr:`nbv.physics.plan.RunFrame.lattice`)."""
    return _solid(sim, lattice, config, transform)


def _solid(
    gaussians, lattice, config: SolidifyConfig, transform: SceneTransform, cameras=None, depths=None
) -> SolidLattice:
    """:func:`gaussians_to_solid` on ``lattice`` (None: the Gaussians' own): tests 1-3 and the specks after the
    lattice's guards, the carving, then the ValueError when too few points are solid; logged."""
    sim, lattice_min, dims = _on_lattice(gaussians, config, transform, lattice)
    tau = config.opacity_threshold
    inv_covs = sim.inverse_covariances()
    log_t = _log_transmittance(sim, inv_covs, lattice_min, dims, config)
    cuts = below(_edge_log_transmittance(sim, inv_covs, lattice_min, dims, config), tau) if config.thin else None
    occupancy, counts = occupancy_from_fields(log_t, cuts, tau, config.fill_cavities)
    del log_t, cuts
    counts["specks"] = counts["carved"] = 0
    if config.thin:
        specks = speck_points(occupancy, sim.means, sim.opacities, lattice_min, config.spacing, tau)
        counts["specks"] = int(specks.sum())
        occupancy |= specks
    if cameras is not None:
        before = int(occupancy.sum())
        if depths is None:
            depths = surface_depths(sim.gaussians, cameras)
        occupancy = carve_outside(
            occupancy, lattice_min, config.spacing, cameras, depths, transform, margin=config.carve_margin
        )
        counts["carved"] = int(occupancy.sum()) - before
    count = counts["total"] = int(occupancy.sum())
    if count < config.min_points:
        what = "empty" if count == 0 else f"degenerate ({count} points < min_points = {config.min_points})"
        raise ValueError(
            f"the solid is {what}: too few lattice points reach the combined opacity tau = "
            f"{tau} at spacing {config.spacing} m over {sim.num} Gaussians; use a lower "
            f"opacity_threshold (tau), a smaller spacing, or check the scene scale ({transform.scale} m per unit)"
        )
    points = lattice_min + config.spacing * np.argwhere(occupancy).astype(np.float64)
    log.info(
        "solid: %d of %d lattice points (%s at %.4g m): %s",
        count,
        occupancy.size,
        list(occupancy.shape),
        config.spacing,
        counts,
    )
    return SolidLattice(
        points=points,
        lattice_min=lattice_min,
        lattice_shape=tuple(int(d) for d in occupancy.shape),
        occupancy=occupancy,
        spacing=float(config.spacing),
        counts=counts,
    )


def combined_opacity_reference(
    points: np.ndarray, means: np.ndarray, covs: np.ndarray, opacities: np.ndarray, *, sigma_cutoff: float | None = None
) -> np.ndarray:
    """Brute-force twin of test 1: 1 - prod_g (1 - min(o_g exp(-d_g^2 / 2), 1 - 1e-6)) at every point, every Gaussian.

    Args:
        points: [P, 3] m. means: [G, 3] m. covs: [G, 3, 3] m^2. opacities: [G].
        sigma_cutoff: None (no cut) or the box cut of the fast path (|x_k - mu_k| <= c sqrt(Sigma_kk)).
    Returns:
        [P] combined opacity, float64.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    log_t = np.zeros(len(pts))
    inv = np.linalg.inv(np.asarray(covs, dtype=np.float64))
    ext = None if sigma_cutoff is None else box_half_extents(np.asarray(covs, np.float64), sigma_cutoff)
    for g, (mu, o) in enumerate(zip(np.asarray(means, np.float64), np.asarray(opacities, np.float64), strict=True)):
        d = pts - mu
        d2 = np.einsum("pi,ij,pj->p", d, inv[g], d)
        term = np.log1p(-np.minimum(o * np.exp(-0.5 * d2), MAX_ALPHA))
        if ext is not None:
            term = np.where(np.all(np.abs(d) <= ext[g], axis=1), term, 0.0)
        log_t += term
    return 1.0 - np.exp(log_t)


def is_empty_solid(exc: ValueError) -> bool:
    """Whether ``exc`` is the solidification's refusal of no (or a degenerate) solid (its "the solid is ..."
    message), as a barely trained reconstruction gives."""
    return "the solid is " in str(exc)
