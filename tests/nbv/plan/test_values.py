"""The one table of per-Gaussian values (:data:`nbv.plan.rules.VALUES`, computed by
:func:`nbv.plan.fused.per_gaussian_values`), read by the fused planners and the oracle study's rules."""

from __future__ import annotations

import pytest
import torch

from nbv.plan import PlanningContext, ProbeFields
from nbv.plan.fused import PER_GAUSSIAN, FusedPlanner, per_gaussian_values
from nbv.plan.physics import shuffled_divergence
from nbv.plan.rules import FUSED_RULES, VALUES
from nbv.study.oracle_config import RULES, VIEW_SCORES
from recon.gaussians import GaussianSet


def context(**callables) -> PlanningContext:
    g = GaussianSet.from_points(torch.arange(12, dtype=torch.float32).reshape(4, 3), scale=0.1)
    return PlanningContext(
        gaussians=g, train_views=[], candidates=[], candidate_ids=[], n_selected=1, budget=4,
        background=torch.ones(3), round=3, **callables,
    )  # fmt: skip


def test_one_vocabulary_for_the_planners_and_the_oracle():
    assert tuple(PER_GAUSSIAN) == tuple(VALUES)
    assert {r.control for r in FUSED_RULES} <= set(VALUES)
    assert {r.values for r in RULES.values()} <= set(VALUES) | set(VIEW_SCORES)
    # a rule named after its values reads what the planner of that control reads
    for name, rule in RULES.items():
        if rule.per_gaussian:
            assert rule.physics == (VALUES[rule.values].probes or VALUES[rule.values].solid), name


def test_each_value_from_what_the_context_carries():
    d = torch.tensor([0.0, 2.0, 5.0, 1.0], dtype=torch.float64)
    empty = torch.tensor([[0.0, 3.0, 1.0, 0.5]], dtype=torch.float64)
    mask = torch.tensor([True, True, False, False])
    ctx = context(
        physics=lambda g: d,
        probe_fields=lambda g: ProbeFields(("-x",), d.reshape(1, -1), empty),
        solid_mask=lambda g: mask,
    )
    v = {name: per_gaussian_values(name, ctx, seed=7) for name in VALUES}
    assert torch.equal(v["fluid"], d) and torch.equal(v["area"], torch.ones(4, dtype=torch.float64))
    assert torch.equal(v["shuffled"], shuffled_divergence(d, 7, 3))  # the context's round
    assert torch.equal(v["excess"], torch.tensor([0.0, 0.0, 4.0, 0.5], dtype=torch.float64))
    assert torch.equal(v["perprobe"], d / (8.0 / 3.0))  # one probe, over its mean where it reached
    assert torch.equal(v["thin"], torch.tensor([0.0, 2.0, 0.0, 0.0], dtype=torch.float64))
    assert torch.equal(v["thin-area"], mask.double())
    assert torch.equal(v["transparency"], 1.0 - ctx.gaussians.opacities.double())
    for rule in FUSED_RULES:  # a fused planner's values are the table's, drawn with its seed
        planner = FusedPlanner(rule)
        assert torch.equal(planner.per_gaussian(ctx), per_gaussian_values(rule.control, ctx, planner.config.seed))


@pytest.mark.parametrize(
    ("name", "missing"), [("fluid", "physics"), ("excess", "probe_fields"), ("thin-area", "solid_mask")]
)
def test_a_value_names_what_the_context_lacks(name, missing):
    with pytest.raises(ValueError, match=f"needs PlanningContext.{missing}"):
        per_gaussian_values(name, context(), seed=0, who="fisher+x")
    with pytest.raises(ValueError, match="unknown per-Gaussian values"):
        per_gaussian_values("divergence", context(), seed=0)
