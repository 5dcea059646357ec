"""Next-best-view planners: one Protocol, one registry (paper Sec. 3.1 and 3.4, Appendix "view selection").

Every planner is built from a small frozen config dataclass with an explicit seed and answers
``select(context) -> Selection`` for one round of active reconstruction:

- ``random``: a uniformly random candidate, from a numpy Generator seeded with (seed, round), so runs are
  reproducible and resumable.
- ``fisher``: FisherRF (:mod:`nbv.fisher`), the candidate with the largest sum H_c / (H_train + lambda).
- ``variance``: ActiveNeRF on 3D Gaussians (:mod:`nbv.variance`), the largest variance reduction.
- ``physics``: the largest physics score S(T) = sum_g w_g(T) D_g (paper Eq. 4-5, :func:`nbv.scores.view_scores`)
  over all candidates.
- ``fisher+fluid`` and ``variance+fluid`` (FluidGaussian, Sec. 3.1 "Step 1/Step 2" and the appendix):
  the visual planner proposes its top-K candidates, K = max(B - n_selected, 2) (the remaining budget,
  at least 2), FisherRF's list chosen greedily; the physics probes run once on the current Gaussians
  and the candidate of the list with the largest S(T) is chosen (ties: the visual planner's order).
- ``random+fluid`` (the paper's random-selection ablation): the same re-ranking of K candidates drawn at random,
  which separates what the physics pick adds from what the visual shortlist adds.
- Controls of the physics pick, on each visual planner (``fisher``, ``variance``, ``random``), with the same
  shortlist and K schedule as ``<visual>+fluid``:

  - ``<visual>+area``: S(T) with D_g = 1, i.e. the coverage sum_{g visible} w_g(T); no probe runs.
  - ``<visual>+shuffled``: S(T) with the probes' D_g permuted across the Gaussians (a numpy Generator seeded
    with (seed, round)), which keeps the values and destroys where they are.

  A physics pick that beats neither control adds nothing a coverage term or the magnitudes alone would not.

- Candidates that try to give the physics information beyond coverage (issue 19 item 4), all on FisherRF's
  shortlist with the same K schedule:

  - ``fisher+fluid-occ`` / ``fisher+area-occ``: S(T) / the coverage with the coarse depth test
    (:class:`nbv.scores.DepthBuffer`) whatever ``PlanningContext.occlusion`` says, so that hidden Gaussians do
    not count; ``fisher+area-occ`` is the coverage control of ``fisher+fluid-occ``.
  - ``fisher+excess``: S(T) of the excess divergence max_p max(D_g^(p) - E_g^(p), 0), E the empty-scene D_g of
    the same probe at the same place (:func:`excess_divergence`; needs the empty-scene probes).
  - ``fisher+perprobe``: S(T) of max_p D_g^(p) / mean_{g reached} D^(p), every probe normalised to its own scale
    before the max (:func:`per_probe_normalised`), so that the strongest probe does not decide alone.
  - ``fisher+balanced``: z(A(T)) + z(S(T) / A(T)) over the shortlist (:func:`balanced_scores`), the coverage
    and the area-weighted mean D_g of the view with equal weight; S/A is the part of S that coverage does not
    explain. ``fisher+balanced-occ``: the same with the depth test.

S(T) needs only the screen-space radii and visibility of the Gaussians in each candidate, which are the
projection's (``recon.render.render`` returns exactly ``project_gaussians(...).radii``), so no candidate
is rasterised for it: :func:`physics_view_scores` takes them from the batched projection
(:func:`nbv.scores.projected_view_scores`).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Protocol, runtime_checkable

import numpy as np
import torch

from recon.camera import Camera
from recon.datasets import View
from recon.gaussians import GaussianSet

from .fisher import FisherConfig, greedy_top_k
from .scores import DepthBuffer, projected_view_scores
from .variance import VarianceConfig, fit_variances, variance_scores

log = logging.getLogger(__name__)

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
            raise ValueError(f"ProbeFields.per_probe must be [P, N] with P = {len(self.directions)} directions, "
                             f"got shape {tuple(d.shape)}")
        if not torch.isfinite(d).all():
            raise ValueError("ProbeFields.per_probe holds NaN or Inf; check the probe run")
        object.__setattr__(self, "per_probe", d)
        if self.empty_per_probe is not None:
            e = torch.as_tensor(self.empty_per_probe, dtype=torch.float64)
            if e.shape != d.shape or not torch.isfinite(e).all():
                raise ValueError(f"ProbeFields.empty_per_probe must be finite and shaped like per_probe "
                                 f"{tuple(d.shape)}, got {tuple(e.shape)}")
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

    def __post_init__(self) -> None:
        if len(self.candidates) != len(self.candidate_ids):
            raise ValueError(f"PlanningContext: {len(self.candidates)} candidates but {len(self.candidate_ids)} "
                             "candidate_ids; pass one id per candidate camera")
        if self.budget < 1 or self.n_selected < 0:
            raise ValueError(f"PlanningContext: budget must be >= 1 and n_selected >= 0, got budget={self.budget}, "
                             f"n_selected={self.n_selected}")
        if not isinstance(self.gaussians, GaussianSet):
            raise ValueError(f"PlanningContext.gaussians must be a GaussianSet, got {type(self.gaussians).__name__}")


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


@dataclass(frozen=True)
class RandomConfig:
    """The random planner.

    Attributes:
        seed: seeds a numpy Generator together with the round number.
    """

    seed: int = 0

    def __post_init__(self) -> None:
        if not isinstance(self.seed, int) or isinstance(self.seed, bool) or self.seed < 0:
            raise ValueError(f"RandomConfig.seed must be an int >= 0, got {self.seed!r}")


@dataclass(frozen=True)
class PhysicsPlannerConfig:
    """The physics-only planner.

    Attributes:
        seed: recorded for the registry contract; the planner draws no random numbers.
        weighted: use the Eq. 5 view weights w_g(T) (False: the plain sum of D_g over the visible Gaussians).
    """

    seed: int = 0
    weighted: bool = True

    def __post_init__(self) -> None:
        if not isinstance(self.seed, int) or isinstance(self.seed, bool):
            raise ValueError(f"PhysicsPlannerConfig.seed must be an int, got {self.seed!r}")
        if not isinstance(self.weighted, bool):
            raise ValueError(f"PhysicsPlannerConfig.weighted must be a bool, got {self.weighted!r}")


def fused_k(budget: int, n_selected: int) -> int:
    """K = max(B - n_selected, 2), the shortlist size of the fused planners."""
    return max(budget - n_selected, MIN_SHORTLIST)


def _nan_scores(count: int) -> list[float]:
    return [math.nan] * count


def _check_candidates(context: PlanningContext, name: str) -> None:
    if len(context.candidates) == 0:
        raise ValueError(f"planner {name!r}: no candidate views are left; stop before the candidate pool is empty")


def _descending(scores: list[float]) -> list[int]:
    """Positions sorted by score, best first (ties keep the lower position first)."""
    return sorted(range(len(scores)), key=lambda i: (-scores[i], i))


def physics_view_scores(gaussians: GaussianSet, cameras: list[Camera], divergence: torch.Tensor,
                        weighted: bool = True, occlusion: bool = False) -> list[float]:
    """S(T) = sum_g w_g(T) D_g (paper Eq. 4-5) of every camera, from the batched projection (no render).

    Args:
        gaussians: N Gaussians (the set ``divergence`` was computed on).
        cameras: C cameras.
        divergence: [N] D_g, 1/s.
        weighted: Eq. 5 weights (False: plain sum over the visible Gaussians).
        occlusion: count only the Gaussians the coarse depth test finds unhidden (:class:`nbv.scores.DepthBuffer`).
    Returns:
        C floats.
    """
    d = torch.as_tensor(divergence).detach().reshape(-1)
    if d.numel() != gaussians.num:
        raise ValueError(f"physics returned {d.numel()} per-Gaussian values for {gaussians.num} Gaussians; "
                         "the physics callable must score the Gaussians it is given")
    if not torch.isfinite(d).all():
        raise ValueError("physics returned NaN or Inf per-Gaussian divergences; check the probe run")
    if not cameras:
        return []
    buffer = DepthBuffer() if occlusion else None
    return projected_view_scores(d, gaussians.detach(), list(cameras), weighted=weighted,
                                 depth_buffer=buffer).scores.tolist()


def shuffled_divergence(divergence: torch.Tensor, seed: int, round_index: int = 0) -> torch.Tensor:
    """D_g permuted across the Gaussians: the same values in random places (the ``+shuffled`` control).

    Args:
        divergence: [N] D_g, 1/s.
        seed: planner seed (any int; negative ones are taken modulo 2^64).
        round_index: selection round, mixed into the seed so every round draws its own permutation.
    Returns:
        [N] ``divergence[perm]`` with perm a permutation from a numpy Generator seeded with (seed, round_index):
        the same multiset of values, deterministic per (seed, round_index).
    """
    d = torch.as_tensor(divergence).detach().reshape(-1)
    rng = np.random.default_rng([int(seed) % 2**64, int(round_index) % 2**64])
    return d[torch.from_numpy(rng.permutation(d.numel())).to(d.device)]


def excess_divergence(fields: ProbeFields) -> torch.Tensor:
    """The excess divergence max_p max(D_g^(p) - E_g^(p), 0) (the ``fisher+excess`` values).

    E_g^(p) is what probe p gives at Gaussian g without the solid: the divergence the inflow front and the domain
    walls make anyway. D - E keeps what the object adds; where the empty scene is the larger, nothing is added.

    Args:
        fields: a probe run with the empty scene (``empty_per_probe`` set).
    Returns:
        [N] float64, 1/s, >= 0.
    Raises:
        ValueError: the empty scene was not run.
    """
    if fields.empty_per_probe is None:
        raise ValueError("fisher+excess needs the empty-scene probes: set the selection physics' empty_reference "
                         "to true (ActiveConfig.physics, or \"physics\": {\"empty_reference\": true} in an "
                         "experiment's \"active\" overrides)")
    return (fields.per_probe - fields.empty_per_probe).clamp_min(0.0).amax(dim=0)


def per_probe_normalised(per_probe: torch.Tensor) -> torch.Tensor:
    """max_p D_g^(p) / s_p with s_p the mean of D^(p) over the Gaussians probe p reached (D > 0).

    The plain D_g = max_p D_g^(p) is decided by the strongest probe: the falling -y probe's D-bar is about a tenth
    of the horizontal ones' (docs/results.md), so it almost never sets the max. Dividing each probe by its own
    scale first gives every direction the same say. A probe that reached no Gaussian contributes zeros.

    Args:
        per_probe: [P, N] D_g^(p), 1/s, >= 0.
    Returns:
        [N] float64, dimensionless (1 = a probe's mean over the Gaussians it reached).
    """
    d = torch.as_tensor(per_probe, dtype=torch.float64)
    if d.ndim != 2:
        raise ValueError(f"per_probe_normalised: per_probe must be [P, N], got shape {tuple(d.shape)}")
    reached = d > 0
    count = reached.sum(dim=1)
    scale = torch.where(reached, d, torch.zeros_like(d)).sum(dim=1) / count.clamp_min(1)
    scale = torch.where(count > 0, scale, torch.ones_like(scale))
    return (d / scale[:, None]).amax(dim=0)


def _standardised(x: torch.Tensor) -> torch.Tensor:
    """(x - mean) / std over the entries (population std); zeros when the entries are all equal."""
    std = x.std(unbiased=False) if x.numel() > 1 else torch.zeros((), dtype=x.dtype)
    scale = float(x.abs().max()) if x.numel() else 0.0
    if not float(std) > 1e-12 * max(scale, 1e-300):
        return torch.zeros_like(x)
    return (x - x.mean()) / std


def balanced_scores(coverage: list[float], physics: list[float]) -> list[float]:
    """z(A) + z(S / A) over a shortlist: coverage and the area-weighted mean D_g of each view, equally weighted.

    S(T) = A(T) (S/A)(T), so ranking by S lets whichever factor varies more between the views decide; under
    frustum visibility that is coverage (S/A varies by about 1 % between views, docs/results.md). Standardising
    both factors over the shortlist gives the physics part the same weight as coverage.

    Args:
        coverage: [K] A(T) = sum_{g visible} w_g.
        physics: [K] S(T) = sum_{g visible} w_g D_g of the same views.
    Returns:
        [K] floats; a view with A = 0 has S/A = 0. A factor equal on every view adds zeros.
    """
    if len(coverage) != len(physics):
        raise ValueError(f"balanced_scores: {len(coverage)} coverages but {len(physics)} physics scores")
    a = torch.tensor(coverage, dtype=torch.float64)
    s = torch.tensor(physics, dtype=torch.float64)
    mean_d = torch.where(a > 0, s / a.clamp_min(1e-300), torch.zeros_like(s))
    return (_standardised(a) + _standardised(mean_d)).tolist()


def _run_physics(context: PlanningContext, name: str) -> torch.Tensor:
    if context.physics is None:
        raise ValueError(f"planner {name!r} needs PlanningContext.physics (the probe runner giving D_g); "
                         "pass one, or use a visual-only planner")
    return context.physics(context.gaussians)


class RandomPlanner:
    """A uniformly random candidate (reproducible from (seed, round))."""

    name = "random"
    config_type = RandomConfig

    def __init__(self, config: RandomConfig = RandomConfig()) -> None:
        self.config = config

    def rank(self, context: PlanningContext, k: int) -> tuple[list[int], list[float]]:
        """k distinct positions drawn uniformly at random (from (seed, round)) and NaN scores."""
        rng = np.random.default_rng([self.config.seed, context.round, k])
        count = len(context.candidates)
        return [int(i) for i in rng.permutation(count)[:k]], _nan_scores(count)

    def select(self, context: PlanningContext) -> Selection:
        _check_candidates(context, self.name)
        start = time.perf_counter()
        rng = np.random.default_rng([self.config.seed, context.round])
        pick = int(rng.integers(len(context.candidates)))
        count = len(context.candidates)
        return Selection(pick=pick, shortlist=list(range(count)), k=None,
                         scores={"visual": _nan_scores(count), "physics": _nan_scores(count)},
                         seconds={"visual": time.perf_counter() - start, "physics": 0.0})


class FisherPlanner:
    """FisherRF: the candidate with the largest expected information gain (:mod:`nbv.fisher`)."""

    name = "fisher"
    config_type = FisherConfig

    def __init__(self, config: FisherConfig | None = None) -> None:
        self.config = config if config is not None else FisherConfig()

    def rank(self, context: PlanningContext, k: int) -> tuple[list[int], list[float]]:
        """The greedy top-k positions and every candidate's score against the selected views."""
        g = context.gaussians.detach()
        ranking = greedy_top_k(g, context.candidates, [v.camera for v in context.train_views],
                               context.background.to(g.device), k, self.config)
        if ranking.recomputed:
            log.info("fisher: %d candidate H recomputed (cache_mb=%g)", ranking.recomputed, self.config.cache_mb)
        return ranking.order, ranking.scores

    def select(self, context: PlanningContext) -> Selection:
        _check_candidates(context, self.name)
        start = time.perf_counter()
        order, scores = self.rank(context, 1)
        shortlist = order + [i for i in _descending(scores) if i not in order]
        return Selection(pick=order[0], shortlist=shortlist, k=None,
                         scores={"visual": scores, "physics": _nan_scores(len(scores))},
                         seconds={"visual": time.perf_counter() - start, "physics": 0.0})


class VariancePlanner:
    """ActiveNeRF on 3D Gaussians: the largest variance reduction (:mod:`nbv.variance`).

    Keeps the fitted log-variances between rounds and warm-starts the next fit from them when the number
    of Gaussians is unchanged (a resumed run starts afresh).
    """

    name = "variance"
    config_type = VarianceConfig

    def __init__(self, config: VarianceConfig | None = None) -> None:
        self.config = config if config is not None else VarianceConfig()
        self.log_variances: torch.Tensor | None = None

    def rank(self, context: PlanningContext, k: int) -> tuple[list[int], list[float]]:
        """The top-k positions by variance reduction and every candidate's score."""
        g = context.gaussians.detach()
        warm = self.log_variances if self.log_variances is not None and self.log_variances.numel() == g.num \
            else None
        fit = fit_variances(g, context.train_views, context.background.to(g.device), self.config, warm)
        self.log_variances = fit.log_variances
        scores = variance_scores(g, context.candidates, fit.variances, self.config.prior_floor)
        return _descending(scores)[:k], scores

    def select(self, context: PlanningContext) -> Selection:
        _check_candidates(context, self.name)
        start = time.perf_counter()
        _, scores = self.rank(context, len(context.candidates))
        return Selection(pick=_descending(scores)[0], shortlist=_descending(scores), k=None,
                         scores={"visual": scores, "physics": _nan_scores(len(scores))},
                         seconds={"visual": time.perf_counter() - start, "physics": 0.0})


class PhysicsPlanner:
    """The candidate with the largest physics score S(T) over all candidates."""

    name = "physics"
    config_type = PhysicsPlannerConfig

    def __init__(self, config: PhysicsPlannerConfig = PhysicsPlannerConfig()) -> None:
        self.config = config

    def select(self, context: PlanningContext) -> Selection:
        _check_candidates(context, self.name)
        start = time.perf_counter()
        divergence = _run_physics(context, self.name)
        scores = physics_view_scores(context.gaussians, context.candidates, divergence, self.config.weighted,
                                     context.occlusion)
        order = _descending(scores)
        return Selection(pick=order[0], shortlist=order, k=None,
                         scores={"visual": _nan_scores(len(scores)), "physics": scores},
                         seconds={"visual": 0.0, "physics": time.perf_counter() - start})


class _FusedPlanner:
    """FluidGaussian: the visual planner's top-K, re-ranked by S(T) (module docstring).

    ``control`` says which per-Gaussian values re-rank the shortlist: "fluid" the probes' D_g, "area" ones (the
    coverage control; the probes never run), "shuffled" the probes' D_g permuted (:func:`shuffled_divergence`),
    "excess" :func:`excess_divergence`, "perprobe" :func:`per_probe_normalised`. ``depth_test`` forces the coarse
    depth test on (else ``PlanningContext.occlusion`` decides); ``combine`` is "sum" (S(T) of those values) or
    "balanced" (:func:`balanced_scores` of the coverage and S(T)).
    """

    name = ""
    visual_type: type = FisherPlanner
    control = "fluid"
    depth_test = False
    combine = "sum"

    def __init__(self, config) -> None:
        self.config = config
        self.visual = self.visual_type(config)

    @property
    def uses_physics(self) -> bool:
        """Whether the pick runs the probes (False for the coverage control)."""
        return self.control != "area"

    def per_gaussian(self, context: PlanningContext) -> torch.Tensor:
        """[N] the values S(T) sums with the view weights: D_g (1/s), ones, or D_g permuted."""
        if self.control == "area":
            return torch.ones(context.gaussians.num, dtype=torch.float64)
        divergence = _run_physics(context, self.name)
        if self.control == "shuffled":
            return shuffled_divergence(divergence, self.config.seed, context.round)
        if self.control in ("excess", "perprobe"):
            if context.probe_fields is None:
                raise ValueError(f"planner {self.name!r} needs PlanningContext.probe_fields (the per-probe D_g of "
                                 "the probe run); the active loop passes it, other callers must too")
            fields = context.probe_fields(context.gaussians)
            if fields.per_probe.shape[1] != context.gaussians.num:
                raise ValueError(f"probe_fields returned {fields.per_probe.shape[1]} Gaussians' values for "
                                 f"{context.gaussians.num} Gaussians; it must score the Gaussians it is given")
            return excess_divergence(fields) if self.control == "excess" else per_probe_normalised(fields.per_probe)
        return divergence

    def select(self, context: PlanningContext) -> Selection:
        _check_candidates(context, self.name)
        count = len(context.candidates)
        k = fused_k(context.budget, context.n_selected)
        start = time.perf_counter()
        shortlist, visual = self.visual.rank(context, min(k, count))
        mid = time.perf_counter()
        divergence = self.per_gaussian(context)
        occlusion = context.occlusion or self.depth_test
        cams = [context.candidates[i] for i in shortlist]
        chosen = physics_view_scores(context.gaussians, cams, divergence, occlusion=occlusion)
        if self.combine == "balanced":
            coverage = physics_view_scores(context.gaussians, cams, torch.ones(context.gaussians.num,
                                                                               dtype=torch.float64),
                                           occlusion=occlusion)
            chosen = balanced_scores(coverage, chosen)
        physics = _nan_scores(count)
        for i, s in zip(shortlist, chosen, strict=True):
            physics[i] = s
        best = max(range(len(shortlist)), key=lambda j: (chosen[j], -j))
        log.info("%s: K=%d, visual top-K %s, S(T) %s -> position %d", self.name, k, shortlist,
                 [f"{s:.4g}" for s in chosen], shortlist[best])
        return Selection(pick=shortlist[best], shortlist=list(shortlist), k=k,
                         scores={"visual": list(visual), "physics": physics},
                         seconds={"visual": mid - start, "physics": time.perf_counter() - mid})


class FisherFluidPlanner(_FusedPlanner):
    """FisherRF + FluidGaussian (config: :class:`nbv.fisher.FisherConfig`)."""

    name = "fisher+fluid"
    config_type = FisherConfig
    visual_type = FisherPlanner

    def __init__(self, config: FisherConfig | None = None) -> None:
        super().__init__(config if config is not None else FisherConfig())


class VarianceFluidPlanner(_FusedPlanner):
    """ActiveNeRF + FluidGaussian (config: :class:`nbv.variance.VarianceConfig`)."""

    name = "variance+fluid"
    config_type = VarianceConfig
    visual_type = VariancePlanner

    def __init__(self, config: VarianceConfig | None = None) -> None:
        super().__init__(config if config is not None else VarianceConfig())


class RandomFluidPlanner(_FusedPlanner):
    """The random-selection ablation: K random candidates, re-ranked by S(T) (config: :class:`RandomConfig`)."""

    name = "random+fluid"
    config_type = RandomConfig
    visual_type = RandomPlanner

    def __init__(self, config: RandomConfig | None = None) -> None:
        super().__init__(config if config is not None else RandomConfig())


class FisherAreaPlanner(FisherFluidPlanner):
    """Control: FisherRF's top-K re-ranked by the coverage sum_g w_g (S(T) with D_g = 1; no probes)."""

    name = "fisher+area"
    control = "area"


class FisherShuffledPlanner(FisherFluidPlanner):
    """Control: FisherRF's top-K re-ranked by S(T) with the probes' D_g permuted across the Gaussians."""

    name = "fisher+shuffled"
    control = "shuffled"


class VarianceAreaPlanner(VarianceFluidPlanner):
    """Control: the variance planner's top-K re-ranked by the coverage sum_g w_g (no probes)."""

    name = "variance+area"
    control = "area"


class VarianceShuffledPlanner(VarianceFluidPlanner):
    """Control: the variance planner's top-K re-ranked by S(T) with D_g permuted across the Gaussians."""

    name = "variance+shuffled"
    control = "shuffled"


class RandomAreaPlanner(RandomFluidPlanner):
    """Control: K random candidates re-ranked by the coverage sum_g w_g (no probes)."""

    name = "random+area"
    control = "area"


class RandomShuffledPlanner(RandomFluidPlanner):
    """Control: K random candidates re-ranked by S(T) with D_g permuted across the Gaussians."""

    name = "random+shuffled"
    control = "shuffled"


class FisherFluidOccPlanner(FisherFluidPlanner):
    """Candidate: FisherRF's top-K re-ranked by S(T) with the coarse depth test (hidden Gaussians do not count)."""

    name = "fisher+fluid-occ"
    depth_test = True


class FisherAreaOccPlanner(FisherFluidPlanner):
    """Control of ``fisher+fluid-occ``: the coverage of the unhidden Gaussians (depth test; no probes)."""

    name = "fisher+area-occ"
    control = "area"
    depth_test = True


class FisherExcessPlanner(FisherFluidPlanner):
    """Candidate: S(T) of the excess divergence over the empty scene (:func:`excess_divergence`)."""

    name = "fisher+excess"
    control = "excess"


class FisherPerProbePlanner(FisherFluidPlanner):
    """Candidate: S(T) of the per-probe normalised D_g (:func:`per_probe_normalised`)."""

    name = "fisher+perprobe"
    control = "perprobe"


class FisherBalancedPlanner(FisherFluidPlanner):
    """Candidate: z(coverage) + z(S / coverage) over FisherRF's top-K (:func:`balanced_scores`)."""

    name = "fisher+balanced"
    combine = "balanced"


class FisherBalancedOccPlanner(FisherFluidPlanner):
    """Candidate: ``fisher+balanced`` with the coarse depth test (the coverage and S(T) of unhidden Gaussians)."""

    name = "fisher+balanced-occ"
    combine = "balanced"
    depth_test = True


PLANNERS: dict[str, type] = {
    "random": RandomPlanner,
    "random+fluid": RandomFluidPlanner,
    "fisher": FisherPlanner,
    "variance": VariancePlanner,
    "physics": PhysicsPlanner,
    "fisher+fluid": FisherFluidPlanner,
    "variance+fluid": VarianceFluidPlanner,
    "fisher+area": FisherAreaPlanner,
    "fisher+shuffled": FisherShuffledPlanner,
    "variance+area": VarianceAreaPlanner,
    "variance+shuffled": VarianceShuffledPlanner,
    "random+area": RandomAreaPlanner,
    "random+shuffled": RandomShuffledPlanner,
    "fisher+fluid-occ": FisherFluidOccPlanner,
    "fisher+area-occ": FisherAreaOccPlanner,
    "fisher+excess": FisherExcessPlanner,
    "fisher+perprobe": FisherPerProbePlanner,
    "fisher+balanced": FisherBalancedPlanner,
    "fisher+balanced-occ": FisherBalancedOccPlanner,
}


def uses_physics(name: str) -> bool:
    """Whether the registered planner ``name`` runs the probes for its pick (physics, +fluid, +shuffled)."""
    if name not in PLANNERS:
        raise ValueError(f"unknown planner {name!r}; choose one of {sorted(PLANNERS)}")
    cls = PLANNERS[name]
    return cls is PhysicsPlanner or (issubclass(cls, _FusedPlanner) and cls.control != "area")


def make_planner(name: str, **overrides) -> Planner:
    """Build a registered planner from its config dataclass with ``overrides`` (e.g. ``seed=3``).

    Args:
        name: a key of :data:`PLANNERS`.
        overrides: fields of the planner's config (``RandomConfig``, ``FisherConfig``, ``VarianceConfig``,
            ``PhysicsPlannerConfig``; the fused planners take their visual planner's config).
    Returns:
        the planner.

    Example:
        >>> make_planner("fisher+fluid", seed=1).name
        'fisher+fluid'
    """
    if name not in PLANNERS:
        raise ValueError(f"unknown planner {name!r}; choose one of {sorted(PLANNERS)}")
    cls = PLANNERS[name]
    known = {f.name for f in fields(cls.config_type)}
    unknown = sorted(set(overrides) - known)
    if unknown:
        raise ValueError(f"planner {name!r}: unknown config fields {unknown}; "
                         f"{cls.config_type.__name__} has {sorted(known)}")
    return cls(cls.config_type(**overrides))
