"""nbv.bench.splash_probe: a probe as a SPlisHSPlasH scene (voxel mesh, fluid block, settings), and the time-mean drag
on a sphere in both engines within 10 % (run for real when pysplishsplash is installed, else skipped)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from fluidsim.config import SolverConfig
from fluidsim.probes import ProbeConfig, probe_setup
from fluidsim.scene import lattice_in_box
from fluidsim.sources import sphere_particles
from nbv.bench import splash as peer
from nbv.bench.splash_probe import (
    fluid_block,
    force_check,
    passage_steps,
    probe_scene_json,
    voxel_surface,
    write_probe_scenes,
)


def _signed_volume(verts, faces) -> float:
    v = np.asarray(verts, np.float64)
    a, b, c = (v[np.asarray(faces)[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def _edge_counts(faces) -> np.ndarray:
    f = np.asarray(faces)
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    return np.unique(edges, axis=0, return_counts=True)[1]


@pytest.mark.parametrize("seed", [0, 1])
def test_voxel_surface_is_the_closed_outward_union_of_cubes(seed):
    rng = np.random.default_rng(seed)
    cells = np.argwhere(rng.random((6, 5, 4)) < 0.5)  # a ragged blob, with cubes touching at edges and corners
    spacing, origin = 0.07, np.array([0.3, -1.2, 0.01])
    verts, faces = voxel_surface(origin + spacing * cells, spacing)
    assert _signed_volume(verts, faces) == pytest.approx(len(cells) * spacing**3, rel=1e-9)  # M s^3, outward
    assert np.all(_edge_counts(faces) % 2 == 0)  # closed: every edge on an even number of faces
    lo = verts.min(0)
    assert np.allclose(lo, origin + spacing * cells.min(0) - spacing / 2)  # the cubes' faces, half a spacing out


def test_voxel_surface_inset_by_half_a_spacing_passes_through_the_outer_centres():
    """A box of 5 x 2 x 3 particles gives the box of their centres, 4 x 1 x 2 spacings; an L of two such boxes (a
    concave edge) gives the union of their centres' boxes, 14 spacings^3; both closed and outward."""
    spacing, origin = 0.07, np.array([0.3, -1.2, 0.01])
    box = np.argwhere(np.ones((5, 2, 3), bool))
    verts, faces = voxel_surface(origin + spacing * box, spacing, 0.5 * spacing)
    assert np.allclose(verts.min(0), origin) and np.allclose(verts.max(0), origin + spacing * np.array([4, 1, 2]))
    assert _signed_volume(verts, faces) == pytest.approx(8 * spacing**3, rel=1e-9)
    leg = np.argwhere(np.ones((2, 3, 3), bool)) + [0, 2, 0]
    verts, faces = voxel_surface(origin + spacing * np.concatenate([box, leg]), spacing, 0.5 * spacing)
    assert _signed_volume(verts, faces) == pytest.approx(14 * spacing**3, rel=1e-9)
    assert np.all(_edge_counts(faces) % 2 == 0)
    with pytest.raises(ValueError, match="inset"):
        voxel_surface(origin + spacing * box, spacing, 0.6 * spacing)


def test_voxel_surface_refuses_points_off_the_lattice():
    with pytest.raises(ValueError, match="lattice"):
        voxel_surface(np.array([[0.0, 0, 0], [0.033, 0, 0]]), 0.05)


def _sphere_probe(r: float = 0.05, radius: float = 0.5):
    config = SolverConfig(particle_radius=r)
    probe = ProbeConfig(directions=("-x",))
    solid = sphere_particles((0.0, 0.0, 0.0), radius, config.spacing, fill=True)
    return solid, probe_setup(solid, "-x", probe, config.spacing), config, probe


