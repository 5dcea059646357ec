"""`fluidgs experiment`: a bad config names its key, an output that is a file is named as the key, and a job that fails
ends the command in one line naming the job (no traceback)."""

import json

import pytest

from apps import cli

from helpers.logs import error_text


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
    "active, key",
    [
        ({"budget": 0}, "'active.budget' must be"),
        ({"budget": 4, "physics": {"steps": 0}}, "'active.physics.steps'"),
        ({"budget": 4, "total_iterations": 10**14}, "'active.total_iterations' must be at most 1,000,000"),  # ran
        ({"budget": 4, "resolution": 10**8}, "'active.resolution' must be at most 65,536"),  # failed in the job
    ],
)
def test_experiment_config_errors_name_the_key(blender_scene, tmp_path, caplog, active, key):
    path = tmp_path / "exp.json"
    path.write_text(json.dumps({"scenes": [str(blender_scene)], "methods": ["random"], "active": active}))
    assert cli.main(["experiment", str(path), "--no-progress"]) == 2
    assert key in error_text(caplog) and "Config." not in error_text(caplog)


def test_experiment_refuses_a_scene_listed_twice(blender_scene, tmp_path, caplog):
    """The same dataset listed twice (here once through a link) ran every job twice, into runs/scene and
    runs/scene-2, and the tables counted the copies as two scenes (n = 2, spread 0)."""
    link = tmp_path / "again"
    link.symlink_to(blender_scene)
    path = tmp_path / "exp.json"
    doc = {"scenes": [str(blender_scene), str(link)], "methods": ["random"], "output": str(tmp_path / "out")}
    path.write_text(json.dumps(doc))
    assert cli.main(["experiment", str(path), "--no-progress"]) == 2
    assert "'scenes' lists the dataset" in error_text(caplog) and not (tmp_path / "out").exists()


def _write_experiment(path, scene, output: str) -> None:
    """An experiment of the random method on ``scene`` with a budget of 4 views and no reference, into ``output``."""
    doc = {"scenes": [str(scene)], "methods": ["random"], "reference_views": None, "output": output}
    path.write_text(json.dumps({**doc, "active": {"budget": 4}}))


def test_experiment_output_that_is_a_file_is_named_as_the_key(blender_scene, tmp_path, caplog):
    """`"output": "../A.ply"` (an existing file) printed "[Errno 17] File exists: ..."."""
    (tmp_path / "A.ply").write_text("not a folder")
    (tmp_path / "sub").mkdir()
    path = tmp_path / "sub" / "exp.json"
    _write_experiment(path, blender_scene, "../A.ply")
    assert cli.main(["experiment", str(path), "--no-progress"]) == 4
    msg = error_text(caplog)
    assert f"the 'output' of {path}" in msg and "is a file, not a folder" in msg and "Errno" not in msg
    assert (tmp_path / "A.ply").read_text() == "not a folder"


def test_speed_0_in_an_experiment_names_the_key(blender_scene, tmp_path, caplog):
    path = tmp_path / "exp.json"
    active = {"budget": 4, "physics": {"speed": 0.0}}
    path.write_text(json.dumps({"scenes": [str(blender_scene)], "methods": ["random+fluid"], "active": active}))
    assert cli.main(["experiment", str(path), "--no-progress"]) == 2
    assert "'active.physics.speed' is 0 m/s" in error_text(caplog)


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
    _write_experiment(path, blender_scene, "out")
    assert cli.main(["experiment", str(path), "--no-progress"]) == code
    msg = error_text(caplog)
    assert "experiment job scene random seed 0" in msg and str(error) in msg and "run the same command again" in msg
    assert "Traceback" not in capsys.readouterr().err
