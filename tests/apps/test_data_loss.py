"""No data loss and no silently empty results (issue 18: items 1, 2, 3, 4, 6, 7, 9).

Outputs that are inputs are refused (also through links), a time step too large for the spacing is refused
before the first step, probes that reach nothing are flagged and an all-zero D_g is refused, a result of
other Gaussians is refused, a diverging probe keeps the completed ones (exit 3), output names the file system
accepts always work, `sim` keeps its frames on SIGINT / SIGTERM, and output errors exit 4.
"""

import errno
import json
import logging
import math
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch

from apps import cli, exit_codes
from fluidsim import SolverConfig
from fluidsim.output import (
    OutputError,
    SimulationWriter,
    atomic_output,
    check_not_input,
    check_writable,
    same_file,
    temp_path,
)
from fluidsim.simulation import check_time_step, run_cfl, speed_bound
from nbv.physics import (
    PhysicsConfig,
    check_result_matches,
    gaussians_sha256,
    load_result,
    save_result,
    simulate_gaussians,
)
from recon.camera import Camera
from recon.formats import load_gaussians
from recon.formats.ply import save_gaussians
from recon.gaussians import GaussianSet

from helpers.cameras import ring_cameras, write_transforms
from helpers.logs import error_text
from helpers.paths import REPO as ROOT
from helpers.scenes import small_scene
from helpers.spheres import sphere_gaussians

FAST = ["--particle-radius", "0.08", "--steps", "20", "--dt", "0.004", "--no-empty-reference", "--threads", "2"]


def _cameras(path: Path) -> Path:
    return write_transforms(path, ring_cameras(4))


def _score(data: dict, gaussians: str, *args: str) -> int:
    """``fluidgs score GAUSSIANS`` on the module's cameras, with ``args``; the exit code."""
    return cli.main(["score", gaussians, "--cameras", str(data["cameras"]), *args])


def _scene(**over) -> dict:
    return small_scene(**over)


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = tmp_path_factory.mktemp("data_loss")
    ply = save_gaussians(sphere_gaussians(), root / "mine.ply")
    cams = _cameras(root / "transforms.json")
    h5 = root / "r.h5"
    assert cli.main(["simulate", str(ply), "-o", str(h5), "--directions=-x", *FAST]) == 0
    return dict(root=root, ply=ply, cameras=cams, h5=h5)


# ---- 1. an output that is an input --------------------------------------------------------------------------
@pytest.mark.parametrize("spelling", ["same", "dotdot", "symlink", "hardlink"])
def test_simulate_refuses_a_ply_output_that_is_the_input(data, tmp_path, caplog, spelling):
    mine = tmp_path / "mine.ply"
    mine.write_bytes(data["ply"].read_bytes())
    (tmp_path / "sub").mkdir()
    target = {
        "same": mine,
        "dotdot": tmp_path / "sub" / ".." / "mine.ply",
        "symlink": tmp_path / "link.ply",
        "hardlink": tmp_path / "hard.ply",
    }[spelling]
    if spelling == "symlink":
        target.symlink_to(mine)
    elif spelling == "hardlink":
        os.link(mine, target)
    before = mine.read_bytes()
    out = tmp_path / "r.h5"
    assert cli.main(["simulate", str(mine), "-o", str(out), "--ply", str(target), *FAST]) == 2
    assert "GAUSSIANS" in caplog.text and "--ply" in caplog.text
    assert mine.read_bytes() == before and not out.exists()  # refused before any work


def test_other_commands_refuse_outputs_that_are_inputs(data, tmp_path, caplog):
    cams = tmp_path / "cams.json"
    cams.write_text(data["cameras"].read_text())
    cams_before = cams.read_text()
    score = ["score", str(data["ply"]), "--cameras", str(cams), "--result"]
    assert cli.main([*score, str(data["h5"]), "-o", str(cams), "--no-png"]) == 2
    assert cams.read_text() == cams_before and "--cameras" in caplog.text
    result_copy = tmp_path / "r.h5"
    result_copy.write_bytes(data["h5"].read_bytes())
    save = ["--save-result", str(result_copy), "-o", str(tmp_path / "s.json"), "--no-png"]
    assert cli.main([*score, str(result_copy), *save]) == 2
    # sim: the scene and each solid's points file
    np.save(tmp_path / "cube.npy", np.full((8, 3), 0.7))
    (tmp_path / "scene.json").write_text(json.dumps(_scene(solids=[{"points": "cube.npy"}])))
    scene_before = (tmp_path / "scene.json").read_text()
    assert cli.main(["sim", str(tmp_path / "scene.json"), "-o", str(tmp_path / "scene.json")]) == 2
    assert cli.main(["sim", str(tmp_path / "scene.json"), "-o", str(tmp_path / "cube.npy")]) == 2
    assert (tmp_path / "scene.json").read_text() == scene_before and np.load(tmp_path / "cube.npy").shape == (8, 3)
    # train: OUT.json next to OUT.ply would replace the dataset's cameras
    dataset = tmp_path / "dataset"
    dataset.mkdir()
    (dataset / "transforms_train.json").write_text('{"frames": []}')
    assert cli.main(["train", str(dataset), "-o", str(dataset / "transforms_train.ply")]) == 2
    assert (dataset / "transforms_train.json").read_text() == '{"frames": []}'


