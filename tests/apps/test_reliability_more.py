"""Limits, messages and silent mistakes of the hostile sweep: each case is first rebuilt as the sweep ran it, and
each must end in one line that names the input or option that caused it and the fix (no traceback, no silent
result)."""

import json
import logging
import math
import shutil

import h5py
import numpy as np
import pytest
import torch

from apps import cli
from recon.camera import Camera
from recon.formats.ply import save_gaussians
from recon.gaussians import GaussianSet

from helpers.cameras import ring_cameras, write_transforms
from helpers.scenes import small_scene

FAST = ["--particle-radius", "0.08", "--steps", "5", "--dt", "0.004", "--no-empty-reference", "--threads", "2"]


def _errors(caplog) -> str:
    return " ".join(r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR)


def _warnings(caplog) -> str:
    return " ".join(r.getMessage() for r in caplog.records if r.levelno == logging.WARNING)


def _scene(**over) -> dict:
    return small_scene(**{"steps": 2, **over})


def _sphere(n: int = 300) -> GaussianSet:
    i = np.arange(n) + 0.5
    phi, th = np.arccos(1 - 2 * i / n), math.pi * (1 + 5**0.5) * i
    pts = np.stack([np.cos(th) * np.sin(phi), np.cos(phi), np.sin(th) * np.sin(phi)], 1) * 0.5
    return GaussianSet.from_points(torch.tensor(pts, dtype=torch.float32), scale=0.06, opacity=0.9)


def _cameras(path, w: int = 48, h: int = 40):
    return write_transforms(path, ring_cameras(4), w, h)


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """A 300-Gaussian sphere, four cameras and its -x RESULT.h5 (simulate, 20 coarse steps)."""
    root = tmp_path_factory.mktemp("more")
    ply = save_gaussians(_sphere(), root / "mine.ply")
    cams = _cameras(root / "transforms.json")
    h5 = root / "r.h5"
    assert cli.main(["simulate", str(ply), "-o", str(h5), "--directions=-x", *FAST, "--steps", "20"]) == 0
    return dict(root=root, ply=ply, cameras=cams, h5=h5)


# ---- counts that allocate ---------------------------------------------------------------------------------------
def test_max_neighbors_1e9_is_refused_before_allocating_naming_the_key(tmp_path, caplog, capsys):
    """`"max_neighbors": 1e9` gave a Taichi allocation traceback (an overflowed size of 1.8e19 bytes)."""
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps(_scene(solver={"max_neighbors": 1_000_000_000})))
    assert cli.main(["sim", str(scene), "-o", str(tmp_path / "o.h5"), "--threads", "1"]) == 2
    msg = _errors(caplog)
    assert "'solver.max_neighbors' = 1000000000" in msg and "remove 'max_neighbors'" in msg
    assert "Traceback" not in capsys.readouterr().err and not (tmp_path / "o.h5").exists()


def test_max_neighbors_enters_the_memory_estimate():
    from fluidsim.memory import BYTES_PER_LIST_SLOT, default_list_capacity, estimate_scene_memory
    from fluidsim.scene import parse_scene

    plain = estimate_scene_memory(parse_scene(_scene(), "."))
    wide = estimate_scene_memory(parse_scene(_scene(solver={"max_neighbors": 1000}), "."))
    extra = 1000 - default_list_capacity(parse_scene(_scene(), ".").config)
    assert plain.list_bytes == 0
    assert wide.bytes - plain.bytes == pytest.approx(plain.fluid_particles * extra * BYTES_PER_LIST_SLOT["f32"])


def test_a_million_wall_layers_blame_the_wall_layers_not_the_domain(tmp_path, caplog):
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps(_scene(domain={"min": [0, 0, 0], "max": [1, 1, 1], "wall_layers": 1_000_000})))
    assert cli.main(["sim", str(scene), "-o", str(tmp_path / "o.h5"), "--threads", "1"]) == 2
    msg = _errors(caplog)
    assert "'domain.wall_layers' = 1000000" in msg and "set 'domain.wall_layers' to 2" in msg
    assert "shrink 'domain'" not in msg


# ---- messages that name the real cause ---------------------------------------------------------------------------
def test_a_tiny_dt_is_called_too_small_not_too_large(data, tmp_path, caplog):
    out = tmp_path / "r.h5"
    assert cli.main(["simulate", str(data["ply"]), "-o", str(out), "--directions=-x", *FAST, "--dt", "1e-300"]) == 2
    msg = _errors(caplog)
    assert "--dt must be at least 1e-08 s" in msg and "too small, not too large" in msg and "reduce dt" not in msg
    assert not out.exists()


