"""Evaluation of active runs (nbv.study.evaluate, `fluidgs eval`) and experiments (nbv.study.experiment,
`fluidgs experiment`)."""

import csv
import importlib.util
import json
import math
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from nbv.active import ActiveConfig, run_active
from nbv.physics import PhysicsConfig
from nbv.study.evaluate import EvalConfig, evaluate_run, sample_mesh_surface
from nbv.study.tables import build_tables, mean_std

from helpers.paths import TORUS
from helpers.study_rows import result_row

COARSE = {"particle_radius": 0.08, "steps": 20, "dt": 0.004, "directions": ["-x", "+z"]}
TINY_ACTIVE = {
    "budget": 3,
    "iterations_per_view": 2,
    "total_iterations": 40,
    "resolution": 16,
    "backend": "torch",
    "train": {
        "init_points": 150,
        "sh_degree": 0,
        "max_gaussians": 300,
        "init_opacity": 0.5,
        "opacity_reset_interval": 100000,
        "densify_from_iter": 0,
    },
    "physics": COARSE,
}


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory):
    """The torus rendered at 24 px: 8 candidate views, 3 test views, with its reference mesh."""
    from recon.mesh_render import MeshDatasetConfig, render_mesh_dataset

    out = tmp_path_factory.mktemp("experiment") / "torus"
    return render_mesh_dataset(
        TORUS, out, MeshDatasetConfig(n_train=8, n_test=3, resolution=24, supersample=1), progress=False
    )


@pytest.fixture(scope="module")
def finished_run(tiny_dataset, tmp_path_factory):
    run = tmp_path_factory.mktemp("eval") / "run"
    cfg = ActiveConfig.from_preset("cpu-small", method="random", **TINY_ACTIVE)
    run_active(tiny_dataset, run, cfg, progress=False)
    return run


# ---- evaluation ----------------------------------------------------------------------------------


def test_sample_mesh_surface_is_on_the_surface_and_area_weighted():
    # two triangles in the z = 0 plane with areas 0.5 and 1.5
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [3, 0, 0], [3, 1, 0], [0, 0, 0]], float)
    vertices[5] = [0, 3, 0]
    triangles = np.array([[0, 1, 2], [3, 4, 5]])
    pts = sample_mesh_surface(vertices, triangles, 20000, seed=1)
    assert np.allclose(pts[:, 2], 0.0)
    in_first = (pts[:, 0] >= 0) & (pts[:, 1] >= 0) & (pts[:, 0] + pts[:, 1] <= 1 + 1e-12)
    area2 = 0.5 * np.linalg.norm(np.cross(vertices[4] - vertices[3], vertices[5] - vertices[3]))
    assert abs(in_first.mean() - 0.5 / (0.5 + area2)) < 0.02
    np.testing.assert_array_equal(pts, sample_mesh_surface(vertices, triangles, 20000, seed=1))


