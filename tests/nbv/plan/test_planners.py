"""Tests for nbv/plan.py: the registry and config overrides; the random planner's (seed, round)
reproducibility; K = max(B - n, 2); the fused re-ranking with a fake physics callable (D_g set on one region):
the pick is the visual top-K member with the largest S(T), a candidate outside the top-K is never chosen even
when its S(T) is larger, the probes run once; the fused planners end to end with the real FisherRF and
variance planners; the physics planner over all candidates; S(T) from projections equals S(T) from renders;
the variance planner's warm start; and input validation."""

import math

import pytest
import torch

from nbv.plan import (
    PLANNERS,
    PhysicsPlanner,
    Planner,
    PlanningContext,
    RandomPlanner,
    Selection,
    VariancePlanner,
    fused_k,
    make_planner,
    physics_view_scores,
)
from nbv.plan.fisher_info import FisherConfig, greedy_top_k
from nbv.plan.variance_model import VarianceConfig
from nbv.scores import view_scores
from recon.camera import Camera
from recon.datasets import View
from recon.gaussians import GaussianSet, concat
from recon.render import render

F32 = torch.float32
CLUSTERS = (-1.2, 0.0, 1.2)  # x of the left, centre and right groups of four Gaussians


def _scene() -> GaussianSet:
    gen = torch.Generator().manual_seed(4)
    centres = torch.tensor([[x, 0.0, 0.0] for x in CLUSTERS for _ in range(4)])
    points = centres + 0.12 * torch.randn(12, 3, generator=gen)
    return GaussianSet.from_points(points, torch.rand(12, 3, generator=gen), scale=0.1, opacity=0.8)


def _cam(x: float, distance=2.5, size=12, fov_deg=30.0) -> Camera:
    return Camera.look_at((x, 0.0, -distance), (x, 0.0, 0.0), (0.0, -1.0, 0.0), size, size, math.radians(fov_deg))


def _candidates() -> list[Camera]:
    """left, centre, right, right from further away."""
    return [_cam(-1.2), _cam(0.0), _cam(1.2), _cam(1.2, distance=3.0)]


class FakePhysics:
    """D_g = 1 on the centre group, 5 on the right group, 0 on the left one; counts its calls."""

    def __init__(self) -> None:
        self.calls = 0

    def __call__(self, gaussians: GaussianSet) -> torch.Tensor:
        self.calls += 1
        x = gaussians.means[:, 0]
        return torch.where(x > 0.6, 5.0, torch.where(x > -0.6, 1.0, 0.0)).to(torch.float64)


class StubVisual:
    """A visual planner with a fixed order, for the fused re-ranking logic."""

    def __init__(self, order: list[int]) -> None:
        self.order = order
        self.asked: list[int] = []

    def rank(self, context, k):
        self.asked.append(k)
        return self.order[:k], [float(len(self.order) - self.order.index(i)) for i in range(len(self.order))]


def _context(
    gaussians=None, train=None, candidates=None, n_selected=2, budget=4, physics=None, round_=0
) -> PlanningContext:
    g = _scene() if gaussians is None else gaussians
    cams = _candidates() if candidates is None else candidates
    if train is None:
        cam = _cam(0.3, distance=3.5, size=12, fov_deg=60.0)
        train = [View(cam, render(g, cam, 1.0).image.detach(), None, "train0")]
    return PlanningContext(
        gaussians=g,
        train_views=train,
        candidates=cams,
        candidate_ids=list(range(10, 10 + len(cams))),
        n_selected=n_selected,
        budget=budget,
        background=torch.ones(3),
        physics=physics,
        round=round_,
    )


def _check_selection(sel: Selection, count: int) -> None:
    assert 0 <= sel.pick < count
    assert sel.pick in sel.shortlist
    assert set(sel.scores) == {"visual", "physics"}
    assert all(len(v) == count for v in sel.scores.values())
    assert set(sel.seconds) == {"visual", "physics"}


