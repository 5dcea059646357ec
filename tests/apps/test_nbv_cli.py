"""Smoke tests of `fluidgs simulate | score | critical | sweep | bench score` on a tiny sphere, and bad input."""

import csv
import json
import math
import re
import time

import h5py
import numpy as np
import pytest
import torch

from apps import cli
from nbv.physics import load_result
from recon.camera import Camera
from recon.camera_files import load_camera_file
from recon.formats import load_gaussians
from recon.formats.ply import save_gaussians
from viz.video import video_info

from helpers.cameras import ring_cameras, write_transforms
from helpers.spheres import sphere_gaussians

FAST = ["--particle-radius", "0.08", "--steps", "40", "--dt", "0.004", "--no-empty-reference", "--threads", "2"]


FOV = math.radians(50)


def _run_on(scene: dict, command: str, *args: str) -> int:
    """``fluidgs COMMAND`` on the module's Gaussians and cameras, with ``args``; the exit code."""
    return cli.main([command, str(scene["ply"]), "--cameras", str(scene["cameras"]), *args])


def _write_cameras(path, cams, width=48, height=40, fov=FOV):
    return write_transforms(path, cams, width, height, fov)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("nbv_cli")
    ply = save_gaussians(sphere_gaussians(), root / "sphere.ply")
    cams = ring_cameras(6)
    cameras = _write_cameras(root / "transforms.json", cams)
    h5 = root / "result.h5"
    video = ["--video=-x", "--walls", "faint", "--width", "320", "--height", "240"]
    assert cli.main(["simulate", str(ply), "-o", str(h5), "--directions=-x,+z", *video, *FAST]) == 0
    return dict(root=root, ply=ply, cameras=cameras, h5=h5)


def test_simulate_outputs(scene):
    res = load_result(scene["h5"])
    assert res.directions == ("-x", "+z") and res.per_probe.shape == (2, 300)
    assert res.divergence.max() > 0
    colored = load_gaussians(scene["root"] / "result_divergence.ply")
    assert colored.sh_degree == 0 and colored.num == 300
    torch.testing.assert_close(colored.means, sphere_gaussians().means)
    # colours follow D_g: the Gaussian with the largest D_g is not coloured like one with D_g = 0
    hi, lo = int(np.argmax(res.divergence)), int(np.argmin(res.divergence))
    assert (colored.sh[hi, 0] - colored.sh[lo, 0]).abs().max() > 0.5
    info = video_info(scene["root"] / "result_probe-x.mp4")  # --video takes render-frames' drawing options
    assert (info.width, info.height) == (320, 240) and info.frames >= 2


def test_simulate_prints_d_to_the_digits_a_rerun_reproduces(scene, capsys):
    """D_g and D-bar move by up to tens of per cent when only the float roundings change (docs/performance.md, "The
    answer's rounding floor"): two significant digits, not four."""
    from apps.simulate import print_result

    print_result(load_result(scene["h5"]))
    text = capsys.readouterr().out
    figures = re.findall(r"mean D_g (\S+) 1/s, max (\S+) 1/s", text)
    dbar = re.search(r"D-bar (\S+) m\^4/s \(mean-combined (\S+); empty scene (\S+)\)", text)
    assert len(figures) == 2 and dbar, text
    values = [v for pair in figures for v in pair] + [dbar[1], dbar[2]] + ([] if dbar[3] == "n/a" else [dbar[3]])
    for v in values:
        mantissa = v.lower().split("e")[0].replace("-", "").replace(".", "").lstrip("0")
        assert 1 <= len(mantissa) <= 2, (v, text)
    assert "D_g per Gaussian repeats at Spearman" in text and "--replicas 2" in text  # no replicas: how noisy it is


def test_score_writes_its_orbit_beside_the_scores(scene, tmp_path):
    out = tmp_path / "s.json"
    assert (
        cli.main(["score", str(scene["ply"]), "--result", str(scene["h5"]), "--cameras", "orbit:4", "-o", str(out)])
        == 0
    )
    scores = json.loads(out.read_text())
    assert len(load_camera_file(tmp_path / "s_cameras.json")) == 4 == len(scores["views"])  # for `fluidgs view`


