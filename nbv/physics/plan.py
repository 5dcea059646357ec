"""The plan of a probe run (paper Sec. 3.2): what every step of :func:`nbv.physics.simulate_gaussians` reads, derived
once.

No paper equation is implemented here; this gathers what the steps of a probe run share, so that none of them
derives it again (a step that recomputes what an earlier one derived is a second owner waiting to disagree):

- :class:`RunFrame`, before any solid exists: the scene -> simulation transform (up and scale), the Gaussians that
  the crop keeps, those Gaussians in simulation metres (:class:`nbv.physics.scene_frame.SimGaussians`), their
  reach n r_g (Eq. 2) and the solid's lattice (:class:`nbv.physics.lattice.Lattice`). The memory bound, the
  solidification, the accumulator and the result read it.
- :class:`ProbePlan`, once the solid exists: one :class:`fluidsim.probes.ProbeSetup` per probe (slab, domain,
  inflow; Fig. 3), laid out once. The exact memory check, the time-step check, the recording check, the
  accumulator's bounds, the probes and the empty scene read it. Before the solid, :meth:`ProbePlan.bound` lays the
  probes out around the lattice for the memory bound.
- :class:`ProbeRunContext`: what the steps of one run read besides these (progress, source, recording, timings).

Example:
    >>> frame = RunFrame.of(gaussians, PhysicsConfig.quick())  # doctest: +SKIP
    >>> plan = ProbePlan.of(frame.solidify().points, frame.config)  # doctest: +SKIP
    >>> plan.setups["-x"].domain_min  # doctest: +SKIP
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np
import torch

from fluidsim.probes import ProbeSetup, probe_setups
from fluidsim.scene import lattice_in_box
from nbv.physics.config import PhysicsConfig, kept_gaussians, scene_transform
from nbv.physics.lattice import Lattice
from nbv.physics.result import PhysicsResult, gaussians_sha256
from nbv.physics.scene_frame import SceneTransform, SimGaussians, gaussian_arrays_in_sim
from nbv.physics.solidify import SolidLattice, solid_on_lattice
from nbv.physics.solidify_config import SolidifyConfig

if TYPE_CHECKING:
    from nbv.physics.trajectory import RecordConfig


@dataclass(frozen=True)
class RunFrame:
    """A probe run's Gaussians in the simulation frame (built once, before the solid).

    Attributes:
        config: the probe settings.
        gaussians: every Gaussian of the run, scene units (checked, on the CPU).
        transform: scene -> simulation metres, Y-up (``config.scale`` "auto" resolved).
        kept: [G] bool, the Gaussians whose centres lie in ``config.crop`` (None: no crop, all are simulated).
        sim: the simulated Gaussians (the kept ones) in simulation metres.
        reach: [K] float64 n r_g of the simulated Gaussians, m (Eq. 2).
        digest: SHA-256 of every Gaussian (:func:`nbv.physics.result.gaussians_sha256`).
        solid_config: ``config.solidify_config()``, how the Gaussians become solid (unshifted).
        lattice: the solid's lattice under ``solid_config``, sized once.
    """

    config: PhysicsConfig
    gaussians: object
    transform: SceneTransform
    kept: np.ndarray | None
    sim: SimGaussians
    reach: np.ndarray
    digest: str
    solid_config: SolidifyConfig
    lattice: Lattice

    @classmethod
    def of(cls, gaussians, config: PhysicsConfig, source: str = "") -> RunFrame:
        """Check ``gaussians`` (a ``recon.gaussians.GaussianSet``, scene units), resolve the frame and the crop, and
        convert the kept Gaussians once.

        Raises:
            ValueError: bad Gaussians (naming ``source``), a crop that keeps none, or no extent for ``scale`` "auto".
        """
        gaussians = gaussians.detach().to("cpu").check(source or "Gaussians")
        kept = kept_gaussians(gaussians, config)
        transform = scene_transform(gaussians, config, kept=kept)
        simulated = gaussians if kept is None else gaussians.subset(torch.from_numpy(np.nonzero(kept)[0]))
        sim = SimGaussians.of(simulated, transform)
        reach = config.reach(sim.radii)
        scfg = config.solidify_config()
        lattice = Lattice.of(sim.means, sim.covariances, sim.opacities, scfg)
        return cls(config, gaussians, transform, kept, sim, reach, gaussians_sha256(gaussians), scfg, lattice)

    @property
    def means(self) -> np.ndarray:
        """[K, 3] float64 centres of the simulated Gaussians, m."""
        return np.ascontiguousarray(self.sim.means, np.float64)

    @property
    def covariances(self) -> np.ndarray:
        """[K, 3, 3] float64 covariances of the simulated Gaussians, m^2."""
        return np.ascontiguousarray(self.sim.covariances, np.float64)

    def solidify(self, lattice_offset: tuple[float, float, float] | None = None) -> SolidLattice:
        """The solid of the simulated Gaussians (:func:`nbv.physics.solidify.gaussians_to_solid` under
        :attr:`solid_config`, on :attr:`lattice`; ``lattice_offset``: the lattice shifted by these fractions
        of the spacing, as a replica of the run is, :mod:`nbv.physics.replicas`)."""
        scfg = (
            self.solid_config if lattice_offset is None else replace(self.solid_config, lattice_offset=lattice_offset)
        )
        return solid_on_lattice(self.sim, self.lattice.shifted(scfg.lattice_offset), scfg, self.transform)

    def expand(self, result: PhysicsResult) -> PhysicsResult:
        """A :class:`nbv.physics.PhysicsResult` on the simulated Gaussians -> one row per Gaussian of the run (the
        cropped-out ones: D_g = 0, no samples; ``kept`` recorded), with the digest of every Gaussian."""
        if self.kept is not None:
            result = expand_to_all(result, self.gaussians, self.kept, self.config)
        return replace(result, gaussians_sha256=self.digest)


def expand_to_all(part: PhysicsResult, gaussians, kept: np.ndarray, config: PhysicsConfig) -> PhysicsResult:
    """A result on the kept Gaussians -> one row per Gaussian of ``gaussians`` (the dropped ones: D_g = 0, no
    samples), with ``kept`` recorded and ``config`` (the crop) restored. D-bar stays the kept Gaussians' own."""
    g = len(kept)

    def full(a: np.ndarray | None, axis: int = 0) -> np.ndarray | None:
        if a is None:
            return None
        shape = list(a.shape)
        shape[axis] = g
        out = np.zeros(shape, a.dtype)
        index = [slice(None)] * a.ndim
        index[axis] = kept
        out[tuple(index)] = a
        return out

    means, covs, _, radii = gaussian_arrays_in_sim(gaussians, part.transform)
    return replace(
        part,
        per_probe=full(part.per_probe, 1),
        per_probe_counts=full(part.per_probe_counts, 1),
        per_probe_distinct=full(part.per_probe_distinct, 1),
        divergence=full(part.divergence),
        divergence_mean=full(part.divergence_mean),
        empty_per_probe=full(part.empty_per_probe, 1),
        means=np.ascontiguousarray(means),
        covariances=np.ascontiguousarray(covs),
        reach=config.reach(radii),
        config=config,
        kept=kept.copy(),
    )


