"""The physics-pick candidates of issue 19 item 4 (nbv/plan.py): fisher+fluid-occ and its coverage control
fisher+area-occ (the depth test forced on), fisher+excess (D_g minus the empty-scene D_g), fisher+perprobe (each
probe normalised before the max), fisher+balanced (z(coverage) + z(S / coverage)). Each against a numpy or
hand-computed twin, with a scene where it picks another view than the plain S(T); the active loop hands the
per-probe fields to the planners; the paired table and M@D know the candidates."""

import math

import numpy as np
import pytest
import torch

from nbv.plan import (
    FUSED_RULES,
    PLANNERS,
    PlanningContext,
    ProbeFields,
    balanced_scores,
    excess_divergence,
    make_planner,
    per_probe_normalised,
    physics_view_scores,
    uses_physics,
)
from recon.camera import Camera
from recon.gaussians import GaussianSet

# the candidates beyond coverage: the fused rules on FisherRF other than FluidGaussian and its two controls
CANDIDATES = tuple(
    r.name
    for r in FUSED_RULES
    if r.visual == "fisher" and (r.depth_test or r.control in ("excess", "perprobe") or r.combine == "balanced")
)


class StubVisual:
    """A visual planner with a fixed order."""

    def __init__(self, order: list[int]) -> None:
        self.order = order

    def rank(self, context, k):
        return self.order[:k], [float(len(self.order) - self.order.index(i)) for i in range(len(self.order))]


def _cam(x: float, distance: float = 2.5, z_sign: float = -1.0) -> Camera:
    return Camera.look_at((x, 0.0, z_sign * distance), (x, 0.0, 0.0), (0.0, -1.0, 0.0), 16, 16, math.radians(30))


def _two_groups() -> GaussianSet:
    """Four Gaussians at x = -1.2 and four at x = +1.2."""
    gen = torch.Generator().manual_seed(1)
    centres = torch.tensor([[x, 0.0, 0.0] for x in (-1.2, 1.2) for _ in range(4)])
    points = centres + 0.1 * torch.randn(8, 3, generator=gen)
    return GaussianSet.from_points(points, torch.rand(8, 3, generator=gen), scale=0.1, opacity=0.8)


def _context(g, cams, physics=None, fields=None, occlusion=False, solid_mask=None) -> PlanningContext:
    return PlanningContext(
        gaussians=g,
        train_views=[],
        candidates=cams,
        candidate_ids=list(range(len(cams))),
        n_selected=1,
        budget=1 + len(cams),
        background=torch.ones(3),
        physics=physics,
        occlusion=occlusion,
        probe_fields=None if fields is None else (lambda _: fields),
        solid_mask=solid_mask,
    )


def _planner(name: str, order: list[int]):
    planner = make_planner(name)
    planner.visual = StubVisual(order)
    return planner


# ---- the per-Gaussian values and the combination ------------------------------------------------------------


def test_excess_divergence_is_the_clamped_per_probe_difference_then_the_max():
    rng = np.random.default_rng(0)
    d, e = rng.random((3, 50)), rng.random((3, 50))
    fields = ProbeFields(("-x", "+x", "-y"), torch.from_numpy(d), torch.from_numpy(e))
    want = np.maximum(d - e, 0.0).max(axis=0)
    np.testing.assert_allclose(excess_divergence(fields).numpy(), want, rtol=0, atol=0)
    # not the difference of the maxima: a Gaussian where each probe is explained by its own empty scene gets 0
    one = ProbeFields(("-x", "+x"), torch.tensor([[2.0], [0.5]]), torch.tensor([[2.5], [0.5]]))
    assert float(excess_divergence(one)) == 0.0 and 2.0 - 2.5 < 0
    with pytest.raises(ValueError, match="empty_reference"):
        excess_divergence(ProbeFields(("-x",), torch.ones(1, 4)))


def test_per_probe_normalisation_gives_every_probe_its_own_scale():
    rng = np.random.default_rng(1)
    d = rng.random((4, 30)) * np.array([[1.0], [10.0], [0.1], [3.0]])
    d[2, :10] = 0.0  # probe 2 does not reach a third of the Gaussians
    d[3] = 0.0  # probe 3 reaches none
    scale = np.array([row[row > 0].mean() if (row > 0).any() else 1.0 for row in d])
    want = (d / scale[:, None]).max(axis=0)
    got = per_probe_normalised(torch.from_numpy(d))
    np.testing.assert_allclose(got.numpy(), want, rtol=1e-14)
    # scaling one probe changes nothing; the plain max would follow the loud probe
    louder = d.copy()
    louder[1] *= 1000.0
    np.testing.assert_allclose(per_probe_normalised(torch.from_numpy(louder)).numpy(), want, rtol=1e-12)
    assert not np.allclose(louder.max(axis=0) / louder.max(), d.max(axis=0) / d.max())
    with pytest.raises(ValueError, match=r"\[P, N\]"):
        per_probe_normalised(torch.ones(5))


