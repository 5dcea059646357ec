"""The planners' names, and the fused planners declared as data (paper Sec. 3.1 and 3.4, Appendix "view selection").

A fused planner is a visual planner's top-K shortlist re-ranked by a physics rule: one :class:`FusedRule` each, in one
table (:data:`FUSED_RULES`), as gsplat declares its densification strategies and nerfstudio its method configs.
Each name is written once, here; the registry (:mod:`nbv.plan.registry`), the command-line help
(:func:`describe_planners`) and the tests read the table. This module needs no torch, so ``--help`` stays fast.

Example:
    >>> FUSED["fisher+area"].control
    'area'
"""

from __future__ import annotations

from dataclasses import dataclass

from fluidsim.config import check_choices

# The planners that score views on their own (nbv.plan.random, fisher, variance, physics, fvs).
BASE_PLANNERS = ("random", "fisher", "variance", "physics", "fvs")
# The planners that propose a fused planner's shortlist.
VISUAL_PLANNERS = ("fisher", "variance", "random", "fvs")
# How the shortlist's scores are formed: S(T) of those values, or z(coverage) + z(S / coverage).
COMBINES = ("sum", "balanced")


@dataclass(frozen=True)
class Values:
    """One kind of per-Gaussian values v_g that S(T) = sum_g w_g(T) v_g sums (computed by
    :data:`nbv.plan.fused.PER_GAUSSIAN`).

    Attributes:
        name: its name in the fused rules (``control``) and the oracle's rules (``values``).
        probes: it reads the probe run (``PlanningContext.physics`` or ``probe_fields``).
        solid: it reads the thin-or-open mask of the solid (``PlanningContext.solid_mask``; no fluid).
        summary: what v_g is.
    """

    name: str
    probes: bool = False
    solid: bool = False
    summary: str = ""


# The one table of per-Gaussian values, read by the fused planners and the oracle study.
VALUES = {
    v.name: v
    for v in (
        Values("fluid", probes=True, summary="the probes' D_g (1/s)"),
        Values("area", summary="ones: S(T) is the coverage A(T), no probe"),
        Values("shuffled", probes=True, summary="D_g permuted across the Gaussians"),
        Values("excess", probes=True, summary="D_g minus the empty-scene D_g, per probe, before the max"),
        Values("perprobe", probes=True, summary="each probe normalised to its own scale before the max"),
        Values("thin", probes=True, solid=True, summary="D_g where the solid is thin or open, 0 elsewhere"),
        Values("thin-area", solid=True, summary="1 where the solid is thin or open, 0 elsewhere (no probe)"),
        Values("transparency", summary="1 - opacity: a coverage of the Gaussians the model is unsure of"),
    )
}
# Which per-Gaussian values may re-rank a fused planner's shortlist.
CONTROLS = tuple(VALUES)


@dataclass(frozen=True)
class FusedRule:
    """One fused planner.

    Attributes:
        name: the planner's registered name, ``<visual>+<rule>``.
        visual: the visual planner of the shortlist (:data:`VISUAL_PLANNERS`); the fused planner takes its config.
        control: the per-Gaussian values S(T) sums, a name of :data:`VALUES` ("fluid" the probes' D_g, "area" the
            coverage control, "thin-area" the coverage of the thin-or-open Gaussians, ...).
        depth_test: always apply the coarse depth test (else ``PlanningContext.occlusion`` decides).
        combine: "sum" (S(T)) or "balanced" (z(coverage) + z(S / coverage)).
        summary: one line for the command-line help.
    """

    name: str
    visual: str
    control: str = "fluid"
    depth_test: bool = False
    combine: str = "sum"
    summary: str = ""

    def __post_init__(self) -> None:
        check_choices(
            self, {"visual": VISUAL_PLANNERS, "control": CONTROLS, "combine": COMBINES}, f"FusedRule {self.name!r}: "
        )

    @property
    def uses_physics(self) -> bool:
        """Whether the pick runs the probes (False for the coverage controls and the thin-or-open coverage)."""
        return VALUES[self.control].probes

    @property
    def reads_empty_scene(self) -> bool:
        """Whether the pick reads the empty-scene probes' D_g (the "excess" control)."""
        return self.control == "excess"


FUSED_RULES = (
    FusedRule("fisher+fluid", "fisher", summary="FluidGaussian: FisherRF's top-K re-ranked by S(T)"),
    FusedRule("variance+fluid", "variance", summary="the same on the variance planner"),
    FusedRule("random+fluid", "random", summary="K random candidates re-ranked by S(T), the paper's ablation"),
    FusedRule("fvs+fluid", "fvs", summary="the K candidates farthest from the views taken, re-ranked by S(T)"),
    FusedRule("fisher+area", "fisher", "area", summary="control: the coverage, no probes"),
    FusedRule("fisher+shuffled", "fisher", "shuffled", summary="control: D_g permuted"),
    FusedRule("variance+area", "variance", "area", summary="control: the coverage, no probes"),
    FusedRule("variance+shuffled", "variance", "shuffled", summary="control: D_g permuted"),
    FusedRule("random+area", "random", "area", summary="control: the coverage, no probes"),
    FusedRule("random+shuffled", "random", "shuffled", summary="control: D_g permuted"),
    FusedRule("fisher+fluid-occ", "fisher", depth_test=True, summary="candidate: depth-tested S(T)"),
    FusedRule("fisher+area-occ", "fisher", "area", depth_test=True, summary="its coverage control"),
    FusedRule("fisher+excess", "fisher", "excess", summary="candidate: D_g minus the empty-scene D_g"),
    FusedRule("fisher+perprobe", "fisher", "perprobe", summary="candidate: each probe normalised"),
    FusedRule("fisher+balanced", "fisher", combine="balanced", summary="candidate: z(coverage) + z(S / coverage)"),
    FusedRule("fisher+balanced-occ", "fisher", depth_test=True, combine="balanced", summary="the same, depth-tested"),
    FusedRule(
        "fisher+thin-area-occ",
        "fisher",
        "thin-area",
        depth_test=True,
        summary="candidate: depth-tested coverage of the Gaussians where the solid is thin or open (no probe)",
    ),
    FusedRule("fisher+thin-area", "fisher", "thin-area", summary="the same, frustum"),
)
FUSED = {r.name: r for r in FUSED_RULES}
# Every registered planner name.
PLANNER_NAMES = BASE_PLANNERS + tuple(FUSED)


def describe_planners() -> str:
    """The names of every planner for the command-line help, the fused ones with their summaries."""
    fused = "; ".join(f"{r.name} ({r.summary})" for r in FUSED_RULES)
    return f"{', '.join(BASE_PLANNERS)}, or a fused planner: {fused}"