def test_score_ranks_views(scene, tmp_path):
    out = tmp_path / "scores.json"
    assert _run_on(scene, "score", "--result", str(scene["h5"]), "-o", str(out), "--top-k", "3") == 0
    data = json.loads(out.read_text())
    views = data["views"]
    assert [v["rank"] for v in views] == list(range(1, 7))
    assert all(a["score"] >= b["score"] for a, b in zip(views, views[1:], strict=False))
    assert sorted(v["index"] for v in views) == list(range(6)) and views[0]["score"] > 0
    pngs = sorted(p.name for p in (tmp_path / "scores_views").glob("rank*.png"))  # the best 5 (--png-top 5)
    assert [p[:7] for p in pngs] == [f"rank{r:03d}" for r in range(1, 6)]
    # a subset keeps the camera indices of the file, and the same scores
    out2 = tmp_path / "subset.json"
    assert (
        _run_on(
            scene,
            "score",
            "--result",
            str(scene["h5"]),
            "-o",
            str(out2),
            "--candidates",
            "1,4",
            "--no-png",
            "--export-solid",
            str(tmp_path / "solid.h5"),
        )
        == 0
    )
    with h5py.File(tmp_path / "solid.h5") as f:  # --export-solid writes the solid stored in RESULT.h5
        assert int(f["occupancy"][()].sum()) == len(load_result(scene["h5"]).solid)
    sub = {v["index"]: v["score"] for v in json.loads(out2.read_text())["views"]}
    full = {v["index"]: v["score"] for v in views}
    assert set(sub) == {1, 4} and all(sub[k] == pytest.approx(full[k]) for k in sub)


def test_score_simulates_without_result(scene, tmp_path):
    out = tmp_path / "s.json"
    assert (
        _run_on(
            scene,
            "score",
            "-o",
            str(out),
            "--no-png",
            "--directions=-x",
            "--occlusion",
            "--save-result",
            str(tmp_path / "r.h5"),
            *FAST,
        )
        == 0
    )
    assert json.loads(out.read_text())["occlusion"] is True
    assert load_result(tmp_path / "r.h5").directions == ("-x",)


def test_critical_subset(scene, tmp_path, caplog):
    out = tmp_path / "critical.json"
    assert (
        _run_on(scene, "critical", "-o", str(out), "--subset", "4", "--save-result", str(tmp_path / "c.h5"), *FAST) == 0
    )
    data = json.loads(out.read_text())
    assert data["directions"] == ["-x"] and data["distinct_particles"]["gaussians_reached"] > 0
    assert data["critical_subset"] == [v["index"] for v in data["views"][:4]]
    assert data["views"][0]["critical_score"] >= data["views"][-1]["critical_score"]
    # 4 of 6 candidates is half or more: a warning, logged and stored
    assert "4 of the 6 candidate views" in caplog.text and "4 of the 6" in data["subset_warning"]
    # --result reuses the saved run: the same C(T), and 2 of 6 warns of nothing
    again = tmp_path / "again.json"
    caplog.clear()
    assert _run_on(scene, "critical", "-o", str(again), "--subset", "2", "--result", str(tmp_path / "c.h5")) == 0
    second = json.loads(again.read_text())
    assert [v["critical_score"] for v in second["views"]] == [v["critical_score"] for v in data["views"]]
    assert second["subset_warning"] is None and "candidate views" not in caplog.text
    # a RESULT.h5 without distinct counts (simulate's) is exit 2, naming the fix
    assert _run_on(scene, "critical", "-o", str(again), "--result", str(scene["h5"])) == 2
    assert "--save-result" in caplog.text


def test_sweep_csv_and_plot(scene, tmp_path, capsys, caplog):
    out = tmp_path / "sweep.csv"
    assert (
        cli.main(
            [
                "sweep",
                str(scene["ply"]),
                "--velocities",
                "3,6",
                "--directions=-x",
                "-o",
                str(out),
                "--compare",
                str(scene["ply"]),
                *[a for a in FAST if a != "--no-empty-reference"],
            ]
        )
        == 0
    )
    rows = list(csv.DictReader(out.open()))
    assert [r["steps"] for r in rows] == ["40", "80"]
    assert float(rows[0]["gap_m4_s"]) == pytest.approx(0.0, abs=1e-12)  # OTHER = the same set
    assert out.with_suffix(".png").stat().st_size > 0
    # the empty scene's column, and L = the object's extent along the flow, stored and printed
    assert all(float(r["dbar_empty_m4_s"]) >= 0 for r in rows) and rows[0]["re_length_from"] == "object"
    text = capsys.readouterr().out
    # the upfront estimate: -x and its empty scene and OTHER: 3 x 40 probe-steps at 3 m/s, 3 x 80 at 6 m/s
    assert "360 probe-steps" in text and text.index("estimate:") < text.index("took ", text.index("estimate:"))
    assert f"L = {float(rows[0]['re_length_m']):.4g} m (the object's extent along the flow of probe -x)" in text
    # C_d of the flow probe: a column, a table column, and its plot against Re beside the CSV
    assert all(r["drag_probe"] == "-x" and math.isfinite(float(r["C_d"])) and float(r["C_d"]) > 0 for r in rows)
    assert "C_d = 2 F / (rho U^2 A) of probe -x" in text and " C_d " in text
    assert (tmp_path / "sweep_cd.png").stat().st_size > 0 and f"C_d plot: {tmp_path / 'sweep_cd.png'}" in text
    t0 = time.perf_counter()
    assert cli.main(["sweep", str(scene["ply"]), "--re-length", "0", "-o", str(tmp_path / "x.csv"), *FAST]) == 2
    assert "--re-length" in caplog.text and time.perf_counter() - t0 < 20


