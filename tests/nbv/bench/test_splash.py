"""nbv.bench.splash: the SPlisHSPlasH peer scene, its meshes and scene file, this engine's side of it, and the child
process (run for real when pysplishsplash is installed, else skipped; its error paths always)."""

from __future__ import annotations

import math
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from fluidsim.scene import lattice_counts
from fluidsim.sources import sphere_particles
from nbv.bench import splash as peer
from nbv.bench.splash import PeerScene, icosphere, peer_config, peer_particles, peer_solver, splash_scene_json, unit_box

SMALL = PeerScene(
    particle_radius=0.1,
    steps=3,
    sphere_radius=0.5,
    fluid_min=(0.8, -0.6, -0.6),
    fluid_max=(1.4, 0.6, 0.6),
    domain_min=(-1.2, -1.0, -1.0),
    domain_max=(2.0, 1.0, 1.0),
    threads=1,
)


def _signed_volume(verts, faces) -> float:
    """Volume enclosed by a triangle mesh, positive when its faces are wound counter-clockwise seen from outside."""
    v = np.asarray(verts, np.float64)
    a, b, c = (v[np.asarray(faces)[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


@pytest.mark.parametrize("k", [0, 1, 3, 5])
def test_icosphere_is_a_closed_outward_unit_sphere(k):
    verts, faces = icosphere(k)
    assert len(verts) == 10 * 4**k + 2 and len(faces) == 20 * 4**k
    edges = {tuple(sorted(e)) for f in faces for e in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0]))}
    assert len(verts) - len(edges) + len(faces) == 2  # Euler characteristic of a sphere: closed, no holes
    assert np.allclose(np.linalg.norm(verts, axis=1), 1.0, atol=1e-12)
    volume = _signed_volume(verts, faces)
    assert 0 < volume < 4 * math.pi / 3  # outward winding; an inscribed polyhedron
    if k == 5:
        assert volume == pytest.approx(4 * math.pi / 3, rel=2e-3)


def test_unit_box_is_the_outward_unit_cube(tmp_path):
    verts, faces = unit_box()
    assert len(faces) == 12 and _signed_volume(verts, faces) == pytest.approx(1.0, abs=1e-12)
    assert np.abs(verts).max() == 0.5
    path = tmp_path / "box.obj"
    peer.write_obj(path, verts, faces)
    lines = path.read_text().splitlines()
    read_v = [tuple(map(float, ln.split()[1:])) for ln in lines if ln.startswith("v ")]
    read_f = [tuple(int(i) - 1 for i in ln.split()[1:]) for ln in lines if ln.startswith("f ")]
    assert read_v == [tuple(map(float, v)) for v in verts] and read_f == faces  # OBJ indices are 1-based


@pytest.mark.parametrize("scene", [PeerScene(), SMALL, replace(SMALL, particle_radius=0.075)])
def test_splash_fluid_block_is_our_lattice(scene):
    """SPlisHSPlasH's denseMode-0 block puts its first particle 2r inside `start` and round((end - start) / 2r) - 1
    per axis: the block widened by r per side is our cell-centred lattice, particle for particle."""
    spacing = scene.spacing
    ours = lattice_counts(scene.fluid_min, scene.fluid_max, spacing).astype(int)
    block = splash_scene_json(scene, "s.obj", "b.obj")["FluidBlocks"][0]
    theirs = [round((e - s) / spacing) - 1 for s, e in zip(block["start"], block["end"], strict=True)]
    assert theirs == ours.tolist() and math.prod(theirs) == scene.expected_fluid_particles()
    particles = peer_particles(scene, spacing)
    assert len(particles.fluid) == scene.expected_fluid_particles()
    first = np.asarray(block["start"]) + spacing
    assert np.allclose(particles.fluid.min(axis=0), first, atol=1e-12)


def test_splash_scene_file_carries_the_scene():
    scene = PeerScene(viscosity=2.5, rest_density=1250.0, dt=0.001)
    cfg = splash_scene_json(scene, "sphere.obj", "box.obj")
    conf = cfg["Configuration"]
    assert conf["simulationMethod"] == 4 and conf["cflMethod"] == 0 and conf["timeStepSize"] == 0.001
    assert conf["particleRadius"] == scene.particle_radius and conf["gravitation"] == list(scene.gravity)
    assert conf["DFSPH"]["maxError"] == scene.max_density_error_percent
    material = cfg["Materials"][0]
    assert material["viscosity"] == pytest.approx(2.5 / 1250.0) and material["density0"] == 1250.0
    walls, sphere = cfg["RigidBodies"]
    assert walls["isWall"] and walls["mapInvert"] and walls["scale"] == pytest.approx([4.4, 3.2, 3.2])
    assert walls["translation"] == pytest.approx([0.2, 0.0, 0.0])
    assert sphere["scale"] == [1.0] * 3 and not sphere["isDynamic"]
    assert cfg["FluidBlocks"][0]["initialVelocity"] == [-3.0, 0.0, 0.0]


