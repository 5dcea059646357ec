"""Errors instead of tracebacks, and messages that say what is wrong (issue 18, items 5 and 8): Ctrl-C, the memory
estimate of `sim`, floaters that sized the solid lattice, --threads, thin fluid blocks, the active budget, method
names of an experiment, candidate lists, render-frames suffixes and render-dataset parents."""

import json
import logging
import math
import os
import signal
import time

import h5py
import numpy as np
import pytest
import torch

from apps import cli
from apps.options import index_list as parse_ints
from apps.render_frames import output_is_video
from apps.runtime import init_taichi
from fluidsim import memory
from fluidsim.scene import SceneError, lattice_counts, lattice_in_box, parse_scene
from fluidsim.simulation import build_solver
from fluidsim.sources import mesh_particles, wall_particle_count, wall_particles
from nbv import physics
from nbv.physics import PhysicsConfig, floaters
from nbv.physics.lattice import estimate_lattice_points
from nbv.physics.solidify import (
    SceneTransform,
    SolidifyConfig,
    combined_opacity_reference,
    gaussians_to_solid,
)
from nbv.study.experiment_config import ExperimentConfig
from nbv.view_scoring import parse_candidates
from recon.formats.ply import save_gaussians
from recon.gaussians import GaussianSet, concat
from viz.cameras import read_scores

from helpers.logs import error_text
from helpers.paths import ASSETS, TORUS
from helpers.scenes import small_scene
from helpers.spheres import sphere_gaussians

COARSE = dict(particle_radius=0.08, steps=5, dt=0.004, empty_reference=False, directions=("-x",))


def _scene(**over) -> dict:
    return small_scene(**{"steps": 2, "velocity": (0, 0, 0), **over})


def _write_scene(path, **over):
    path.write_text(json.dumps(_scene(**over)))
    return path


def _with_gaussian(base: GaussianSet, mean, log_scale: float, opacity: float) -> GaussianSet:
    one = GaussianSet.from_points(torch.tensor([mean], dtype=torch.float32), scale=1.0, opacity=opacity)
    one = GaussianSet(one.means, one.quats, torch.full_like(one.log_scales, log_scale), one.opacity_logits, one.sh)
    return concat([base, one])


# ---- Ctrl-C ---------------------------------------------------------------------------------------------------
def test_ctrl_c_prints_one_line_and_exits_130(monkeypatch, tmp_path, caplog, capsys):
    from apps import sim

    def interrupted(args):
        os.kill(os.getpid(), signal.SIGINT)  # a real SIGINT: Python's handler raises KeyboardInterrupt
        time.sleep(5)
        raise AssertionError("SIGINT did not arrive")

    monkeypatch.setattr(sim, "run_command", interrupted)
    assert cli.main(["sim", str(tmp_path / "s.json"), "-o", str(tmp_path / "o.h5")]) == 130
    assert "interrupted" in error_text(caplog)
    assert "Traceback" not in capsys.readouterr().err


# ---- sim: the memory estimate ---------------------------------------------------------------------------------
def test_sim_refuses_a_20_km_domain_before_allocating(tmp_path, caplog):
    scene = _write_scene(
        tmp_path / "wide.json",
        domain={"min": [0, 0, 0], "max": [20000, 10, 10], "walls": True},
        fluid_blocks=[{"min": [0.1, 0.1, 0.1], "max": [1, 1, 1]}],
    )
    t0 = time.perf_counter()
    assert cli.main(["sim", str(scene), "-o", str(tmp_path / "new" / "out.h5")]) == 2
    assert time.perf_counter() - t0 < 20
    msg = error_text(caplog)
    assert "would need about" in msg and "domain" in msg and "--max-memory-gb" in msg
    assert "20000 x 10 x 10 m domain" in msg
    assert not (tmp_path / "new").exists()  # refused before the output folder is made


def test_sim_max_memory_gb_is_the_limit(tmp_path, caplog):
    scene = _write_scene(tmp_path / "s.json")
    assert cli.main(["sim", str(scene), "-o", str(tmp_path / "a.h5"), "--max-memory-gb", "1e-4"]) == 2
    assert "the limit is" in error_text(caplog) and "--max-memory-gb" in error_text(caplog)
    assert cli.main(["sim", str(scene), "-o", str(tmp_path / "b.h5"), "--max-memory-gb", "8"]) == 0