def test_registry_names_and_make_planner():
    from nbv.plan import FUSED_RULES, PLANNER_NAMES, FusedRule, describe_planners, uses_physics

    assert tuple(PLANNERS) == PLANNER_NAMES and len(set(PLANNER_NAMES)) == len(PLANNER_NAMES)
    assert {
        "random",
        "fisher",
        "variance",
        "physics",
        "fisher+fluid",
        "variance+fluid",
        "random+fluid",
        "fvs",
        "fvs+fluid",
    } <= set(PLANNERS)
    for name in PLANNERS:
        planner = make_planner(name, seed=3)
        assert isinstance(planner, Planner)
        assert planner.name == name and planner.config.seed == 3
        assert f"{name}" in describe_planners()  # the help names every planner
    for rule in FUSED_RULES:  # each rule's name is <visual>+..., and the planner runs that rule on that visual planner
        planner = make_planner(rule.name)
        assert rule.name.startswith(rule.visual + "+") and planner.rule is rule
        assert (
            type(planner.visual).__name__
            == {
                "fisher": "FisherPlanner",
                "variance": "VariancePlanner",
                "random": "RandomPlanner",
                "fvs": "FVSPlanner",
            }[rule.visual]
        )
        assert uses_physics(rule.name) == (rule.control not in ("area", "thin-area")) == planner.uses_physics
    with pytest.raises(ValueError, match="control must be one of"):
        FusedRule("fisher+x", "fisher", control="x")
    with pytest.raises(ValueError, match="visual must be one of"):
        FusedRule("physics+x", "physics")
    assert make_planner("fisher+fluid", regularization=1e-3).config.regularization == 1e-3
    assert make_planner("variance+fluid", iterations=5).config.iterations == 5
    with pytest.raises(ValueError, match="unknown planner"):
        make_planner("fisherrf")
    with pytest.raises(ValueError, match="iterations"):
        make_planner("fisher", iterations=3)
    with pytest.raises(ValueError, match="seed"):
        make_planner("random", seed=-1)


def test_random_planner_is_reproducible_per_seed_and_round():
    g = _scene()
    cams = [_cam(0.1 * i) for i in range(9)]

    def picks(seed):
        planner = make_planner("random", seed=seed)
        return [planner.select(_context(g, train=[], candidates=cams, round_=r)).pick for r in range(8)]

    assert picks(0) == picks(0)  # a resumed run (fresh planner, same rounds) repeats the choices
    assert picks(0) != picks(1)
    assert len(set(picks(0))) > 1
    sel = RandomPlanner().select(_context(g, train=[], candidates=cams))
    _check_selection(sel, 9)
    assert sel.k is None and all(math.isnan(s) for s in sel.scores["visual"])


def test_random_fluid_picks_the_best_physics_score_of_k_random_candidates():
    g, cams = _scene(), _candidates()
    full = physics_view_scores(g, cams, FakePhysics()(g))
    shortlists = set()
    for seed in range(6):
        physics = FakePhysics()
        ctx = _context(g, candidates=cams, n_selected=2, budget=4, physics=physics)
        sel = make_planner("random+fluid", seed=seed).select(ctx)
        _check_selection(sel, 4)
        assert sel.k == 2 and len(set(sel.shortlist)) == 2 and physics.calls == 1
        assert sel.pick == max(sel.shortlist, key=lambda i: full[i])
        assert make_planner("random+fluid", seed=seed).select(ctx).shortlist == sel.shortlist  # reproducible
        shortlists.add(tuple(sorted(sel.shortlist)))
    assert len(shortlists) > 1  # the shortlist is drawn, not fixed


def test_fused_k_rule():
    assert fused_k(10, 2) == 8
    assert fused_k(10, 8) == 2
    assert fused_k(10, 9) == 2
    assert fused_k(3, 0) == 3


def test_physics_scores_from_projection_equal_scores_from_renders():
    g, cams = _scene(), _candidates()
    d = FakePhysics()(g)
    renders = [render(g, c, 1.0) for c in cams]
    expected = view_scores(d, renders)
    assert physics_view_scores(g, cams, d) == pytest.approx(expected.tolist(), rel=1e-12)
    # the scene is built so that the right-hand candidates score highest and the left one lowest
    assert expected[2] > expected[1] > expected[0]
    with pytest.raises(ValueError, match="per-Gaussian values"):
        physics_view_scores(g, cams, d[:3])