@pytest.mark.parametrize("command", ["inspect", "score", "critical", "compare", "cameras"])
def test_no_output_overwrites_a_file_the_gaussian_file_needs(data, tmp_path, caplog, command):
    """--dataparser-transforms and the model files of --colmap were not inputs to the output checks: `inspect --json`,
    score/critical/compare -o overwrote the dataparser_transforms.json, `cameras --format colmap -o DIR --colmap DIR`
    the COLMAP model, and `cameras G -o DIR --format colmap` an input G named DIR/images.txt. Each is refused before
    any work, naming the input."""
    dp = tmp_path / "dataparser_transforms.json"
    dp.write_text('{"transform": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]], "scale": 1.0}')
    model = tmp_path / "sparse"
    model.mkdir()
    for name in ("cameras.txt", "images.txt", "points3D.txt"):
        (model / name).write_text("# the capture's model\n")
    ply, cams = str(data["ply"]), str(data["cameras"])
    given = ["--dataparser-transforms", str(dp), "--colmap", str(model)]
    argv = {
        "inspect": ["inspect", ply, "--json", str(dp)],
        "score": ["score", ply, "--cameras", cams, "--result", str(data["h5"]), "-o", str(dp), "--no-png"],
        "critical": ["critical", ply, "--cameras", cams, "-o", str(dp)],
        "compare": ["compare", ply, "--reference", ply, "-o", str(dp)],
        "cameras": ["cameras", ply, "--orbit", "4", "-o", str(model), "--format", "colmap"],
    }[command]
    assert cli.main([*argv, *given]) == 2
    label = "--colmap" if command == "cameras" else "--dataparser-transforms"
    assert f"is the input {label}" in error_text(caplog), error_text(caplog)
    if command == "cameras":
        inside = model / "images.txt"
        inside.write_bytes(data["ply"].read_bytes())
        assert cli.main(["cameras", str(inside), "--orbit", "4", "-o", str(model), "--format", "colmap"]) == 2
        assert f"-o {inside} is the input GAUSSIANS {inside}" in error_text(caplog)
        assert inside.read_bytes() == data["ply"].read_bytes()
    assert (
        dp.read_text().startswith('{"transform"') and (model / "cameras.txt").read_text() == "# the capture's model\n"
    )


def test_cameras_keeps_a_colmap_reconstruction_it_would_replace_or_hide(data, tmp_path, caplog):
    """`cameras --format colmap -o sparse/0` into a reconstruction's model replaced its points3D.txt by an empty list,
    and beside .bin files (which the readers take first) its cameras were written and then never read. Both are
    refused; the folder of an earlier `cameras --format colmap` is written again."""
    argv = ["cameras", str(data["ply"]), "--orbit", "4", "--format", "colmap", "-o"]
    model, binary, earlier = tmp_path / "model", tmp_path / "binary", tmp_path / "earlier"
    model.mkdir()
    (model / "points3D.txt").write_text("1 0.5 0.5 0.5 255 255 255 0.1\n")
    binary.mkdir()
    (binary / "images.bin").write_bytes(bytes(8))
    for folder, names in ((model, "points3D.txt"), (binary, "images.bin")):
        caplog.clear()
        assert cli.main([*argv, str(folder)]) == 2
        assert f"-o {folder} holds a COLMAP model ({names})" in error_text(caplog)
    assert (model / "points3D.txt").read_text().startswith("1 0.5") and sorted(p.name for p in binary.iterdir()) == [
        "images.bin"
    ]
    assert cli.main([*argv, str(earlier)]) == 0 and cli.main([*argv, str(earlier)]) == 0