def test_eval_json_keys_and_finite_metrics(finished_run):
    from recon.datasets import load_dataset
    from recon.formats import load_gaussians
    from recon.train import evaluate

    out = evaluate_run(
        finished_run, EvalConfig(physics=PhysicsConfig.from_dict(COARSE), critical_views=2), progress=False
    )
    stored = json.loads((finished_run / "eval.json").read_text())
    assert stored == out
    for key in ("psnr", "ssim", "dbar", "dbar_empty", "chamfer", "critical_psnr", "critical_dbar"):
        assert isinstance(out[key], float) and math.isfinite(out[key]), key
    # the functional error against the torus mesh, beside its floor (nbv.functional), in the summary too
    assert math.isfinite(out["functional_error"]) and out["functional_error"] >= 0, out.get("reason_functional")
    assert math.isfinite(out["functional_floor"]) and out["summary"]["functional_error"] == out["functional_error"]
    assert out["functional"]["metric"] == "mean_force" and "-x" in out["functional"]["probes"]
    assert out["lpips"] == "unavailable" or math.isfinite(out["lpips"])
    assert set(out["dbar_per_direction"]) == {"-x", "+z"}
    # D_g is the max over the probes, so D-bar lies between the largest and the sum of the per-direction D-bars
    per_dir = list(out["dbar_per_direction"].values())
    assert max(per_dir) * (1 - 1e-9) <= out["dbar"] <= sum(per_dir) * (1 + 1e-9)
    assert len(out["critical_views"]) == 2 and len(out["critical_scores"]) == 3
    # the critical subset is the top 2 by C(T), and its PSNR is the mean over those views
    order = sorted(range(3), key=lambda i: -out["critical_scores"][i])[:2]
    names = [out["per_view"][i]["name"] for i in order]
    assert out["critical_views"] == names
    assert out["critical_psnr"] == pytest.approx(np.mean([out["per_view"][i]["psnr"] for i in order]))
    # visual metrics agree with the trainer's evaluate (the reference computation)
    ds = load_dataset(json.loads((finished_run / "config.json").read_text())["dataset"], resolution=16)
    ref = evaluate(load_gaussians(finished_run / "gaussians.ply"), ds.test, ds.background, backend="torch")
    assert out["psnr"] == pytest.approx(ref["psnr"], abs=1e-5) and out["ssim"] == pytest.approx(ref["ssim"], abs=1e-6)
    # the scene -> metres scale is pinned to the reference mesh (largest extent -> target_extent = 2 m)
    from recon.mesh_render import load_mesh

    vertices, _ = load_mesh(ds.mesh_path)
    assert out["scale_m_per_unit"] == pytest.approx(2.0 / np.ptp(vertices, axis=0).max())
    assert "| random |" in (finished_run / "eval.md").read_text()
    assert not [p for p in finished_run.iterdir() if p.name.endswith(".tmp")]


def test_eval_cli_smoke_and_bad_input(finished_run, tmp_path):
    from apps.cli import main

    assert (
        main(
            [
                "eval",
                str(finished_run),
                "--particle-radius",
                "0.1",
                "--probe-steps",
                "6",
                "--directions=-x",
                "--critical-views",
                "1",
                "--chamfer-samples",
                "500",
                "--threads",
                "1",
                "--no-progress",
            ]
        )
        == 0
    )
    out = json.loads((finished_run / "eval.json").read_text())
    assert out["physics_config"]["particle_radius"] == 0.1 and len(out["critical_views"]) == 1
    assert main(["eval", str(tmp_path)]) == 2  # not a run folder


# ---- tables --------------------------------------------------------------------------------------


def row(method, seed, psnr, dbar, kind="method"):
    per_direction = {"-x": dbar, "+x": dbar / 4}
    return result_row(
        method, "s", seed, psnr, dbar, kind, dbar_empty=2.0, critical_dbar=dbar / 2, dbar_per_direction=per_direction
    )


def test_mean_std_and_tables():
    assert mean_std([1.0, 3.0, None, float("nan")]) == (2.0, pytest.approx(math.sqrt(2.0)), 2)
    assert mean_std([None]) == (None, None, 0)
    rows = [
        row("random", 0, 20.0, 0.5),
        row("random", 1, 22.0, 0.7),
        row("fisher+fluid", 0, 21.0, 0.3),
        row("reference-20views", 0, 25.0, 0.1, kind="reference"),
    ]
    tables = build_tables(rows)
    assert set(tables) == {"visual", "physics", "ablation_random", "ablation_direction"}
    vis = list(csv.reader(tables["visual"][1].splitlines()))
    assert vis[0][:3] == ["method", "n", "PSNR (dB)"]
    # one run has no spread: n/a, not 0
    assert vis[1][:3] == ["random", "2", "21.0000 ± 1.4142"] and vis[2][:3] == ["fisher+fluid", "1", "21.0000 ± n/a"]
    assert vis[3][0] == "reference-20views"
    phys = {r[0]: r for r in csv.reader(tables["physics"][1].splitlines())}
    assert phys["empty scene (reference)"][2] == "2.0000 ± 0.0000"
    assert phys["many-view: reference-20views"][2] == "0.1000 ± n/a"
    abl = [r[0] for r in csv.reader(tables["ablation_random"][1].splitlines())][1:]
    assert abl == ["random", "fisher+fluid"]
    dirs = list(csv.reader(tables["ablation_direction"][1].splitlines()))
    assert dirs[0][2:4] == ["D-bar -x (m^4/s)", "D-bar +x (m^4/s)"] and dirs[1][3] == "0.1500 ± 0.0354"


