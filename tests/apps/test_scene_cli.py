"""Scene validation names the bad key; `fluidgs sim` writes the documented HDF5 layout atomically."""

import json

import h5py
import numpy as np
import pytest

from apps import cli
from fluidsim.scene import SceneError, load_scene, parse_scene

from helpers.scenes import small_scene


def _scene(**over) -> dict:
    return small_scene(**over)


@pytest.mark.parametrize(
    "change,key",
    [
        ({"partcle_radius": 0.1}, "partcle_radius"),
        ({"particle_radius": -1.0}, "particle_radius"),
        ({"dt": float("nan")}, "dt"),
        ({"gravity": [0, 1]}, "gravity"),
        ({"steps": 0}, "steps"),
        ({"domain": {"min": [0, 0, 0], "max": [1, -1, 1]}}, "domain"),
        ({"domain": {"min": [0, 0, 0], "max": [1, 1, 1], "wals": True}}, "wals"),
        ({"fluid_blocks": [{"min": [0, 0, 0], "max": [2, 2, 2]}]}, "fluid_blocks[0]"),
        ({"fluid_blocks": []}, "fluid_blocks"),
        # 10^5 copies of one block: every particle had 10^5 neighbours, and the first step ran for hours in a kernel
        # that SIGTERM could not stop
        ({"fluid_blocks": [{"min": [0.1] * 3, "max": [0.5] * 3}] * 100_000}, "more than the 1,000 a scene"),
        ({"fluid_blocks": [{"min": [0.1] * 3, "max": [0.5] * 3}, {"min": [0.4] * 3, "max": [0.9] * 3}]}, "overlaps"),
        ({"solids": [{"mesh": "nope.obj"}]}, "solids[0]"),
        ({"solids": [{"points": "a.npy", "mesh": "b.obj"}]}, "solids[0]"),
        ({"solver": {"max_density_eror": 0.1}}, "max_density_eror"),
        ({"solver": {"min_iterations": 5, "max_iterations": 2}}, "min_iterations"),
    ],
)
def test_bad_scenes_name_the_key(change, key):
    with pytest.raises(SceneError, match=key.replace("[", r"\[").replace("]", r"\]")):
        parse_scene(_scene(**change))


def test_a_solid_that_is_a_fifo_or_a_device_is_named_as_such(tmp_path):
    """A solid's 'points' or 'mesh' naming /dev/zero or a FIFO was said to be a file that was "not found"."""
    import os

    os.mkfifo(tmp_path / "pipe.npy")
    with pytest.raises(SceneError, match=r"'solids\[0\]': 'pipe\.npy' is a FIFO \(named pipe\)"):
        parse_scene(_scene(solids=[{"points": "pipe.npy"}]), tmp_path)
    with pytest.raises(SceneError, match=r"'solids\[0\]': '/dev/zero' is a character device"):
        parse_scene(_scene(solids=[{"mesh": "/dev/zero"}]), tmp_path)
    with pytest.raises(SceneError, match=r"'solids\[0\]': file 'nope\.npy' not found"):
        parse_scene(_scene(solids=[{"points": "nope.npy"}]), tmp_path)


def test_scene_round_trips(tmp_path):
    p = tmp_path / "scene.json"
    p.write_text(json.dumps(_scene(solver={"time_step": "cfl"})))
    scene = load_scene(p)
    assert scene.config.time_step == "cfl"
    again = parse_scene(scene.to_dict(), tmp_path)
    assert again.config == scene.config and again.domain == scene.domain


def test_sim_command_writes_documented_layout(tmp_path):
    np.save(
        tmp_path / "cube.npy", np.stack(np.meshgrid(*[np.arange(0.6, 0.8, 0.1)] * 3, indexing="ij"), -1).reshape(-1, 3)
    )
    scene = _scene(
        steps=6,
        solids=[{"points": "cube.npy"}],
        fluid_blocks=[{"min": [0.1, 0.1, 0.1], "max": [0.9, 0.9, 0.9], "velocity": [1, 0, 0]}],
    )
    (tmp_path / "scene.json").write_text(json.dumps(scene))
    out = tmp_path / "res" / "out.h5"
    assert cli.main(["sim", str(tmp_path / "scene.json"), "-o", str(out), "--save-every", "3"]) == 0
    assert not list(out.parent.glob(".*tmp"))
    with h5py.File(out) as f:
        assert sorted(f["frames"]) == ["000000", "000003", "000006"]
        fr = f["frames/000006"]
        n = fr["x"].shape[0]
        assert fr["v"].shape == (n, 3) and fr["divergence"].shape == (n,)
        assert abs(fr.attrs["time"] - 6 * 0.002) < 1e-9
        assert len(f["stats"]) == 6 and "density_iterations" in f["stats"].dtype.names
        total = f["divergence_sum"].shape[0]
        assert f["divergence_count"][:].max() == 6 and total >= n
        assert json.loads(f.attrs["scene"])["steps"] == 6
        assert f.attrs["status"] == "complete"
        assert f.attrs["removed_inside_solid"] > 0  # the fluid block overlapped the cube


def test_sim_command_refuses_bad_output_before_work(tmp_path):
    (tmp_path / "scene.json").write_text(json.dumps(_scene()))
    (tmp_path / "blocker").write_text("")
    assert cli.main(["sim", str(tmp_path / "scene.json"), "-o", str(tmp_path / "blocker" / "x.h5")]) == 4


def test_diverging_sim_keeps_frames(tmp_path):
    (tmp_path / "scene.json").write_text(json.dumps(_scene(steps=200, solver={"max_speed": 1.2})))
    out = tmp_path / "out.h5"
    assert cli.main(["sim", str(tmp_path / "scene.json"), "-o", str(out), "--save-every", "1"]) == 3
    with h5py.File(out) as f:
        assert "diverged at step" in f.attrs["status"]
        assert len(f["frames"]) >= 2


def test_f64_run_agrees_with_f32(tmp_path):
    """The f64 path (i64-packed neighbour pairs, f64 kernels) runs in its own process and tracks f32."""
    import subprocess
    import sys

    block = {"min": [0.1, 0.1, 0.1], "max": [0.5, 0.5, 0.5], "velocity": [2, 0, 0]}
    scene = _scene(steps=25, particle_radius=0.025, fluid_blocks=[block])
    (tmp_path / "scene.json").write_text(json.dumps(scene))
    finals = {}
    for precision in ("f32", "f64"):
        out = tmp_path / f"{precision}.h5"
        sim = [sys.executable, "-m", "apps.cli", "sim", str(tmp_path / "scene.json"), "-o", str(out)]
        subprocess.run([*sim, "--precision", precision, "--save-every", "25"], check=True, capture_output=True)
        with h5py.File(out) as f:
            finals[precision] = (f["frames/000025/x"][:].astype(np.float64), f["stats"][:])
    (x32, s32), (x64, s64) = finals["f32"], finals["f64"]
    assert x64.shape == x32.shape and len(x32) > 300
    assert np.abs(x64 - x32).max() < 1e-4  # m, after 25 steps (measured 2.6e-7: f32 round-off only)
    assert np.all(s64["density_error"] < 0.05) and np.all(s32["density_error"] < 0.05)  # %, converged
    moved = x32[:, 0].mean() - 0.3  # the block moved +x by about 2 m/s x 0.05 s (measured 0.100 m)
    assert 0.05 < moved < 0.15
