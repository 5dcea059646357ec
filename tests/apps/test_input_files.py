"""Inputs refused by their type or shape before anything reads them: FIFOs, devices, link loops, thread counts beyond
reason and deeply nested JSON, each in one line (no hang, no traceback)."""

import logging

import pytest

from apps import cli

from helpers.logs import error_text


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
    assert error_text(caplog).count(what) == 3
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


def test_deeply_nested_json_is_a_clear_error(tmp_path, caplog):
    from nbv.study.experiment_config import ExperimentConfig
    from recon.datasets import load_cameras
    from viz.cameras import read_scores

    deep = "[" * 100000 + "]" * 100000
    for name in ("scene.json", "exp.json", "transforms.json", "scores.json"):
        (tmp_path / name).write_text(deep if name != "transforms.json" else '{"frames": ' + deep + "}")
    assert cli.main(["sim", str(tmp_path / "scene.json"), "-o", str(tmp_path / "o.h5")]) == 2
    assert "nests its JSON too deeply" in error_text(caplog)
    for read, name in (
        (ExperimentConfig.load, "exp.json"),
        (load_cameras, "transforms.json"),
        (read_scores, "scores.json"),
    ):
        with pytest.raises(ValueError, match="too deeply"):
            read(tmp_path / name)


def test_a_dataset_without_train_views_is_named(tmp_path, caplog):
    """A transforms_train.json with an empty 'frames' list was an IndexError traceback in train, and active, the
    experiment and the oracle said to lower the budget or the states 'to at most 0'."""
    import json

    ds = tmp_path / "ds"
    ds.mkdir()
    (ds / "transforms_train.json").write_text(json.dumps({"camera_angle_x": 0.7, "frames": []}))
    assert cli.main(["train", str(ds), "-o", str(tmp_path / "o.ply"), "--iters", "2"]) == 2
    assert "transforms_train.json: 'frames' is empty; a dataset needs at least one train view" in error_text(caplog)
    caplog.clear()
    assert cli.main(["active", str(ds), "-o", str(tmp_path / "run"), "--budget", "3"]) == 2
    assert "has no train (candidate) views" in error_text(caplog) and not (tmp_path / "run").exists()
    caplog.clear()
    exp = tmp_path / "exp.json"
    exp.write_text(json.dumps({"scenes": [str(ds)], "methods": ["random"], "output": str(tmp_path / "out")}))
    assert cli.main(["experiment", str(exp), "--no-progress"]) == 2
    assert "'scenes': " in error_text(caplog) and "has no train (candidate) views" in error_text(caplog)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("kind", ["fifo", "zero", "loop", "folder", "missing"])
def test_bench_forces_solid_is_named_as_what_it_is(tmp_path, odd_inputs, caplog, kind):
    """`bench forces --solid /dev/zero` (a FIFO, a folder, a link loop) said "no such file"; each is named as what it
    is, before any engine runs, as the other commands name their inputs."""
    odd_inputs["folder"] = (tmp_path, "is a folder, not a Gaussian file")
    odd_inputs["missing"] = (tmp_path / "none.obj", "does not exist")
    path, what = odd_inputs[kind]
    assert cli.main(["bench", "forces", "--solid", str(path)]) == 2
    assert what in error_text(caplog) and "no such file" not in error_text(caplog), error_text(caplog)
