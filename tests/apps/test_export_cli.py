"""`simulate --export-solid`, the D_g columns of the coloured .ply and `fluidgs export RESULT.h5 --vtk DIR`, on a tiny
sphere through the CLI: the mesh is watertight with the cells' volume, the .ply columns are RESULT.h5's D_g, the
VTK frames read back by VTK's own reader equal the recorded trajectory; bad input exits 2 before any simulation."""

import json
import time

import h5py
import numpy as np
import pytest

from apps import cli
from recon.formats.ply import read_ply_vertices, save_gaussians
from recon.gaussians import SH_C0
from viz.colors import UNREACHED_RGB

from helpers.logs import error_text
from helpers.spheres import sphere_gaussians
from helpers.vtk_files import read_pvd, read_vtu

FAST = ["--particle-radius", "0.08", "--steps", "20", "--dt", "0.004", "--no-empty-reference", "--threads", "2"]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    root = tmp_path_factory.mktemp("export")
    ply = save_gaussians(sphere_gaussians(), root / "sphere.ply")
    h5 = root / "result.h5"
    record = ["--record-probe", "-x", "--record-every", "5"]
    export = ["--export-solid", str(root / "solid.glb"), "--export-frame", "sim"]
    assert cli.main(["simulate", str(ply), "-o", str(h5), "--directions=-x,+z", *record, *export, *FAST]) == 0
    return root, ply, h5


def test_simulate_exports_a_watertight_solid_and_the_d_columns(run):
    import trimesh

    root, _, h5 = run
    mesh = trimesh.load(root / "solid.glb", force="mesh")
    with h5py.File(h5) as f:
        solid = f["solid/x"][()]
        d_max, per_probe = f["gaussians/D"][()], {d: f[f"probes/{d}/D"][()] for d in ("-x", "+z")}
    with h5py.File(root / "solid.voxels.h5") as f:
        assert int(f["occupancy"][()].sum()) == len(solid) == f.attrs["cells"]
        volume = f.attrs["volume_m3"]
    assert mesh.is_watertight and abs(mesh.volume / volume - 1) < 0.15
    cols = read_ply_vertices(root / "result_divergence.ply")
    np.testing.assert_allclose(cols["D_max"], d_max.astype(np.float32))
    np.testing.assert_allclose(cols["D_neg_x"], per_probe["-x"].astype(np.float32))
    np.testing.assert_allclose(cols["D_pos_z"], per_probe["+z"].astype(np.float32))
    # the reached column: some probe's fluid came within reach (else D_g = 0 is unmeasured), in the .ply and the .h5
    with h5py.File(h5) as f:
        reached = f["gaussians/reached"][()]
        counts = f["probes/-x/counts"][()] + f["probes/+z/counts"][()]
    np.testing.assert_array_equal(reached, counts > 0)
    np.testing.assert_array_equal(cols["reached"], reached.astype(np.float32))
    assert (d_max[~reached] == 0).all()
    grey = (np.float32(UNREACHED_RGB) - 0.5) / SH_C0  # SH DC of the grey
    dc = np.stack([cols[f"f_dc_{k}"] for k in range(3)], axis=1)
    np.testing.assert_allclose(dc[~reached], np.tile(grey, ((~reached).sum(), 1)), atol=1e-5)
    assert not np.isclose(dc[reached], grey, atol=1e-3).all(axis=1).any()


def test_export_result_vtk_equals_the_trajectory(run, tmp_path):
    _, _, h5 = run
    out = tmp_path / "vtk"
    assert cli.main(["export", str(h5), "--vtk", str(out), "--probe", "-x"]) == 0
    series = read_pvd(out / "probe_neg_x.pvd")
    with h5py.File(h5) as f:
        t = f["probes/-x/trajectory"]
        steps, x, d, v, rho = t["steps"][()], t["x"][()], t["D"][()], t["v"][()], t["density"][()]
        dt = float(json.loads(f.attrs["config"])["dt"])
        solid = f["solid/x"][()]
    assert len(series) == len(steps) == 4
    for (when, name), k in zip(series, range(len(steps)), strict=True):
        assert when == pytest.approx(steps[k] * dt)
        keep = np.isfinite(x[k]).all(axis=1)
        points, data, _ = read_vtu(out / name)
        assert len(points) == keep.sum()
        np.testing.assert_array_equal(points, x[k][keep])
        np.testing.assert_array_equal(data["divergence"], d[k][keep].astype(np.float32))
        np.testing.assert_array_equal(data["velocity"], v[k][keep].astype(np.float32))
        np.testing.assert_array_equal(data["density"], rho[k][keep].astype(np.float32))
        np.testing.assert_array_equal(data["id"], np.flatnonzero(keep))
        # density rho / rho_0 of a fluid that is not yet compressed much
        assert 0.5 < float(np.median(data["density"])) < 1.5
    assert len(read_vtu(out / "solid.vtu")[0]) == len(solid)


