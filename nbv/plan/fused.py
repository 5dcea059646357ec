"""The fused planners: a visual shortlist re-ranked by the physics score S(T), its controls and candidates.

See :mod:`nbv.plan` for what each name does (paper Sec. 3.1 and 3.4, Appendix "view selection").
"""
from __future__ import annotations

import logging
import time

import torch

from nbv.plan.base import PlanningContext, ProbeFields, Selection, _check_candidates, _nan_scores, fused_k
from nbv.plan.fisher import FisherPlanner
from nbv.plan.fisher_info import FisherConfig
from nbv.plan.physics import _run_physics, physics_view_scores, shuffled_divergence
from nbv.plan.random import RandomConfig, RandomPlanner
from nbv.plan.variance import VariancePlanner
from nbv.plan.variance_model import VarianceConfig

log = logging.getLogger(__name__)


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
    """FisherRF + FluidGaussian (config: :class:`nbv.plan.fisher_info.FisherConfig`)."""

    name = "fisher+fluid"
    config_type = FisherConfig
    visual_type = FisherPlanner

    def __init__(self, config: FisherConfig | None = None) -> None:
        super().__init__(config if config is not None else FisherConfig())



class VarianceFluidPlanner(_FusedPlanner):
    """ActiveNeRF + FluidGaussian (config: :class:`nbv.plan.variance_model.VarianceConfig`)."""

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