def test_a_huge_viscosity_is_refused_naming_the_viscosity_and_its_limit(data, tmp_path, caplog):
    """`--viscosity 1e6` diverged at step 2 ("fluid speed 2.55e+04 m/s exceeds max_speed; reduce dt")."""
    out = tmp_path / "r.h5"
    args = ["simulate", str(data["ply"]), "-o", str(out), "--directions=-x", *FAST, "--viscosity", "1e6"]
    assert cli.main(args) == 2
    msg = _errors(caplog)
    assert "viscosity 1e+06 Pa s is above the stability limit of the explicit viscosity step" in msg
    assert "lower viscosity to 800 Pa s or less" in msg and not out.exists()


def test_the_viscous_limit_follows_the_diffusion_bound():
    """dt <= 0.125 (h/2)^2 rho0 / mu: at r = 0.05 m (h = 0.2 m), rho0 = 1000, dt = 0.002 s the bound is 625 Pa s
    (measured with `fluidgs sim`: 600 Pa s ran 60 steps, 1000 Pa s diverged at step 19)."""
    from fluidsim.config import SolverConfig
    from fluidsim.simulation import check_viscous_time_step, viscous_dt_limit

    cfg = SolverConfig(particle_radius=0.05, dt=0.002, viscosity=600.0)
    assert viscous_dt_limit(cfg, 625.0) == pytest.approx(0.002)
    assert viscous_dt_limit(cfg, 0.0) == math.inf
    check_viscous_time_step(cfg)
    with pytest.raises(ValueError, match="viscosity 1000 Pa s.*lower viscosity to 625 Pa s"):
        check_viscous_time_step(SolverConfig(particle_radius=0.05, dt=0.002, viscosity=1000.0), "scene s.json")
    with pytest.raises(ValueError, match="boundary_viscosity 5000 Pa s"):
        check_viscous_time_step(SolverConfig(particle_radius=0.05, dt=0.002, boundary_viscosity=5000.0))


def test_config_errors_name_the_option_not_the_class(tmp_path, caplog):
    """`PhysicsConfig.scale` and `ActiveConfig.budget` appeared where the user wrote --scale and --budget."""
    (tmp_path / "ds").mkdir()
    assert cli.main(["simulate", "g.ply", "-o", str(tmp_path / "r.h5"), "--scale", "0"]) == 2
    assert cli.main(["active", str(tmp_path / "ds"), "-o", str(tmp_path / "run"), "--budget", "0"]) == 2
    assert cli.main(["active", str(tmp_path / "ds"), "-o", str(tmp_path / "run"), "--probe-steps", "0"]) == 2
    msg = _errors(caplog)
    assert "--scale must be 'auto' or a number > 0" in msg and "--budget must be an integer >= 1" in msg
    assert "--probe-steps must be an integer >= 1" in msg and "Config." not in msg


def test_rename_fields_replaces_whole_names_only():
    from apps.options import option_names
    from apps.options.fields import rename_fields
    from nbv.physics import PhysicsConfig

    names = option_names(PhysicsConfig, ("steps", "fill_cavities"), {"fill_cavities": {"flags": ("--no-fill",)}})
    assert names == {"PhysicsConfig.steps": "--steps", "PhysicsConfig.fill_cavities": "--no-fill"}
    assert rename_fields("PhysicsConfig.steps and PhysicsConfig.steps_x", names) == "--steps and PhysicsConfig.steps_x"