def test_render_dataset_overwrite_refuses_a_mesh_inside_the_folder_it_replaces(tmp_path, caplog):
    out = tmp_path / "ds"
    out.mkdir()
    mesh = out / "tetra.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    assert (
        cli.main(
            [
                "render-dataset",
                str(mesh),
                "-o",
                str(out),
                "--overwrite",
                "--train",
                "1",
                "--test",
                "1",
                "--res",
                "16",
                "--no-progress",
            ]
        )
        == 2
    )
    assert mesh.is_file() and "MESH" in caplog.text


@pytest.mark.parametrize("overwrite", [[], ["--overwrite"]])
def test_render_dataset_replaces_only_a_dataset_folder(tmp_path, caplog, overwrite):
    """`render-dataset -o /etc --overwrite` swapped the new dataset in and deleted all of /etc; a folder of
    other files (here the current folder, as `-o .`) is refused, with or without --overwrite."""
    mesh = tmp_path / "tetra.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    out = tmp_path / "home"
    out.mkdir()
    (out / "notes.txt").write_text("kept")
    args = ["render-dataset", str(mesh), "-o", str(out), "--train", "1", "--test", "1", "--res", "16"]
    assert cli.main([*args, "--supersample", "1", "--no-progress", *overwrite]) == 2
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    assert "-o " in error_text(caplog) and "notes.txt" in error_text(caplog)


@pytest.mark.parametrize("overwrite", [False, True])
def test_active_leaves_files_of_a_run_s_names_that_are_not_a_run(tmp_path, overwrite):
    """`active -o FOLDER` wrote its gaussians.ply over a user's gaussians.ply in a folder without a run, and with
    --overwrite deleted a config.json (and rounds.json) that was not a run's."""
    from nbv.active.run_dir import prepare_run_dir

    run = {"dataset": "ds", "active": {"budget": 4}}
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "gaussians.ply").write_text("kept")
    with pytest.raises(ValueError, match="holds gaussians.ply but no run's config.json"):
        prepare_run_dir(mine, run, overwrite)
    other = tmp_path / "other"
    other.mkdir()
    (other / "config.json").write_text('{"method": "splatfacto"}')
    (other / "rounds.json").write_text("kept")
    with pytest.raises(ValueError, match="is not the config.json of a `fluidgs active` run"):
        prepare_run_dir(other, run, overwrite)
    assert (mine / "gaussians.ply").read_text() == (other / "rounds.json").read_text() == "kept"
    assert json.loads((other / "config.json").read_text()) == {"method": "splatfacto"}
    assert prepare_run_dir(tmp_path / "new", run, overwrite) is False  # a new folder, and a run folder, still work
    assert prepare_run_dir(tmp_path / "new", run, overwrite) is False


def test_check_not_input_sees_links_and_labels():
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        a = Path(d) / "a.ply"
        a.write_text("x")
        os.link(a, Path(d) / "b.ply")
        assert same_file(a, Path(d) / "b.ply") and not same_file(a, Path(d) / "c.ply")
        check_not_input({"-o": Path(d) / "c.ply", "--ply": None}, {"IN": a})  # a fresh name passes
        with pytest.raises(ValueError, match=r"--ply .*b\.ply is the input IN .*a\.ply \(a hard link"):
            check_not_input({"--ply": Path(d) / "b.ply"}, [("IN", a)])
        with pytest.raises(ValueError, match="would be replaced"):
            check_not_input({}, {"IN": a}, replaced={"-o": d})