def test_bench_score_prints_share(scene, capsys):
    assert (
        cli.main(
            [
                "bench",
                "score",
                "--gaussians",
                str(scene["ply"]),
                "--particle-radius",
                "0.08",
                "--steps",
                "20",
                "--directions=-x",
            ]
        )
        == 0
    )
    text = capsys.readouterr().out
    assert "aggregation share of the step time" in text and "fluid particles" in text
    assert "(target < 10 % at " in text  # a small set: the 10 % target, not the million-Gaussian one
    assert "view ranking at r = 0.08 m x 20 steps: NOT converged (needs >= 750 steps)" in text
    assert "one physics pick at this setting costs" in text
    # one probe: the per-probe time is the whole probe time; the GPU target is stated only at the paper setting
    total = float(text.split("quick total for 1 probes: ")[1].split(" s")[0])
    assert f"per probe: {total:.1f} s\n" in text and "H200" not in text


def test_bench_score_share_target_by_set_size():
    from nbv.bench.probe_timing import MILLION_GAUSSIANS, share_target

    assert share_target(MILLION_GAUSSIANS - 1) == 0.10
    assert share_target(MILLION_GAUSSIANS) == share_target(5_000_000) == 0.15


def test_bad_inputs_fail_early(scene, tmp_path, caplog):
    not_3dgs = tmp_path / "points.ply"
    not_3dgs.write_text(
        "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
        "property float z\nend_header\n0 0 0\n"
    )
    assert cli.main(["simulate", str(not_3dgs), "-o", str(tmp_path / "a.h5"), *FAST]) == 2
    away = [Camera.look_at((0, 0, 3), (0, 0, 6), (0, 1, 0), 48, 40, math.radians(50), name="away")]
    cams_away = _write_cameras(tmp_path / "away.json", away)
    caplog.clear()
    assert (
        cli.main(["score", str(scene["ply"]), "--cameras", str(cams_away), "-o", str(tmp_path / "s.json"), *FAST]) == 2
    )
    assert "sees any Gaussian" in caplog.text
    blocker = tmp_path / "blocker"
    blocker.write_text("a file, not a folder")
    assert cli.main(["simulate", str(scene["ply"]), "-o", str(blocker / "r.h5"), *FAST]) == 4  # an output error
    caplog.clear()
    assert (
        cli.main(
            [
                "simulate",
                str(scene["ply"]),
                "-o",
                str(tmp_path / "big.h5"),
                "--particle-radius",
                "0.002",
                "--steps",
                "5",
                "--no-empty-reference",
            ]
        )
        == 2
    )
    assert "GiB" in caplog.text and "particle radius" in caplog.text
    assert not (tmp_path / "big.h5").exists()
    assert (
        _run_on(scene, "score", "--result", str(scene["h5"]), "-o", str(tmp_path / "x.json"), "--candidates", "9") == 2
    )


def test_demo_runs_on_given_gaussians(scene, tmp_path):
    out = tmp_path / "demo"
    assert (
        cli.main(
            [
                "demo",
                "-o",
                str(out),
                "--gaussians",
                str(scene["ply"]),
                "--cameras",
                str(scene["cameras"]),
                "--particle-radius",
                "0.08",
                "--steps",
                "20",
                "--no-video",
                "--threads",
                "2",
            ]
        )
        == 0
    )
    summary = json.loads((out / "summary.json").read_text())
    assert summary["gaussians"] == 300 and set(summary["probes"]) == {"-x", "+x", "-z", "+z", "-y"}
    assert len(json.loads((out / "scores.json").read_text())["views"]) == 6
    assert (out / "gaussians_divergence.ply").is_file() and len(list((out / "views").glob("*.png"))) == 5  # top 5
    import cv2

    view = cv2.imread(str(sorted((out / "views").glob("*.png"))[0]))
    # the 64 px cameras are rendered at --render-width (240; each panel then doubled to >= 320 px), not at 64 px
    # enlarged 5x into a blur
    assert view.shape[1] == 2 * 2 * 240