@pytest.fixture(scope="module")
def blender_scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("scene") / "scene"
    root.mkdir()
    frame = {"file_path": "./train/r_0", "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]}
    for split in ("train", "test"):
        (root / f"transforms_{split}.json").write_text(json.dumps({"camera_angle_x": 0.7, "frames": [frame] * 8}))
    return root


@pytest.mark.parametrize(
    "active, key",
    [({"budget": 0}, "'active.budget' must be"), ({"budget": 4, "physics": {"steps": 0}}, "'active.physics.steps'")],
)
def test_experiment_config_errors_name_the_key(blender_scene, tmp_path, caplog, active, key):
    path = tmp_path / "exp.json"
    path.write_text(json.dumps({"scenes": [str(blender_scene)], "methods": ["random"], "active": active}))
    assert cli.main(["experiment", str(path), "--no-progress"]) == 2
    assert key in _errors(caplog) and "Config." not in _errors(caplog)


def test_experiment_output_that_is_a_file_is_named_as_the_key(blender_scene, tmp_path, caplog):
    """`"output": "../A.ply"` (an existing file) printed "[Errno 17] File exists: ..."."""
    (tmp_path / "A.ply").write_text("not a folder")
    (tmp_path / "sub").mkdir()
    path = tmp_path / "sub" / "exp.json"
    path.write_text(
        json.dumps(
            {
                "scenes": [str(blender_scene)],
                "methods": ["random"],
                "reference_views": None,
                "output": "../A.ply",
                "active": {"budget": 4},
            }
        )
    )
    assert cli.main(["experiment", str(path), "--no-progress"]) == 4
    msg = _errors(caplog)
    assert f"the 'output' of {path}" in msg and "is a file, not a folder" in msg and "Errno" not in msg
    assert (tmp_path / "A.ply").read_text() == "not a folder"


# ---- a result with no completed probe --------------------------------------------------------------------------------
@pytest.fixture
def no_probe(data, tmp_path):
    """RESULT.h5 of a run that diverged in its first probe (the layout `simulate` writes then)."""
    bad = tmp_path / "none.h5"
    shutil.copy(data["h5"], bad)
    with h5py.File(bad, "r+") as f:
        del f["probes"]
        f.attrs["directions"] = "[]"
        f.attrs.update(status="diverged", diverged_probe="-x", diverged_step=0, diverged_reason="fluid speed 250 m/s")
    return bad


def test_view_of_a_result_with_no_completed_probe_is_one_line(no_probe, caplog, capsys):
    pytest.importorskip("viser")
    assert cli.main(["view", str(no_probe), "--port", "0"]) == 2
    msg = _errors(caplog)
    assert "has no D_g to show" in msg and "diverged in probe -x at step 0" in msg and "before completing" in msg
    assert "IndexError" not in capsys.readouterr().err


def test_score_of_a_result_with_no_completed_probe_says_none_completed(data, no_probe, tmp_path, caplog):
    out = tmp_path / "s.json"
    args = ["score", str(data["ply"]), "--cameras", str(data["cameras"]), "--result", str(no_probe), "-o", str(out)]
    assert cli.main([*args, "--no-png"]) == 2
    assert "no probe completed" in _errors(caplog) and not out.exists()


# ---- nothing silently wrong ------------------------------------------------------------------------------------------
def test_speed_0_is_refused_naming_the_option(data, tmp_path, caplog):
    """`--speed 0` completed with D-bar = 0 and no warning."""
    out = tmp_path / "r.h5"
    assert cli.main(["simulate", str(data["ply"]), "-o", str(out), "--directions=-x,-y", *FAST, "--speed", "0"]) == 2
    msg = _errors(caplog)
    assert "--speed is 0 m/s: the probes -x would have no inflow and measure nothing" in msg and not out.exists()
    from nbv.physics import PhysicsConfig

    assert PhysicsConfig(speed=0.0, directions=("-y",)).speed == 0.0  # the -y probe falls from rest: allowed


# ---- extreme numbers in a Gaussian file ----------------------------------------------------------------------------
@pytest.mark.parametrize(
    "field, value, what",
    [
        ("means", 1e38, "a centre coordinate beyond +-1e15 scene units"),
        ("log_scales", 88.0, "a log-scale beyond +-30"),
        ("log_scales", -88.0, "a log-scale beyond +-30"),
    ],
)
def test_extreme_means_and_scales_name_the_gaussians(tmp_path, caplog, capsys, field, value, what):
    """Means of 1e38 and log-scales of +-88 printed 113-digit counts from an int64 overflow (or passed silently)."""
    props = ("x", "y", "z") if field == "means" else ("scale_0", "scale_1", "scale_2")
    path = _patched_ply(save_gaussians(_sphere(), tmp_path / "x.ply"), [3, 7], props, value)
    assert cli.main(["inspect", str(path), "--threads", "1"]) == 2
    msg = _errors(caplog)
    assert f"2 Gaussians have {what}" in msg and "first rows [3, 7]" in msg and f"{value:.3g}" in msg
    assert ",000,000" not in msg and "Traceback" not in capsys.readouterr().err


def _patched_ply(path, rows, props, value):
    """``path`` (a binary float32 3DGS .ply) with ``props`` of ``rows`` set to ``value`` (the writer refuses it)."""
    raw = path.read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    names = [line.split()[-1].decode() for line in raw[:end].splitlines() if line.startswith(b"property")]
    table = np.frombuffer(raw[end:], np.float32).reshape(-1, len(names)).copy()
    for p in props:
        table[rows, names.index(p)] = value
    path.write_bytes(raw[:end] + table.tobytes())
    return path


def test_subnormal_centres_are_named_as_such_by_scale_auto(tmp_path, caplog):
    path = save_gaussians(_sphere(), tmp_path / "tiny.ply")
    raw = path.read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    names = [line.split()[-1].decode() for line in raw[:end].splitlines() if line.startswith(b"property")]
    table = np.frombuffer(raw[end:], np.float32).reshape(-1, len(names)).copy()
    table[:, :3] = _sphere().means.numpy() * 1e-39  # subnormal float32 centres (0 where Taichi flushes them)
    path.write_bytes(raw[:end] + table.tobytes())
    assert cli.main(["inspect", str(path), "--threads", "1"]) == 2
    assert "centres coincide or nearly" in _errors(caplog) and "pass --scale" in _errors(caplog)


def test_huge_counts_are_written_in_powers_of_ten():
    from nbv.physics.memory import _count

    assert _count(1234567) == "1,234,567" and _count(1.65e114) == "1.65e+114"


def test_a_diverged_result_records_a_positive_simulation_time(data):
    """A probe that diverged after some aggregated steps recorded simulation = probe time (0: not added) minus
    aggregation time (added each step): -0.22 s."""
    from nbv.physics import PhysicsConfig, ProbeDiverged, simulate_gaussians
    from recon import load_gaussians

    cfg = PhysicsConfig(
        particle_radius=0.08, steps=20, dt=0.004, empty_reference=False, directions=("-x",), solver={"max_speed": 3.05}
    )
    with pytest.raises(ProbeDiverged) as info:
        simulate_gaussians(load_gaussians(data["ply"]), cfg, progress=False)
    t = info.value.result.timings
    assert info.value.step > 0 and t["aggregation"] > 0 and t["simulation"] > 0


def test_speed_0_in_an_experiment_names_the_key(blender_scene, tmp_path, caplog):
    path = tmp_path / "exp.json"
    active = {"budget": 4, "physics": {"speed": 0.0}}
    path.write_text(json.dumps({"scenes": [str(blender_scene)], "methods": ["random+fluid"], "active": active}))
    assert cli.main(["experiment", str(path), "--no-progress"]) == 2
    assert "'active.physics.speed' is 0 m/s" in _errors(caplog)


def test_absurd_image_sizes_are_refused_naming_the_camera(data, tmp_path, caplog):
    """Cameras with w = h = 1e9 tied every view with no warning."""
    from recon.camera import MAX_IMAGE_SIDE

    huge = _cameras(tmp_path / "huge.json", w=10**9, h=10**9)
    out = tmp_path / "s.json"
    args = ["score", str(data["ply"]), "--cameras", str(huge), "--result", str(data["h5"]), "-o", str(out), "--no-png"]
    assert cli.main(args) == 2
    msg = _errors(caplog)
    assert "frame 0 (file_path './cam0'): key 'w' (top level) is 1,000,000,000 pixels" in msg
    assert f"more than {MAX_IMAGE_SIDE:,}" in msg and not out.exists()
    with pytest.raises(ValueError, match="Camera 'c': height 70,000 pixels is more than 65,536"):
        Camera(10, 70_000, 5.0, 5.0, 5.0, 5.0, torch.eye(4), "c")


def test_score_removes_its_own_stale_view_images_only(data, tmp_path):
    """Re-running `score` into the same views folder kept the old PNGs beside the new ones."""
    out, views = tmp_path / "s.json", tmp_path / "s_views"
    views.mkdir()
    stale = [views / "rank003_002_cam2.png", views / "rank009_009_old_uncertainty.npy"]
    mine = [views / "notes.png", views / "rank_1.png", views / "readme.txt"]
    for p in stale + mine:
        p.write_bytes(b"x")
    args = ["score", str(data["ply"]), "--cameras", str(data["cameras"]), "--result", str(data["h5"]), "-o", str(out)]
    assert cli.main([*args, "--png-top", "1"]) == 0
    written = sorted(p.name for p in views.iterdir() if p.name.startswith("rank0"))
    assert len(written) == 1 and written[0].startswith("rank001_")
    assert all(p.exists() for p in mine) and not any(p.exists() for p in stale)


def test_render_dataset_into_an_unwritable_folder_is_exit_4(tmp_path, monkeypatch, caplog):
    """render-dataset exited 2 on a read-only output where the other commands exit 4 (root ignores the mode bits,
    so the check is made to see an unwritable folder)."""
    import os

    import recon.mesh_render

    from helpers.paths import TORUS

    real = os.access
    monkeypatch.setattr(recon.mesh_render.os, "access", lambda path, mode, **k: not mode & os.W_OK and real(path, mode))
    assert cli.main(["render-dataset", str(TORUS), "-o", str(tmp_path / "ds"), "--no-progress"]) == 4
    assert "is not writable" in _errors(caplog) and not (tmp_path / "ds").exists()
    monkeypatch.undo()
    (tmp_path / "file").write_text("x")
    assert cli.main(["render-dataset", str(TORUS), "-o", str(tmp_path / "file"), "--no-progress"]) == 4


@pytest.mark.parametrize(
    "body, what",
    [
        (b"\x00\x01\x02garbage" * 2000, "runs past 4,096 bytes"),
        (b"\xff\xfe\x80\n" * 10, "before the non-ASCII bytes at byte 70"),
        (b"comment a\n" * 20000, "within its first 10,000 lines"),
    ],
    ids=["binary", "non-ascii", "endless"],
)
def test_a_ply_header_that_never_ends_says_so(tmp_path, body, what):
    """A header with no end_header was reported as an unknown keyword (the data read as one)."""
    from recon import load_gaussians

    path = tmp_path / "noend.ply"
    path.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\n" + body)
    with pytest.raises(ValueError) as info:
        load_gaussians(path)
    assert "has no 'end_header' line" in str(info.value) and what in str(info.value)
    assert "unknown PLY header keyword" not in str(info.value)


# ---- names and full disks ------------------------------------------------------------------------------------------
def test_a_gaussian_set_with_1d_means_names_the_shape_not_n_minus_1():
    with pytest.raises(ValueError) as info:
        GaussianSet(torch.zeros(3), torch.zeros(1, 4), torch.zeros(1, 3), torch.zeros(1), torch.zeros(1, 1, 3))
    assert "GaussianSet.means must have shape (N, 3)" in str(info.value) and "-1" not in str(info.value)


def test_a_non_utf8_file_name_is_refused_before_the_run(data, tmp_path, caplog):
    """A non-UTF-8 Gaussian file name ran the whole job, then failed writing RESULT.h5 ("'utf-8' codec can't
    encode character '\\udcff'") without naming the file."""
    import os
    import time

    odd = os.fsdecode(os.fsencode(str(tmp_path)) + b"/m\xff.ply")
    shutil.copy(data["ply"], odd)
    t0 = time.monotonic()
    assert cli.main(["simulate", odd, "-o", str(tmp_path / "r.h5"), "--directions=-x", *FAST]) == 2
    assert cli.main(["simulate", str(data["ply"]), "-o", odd[:-4] + ".h5", "--directions=-x", *FAST]) == 2
    assert time.monotonic() - t0 < 5
    msg = _errors(caplog)
    assert "GAUSSIANS b'" in msg and "--output b'" in msg and "m\\xff" in msg and "is not valid UTF-8" in msg
    assert not (tmp_path / "r.h5").exists()


H5_FULL = (
    "Unable to synchronously create dataset (file write failed: time = Thu Dec  3 05:00:00 2026, filename = "
    "'/tmp/x/.fgs-0a1b2c3d.tmp', file descriptor = 5, errno = 28, error message = 'No space left on device', buf = "
    "0x55d0, total write size = 4096, bytes this sub-write = 4096, bytes actually written = 18446744073709551615)"
)


def test_a_full_disk_in_h5py_is_named_in_words(data, tmp_path, monkeypatch, caplog):
    """A full disk printed h5py's raw text (time, file descriptor, buffer address...)."""
    import nbv.io

    def full(*args, **kwargs):
        raise OSError(H5_FULL)

    monkeypatch.setattr(nbv.io.h5py.File, "create_dataset", full)
    out = tmp_path / "r.h5"
    assert cli.main(["simulate", str(data["ply"]), "-o", str(out), "--directions=-x", *FAST]) == 4
    msg = _errors(caplog)
    assert f"cannot write {out}: No space left on device (errno 28)" in msg and "file descriptor" not in msg
    assert "no output was written" in msg and sorted(p.name for p in tmp_path.iterdir()) == []


def test_a_second_output_that_fails_says_which_survived(data, tmp_path, monkeypatch, caplog):
    """RESULT.h5 written, then the coloured .ply hits a full disk: the message says RESULT.h5 is complete."""
    import nbv.outputs
    from fluidsim.files import output_errors

    def full(gaussians, values, path, columns, *reached):
        with output_errors(path):
            raise OSError(H5_FULL)

    monkeypatch.setattr(nbv.outputs, "save_colored_gaussians", full)
    out, ply = tmp_path / "r.h5", tmp_path / "c.ply"
    assert cli.main(["simulate", str(data["ply"]), "-o", str(out), "--ply", str(ply), "--directions=-x", *FAST]) == 4
    msg = _errors(caplog)
    assert f"cannot write {ply}: No space left on device" in msg and f"written before it, complete: {out}" in msg
    assert out.exists() and not ply.exists()