def test_probe_scene_carries_the_probe(tmp_path):
    solid, setup, config, _ = _sphere_probe()
    scene = probe_scene_json(setup, config, 100)
    c, m = scene["Configuration"], scene["Materials"][0]
    assert c["boundaryHandlingMethod"] == 0 and c["simulationMethod"] == 4 and c["cflMethod"] == 0
    assert c["timeStepSize"] == config.dt and c["stopAt"] == pytest.approx(100 * config.dt)
    assert c["maxError"] == config.max_density_error and c["maxErrorV"] == config.max_divergence_error
    assert m["viscosityMethod"] == 1 and m["viscosity"] == pytest.approx(config.viscosity / config.rest_density)
    assert m["viscosityBoundary"] == pytest.approx(config.wall_viscosity / config.rest_density)
    box, body = scene["RigidBodies"]
    assert box["isWall"] and not body["isWall"] and not body["isDynamic"]
    lo, hi = np.asarray(setup.domain_min), np.asarray(setup.domain_max)
    assert np.allclose(box["translation"], (lo + hi) / 2) and np.allclose(box["scale"], hi - lo)
    block = scene["FluidBlocks"][0]
    assert block["initialVelocity"] == list(setup.velocity)
    start, end = fluid_block(setup, config.particle_radius)
    counts = [round((e - s) / config.spacing) - 1 for s, e in zip(start, end, strict=True)]
    ours = lattice_in_box(setup.fluid_min, setup.fluid_max, config.spacing)
    assert np.prod(counts) == len(ours)  # SPlisHSPlasH's block is our slab, particle for particle
    assert np.allclose(np.asarray(start) + config.spacing, ours.min(0))
    paths = write_probe_scenes(tmp_path, solid, {"-x": setup}, config, 100, dynamic=True)
    written = json.loads(paths["-x"].read_text())
    assert written["RigidBodies"][1]["isDynamic"] and (tmp_path / "solid.obj").exists()


def test_passage_steps_ends_at_the_far_side_or_when_the_tail_reaches_the_solid():
    solid, setup, config, _ = _sphere_probe()
    to_far = setup.fluid_min[0] - solid[:, 0].min()  # the slab's downstream face to the sphere's far side
    tail_to_near = setup.fluid_max[0] - solid[:, 0].max()  # the slab's upstream face to the sphere's near side
    expected = round(min(to_far, tail_to_near) / (3.0 * config.dt))
    assert passage_steps(solid, setup, config.dt) == expected
    # a solid longer than the slab: the tail reaches it before the front passes it
    long_solid = np.concatenate([solid, solid - [3.0 * (solid[:, 0].max() - solid[:, 0].min()), 0.0, 0.0]])
    tail_first = round((setup.fluid_max[0] - long_solid[:, 0].max()) / (3.0 * config.dt))
    assert passage_steps(long_solid, setup, config.dt) == tail_first
    assert tail_first < round((setup.fluid_min[0] - long_solid[:, 0].min()) / (3.0 * config.dt))
    with pytest.raises(ValueError, match="inflow"):
        passage_steps(solid, probe_setup(solid, "-y", ProbeConfig(), config.spacing), config.dt)


def _splash_installed() -> bool:
    return subprocess.run([sys.executable, str(peer.WORKER), "--probe"], capture_output=True).returncode == 0


@pytest.mark.skipif(not _splash_installed(), reason="pysplishsplash is not installed (pip install -e .[bench])")
def test_sphere_drag_matches_splishsplash():
    """The -x probe on a filled sphere (R = 0.5 m, r = 0.05 m, ~1k fluid particles), over the slab's passage: the
    time-mean drag of the two engines within 10 % (measured 0.97; at r = 0.035 m, 1.05)."""
    solid, setup, config, probe = _sphere_probe()
    check = force_check(solid, setup, config, probe, passage_steps(solid, setup, config.dt), threads=2)
    assert check.ours.fluid_particles == check.splash.fluid_particles
    assert check.drag_ours > 0 and check.drag_splash > 0  # both push the sphere along the flow
    assert check.ratio == pytest.approx(1.0, abs=0.10)


def test_export_splishsplash_writes_a_scene_per_probe(tmp_path):
    """`fluidgs export RESULT.h5 --splishsplash DIR`: the probes laid out around the stored solid, one scene each."""
    import h5py

    from apps import cli
    from nbv.physics.config import PhysicsConfig
    from nbv.physics.plan import ProbePlan

    config = PhysicsConfig.quick(particle_radius=0.05, directions=("-x", "+z"))
    solid = sphere_particles((0.0, 0.2, 0.0), 0.3, 0.1, fill=True)
    h5 = tmp_path / "result.h5"
    with h5py.File(h5, "w") as f:
        f["solid/x"] = solid
        f.attrs["config"] = json.dumps(config.to_dict())
    out = tmp_path / "scenes"
    assert cli.main(["export", str(h5), "--splishsplash", str(out), "--probe=+z", "--steps", "40"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["box.obj", "probe_+z.json", "solid.obj"]
    scene = json.loads((out / "probe_+z.json").read_text())
    setup = ProbePlan.of(solid, config).setups["+z"]
    assert scene["FluidBlocks"][0]["initialVelocity"] == list(setup.velocity)
    assert scene["Configuration"]["stopAt"] == pytest.approx(40 * config.dt)
    assert cli.main(["export", str(h5), "--splishsplash", str(out), "--probe=-y"]) == 2  # not a probe of the run
