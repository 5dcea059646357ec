"""Hostile files and limits: checkpoints that would run code, counts that would exhaust the memory, inputs that
would hang, and errors that must be one line naming the cause (no traceback, no hang)."""

import json
import logging

import pytest

from apps import cli

from helpers.scenes import small_scene


def _errors(caplog) -> str:
    return " ".join(r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR)


@pytest.fixture(scope="module")
def blender_scene(tmp_path_factory):
    """A Blender dataset folder with 8 train frames (cameras only: no job here reads an image)."""
    root = tmp_path_factory.mktemp("scene") / "scene"
    root.mkdir()
    frame = {"file_path": "./train/r_0", "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]}
    for split in ("train", "test"):
        (root / f"transforms_{split}.json").write_text(json.dumps({"camera_angle_x": 0.7, "frames": [frame] * 8}))
    return root


class _InProcess:
    """An executor that runs the jobs here, attaching the job to its error as the real executors do."""

    def map(self, fn, jobs):
        for job in jobs:
            try:
                result = fn(job)
            except Exception as exc:
                exc.job = job
                raise
            yield job, result


@pytest.mark.parametrize(
    "error, code",
    [
        (RuntimeError("boom inside the job"), 1),
        (ValueError("bad frame"), 2),
        (OSError(28, "No space left on device"), 4),
    ],
)
def test_a_failing_experiment_job_is_one_line(blender_scene, tmp_path, monkeypatch, caplog, capsys, error, code):
    import apps.experiment
    import nbv.study.experiment

    def fail(job):
        raise error

    monkeypatch.setattr(nbv.study.experiment, "run_job", fail)
    monkeypatch.setattr(apps.experiment, "make_executor", lambda *a, **k: _InProcess())
    path = tmp_path / "exp.json"
    path.write_text(
        json.dumps(
            {
                "scenes": [str(blender_scene)],
                "methods": ["random"],
                "reference_views": None,
                "output": "out",
                "active": {"budget": 4},
            }
        )
    )
    assert cli.main(["experiment", str(path), "--no-progress"]) == code
    msg = _errors(caplog)
    assert "experiment job scene random seed 0" in msg and str(error) in msg and "run the same command again" in msg
    assert "Traceback" not in capsys.readouterr().err


# ---- inputs refused by their type, before anything reads them ----------------------------------------------------
@pytest.fixture
def odd_inputs(tmp_path):
    import os

    fifo = tmp_path / "g.ply"
    os.mkfifo(fifo)
    loop = tmp_path / "loop.ply"
    loop.symlink_to(loop)
    return {
        "fifo": (fifo, "is a FIFO (named pipe)"),
        "zero": ("/dev/zero", "is a character device"),
        "loop": (loop, "is a symbolic link loop"),
    }


@pytest.mark.parametrize("kind", ["fifo", "zero", "loop"])
def test_fifo_dev_zero_and_link_loop_are_named_not_read(tmp_path, odd_inputs, caplog, kind):
    """A FIFO as the Gaussian file hung forever; /dev/zero and a link loop were "does not exist". Each is refused
    by its type at once (exit 2), named as what it is."""
    import time

    path, what = odd_inputs[kind]
    t0 = time.monotonic()
    assert cli.main(["simulate", str(path), "-o", str(tmp_path / "r.h5"), "--threads", "1"]) == 2
    assert cli.main(["inspect", str(path), "--threads", "1"]) == 2
    (tmp_path / "scene.json").unlink(missing_ok=True)
    assert cli.main(["sim", str(path), "-o", str(tmp_path / "o.h5")]) == 2
    assert time.monotonic() - t0 < 30
    assert _errors(caplog).count(what) == 3
    assert not (tmp_path / "r.h5").exists() and not (tmp_path / "o.h5").exists()


def test_threads_above_a_sane_bound_are_refused_and_above_the_cores_noticed(tmp_path, caplog, capsys):
    import os

    from apps.taichi_runtime import MAX_THREADS, check_threads

    with pytest.raises(SystemExit) as info:
        cli.main(["simulate", "g.ply", "-o", str(tmp_path / "r.h5"), "--threads", "100000"])
    assert info.value.code == 2 and f"must be at most {MAX_THREADS}" in capsys.readouterr().err
    with pytest.raises(ValueError, match="at most 1024"):
        check_threads(100000)
    with caplog.at_level(logging.WARNING):
        assert check_threads((os.cpu_count() or 1) + 1) == (os.cpu_count() or 1) + 1
    assert "more than this machine's" in caplog.text


# ---- deeply nested JSON: a clear error in every JSON reader ----------------------------------------------------------
def test_deeply_nested_json_is_a_clear_error(tmp_path, caplog):
    from nbv.study.experiment_config import ExperimentConfig
    from recon.datasets import load_cameras
    from viz.cameras import read_scores

    deep = "[" * 100000 + "]" * 100000
    for name in ("scene.json", "exp.json", "transforms.json", "scores.json"):
        (tmp_path / name).write_text(deep if name != "transforms.json" else '{"frames": ' + deep + "}")
    assert cli.main(["sim", str(tmp_path / "scene.json"), "-o", str(tmp_path / "o.h5")]) == 2
    assert "nests its JSON too deeply" in _errors(caplog)
    for read, name in (
        (ExperimentConfig.load, "exp.json"),
        (load_cameras, "transforms.json"),
        (read_scores, "scores.json"),
    ):
        with pytest.raises(ValueError, match="too deeply"):
            read(tmp_path / name)


# ---- a disk that fills while the file is closed --------------------------------------------------------------------
def test_sim_disk_full_at_close_is_exit_4(tmp_path, monkeypatch, caplog, capsys):
    import h5py

    scene = small_scene(steps=2)
    (tmp_path / "scene.json").write_text(json.dumps(scene))
    real_close = h5py.File.close

    def full_at_close(self):
        real_close(self)
        raise RuntimeError("Can't decrement id ref count (unable to flush file: No space left on device)")

    monkeypatch.setattr(h5py.File, "close", full_at_close)
    assert cli.main(["sim", str(tmp_path / "scene.json"), "-o", str(tmp_path / "out.h5"), "--threads", "2"]) == 4
    monkeypatch.setattr(h5py.File, "close", real_close)
    assert "cannot write" in _errors(caplog) and "out.h5" in _errors(caplog)
    assert "Traceback" not in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.json"]


def test_sim_steps_0_names_the_option(tmp_path, caplog):
    (tmp_path / "scene.json").write_text(
        json.dumps(
            {
                "particle_radius": 0.05,
                "dt": 0.002,
                "steps": 2,
                "rest_density": 1000.0,
                "viscosity": 10.0,
                "domain": {"min": [0, 0, 0], "max": [1, 1, 1]},
                "fluid_blocks": [{"min": [0.1] * 3, "max": [0.5] * 3}],
            }
        )
    )
    assert cli.main(["sim", str(tmp_path / "scene.json"), "-o", str(tmp_path / "o.h5"), "--steps", "0"]) == 2
    assert "--steps must be an integer >= 1" in _errors(caplog) and "scene key" not in _errors(caplog)