def test_our_side_of_the_peer_scene():
    cfg = peer_config(SMALL, divergence_warm_start=False)
    assert (cfg.particle_radius, cfg.dt, cfg.viscosity, cfg.boundary_viscosity) == (0.1, SMALL.dt, 10.0, 0.0)
    assert (cfg.min_iterations, cfg.max_iterations, cfg.divergence_warm_start) == (2, 100, False)
    particles = peer_particles(SMALL, cfg.spacing)
    assert len(particles.solid) == len(sphere_particles((0, 0, 0), 0.5, cfg.spacing, fill=True))
    assert np.array_equal(particles.velocity, np.tile([-3.0, 0.0, 0.0], (len(particles.fluid), 1)))
    lo, hi = np.asarray(SMALL.domain_min), np.asarray(SMALL.domain_max)
    assert not np.any(np.all((particles.walls > lo) & (particles.walls < hi), axis=1))  # all walls outside
    solver = peer_solver(SMALL, particles, cfg)
    assert solver.fluid.capacity == SMALL.expected_fluid_particles()
    stats = solver.step()
    assert stats.density_iterations >= 2


def test_run_splash_names_the_fix_when_the_worker_cannot_import(monkeypatch):
    monkeypatch.setattr(peer, "_worker_cmd", lambda *a: [sys.executable, "-c", f"import sys; sys.exit({17})"])
    with pytest.raises(RuntimeError, match="pip install pysplishsplash"):
        peer.run_splash(SMALL)
    assert not peer.splash_available()
    monkeypatch.setattr(peer, "_worker_cmd", lambda *a: [sys.executable, "-c", "import sys; sys.exit(3)"])
    with pytest.raises(RuntimeError, match="exit code 3"):
        peer.run_splash(SMALL)


def _splash_installed() -> bool:
    return subprocess.run([sys.executable, str(peer.WORKER), "--probe"], capture_output=True).returncode == 0


@pytest.mark.skipif(not _splash_installed(), reason="pysplishsplash is not installed (pip install -e .[bench])")
def test_splash_runs_the_same_scene():
    result = peer.run_splash(SMALL, timeout_s=300)
    assert result["fluid_particles"] == SMALL.expected_fluid_particles()  # the same lattice
    assert result["steps"] == 3 and len(result["ms_per_step"]) == 3 and result["median_ms_steps_2_to_n"] > 0
    assert result["config"]["dt"] == pytest.approx(SMALL.dt)
    assert result["config"]["viscosity_kinematic"] == pytest.approx(SMALL.kinematic_viscosity)
    assert result["threads"] == 1 and result["boundary_particles"] > 0
    assert result["final_max_speed"] < 10.0  # the slab moved at 3 m/s, under gravity, for 6 ms


def test_bench_sim_smoke(tmp_path, capsys):
    """`fluidgs bench sim` on the paper-scale peer scene, two steps, no peer: the counts the docs quote."""
    import json

    from apps import cli

    out = tmp_path / "sim.json"
    assert cli.main(["bench", "sim", "--steps", "2", "--no-peer", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "particles: 58320 fluid, 33401 solid, 64960 wall" in text and "median over steps 2..2" in text
    figures = json.loads(out.read_text())["fluidgaussian"]
    assert figures["fluid_particles"] == PeerScene().expected_fluid_particles() == 58320 and figures["steps"] == 2
    # the throughput the engine target is stated in: fluid particles over the median step time
    rate = figures["fluid_particle_steps_per_s"]
    assert rate == pytest.approx(58320 / (figures["median_ms_steps_2_to_n"] / 1e3))
    assert f"{rate / 1e6:.2g} M fluid particle-steps/s" in text
    assert cli.main(["bench", "sim", "--steps", "1", "--no-peer"]) == 2


@pytest.mark.parametrize(
    "change, message",
    [
        ({"particle_radius": 0.0}, "particle_radius must be a finite number > 0"),
        ({"dt": float("nan")}, "dt must be a finite number > 0"),
        ({"steps": 0}, "steps must be an integer >= 1"),
        ({"max_iterations": 1}, "max_iterations .1. must be >= min_iterations"),
        ({"fluid_min": (2.2, -1.0, -1.0)}, "fluid_min/fluid_max must be 3 numbers each with min < max"),
        ({"fluid_max": (3.0, 1.35, 1.35)}, "must lie inside the domain"),
    ],
)
def test_peer_scene_is_validated(change, message):
    with pytest.raises(ValueError, match=message):
        replace(PeerScene(), **change)


def test_bench_sim_states_the_release_target():
    from apps.bench.sim import RATIO_TARGET, target_verdict

    assert RATIO_TARGET == 0.25  # a quarter of SPlisHSPlasH's step time: about 3 M fluid particle-steps/s on 2 cores
    assert target_verdict(0.25) == "(target <= 0.25: met)"
    assert target_verdict(0.41) == "(target <= 0.25: not met)"
