"""The solid's lattice before anything large is allocated: its extent, its size, and the guards on its memory and on
the work of the opacity tests (paper Sec. 3.2; the tests themselves are in :mod:`nbv.physics.solidify`).

The lattice spans the sigma boxes of the Gaussians that can make solid (:mod:`nbv.physics.floaters`), snapped to a
multiple of the spacing and clipped to ``SolidifyConfig.bounds``. A work item is one Gaussian and one lattice point
(test 1) or edge (test 2) of its box; the counts here are exact, computed in numpy from the boxes alone.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from nbv.physics import floaters
from nbv.physics.scene_frame import SceneTransform, SimGaussians, as_sim
from nbv.physics.solidify_config import SolidifyConfig
from recon.gaussians import GaussianSet

# Peak bytes per lattice point during solidification: f32 log-transmittance of the point and of its three edges,
# a comparison's f64 copy, three edge flags, the occupancy, and the fill's masks, int32 run labels and links.
BYTES_PER_POINT = 16 + 24 + 3 + 1 + 32
# Wall time of one work item of tests 1-2 on the project's 2-core CPU (2 threads), measured with the splat kernels:
# 55-115 ns per (Gaussian, lattice point) pair and 85-130 ns per (Gaussian, edge) pair for 2k large Gaussians,
# 165-250 ns for 200k small ones (their per-Gaussian set-up). The guard quotes the worst case.
SECONDS_PER_WORK_ITEM = 2.5e-7
# Peak bytes per Gaussian while solidifying (float64 unless noted): the simulation-frame means, covariances,
# opacities and radii (112 B) and inverse covariances (72 B), the rotations while they are built (72 B), each
# field's box indices and sizes (int64 first, last and sizes: 72 B; float temporaries: 48 B), the prefix sum (8 B)
# and the kernels' copies (box corner and size int32, means, inverse covariances, opacities: 128 B). Measured on
# the 5.35M-Gaussian set (the person capture and 34 jittered copies): see docs/performance.md.
BYTES_PER_GAUSSIAN = 512


def box_half_extents(covs: np.ndarray, sigma_cutoff: float) -> np.ndarray:
    """[N, 3] half-extents of the axis-aligned boxes of the sigma_cutoff ellipsoids, m."""
    return sigma_cutoff * np.sqrt(np.maximum(np.einsum("nkk->nk", covs), 0.0))


def solid_boxes(means: np.ndarray, covs: np.ndarray, opacities: np.ndarray, config: SolidifyConfig):
    """The sigma boxes reduced to where each Gaussian can take part in making solid (:mod:`nbv.physics.floaters`: faint
    Gaussians, o_g < tau, clipped to the others' box; o_g < tau / 10 left out): lo, hi [N, 3] m, keep [N]."""
    ext = box_half_extents(covs, config.sigma_cutoff)
    return floaters.solid_capable_boxes(means - ext, means + ext, opacities, config.opacity_threshold)


@dataclass(frozen=True)
class Lattice:
    """The solid's lattice, sized from the Gaussians' boxes before anything large is allocated (once per run: the
    memory estimate, the guards and the solidification read it; a replica shifts it, :meth:`shifted`).

    The lattice spans the boxes of the Gaussians that can make solid (:func:`solid_boxes`), so a faint floater,
    however large, does not widen it.

    Attributes:
        boxes: (lo [N, 3], hi [N, 3], keep [N]) of :func:`solid_boxes`, m.
        extent: (min [3], max [3]) m, the kept boxes' corners clipped to ``SolidifyConfig.bounds``.
        origin: [3] m, lattice point (0, 0, 0): a multiple of the spacing, plus ``lattice_offset`` spacings.
        dims: [3] float64 lattice points per axis (may be huge).
        spacing: m.
    """

    boxes: tuple[np.ndarray, np.ndarray, np.ndarray]
    extent: tuple[np.ndarray, np.ndarray]
    origin: np.ndarray
    dims: np.ndarray
    spacing: float

    @classmethod
    def of(cls, means: np.ndarray, covs: np.ndarray, opacities: np.ndarray, config: SolidifyConfig) -> Lattice:
        """The lattice of ``config`` (spacing, sigma cut-off, tau, bounds, offset) around these Gaussians (sim m).

        Raises:
            ValueError: ``config.bounds`` do not overlap the boxes.
        """
        boxes = solid_boxes(means, covs, opacities, config)
        lo, hi = floaters.lattice_extent(*boxes)
        if config.bounds is not None:
            lo = np.maximum(lo, config.bounds[0])
            hi = np.minimum(hi, config.bounds[1])
            if (hi < lo).any():
                raise ValueError(
                    f"SolidifyConfig.bounds {config.bounds} do not overlap the Gaussians' 3-sigma boxes "
                    f"[{lo.tolist()}, {hi.tolist()}] (sim metres); widen the bounds or check the scale"
                )
        return cls(boxes, (lo, hi), *_placed(lo, hi, config.spacing, config.lattice_offset), config.spacing)

    def shifted(self, lattice_offset) -> Lattice:
        """The same extent with the origin at ``lattice_offset`` (3,) spacings past a multiple of the spacing."""
        origin, dims = _placed(*self.extent, self.spacing, lattice_offset)
        return replace(self, origin=origin, dims=dims)

    @property
    def points(self) -> float:
        """X * Y * Z (float64: may exceed any integer type)."""
        return float(np.prod(self.dims))


def _placed(lo: np.ndarray, hi: np.ndarray, s: float, lattice_offset) -> tuple[np.ndarray, np.ndarray]:
    """Origin and points per axis (float64, at least 1) of the lattice of spacing ``s`` over [lo, hi] whose points
    lie ``lattice_offset`` spacings past the multiples of ``s``."""
    offset = np.asarray(lattice_offset, np.float64)  # spacings; 0: exactly the multiples of s
    origin = (np.floor(lo / s - offset) + offset) * s
    return origin, np.maximum(np.floor((hi - origin) / s + 1e-9) + 1.0, 1.0)


def estimate_lattice_points(
    gaussians: GaussianSet | SimGaussians, config: SolidifyConfig, transform: SceneTransform
) -> int:
    """Number of lattice points :func:`nbv.physics.solidify.gaussians_to_solid` would allocate (cheap; nothing
    large is allocated).

    Args:
        gaussians: N Gaussians, scene units. config: solidification parameters. transform: scene -> sim.
    Returns:
        X * Y * Z.
    """
    sim = as_sim(gaussians, transform)
    return int(Lattice.of(sim.means, sim.covariances, sim.opacities, config).points)


def box_index_ranges(means, covs, lattice_min, dims, config) -> tuple[np.ndarray, np.ndarray]:
    """First and last lattice index (inclusive, clipped to the lattice) of every Gaussian's sigma box."""
    ext = box_half_extents(covs, config.sigma_cutoff)
    s = config.spacing
    first = np.ceil((means - ext - lattice_min) / s)
    last = np.floor((means + ext - lattice_min) / s)
    first = np.clip(first, 0, dims - 1).astype(np.int64)
    last = np.clip(last, -1, dims - 1).astype(np.int64)
    return first, last


def estimate_solidify_bytes(num_gaussians: int, lattice_points: float) -> float:
    """Peak bytes of :func:`nbv.physics.solidify.gaussians_to_solid`: ``BYTES_PER_POINT`` per lattice point and
    ``BYTES_PER_GAUSSIAN`` per Gaussian (the Gaussian set itself, in the caller's hands, is not counted)."""
    return float(lattice_points) * BYTES_PER_POINT + float(num_gaussians) * BYTES_PER_GAUSSIAN


def work_sizes(
    means, covs, lattice_min, dims, config: SolidifyConfig, points: bool = True, edges: bool = True
) -> np.ndarray:
    """[N] float64 work items of each Gaussian: lattice points of its sigma box (test 1, with ``points``) plus the
    edges along x, y and z that meet it (test 2, with ``edges`` and ``config.thin``), the counts of
    :func:`box_index_ranges` and the edge boxes of :mod:`nbv.physics.solidify` from one pass over the Gaussians
    (float64 counts are exact below 2^53)."""
    half = box_half_extents(covs, config.sigma_cutoff)
    lo, hi, span, runs = [], [], [], []
    for a in range(3):  # one axis at a time: contiguous columns, few temporaries
        top = float(dims[a] - 1)
        lo.append(np.ceil((means[:, a] - half[:, a] - lattice_min[a]) / config.spacing))
        hi.append(np.floor((means[:, a] + half[:, a] - lattice_min[a]) / config.spacing))
        span.append(np.maximum(np.clip(hi[a], -1.0, top) - np.clip(lo[a], 0.0, top) + 1.0, 0.0))  # points on a
        if edges and config.thin and dims[a] >= 2:  # edges along a start at points lo - 1 .. hi, up to top - 1
            runs.append(np.maximum(np.clip(hi[a], -1.0, top - 1.0) - np.clip(lo[a] - 1.0, 0.0, top - 1.0) + 1.0, 0.0))
        else:
            runs.append(None)
    sizes = span[0] * span[1] * span[2] if points else np.zeros(len(means))
    for a, run in enumerate(runs):
        if run is not None:
            sizes += run * span[(a + 1) % 3] * span[(a + 2) % 3]
    return sizes


def estimate_work(gaussians: GaussianSet | SimGaussians, config: SolidifyConfig, transform: SceneTransform) -> int:
    """Work items of tests 1 and 2 (a Gaussian and one lattice point or edge of its sigma box) that
    :func:`nbv.physics.solidify.gaussians_to_solid` would run, counted in numpy before anything is allocated
    (``config.max_work`` is the guard)."""
    sim = as_sim(gaussians, transform)
    lattice = Lattice.of(sim.means, sim.covariances, sim.opacities, config)
    return int(work_sizes(sim.means, sim.covariances, lattice.origin, lattice.dims.astype(np.int64), config).sum())


def checked_lattice(
    lattice: Lattice,
    means: np.ndarray,
    covs: np.ndarray,
    config: SolidifyConfig,
    transform: SceneTransform,
    opacities: np.ndarray,
    points: bool = True,
    edges: bool = True,
) -> tuple[np.ndarray, np.ndarray, float]:
    """``lattice``'s origin, point counts per axis (int64) and their product, or the ValueError of a guard: the
    lattice size (naming the Gaussian that alone widens the lattice, if one does), the memory (``config.max_bytes``)
    and the work of the tests to run (``points``: test 1; ``edges``: test 2; ``config.max_work``)."""
    lattice_min, dims_f = lattice.origin, lattice.dims
    estimate = float(np.prod(dims_f))
    if estimate > config.max_points:
        note = floaters.dominant_note(*lattice.boxes, config.spacing, means, covs, opacities, transform)
        raise ValueError(
            f"the solid lattice would have about {estimate:.3g} points ({' x '.join(f'{d:.3g}' for d in dims_f)}, "
            f"~{estimate * BYTES_PER_POINT / 2**20:.3g} MiB) > max_points = {config.max_points}{note}; otherwise use "
            f"a larger spacing (now {config.spacing} m), a smaller scene scale (now {transform.scale} m per unit), "
            f"prune large or far-away floater Gaussians, or set SolidifyConfig.bounds around the object"
        )
    need = estimate_solidify_bytes(len(means), estimate)
    if config.max_bytes is not None and need > config.max_bytes:
        raise ValueError(
            f"solidifying would need about {need / 2**30:.3g} GiB ({estimate:.3g} lattice points x {BYTES_PER_POINT} B "
            f"and {len(means):,} Gaussians x {BYTES_PER_GAUSSIAN} B) but {config.max_bytes / 2**30:.3g} GiB are "
            f"allowed (--max-memory-gb); crop the Gaussians to the object (--crop auto), use a larger spacing "
            f"(--particle-radius; now {config.spacing} m apart), prune Gaussians, or allow more memory"
        )
    dims = dims_f.astype(np.int64)
    sizes = work_sizes(means, covs, lattice_min, dims, config, points, edges)
    _check_work(sizes, estimate, config, transform, means)
    return lattice_min, dims, estimate


def _check_work(
    sizes: np.ndarray, estimate: float, config: SolidifyConfig, transform: SceneTransform, means: np.ndarray
) -> None:
    """The time guard: ValueError when the work items ``sizes`` [N] add up to more than ``config.max_work``, with
    the time it would take, the Gaussian that takes the most and the fix."""
    total = int(sizes.sum())
    if total <= config.max_work:
        return
    worst = int(np.argmax(sizes))
    share = sizes[worst] / total
    note = ""
    if share > 0.1:
        centre = ", ".join(f"{v:.4g}" for v in transform.to_scene(means[worst : worst + 1])[0])
        note = (
            f"; Gaussian {worst} (centre ({centre})) alone takes {100 * share:.0f} % of it: prune it or leave "
            f"it out with a --crop box"
        )
    raise ValueError(
        f"the solid's opacity tests would take {total:.3g} work items (a Gaussian and a lattice point or edge of its "
        f"{config.sigma_cutoff}-sigma box, {total / max(len(sizes), 1):.3g} per Gaussian over a lattice of "
        f"{estimate:.3g} points), about {total * SECONDS_PER_WORK_ITEM / 60:.3g} min on a 2-core CPU, "
        f"> max_work = {config.max_work:.3g}{note}; crop the Gaussians to the object (--crop auto), use a larger "
        f"spacing (--particle-radius; now {config.spacing} m apart) or a smaller scale (--scale; now "
        f"{transform.scale} m per unit), prune large floater Gaussians, or set SolidifyConfig.bounds or max_work"
    )