@pytest.mark.parametrize("name", ["fisher+fluid", "variance+fluid"])
def test_fused_pick_is_the_top_k_member_with_largest_physics_score(name):
    g, cams = _scene(), _candidates()
    full = physics_view_scores(g, cams, FakePhysics()(g))
    planner = make_planner(name)
    planner.visual = StubVisual([0, 1, 2, 3])
    physics = FakePhysics()
    sel = planner.select(_context(g, candidates=cams, n_selected=2, budget=4, physics=physics))
    _check_selection(sel, 4)
    # K = max(4 - 2, 2) = 2: the top-2 are positions 0 and 1; 2 and 3 score higher on physics but are out
    assert sel.k == 2 and sel.shortlist == [0, 1] and planner.visual.asked == [2]
    assert max(full) in (full[2], full[3]) and full[2] > full[1]
    assert sel.pick == 1
    assert physics.calls == 1
    assert math.isnan(sel.scores["physics"][2]) and math.isnan(sel.scores["physics"][3])
    assert sel.scores["physics"][1] == pytest.approx(full[1])
    # with one view selected out of a budget of 5, K = 4 admits the right-hand candidates
    planner.visual = StubVisual([1, 0, 3, 2])
    sel = planner.select(_context(g, candidates=cams, n_selected=1, budget=5, physics=FakePhysics()))
    assert sel.k == 4 and sel.shortlist == [1, 0, 3, 2]
    assert sel.pick == max(range(4), key=lambda i: full[i])
    # the budget is spent: K stays 2, ties in S(T) go to the visual planner's order
    planner.visual = StubVisual([0, 3, 1, 2])
    sel = planner.select(_context(g, candidates=cams, n_selected=10, budget=10, physics=lambda gs: torch.zeros(gs.num)))
    assert sel.k == 2 and sel.pick == 0


def test_fisher_fluid_end_to_end_picks_from_the_greedy_fisher_list():
    ctx = _context(n_selected=1, budget=3, physics=FakePhysics())
    sel = make_planner("fisher+fluid").select(ctx)
    order = greedy_top_k(
        ctx.gaussians, ctx.candidates, [v.camera for v in ctx.train_views], ctx.background, 2, FisherConfig()
    ).order
    assert sel.k == 2 and sel.shortlist == order
    physics = [sel.scores["physics"][i] for i in order]
    assert sel.pick == order[max(range(2), key=lambda j: (physics[j], -j))]
    assert sel.seconds["visual"] > 0 and sel.seconds["physics"] > 0
    plain = make_planner("fisher").select(ctx)
    _check_selection(plain, 4)
    assert plain.pick == order[0] and sorted(plain.shortlist) == [0, 1, 2, 3]
    assert plain.scores["visual"] == pytest.approx(sel.scores["visual"])


def test_variance_fluid_end_to_end_and_warm_start():
    g = _scene()
    ctx = _context(g, n_selected=2, budget=5, physics=FakePhysics())
    planner = make_planner("variance+fluid", iterations=20)
    sel = planner.select(ctx)
    visual = sel.scores["visual"]
    top = sorted(range(4), key=lambda i: (-visual[i], i))[:3]
    assert sel.k == 3 and sel.shortlist == top
    assert sel.pick == max(top, key=lambda i: (sel.scores["physics"][i], -top.index(i)))
    # the plain variance planner keeps its fitted variances: zero further iterations reuse them exactly
    plain = VariancePlanner(VarianceConfig(iterations=20))
    first = plain.select(ctx)
    fitted = plain.log_variances.clone()
    plain.config = VarianceConfig(iterations=0)
    second = plain.select(ctx)
    torch.testing.assert_close(plain.log_variances, fitted)
    assert second.scores["visual"] == pytest.approx(first.scores["visual"])
    assert first.pick == first.shortlist[0] == max(range(4), key=lambda i: (first.scores["visual"][i], -i))
    # after densification (N changed) the fit starts afresh
    grown = concat([g, g.subset(torch.arange(2))])
    plain.select(_context(grown, n_selected=2, budget=5))
    assert plain.log_variances.shape == (14,)
    assert torch.allclose(plain.log_variances, torch.full((14,), math.log(0.01), dtype=torch.float64))


