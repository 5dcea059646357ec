"""Outputs that cannot be written: a read-only folder and a disk that fills at close end with exit 4 and one line naming
the file, leaving no partial output."""

import json

import h5py

from apps import cli

from helpers.logs import error_text
from helpers.scenes import small_scene


def test_render_dataset_into_an_unwritable_folder_is_exit_4(tmp_path, monkeypatch, caplog):
    """render-dataset exited 2 on a read-only output where the other commands exit 4 (root ignores the mode bits,
    so the check is made to see an unwritable folder)."""
    import os

    import recon.mesh_render

    from helpers.paths import TORUS

    real = os.access
    monkeypatch.setattr(recon.mesh_render.os, "access", lambda path, mode, **k: not mode & os.W_OK and real(path, mode))
    assert cli.main(["render-dataset", str(TORUS), "-o", str(tmp_path / "ds"), "--no-progress"]) == 4
    assert "is not writable" in error_text(caplog) and not (tmp_path / "ds").exists()
    monkeypatch.undo()
    (tmp_path / "file").write_text("x")
    assert cli.main(["render-dataset", str(TORUS), "-o", str(tmp_path / "file"), "--no-progress"]) == 4


def test_sim_disk_full_at_close_is_exit_4(tmp_path, monkeypatch, caplog, capsys):

    scene = small_scene(steps=2)
    (tmp_path / "scene.json").write_text(json.dumps(scene))
    real_close = h5py.File.close

    def full_at_close(self):
        real_close(self)
        raise RuntimeError("Can't decrement id ref count (unable to flush file: No space left on device)")

    monkeypatch.setattr(h5py.File, "close", full_at_close)
    assert cli.main(["sim", str(tmp_path / "scene.json"), "-o", str(tmp_path / "out.h5"), "--threads", "2"]) == 4
    monkeypatch.setattr(h5py.File, "close", real_close)
    assert "cannot write" in error_text(caplog) and "out.h5" in error_text(caplog)
    assert "Traceback" not in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.json"]


def test_an_output_folder_that_takes_no_files_says_so(tmp_path, monkeypatch):
    """A folder where a new file cannot be made for another reason than permissions (procfs: ENOENT) is not called
    unwritable: the message says it takes no new files, with the system's reason."""
    import errno
    import os

    import pytest

    from fluidsim.files import OutputError, check_writable

    real = os.open

    def refuse(path, flags, *a, **k):
        if str(path).startswith(str(tmp_path)):
            raise FileNotFoundError(errno.ENOENT, "No such file or directory")
        return real(path, flags, *a, **k)

    monkeypatch.setattr(os, "open", refuse)
    with pytest.raises(OutputError, match="takes no new files .No such file or directory"):
        check_writable(tmp_path / "out.h5")


def test_render_dataset_without_test_views_says_what_needs_them(tmp_path, capsys):
    from helpers.paths import TORUS

    out = tmp_path / "ds"
    args = ["render-dataset", str(TORUS), "-o", str(out), "--train", "1", "--test", "0", "--res", "16", "--no-progress"]
    assert cli.main(args) == 0
    assert "no test views" in capsys.readouterr().out and (out / "transforms_train.json").exists()


def test_render_dataset_given_a_folder_as_the_mesh_says_it_is_a_folder(tmp_path, caplog):
    assert cli.main(["render-dataset", str(tmp_path), "-o", str(tmp_path / "ds"), "--no-progress"]) == 2
    assert "is a folder; pass a mesh file" in error_text(caplog)


def test_active_refuses_a_run_folder_inside_its_dataset(tmp_path, caplog):
    """`active -o DATASET` (or a folder inside it) wrote config.json, rounds.json and checkpoint.pt among the dataset's
    files: refused before any work, the dataset untouched."""
    from helpers.paths import TORUS

    ds = tmp_path / "ds"
    args = ["render-dataset", str(TORUS), "-o", str(ds), "--train", "2", "--test", "1", "--res", "16", "--no-progress"]
    assert cli.main(args) == 0
    before = sorted(p.name for p in ds.iterdir())
    for out in (ds, ds / "run"):
        caplog.clear()
        run = ["active", str(ds), "-o", str(out), "--preset", "cpu-small", "--budget", "2", "--no-progress"]
        assert cli.main(run) == 2
        assert "lies inside the dataset" in error_text(caplog)
    assert sorted(p.name for p in ds.iterdir()) == before