def test_balanced_scores_standardise_coverage_and_the_mean_divergence():
    a, s = [1.0, 2.0, 4.0], [3.0, 2.0, 4.0]
    m = np.array(s) / np.array(a)

    def z(x):
        x = np.asarray(x, float)
        return (x - x.mean()) / x.std()

    np.testing.assert_allclose(balanced_scores(a, s), z(a) + z(m), rtol=1e-12)
    # S proportional to A: the mean D_g is the same everywhere and coverage alone ranks
    np.testing.assert_allclose(balanced_scores(a, [2 * x for x in a]), z(a), rtol=1e-12)
    # the same coverage everywhere: the mean D_g alone ranks; a view with A = 0 has mean 0
    np.testing.assert_allclose(balanced_scores([0.0, 1.0, 1.0], [0.0, 1.0, 3.0]), z([0, 1, 1]) + z([0, 1, 3]))
    assert balanced_scores([1.0, 1.0], [5.0, 5.0]) == [0.0, 0.0]
    with pytest.raises(ValueError, match="coverages"):
        balanced_scores([1.0], [1.0, 2.0])


def test_probe_fields_validation():
    with pytest.raises(ValueError, match=r"\[P, N\]"):
        ProbeFields(("-x", "+x"), torch.ones(1, 3))
    with pytest.raises(ValueError, match="NaN"):
        ProbeFields(("-x",), torch.tensor([[1.0, math.nan]]))
    with pytest.raises(ValueError, match="shaped like"):
        ProbeFields(("-x",), torch.ones(1, 3), torch.ones(1, 2))


# ---- the planners -----------------------------------------------------------------------------------------


def test_candidates_are_registered_and_say_whether_they_simulate():
    assert set(CANDIDATES) <= set(PLANNERS)
    for name in CANDIDATES:
        p = make_planner(name, seed=3)
        assert p.name == name and p.config.seed == 3 and type(p.visual).__name__ == "FisherPlanner"
        assert uses_physics(name) == (name not in ("fisher+area-occ", "fisher+thin-area-occ")) == p.uses_physics
    assert make_planner("fisher+fluid-occ").depth_test and make_planner("fisher+area-occ").depth_test
    assert not make_planner("fisher+excess").depth_test and make_planner("fisher+balanced").combine == "balanced"
    both = make_planner("fisher+balanced-occ")
    assert both.depth_test and both.combine == "balanced" and both.control == "fluid"


def test_occ_candidates_use_the_depth_test_whatever_the_context_says():
    """Two groups behind each other along z; one camera in front, one behind, one aside. With the depth test the
    front group hides the back one, so S(T) differs from the frustum S(T), and -occ equals the depth-tested score."""
    gen = torch.Generator().manual_seed(2)
    centres = torch.tensor([[0.0, 0.0, z] for z in (-0.4, 0.4) for _ in range(30)])
    g = GaussianSet.from_points(centres + 0.08 * torch.randn(60, 3, generator=gen), scale=0.12, opacity=0.95)
    cams = [_cam(0.0), _cam(0.0, z_sign=1.0), _cam(0.3, distance=3.0)]
    d = torch.where(g.means[:, 2] > 0, 5.0, 1.0).double()  # the +z group disturbs the fluid
    depth = physics_view_scores(g, cams, d, occlusion=True)
    frustum = physics_view_scores(g, cams, d)
    assert depth != pytest.approx(frustum, rel=1e-3)
    for occlusion in (False, True):
        ctx = _context(g, cams, physics=lambda _: d, occlusion=occlusion)
        sel = _planner("fisher+fluid-occ", [0, 1, 2]).select(ctx)
        assert sel.scores["physics"] == pytest.approx(depth, rel=1e-12)
        assert sel.pick == max(range(3), key=lambda i: (depth[i], -i))
        cover = _planner("fisher+area-occ", [0, 1, 2]).select(_context(g, cams, physics=None, occlusion=occlusion))
        area_depth = physics_view_scores(g, cams, torch.ones(60), occlusion=True)
        assert cover.scores["physics"] == pytest.approx(area_depth, rel=1e-12)
        balanced = _planner("fisher+balanced-occ", [0, 1, 2]).select(ctx)
        assert balanced.scores["physics"] == pytest.approx(balanced_scores(area_depth, depth), rel=1e-12)
    # the plain fisher+fluid follows the context
    plain = _planner("fisher+fluid", [0, 1, 2]).select(_context(g, cams, physics=lambda _: d))
    assert plain.scores["physics"] == pytest.approx(frustum, rel=1e-12)