def test_scene_counts_match_what_the_solver_builds(tmp_path):
    for lo, hi, s, layers in (([0, 0, 0], [1, 1, 1], 0.1, 2), ([0, -0.2, 0.1], [1.05, 0.33, 2.0], 0.07, 3)):
        assert wall_particle_count(lo, hi, s, layers) == len(wall_particles(lo, hi, s, layers))
        assert int(np.prod(lattice_counts(lo, hi, s))) == len(lattice_in_box(lo, hi, s))
    assert np.prod(lattice_counts([0, 0, 0], [0.05, 1, 1], 0.1)) == 0
    np.save(tmp_path / "pts.npy", np.full((37, 3), 0.8))
    scene = parse_scene(_scene(solids=[{"points": "pts.npy"}]), tmp_path)
    est = memory.estimate_scene_memory(scene)
    solver = build_solver(scene)
    assert est.grid_cells == solver.grid.num_cells
    assert est.fluid_particles == solver.fluid.capacity + solver.removed_inside_solid
    assert est.wall_particles + est.solid_particles == solver.boundary.count
    assert est.bytes == pytest.approx(sum(est.parts().values()))


def test_mesh_solid_estimate_is_an_upper_bound(tmp_path):
    spacing = 0.1  # the scene's particle_radius 0.05
    empty = memory.estimate_scene_memory(parse_scene(_scene(), tmp_path))
    for fill in (False, True):
        scene = parse_scene(_scene(solids=[{"mesh": str(TORUS), "fill": fill}]), tmp_path)
        est = memory.estimate_scene_memory(scene)
        count, sampling = est.solid_particles - empty.solid_particles, est.sampling_bytes - empty.sampling_bytes
        actual = len(mesh_particles(TORUS, spacing, fill))
        assert actual <= count < 3 * actual and sampling > 0


# ---- floaters do not size the solid lattice -----------------------------------------------------------------------
def test_a_faint_huge_floater_does_not_size_the_lattice():
    sphere = sphere_gaussians()
    cfg = SolidifyConfig(spacing=0.16)
    tr = SceneTransform()
    floater = _with_gaussian(sphere, [0.1, 0.0, 0.0], 10.0, 0.1)  # o = 0.1 < tau = 0.3, 3 sigma = 66 km
    assert estimate_lattice_points(floater, cfg, tr) == estimate_lattice_points(sphere, cfg, tr)
    solid = gaussians_to_solid(floater, cfg, tr)
    assert solid.lattice_shape == gaussians_to_solid(sphere, cfg, tr).lattice_shape
    pcfg = PhysicsConfig(**COARSE, scale=1.0)
    assert (
        physics.estimate_memory(physics.RunFrame.of(floater, pcfg))["fluid_particles"]
        == physics.estimate_memory(physics.RunFrame.of(sphere, pcfg))["fluid_particles"]
    )


def test_simulate_runs_with_one_faint_floater(tmp_path):
    ply = save_gaussians(_with_gaussian(sphere_gaussians(), [0.1, 0.0, 0.0], 10.0, 0.1), tmp_path / "floater.ply")
    assert (
        cli.main(
            [
                "simulate",
                str(ply),
                "-o",
                str(tmp_path / "r.h5"),
                "--particle-radius",
                "0.08",
                "--steps",
                "4",
                "--dt",
                "0.004",
                "--no-empty-reference",
                "--threads",
                "2",
                "--directions=-x",
            ]
        )
        == 0
    )


def test_an_opaque_huge_gaussian_is_named():
    sphere = sphere_gaussians()
    huge = _with_gaussian(sphere, [0.1, 0.0, 0.0], 10.0, 0.9)
    with pytest.raises(ValueError, match="Gaussian 300 .*centre .*opacity 0.9") as err:
        gaussians_to_solid(huge, SolidifyConfig(spacing=0.16), SceneTransform())
    assert "a --crop box keeps it" in str(err.value)
    with pytest.raises(ValueError, match="Gaussian 300") as err:
        physics.check_memory(physics.RunFrame.of(huge, PhysicsConfig(**COARSE, scale=1.0)))
    assert "cannot help" in str(err.value) and "use a particle radius" not in str(err.value)


