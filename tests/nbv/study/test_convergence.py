"""nbv.study.convergence: average ranks, Pearson and Spearman against scipy (or hand values), the view terms against
nbv.scores.view_scores, the agreement of synthetic settings whose relation is known (a rescaled D_g agrees
perfectly, a shuffled one does not, a constant one leaves coverage alone), and loading a RESULT.h5."""

import math

import numpy as np
import pytest
import torch

from nbv.ranking import average_ranks, pearson, spearman
from nbv.scores import view_scores
from nbv.study.convergence import (
    ProbeSetting,
    compare_settings,
    format_study,
    load_setting,
    study,
    view_terms,
    view_weight_matrix,
)
from recon.camera import Camera
from recon.gaussians import GaussianSet
from recon.render import render


def test_average_ranks_and_correlations():
    np.testing.assert_array_equal(average_ranks([3.0, 1.0, 2.0, 2.0]), [4.0, 1.0, 2.5, 2.5])
    np.testing.assert_array_equal(average_ranks([5.0, 5.0, 5.0]), [2.0, 2.0, 2.0])
    rng = np.random.default_rng(0)
    a = rng.normal(size=50)
    b = a + rng.normal(size=50)
    c = np.round(b, 0)  # many ties
    assert pearson(a, b) == pytest.approx(np.corrcoef(a, b)[0, 1], rel=1e-12)
    assert spearman(a, a**3) == pytest.approx(1.0)  # monotone: rank correlation 1, Pearson below
    assert pearson(a, a**3) < 0.95
    assert spearman(a, -a) == pytest.approx(-1.0)
    assert math.isnan(pearson([1.0, 1.0, 1.0], [1.0, 2.0, 3.0])) and math.isnan(spearman([2.0], [3.0]))
    scipy_stats = pytest.importorskip("scipy.stats")
    np.testing.assert_allclose(average_ranks(c), scipy_stats.rankdata(c))
    assert spearman(a, c) == pytest.approx(scipy_stats.spearmanr(a, c).statistic, rel=1e-12)
    assert pearson(b, c) == pytest.approx(scipy_stats.pearsonr(b, c).statistic, rel=1e-12)


def _scene():
    gen = torch.Generator().manual_seed(1)
    pts = torch.cat([torch.randn(40, 3, generator=gen) * 0.3 + torch.tensor([x, 0.0, 0.0]) for x in (-1.0, 1.0)])
    return GaussianSet.from_points(pts, torch.rand(80, 3, generator=gen), scale=0.08, opacity=0.9)


def _cams():
    out = []
    for k, a in enumerate(np.linspace(0, 2 * math.pi, 7, endpoint=False)):
        d = 3.0 + 0.4 * k
        out.append(
            Camera.look_at((d * math.cos(a), 0.3, d * math.sin(a)), (0, 0, 0), (0, 1, 0), 24, 24, 0.9, name=f"c{k}")
        )
    return out


def _setting(label, d, reached=None, seconds=1.0):
    d = np.asarray(d, np.float64)
    return ProbeSetting(
        label=label,
        particle_radius=0.05,
        steps=10,
        divergence=d,
        reached=np.ones(d.size, bool) if reached is None else reached,
        dbar=1e-3,
        seconds=seconds,
    )


def test_view_terms_equal_view_scores():
    g, cams = _scene(), _cams()
    w = view_weight_matrix(g, cams)
    d = np.abs(np.random.default_rng(2).normal(size=g.num))
    score, cover, mean_seen = view_terms(w, d)
    renders = [render(g, c, 1.0) for c in cams]
    np.testing.assert_allclose(score, view_scores(torch.from_numpy(d), renders).numpy(), rtol=1e-12)
    np.testing.assert_allclose(cover, view_scores(torch.ones(g.num), renders).numpy(), rtol=1e-12)
    np.testing.assert_allclose(mean_seen, score / cover)
    occluded = view_weight_matrix(g, cams, occlusion=True)
    assert (occluded <= w).all() and (occluded > 0).sum() < (w > 0).sum()  # the depth test hides some Gaussians
    with pytest.raises(ValueError, match="per-Gaussian values"):
        view_terms(w, d[:5])


