"""The camera options of score, critical and demo, `fluidgs cameras`, the frame hints and --result's ignored options:
what the commands choose, say and refuse (exit 2 naming the option and the fix), in-process and before any probe."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np
import pytest
import torch

import apps.runtime
from apps import cli
from apps.options import check_up_against_cameras, frame_hint, result_overridden_options
from nbv.orbit import Orbit, orbit_cameras
from nbv.physics import PhysicsConfig
from recon.camera_files import load_camera_file
from recon.formats import load_gaussians
from recon.formats.ply import save_gaussians
from recon.gaussians import GaussianSet


def _ply(tmp_path, n=400):
    rng = np.random.default_rng(1)
    pts = rng.standard_normal((n, 3)) * [0.3, 0.6, 0.3] + [0.2, -1.0, 0.4]
    path = tmp_path / "capture.ply"
    save_gaussians(GaussianSet.from_points(torch.tensor(pts, dtype=torch.float32), scale=0.02, opacity=0.8), path)
    return path


def _run(argv, caplog):
    with caplog.at_level(logging.INFO):
        try:
            code = int(cli.main(argv) or 0)
        except SystemExit as exc:
            code = exc.code
    return code, " ".join(r.getMessage() for r in caplog.records)


class _Stop(RuntimeError):
    pass


@pytest.fixture
def stop_before_probes(monkeypatch):
    """The commands stop where the probes would start (the cameras are chosen and checked by then)."""

    def stop(*args, **kwargs):
        raise _Stop("stopped before the probes")

    monkeypatch.setattr(apps.runtime, "init_taichi", stop)


def test_cameras_command_writes_the_orbit_in_every_format(tmp_path, caplog):
    ply = _ply(tmp_path)
    code, log = _run(
        [
            "cameras",
            str(ply),
            "--orbit",
            "6",
            "--up",
            "-y",
            "--elevations",
            "-10,30",
            "-o",
            str(tmp_path / "cams.json"),
        ],
        caplog,
    )
    assert code == 0, log
    g = load_gaussians(ply)
    want = orbit_cameras(g, PhysicsConfig(up="-y"), Orbit(6, elevations_deg=(-10.0, 30.0)))
    for fmt, out in (
        ("transforms", tmp_path / "cams.json"),
        ("graphdeco", tmp_path / "g.json"),
        ("colmap", tmp_path / "model"),
    ):
        if fmt != "transforms":
            assert (
                _run(
                    [
                        "cameras",
                        str(ply),
                        "--orbit",
                        "6",
                        "--up=-y",
                        "--elevations=-10,30",
                        "--format",
                        fmt,
                        "-o",
                        str(out),
                    ],
                    caplog,
                )[0]
                == 0
            )
        got = load_camera_file(out)
        assert len(got) == 6, fmt
        for a, b in zip(got, want, strict=True):
            torch.testing.assert_close(a.world_to_camera, b.world_to_camera, atol=1e-9, rtol=0, msg=fmt)
            assert (a.width, a.height, a.fx) == pytest.approx((b.width, b.height, b.fx)), fmt
    assert "frame: no --up given" not in log  # --up was given


def test_colmap_cameras_stopped_midway_leave_the_earlier_three_files(tmp_path, caplog, monkeypatch):
    """The three text files were written one after another: a stop between them left a new cameras.txt beside an
    earlier run's images.txt. Now they are moved in together at the end."""
    from apps.cameras import NO_POINTS

    ply = _ply(tmp_path)
    model = tmp_path / "model"
    model.mkdir()
    earlier = {"cameras.txt": "# earlier cameras\n", "images.txt": "# earlier images\n", "points3D.txt": NO_POINTS}
    for name, text in earlier.items():
        (model / name).write_text(text)
    real = Path.write_bytes

    def write_bytes(self, data):
        if self.name == "points3D.txt":
            raise KeyboardInterrupt  # stopped after two of the three were written
        return real(self, data)

    monkeypatch.setattr(Path, "write_bytes", write_bytes)
    code, _ = _run(["cameras", str(ply), "--orbit", "4", "--format", "colmap", "-o", str(model)], caplog)
    assert code == 130  # Ctrl-C's exit code
    assert {p.name: p.read_text() for p in model.iterdir()} == earlier  # no temporary folder left either
    monkeypatch.undo()
    assert _run(["cameras", str(ply), "--orbit", "4", "--format", "colmap", "-o", str(model)], caplog)[0] == 0
    assert len(load_camera_file(model)) == 4 and (model / "points3D.txt").read_text() == NO_POINTS


