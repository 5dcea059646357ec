"""Hostile files and limits: checkpoints that would run code, counts that would exhaust the memory, inputs that
would hang, and errors that must be one line naming the cause (no traceback, no hang)."""

import json
import logging

import pytest

from apps import cli


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


@pytest.mark.parametrize("error, code", [(RuntimeError("boom inside the job"), 1), (ValueError("bad frame"), 2),
                                         (OSError(28, "No space left on device"), 4)])
def test_a_failing_experiment_job_is_one_line(blender_scene, tmp_path, monkeypatch, caplog, capsys, error, code):
    import apps.experiment
    import nbv.study.experiment

    def fail(job):
        raise error

    monkeypatch.setattr(nbv.study.experiment, "run_job", fail)
    monkeypatch.setattr(apps.experiment, "make_executor", lambda *a, **k: _InProcess())
    path = tmp_path / "exp.json"
    path.write_text(json.dumps({"scenes": [str(blender_scene)], "methods": ["random"], "reference_views": None,
                                "output": "out", "active": {"budget": 4}}))
    assert cli.main(["experiment", str(path), "--no-progress"]) == code
    msg = _errors(caplog)
    assert "experiment job scene random seed 0" in msg and str(error) in msg and "run the same command again" in msg
    assert "Traceback" not in capsys.readouterr().err