def test_physics_planner_scores_all_candidates():
    physics = FakePhysics()
    sel = PhysicsPlanner().select(_context(physics=physics))
    _check_selection(sel, 4)
    full = sel.scores["physics"]
    assert sel.pick == max(range(4), key=lambda i: (full[i], -i)) and physics.calls == 1
    assert sel.shortlist[0] == sel.pick and sorted(sel.shortlist) == [0, 1, 2, 3]
    with pytest.raises(ValueError, match="needs PlanningContext.physics"):
        PhysicsPlanner().select(_context())
    with pytest.raises(ValueError, match="needs PlanningContext.physics"):
        make_planner("fisher+fluid").select(_context())


def test_context_validation():
    with pytest.raises(ValueError, match="candidate_ids"):
        PlanningContext(_scene(), [], _candidates(), [0], 0, 10, torch.ones(3))
    with pytest.raises(ValueError, match="budget"):
        PlanningContext(_scene(), [], _candidates(), [0, 1, 2, 3], 0, 0, torch.ones(3))
    with pytest.raises(ValueError, match="no candidate views"):
        make_planner("random").select(_context(candidates=[]))


# ---- controls of the physics pick (issue 19): +area (D_g = 1, no probes) and +shuffled (D_g permuted) ----------


def _raising_physics(gaussians):
    raise AssertionError("the coverage control must not run the probes")


def _coverage(g: GaussianSet, cams: list[Camera]) -> list[float]:
    """sum_{g visible} w_g(T), the coverage, from the renderer's radii (independent of physics_view_scores)."""
    from nbv.scores import view_weights

    out = []
    for cam in cams:
        rend = render(g, cam, 1.0)
        out.append(float((view_weights(rend.radii, cam.height, cam.width) * rend.visible.double()).sum()))
    return out


def test_control_planners_are_registered_and_say_whether_they_simulate():
    from nbv.plan import uses_physics

    for visual in ("fisher", "variance", "random"):
        area, shuffled, fluid = (make_planner(f"{visual}+{c}", seed=2) for c in ("area", "shuffled", "fluid"))
        assert (area.control, shuffled.control, fluid.control) == ("area", "shuffled", "fluid")
        assert type(area.visual) is type(fluid.visual) and area.config.seed == 2
        assert not area.uses_physics and shuffled.uses_physics and fluid.uses_physics
        assert not uses_physics(f"{visual}+area") and uses_physics(f"{visual}+shuffled")
        assert not uses_physics(visual)
    assert uses_physics("physics") and uses_physics("fisher+fluid")
    with pytest.raises(ValueError, match="unknown planner"):
        uses_physics("fisher+coverage")


@pytest.mark.parametrize("visual", ["fisher", "variance", "random"])
def test_area_control_is_the_physics_score_with_ones_and_never_simulates(visual):
    g, cams = _scene(), _candidates()
    planner = make_planner(f"{visual}+area")
    if visual != "random":
        planner.visual = StubVisual([1, 0, 3, 2])
    # K = max(5 - 1, 2) = 4: the whole pool is shortlisted, so the pick is the coverage argmax over all four
    sel = planner.select(_context(g, candidates=cams, n_selected=1, budget=5, physics=_raising_physics))
    _check_selection(sel, 4)
    assert sel.k == 4 and sorted(sel.shortlist) == [0, 1, 2, 3]
    ones = physics_view_scores(g, cams, torch.ones(g.num, dtype=torch.float64))
    assert sel.scores["physics"] == pytest.approx(ones, rel=1e-12)
    assert ones == pytest.approx(_coverage(g, cams), rel=1e-9)
    assert sel.pick == max(range(4), key=lambda i: (ones[i], -sel.shortlist.index(i)))
    # the nearer right-hand camera covers more than the same view from further away: coverage, not physics
    assert ones[2] > ones[3]
    # no physics callable at all is fine too
    assert planner.select(_context(g, candidates=cams, n_selected=1, budget=5, physics=None)).pick == sel.pick