@pytest.mark.parametrize(
    "outputs",
    [
        ["-o", "r.h5", "--export-solid", "r.h5"],
        ["-o", "r.h5", "--export-solid", "r_divergence.ply"],
        ["-o", "v.voxels.h5", "--export-solid", "v.ply"],
    ],
)
def test_simulate_refuses_outputs_that_are_each_other(data, tmp_path, caplog, outputs, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert cli.main(["simulate", str(data["ply"]), *outputs, *FAST]) == 2
    assert "one output would overwrite the other" in caplog.text and "--export-solid" in caplog.text
    assert list(tmp_path.iterdir()) == []  # refused before any work


def test_score_refuses_a_saved_result_that_is_the_solid_export(data, tmp_path, caplog):
    s = tmp_path / "s.h5"
    args = ["score", str(data["ply"]), "--cameras", str(data["cameras"]), "-o", str(tmp_path / "s.json")]
    assert cli.main([*args, "--save-result", str(s), "--export-solid", str(s), "--no-png", *FAST]) == 2
    assert "--save-result" in caplog.text and not s.exists()


def test_score_keeps_its_work_whatever_the_camera_names(data, tmp_path):
    """graphdeco's img_name with '/' or 300 characters: the views land in the views folder under a safe name and
    scores.json is written (it used to end in exit 4 after all the scoring)."""
    from viz.cameras import view_file_stem

    names = ["sub/dir/a", "b" * 300, "../c", "d"]
    entries = []
    for k, a in enumerate(np.arange(4) * math.pi / 2):
        eye = (2.5 * math.cos(a), 0.3, 2.5 * math.sin(a))
        cam = Camera.look_at(eye, (0, 0, 0), (0, 1, 0), 48, 40, math.radians(50))
        c2w = cam.camera_to_world.numpy()
        f = float(cam.fx)
        entry = {"id": k, "img_name": names[k], "width": 48, "height": 40, "fx": f, "fy": f}
        entries.append({**entry, "position": c2w[:3, 3].tolist(), "rotation": c2w[:3, :3].tolist()})
    cams = tmp_path / "cameras.json"
    cams.write_text(json.dumps(entries))
    out = tmp_path / "s.json"
    args = ["score", str(data["ply"]), "--cameras", str(cams), "--result", str(data["h5"]), "-o", str(out)]
    assert cli.main([*args, "--png-all"]) == 0
    assert json.loads(out.read_text())
    pngs = sorted(p.name for p in (tmp_path / "s_views").iterdir())
    assert len(pngs) == 4 and all(len(p) < 120 for p in pngs), pngs
    assert view_file_stem(1, 0, "sub/dir/a") == "rank001_000_sub_dir_a"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cameras.json", "s.json", "s_views"]


def test_check_distinct_outputs_sees_links():
    import tempfile

    from fluidsim.files import check_distinct_outputs

    with tempfile.TemporaryDirectory() as d:
        a = Path(d) / "a.h5"
        a.write_text("x")
        (Path(d) / "link.h5").symlink_to(a)
        check_distinct_outputs({"-o": a, "--ply": Path(d) / "b.ply", "--video": None})
        with pytest.raises(ValueError, match=r"--ply .*link\.h5 is the same file as -o .*a\.h5"):
            check_not_input({"-o": a, "--ply": Path(d) / "link.h5"}, {})


# ---- 2. a time step too large, probes that reach nothing, an all-zero D_g --------------------------------------
def test_speed_bound_is_the_free_fall_speed():
    """A particle launched horizontally at v0 from the top of a box of height H (the numpy twin: the ballistic
    speed sqrt(v0^2 + (g t)^2) until the floor or the end of the run) never beats the bound, which equals it at
    the floor (energy: sqrt(v0^2 + 2 g H)) and bounds it by v0 + g T before."""
    g, v0, height = 9.81, 3.0, 3.2
    t_floor = math.sqrt(2 * height / g)
    for duration in (0.1, t_floor, 5.0):
        t = np.linspace(0.0, min(duration, t_floor), 2001)
        speed = np.sqrt(v0**2 + (g * t) ** 2)  # |v| of the free fall until the floor or the end of the run
        bound = speed_bound(v0, g, height, duration)
        assert speed.max() <= bound + 1e-12
    assert speed_bound(v0, g, height, 5.0) == pytest.approx(math.sqrt(v0**2 + 2 * g * height))
    assert speed_bound(0.0, g, 100.0, 0.1) == pytest.approx(g * 0.1)


def test_time_step_check_passes_paper_settings_and_refuses_a_large_dt():
    paper = SolverConfig(particle_radius=0.025, dt=0.002)
    lo, hi = (-1.6, -1.6, -1.6), (1.6, 2.1, 1.6)  # a 3.7 m tall -y probe domain around a 2 m object
    cfl = check_time_step(paper, 3.0, lo, hi, 750)
    assert 0.3 < cfl < 0.4  # sqrt(9 + 2 g 3.7) = 8.5 m/s: 8.5 x 0.002 / 0.05
    quick = SolverConfig(particle_radius=0.05, dt=0.002)
    assert check_time_step(quick, 3.0, lo, hi, 300) < 0.2
    with pytest.raises(ValueError, match=r"CFL number .* > max_cfl 1.*dt <= 0.00"):
        check_time_step(SolverConfig(particle_radius=0.025, dt=0.5), 3.0, lo, hi, 750, where="probe -x")
    # the adaptive step keeps cfl_factor whatever the initial dt (it is clamped to dt_max)
    adaptive = SolverConfig(particle_radius=0.025, dt=0.5, time_step="cfl")
    assert run_cfl(adaptive, 3.0, lo, hi, 750)[0] == pytest.approx(0.5)


def test_simulate_and_sim_refuse_a_dt_that_empties_the_domain(data, tmp_path, caplog):
    out = tmp_path / "r.h5"
    args = ["--particle-radius", "0.08", "--steps", "20", "--dt", "0.5", "--no-empty-reference", "--threads", "2"]
    assert cli.main(["simulate", str(data["ply"]), "-o", str(out), "--directions=-x", *args]) == 2
    assert "CFL number" in caplog.text and "probe -x" in caplog.text and not out.exists()
    caplog.clear()
    (tmp_path / "scene.json").write_text(json.dumps(_scene(dt=10.0)))
    assert cli.main(["sim", str(tmp_path / "scene.json"), "-o", str(tmp_path / "o.h5")]) == 2
    assert "CFL number" in caplog.text and not (tmp_path / "o.h5").exists()


def test_probe_that_loses_its_fluid_is_recorded_and_score_refuses_zero_divergence(data, tmp_path, caplog):
    from dataclasses import replace

    from nbv.physics import probe_warnings

    # max_cfl lifted on purpose: every fluid particle leaves the domain in the first step (the issue's --dt 0.5); a
    # viscosity under the explicit step's limit at that dt (6.4 Pa s at r = 0.08 m)
    cfg = PhysicsConfig(
        particle_radius=0.08,
        steps=3,
        dt=0.5,
        viscosity=1.0,
        empty_reference=False,
        directions=("-x",),
        solver={"max_cfl": 1e6},
    )
    res = simulate_gaussians(load_gaussians(data["ply"]), cfg, progress=False)
    assert res.divergence.max() < 1e-4  # 1/s: what a few particles on their way out left behind
    warns = res.warnings["-x"]
    assert any("(100 %) left the domain within 3 steps" in w for w in warns)
    back = load_result(save_result(tmp_path / "lost.h5", res))
    assert back.warnings == res.warnings
    with h5py.File(tmp_path / "lost.h5") as f:
        assert json.loads(f["probes/-x"].attrs["warnings"]) == warns
    # a probe that reaches no Gaussian: D_g^(IC) = 0 everywhere, said so
    assert any(
        "no fluid particle came within reach" in w
        for w in probe_warnings("-x", np.zeros(300, np.int64), list(res.stats["-x"][:0]))
    )
    zero = replace(
        res,
        per_probe=np.zeros_like(res.per_probe),
        divergence=np.zeros(300),
        divergence_mean=np.zeros(300),
        per_probe_counts=np.zeros_like(res.per_probe_counts),
    )
    save_result(tmp_path / "zero.h5", zero)
    caplog.clear()
    assert (
        _score(
            data, str(data["ply"]), "--result", str(tmp_path / "zero.h5"), "-o", str(tmp_path / "s.json"), "--no-png"
        )
        == 2
    )
    assert "is 0 for every one of the 300 Gaussians" in caplog.text and "left the domain" in caplog.text
    assert not (tmp_path / "s.json").exists()


# ---- 3. a result of other Gaussians ---------------------------------------------------------------------------
def test_score_refuses_the_result_of_other_gaussians_with_the_same_count(data, tmp_path, caplog):
    g = load_gaussians(data["ply"])
    other = GaussianSet(g.means + 0.01, g.quats, g.log_scales, g.opacity_logits, g.sh)
    save_gaussians(other, tmp_path / "other.ply")
    assert (
        _score(
            data, str(tmp_path / "other.ply"), "--result", str(data["h5"]), "-o", str(tmp_path / "s.json"), "--no-png"
        )
        == 2
    )
    assert "other Gaussians" in caplog.text
    # a re-coloured copy (the heat-map .ply) has the same geometry: accepted
    recolored = GaussianSet(g.means, g.quats, g.log_scales, g.opacity_logits, torch.zeros_like(g.sh))
    assert gaussians_sha256(recolored) == load_result(data["h5"]).gaussians_sha256
    save_gaussians(recolored, tmp_path / "recolored.ply")
    assert (
        _score(
            data,
            str(tmp_path / "recolored.ply"),
            "--result",
            str(data["h5"]),
            "-o",
            str(tmp_path / "s.json"),
            "--no-png",
        )
        == 0
    )


def test_results_without_a_hash_are_checked_by_their_centres(data, tmp_path):
    old = tmp_path / "old.h5"
    old.write_bytes(data["h5"].read_bytes())
    with h5py.File(old, "a") as f:
        del f.attrs["gaussians_sha256"]
    res = load_result(old)
    assert res.gaussians_sha256 == ""
    g = load_gaussians(data["ply"])
    check_result_matches(res, g, old)
    shifted = GaussianSet(g.means + 0.001, g.quats, g.log_scales, g.opacity_logits, g.sh)
    with pytest.raises(ValueError, match="other Gaussians .* centres"):
        check_result_matches(res, shifted, old)


# ---- 4. a probe that diverges inside simulate / score -----------------------------------------------------------
DIVERGE = [
    "--directions=-y,-x",
    "--speed",
    "250",
    "--dt",
    "0.0001",
    "--particle-radius",
    "0.08",
    "--steps",
    "10",
    "--no-empty-reference",
    "--threads",
    "2",
]  # -y falls from rest; -x starts at 250 m/s > max_speed 200


def test_simulate_keeps_the_completed_probes_of_a_diverging_run(data, tmp_path, caplog):
    out = tmp_path / "r.h5"
    assert cli.main(["simulate", str(data["ply"]), "-o", str(out), *DIVERGE]) == 3
    assert "probe -x diverged at step 0" in caplog.text and "Traceback" not in caplog.text
    res = load_result(out)
    assert res.status == "diverged" and res.directions == ("-y",)
    assert res.failure["probe"] == "-x" and res.failure["step"] == 0 and "max_speed" in res.failure["reason"]
    assert res.per_probe.shape == (1, 300) and len(res.stats["-y"]) == 10
    with pytest.raises(ValueError, match="diverged"):
        check_result_matches(res, load_gaussians(data["ply"]), out)
    caplog.clear()
    saved = tmp_path / "saved.h5"
    assert (
        _score(
            data, str(data["ply"]), "-o", str(tmp_path / "s.json"), "--no-png", "--save-result", str(saved), *DIVERGE
        )
        == 3
    )
    assert "probe -x diverged" in caplog.text and load_result(saved).status == "diverged"
    assert not (tmp_path / "s.json").exists()


def test_a_result_with_no_completed_probe_loads(data, tmp_path):
    from nbv.physics import ProbeDiverged

    cfg = PhysicsConfig(
        particle_radius=0.08, steps=5, dt=0.0001, speed=250.0, empty_reference=False, directions=("-x",)
    )
    with pytest.raises(ProbeDiverged, match="probe -x diverged at step 0.*probes completed: none") as info:
        simulate_gaussians(load_gaussians(data["ply"]), cfg, progress=False)
    back = load_result(save_result(tmp_path / "none.h5", info.value.result))
    assert back.directions == () and back.per_probe.shape == (0, 300) and back.failure["probe"] == "-x"


# ---- 6. output names: the temporary name, a parent that is a file -------------------------------------------
def test_a_legal_255_byte_output_name_is_written(data, tmp_path):
    name = "r" * 252 + ".h5"  # 255 bytes: the longest name ext4 allows
    out = tmp_path / name
    assert (
        cli.main(
            ["simulate", str(data["ply"]), "-o", str(out), "--ply", str(tmp_path / "c.ply"), "--directions=-x", *FAST]
        )
        == 0
    )
    assert load_result(out).directions == ("-x",) and not list(tmp_path.glob(".*tmp*"))


def test_too_long_names_and_file_parents_are_refused_before_any_work(data, tmp_path, caplog):
    with pytest.raises(OutputError, match="longer than the 255 bytes"):
        check_writable(tmp_path / ("r" * 253 + ".h5"))
    # the default coloured .ply of a 255-byte -o is longer still: refused up front (exit 4), not after the probes
    assert cli.main(["simulate", str(data["ply"]), "-o", str(tmp_path / ("r" * 252 + ".h5")), *FAST]) == 4
    assert "_divergence.ply" in caplog.text
    blocker = tmp_path / "blocker"
    blocker.write_text("a file")
    for path in (blocker / "x.h5", blocker / "sub" / "x.h5"):
        with pytest.raises(OutputError, match="blocker is a file, not a folder"):
            check_writable(path)
    assert not list(tmp_path.glob(".fgs-*"))  # the writability probe cleaned up


def test_every_writer_uses_the_short_temporary_name(tmp_path):
    long = "w" * 250
    assert len(temp_path(tmp_path / (long + ".h5")).name) < 20
    with SimulationWriter(tmp_path / (long + ".h5"), {"a": 1}) as w:
        w.finish([], np.zeros(0), np.zeros(0))
    assert h5py.File(tmp_path / (long + ".h5")).attrs["status"] == "complete"
    save_gaussians(sphere_gaussians(10), tmp_path / (long + ".ply"))
    assert load_gaussians(tmp_path / (long + ".ply")).num == 10
    with atomic_output(tmp_path / (long + ".json")) as tmp:
        tmp.write_text("{}")
    assert (tmp_path / (long + ".json")).read_text() == "{}"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(long + s for s in (".h5", ".json", ".ply"))


# ---- 7. sim interrupted by SIGTERM or SIGINT ---------------------------------------------------------------------
def _run_until_steps(cmd: list[str], log: Path, steps: int, timeout: float = 240.0) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=open(log, "w"), cwd=ROOT, env=env)
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        done = [int(m) for m in re.findall(r"\| *(\d+)/\d+ \[", log.read_text())]
        if done and max(done) >= steps:
            return proc
        if proc.poll() is not None:
            raise AssertionError(f"sim ended early: {log.read_text()[-2000:]}")
        time.sleep(0.2)
    proc.kill()
    raise AssertionError("sim did not reach the steps in time")


