"""The fused planners: a visual shortlist re-ranked by the physics score S(T), its controls and candidates.

One class, :class:`FusedPlanner`, runs every rule of the table :data:`nbv.plan.rules.FUSED_RULES`; see :mod:`nbv.plan`
for what each rule does (paper Sec. 3.1 and 3.4, Appendix "view selection").
"""

from __future__ import annotations

import logging
import time

import torch

from nbv.plan.base import PlanningContext, ProbeFields, Selection, check_candidates, fused_k, nan_scores
from nbv.plan.fisher import FisherPlanner
from nbv.plan.fvs import FVSPlanner
from nbv.plan.physics import physics_view_scores, run_physics, shuffled_divergence
from nbv.plan.random import RandomPlanner
from nbv.plan.rules import FUSED, VALUES, FusedRule
from nbv.plan.variance import VariancePlanner

log = logging.getLogger(__name__)

# The visual planner of each fused rule's ``visual`` name.
VISUAL_TYPES = {"fisher": FisherPlanner, "variance": VariancePlanner, "random": RandomPlanner, "fvs": FVSPlanner}


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
        raise ValueError(
            "fisher+excess needs the empty-scene probes: set the selection physics' empty_reference "
            'to true (ActiveConfig.physics, or "physics": {"empty_reference": true} in an '
            'experiment\'s "active" overrides)'
        )
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


# ---- the per-Gaussian values (the table nbv.plan.rules.VALUES names) ----------------------------------------
def _mask(context: PlanningContext, who: str) -> torch.Tensor:
    if context.solid_mask is None:
        raise ValueError(
            f"planner {who!r} needs PlanningContext.solid_mask (nbv.physics.thin.thin_or_open_gaussians under the "
            "selection physics); the active loop passes it, other callers must too"
        )
    mask = torch.as_tensor(context.solid_mask(context.gaussians))
    if mask.shape != (context.gaussians.num,):
        raise ValueError(
            f"solid_mask returned shape {tuple(mask.shape)} for {context.gaussians.num} Gaussians; it must mark the "
            "Gaussians it is given"
        )
    return mask


def _fields(context: PlanningContext, who: str) -> ProbeFields:
    if context.probe_fields is None:
        raise ValueError(
            f"planner {who!r} needs PlanningContext.probe_fields (the per-probe D_g of the probe run); the active "
            "loop passes it, other callers must too"
        )
    fields = context.probe_fields(context.gaussians)
    if fields.per_probe.shape[1] != context.gaussians.num:
        raise ValueError(
            f"probe_fields returned {fields.per_probe.shape[1]} Gaussians' values for {context.gaussians.num} "
            "Gaussians; it must score the Gaussians it is given"
        )
    return fields


def _thin(context: PlanningContext, seed: int, who: str) -> torch.Tensor:
    divergence = run_physics(context, who)
    return torch.where(_mask(context, who), divergence, torch.zeros_like(divergence))


# name -> (context, planner seed, who asks) -> [N] float64 v_g on context.gaussians
PER_GAUSSIAN = {
    "fluid": lambda context, seed, who: run_physics(context, who),
    "area": lambda context, seed, who: torch.ones(context.gaussians.num, dtype=torch.float64),
    "shuffled": lambda context, seed, who: shuffled_divergence(run_physics(context, who), seed, context.round),
    "excess": lambda context, seed, who: excess_divergence(_fields(context, who)),
    "perprobe": lambda context, seed, who: per_probe_normalised(_fields(context, who).per_probe),
    "thin": _thin,
    "thin-area": lambda context, seed, who: _mask(context, who).to(torch.float64),
    "transparency": lambda context, seed, who: 1.0 - context.gaussians.opacities.detach().to(torch.float64),
}
if tuple(PER_GAUSSIAN) != tuple(VALUES):
    raise RuntimeError(f"nbv.plan.fused computes {tuple(PER_GAUSSIAN)}, nbv.plan.rules names {tuple(VALUES)}")


def per_gaussian_values(name: str, context: PlanningContext, seed: int, who: str = "") -> torch.Tensor:
    """The per-Gaussian values v_g ``name`` (:data:`nbv.plan.rules.VALUES`) of ``context.gaussians``.

    Args:
        name: a key of :data:`nbv.plan.rules.VALUES` ("fluid", "area", "thin-area", ...).
        context: the round; the values that read the probes call ``context.physics`` / ``probe_fields``, those that
            read the solid ``context.solid_mask``.
        seed: the planner seed ("shuffled" draws its permutation from (seed, ``context.round``)).
        who: the planner or rule asking, named by the errors.
    Returns:
        [N] float64 (1/s for the divergences; dimensionless for the masks, ones and 1 - opacity).
    Raises:
        ValueError: an unknown name, or a context without the callable the values read.
    """
    if name not in PER_GAUSSIAN:
        raise ValueError(f"unknown per-Gaussian values {name!r}; choose one of {', '.join(PER_GAUSSIAN)}")
    return PER_GAUSSIAN[name](context, seed, who or name)


def _rule_field(name: str, doc: str = "") -> property:
    """A read-only property of a fused planner that reads its rule's ``name`` (the rule owns it)."""
    return property(lambda planner: getattr(planner.rule, name), doc=doc or f"The rule's {name}.")


class FusedPlanner:
    """A visual planner's top-K, re-ranked by a physics rule (FluidGaussian and its controls and candidates).

    The rule (:class:`nbv.plan.rules.FusedRule`) says which per-Gaussian values re-rank the shortlist (a name of
    :data:`nbv.plan.rules.VALUES`, computed by :func:`per_gaussian_values`), whether the coarse depth test is forced
    on, and how the scores are combined ("sum": S(T); "balanced": :func:`balanced_scores`).

    Args:
        rule: a :class:`~nbv.plan.rules.FusedRule` or a registered fused name (``"fisher+fluid"``).
        config: the visual planner's config (default: its defaults).
    """

    def __init__(self, rule: FusedRule | str, config=None) -> None:
        self.rule = FUSED[rule] if isinstance(rule, str) else rule
        visual = VISUAL_TYPES[self.rule.visual]
        self.config = config if config is not None else visual.config_type()
        self.visual = visual(self.config)

    name = _rule_field("name")
    control = _rule_field("control")
    depth_test = _rule_field("depth_test")
    combine = _rule_field("combine")
    uses_physics = _rule_field("uses_physics", "Whether the pick runs the probes (False for the coverage controls).")

    def per_gaussian(self, context: PlanningContext) -> torch.Tensor:
        """[N] the values S(T) sums with the view weights (:func:`per_gaussian_values` of the rule's control)."""
        return per_gaussian_values(self.control, context, self.config.seed, self.name)

    def select(self, context: PlanningContext) -> Selection:
        check_candidates(context, self.name)
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
            coverage = physics_view_scores(
                context.gaussians, cams, torch.ones(context.gaussians.num, dtype=torch.float64), occlusion=occlusion
            )
            chosen = balanced_scores(coverage, chosen)
        physics = nan_scores(count)
        for i, s in zip(shortlist, chosen, strict=True):
            physics[i] = s
        best = max(range(len(shortlist)), key=lambda j: (chosen[j], -j))
        log.info(
            "%s: K=%d, visual top-K %s, S(T) %s -> position %d",
            self.name,
            k,
            shortlist,
            [f"{s:.4g}" for s in chosen],
            shortlist[best],
        )
        return Selection(
            pick=shortlist[best],
            shortlist=list(shortlist),
            k=k,
            scores={"visual": list(visual), "physics": physics},
            seconds={"visual": mid - start, "physics": time.perf_counter() - mid},
        )