def cameras_only_scene(root: Path, views: int, width: int, height: int) -> str:
    """A Blender folder with cameras and no images: what the estimate reads (views, image size)."""
    root.mkdir(parents=True)
    frames = [{"file_path": f"train/r_{i:03d}", "transform_matrix": np.eye(4).tolist()} for i in range(views)]
    meta = {"camera_angle_x": 0.7, "w": width, "h": height, "frames": frames}
    (root / "transforms_train.json").write_text(json.dumps(meta))
    return str(root)


def test_the_time_estimate_comes_from_the_configs_own_protocol(tmp_path):
    from nbv.study.cost import MEASURED, parallel
    from nbv.study.experiment import actual_line, job_estimate, plan_jobs, scene_facts, time_estimate
    from nbv.study.experiment_config import ExperimentConfig

    scene = cameras_only_scene(tmp_path / "scene", views=12, width=80, height=60)
    assert scene_facts(scene, 32).pixels == 32 * 24 and scene_facts(scene, None).pixels == 80 * 60
    assert scene_facts(scene, 32).views == 12 and scene_facts(str(tmp_path / "missing"), 32) is None

    def config(seeds, **active):
        return ExperimentConfig(
            scenes=(scene,),
            methods=("fisher", "fisher+fluid"),
            seeds=seeds,
            output=str(tmp_path / "o"),
            reference_views=None,
            active={"resolution": 32, "budget": 4, **active},
            eval={"physics": {"particle_radius": 0.1, "steps": 40, "directions": ["-x"]}},
        )

    jobs = plan_jobs(config((0,)))
    one = job_estimate(jobs[1], scene_facts(scene, 32))
    a = ActiveConfig.from_dict(jobs[1]["active"])
    assert one["training"] == pytest.approx(MEASURED.train_s * a.total_iterations * 32 * 24)
    eval_steps = 40 * 2 * (0.05 / 0.1) ** 3  # one probe and its empty scene, at r = 0.1 m
    assert one["eval"] == pytest.approx(
        eval_steps * MEASURED.eval_step_s + 4000 * MEASURED.probe_gaussian_s + MEASURED.eval_s
    )
    line, est = time_estimate(jobs, workers=1, threads=1, cores=2, slowdown=1.0)
    assert line.startswith("estimate: 2 jobs to run: about ")
    assert "12 views of 768 px" in line and "budget 4" in line
    # N seeds cost N times one seed; the start-up is paid once per worker
    _, three = time_estimate(plan_jobs(config((0, 1, 2))), workers=1, threads=1, cores=2, slowdown=1.0)
    assert three.wall_s - MEASURED.start_s == pytest.approx(3 * (est.wall_s - MEASURED.start_s))
    # two threads on two cores halve the work; a third worker finds no free core
    _, two = time_estimate(jobs, workers=2, threads=1, cores=2, slowdown=1.0)
    assert two.wall_s == pytest.approx(est.wall_s / 2 - MEASURED.start_s / 2 + 2 * MEASURED.start_s)
    assert parallel(3, 1, 2) == 2 and parallel(1, 4, 16) == 4
    # other processes: a thread that gets a third of a core takes three times as long
    line, loaded = time_estimate(jobs, workers=1, threads=1, cores=2, slowdown=3.0)
    assert loaded.wall_s == pytest.approx(3 * est.wall_s) and "x 3.0: a thread gets 1/3.0 of a core now" in line
    assert "actual / estimate = 2.00" in actual_line(est, 2 * est.wall_s, 2)
    done = Path(jobs[0]["run_dir"])  # a resumed experiment does not count its finished jobs
    done.mkdir(parents=True)
    (done / "eval.json").write_text("{}")
    (done / "gaussians.ply").write_text("")
    assert time_estimate(jobs, slowdown=1.0)[0].startswith("estimate: 1 job to run (1 already done)")
    unread = plan_jobs(replace_scenes(config((0,)), str(tmp_path / "missing")))
    assert "cannot be read" in time_estimate(unread)[0] and time_estimate(unread)[1] is None


