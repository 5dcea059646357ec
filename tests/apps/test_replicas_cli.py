"""`--replicas N` on simulate, score and critical: the agreement in the JSON and the printed line, and bad input."""

import json
import math

import h5py
import numpy as np
import pytest
import torch

from apps import cli
from recon.formats.ply import save_gaussians
from recon.gaussians import GaussianSet

FAST = ["--particle-radius", "0.08", "--steps", "40", "--dt", "0.004", "--no-empty-reference", "--threads", "2"]


@pytest.fixture(scope="module")
def ply(tmp_path_factory):
    n = 300
    i = np.arange(n) + 0.5
    phi, th = np.arccos(1 - 2 * i / n), math.pi * (1 + 5**0.5) * i
    pts = np.stack([np.cos(th) * np.sin(phi), np.cos(phi), np.sin(th) * np.sin(phi)], 1) * 0.5
    g = GaussianSet.from_points(torch.tensor(pts, dtype=torch.float32), scale=0.06, opacity=0.9)
    return save_gaussians(g, tmp_path_factory.mktemp("replicas") / "sphere.ply")


def test_score_reports_the_replicas_agreement(ply, tmp_path, capsys):
    out, h5 = tmp_path / "s.json", tmp_path / "r.h5"
    args = ["score", str(ply), "--cameras", "orbit:6", "-o", str(out), "--no-png", "--directions=-x,+z"]
    assert cli.main([*args, "--replicas", "2", "--save-result", str(h5), *FAST]) == 0
    printed = capsys.readouterr().out
    rep = json.loads(out.read_text())["agreement"]["replicas"]
    assert rep["count"] == 2 and rep["offsets"][0] == [0.0, 0.0, 0.0]
    line = next(x for x in printed.splitlines() if x.startswith("replicas: 2 shifted lattices"))
    # the printed line is the JSON's, each figure named: the ranking S(T), its physics part S/A, D_g per Gaussian
    assert f"the view ranking S(T) {rep['spearman_views_mean']:.2f}" in line
    assert f"its physics part S/A {rep['spearman_physics_mean']:.2f}" in line
    assert f"D_g per Gaussian {rep['spearman_gaussians_mean']:.2f}" in line
    assert -1.0 <= rep["spearman_gaussians_min"] <= rep["spearman_gaussians_mean"] <= 1.0
    with h5py.File(h5, "r") as f:
        assert f["replicas/D"].shape == (2, 2, 300)
    # the saved result gives the same agreement again
    again = tmp_path / "again.json"
    assert cli.main([*args[:5], str(again), "--no-png", "--result", str(h5)]) == 0
    assert json.loads(again.read_text())["agreement"]["replicas"] == rep
    capsys.readouterr()
    assert cli.main([*args, *FAST]) == 0  # one run: a note instead of the figures, no replicas entry
    printed = capsys.readouterr().out
    assert "replicas: 1 lattice position" in printed and "shifted lattices, S(T)" not in printed
    assert "replicas" not in json.loads(out.read_text())["agreement"]


def test_critical_and_simulate_take_replicas(ply, tmp_path, capsys):
    out = tmp_path / "c.json"
    assert cli.main(["critical", str(ply), "--cameras", "orbit:6", "-o", str(out), "--replicas", "2", *FAST]) == 0
    assert json.loads(out.read_text())["agreement"]["replicas"]["count"] == 2
    assert "replicas: 2 shifted lattices, C(T) from their mean" in capsys.readouterr().out
    h5 = tmp_path / "sim.h5"
    assert cli.main(["simulate", str(ply), "-o", str(h5), "--directions=-x", "--replicas", "2", *FAST]) == 0
    assert "their D_g agree at Spearman" in capsys.readouterr().out


@pytest.mark.parametrize("command", ["simulate", "score", "critical"])
@pytest.mark.parametrize("value", ["0", "-1"])
def test_replicas_below_one_exit_2_naming_the_option(ply, tmp_path, caplog, command, value):
    out = tmp_path / ("r.h5" if command == "simulate" else "s.json")
    cams = [] if command == "simulate" else ["--cameras", "orbit:6"]
    assert cli.main([command, str(ply), *cams, "-o", str(out), "--replicas", value, *FAST]) == 2
    assert "--replicas" in caplog.text and "probe -x" not in caplog.text
    assert not out.exists()


def test_too_many_replicas_for_memory_exit_2_before_any_probe(ply, tmp_path, caplog):
    out = tmp_path / "r.h5"
    code = cli.main(["simulate", str(ply), "-o", str(out), "--replicas", "1000000000", "--max-memory-gb", "1", *FAST])
    assert code == 2
    assert "--replicas 1000000000 is too many" in caplog.text and not out.exists()
