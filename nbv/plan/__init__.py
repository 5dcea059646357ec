"""Next-best-view planners: one Protocol, one registry (paper Sec. 3.1 and 3.4, Appendix "view selection").

The fused planners are data: one :class:`~nbv.plan.rules.FusedRule` per name in :data:`nbv.plan.rules.FUSED_RULES`,
run by one class, :class:`~nbv.plan.fused.FusedPlanner`. Importing the package loads nothing (PEP 562), so the
command-line help reads the names without torch.

Every planner is built from a small frozen config dataclass with an explicit seed and answers
``select(context) -> Selection`` for one round of active reconstruction:

- ``random``: a uniformly random candidate, from a numpy Generator seeded with (seed, round), so runs are
  reproducible and resumable.
- ``fisher``: FisherRF (:mod:`nbv.plan.fisher_info`), the candidate with the largest sum H_c / (H_train + lambda).
- ``variance``: ActiveNeRF on 3D Gaussians (:mod:`nbv.plan.variance_model`), the largest variance reduction.
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

- Candidates that try to give the physics information beyond coverage (docs/results.md), all on FisherRF's
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
  - ``fisher+thin-area-occ``: the depth-tested coverage of the Gaussians where the solid is thin or open
    (``PlanningContext.solid_mask``, :func:`nbv.physics.thin.thin_or_open_gaussians`): the solid only, no fluid,
    no probe. ``fisher+thin-area``: the same with frustum visibility. In the oracle study (docs/results.md) this
    coverage predicted the gain better than coverage on the six shapes at seed 0, but not at seeds 1-4 nor on two
    held-out shapes made of thin parts: a candidate, not a finding.

S(T) needs only the screen-space radii and visibility of the Gaussians in each candidate, which are the
projection's (``recon.render.render`` returns exactly ``project_gaussians(...).radii``), so no candidate
is rasterised for it: :func:`physics_view_scores` takes them from the batched projection
(:func:`nbv.scores.projected_view_scores`).
"""

from fluidsim.lazy import lazy_exports

_EXPORTS = {
    **dict.fromkeys(("MIN_SHORTLIST", "Planner", "PlanningContext", "ProbeFields", "Selection", "fused_k"), "base"),
    "FisherPlanner": "fisher",
    "VariancePlanner": "variance",
    "RandomConfig": "random",
    "RandomPlanner": "random",
    **dict.fromkeys(("FusedPlanner", "balanced_scores", "excess_divergence", "per_probe_normalised"), "fused"),
    **dict.fromkeys(
        ("PhysicsPlanner", "PhysicsPlannerConfig", "physics_view_scores", "shuffled_divergence"), "physics"
    ),
    **dict.fromkeys(("PLANNERS", "config_type", "make_planner", "reads_empty_scene", "uses_physics"), "registry"),
    **dict.fromkeys(("FUSED", "FUSED_RULES", "FusedRule", "PLANNER_NAMES", "describe_planners"), "rules"),
}
__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals())