def replace_scenes(config, scene):
    from dataclasses import replace

    return replace(config, scenes=(scene,))


def test_single_direction_methods_and_their_table():
    from nbv.study.experiment_config import ExperimentConfig, method_folder, split_method

    assert split_method("fisher+fluid@-x") == ("fisher+fluid", "-x") and split_method("fisher") == ("fisher", None)
    assert method_folder("fisher+fluid@-x") == "fisher_fluid_at-x"
    assert method_folder("fisher+fluid@+x") == "fisher_fluid_at+x"
    assert method_folder("variance+fluid") == "variance_fluid"
    with pytest.raises(ValueError, match="unknown probe direction"):
        split_method("fisher+fluid@+y")
    with pytest.raises(ValueError, match="uses\\s+the physics|uses the physics"):
        split_method("fisher@-x")
    config = ExperimentConfig(
        scenes=("a",),
        methods=("fisher", "fisher+fluid", "fisher+fluid@-z"),
        seeds=(0,),
        active={"physics": {"steps": 30}},
    )
    single = config.active_config("fisher+fluid@-z", 0)
    assert single.method == "fisher+fluid" and single.physics.directions == ("-z",) and single.physics.steps == 30
    assert config.active_config("fisher+fluid", 0).physics.directions == ("-x", "+x", "-z", "+z", "-y")
    with pytest.raises(ValueError, match="unknown probe direction"):
        ExperimentConfig(scenes=("a",), methods=("fisher+fluid@up",), seeds=(0,))

    rows = [
        row("fisher", 0, 20.0, 0.5),
        row("fisher+fluid", 0, 22.0, 0.3),
        row("fisher+fluid@-z", 0, 21.0, 0.4),
        row("fisher+fluid@-x", 0, 21.5, 0.35),
        row("random", 0, 19.0, 0.6),
    ]
    tables = build_tables(rows)
    body = list(csv.reader(tables["ablation_selection_direction"][1].splitlines()))
    assert [r[0] for r in body[1:]] == ["fisher", "fisher+fluid", "fisher+fluid@-x", "fisher+fluid@-z"]
    assert [r[1] for r in body[1:]] == ["none", "all five probes", "-x", "-z"]
    assert body[3][3] == "21.5000 ± n/a"
    assert "@" not in "".join(r[0] for r in csv.reader(tables["ablation_random"][1].splitlines()))
    # the evaluation of a single-direction run still measures D-bar over all five probes
    from nbv.study.evaluate import EvalConfig, eval_physics_config

    ev = eval_physics_config(single.physics, EvalConfig(), "z")
    assert ev.directions == ("-x", "+x", "-z", "+z", "-y") and ev.up == "+z" and ev.track_distinct
    assert ev.steps == single.physics.steps
    explicit = eval_physics_config(single.physics, EvalConfig(physics=PhysicsConfig(directions=("+z",))), "y")
    assert explicit.directions == ("+z", "-x")  # an explicit choice is kept; the critical direction is added


# ---- experiment ----------------------------------------------------------------------------------


