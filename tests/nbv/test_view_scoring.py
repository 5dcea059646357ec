"""The library side of `fluidgs score` and `bench views`: nbv.view_scoring (metric choice, checks, camera width,
ranked rows, the scores.json record, the stale files of a views folder), nbv.bench.score_agreement (projection
scores against full renders), nbv.bench.dense_sets.jittered_to_count and viz.annotate (the labelled PNG panels)."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from nbv import scores
from nbv.bench.dense_sets import jittered_to_count
from nbv.bench.score_agreement import compare_with_renders, load_divergence, spearman, stand_in_divergence
from nbv.view_scoring import (
    ScoreSettings,
    check_cameras_see,
    check_some_divergence,
    format_table,
    metric_values,
    rank_views,
    remove_stale,
    render_size,
    score_views,
    scores_record,
    view_files,
    write_views_folder,
)
from recon.camera import Camera
from viz.annotate import label, to_bgr

from helpers.random_scenes import RING_ANGLES, random_gaussians


def _scene(n: int = 300, seed: int = 0):
    g = random_gaussians(n, torch.Generator().manual_seed(seed))
    cams = [
        Camera.look_at(
            (3 * math.cos(a), 0.4, 3 * math.sin(a)), (0, 0, 0), (0, 1, 0), 40, 32, math.radians(55), name=f"c{k}"
        )
        for k, a in enumerate(RING_ANGLES)
    ]
    return g, cams


def _result(per_probe: np.ndarray, directions=("-x", "+x")):
    return SimpleNamespace(
        divergence=per_probe.max(0),
        divergence_mean=per_probe.mean(0),
        per_probe=per_probe,
        directions=list(directions),
        warnings={},
    )


def test_metric_values_pick_the_probe_or_the_combination():
    per_probe = np.array([[1.0, 0.0, 4.0], [3.0, 2.0, 0.0]])
    result = _result(per_probe)
    assert metric_values(result, "max").tolist() == [3.0, 2.0, 4.0]
    assert metric_values(result, "mean").tolist() == [2.0, 1.0, 2.0]
    assert metric_values(result, "+x").tolist() == [3.0, 2.0, 0.0]
    with pytest.raises(ValueError, match=r"--metric -z: the result has no probe -z \(it has -x,\+x\)"):
        metric_values(result, "-z")
    zero = _result(np.zeros((2, 3)))
    zero.warnings = {"-x": ["no Gaussian was reached"]}
    with pytest.raises(ValueError, match="is 0 for every one of the 3 Gaussians.*probe -x: no Gaussian was reached"):
        check_some_divergence(zero, "max", "r.h5")
    assert check_some_divergence(result, "mean", "r.h5").tolist() == [2.0, 1.0, 2.0]


def test_cameras_that_see_nothing_are_refused_or_warned(caplog):
    g, cams = _scene()
    away = Camera.look_at((0, 0, 3), (0, 0, 6), (0, 1, 0), 40, 32, math.radians(50), name="away")
    counts = check_cameras_see(g, [*cams, away], [c.name for c in [*cams, away]])
    assert counts[-1] == 0 and (counts[:-1] > 0).all() and "camera away sees no Gaussian" in caplog.text
    with pytest.raises(ValueError, match="none of the 1 candidate cameras sees any Gaussian"):
        check_cameras_see(g, [away], ["away"])


def test_render_size_caps_the_width_only():
    cam = Camera.look_at((0, 0, -3), (0, 0, 0), (0, -1, 0), 800, 600, math.radians(50))
    small = render_size(cam, 320)
    assert (small.width, small.height) == (320, 240) and small.fx == pytest.approx(cam.fx * 0.4)
    assert render_size(small, 320) is small
    with pytest.raises(ValueError, match="--render-width must be >= 8"):
        render_size(cam, 4)


def test_score_rows_are_the_projected_scores_best_first():
    g, cams = _scene()
    metric = np.random.default_rng(3).uniform(0, 5, g.num)
    rows = score_views(
        g,
        cams,
        [7, 8, 9, 10],
        _result(np.stack([metric, metric / 2])),
        "-x",
        None,
        visible_centres=[1, 2, 3, 4],
        progress=False,
    )  # the depth test is the default
    expected = scores.projected_view_scores(torch.from_numpy(metric), g, cams, depth_buffer=scores.DepthBuffer())
    order = scores.rank(expected.scores).tolist()
    assert [r["index"] for r in rows] == [7 + k for k in order] and [r["rank"] for r in rows] == [1, 2, 3, 4]
    assert [r["score"] for r in rows] == pytest.approx(expected.scores[order].tolist(), rel=1e-12)
    assert [r["visible_centres"] for r in rows] == [1 + k for k in order]
    frustum = score_views(
        g, cams, [7, 8, 9, 10], _result(np.stack([metric, metric / 2])), "-x", None, occlusion=False, progress=False
    )
    paper = scores.projected_view_scores(torch.from_numpy(metric), g, cams)
    assert sorted(r["score"] for r in frustum) == pytest.approx(sorted(paper.scores.tolist()), rel=1e-12)


def test_rank_views_ranks_as_score_views_and_records_its_settings():
    g, cams = _scene()
    metric = np.random.default_rng(4).uniform(0, 5, g.num)
    result = SimpleNamespace(**vars(_result(np.stack([metric, metric / 2]))), replicas=None, dbar=1.5, dbar_empty=0.5)
    result.config = SimpleNamespace(to_dict=lambda: {"steps": 3})
    settings = ScoreSettings("-x", weighted=True, occlusion=False)
    scored, rows, agreement = rank_views(g, cams, [7, 8, 9, 10], result, metric, settings, [1, 2, 3, 4])
    expected = score_views(g, cams, [7, 8, 9, 10], result, "-x", None, occlusion=False, visible_centres=[1, 2, 3, 4])
    assert rows == expected and scored.scores.shape == (4,) and "replicas" not in agreement
    assert write_views_folder(g, cams, scored, rows, metric, settings, None) == ({}, [])  # no views folder
    images = {rows[0]["index"]: {"npy": "a.npy", "png": "a.png"}}
    record = scores_record(rows, agreement, result, settings, "c.json", "g.ply", images, Path("v"))
    assert list(record) == [
        "cameras",
        "gaussians",
        "metric",
        "weighted",
        "occlusion",
        "dbar_m4_s",
        "dbar_empty_m4_s",
        "agreement",
        "views",
        "config",
    ]
    assert (record["metric"], record["weighted"], record["occlusion"]) == ("-x", True, False)
    assert record["views"][0]["uncertainty_image"] == {"npy": str(Path("v") / "a.npy"), "png": str(Path("v") / "a.png")}
    assert all("uncertainty_image" not in r for r in rows + record["views"][1:])  # the rows themselves are unchanged


def test_stale_view_files_are_the_unrewritten_ones_of_the_naming_pattern(tmp_path):
    for name in ("rank001_002_a.png", "rank002_000_b_uncertainty.npy", "notes.png", "rank1_2_c.png"):
        (tmp_path / name).write_bytes(b"x")
    earlier = view_files(tmp_path)
    assert sorted(p.name for p in earlier) == ["rank001_002_a.png", "rank002_000_b_uncertainty.npy"]
    fresh = tmp_path / "new.png"
    fresh.write_bytes(b"y")
    fresh.replace(tmp_path / "rank001_002_a.png")  # rewritten atomically: a new inode
    assert [p.name for p in remove_stale(earlier)] == ["rank002_000_b_uncertainty.npy"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.png", "rank001_002_a.png", "rank1_2_c.png"]
    assert view_files(tmp_path / "missing") == {}


def test_projection_scores_agree_with_full_renders():
    g, cams = _scene(seed=2)
    d = stand_in_divergence(g.num, seed=4)
    out = compare_with_renders(g, cams, d, occlusion=True, device="cpu")
    assert out["views"] == 4 and out["radii_equal"] and out["identical_order"]
    assert out["max_relative_difference"] < 1e-9 and out["spearman"] == pytest.approx(1.0)
    occ = out["occlusion"]
    assert 0.5 < occ["verdict_agreement"] <= 1.0 and 0 <= occ["hidden_coarse"] < 1 and 0 <= occ["top5_overlap"] <= 4
    assert spearman([1, 2, 3], [3, 2, 1]) == pytest.approx(-1.0)


def test_stand_in_metric_is_seeded_log_normal():
    a, b = stand_in_divergence(20000, 1), stand_in_divergence(20000, 1)
    assert np.array_equal(a, b) and not np.array_equal(a, stand_in_divergence(20000, 2))
    assert np.log(a).mean() == pytest.approx(0.0, abs=0.03) and np.log(a).std() == pytest.approx(1.0, abs=0.03)
    g, _ = _scene(50)
    d, source = load_divergence(None, g, 1)
    assert len(d) == 50 and "stand-in (seed 1)" in source


def test_jittered_to_count_repeats_and_moves_by_the_largest_radius():
    g, _ = _scene(200, seed=5)
    big = jittered_to_count(g, 1050, seed=3)
    assert big.num == 1050 and torch.equal(big.means[:200], g.means)
    index = torch.arange(1050) % 200
    for name in ("quats", "log_scales", "opacity_logits", "sh"):
        assert torch.equal(getattr(big, name), getattr(g, name)[index])
    offsets = (big.means[200:] - g.means[index[200:]]).double() / g.max_radii()[index[200:], None].double()
    assert offsets.std().item() == pytest.approx(1.0, abs=0.06) and abs(offsets.mean().item()) < 0.06
    assert torch.equal(jittered_to_count(g, 1050, seed=3).means, big.means)
    assert jittered_to_count(g, 50, seed=0).num == 50
    with pytest.raises(ValueError, match="--count must be >= 1"):
        jittered_to_count(g, 0, seed=0)


def test_to_bgr_and_label():
    rgb = np.zeros((10, 16, 3), np.float32)
    rgb[..., 0] = 1.0  # red
    rgb[0, 0] = (2.0, -1.0, 0.5)  # clipped to (1, 0, 0.5)
    bgr = to_bgr(rgb, min_width=40)
    assert bgr.shape == (30, 48, 3) and bgr.dtype == np.uint8  # enlarged x3 (nearest)
    assert bgr[5, 5].tolist() == [0, 0, 255] and bgr[0, 0].tolist() == [128, 0, 255]
    assert to_bgr(rgb, min_width=16).shape == (10, 16, 3)
    with pytest.raises(ValueError, match=r"\[H, W, 3\]"):
        to_bgr(np.zeros((4, 4)))
    canvas = np.full((60, 200, 3), 100, np.uint8)
    out = label(canvas, ["#1 view", "S = 2"])
    assert out is canvas and (canvas[:45, :60] == 255).any() and (canvas[:45, :60] == 0).any()
    assert (canvas[50:, :] == 100).all()  # only the corner is written


def test_format_table_lists_the_best_rows_with_their_parts():
    rows = [
        {
            "rank": 1,
            "index": 7,
            "name": "a_very_long_camera_name_cut_at_24",
            "score": 0.000123456,
            "visible": 12,
            "coverage": 0.5,
            "coverage_rank": 2,
            "physics_mean": 0.000246912,
            "physics_rank": 1,
        },
        {"rank": 2, "index": 3, "name": "b", "score": 5.0, "visible": 0},
    ]
    lines = format_table(rows).splitlines()
    assert lines[0].split() == ["rank", "index", "name", "S", "A", "A#", "S/A", "S/A#", "visible"]
    assert len(lines) == 3
    assert lines[1].split() == ["1", "7", "a_very_long_camera_name_", "0.00012", "0.5", "2", "0.00025", "1", "12"]
    assert lines[2].split() == ["2", "3", "b", "5", "-", "-", "-", "-", "0"]  # rows without parts
    assert format_table(rows, top_k=1).count("\n") == 1
    rows[0]["critical_score"] = 2.5
    assert format_table(rows[:1], value="critical_score").splitlines()[1].split()[3] == "2.5"