def test_bad_exports_exit_2_before_any_work(run, tmp_path, caplog):
    root, ply, h5 = run
    t0 = time.perf_counter()
    assert (
        cli.main(
            ["simulate", str(ply), "-o", str(tmp_path / "r.h5"), "--export-solid", str(tmp_path / "solid.fbx"), *FAST]
        )
        == 2
    )
    assert "--export-solid" in caplog.text and ".glb" in caplog.text
    assert cli.main(["simulate", str(ply), "-o", str(tmp_path / "r.h5"), "--walls", "faint", *FAST]) == 2
    assert "apply to --video" in caplog.text
    assert cli.main(["export", str(root / "solid.voxels.h5"), "--vtk", str(tmp_path / "v")]) == 2
    assert "--vtk" in caplog.text and "neither /frames" in caplog.text
    with h5py.File(tmp_path / "plain.h5", "w") as f:  # a RESULT.h5 without recorded probes
        f["gaussians/D"] = np.zeros(2)
        f.create_group("probes/-x")
    assert cli.main(["export", str(tmp_path / "plain.h5"), "--vtk", str(tmp_path / "v")]) == 2
    assert "--record-probe" in caplog.text
    assert cli.main(["export", str(h5), "--vtk", str(tmp_path / "v"), "--probe", "+z"]) == 2
    assert "not recorded" in caplog.text
    assert cli.main(["export", str(h5)]) == 2
    assert "nothing to write" in caplog.text
    with pytest.raises(SystemExit) as bad_steps:  # bounded at parse time, before the scenes' solid is made
        cli.main(["export", str(ply), "--splishsplash", str(tmp_path / "s"), "--steps", "10000000000"])
    assert bad_steps.value.code == 2
    assert cli.main(["export", str(ply), "--splishsplash", "/proc/fluidgs-test/s", "--quick"]) == 4
    assert "/proc/fluidgs-test" in caplog.text and "solid:" not in caplog.text
    assert time.perf_counter() - t0 < 30
    assert not (tmp_path / "r.h5").exists() and not (tmp_path / "v").exists()


def test_vtk_folder_is_replaced_only_when_it_holds_an_earlier_export(run, tmp_path, caplog):
    """`export --vtk DIR` into the folder of an earlier export was exit 4 ("is a folder; give a file name"). The folder
    is replaced as a whole, so an earlier export is replaced, while a folder holding other files, the input or another
    output of the same run (each would be deleted with it) is refused before any work (exit 2)."""
    import shutil

    root, ply, h5 = run
    vtk = tmp_path / "v"
    assert cli.main(["export", str(h5), "--vtk", str(vtk)]) == 0
    (vtk / "probe_pos_z.pvd").write_text("<VTKFile/>")  # as an export of another run would have left it
    assert cli.main(["export", str(h5), "--vtk", str(vtk)]) == 0  # the earlier export replaced as a whole
    assert (vtk / "probe_neg_x.pvd").is_file() and not (vtk / "probe_pos_z.pvd").exists()
    (vtk / "notes.txt").write_text("mine")
    assert cli.main(["export", str(h5), "--vtk", str(vtk)]) == 2
    assert "--vtk" in error_text(caplog) and "holds more than an earlier VTK export (notes.txt)" in error_text(caplog)
    assert (vtk / "notes.txt").read_text() == "mine"
    inside = tmp_path / "in"
    inside.mkdir()
    shutil.copy(h5, inside / "r.h5")
    assert cli.main(["export", str(inside / "r.h5"), "--vtk", str(inside)]) == 2
    assert "the input H5" in error_text(caplog) and (inside / "r.h5").read_bytes() == h5.read_bytes()
    w = tmp_path / "w"
    for option, path in (("--solid", w / "s.ply"), ("--splishsplash", w / "ss")):
        caplog.clear()
        assert cli.main(["export", str(h5), "--vtk", str(w), option, str(path)]) == 2
        assert f"{option} {path} lies inside --vtk {w}, which is replaced as a whole" in error_text(caplog)
    assert not w.exists()


def test_hostile_hdf5_files_are_refused_before_any_allocation(tmp_path, caplog):
    config = json.dumps({"particle_radius": 0.025})
    with h5py.File(tmp_path / "far.h5", "w") as f:  # two solid points 1 km apart: 8e12 cells
        f["solid/x"] = np.array([[0, 0, 0], [1000, 1000, 1000]], np.float32)
        f.attrs["config"] = config
    with h5py.File(tmp_path / "chunks.h5", "w") as f:  # 12 TB declared, no chunk written
        f.create_dataset("solid/x", shape=(10**12, 3), dtype="f4", chunks=(1024, 3))
        f.attrs["config"] = config
    assert cli.main(["export", str(tmp_path / "far.h5"), "--solid", str(tmp_path / "s.ply")]) == 2
    assert "points far apart" in caplog.text
    assert cli.main(["export", str(tmp_path / "chunks.h5"), "--solid", str(tmp_path / "s.ply")]) == 2
    assert "stores only 0 bytes" in caplog.text
    assert cli.main(["export", str(tmp_path / "chunks.h5"), "--vtk", str(tmp_path / "v")]) == 2
    from viz.data import load_view_data

    with pytest.raises(ValueError, match="unwritten chunks"):
        load_view_data(tmp_path / "chunks.h5")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["chunks.h5", "far.h5"]
