"""Tests for viz/plots.py (matplotlib charts): each PNG exists, has the requested size, and shows its series in
their colours on the white background; bad input raises naming the file; the sweep and experiment callers."""

from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from viz.plots import PALETTE, bar_chart, plot_drag_coefficient, plot_sweep


def _pixels_near(image_bgr: np.ndarray, hex_rgb: str, tol: int = 30) -> int:
    rgb = np.array([int(hex_rgb[i : i + 2], 16) for i in (1, 3, 5)])
    return int((np.abs(image_bgr[..., ::-1].astype(int) - rgb).max(axis=-1) <= tol).sum())


def _read(path) -> np.ndarray:
    image = cv2.imread(str(path))
    assert image is not None, path
    return image


def _check_png(path, width, height):
    image = _read(path)
    assert image.shape == (height, width, 3)
    background = (image == 255).all(axis=-1)
    assert 0.02 < 1 - background.mean() < 0.9  # something drawn, mostly on white
    assert not list(path.parent.glob(".fgs-*"))  # no temporary file left
    return image


def test_sweep_plot_draws_both_series_and_the_table(tmp_path):
    speeds = [3, 4, 5, 10, 20, 50]
    out = plot_sweep(
        tmp_path / "sweep.png",
        speeds,
        [1e-4 * u for u in speeds],
        dbar_other=[1.3e-4 * u for u in speeds],
        reynolds=[1e5 * u for u in speeds],
        dts=[3e-3 / u for u in speeds],
        steps=[40 * u for u in speeds],
        title="D-bar vs U",
    )
    image = _check_png(out, 900, 620)
    assert _pixels_near(image, PALETTE[0]) > 300 and _pixels_near(image, PALETTE[1]) > 300
    single = _check_png(plot_sweep(tmp_path / "one.png", speeds, [2e-4] * len(speeds)), 900, 620)
    assert _pixels_near(single, PALETTE[1]) < 20  # no second series without OTHER


def test_sweep_plot_rejects_bad_input(tmp_path):
    with pytest.raises(ValueError, match="one.png.*speed.*> 0"):
        plot_sweep(tmp_path / "one.png", [0.0, 3.0], [1.0, 2.0])
    with pytest.raises(ValueError, match="dbar needs 2 values"):
        plot_sweep(tmp_path / "one.png", [1.0, 3.0], [1.0])
    with pytest.raises(ValueError, match="dbar must be finite"):
        plot_sweep(tmp_path / "one.png", [1.0, 3.0], [1.0, float("nan")])
    assert list(tmp_path.iterdir()) == []


def test_drag_coefficient_plot_draws_the_points_and_rejects_bad_input(tmp_path):
    out = plot_drag_coefficient(tmp_path / "cd.png", [9e2, 1.8e3, 3.6e3], [1.2, 1.0, 0.9], [3, 6, 12], title="C_d")
    image = _check_png(out, 900, 560)
    assert _pixels_near(image, PALETTE[0]) > 200
    with pytest.raises(ValueError, match="Reynolds.*> 0"):
        plot_drag_coefficient(tmp_path / "bad.png", [0.0, 1e3], [1.0, 1.0], [3, 6])
    with pytest.raises(ValueError, match="drag_coefficients must be finite"):
        plot_drag_coefficient(tmp_path / "bad.png", [1e2, 1e3], [1.0, float("nan")], [3, 6])
    assert not (tmp_path / "bad.png").exists()


def test_bar_chart_bars_whiskers_and_missing_values(tmp_path):
    out = bar_chart(
        tmp_path / "psnr.png",
        ["random", "physics", "reference-4views"],
        [22.0, 24.0, None],
        [0.5, 0.0, None],
        title="test PSNR",
        ylabel="PSNR (dB)",
    )
    image = _check_png(out, 720, 420)
    assert _pixels_near(image, PALETTE[0], 10) > 2000 and _pixels_near(image, PALETTE[1], 10) > 2000
    assert _pixels_near(image, PALETTE[2], 10) == 0  # the missing mean has no bar ("n/a")
    wide = bar_chart(
        tmp_path / "wide.png",
        [f"m{i}" for i in range(20)],
        list(range(20)),
        [1.0] * 20,
        title="D-bar per probe direction",
        ylabel="D-bar (m^4/s)",
        width=1200,
    )
    _check_png(wide, 1200, 420)
    with pytest.raises(ValueError, match="means needs 2 values"):
        bar_chart(tmp_path / "x.png", ["a", "b"], [1.0], [0.0, 0.0], title="t", ylabel="y")


def test_apps_sweep_plot_takes_sweep_points(tmp_path):
    from apps.sweep import plot_sweep as app_plot

    points = [
        SimpleNamespace(
            speed=u,
            dbar=1e-4 * u,
            dbar_other=None,
            reynolds=1e5 * u,
            dt=1e-3 / u,
            steps=40 * u,
            gap=None,
            dbar_empty=1e-5 * u,
        )
        for u in (3, 6)
    ]
    _check_png(app_plot(points, tmp_path / "sweep.png", title="D-bar vs U: x.ply"), 900, 620)


def test_experiment_bar_charts(tmp_path):
    from nbv.study.experiment_config import ExperimentConfig
    from nbv.study.tables import write_tables

    rows = [
        {
            "kind": "method",
            "method": m,
            "scene": "torus",
            "seed": s,
            "psnr": 20.0 + s + (m == "physics"),
            "ssim": 0.8,
            "lpips": 0.2,
            "chamfer": 0.01,
            "dbar": 1e-3 * (1 + s),
            "dbar_empty": 1e-4,
            "critical_psnr": 19.0,
            "critical_dbar": 1e-3,
            "dbar_per_direction": {"-x": 1e-3, "+x": 2e-3},
        }
        for m in ("random", "physics")
        for s in (0, 1)
    ]
    config = ExperimentConfig(scenes=("torus",), methods=("random", "physics"), seeds=(0, 1))
    written = write_tables(rows, config, tmp_path)
    for name in ("psnr.png", "dbar.png", "dbar_direction.png"):
        assert str(tmp_path / "plots" / name) in written["files"]
        _check_png(tmp_path / "plots" / name, 720, 420)