@dataclass(frozen=True)
class ProbePlan:
    """The probes of a run laid out around its solid, once.

    Attributes:
        setups: {direction: ProbeSetup} in the order run (``config.directions``).
        spacing: particle spacing 2 r, m.
        solid_count: the solid particles the probes hold (:meth:`bound`: every lattice point).
    """

    setups: dict[str, ProbeSetup]
    spacing: float
    solid_count: int

    @classmethod
    def of(cls, solid_points: np.ndarray, config: PhysicsConfig) -> ProbePlan:
        """One setup per probe of ``config`` around ``solid_points`` [M, 3] (sim metres)."""
        spacing = 2.0 * config.particle_radius
        setups = probe_setups(solid_points, config.probe_config(), spacing, config.directions)
        return cls(setups, spacing, len(solid_points))

    @classmethod
    def bound(cls, frame: RunFrame) -> ProbePlan:
        """The probes around ``frame``'s lattice, before the solid exists: the lattice's box stands for the solid's
        (the probes laid out around a box of points are those around its two corners) and every lattice point
        counts as solid, so it bounds the plan of :meth:`of` from above."""
        plan = cls.of(np.stack(frame.lattice.extent), frame.config)
        return replace(plan, solid_count=int(frame.lattice.points))

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(min [3], max [3]) m: the box around every probe's domain (the accumulator's lists cover it)."""
        return probe_domains_union(self.setups)

    def fluid_counts(self, directions) -> dict[str, int]:
        """F per probe of ``directions``: the fluid particles of its slab, before running."""
        return {
            d: int(len(lattice_in_box(self.setups[d].fluid_min, self.setups[d].fluid_max, self.spacing)))
            for d in directions
        }


def probe_domains_union(setups: dict[str, ProbeSetup]) -> tuple[np.ndarray, np.ndarray]:
    """(min [3], max [3]) m: the box around the domains of ``setups``."""
    return (
        np.min([np.asarray(s.domain_min, np.float64) for s in setups.values()], axis=0),
        np.max([np.asarray(s.domain_max, np.float64) for s in setups.values()], axis=0),
    )


@dataclass(frozen=True)
class ProbeRunContext:
    """What the steps of one probe run (:func:`nbv.physics.simulate_gaussians`) read besides its solid and plan: set
    at the top, handed down once (a replica gets its own, with its start and recording).

    Attributes:
        frame: the run's :class:`RunFrame`.
        progress: one bar over the probes and the empty scene. source: a label for the result (the .ply path).
        record: the probes to record (:class:`nbv.physics.trajectory.RecordConfig`), or None.
        exact_memory: check the memory around the solid (False: the Gaussians' box was checked and fits).
        started: the run's start (``time.perf_counter()``). solidify_s: the solidification's seconds.
        empty_worker: sets up a worker process that runs empty-scene probes beside the probes
            (:mod:`nbv.physics.empty_worker`; from ``apps``, which alone initialises Taichi), or None: this process
            runs them after the probes.
    """

    frame: RunFrame
    progress: bool = True
    source: str = ""
    record: RecordConfig | None = None
    exact_memory: bool = True
    started: float = field(default_factory=time.perf_counter)
    solidify_s: float = 0.0
    empty_worker: Callable[[], None] | None = None
