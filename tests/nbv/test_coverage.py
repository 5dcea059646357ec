"""Coverage beside S(T): A(T) is S(T) with M_g = 1 over the same counted Gaussians, P(T) = S / A, the agreement of
the S and A rankings and its one printed line; the physics-uncertainty image of a view."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from nbv import scores
from nbv.coverage import (
    agreement_lines,
    coverage_line,
    format_number,
    ranking_agreement,
    view_parts,
)
from nbv.heatmap import over_range_marks, uncertainty_image, uncertainty_png, unreached_pixels
from recon.camera import Camera
from recon.gaussians import GaussianSet, concat
from viz.colors import UNREACHED_RGB

from helpers.random_scenes import random_scene


def _scene(n: int = 300, seed: int = 0):
    return random_scene(n, seed)


@pytest.mark.parametrize("occlusion", [False, True])
@pytest.mark.parametrize("weighted", [True, False])
def test_coverage_is_the_score_of_ones_over_the_same_counted_gaussians(occlusion, weighted):
    g, cams, metric = _scene()
    buffer = scores.DepthBuffer() if occlusion else None
    scored = scores.projected_view_scores(metric, g, cams, weighted=weighted, depth_buffer=buffer)
    ones = scores.projected_view_scores(
        torch.ones(g.num, dtype=torch.float64), g, cams, weighted=weighted, depth_buffer=buffer
    )
    assert torch.allclose(scored.coverage, ones.scores, rtol=1e-12, atol=0)
    assert torch.equal(scored.counted, ones.counted)
    if not weighted:
        assert scored.coverage.tolist() == scored.counted.double().tolist()
    # S = A P, P the area-weighted mean of M over what the view counts: between the smallest and largest M
    assert torch.allclose(scored.physics_mean * scored.coverage, scored.scores, rtol=1e-12, atol=0)
    assert (scored.physics_mean >= 0).all() and (scored.physics_mean <= metric.max()).all()
    # a constant metric c gives P = c in every view that counts anything
    const = scores.projected_view_scores(
        torch.full((g.num,), 2.5, dtype=torch.float64), g, cams, weighted=weighted, depth_buffer=buffer
    )
    assert torch.allclose(const.physics_mean, torch.full((len(cams),), 2.5, dtype=torch.float64), rtol=1e-12)
    # seen: the union of what the views count (a metric that is 1 only off the union scores 0 everywhere)
    assert scored.seen.shape == (g.num,) and scored.seen.any()
    off = scores.projected_view_scores((~scored.seen).double(), g, cams, weighted=weighted, depth_buffer=buffer)
    assert off.scores.abs().max() == 0


def test_view_parts_ranks_each_part():
    parts = view_parts([6.0, 4.0, 3.0, 0.0], [3.0, 1.0, 3.0, 0.0])
    assert [p["rank"] for p in parts] == [1, 2, 3, 4]
    assert [p["coverage_rank"] for p in parts] == [1, 3, 2, 4]
    assert [p["physics_mean"] for p in parts] == [2.0, 4.0, 1.0, None]  # no coverage: no physics part
    assert [p["physics_rank"] for p in parts] == [2, 1, 3, None]
    with pytest.raises(ValueError, match="3 scores against 2"):
        view_parts([1, 2, 3], [1, 2])


def test_agreement_when_coverage_decides_and_when_physics_does():
    cover = np.arange(1.0, 11.0)
    same = ranking_agreement(cover * 3.0, cover)  # a constant physics part: S is coverage
    assert same["spearman_score_coverage"] == pytest.approx(1.0) and same["coverage_decides"]
    assert same["top5_overlap_with_coverage"] == 5 and same["top5_changed_by_physics"] == 0
    assert same["physics_mean_spread"] == pytest.approx(0.0, abs=1e-12)
    line = coverage_line(same)
    assert line.startswith("coverage decides the ranking at this setting") and "Spearman 1.00 over 10 views" in line
    flipped = ranking_agreement(cover * (11.0 - cover) ** 2, cover)  # the physics part reverses the order
    assert not flipped["coverage_decides"] and flipped["spearman_score_coverage"] < 0.9
    # S's top five are views 1-5 (0-based 0..4: the largest (11 - a)^2 a), coverage's are 6-10: all five changed
    top_s = set(np.argsort(-(cover * (11.0 - cover) ** 2))[:5])
    assert flipped["top5_overlap_with_coverage"] == len(top_s & {5, 6, 7, 8, 9})
    assert coverage_line(flipped).startswith(f"the physics changed {flipped['top5_changed_by_physics']} of the top 5")
    assert agreement_lines(flipped) == [coverage_line(flipped)]
    few = ranking_agreement([1.0, 2.0], [1.0, 2.0])
    assert few["spearman_score_coverage"] is None and few["top"] == 2 and "cannot say" in coverage_line(few)


def test_format_number_gives_two_significant_digits():
    assert [format_number(v) for v in (364.8, 4.866, 0.0123, 1.26e-6, 5.0, None)] == [
        "360",
        "4.9",
        "0.012",
        "1.3e-06",
        "5",
        "-",
    ]


def _blob(value: float, x: float) -> GaussianSet:
    return GaussianSet.from_points(torch.tensor([[x, 0.0, 0.0]], dtype=torch.float64), scale=0.15, opacity=0.8)


def test_uncertainty_image_of_a_constant_is_that_constant_times_alpha():
    g, cams, _ = _scene(150, seed=3)
    for cam in cams[:2]:
        img, alpha = uncertainty_image(g, cam, np.full(g.num, 3.7))
        assert img.shape == (cam.height, cam.width) and alpha.max() > 0.1
        np.testing.assert_allclose(img, 3.7 * alpha, rtol=1e-5, atol=1e-6)


def _two_blobs():
    """A 64x48 camera 3 m out on -z, upside down, and two opaque blobs left and right of its axis."""
    cam = Camera.look_at((0, 0, -3.0), (0, 0, 0), (0, -1, 0), 64, 48, 0.9)
    return cam, _blob(1.0, -0.6), _blob(1.0, 0.6)


def test_uncertainty_image_shows_a_gaussians_own_value_where_it_is_drawn():
    cam, left, right = _two_blobs()
    both = concat([left, right])
    img, alpha = uncertainty_image(both, cam, np.array([0.0, 8.0]))
    _, alpha_right = uncertainty_image(right, cam, np.array([1.0]))
    np.testing.assert_allclose(img, 8.0 * alpha_right, rtol=1e-5, atol=1e-6)  # only the right blob's pixels
    u_r, v_r = (int(t) for t in cam.project(right.means)[0][0].floor())
    u_l, v_l = (int(t) for t in cam.project(left.means)[0][0].floor())
    assert img[v_r, u_r] == pytest.approx(8.0 * alpha[v_r, u_r], rel=1e-5) and img[v_r, u_r] > 4.0
    assert img[v_l, u_l] == 0.0 and alpha[v_l, u_l] > 0.5
    with pytest.raises(ValueError, match="1 values for 2 Gaussians"):
        uncertainty_image(both, cam, np.array([1.0]))
    with pytest.raises(ValueError, match="finite and >= 0"):
        uncertainty_image(both, cam, np.array([1.0, -1.0]))


def test_uncertainty_png_marks_what_lies_above_the_range():
    img = np.zeros((40, 40), np.float32)
    img[:, 20:] = 5.0  # right half above the range 0..2
    png = uncertainty_png(img, 2.0, "1/s")
    assert png.shape[0] == 40 and png.shape[1] > 40 and png.dtype == np.uint8
    white = (png[:, :40] == 255).all(axis=2)
    assert white[:, 20:].any() and not white[:, :17].any()  # "+" marks (2 px arms) on the clipped half only
    marked = over_range_marks(np.zeros((16, 16, 3), np.uint8), np.ones((16, 16), bool), step=8)
    assert (marked == 255).any()
    with pytest.raises(ValueError, match="differ"):
        over_range_marks(np.zeros((16, 16, 3), np.uint8), np.ones((8, 8), bool))


def test_the_uncertainty_colour_bar_reads_values_at_every_tick():
    import cv2

    from nbv.heatmap import _side_colorbar

    def text_rows(img):  # the rows of the tick column with dark text pixels
        ink = (img[:, 30:] < 100).all(axis=2)
        return np.flatnonzero(ink.any(axis=1))

    bar = _side_colorbar(200, 110, 8.0, "1/s", over=True)
    rows = text_rows(bar)
    assert rows.min() < 15 and rows.max() > 185 and ((rows > 90) & (rows < 110)).any()  # top, middle, bottom ticks
    middle = np.full((20, 80, 3), 255, np.uint8)
    cv2.putText(middle, "4", (0, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 0, 0), 1, cv2.LINE_AA)
    unit = np.full((20, 80, 3), 255, np.uint8)
    cv2.putText(unit, "1/s", (0, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 0, 0), 1, cv2.LINE_AA)
    tick = bar[100 - 10 : 100 + 10, 29:109]  # the middle tick is the value vmax / 2, not the unit
    assert np.abs(tick.astype(int) - middle).mean() < np.abs(tick.astype(int) - unit).mean()


def test_small_views_are_enlarged_for_their_labels():
    from nbv.view_scoring import enlarged

    small = np.arange(64 * 48, dtype=np.float32).reshape(48, 64)
    big = enlarged(small)
    assert big.shape == (48 * 5, 64 * 5) and (big[::5, ::5] == small).all()  # nearest: every pixel one value
    assert enlarged(np.zeros((10, 400))).shape == (10, 400)


def test_uncertainty_pictures_draw_the_unreached_grey():
    # U is 0 under an unreached Gaussian as under a calm one; the picture tells them apart
    cam, left, right = _two_blobs()
    both = concat([left, right])
    grey = unreached_pixels(both, cam, np.array([True, False]))  # the right one was never reached
    u_r, v_r = (int(t) for t in cam.project(right.means)[0][0].floor())
    u_l, v_l = (int(t) for t in cam.project(left.means)[0][0].floor())
    assert grey[v_r, u_r] and not grey[v_l, u_l] and not grey[0, 0]  # the background is not grey
    img, _ = uncertainty_image(both, cam, np.array([0.0, 0.0]))
    png = uncertainty_png(img, 2.0, "1/s", grey)
    np.testing.assert_array_equal(png[v_r, u_r], np.round(np.float32(UNREACHED_RGB)[::-1] * 255).astype(np.uint8))
    assert (png[v_l, u_l] != png[v_r, u_r]).any()  # calm: dark blue
    with pytest.raises(ValueError, match="unreached"):
        uncertainty_png(img, 2.0, "1/s", grey[:4])


@pytest.mark.parametrize(
    "argv, option",
    [
        (["score", "g.ply", "--cameras", "c.json", "-o", "s.json", "--uncertainty-images", "--no-png"], "--no-png"),
        (["score", "g.ply", "--cameras", "c.json", "-o", "s.json", "--frustum-only", "--occlusion"], "--frustum-only"),
        (["critical", "g.ply", "--cameras", "c.json", "--frustum-only", "--occlusion"], "--frustum-only"),
    ],
)
def test_contradictory_options_exit_2_before_any_file_is_read(argv, option, tmp_path, monkeypatch, caplog):
    from apps.cli import main

    monkeypatch.chdir(tmp_path)  # none of the named files exists: the check comes first
    assert main(argv) == 2
    assert option in caplog.text and "drop" in caplog.text and "does not exist" not in caplog.text