@pytest.mark.parametrize("sig, code", [(signal.SIGTERM, 143), (signal.SIGINT, 130), (signal.SIGHUP, 129)])
def test_sim_keeps_its_frames_when_interrupted(tmp_path, sig, code):
    block = {"min": [0.1, 0.1, 0.1], "max": [0.6, 0.6, 0.6], "velocity": [1, 0, 0]}
    (tmp_path / "scene.json").write_text(json.dumps(_scene(steps=100000, particle_radius=0.02, fluid_blocks=[block])))
    out = tmp_path / "out.h5"
    cmd = [sys.executable, "-m", "apps.cli", "sim", str(tmp_path / "scene.json"), "-o", str(out)]
    cmd += ["--save-every", "3", "--threads", "2"]
    proc = _run_until_steps(cmd, tmp_path / "log.txt", 7)
    proc.send_signal(sig)
    assert proc.wait(timeout=120) == code, (tmp_path / "log.txt").read_text()[-2000:]
    assert not list(tmp_path.glob(".*tmp*"))
    with h5py.File(out) as f:
        assert f.attrs["status"] == "interrupted"
        assert f.attrs["interrupted_by"] == signal.Signals(sig).name
        last = int(f.attrs["interrupted_after_step"])
        assert last >= 7 and len(f["stats"]) == last
        frames = sorted(f["frames"])
        assert frames[:3] == ["000000", "000003", "000006"] and frames[-1] == f"{last:06d}"  # the state at the stop
        assert f[f"frames/{frames[-1]}/x"].shape[0] > 1000
    if sig == signal.SIGTERM:  # a rerun overwrites the interrupted file
        subprocess.run(
            [*cmd, "--steps", "3"],
            check=True,
            capture_output=True,
            cwd=ROOT,
            env={**os.environ, "PYTHONPATH": str(ROOT)},
        )
        with h5py.File(out) as f:
            assert f.attrs["status"] == "complete" and len(f["stats"]) == 3