def test_area_control_differs_from_the_physics_pick_where_d_g_matters():
    """The right group seen from further away (D_g = 5) against the left group from nearer (D_g = 0): the
    physics pick takes the far right view, the coverage control the near left one."""
    g = _scene()
    cams = [_cam(1.2, distance=3.0), _cam(-1.2)]
    cover = physics_view_scores(g, cams, torch.ones(g.num))
    assert cover[1] > 1.5 * cover[0]
    for visual in ("fisher", "variance"):
        fluid, area = make_planner(f"{visual}+fluid"), make_planner(f"{visual}+area")
        fluid.visual, area.visual = StubVisual([0, 1]), StubVisual([0, 1])
        ctx = _context(g, candidates=cams, n_selected=1, budget=4, physics=FakePhysics())
        assert fluid.select(ctx).pick == 0
        assert area.select(ctx).pick == 1


def test_shuffled_divergence_is_a_seeded_permutation():
    from nbv.plan import shuffled_divergence

    d = torch.linspace(0.0, 3.0, 200, dtype=torch.float64) ** 2
    a = shuffled_divergence(d, 7, 2)
    torch.testing.assert_close(torch.sort(a).values, torch.sort(d).values, rtol=0, atol=0)  # the same multiset
    torch.testing.assert_close(shuffled_divergence(d, 7, 2), a, rtol=0, atol=0)  # deterministic per (seed, round)
    assert not torch.equal(shuffled_divergence(d, 8, 2), a)
    assert not torch.equal(shuffled_divergence(d, 7, 3), a)
    assert (a != d).float().mean() > 0.9  # a real shuffle: almost every Gaussian gets another value
    assert shuffled_divergence(d, -3, 0).shape == d.shape  # any int seed


@pytest.mark.parametrize("visual", ["fisher", "variance", "random"])
def test_shuffled_control_scores_the_permuted_divergence(visual):
    from nbv.plan import shuffled_divergence

    g, cams = _scene(), _candidates()
    picks = set()
    for seed in range(6):
        planner = make_planner(f"{visual}+shuffled", seed=seed)
        if visual != "random":
            planner.visual = StubVisual([0, 1, 2, 3])
        physics = FakePhysics()
        ctx = _context(g, candidates=cams, n_selected=1, budget=5, physics=physics, round_=3)
        sel = planner.select(ctx)
        _check_selection(sel, 4)
        assert physics.calls == 1  # the probes run (once)
        expected = physics_view_scores(g, cams, shuffled_divergence(FakePhysics()(g), seed, 3))
        assert [sel.scores["physics"][i] for i in range(4)] == pytest.approx(expected, rel=1e-12)
        assert make_planner(f"{visual}+shuffled", seed=seed).select(ctx).scores["physics"] == pytest.approx(
            sel.scores["physics"], rel=0
        )  # reproducible from the seed
        picks.add(sel.pick)
    fluid = physics_view_scores(g, cams, FakePhysics()(g))
    assert max(range(4), key=lambda i: fluid[i]) in (2, 3)  # the true D_g points right ...
    assert picks - {2, 3}  # ... the shuffled one sends some seeds elsewhere


def test_occlusion_in_the_context_reaches_the_physics_score():
    from dataclasses import replace

    from nbv.scores import DepthBuffer, projected_view_scores

    g, cams = _scene(), _candidates()
    d = torch.linspace(0.5, 2.0, g.num, dtype=torch.float64)
    want = projected_view_scores(d, g, cams, depth_buffer=DepthBuffer()).scores.tolist()
    assert physics_view_scores(g, cams, d, occlusion=True) == pytest.approx(want, rel=1e-12)
    planner = make_planner("physics")
    ctx = _context(g, candidates=cams, physics=lambda _: d)
    sel = planner.select(replace(ctx, occlusion=True))
    assert sel.scores["physics"] == pytest.approx(want, rel=1e-12)
    plain = planner.select(ctx).scores["physics"]
    assert plain == pytest.approx(physics_view_scores(g, cams, d), rel=1e-12)
