"""`fluidgs inspect`: the figures, the JSON keys the issue names, the picture, and bad input."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from apps.cli import main
from recon.formats.ply import save_gaussians
from recon.gaussians import GaussianSet

from helpers.paths import BIKER_COMPRESSED_PLY as REAL

KEYS = (
    "format",
    "count",
    "sh_degree",
    "bbox_min",
    "bbox_max",
    "robust_min",
    "robust_max",
    "up",
    "scale_m_per_unit",
    "solid_particles",
)


def _ball(tmp_path: Path, n: int = 3000) -> Path:
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(n, 3))
    pts = pts / np.linalg.norm(pts, axis=1, keepdims=True) * rng.uniform(0, 1, (n, 1)) ** (1 / 3)
    pts = np.vstack([pts * [0.5, 1.0, 0.5] - [0, 3, 0], [[40.0, 0, 0]]])  # a far floater
    g = GaussianSet.from_points(torch.tensor(pts, dtype=torch.float32), scale=0.05, opacity=0.9)
    return save_gaussians(g, tmp_path / "ball.ply")


def test_inspect_writes_the_figures_and_three_views(tmp_path, capsys):
    ply = _ball(tmp_path)
    js, png = tmp_path / "i.json", tmp_path / "i.png"
    assert main(["inspect", str(ply), "--quick", "--up", "-y", "--json", str(js), "--png", str(png)]) == 0
    out = capsys.readouterr().out
    assert "robust box" in out and "solid:" in out
    s = json.loads(js.read_text())
    assert all(k in s for k in KEYS)
    assert s["format"] == "ply" and s["count"] == 3001 and s["sh_degree"] == 0
    assert s["bbox_max"][0] == pytest.approx(40.0)  # the floater widens the raw box ...
    assert s["robust_max"][0] < 0.6  # ... but not the robust one
    assert s["up"] == [0.0, -1.0, 0.0] and s["solid_particles"] > 20
    # the 2-unit tall ellipsoid -> 2 m; its 0.5-99.5 % box is a little shorter (few centres near the poles)
    assert 1.0 < s["scale_m_per_unit"] < 1.15
    image = cv2.imread(str(png))
    assert image is not None and image.shape[1] == 3 * (image.shape[0] - 60)  # three square panels
    # the solid (red) is drawn in every panel
    red = image[..., 2].astype(int) - image[..., 0] > 50
    third = image.shape[1] // 3
    assert all(red[:, k * third : (k + 1) * third].sum() > 50 for k in range(3))


def test_inspect_crop_auto_drops_the_floater(tmp_path, capsys):
    ply = _ball(tmp_path)
    js = tmp_path / "c.json"
    assert main(["inspect", str(ply), "--quick", "--crop", "auto", "--json", str(js)]) == 0
    s = json.loads(js.read_text())
    assert s["kept"] == 3000 and "kept 3,000 of 3,001" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--up", "0,0,0"], "zero vector"),
        (["--up", "w"], "--up"),
        (["--crop", "100,100,100,101,101,101"], "keeps none"),
    ],
)
def test_inspect_bad_options_exit_2_naming_them(tmp_path, caplog, argv, message):
    ply = _ball(tmp_path, 200)
    assert main(["inspect", str(ply), "--quick", *argv]) == 2
    assert message in caplog.text


@pytest.mark.skipif(not REAL.is_file(), reason="the real capture in ../shared/real-splats is not present")
def test_inspect_real_capture_stands_upright(tmp_path):
    js = tmp_path / "b.json"
    assert main(["inspect", str(REAL), "--quick", "--up", "-y", "--json", str(js)]) == 0
    s = json.loads(js.read_text())
    assert s["count"] == 152_746 and s["format"] == "compressed_ply"
    # the feet are at +y in the file; with --up -y the person is about 2 m tall and stands on y = solid min
    assert s["bbox_max"][1] > s["bbox_min"][1] + 3.0
    assert s["object_extent_m"][1] > 1.9