# ---- 9. output errors get exit code 4 ---------------------------------------------------------------------------
def test_output_errors_map_to_exit_4_and_bad_input_to_2(tmp_path, monkeypatch, caplog):
    assert exit_codes.is_output_error(OSError(errno.ENOSPC, "No space left on device"))
    assert exit_codes.is_output_error(OSError(errno.ENAMETOOLONG, "File name too long"))
    assert exit_codes.is_output_error(OSError(errno.EROFS, "Read-only file system"))
    assert exit_codes.is_output_error(OutputError("cannot write x"))
    assert not exit_codes.is_output_error(OSError(errno.ENOENT, "No such file"))
    assert not exit_codes.is_output_error(ValueError("bad option"))
    (tmp_path / "scene.json").write_text(json.dumps(_scene()))
    real_replace = os.replace

    def full_disk(src, dst):
        if str(dst).endswith("out.h5"):
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_replace(src, dst)

    monkeypatch.setattr(os, "replace", full_disk)
    assert cli.main(["sim", str(tmp_path / "scene.json"), "-o", str(tmp_path / "out.h5"), "--threads", "2"]) == 4
    assert "No space left on device" in caplog.text and "out.h5" in caplog.text
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.json"]  # no half file, no temporary left
    assert cli.main(["sim", str(tmp_path / "missing.json"), "-o", str(tmp_path / "o.h5")]) == 2


