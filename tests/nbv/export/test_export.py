"""nbv.export: the solid as a voxel grid and a closed mesh, D_g as .ply vertex properties, particle frames as VTK.

- the voxel grid rebuilds the lattice points exactly; the marching-cubes mesh is watertight, bounded by the cubes
  of the cells, and its volume is M s^3 within the bounds the module docstring states;
- extra .ply vertex properties read back with the values written, and the Gaussians still load;
- an OUT.h5 of a real probe written as VTK and read back by VTK's own reader (an independent implementation of
  the format): per frame the particle count and the positions, velocity, D_i and density equal the HDF5's; the
  .pvd series lists every frame with its time; the solid and the walls are the boundary split by the domain.
"""

import json

import h5py
import numpy as np
import pytest
import torch

from nbv.export.particles import check_vtk_source, export_vtk, split_boundary
from nbv.export.solid import check_export_path, export_paths, export_solid, solid_mesh, voxel_grid
from recon.formats import load_gaussians
from recon.formats.ply import read_ply_vertices, save_gaussians
from recon.gaussians import GaussianSet

from helpers.probe_files import sphere_probe_file
from helpers.vtk_files import read_pvd, read_vtu

S = 0.05


def _ball(radius_cells: int) -> np.ndarray:
    g = (
        np.mgrid[
            -radius_cells - 1 : radius_cells + 2,
            -radius_cells - 1 : radius_cells + 2,
            -radius_cells - 1 : radius_cells + 2,
        ]
        .reshape(3, -1)
        .T
    )
    return g[(g**2).sum(1) <= radius_cells**2]


# ---- the solid -------------------------------------------------------------------------------------------------
def test_voxel_grid_rebuilds_the_lattice_points():
    pts = _ball(4) * S + np.array([0.3, -0.15, 0.05])
    grid = voxel_grid(pts, S)
    assert grid.cells == len(pts) and grid.volume == pytest.approx(len(pts) * S**3)
    np.testing.assert_allclose(np.sort(grid.centres(), axis=0), np.sort(pts, axis=0), atol=1e-12)
    with pytest.raises(ValueError, match="off the lattice"):
        voxel_grid(pts + np.array([0.3 * S, 0, 0]) * (np.arange(len(pts)) % 2)[:, None], S)
    with pytest.raises(ValueError, match="shape"):
        voxel_grid(np.zeros((0, 3)), S)


@pytest.mark.parametrize(
    "cells, refine, low",
    [
        (_ball(10), 2, 0.995),
        (_ball(10), 1, 0.99),  # a sphere 20 cells across: only edges and corners are cut
        (np.array([[i, j, 0] for i in range(10) for j in range(10)]), 2, 0.97),  # a one-cell sheet
        (np.array([[i, 0, 0] for i in range(10)]), 2, 0.85),  # a one-cell line
        (np.array([[0, 0, 0], [1, 1, 0], [2, 2, 1]]), 2, 0.74),  # cells touching only along edges and at a corner
    ],
)
def test_mesh_is_watertight_inside_the_cubes_and_keeps_the_volume(cells, refine, low):
    grid = voxel_grid(cells * S, S)
    mesh = solid_mesh(grid, refine)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    assert low * grid.volume <= mesh.volume <= grid.volume * (1 + 1e-9)
    lo, hi = grid.origin - S / 2, grid.origin + S * (np.array(grid.occupancy.shape) - 0.5)
    assert (mesh.vertices >= lo - 1e-6).all() and (mesh.vertices <= hi + 1e-6).all()  # float32 vertices
    # a flat face lies exactly where the cubes end: the bounding box is the cells' box
    np.testing.assert_allclose(mesh.bounds, [lo, hi], atol=1e-6)


def test_one_cell_mesh_is_the_cube_with_cut_edges():
    grid = voxel_grid(np.zeros((1, 3)), S)
    # refine 1: the octahedron through the face centres, volume s^3 / 6
    assert solid_mesh(grid, 1).volume == pytest.approx(S**3 / 6, rel=1e-6)
    assert solid_mesh(grid, 2).volume == pytest.approx(S**3 * 17 / 24, rel=1e-6)


def test_export_writes_mesh_and_voxels_that_read_back(tmp_path):
    import trimesh

    pts = _ball(6) * S
    scene_to_sim = np.diag([2.0, 2.0, 2.0, 1.0])
    for suffix in (".glb", ".ply", ".obj", ".stl"):
        info = export_solid(tmp_path / f"solid{suffix}", pts, S, scene_to_sim)
        mesh = trimesh.load(info["mesh"], force="mesh")
        assert mesh.is_watertight, suffix
        assert mesh.volume == pytest.approx(info["mesh_volume_m3"], rel=1e-5)
        assert abs(mesh.volume / info["volume_m3"] - 1) < 0.05
    with h5py.File(tmp_path / "solid.voxels.h5") as f:
        occ = f["occupancy"][()].astype(bool)
        centres = f.attrs["origin"] + f.attrs["spacing"] * np.argwhere(occ)
        np.testing.assert_allclose(np.sort(centres, axis=0), np.sort(pts, axis=0), atol=1e-12)
        np.testing.assert_array_equal(f.attrs["scene_to_sim"], scene_to_sim)
        assert f.attrs["volume_m3"] == pytest.approx(len(pts) * S**3)
    # the scene frame: the inverse of scene_to_sim (half the size here)
    info = export_solid(tmp_path / "scene.ply", pts, S, scene_to_sim, frame="scene")
    assert trimesh.load(info["mesh"], force="mesh").volume == pytest.approx(info["mesh_volume_m3"] / 8, rel=1e-5)
    info = export_solid(tmp_path / "only.h5", pts, S)
    assert info["mesh"] is None and (tmp_path / "only.h5").is_file()
    assert not list(tmp_path.glob(".fgs-*"))  # no temporary file left