def test_excess_candidate_ignores_what_the_empty_scene_explains():
    """The right group has the larger D_g, but the empty scene gives the same there (the inflow front): the excess
    pick goes left, the plain pick right."""
    g = _two_groups()
    right = g.means[:, 0] > 0
    d = torch.where(right, 4.0, 2.0).double()
    e = torch.where(right, 4.0, 0.5).double()
    fields = ProbeFields(("-x",), d[None], e[None])
    cams = [_cam(1.2), _cam(-1.2)]
    ctx = _context(g, cams, physics=lambda _: d, fields=fields)
    assert _planner("fisher+fluid", [0, 1]).select(ctx).pick == 0
    sel = _planner("fisher+excess", [0, 1]).select(ctx)
    assert sel.pick == 1
    assert sel.scores["physics"] == pytest.approx(physics_view_scores(g, cams, (d - e).clamp_min(0)), rel=1e-12)
    with pytest.raises(ValueError, match="probe_fields"):
        _planner("fisher+excess", [0, 1]).select(_context(g, cams, physics=lambda _: d))
    with pytest.raises(ValueError, match="empty_reference"):
        _planner("fisher+excess", [0, 1]).select(
            _context(g, cams, physics=lambda _: d, fields=ProbeFields(("-x",), d[None]))
        )


def test_perprobe_candidate_lets_the_quiet_probe_count():
    """Probe 1 is loud on the right group, probe 2 ten times quieter but strong on the left: the plain max picks
    right, the normalised max left (probe 2 at 1.8x its mean beats probe 1 at 1.6x its mean)."""
    g = _two_groups()
    right = g.means[:, 0] > 0
    loud = torch.where(right, 8.0, 2.0).double()
    quiet = torch.where(right, 0.1, 0.9).double()
    fields = ProbeFields(("-x", "-y"), torch.stack([loud, quiet]))
    cams = [_cam(1.2), _cam(-1.2)]
    ctx = _context(g, cams, physics=lambda _: torch.maximum(loud, quiet), fields=fields)
    assert _planner("fisher+fluid", [0, 1]).select(ctx).pick == 0
    sel = _planner("fisher+perprobe", [0, 1]).select(ctx)
    assert sel.pick == 1
    want = physics_view_scores(g, cams, per_probe_normalised(fields.per_probe))
    assert sel.scores["physics"] == pytest.approx(want, rel=1e-12)


def test_balanced_candidate_weighs_the_mean_divergence_against_coverage():
    """The near left view covers more, the far right one sees the larger D_g per area: S(T) follows coverage
    (left), the balanced score ranks by z(A) + z(S/A), which the mean D_g decides here."""
    g = _two_groups()
    d = torch.where(g.means[:, 0] > 0, 1.2, 1.0).double()
    cams = [_cam(-1.2), _cam(1.2, distance=3.0), _cam(-1.2, distance=4.0)]
    s = physics_view_scores(g, cams, d)
    a = physics_view_scores(g, cams, torch.ones(g.num))
    assert s.index(max(s)) == 0 and a[0] > a[1] > a[2]  # coverage wins the plain score
    want = balanced_scores(a, s)
    sel = _planner("fisher+balanced", [0, 1, 2]).select(_context(g, cams, physics=lambda _: d))
    assert sel.scores["physics"] == pytest.approx(want, rel=1e-12)
    assert sel.pick == max(range(3), key=lambda i: (want[i], -i)) == 1


# ---- the loop, the experiment tables and M@D --------------------------------------------------------------


