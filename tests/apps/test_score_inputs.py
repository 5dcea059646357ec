"""`fluidgs score` and `fluidgs view` on hostile inputs: a result with no completed probe, absurd image sizes, and the
views folder of an earlier run."""

import shutil

import h5py
import numpy as np
import pytest
import torch

from apps import cli
from recon.camera import Camera

from helpers.logs import error_text
from helpers.sphere_run import ring_transforms, simulate_sphere


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """A 300-Gaussian sphere, four cameras and its -x RESULT.h5 (simulate, 20 coarse steps)."""
    return simulate_sphere(tmp_path_factory.mktemp("more"))


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
    msg = error_text(caplog)
    assert "has no D_g to show" in msg and "diverged in probe -x at step 0" in msg and "before completing" in msg
    assert "IndexError" not in capsys.readouterr().err


def test_score_of_a_result_with_no_completed_probe_says_none_completed(data, no_probe, tmp_path, caplog):
    out = tmp_path / "s.json"
    args = ["score", str(data["ply"]), "--cameras", str(data["cameras"]), "--result", str(no_probe), "-o", str(out)]
    assert cli.main([*args, "--no-png"]) == 2
    assert "no probe completed" in error_text(caplog) and not out.exists()


def test_a_result_declaring_more_than_it_stores_is_refused_before_reading(data, tmp_path, caplog):
    """score and critical --result read RESULT.h5's datasets whole: a /gaussians/D declared (10^12,) with no chunk
    written (a few KB on disk) was a 7 TiB MemoryError traceback. It is refused (exit 2) naming the dataset, as view
    and export refuse it; a recorded trajectory, which load_result reads only when asked, is checked only then."""
    from nbv.physics.result import load_result

    bad = tmp_path / "huge.h5"
    shutil.copy(data["h5"], bad)
    with h5py.File(bad, "r+") as f:
        del f["gaussians/D"]
        f.create_dataset("gaussians/D", shape=(10**12,), dtype="f8", chunks=(1024,))
    for command, extra in (("score", ["--no-png"]), ("critical", [])):
        out = tmp_path / f"{command}.json"
        args = ["--cameras", str(data["cameras"]), "--result", str(bad), "-o", str(out), *extra]
        caplog.clear()
        assert cli.main([command, str(data["ply"]), *args]) == 2
        assert "/gaussians/D declares (1000000000000,) float64" in error_text(caplog) and not out.exists()
    recorded = tmp_path / "recorded.h5"
    shutil.copy(data["h5"], recorded)
    with h5py.File(recorded, "r+") as f:
        f.create_dataset("probes/-x/trajectory/x", shape=(4, 10**10, 3), dtype="f4", chunks=(1, 1024, 3))
    assert load_result(recorded).divergence.shape == (300,)
    uneven = tmp_path / "uneven.h5"
    shutil.copy(data["h5"], uneven)
    with h5py.File(uneven, "r+") as f:
        f.copy("probes/-x", "probes/+x")  # a second probe whose D lost a row
        f.attrs["directions"] = '["-x", "+x"]'
        del f["probes/+x/D"]
        f["probes/+x/D"] = np.zeros(299)
    with pytest.raises(ValueError, match=r"uneven\.h5: the probes' 'D' datasets have the shapes \(300,\) and \(299,\)"):
        load_result(uneven)
    with pytest.raises(ValueError, match="trajectory/x declares"):
        load_result(recorded, trajectories=True)


def test_absurd_image_sizes_are_refused_naming_the_camera(data, tmp_path, caplog):
    """Cameras with w = h = 1e9 tied every view with no warning."""
    from recon.camera import MAX_IMAGE_SIDE

    huge = ring_transforms(tmp_path / "huge.json", w=10**9, h=10**9)
    out = tmp_path / "s.json"
    args = ["score", str(data["ply"]), "--cameras", str(huge), "--result", str(data["h5"]), "-o", str(out), "--no-png"]
    assert cli.main(args) == 2
    msg = error_text(caplog)
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