def test_experiment_local_executor_end_to_end(tiny_dataset, tmp_path):
    from apps.cli import main

    config = {
        "scenes": [str(tiny_dataset)],
        "methods": ["random", "physics"],
        "seeds": [0, 1],
        "preset": "cpu-small",
        "output": "out",
        "reference_views": 4,
        "active": TINY_ACTIVE,
        "eval": {"physics": COARSE, "critical_views": 2, "chamfer_samples": 500},
    }
    path = tmp_path / "exp.json"
    path.write_text(json.dumps(config))
    args = ["experiment", str(path), "--executor", "local", "--workers", "1", "--threads", "1", "--no-progress"]
    assert main(args) == 0
    out = tmp_path / "out"
    rows = json.loads((out / "results.json").read_text())["rows"]
    assert len(rows) == 2 * 2 + 2  # methods x seeds, plus one many-view reference per seed
    assert {(r["method"], r["seed"]) for r in rows} >= {("random", 0), ("random", 1), ("physics", 0), ("physics", 1)}
    for name in ("visual", "physics", "ablation_random", "ablation_direction"):
        assert (out / "tables" / f"{name}.md").is_file()
        body = list(csv.reader((out / "tables" / f"{name}.csv").read_text().splitlines()))
        assert len(body) >= 3
    vis = {r[0]: r for r in csv.reader((out / "tables" / "visual.csv").read_text().splitlines())}
    assert vis["random"][1] == "2" and vis["physics"][1] == "2" and vis["reference-4views"][1] == "2"
    for png in ("psnr.png", "dbar.png"):
        img = cv2.imread(str(out / "plots" / png))
        assert img is not None and img.shape[2] == 3
    ref = json.loads((out / "runs" / "torus" / "reference-4views" / "seed0" / "rounds.json").read_text())
    assert ref["selected"] == [0, 1, 2, 3] and ref["rounds"] == []  # the reference trains on 4 views, no selection
    stamp = (out / "runs" / "torus" / "random" / "seed0" / "eval.json").stat().st_mtime
    assert main(args) == 0  # finished jobs are skipped
    assert (out / "runs" / "torus" / "random" / "seed0" / "eval.json").stat().st_mtime == stamp
    assert json.loads((out / "results.json").read_text())["rows"] == rows
    assert not [p for p in out.rglob("*.tmp")]


def test_experiment_config_errors(tmp_path):
    from nbv.study.experiment_config import ExperimentConfig

    path = tmp_path / "bad.json"
    path.write_text(json.dumps({"scenes": ["a"], "methods": ["random"], "sedes": [0]}))
    with pytest.raises(ValueError, match="unknown keys"):
        ExperimentConfig.load(path)
    with pytest.raises(ValueError, match="seeds"):
        ExperimentConfig(scenes=("a",), methods=("random",), seeds=())
    with pytest.raises(ValueError, match=r"unknown keys in 'active' \['budgte'\]"):
        ExperimentConfig(scenes=("a",), methods=("random",), active={"budgte": 3})


def _fail_on_two(job: int) -> int:
    if job == 2:
        raise ArithmeticError("job two is bad")
    return job


def test_local_executor_names_the_failed_job_and_cancels_the_rest():
    from nbv.study.executors import LocalExecutor

    seen = []
    with pytest.raises(ArithmeticError, match="job two") as info:
        for _job, result in LocalExecutor(workers=1).map(_fail_on_two, [1, 2, 3, 4, 5, 6]):
            seen.append(result)
    assert info.value.job == 2
    assert 1 in seen and len(seen) < 5  # the jobs queued behind the failure were cancelled, not run


def test_experiment_checks_every_scene_before_any_job(tiny_dataset, tmp_path):
    from nbv.study.experiment import run_experiment
    from nbv.study.experiment_config import ExperimentConfig

    class Recorder:
        def map(self, fn, jobs):
            raise AssertionError("no job may start with a bad scene in the config")

    config = ExperimentConfig(
        scenes=(str(tiny_dataset), str(tmp_path / "tiyn")),
        methods=("random",),
        seeds=(0,),
        output=str(tmp_path / "out"),
    )
    with pytest.raises(ValueError, match="'scenes'.*tiyn.*does not exist"):
        run_experiment(config, Recorder(), progress=False)