@pytest.mark.parametrize(
    "extra, names",
    [
        (["--cameras", "orbit:0"], ["orbit:0", "orbit:24"]),
        (["--cameras", "orbit:4", "--crop", "5,5,5,6,6,6"], ["--crop", "widen the box"]),
        (["--cameras", "FOLDER"], ["a folder with no camera file", "COLMAP model"]),
        (["--cameras", "MISSING"], ["no such file or folder", "transforms.json"]),
        (["--cameras", "FOLDER", "--elevations", "10"], ["--elevations", "orbit:N"]),
        (["--cameras", "orbit:4", "--up", "auto"], ["--up auto", "orbit:N"]),
    ],
)
@pytest.mark.parametrize("command", ["score", "critical"])
def test_bad_cameras_exit_2_naming_the_option_and_the_fix(command, extra, names, tmp_path, caplog, stop_before_probes):
    ply = _ply(tmp_path)
    (tmp_path / "empty").mkdir()
    extra = [
        str(tmp_path / "empty") if e == "FOLDER" else str(tmp_path / "nothing") if e == "MISSING" else e for e in extra
    ]
    code, log = _run([command, str(ply), *extra, "-o", str(tmp_path / "out.json")], caplog)
    assert code == 2, log
    for name in names:
        assert name in log, (name, log)


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--orbit", "0"], "--orbit must be a number of cameras from 1 to 10,000, got 0"),
        (["--orbit", "100000000"], "--orbit must be a number of cameras from 1 to 10,000, got 100000000"),
        (["--orbit", "4", "--width", "100000000"], "--width must be a positive number of pixels, at most 65,536"),
    ],
)
def test_cameras_command_names_its_own_options(extra, message, tmp_path, caplog):
    """`cameras --orbit 0` spoke of `--cameras orbit:0`, an option this command does not have."""
    code, log = _run(["cameras", str(_ply(tmp_path)), *extra, "-o", str(tmp_path / "c.json")], caplog)
    assert code == 2 and message in log and "--cameras" not in log, log
    assert not (tmp_path / "c.json").exists()


def test_score_orbit_runs_up_to_the_probes_and_says_what_it_built(tmp_path, caplog, stop_before_probes):
    ply = _ply(tmp_path)
    (tmp_path / "s_cameras.json").write_text("an earlier run's")
    with pytest.raises(_Stop):
        _run(["score", str(ply), "--cameras", "orbit:5", "-o", str(tmp_path / "s.json"), "--no-png"], caplog)
    log = " ".join(r.getMessage() for r in caplog.records)
    assert "an orbit of 5 cameras on rings at 15, 45 deg" in log
    assert frame_hint() in log  # no --up: the one-line hint
    # the cameras are written with their scores: a run stopped before them leaves an earlier run's pair as it was
    assert (tmp_path / "s_cameras.json").read_text() == "an earlier run's"


def test_critical_orbit_stopped_before_the_probes_keeps_an_earlier_cameras_file(tmp_path, caplog, stop_before_probes):
    ply = _ply(tmp_path)
    (tmp_path / "c_cameras.json").write_text("an earlier run's")
    with pytest.raises(_Stop):
        _run(["critical", str(ply), "--cameras", "orbit:5", "-o", str(tmp_path / "c.json")], caplog)
    assert (tmp_path / "c_cameras.json").read_text() == "an earlier run's"


def test_demo_on_other_gaussians_scores_an_orbit_and_says_so(tmp_path, caplog, stop_before_probes):
    ply = _ply(tmp_path)
    with pytest.raises(_Stop):
        _run(["demo", "--gaussians", str(ply), "--up", "-y", "-o", str(tmp_path / "demo"), "--no-video"], caplog)
    log = " ".join(r.getMessage() for r in caplog.records)
    assert "no --cameras: scoring orbit:12" in log and "an orbit of 12 cameras" in log
    assert len(load_camera_file(tmp_path / "demo" / "cameras.json")) == 12


def test_cameras_far_from_the_up_are_named():
    cams = orbit_cameras(GaussianSet.from_points(torch.randn(50, 3)), PhysicsConfig(up="+y"), Orbit(8))
    assert check_up_against_cameras("+y", cams) is None
    upside_down = check_up_against_cameras("-y", cams)
    assert "180 deg" in upside_down and "upside down" in upside_down and "--up +y" in upside_down
    side = check_up_against_cameras("+x", cams)
    assert "90 deg" in side and "on its side" in side
    assert check_up_against_cameras("0.5,1,0", cams) is None  # 27 deg: within 60


def test_result_lists_every_option_it_overrides():
    parser = cli.build_parser("score")
    argv = [
        "score",
        "g.ply",
        "--cameras",
        "c.json",
        "-o",
        "s.json",
        "--result",
        "r.h5",
        "--up",
        "-y",
        "--quick",
        "--particle-radius",
        "0.05",
        "--no-fill",
        "--directions",
        "-x,+x",
        "--crop=auto",
        "--device",
        "cpu",
    ]
    args = parser.parse_args(cli.join_dash_values(argv, parser))
    assert result_overridden_options(args) == [
        "--quick",
        "--particle-radius 0.05",
        "--directions -x,+x",
        "--up -y",
        "--crop auto",
        "--no-fill",
    ]
    assert result_overridden_options(argparse.Namespace()) == []
