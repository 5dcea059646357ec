"""The five fluid probes of the paper (Sec. 3.2, Fig. 3 and the appendix "Fluid Initialization").

For a static solid, a fluid slab is placed upstream of it and released:

- ``-x``, ``+x``, ``-z``, ``+z``: the slab flows along that direction at speed lambda (3 m/s);
- ``-y``: the slab sits above the solid and falls from rest under gravity (Y-up).

The slab leaves a gap to the solid's bounding box, has a given thickness along the flow and spans the
solid across the flow with a margin. The domain box is the bounding box of solid and slab, padded.

The solid's bounding box is first snapped outward to a grid of ``snap`` particle spacings (:func:`snapped_box`),
and the slab and domain are laid out around the snapped box. The grid is anchored at the origin, shifted by where
the solid's lattice sits (:func:`lattice_phase`), so that the snapped box moves the box's sides by whole spacings
and the slab's particles stay on the solid's lattice along the flow, shifted with it in a replica. Solids on one
lattice whose boxes' sides lie in the same grid cells (runs on nearly the same Gaussians) then get the same probes,
bit for bit, and so the same empty scene, which is cached by its setup. The price: the solid's box grows by less
than one snap per side, and the slab and the domain, laid out in fractions of its extent, by at most 2.3 snaps per
side (upstream: the box, half its growth in extent as slab thickness, 15 % as padding). Off by default: on the
rounds of an active loop, whose solids' boxes move by several spacings, the larger probes cost more than the empty
scenes the cache saves.
All probes reuse the kernels already compiled in this Taichi runtime: arrays are ndarrays, so a new
probe allocates memory but never recompiles.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from . import sources
from .config import SolverConfig
from .directions import DIRECTIONS
from .scene import lattice_in_box
from .simulation import run
from .solver import DFSPHSolver, StepStats

_AXIS = {"x": 0, "y": 1, "z": 2}


@dataclass(frozen=True)
class ProbeConfig:
    """How the probe slabs are built.

    Attributes:
        speed: inflow speed lambda of the horizontal probes, m/s (the -y probe starts at rest).
        slab_thickness: slab size along the flow, m; None = half the solid's extent along the flow.
        gap: distance from the solid's bounding box to the slab, m; None = two particle spacings.
        margin: how far the slab spans past the solid across the flow, m; None = 15 % of the largest
            solid extent.
        padding: space between the solid/slab box and the domain walls, m; None = 15 % of the largest
            solid extent (at least 3 particle spacings).
        walls: close the domain with wall particles (as the paper does).
        wall_layers: layers of wall particles.
        directions: which probes to run, a subset of :data:`DIRECTIONS`.
        snap: the grid the solid's bounding box is snapped outward to before the slab and the domain are laid out,
            in particle spacings (anchored at the origin plus the solid lattice's phase; :func:`snapped_box`); 0:
            the box as it is.
    """

    speed: float = 3.0
    slab_thickness: float | None = None
    gap: float | None = None
    margin: float | None = None
    padding: float | None = None
    walls: bool = True
    wall_layers: int = 2
    directions: tuple[str, ...] = DIRECTIONS
    snap: int = 0

    def __post_init__(self) -> None:
        if isinstance(self.snap, bool) or not isinstance(self.snap, int) or self.snap < 0:
            raise ValueError(f"probe snap must be a whole number of particle spacings >= 0 (0: off), got {self.snap!r}")
        if not (math.isfinite(self.speed) and self.speed >= 0):
            raise ValueError(f"probe speed must be a finite number >= 0 m/s, got {self.speed}")
        for name in ("slab_thickness", "gap", "margin", "padding"):
            val = getattr(self, name)
            if val is not None and not (math.isfinite(val) and val > 0):
                raise ValueError(f"probe {name} must be > 0 m (or null for the default), got {val}")
        bad = [d for d in self.directions if d not in DIRECTIONS]
        if bad or not self.directions:
            raise ValueError(f"probe directions must be a non-empty subset of {DIRECTIONS}, got {self.directions}")
        object.__setattr__(self, "directions", tuple(self.directions))


@dataclass(frozen=True)
class ProbeSetup:
    """One probe's geometry: domain box, fluid slab and its initial velocity (m, m/s)."""

    direction: str
    velocity: tuple[float, float, float]
    domain_min: tuple[float, float, float]
    domain_max: tuple[float, float, float]
    fluid_min: tuple[float, float, float]
    fluid_max: tuple[float, float, float]


def flow_vector(direction: str) -> np.ndarray:
    """Unit vector of the flow for a probe name, e.g. ``"-x"`` -> (-1, 0, 0)."""
    if direction not in DIRECTIONS:
        raise ValueError(f"unknown probe direction {direction!r}; use one of {DIRECTIONS}")
    v = np.zeros(3)
    v[_AXIS[direction[1]]] = -1.0 if direction[0] == "-" else 1.0
    return v


# A box side within this fraction of the snap grid's cell from a grid line counts as on it, so that float noise in
# a solid's coordinates (one lattice point computed from two origins) never moves the snapped side by a whole cell.
SNAP_TOLERANCE = 1e-6
# The lattice phase is rounded to this fraction of a spacing, for the same reason.
PHASE_STEPS = 2**20


def lattice_phase(lo, spacing: float) -> np.ndarray:
    """Where a box's low sides sit on the lattice of the spacing: ``lo`` modulo ``spacing``, rounded to
    1 / ``PHASE_STEPS`` of a spacing so that float noise never changes it.

    Every solid sampled on one lattice (the solid lattice at one offset, whatever its origin) has one phase: its box
    sides lie half a spacing off its points.

    Args:
        lo: (3,) m. spacing: m (> 0).
    Returns:
        (3,) float64 in [0, spacing), m.
    """
    u = np.asarray(lo, np.float64) / spacing
    steps = np.round((u - np.floor(u)) * PHASE_STEPS) % PHASE_STEPS
    return steps / PHASE_STEPS * spacing


def snapped_box(lo, hi, cell: float, phase=0.0) -> tuple[np.ndarray, np.ndarray]:
    """A box grown outward to a grid: the smallest box around (lo, hi) whose sides lie on ``phase + k cell``.

    Each side moves outward by less than one cell; a side within ``SNAP_TOLERANCE`` cells of a grid line goes to that
    line (so it may move inward by at most that much; with a phase from :func:`lattice_phase`, by its rounding too,
    1 / (2 ``PHASE_STEPS``) spacings: well under a micrometre, against the half spacing between a solid's box and its
    points). Boxes whose sides lie in the same grid cells give the same floats, whatever their own coordinates.

    Args:
        lo, hi: (3,) m, the box. cell: the grid's cell size, m (> 0). phase: (3,) or scalar m, where the grid lines
            sit (:func:`lattice_phase`; 0: the multiples of ``cell``).
    Returns:
        (lo [3], hi [3]) float64 on the grid.
    Example:
        >>> [b.tolist() for b in snapped_box([-0.9, 0.1, 0.0], [0.8, 0.3, 0.5], 0.5)]
        [[-1.0, 0.0, 0.0], [1.0, 0.5, 0.5]]
    """
    phase = np.broadcast_to(np.asarray(phase, np.float64), (3,))
    lo = np.asarray(lo, np.float64) - phase
    hi = np.asarray(hi, np.float64) - phase
    return (
        np.floor(lo / cell + SNAP_TOLERANCE) * cell + phase,
        np.ceil(hi / cell - SNAP_TOLERANCE) * cell + phase,
    )


def probe_setup(solid_points: np.ndarray, direction: str, probe: ProbeConfig, spacing: float) -> ProbeSetup:
    """The slab and domain of one probe around a solid particle set.

    Args:
        solid_points: (M, 3) m, the static solid.
        direction: one of :data:`DIRECTIONS`.
        probe: slab parameters (``probe.snap``: the solid's box is snapped outward to that grid first).
        spacing: particle spacing 2 r, m.
    Returns:
        ProbeSetup.
    """
    pts = np.asarray(solid_points, np.float64).reshape(-1, 3)
    if len(pts) == 0 or not np.isfinite(pts).all():
        raise ValueError("the solid has no particles or non-finite ones; check the solid input")
    lo, hi = pts.min(0) - 0.5 * spacing, pts.max(0) + 0.5 * spacing
    if probe.snap:  # reproducible under small changes of the solid: the same setup, the same empty scene
        lo, hi = snapped_box(lo, hi, probe.snap * spacing, lattice_phase(lo, spacing))
    extent = hi - lo
    flow = flow_vector(direction)
    axis = int(np.argmax(np.abs(flow)))
    upstream_sign = -flow[axis]  # the slab sits on the side the flow comes from
    thickness = probe.slab_thickness if probe.slab_thickness is not None else 0.5 * extent[axis]
    thickness = max(thickness, spacing)
    gap = probe.gap if probe.gap is not None else 2.0 * spacing
    margin = probe.margin if probe.margin is not None else 0.15 * extent.max()
    padding = probe.padding if probe.padding is not None else max(0.15 * extent.max(), 3.0 * spacing)
    fmin, fmax = lo - margin, hi + margin
    if upstream_sign > 0:
        fmin[axis], fmax[axis] = hi[axis] + gap, hi[axis] + gap + thickness
    else:
        fmin[axis], fmax[axis] = lo[axis] - gap - thickness, lo[axis] - gap
    dmin = np.minimum(lo, fmin) - padding
    dmax = np.maximum(hi, fmax) + padding
    speed = 0.0 if direction == "-y" else probe.speed
    return ProbeSetup(
        direction,
        tuple(float(c) for c in flow * speed),
        tuple(dmin.tolist()),
        tuple(dmax.tolist()),
        tuple(fmin.tolist()),
        tuple(fmax.tolist()),
    )


def probe_setups(
    solid_points: np.ndarray, probe: ProbeConfig, spacing: float, directions: Sequence[str] | None = None
) -> dict[str, ProbeSetup]:
    """The setup of every probe around one solid (:func:`probe_setup` per direction), in the order run.

    Args:
        solid_points: (M, 3) m, the static solid (or any points with its bounding box).
        probe: slab parameters.
        spacing: particle spacing 2 r, m.
        directions: which probes (default ``probe.directions``).
    Returns:
        {direction: ProbeSetup}.
    """
    dirs = tuple(directions) if directions is not None else probe.directions
    return {d: probe_setup(solid_points, d, probe, spacing) for d in dirs}


def build_probe_solver(
    solid_points: np.ndarray, setup: ProbeSetup, config: SolverConfig, probe: ProbeConfig
) -> DFSPHSolver:
    """A solver for one probe: solid plus optional walls as boundary (the solid flagged, so each step reports the
    force on it apart from the walls), the slab as fluid."""
    spacing = config.spacing
    boundary = [np.asarray(solid_points, np.float64).reshape(-1, 3)]
    if probe.walls:
        boundary.append(sources.wall_particles(setup.domain_min, setup.domain_max, spacing, probe.wall_layers))
    fluid = lattice_in_box(setup.fluid_min, setup.fluid_max, spacing)
    vel = np.broadcast_to(np.asarray(setup.velocity), fluid.shape)
    solid = np.arange(sum(len(b) for b in boundary)) < len(boundary[0])  # the solid first, then the walls
    return DFSPHSolver(config, setup.domain_min, setup.domain_max, fluid, vel, np.concatenate(boundary), solid)


def run_probes(
    solid_points: np.ndarray,
    config: SolverConfig,
    probe: ProbeConfig,
    steps: int,
    on_step: Callable[[str, DFSPHSolver, StepStats], None] | None = None,
    on_probe_start: Callable[[str, DFSPHSolver], None] | None = None,
    on_probe_end: Callable[[str, DFSPHSolver, list[StepStats]], None] | None = None,
    progress: Callable[[str, StepStats], None] | None = None,
    directions: Sequence[str] | None = None,
    setups: Mapping[str, ProbeSetup] | None = None,
    stop: Callable[[str, DFSPHSolver, StepStats], bool] | None = None,
) -> dict[str, list[StepStats]]:
    """Run the probes one after another in the current Taichi runtime.

    Args:
        solid_points: (M, 3) m.
        config: solver parameters (shared by all probes).
        probe: slab parameters.
        steps: steps per probe.
        on_step(direction, solver, stats): after every step (per-Gaussian accumulation, frames).
        on_probe_start / on_probe_end: around each probe.
        progress(direction, stats): after every step.
        directions: override ``probe.directions``.
        setups: the probes' setups already laid out around ``solid_points`` (:func:`probe_setups`); None: laid out
            here.
        stop(direction, solver, stats): after ``on_step``; True ends that probe after this step
            (:func:`fluidsim.simulation.run`). None: every probe runs ``steps``.
    Returns:
        the step statistics per direction (each as long as its probe ran).
    """
    dirs = tuple(directions) if directions is not None else probe.directions
    if setups is None:
        setups = probe_setups(solid_points, probe, config.spacing, dirs)
    out: dict[str, list[StepStats]] = {}
    for d in dirs:
        solver = build_probe_solver(solid_points, setups[d], config, probe)
        if on_probe_start is not None:
            on_probe_start(d, solver)
        history = run(
            solver,
            steps,
            on_step=None if on_step is None else (lambda s, st, d=d: on_step(d, s, st)),
            progress=None if progress is None else (lambda st, d=d: progress(d, st)),
            stop=None if stop is None else (lambda s, st, d=d: stop(d, s, st)),
        )
        out[d] = history
        if on_probe_end is not None:
            on_probe_end(d, solver, history)
    return out