def test_a_far_opaque_speck_is_named_with_crop():
    sphere = sphere_gaussians()
    far = _with_gaussian(sphere, [60.0, 0.0, 0.0], math.log(0.06), 0.9)
    near = physics.estimate_memory(physics.RunFrame.of(sphere, PhysicsConfig(**COARSE, scale=1.0)))["bytes"]
    cfg = PhysicsConfig(**COARSE, scale=1.0, max_memory_gb=2 * near / 2**30)
    with pytest.raises(ValueError, match="Gaussian 300 .*centre \\(60, 0, 0\\).*--crop"):
        physics.check_memory(physics.RunFrame.of(far, cfg))
    # without a dominant Gaussian the advice is the radius that fits (the fluid's bytes shrink with it, the
    # Gaussians' do not), or, when the Gaussians alone do not fit, cropping them
    parts = physics.estimate_memory(physics.RunFrame.of(sphere, PhysicsConfig(**COARSE, scale=1.0)))
    with pytest.raises(ValueError, match="particle radius of about"):
        limit = (near - parts["probe_bytes"] / 2) / 2**30
        physics.check_memory(physics.RunFrame.of(sphere, PhysicsConfig(**COARSE, scale=1.0, max_memory_gb=limit)))
    with pytest.raises(ValueError, match="Gaussians alone need about .*cannot help: crop them"):
        physics.check_memory(
            physics.RunFrame.of(sphere, PhysicsConfig(**COARSE, scale=1.0, max_memory_gb=near / 4 / 2**30))
        )


def test_others_box_matches_brute_force():
    rng = np.random.default_rng(3)
    lo = rng.normal(size=(9, 3))
    hi = lo + rng.uniform(0.1, 2.0, (9, 3))
    lo[4, 1] = lo[:, 1].min()  # a tie on one axis
    olo, ohi = floaters.others_box(lo, hi)
    for i in range(9):
        rest = np.delete(np.arange(9), i)
        assert np.array_equal(olo[i], lo[rest].min(0)) and np.array_equal(ohi[i], hi[rest].max(0))


def test_clipped_boxes_keep_every_solid_point():
    """Brute force over the unclipped lattice: every point whose combined opacity reaches tau lies in the box of
    the clipped (solid-capable) boxes, while isolated faint Gaussians no longer widen it."""
    rng = np.random.default_rng(7)
    strong = rng.uniform(-0.3, 0.3, (20, 3))
    isolated = np.array([[1.6, 0.0, 0.0], [0.0, -1.7, 0.4], [-1.5, 1.5, 0.0]])
    pair = np.array([[0.0, 0.0, 1.6], [0.02, 0.0, 1.62]])  # two faint ones that together reach tau
    means = np.concatenate([strong, isolated, pair])
    sig = np.concatenate([rng.uniform(0.04, 0.1, 20), [0.08, 0.08, 0.08], [0.08, 0.08]])
    opac = np.concatenate([rng.uniform(0.35, 0.95, 20), [0.25, 0.2, 0.1], [0.25, 0.25]])
    covs = (sig**2)[:, None, None] * np.eye(3)
    tau, s = 0.3, 0.04
    ext = 3.0 * sig[:, None]
    lo, hi, keep = floaters.solid_capable_boxes(means - ext, means + ext, opac, tau)
    blo, bhi = floaters.lattice_extent(lo, hi, keep)
    assert not keep[20:23].any() and keep[23:].all()
    axes = [np.arange(a, b + s, s) for a, b in zip((means - ext).min(0), (means + ext).max(0), strict=True)]
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    solid = pts[combined_opacity_reference(pts, means, covs, opac, sigma_cutoff=3.0) >= tau]
    assert len(solid) and (solid[:, 2] > 1.4).any()  # the pair makes solid far out: it must stay in the box
    assert (solid >= blo - 1e-9).all() and (solid <= bhi + 1e-9).all()
    assert bhi[0] < 0.7 and blo[1] > -0.7  # the isolated ones are gone


def test_dominant_gaussian_only_when_one_widens_the_box():
    means = np.random.default_rng(0).uniform(-0.5, 0.5, (50, 3))
    lo, hi = means - 0.05, means + 0.05
    keep = np.ones(50, bool)
    assert floaters.dominant_gaussian(lo, hi, keep, 0.1) is None
    lo[17, 0] -= 30.0
    index, factor = floaters.dominant_gaussian(lo, hi, keep, 0.1)
    assert index == 17 and factor > 20


# ---- --threads ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("value", ["-1", "0", "two"])
def test_threads_must_be_positive(tmp_path, capsys, value):
    scene = _write_scene(tmp_path / "s.json")
    with pytest.raises(SystemExit) as exc:
        cli.main(["sim", str(scene), "-o", str(tmp_path / "o.h5"), "--threads", value])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--threads" in err and ">= 1" in err and "_M_default_append" not in err
    with pytest.raises(SystemExit):
        cli.main(["simulate", "g.ply", "-o", str(tmp_path / "r.h5"), "--threads", value])