def _sim_with_full_disk(tmp_path, caplog) -> tuple[int, Path]:
    (tmp_path / "scene.json").write_text(json.dumps(_scene(steps=8)))
    out = tmp_path / "out.h5"
    code = cli.main(["sim", str(tmp_path / "scene.json"), "-o", str(out), "--save-every", "2", "--threads", "2"])
    errors = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
    assert len(errors) == 1 and "\n" not in errors[0], errors
    assert str(out) in errors[0] and "free disk space or choose another -o" in errors[0], errors[0]
    assert "Traceback" not in caplog.text
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.h5", "scene.json"]  # no .fgs-*.tmp, no reserve
    return code, out


def test_sim_keeps_its_frames_when_the_disk_has_no_room_for_the_next(tmp_path, monkeypatch, caplog):
    import fluidsim.output

    checks = []

    def free_bytes(folder):  # room for three frames (steps 0, 2, 4), then 10 kB left
        checks.append(folder)
        return 10**12 if len(checks) <= 3 else 10**4

    monkeypatch.setattr(fluidsim.output, "free_bytes", free_bytes)
    code, out = _sim_with_full_disk(tmp_path, caplog)
    assert code == exit_codes.EXIT_OUTPUT
    assert "frame of step 6" in caplog.text and "3 frames up to step 4" in caplog.text
    with h5py.File(out) as f:
        assert f.attrs["status"] == "disk full" and f.attrs["disk_full_after_step"] == 6
        assert sorted(f["frames"]) == ["000000", "000002", "000004"] and len(f["stats"]) == 6
        assert f["frames/000004/x"][:].shape == (64, 3) and np.isfinite(f["frames/000004/v"][:]).all()