def test_thin_area_candidates_score_the_coverage_of_the_masked_gaussians_without_probes():
    gen = torch.Generator().manual_seed(2)
    centres = torch.tensor([[0.0, 0.0, z] for z in (-0.4, 0.4) for _ in range(30)])
    g = GaussianSet.from_points(centres + 0.08 * torch.randn(60, 3, generator=gen), scale=0.12, opacity=0.95)
    cams = [_cam(0.0), _cam(0.0, z_sign=1.0), _cam(0.3, distance=3.0)]
    mask = g.means[:, 2] > 0  # the +z group is thin or open

    def no_probes(_):
        raise AssertionError("a thin-area planner must not run the probes")

    for name, occ in (("fisher+thin-area-occ", True), ("fisher+thin-area", False)):
        ctx = _context(g, cams, physics=no_probes, solid_mask=lambda _: mask)
        sel = _planner(name, [0, 1, 2]).select(ctx)
        want = physics_view_scores(g, cams, mask.double(), occlusion=occ)
        assert sel.scores["physics"] == pytest.approx(want, rel=1e-12)
        assert sel.pick == max(range(3), key=lambda i: (want[i], -i))
    # the camera behind the +z group sees more of it than the one in front, whose view the -z group hides
    occ = physics_view_scores(g, cams, mask.double(), occlusion=True)
    assert occ[1] > occ[0]
    with pytest.raises(ValueError, match="solid_mask"):
        _planner("fisher+thin-area-occ", [0, 1, 2]).select(_context(g, cams))
    with pytest.raises(ValueError, match="shape"):
        _planner("fisher+thin-area-occ", [0, 1, 2]).select(_context(g, cams, solid_mask=lambda _: mask[:5]))


def _tiny_loop(tmp_path, method: str, physics_fn) -> dict:
    """rounds.json of a 4-view loop of ``method`` on a 16 px torus, the probes replaced by ``physics_fn``."""
    from nbv.active import run_active
    from recon.mesh_render import MeshDatasetConfig, render_mesh_dataset

    from helpers.paths import TORUS
    from helpers.training import tiny_active_config

    ds = render_mesh_dataset(
        TORUS, tmp_path / "torus", MeshDatasetConfig(n_train=6, n_test=2, resolution=16, supersample=1), progress=False
    )
    cfg = tiny_active_config(method=method, iterations_per_view=1, total_iterations=6, mode="reset")
    return run_active(ds, tmp_path / "run", cfg, physics_fn=physics_fn, progress=False)


def test_active_loop_hands_the_probe_fields_to_the_planner(tmp_path):
    calls = []

    def fake_physics(gaussians):
        calls.append(gaussians.num)
        return gaussians.means.detach()[:, 0].abs().double()

    rounds = _tiny_loop(tmp_path, "fisher+perprobe", fake_physics)
    assert len(calls) == 2  # the probes ran once per selection, for both the D_g and the per-probe fields
    for rec in rounds["rounds"]:
        scores = {int(i): v for i, v in rec["scores"]["physics"].items() if v is not None}
        assert set(scores) == set(rec["shortlist"]) and rec["pick"] == max(scores, key=scores.get)


def test_paired_table_and_single_directions_know_the_candidates():
    from nbv.study.experiment_config import PICKS, split_method
    from nbv.study.paired import comparisons

    pairs = comparisons(["fisher+area", "fisher+fluid", "fisher+area-occ", "fisher+fluid-occ", "fisher+excess"])
    assert ("fisher+fluid", "fisher+area") in pairs
    for m in ("fisher+fluid-occ", "fisher+excess"):
        assert {(m, "fisher+area"), (m, "fisher+fluid"), (m, "fisher+area-occ")} <= set(pairs)
    assert ("fisher+area-occ", "fisher+area") in pairs and ("fisher+area-occ", "fisher+area-occ") not in pairs
    assert split_method("fisher+excess@-x") == ("fisher+excess", "-x")
    assert split_method("fisher+fluid-occ@+z") == ("fisher+fluid-occ", "+z")
    with pytest.raises(ValueError, match="run no probe"):
        split_method("fisher+area-occ@-x")
    assert {m.partition("+")[2] for m in CANDIDATES} <= set(PICKS)


def test_active_loop_hands_the_solid_mask_to_a_thin_area_planner_and_runs_no_probe(tmp_path):
    def no_probes(gaussians):
        raise AssertionError("fisher+thin-area-occ must not run the probes")

    rounds = _tiny_loop(tmp_path, "fisher+thin-area-occ", no_probes)
    for rec in rounds["rounds"]:
        assert "physics" not in rec and 0.0 <= rec["solid_mask"]["share"] <= 1.0
        scores = {int(i): v for i, v in rec["scores"]["physics"].items() if v is not None}
        order = rec["shortlist"]  # ties go to the earlier shortlist entry
        assert set(scores) == set(order)
        assert rec["pick"] == max(order, key=lambda i: (scores[i], -order.index(i)))