def test_init_taichi_refuses_bad_threads():
    for bad in (-1, 0, 2.5, True):
        with pytest.raises(ValueError, match="--threads must be an integer >= 1"):
            init_taichi("cpu", "f32", bad)


# ---- fluid blocks -------------------------------------------------------------------------------------------------
def test_a_block_thinner_than_the_spacing_is_not_said_to_lie_in_a_solid(tmp_path, caplog):
    thin = [{"min": [0.4, 0.4, 0.4], "max": [0.45, 0.6, 0.6]}]
    with pytest.raises(SceneError, match=r"fluid_blocks\[0\].*0.05 m along x, less than the particle spacing 0.1 m"):
        parse_scene(_scene(fluid_blocks=thin))
    assert (
        cli.main(["sim", str(_write_scene(tmp_path / "s.json", fluid_blocks=thin)), "-o", str(tmp_path / "o.h5")]) == 2
    )
    assert "solid" not in error_text(caplog) and "particle spacing" in error_text(caplog)


def test_fluid_removed_by_a_solid_says_how_many_and_why(tmp_path):
    lattice = lattice_in_box([0.1, 0.1, 0.1], [0.5, 0.5, 0.5], 0.1)
    np.save(tmp_path / "block.npy", lattice)
    scene = parse_scene(_scene(solids=[{"points": "block.npy"}]), tmp_path)
    with pytest.raises(ValueError, match=f"all {len(lattice)} fluid particles .*0.9 particle spacings"):
        build_solver(scene)


# ---- active: budget and method ------------------------------------------------------------------------------------
def _fake_dataset(folder, frames: int):
    folder.mkdir()
    eye = np.eye(4).tolist()
    (folder / "transforms_train.json").write_text(
        json.dumps(
            {
                "camera_angle_x": 0.8,
                "frames": [{"file_path": f"./train/r_{i}", "transform_matrix": eye} for i in range(frames)],
            }
        )
    )
    return folder


def test_active_budget_above_the_candidates(tmp_path, caplog):
    ds = _fake_dataset(tmp_path / "ds", 12)
    assert cli.main(["active", str(ds), "-o", str(tmp_path / "run"), "--budget", "50"]) == 2
    msg = error_text(caplog)
    assert "--budget 50 is more than the 12 candidate (train) views" in msg and "iteration" not in msg


def test_active_schedule_speaks_of_the_options(tmp_path, caplog):
    ds = _fake_dataset(tmp_path / "ds", 100)
    assert cli.main(["active", str(ds), "-o", str(tmp_path / "run"), "--budget", "30"]) == 2
    msg = error_text(caplog)
    assert "--iterations 43400 or more" in msg and "--iters-per-view" in msg and "ActiveConfig" not in msg


def test_active_unknown_method(tmp_path, caplog):
    ds = _fake_dataset(tmp_path / "ds", 12)
    assert cli.main(["active", str(ds), "-o", str(tmp_path / "run"), "--method", "fishr+fluid"]) == 2
    assert "--method 'fishr+fluid' is not a planner" in error_text(caplog)


def test_experiment_config_checks_method_names_when_it_loads(tmp_path):
    with pytest.raises(ValueError, match="'fishr\\+fluid' is not a planner \\(did you mean 'fisher\\+fluid'\\?\\)"):
        ExperimentConfig(scenes=("a",), methods=("random", "fishr+fluid"))
    with pytest.raises(ValueError, match="'fishr@-x' is not a planner"):
        ExperimentConfig(scenes=("a",), methods=("fishr@-x",))
    path = tmp_path / "exp.json"
    path.write_text(json.dumps({"scenes": ["a"], "methods": ["random", "varaince"]}))
    with pytest.raises(ValueError, match="'varaince' is not a planner"):
        ExperimentConfig.load(path)
    assert ExperimentConfig(scenes=("a",), methods=("random", "fisher+fluid@-z")).methods[1] == "fisher+fluid@-z"


