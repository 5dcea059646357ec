"""The functional error (nbv.functional): the reference against itself, planted defects above the floor, the solids'
overlap, the velocity sampling's twin, the cache and the command."""

import json
import os
from pathlib import Path

import numpy as np
import pytest

from fluidsim.scene import lattice_in_box
from nbv.functional import METRICS, FlowCache, compare, solid_overlap
from nbv.functional.flow import SampleGrid, relative_l2, sph_velocity, sph_velocity_np
from nbv.functional.solids import SolidSource, lattice_points, resample_cubes
from nbv.physics import PhysicsConfig
from nbv.physics.forces import moving_mean
from nbv.physics.scene_frame import SceneTransform

SPACING = 0.1
CONFIG = PhysicsConfig(particle_radius=0.05, steps=150, empty_reference=False)


def _solid(points: np.ndarray, name: str) -> SolidSource:
    return SolidSource(Path(name), "result", SceneTransform(), (), _solid=points)


@pytest.fixture(scope="module")
def body() -> np.ndarray:
    """A 1.6 x 0.8 x 0.8 m block on the lattice of offset 0 (spacing 0.1 m)."""
    return lattice_in_box([-0.8, -0.4, -0.4], [0.8, 0.4, 0.4], SPACING) - 0.05


def test_lattice_resampling_keeps_a_lattice_solid_and_shifts_it_as_cubes(body):
    same = resample_cubes(body, SPACING, (0, 0, 0))
    assert {tuple(p) for p in np.round(same / SPACING, 6)} == {tuple(p) for p in np.round(body / SPACING, 6)}
    shifted = resample_cubes(body, SPACING, (0.5, 1 / 3, 0.2))
    assert abs(len(shifted) - len(body)) <= 0.25 * len(body)  # the same volume, give or take a face layer
    assert np.allclose(((shifted / SPACING) - (0.5, 1 / 3, 0.2)) % 1.0 % 0.999999, 0.0, atol=1e-6)
    assert len(lattice_points([0, 0, 0], [0.35, 0.1, 0.1], SPACING, (0, 0, 0))) == 4 * 2 * 2


def test_overlap_of_a_solid_with_itself_and_with_a_disjoint_one(body):
    assert solid_overlap(body, body, SPACING).iou == 1.0
    assert solid_overlap(body, body, SPACING).chamfer == 0.0
    far = solid_overlap(body, body + [5.0, 0, 0], SPACING)
    assert far.iou == 0.0 and 5.0 - 1.6 < far.chamfer < 5.0  # the near faces are 3.4 m apart, the far ones 6.6


def test_sph_velocity_equals_its_twin():
    rng = np.random.default_rng(0)
    x, v = rng.uniform(0, 0.5, (400, 3)), rng.normal(size=(400, 3))
    pts = rng.uniform(-0.1, 0.6, (60, 3))
    np.testing.assert_allclose(sph_velocity(pts, x, v, 0.1, 1e-4), sph_velocity_np(pts, x, v, 0.1, 1e-4), atol=1e-12)


def test_moving_mean_and_relative_l2():
    s = np.array([[1.0, 0, 0], [3.0, 0, 0], [5.0, 0, 0], [7.0, 0, 0]])
    np.testing.assert_allclose(moving_mean(s, np.full(4, 0.5), 1.0)[:, 0], [2.0, 4.0, 6.0])
    assert relative_l2(s, s) == 0.0 and relative_l2(2 * s, s) == pytest.approx(1.0)
    assert relative_l2(np.zeros(3), np.zeros(3)) == 0.0


@pytest.fixture(scope="module")
def comparisons(body):
    """The block against itself, and two planted defects: its front half missing (the -x probe comes from +x), and a
    tunnel through it along the flow. (A vertical hole the -x probe's fluid never enters in the run gives the same
    forces to round-off: the error measures what the probe sees.)"""
    ref = _solid(body, "reference")
    rear = body[body[:, 0] < 0.1]
    hole = body[np.linalg.norm(body[:, [1, 2]], axis=1) > 0.2]  # a tunnel along the flow
    cache = FlowCache(None)
    return {
        name: compare(ref, _solid(pts, name), CONFIG, ("-x",), progress=False, cache=cache)
        for name, pts in (("same", body), ("rear", rear), ("hole", hole))
    }