def test_ray_executor_on_a_local_instance(tmp_path, monkeypatch):
    if importlib.util.find_spec("ray") is None:
        pytest.skip("Ray is not installed (optional extra: pip install -e .[ray])")
    import ray

    from nbv.study.executors import RayExecutor

    # a single-machine instance on the loopback address (tests/nbv/study/test_ray_cluster.py runs a two-node cluster)
    monkeypatch.setenv("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
    monkeypatch.setattr(ray._private.ray_constants, "ENABLE_RAY_CLUSTER", False)

    with pytest.raises(ValueError, match="local_cpus"):
        RayExecutor(local_cpus=0)
    ex = RayExecutor(initializer=None, local_cpus=1)
    try:
        assert sorted(r for _, r in ex.map(abs, [-1, -2, 3])) == [1, 2, 3]
        assert ray.cluster_resources().get("CPU") == 1.0
    finally:
        ray.shutdown()


def test_ray_missing_is_a_clear_error(monkeypatch):
    from nbv.study.executors import RayExecutor

    monkeypatch.setitem(sys.modules, "ray", None)  # what `import ray` sees without the package
    with pytest.raises(ValueError, match="pip install ray"):
        RayExecutor()


def test_experiment_counts_that_allocate_are_refused_quickly(tiny_dataset, tmp_path):
    """A config number that would allocate without bound is refused at once, before any job and before the output
    folder exists: a billion reference views (it built tuple(range(n))), a budget of a billion, a million seeds
    (90 s of silent planning), a reference run with more views than the scene has."""
    import time

    from apps.cli import main
    from nbv.study.experiment import run_experiment
    from nbv.study.experiment_config import ExperimentConfig

    cases = [
        ({"reference_views": 1_000_000_000}, "'reference_views' must be null or an integer from 1 to 100,000"),
        ({"active": {"budget": 1_000_000_000}}, "'active.budget' must be at most 100,000"),
        ({"seeds": list(range(1_000_000))}, "1,000,000 jobs, more than the 10,000"),
        ({"seeds": [2**70]}, "'seeds' must be integers from 0 to"),
        (
            {"reference_views": 9, "active": TINY_ACTIVE},
            "'reference_views' is 9, but the scene .* has only 8 candidate",
        ),
        (
            {"active": {**TINY_ACTIVE, "budget": 12, "total_iterations": 500}},
            "'active.budget' is 12, but the scene .* has only 8",
        ),
    ]
    for i, (extra, message) in enumerate(cases):
        config = {
            "scenes": [str(tiny_dataset)],
            "methods": ["random"],
            "preset": "cpu-small",
            "output": f"out{i}",
            **extra,
        }
        path = tmp_path / f"exp{i}.json"
        path.write_text(json.dumps(config))
        t0 = time.perf_counter()
        with pytest.raises(ValueError, match=message):
            run_experiment(ExperimentConfig.load(path), None, progress=False)
        assert time.perf_counter() - t0 < 10, extra
        assert not (tmp_path / f"out{i}").exists()  # a refused run leaves no empty folder
    assert main(["experiment", str(tmp_path / "exp0.json"), "--no-progress"]) == 2


def test_eval_counts_are_bounded_and_scenes_must_be_a_list(tmp_path):
    """`eval --chamfer-samples 10^14` and `--critical-views 10^11` were accepted (petabytes of mesh samples); a config
    whose "scenes" is a string walked its characters as scene folders."""
    from nbv.study.evaluate import MAX_CHAMFER_SAMPLES, MAX_CRITICAL_VIEWS
    from nbv.study.experiment_config import ExperimentConfig

    for key, top in (("chamfer_samples", MAX_CHAMFER_SAMPLES), ("critical_views", MAX_CRITICAL_VIEWS)):
        assert getattr(EvalConfig(**{key: top}), key) == top
        with pytest.raises(ValueError, match=f"{key} must be an integer from 1 to"):
            EvalConfig(**{key: top + 1})
    path = tmp_path / "exp.json"
    path.write_text(json.dumps({"scenes": "/data/torus", "methods": ["fisher"], "seeds": [0]}))
    with pytest.raises(ValueError, match="'scenes' must be a list of dataset folders"):
        ExperimentConfig.load(path)


def test_scene_folder_names_are_unique_and_the_first_keeps_its_name():
    """One naming for the experiment's and the oracle's scene folders: a second scene of the same folder name gets
    '-2', and adding it leaves the first one's folder as it was."""
    from nbv.study import oracle
    from nbv.study.experiment_config import scene_names

    assert scene_names(["a/chair", "b/chair", "c/torus", "d/chair"]) == ["chair", "chair-2", "torus", "chair-3"]
    assert scene_names(["a/chair"]) == ["chair"]
    assert oracle.scene_names is scene_names