# ---- candidate lists ----------------------------------------------------------------------------------------------
def test_candidate_lists():
    for empty in ("", ",", " , "):
        with pytest.raises(ValueError, match="lists no camera.*leave the option out to score all 6"):
            parse_candidates(empty, 6)
    with pytest.raises(ValueError, match=r"camera\(s\) \[1\] more than once"):
        parse_candidates("1,3,1", 6)
    with pytest.raises(ValueError, match=r"\[6\] out of range"):
        parse_candidates("0,6", 6)
    assert parse_candidates("4, 2", 6) == [4, 2] and parse_candidates(None, 3) == [0, 1, 2]
    with pytest.raises(ValueError, match=r"--initial-views '0,0' lists \[0\] more than once"):
        parse_ints("0,0", "--initial-views")
    with pytest.raises(ValueError, match="indices start at 0"):
        parse_ints("-1,2", "--initial-views")


# ---- render-frames and render-dataset ------------------------------------------------------------------------------
def test_render_frames_output_kinds(tmp_path):
    assert output_is_video(tmp_path / "v.mp4") and output_is_video(tmp_path / "V.MP4")
    assert not output_is_video(tmp_path / "frames")
    assert not output_is_video(tmp_path / "run.v2", png=True)
    for bad in ("x.avi", "x.gif", "frame.png"):
        with pytest.raises(ValueError, match="\\.mp4.*--png"):
            output_is_video(tmp_path / bad)
    with pytest.raises(ValueError, match="drop --png"):
        output_is_video(tmp_path / "v.mp4", png=True)


def test_render_frames_refuses_avi_and_writes_pngs_with_png(tmp_path, caplog):
    h5 = tmp_path / "sim.h5"
    assert cli.main(["sim", str(_write_scene(tmp_path / "s.json")), "-o", str(h5), "--save-every", "1"]) == 0
    assert cli.main(["render-frames", str(h5), "-o", str(tmp_path / "x.avi")]) == 2
    assert ".mp4" in error_text(caplog) and not (tmp_path / "x.avi").exists()
    out = tmp_path / "run.v2"
    assert cli.main(["render-frames", str(h5), "-o", str(out), "--png", "--width", "160", "--height", "120"]) == 0
    assert len(list(out.glob("frame_*.png"))) == 3


def test_render_dataset_creates_the_parents(tmp_path, caplog):
    out = tmp_path / "a" / "b"
    args = ["--train", "2", "--test", "1", "--res", "16", "--supersample", "1", "--no-progress"]
    assert cli.main(["render-dataset", str(TORUS), "-o", str(out), *args]) == 0
    assert (out / "transforms_train.json").is_file()
    (tmp_path / "file").write_text("x")
    assert cli.main(["render-dataset", str(TORUS), "-o", str(tmp_path / "file" / "c" / "d"), *args]) == cli.EXIT_OUTPUT
    assert "is a file" in error_text(caplog)


@pytest.mark.parametrize(
    "args, message",
    [
        (["--train", "100000000", "--test", "1"], "--train + --test must be at most 10,000 views"),
        (["--res", "1000000"], "--res must be at most 2048 pixels at --supersample 2"),
        (["--res", "2048", "--supersample", "4"], "--res must be at most 1024 pixels at --supersample 4"),
    ],
)
def test_render_dataset_bounds_views_and_resolution_naming_the_options(tmp_path, caplog, args, message):
    """10^8 views ran silent for hours; --res 1000000 spoke of "the camera view_000's image size"."""
    assert cli.main(["render-dataset", str(TORUS), "-o", str(tmp_path / "ds"), *args]) == 2
    assert message in error_text(caplog) and "view_000" not in error_text(caplog)
    assert list(tmp_path.iterdir()) == []


def test_render_frames_output_that_cannot_be_written_is_exit_4(tmp_path, caplog):
    """A parent that is a file (or a read-only folder) was a plain OSError without errno: exit 2, "bad input"."""
    _write_scene(tmp_path / "scene.json")
    assert cli.main(["sim", str(tmp_path / "scene.json"), "-o", str(tmp_path / "OUT.h5"), "--threads", "1"]) == 0
    (tmp_path / "file").write_text("x")
    for out in (tmp_path / "file" / "f.mp4", tmp_path / "file" / "pngs"):
        caplog.clear()
        assert cli.main(["render-frames", str(tmp_path / "OUT.h5"), "-o", str(out)]) == cli.EXIT_OUTPUT, out
        assert f"{tmp_path / 'file'} is a file, not a folder" in error_text(caplog)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["OUT.h5", "file", "scene.json"]