def test_sim_keeps_its_frames_when_the_disk_refuses_a_write(tmp_path, monkeypatch, caplog):
    real = h5py.Group.create_dataset

    def create_dataset(self, name, *args, **kwargs):  # ENOSPC halfway through the frame of step 4
        if self.name == "/frames/000004" and name == "v":
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(self, name, *args, **kwargs)

    monkeypatch.setattr(h5py.Group, "create_dataset", create_dataset)
    code, out = _sim_with_full_disk(tmp_path, caplog)
    assert code == exit_codes.EXIT_OUTPUT and "No space left on device" in caplog.text
    with h5py.File(out) as f:
        assert f.attrs["status"] == "disk full" and f.attrs["disk_full_after_step"] == 4
        assert sorted(f["frames"]) == ["000000", "000002"]  # the half-written frame is gone
        assert len(f["stats"]) == 4 and f["divergence_sum"].shape == f["divergence_count"].shape
        assert f["frames/000002/x"][:].shape == f["frames/000002/v"][:].shape


def test_sim_with_no_room_for_its_reserve_writes_nothing(tmp_path, monkeypatch, caplog):
    def no_room(fd, offset, size):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "posix_fallocate", no_room, raising=False)
    (tmp_path / "scene.json").write_text(json.dumps(_scene(steps=2)))
    assert cli.main(["sim", str(tmp_path / "scene.json"), "-o", str(tmp_path / "out.h5"), "--threads", "2"]) == 4
    assert "No space left on device" in caplog.text and "no output was written" in caplog.text
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.json"]


def test_exit_code_table_is_documented_in_both_places():
    doc = (ROOT / "docs" / "exit-codes.md").read_text()
    for code in (0, 1, exit_codes.EXIT_BAD_INPUT, exit_codes.EXIT_DIVERGED, exit_codes.EXIT_OUTPUT, 129, 130, 143):
        assert re.search(rf"^\| *{code} *\|", doc, re.M), code
        assert re.search(rf"^{code} +\S", exit_codes.__doc__, re.M), code