def test_export_paths_and_suffixes():
    assert export_paths(check_export_path("a/solid.glb")) == (
        check_export_path("a/solid.glb"),
        check_export_path("a/solid.voxels.h5"),
    )
    with pytest.raises(ValueError, match=r"--export-solid .*'\.fbx'.*\.glb"):
        check_export_path("solid.fbx")


# ---- D_g in the .ply -------------------------------------------------------------------------------------------
def test_extra_ply_properties_read_back(tmp_path):
    g = GaussianSet.from_points(torch.rand(20, 3), torch.rand(20, 3), scale=0.05, opacity=0.5)
    d = {"D_max": np.linspace(0, 5, 20), "D_neg_x": np.arange(20.0)}
    path = save_gaussians(g, tmp_path / "g.ply", extra=d)
    cols = read_ply_vertices(path)
    assert list(cols)[-2:] == ["D_max", "D_neg_x"]
    for k, v in d.items():
        np.testing.assert_array_equal(cols[k], v.astype(np.float32))
    torch.testing.assert_close(load_gaussians(path).means, g.means)
    for bad, match in (
        ({"x": np.zeros(20)}, "standard"),
        ({"D max": np.zeros(20)}, "letters"),
        ({"D": np.zeros(3)}, "3 values"),
        ({"D": np.full(20, np.nan)}, "NaN"),
    ):
        with pytest.raises(ValueError, match=match):
            save_gaussians(g, tmp_path / "bad.ply", extra=bad)
    with pytest.raises(ValueError, match=r"need a \.ply"):
        save_gaussians(g, tmp_path / "g.npz", extra=d)


# ---- VTK -------------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def probe_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("vtk") / "OUT.h5"
    _, solid, _ = sphere_probe_file(path, 10)
    return path, solid


def test_out_h5_frames_read_back_by_vtk(probe_file, tmp_path):
    path, solid = probe_file
    assert check_vtk_source(path) == "out"
    info = export_vtk(path, tmp_path / "vtk")
    series = read_pvd(tmp_path / "vtk" / "fluid.pvd")
    with h5py.File(path) as f:
        keys = sorted(f["frames"], key=int)
        assert info["series"] == {"fluid": len(keys)} and len(series) == len(keys) and info["missing"] == []
        for (time, name), k in zip(series, keys, strict=True):
            g = f["frames"][k]
            assert time == pytest.approx(g.attrs["time"])
            points, data, cells = read_vtu(tmp_path / "vtk" / name)
            assert len(points) == cells == len(g["x"])
            np.testing.assert_array_equal(points, g["x"][()].astype(np.float32))
            np.testing.assert_array_equal(data["velocity"], g["v"][()].astype(np.float32))
            np.testing.assert_array_equal(data["divergence"], g["divergence"][()].astype(np.float32))
            np.testing.assert_array_equal(data["density"], g["density"][()].astype(np.float32))
            np.testing.assert_array_equal(data["id"], g["ids"][()])
        scene = json.loads(f.attrs["scene"])
        boundary = f["boundary/x"][()]
    solid_pts, _, _ = read_vtu(tmp_path / "vtk" / "solid.vtu")
    walls, _, _ = read_vtu(tmp_path / "vtk" / "walls.vtu")
    assert len(solid_pts) == len(solid) and len(solid_pts) + len(walls) == len(boundary)
    np.testing.assert_allclose(np.sort(solid_pts, axis=0), np.sort(solid.astype(np.float32), axis=0), atol=1e-6)
    lo, hi = np.array(scene["domain"]["min"]), np.array(scene["domain"]["max"])
    assert (((walls < lo) | (walls > hi)).any(axis=1)).all()
    assert not list(tmp_path.glob(".fgs-*"))


def test_split_boundary_without_a_domain_keeps_everything_as_solid():
    b = np.random.default_rng(0).random((10, 3))
    solid, walls = split_boundary(b, {})
    assert len(solid) == 10 and len(walls) == 0


def test_vtk_refuses_a_file_without_frames(tmp_path):
    with h5py.File(tmp_path / "r.h5", "w") as f:
        f["gaussians/D"] = np.zeros(3)
        f.create_group("probes/-x")
    with pytest.raises(ValueError, match="--vtk.*--record-probe"):
        check_vtk_source(tmp_path / "r.h5")
    with h5py.File(tmp_path / "other.h5", "w") as f:
        f["x"] = np.zeros(3)
    with pytest.raises(ValueError, match="--vtk.*neither /frames"):
        export_vtk(tmp_path / "other.h5", tmp_path / "out")
    assert not (tmp_path / "out").exists()