def test_the_reference_against_itself_is_at_the_floor(comparisons):
    c = comparisons["same"]
    assert c.error == 0.0 and c.overlap.iou == 1.0  # the same lattice: the same flow, bit for bit
    assert c.floor > 0.0  # the shifted lattice does change the flow: that is the floor
    assert all(c.floors["-x"][m] >= 0 and np.isfinite(c.floors["-x"][m]) for m in METRICS)


@pytest.mark.parametrize("defect", ["rear", "hole"])
def test_a_planted_defect_is_above_the_floor(comparisons, defect):
    c = comparisons[defect]
    assert c.overlap.iou < c.overlap_floor.iou
    assert c.error > 2.0 * c.floor, (c.error, c.floor)
    rec = c.record()
    assert rec["functional_error"]["value"] == c.error and rec["functional_error"]["floor"] == c.floor
    json.dumps(rec)  # JSON-able


def test_solids_that_do_not_overlap_are_refused_before_any_probe(body):
    with pytest.raises(ValueError, match="do not overlap.*--reference-transform"):
        compare(_solid(body, "ref"), _solid(body + [9.0, 0, 0], "rec"), CONFIG, ("-x",), progress=False)


def test_the_cache_serves_the_reference_and_reads_only_regular_well_formed_files(body, tmp_path):
    cache = FlowCache(tmp_path)
    cfg = PhysicsConfig(particle_radius=0.05, steps=30, empty_reference=False)
    ref = _solid(body, "reference")
    first = compare(ref, _solid(body[body[:, 0] < 0.3], "rec"), cfg, ("-x",), progress=False, cache=cache)
    assert first.settings["probe_runs"] == 3 and first.settings["cached_runs"] == 0
    again = compare(ref, _solid(body[body[:, 0] < 0.3], "rec"), cfg, ("-x",), progress=False, cache=cache)
    assert again.settings["probe_runs"] == 1 and again.settings["cached_runs"] == 2
    assert again.error == first.error and again.floor == pytest.approx(first.floor, rel=1e-6)
    entries = sorted(tmp_path.glob("*.npz"))
    assert len(entries) == 2
    grid = SampleGrid(np.zeros((5, 3)), 0.1, np.zeros(3), np.ones(3), (1,))
    # a FIFO, a link to a device and a truncated entry under the right names are ignored, never read
    os.mkfifo(tmp_path / "fifo.npz")
    (tmp_path / "link.npz").symlink_to("/dev/zero")
    (tmp_path / "bad.npz").write_bytes(b"PK\x03\x04 not a zip")
    for key in ("fifo", "link", "bad"):
        assert cache.get(key, 30, len(grid.points)) is None
    assert cache.get(entries[0].stem, 31, 5) is None  # the wrong shape for this run


def test_compare_command_on_a_mesh_against_itself_and_a_non_watertight_one(tmp_path, assets_dir, capsys):
    import open3d as o3d

    from apps.cli import main

    torus = assets_dir / "torus.obj"
    out = tmp_path / "c.json"
    args = ["compare", str(torus), "--reference", str(torus), "--particle-radius", "0.1", "--steps", "60"]
    assert main([*args, "-o", str(out), "--no-cache"]) == 0
    rec = json.loads(out.read_text())
    assert rec["functional_error"]["value"] == 0.0 and rec["overlap"]["iou"] == 1.0
    assert (tmp_path / "c.png").stat().st_size > 1000
    text = capsys.readouterr().out
    assert "noise floor" in text and "IoU 1.000" in text
    mesh = o3d.io.read_triangle_mesh(str(torus))
    mesh.remove_triangles_by_index(list(range(40)))
    o3d.io.write_triangle_mesh(str(tmp_path / "open.obj"), mesh)
    args = ["compare", str(torus), "--reference", str(tmp_path / "open.obj"), "--particle-radius", "0.1"]
    assert main([*args, "--steps", "30", "-o", str(tmp_path / "o.json"), "--no-cache"]) == 0
    assert "not watertight" in capsys.readouterr().out
    far = tmp_path / "far.json"
    shift = "1 0 0 50  0 1 0 0  0 0 1 0  0 0 0 1"
    assert main([*args, "--steps", "30", "-o", str(far), "--reference-transform", shift]) == 2
    assert not far.exists() and not (tmp_path / "far.png").exists()


