"""The planner protocol: what a planner sees each round (:class:`PlanningContext`) and what it answers
(:class:`Selection`), with the fused planners' shortlist size K (:func:`fused_k`)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import torch

from recon.camera import Camera
from recon.datasets import View
from recon.gaussians import GaussianSet

MIN_SHORTLIST = 2  # the smallest top-K of the fused planners (paper appendix: K = max(B - n, 2))


@dataclass(frozen=True)
class ProbeFields:
    """The per-direction divergence of one probe run on the current Gaussians.

    Attributes:
        directions: the P probes, in run order.
        per_probe: [P, N] float64 D_g^(p), 1/s.
        empty_per_probe: [P, N] float64 the same probes without the solid, accumulated onto the same Gaussians
            (1/s), or None when the empty scene was not run (``PhysicsConfig.empty_reference`` False).
    """

    directions: tuple[str, ...]
    per_probe: torch.Tensor
    empty_per_probe: torch.Tensor | None = None

    def __post_init__(self) -> None:
        d = torch.as_tensor(self.per_probe, dtype=torch.float64)
        if d.ndim != 2 or d.shape[0] != len(self.directions) or d.shape[0] < 1:
            raise ValueError(
                f"ProbeFields.per_probe must be [P, N] with P = {len(self.directions)} directions, "
                f"got shape {tuple(d.shape)}"
            )
        if not torch.isfinite(d).all():
            raise ValueError("ProbeFields.per_probe holds NaN or Inf; check the probe run")
        object.__setattr__(self, "per_probe", d)
        if self.empty_per_probe is not None:
            e = torch.as_tensor(self.empty_per_probe, dtype=torch.float64)
            if e.shape != d.shape or not torch.isfinite(e).all():
                raise ValueError(
                    f"ProbeFields.empty_per_probe must be finite and shaped like per_probe "
                    f"{tuple(d.shape)}, got {tuple(e.shape)}"
                )
            object.__setattr__(self, "empty_per_probe", e)


@dataclass(frozen=True)
class PlanningContext:
    """What a planner knows when it picks the next view.

    Attributes:
        gaussians: the current reconstruction (detached).
        train_views: the views selected so far, with their images.
        candidates: the remaining candidate cameras (their images are unknown to the planner).
        candidate_ids: their indices in the dataset's candidate (train) split.
        n_selected: the number of views selected so far.
        budget: the view budget B.
        background: [3] render background.
        physics: per-Gaussian divergence D_g [N] of given Gaussians (runs the probes; called at most once
            per selection), or None when the planner does not need it.
        round: the selection round (0-based), seeds the random planner.
        occlusion: S(T) counts only the Gaussians the coarse depth test (:class:`nbv.scores.DepthBuffer`) finds
            unhidden (not in the paper, whose visibility is frustum culling); the ``+area`` controls use it too.
        probe_fields: the probes' per-direction D_g (and the empty scene's) of given Gaussians, from the same run as
            ``physics`` (:class:`ProbeFields`), or None; needed by ``fisher+excess`` and ``fisher+perprobe``.
        sh_degree: the SH degree the trainer renders and fits now (its active degree, which rises during
            training), 0..the stored degree; None = all stored bands. FisherRF differentiates these bands only.
        solid_mask: [N] bool, the Gaussians of given Gaussians where their solid is thin or open
            (:func:`nbv.physics.thin.thin_or_open_gaussians`: the solid only, no probe), or None; needed by the
            ``+thin-area`` planners.
    """

    gaussians: GaussianSet
    train_views: list[View]
    candidates: list[Camera]
    candidate_ids: list[int]
    n_selected: int
    budget: int
    background: torch.Tensor
    physics: Callable[[GaussianSet], torch.Tensor] | None = None
    round: int = 0
    occlusion: bool = False
    probe_fields: Callable[[GaussianSet], ProbeFields] | None = None
    sh_degree: int | None = None
    solid_mask: Callable[[GaussianSet], torch.Tensor] | None = None

    def __post_init__(self) -> None:
        if len(self.candidates) != len(self.candidate_ids):
            raise ValueError(
                f"PlanningContext: {len(self.candidates)} candidates but {len(self.candidate_ids)} "
                "candidate_ids; pass one id per candidate camera"
            )
        if self.budget < 1 or self.n_selected < 0:
            raise ValueError(
                f"PlanningContext: budget must be >= 1 and n_selected >= 0, got budget={self.budget}, "
                f"n_selected={self.n_selected}"
            )
        if not isinstance(self.gaussians, GaussianSet):
            raise ValueError(f"PlanningContext.gaussians must be a GaussianSet, got {type(self.gaussians).__name__}")
        if self.sh_degree is not None and (
            isinstance(self.sh_degree, bool)
            or not isinstance(self.sh_degree, int)
            or not 0 <= self.sh_degree <= self.gaussians.sh_degree
        ):
            raise ValueError(
                f"PlanningContext.sh_degree must be None or 0..{self.gaussians.sh_degree} (the stored SH degree), "
                f"got {self.sh_degree!r}; pass the trainer's active SH degree"
            )


@dataclass
class Selection:
    """One planner decision.

    Attributes:
        pick: position in ``context.candidates`` of the chosen view.
        shortlist: positions considered, in the visual planner's order (its top-K for the fused planners,
            all positions otherwise).
        k: K of the fused planners, else None.
        scores: per candidate position, "visual" and "physics" (nan where not computed).
        seconds: time spent per part, "visual" and "physics".
    """

    pick: int
    shortlist: list[int]
    k: int | None
    scores: dict[str, list[float]]
    seconds: dict[str, float]


@runtime_checkable
class Planner(Protocol):
    """A next-best-view planner (see the module docstring for the registered ones)."""

    name: str

    def select(self, context: PlanningContext) -> Selection: ...


class ConfiguredPlanner:
    """The constructor the planners share: ``config`` is an instance of the class's ``config_type``, its defaults
    when None."""

    config_type: type

    def __init__(self, config=None) -> None:
        self.config = config if config is not None else self.config_type()


def fused_k(budget: int, n_selected: int) -> int:
    """K = max(B - n_selected, 2), the shortlist size of the fused planners."""
    return max(budget - n_selected, MIN_SHORTLIST)


def nan_scores(count: int) -> list[float]:
    """``count`` NaN scores: the scores of a planner that scores no view (random)."""
    return [math.nan] * count


def check_candidates(context: PlanningContext, name: str) -> None:
    """Raise ValueError naming planner ``name`` when ``context`` has no candidate view left."""
    if len(context.candidates) == 0:
        raise ValueError(f"planner {name!r}: no candidate views are left; stop before the candidate pool is empty")


def descending(scores: list[float]) -> list[int]:
    """Positions sorted by score, best first (ties keep the lower position first)."""
    return sorted(range(len(scores)), key=lambda i: (-scores[i], i))
