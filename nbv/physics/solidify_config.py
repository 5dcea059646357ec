"""How Gaussians become solid lattice points (paper Sec. 3.2): the settings of :mod:`nbv.physics.solidify`, read by
the lattice's guards (:mod:`nbv.physics.lattice`) before anything is allocated. Standard library and numpy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SolidifyConfig:
    """How Gaussians become solid lattice points (see the module docstring for the three tests).

    Attributes:
        spacing: lattice spacing, simulation metres (= the fluid particle spacing 2 r).
        opacity_threshold: tau in (0, 1): the combined opacity at a point, or one Gaussian's peak along an
            edge, that makes solid.
        sigma_cutoff: each Gaussian visits only the lattice points in its ``sigma_cutoff``-sigma box (test 1);
            the lattice spans these boxes.
        fill_cavities: fill what the Gaussians enclose (default; a closed shell becomes a filled body). False
            keeps the shell: test 1 plus one point per cut edge.
        thin: test the lattice edges against each Gaussian's tau-ellipsoid (test 2), so thin Gaussians between
            lattice points are not missed. False: only the combined opacity at the points (the earlier solid,
            for comparisons).
        max_points: lattice-size guard, checked on an estimate before anything is allocated.
        max_work: time guard: the most work items of tests 1 and 2 together (a Gaussian and one lattice point or
            edge of its sigma box; about ``nbv.physics.lattice.SECONDS_PER_WORK_ITEM`` each on the 2-core CPU, so
            the default, 2e9, is at most about 8 min), counted before anything is allocated
            (:func:`nbv.physics.lattice.estimate_work`). The 1.07M- and 5.35M-Gaussian sets at spacing 0.05 take
            4.8e6 and 2.4e7.
        max_bytes: memory guard, bytes: the estimated peak of the solidification
            (:func:`nbv.physics.lattice.estimate_solidify_bytes`) is checked against it before anything is allocated
            (None: not checked).
        bounds: optional ((3,), (3,)) min and max corners, simulation metres; the lattice is clipped to
            this box (to leave out floaters far from the object).
        min_points: fewer solid points than this is a degenerate solid (an error).
        carve_margin: space carving keeps the points within this many spacings in front of a depth map's
            surface. 0 (default): the Gaussians' own solid points are never carved, so no margin is needed to
            keep the surface, and each spacing of margin grows the carved body by about that much.
        lattice_offset: (3,) where the lattice sits, in spacings, each in [0, 1): its points are
            (lattice_offset + (i, j, k)) spacing. (0, 0, 0) (default): the multiples of the spacing. Replicas of a
            probe run (:mod:`nbv.physics.replicas`) shift it to sample the same Gaussians at other lattice positions.
    """

    spacing: float
    opacity_threshold: float = 0.3
    sigma_cutoff: float = 3.0
    fill_cavities: bool = True
    thin: bool = True
    max_points: int = 20_000_000
    max_work: int = 2_000_000_000
    max_bytes: float | None = None
    bounds: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    min_points: int = 8
    carve_margin: float = 0.0
    lattice_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.spacing) and self.spacing > 0):
            raise ValueError(f"SolidifyConfig.spacing must be a finite length > 0 m, got {self.spacing}")
        if not (0.0 < self.opacity_threshold < 1.0):
            raise ValueError(f"SolidifyConfig.opacity_threshold (tau) must be in (0, 1), got {self.opacity_threshold}")
        if not (math.isfinite(self.sigma_cutoff) and self.sigma_cutoff > 0):
            raise ValueError(
                f"SolidifyConfig.sigma_cutoff must be > 0 (in standard deviations), got {self.sigma_cutoff}"
            )
        for name in ("fill_cavities", "thin"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"SolidifyConfig.{name} must be True or False, got {getattr(self, name)!r}")
        if int(self.max_points) < 1:
            raise ValueError(f"SolidifyConfig.max_points must be >= 1, got {self.max_points}")
        if int(self.max_work) < 1:
            raise ValueError(f"SolidifyConfig.max_work must be >= 1 work item, got {self.max_work}")
        if self.max_bytes is not None and not self.max_bytes > 0:
            raise ValueError(f"SolidifyConfig.max_bytes must be > 0 or None, got {self.max_bytes}")
        if int(self.min_points) < 1:
            raise ValueError(f"SolidifyConfig.min_points must be >= 1, got {self.min_points}")
        if not (math.isfinite(self.carve_margin) and self.carve_margin >= 0):
            raise ValueError(
                f"SolidifyConfig.carve_margin must be a finite number >= 0 (spacings), got {self.carve_margin}"
            )
        if self.bounds is not None:
            try:
                lo, hi = (np.asarray(b, dtype=np.float64).reshape(3) for b in self.bounds)
            except (TypeError, ValueError) as exc:
                raise ValueError(
                    f"SolidifyConfig.bounds must be ((xmin, ymin, zmin), (xmax, ymax, zmax)) in m, got {self.bounds!r}"
                ) from exc
            if not (np.isfinite(lo).all() and np.isfinite(hi).all() and (lo < hi).all()):
                raise ValueError(
                    f"SolidifyConfig.bounds must be finite with min < max on every axis, got {self.bounds!r}"
                )
            object.__setattr__(self, "bounds", (tuple(lo.tolist()), tuple(hi.tolist())))
        try:
            offset = np.asarray(self.lattice_offset, dtype=np.float64).reshape(3)
        except (TypeError, ValueError) as exc:
            raise ValueError(
                f"SolidifyConfig.lattice_offset must be 3 fractions of the spacing, got {self.lattice_offset!r}"
            ) from exc
        if not (np.isfinite(offset).all() and (offset >= 0).all() and (offset < 1).all()):
            raise ValueError(
                "SolidifyConfig.lattice_offset must be 3 fractions of the spacing in [0, 1), "
                f"got {self.lattice_offset!r}"
            )
        object.__setattr__(self, "lattice_offset", tuple(offset.tolist()))