def test_the_verdict_needs_a_floor_that_leaves_room_to_judge():
    """A floor of 50 % or more (too few steps for the fluid to pass the object) gives no verdict: a reconstruction
    that made no force at all once read 'indistinguishable' beside a floor of 100 %."""
    from nbv.functional import FLOOR_LIMIT, verdict_line

    assert "indistinguishable" in verdict_line(0.05, 0.04) and "above" in verdict_line(0.5, 0.04)
    for floor in (FLOOR_LIMIT, 1.0, float("nan")):
        line = verdict_line(1.0, floor)
        assert "cannot judge" in line and "--steps" in line and "indistinguishable" not in line
    assert "100 %" in verdict_line(1.0, 1.0) and "2.8 %" in verdict_line(0.028, 0.001)


def test_an_stl_reference_is_watertight_and_a_nan_mesh_is_named(tmp_path):
    """An STL stores each triangle's corners apart; read as it is, a closed box had no inside (an open can)."""
    import open3d as o3d

    from nbv.functional.solids import reference_source

    box = o3d.geometry.TriangleMesh.create_box(0.4, 0.4, 0.4)
    box.compute_triangle_normals()
    o3d.io.write_triangle_mesh(str(tmp_path / "box.stl"), box)
    src = reference_source(tmp_path / "box.stl", PhysicsConfig.quick(up="+y"), None, None)
    assert src.warnings == ()
    (tmp_path / "nan.obj").write_text("v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(ValueError, match="nan.obj: the mesh has NaN or Inf"):
        reference_source(tmp_path / "nan.obj", PhysicsConfig.quick(up="+y"), None, None)


def test_the_reference_transform_file_is_checked_and_never_overwritten(tmp_path, caplog):
    """--reference-transform m.json -o m.json replaced the matrix with the record; a FIFO, a missing file, a huge
    file and a NaN are named before any work."""
    from apps import cli
    from nbv.functional.solids import MATRIX_FILE_BYTES, parse_matrix

    m = tmp_path / "m.json"
    m.write_text(json.dumps(np.eye(4).reshape(-1).tolist()))
    np.testing.assert_array_equal(parse_matrix(str(m)), np.eye(4))
    os.mkfifo(tmp_path / "fifo.txt")
    (tmp_path / "big.txt").write_text("1 " * MATRIX_FILE_BYTES)
    for text, what in (
        (str(tmp_path / "fifo.txt"), "not a regular file"),
        (str(tmp_path / "none.json"), "does not exist"),
        (str(tmp_path / "big.txt"), "too large"),
        ("1,0,0,0,0,nan,0,0,0,0,1,0,0,0,0,1", "not finite"),
    ):
        with pytest.raises(ValueError, match=what):
            parse_matrix(text)
    before = m.read_bytes()
    mesh = tmp_path / "box.obj"
    import open3d as o3d

    o3d.io.write_triangle_mesh(str(mesh), o3d.geometry.TriangleMesh.create_box(0.4, 0.4, 0.4))
    args = ["compare", str(mesh), "--reference", str(mesh), "--reference-transform", str(m), "-o", str(m)]
    assert cli.main(args) == 2
    assert "would destroy the input" in caplog.text and m.read_bytes() == before