def test_study_of_synthetic_settings():
    g, cams = _scene(), _cams()
    w = view_weight_matrix(g, cams)
    x = g.means[:, 0].double().numpy()
    base = _setting("base", np.exp(x))  # larger on the +x cluster
    scaled = _setting("scaled", 3.0 * np.exp(x), seconds=None)
    shuffled = _setting("shuffled", np.random.default_rng(0).permutation(np.exp(x)))
    flat = _setting("flat", np.full(g.num, 0.7))
    summaries, pairs = study([base, scaled, shuffled, flat], w)
    assert [p.first + ">" + p.second for p in pairs[:3]] == ["base>scaled", "base>shuffled", "base>flat"]
    same = pairs[0]
    assert same.d_pearson == pytest.approx(1.0) and same.d_spearman == pytest.approx(1.0)
    assert same.score_spearman == pytest.approx(1.0) and same.mean_seen_spearman == pytest.approx(1.0)
    assert same.top_view_rank == 1 and same.top_k_overlap == 5 and same.common == g.num
    assert abs(pairs[1].d_spearman) < 0.3  # the shuffle destroys where the values are
    assert pairs[1].mean_seen_spearman < same.mean_seen_spearman
    by = {s.label: s for s in summaries}
    # constant D_g: S = 0.7 A, so coverage orders the views exactly and S/A does not vary
    assert by["flat"].score_vs_coverage_spearman == pytest.approx(1.0) and by["flat"].mean_seen_cv < 1e-12
    assert by["base"].mean_seen_cv > 0.05  # a D_g that differs between the clusters varies S/A
    assert math.isnan(by["flat"].mean_seen_vs_coverage_spearman)  # S/A is constant: no rank correlation
    assert -1.0 <= by["base"].mean_seen_vs_coverage_spearman <= 1.0
    assert math.isnan(compare_settings(flat, _setting("flat2", np.full(g.num, 0.2)), w).mean_seen_spearman)
    assert by["base"].top_view == by["scaled"].top_view
    text = format_study(summaries, pairs)
    assert "| base | scaled | 80 | 1.000 | 1.000 | 1.000 | 1.000 | 1 | 5 |" in text
    assert "| scaled | n/a | n/a |" in text  # no particle count, no time
    # D_g is compared only where both runs reached the Gaussians
    half = np.arange(g.num) < 40
    part = compare_settings(_setting("a", np.exp(x), reached=half), _setting("b", np.exp(x), reached=~half | half), w)
    assert part.common == 40
    with pytest.raises(ValueError, match="one Gaussian set"):
        compare_settings(base, _setting("small", np.ones(3)), w)
    with pytest.raises(ValueError, match="NaN"):
        _setting("bad", [1.0, math.nan])


def test_load_setting_reads_a_result_file(tmp_path):
    from fluidsim.output import stats_table
    from fluidsim.solver import StepStats
    from nbv.physics import PhysicsConfig, PhysicsResult, save_result, scene_transform

    n = 6
    config = PhysicsConfig(particle_radius=0.035, steps=300, scale=2.0)
    stats = stats_table([StepStats(0, 0.002, 0.002, 2, 0.1, 1, 0.1, 3.0, 0, 0, 123, 20, 10)])
    res = PhysicsResult(
        directions=("-x", "+x"),
        per_probe=np.array([[0.0, 1.0, 2.0, 0.0, 4.0, 0.0], [0.0, 3.0, 0.0, 0.0, 1.0, 0.0]]),
        per_probe_counts=np.array([[0, 2, 1, 0, 5, 0], [0, 1, 0, 0, 2, 1]]),
        per_probe_distinct=None,
        divergence=np.array([0.0, 3.0, 2.0, 0.0, 4.0, 0.0]),
        divergence_mean=np.array([0.0, 2.0, 1.0, 0.0, 2.5, 0.0]),
        dbar=1.5e-3,
        dbar_mean=1e-3,
        dbar_empty=None,
        dbar_empty_mean=None,
        empty_per_probe=None,
        solid=np.zeros((2, 3)),
        transform=scene_transform(_scene(), config),
        means=np.zeros((n, 3)),
        covariances=np.tile(np.eye(3), (n, 1, 1)),
        reach=np.ones(n),
        stats={"-x": stats, "+x": stats},
        domains={},
        timings={"total": 12.5},
        config=config,
    )
    path = save_result(tmp_path / "r.h5", res)
    s = load_setting(path)
    assert s.label == "r=0.035 m, 300 steps" and s.particle_radius == 0.035 and s.steps == 300
    np.testing.assert_array_equal(s.divergence, res.divergence)
    np.testing.assert_array_equal(s.reached, [False, True, True, False, True, True])  # the +x probe reached g5
    assert s.seconds == 12.5 and s.fluid_particles == 123 and s.dbar == 1.5e-3
    assert load_setting(path, label="paper").label == "paper"