# ---- JSON files a user hands in: one reader, one line each ------------------------------------------------------
BAD_JSON = {
    "deep": b"[" * 100000 + b"]" * 100000,  # RecursionError inside json
    "deep object": b'{"a": ' * 100000 + b"1" + b"}" * 100000,
    "empty": b"",
    "not UTF-8": b"\xff\xfe\x00{",
    "huge integer": b"1" * 5000,  # ValueError: more than 4,300 digits
    "truncated": b'{"frames": [{"transform_matrix": ',
}


@pytest.mark.parametrize("kind", sorted(BAD_JSON))
def test_every_json_input_gives_one_line_naming_the_file(tmp_path, caplog, kind):
    bad = tmp_path / "bad.json"
    bad.write_bytes(BAD_JSON[kind])
    dataset, run = tmp_path / "dataset", tmp_path / "run"
    dataset.mkdir()
    run.mkdir()
    (dataset / "transforms_train.json").write_bytes(BAD_JSON[kind])
    (run / "config.json").write_bytes(BAD_JSON[kind])
    (run / "gaussians.ply").write_bytes((ASSETS / "ahmed_gaussians.ply").read_bytes())
    cases = [
        (["sim", str(bad), "-o", str(tmp_path / "o.h5")], bad),
        (["score", str(ASSETS / "ahmed_gaussians.ply"), "--cameras", str(bad), "-o", str(tmp_path / "s.json")], bad),
        (["study", "oracle", str(bad)], bad),
        (["train", str(dataset), "-o", str(tmp_path / "t.ply")], dataset / "transforms_train.json"),
        (["eval", str(run)], run / "config.json"),
    ]
    for argv, named in cases:
        caplog.clear()
        assert cli.main(argv) == 2, argv
        errors = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
        assert len(errors) == 1 and "\n" not in errors[0] and str(named) in errors[0], (argv, errors)
        assert "Traceback" not in caplog.text and "Error:" not in errors[0], errors[0]
    with pytest.raises(ValueError, match=r"--scores \S*bad\.json .*; write it with `fluidgs score"):
        read_scores(bad)


def test_a_truncated_hdf5_file_is_named_by_render_frames_and_export(tmp_path, caplog):
    whole, cut = tmp_path / "whole.h5", tmp_path / "OUT.h5"
    with h5py.File(whole, "w") as f:
        f.create_dataset("frames/000000/x", data=np.zeros((20000, 3), np.float32))
    cut.write_bytes(whole.read_bytes()[:5000])  # the HDF5 signature is there; the rest is cut off
    assert h5py.is_hdf5(cut)
    for argv in (
        ["render-frames", str(cut), "-o", str(tmp_path / "f.mp4")],
        ["export", str(cut), "--vtk", str(tmp_path / "vtk")],
    ):
        caplog.clear()
        assert cli.main(argv) == 2, argv
        errors = error_text(caplog)
        assert f"{cut} is a truncated or damaged HDF5 file" in errors and "write it again" in errors, errors
    assert sorted(p.name for p in tmp_path.iterdir()) == ["OUT.h5", "whole.h5"]


def test_steps_are_bounded_before_any_allocation(tmp_path, caplog):
    """`simulate --steps 99999999999` was a Taichi traceback (no ndarray of that shape); `sim` failed late with
    "File too large" for the room its statistics needed."""
    from fluidsim.config import MAX_STEPS

    scene = _write_scene(tmp_path / "scene.json")
    big = str(MAX_STEPS + 1)
    assert cli.main(["sim", str(scene), "-o", str(tmp_path / "o.h5"), "--steps", big]) == 2
    assert f"--steps must be at most {MAX_STEPS:,} time steps" in error_text(caplog)
    caplog.clear()
    _write_scene(scene, steps=99999999999)
    assert cli.main(["sim", str(scene), "-o", str(tmp_path / "o.h5")]) == 2
    assert "scene key 'steps' = 99999999999 is more than the 1,000,000" in error_text(caplog)
    caplog.clear()
    ply = save_gaussians(sphere_gaussians(), tmp_path / "g.ply")
    assert cli.main(["simulate", str(ply), "-o", str(tmp_path / "r.h5"), "--quick", "--steps", "99999999999"]) == 2
    assert "--steps must be at most 1,000,000 time steps per probe" in error_text(caplog)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["g.ply", "scene.json"]
    with pytest.raises(ValueError, match="at most 1,000,000"):
        PhysicsConfig(steps=MAX_STEPS + 1)
