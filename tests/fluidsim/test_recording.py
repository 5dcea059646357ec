"""fluidsim/recording.py: one probe stepped to OUT.h5 (the library half of `fluidgs sim`, the mesh demo and
`simulate --video`), and its summary checked against the file it wrote."""

import json

import h5py
import numpy as np
import pytest

from fluidsim import ProbeConfig, SolverConfig
from fluidsim.recording import Interrupted, probe_file_summary, probes_to_h5, simulate_to_h5
from fluidsim.sources import sphere_particles

from helpers.probe_files import sphere_probe_file

STEPS = 12


@pytest.fixture(scope="module")
def probe_run(tmp_path_factory):
    run, _, cfg = sphere_probe_file(tmp_path_factory.mktemp("rec") / "probe_-x.h5", STEPS)
    return (*run, cfg)


def test_probe_file_holds_the_frames_the_scene_and_the_sums(probe_run):
    path, history, solver, cfg = probe_run
    assert len(history) == STEPS
    with h5py.File(path) as f:
        scene = json.loads(f.attrs["scene"])
        assert scene["probe"] == "-x" and scene["steps"] == STEPS and scene["velocity"] == [-3.0, 0.0, 0.0]
        assert scene["dt"] == cfg.dt and scene["particle_radius"] == cfg.particle_radius
        steps = sorted(int(g.attrs["step"]) for g in f["frames"].values())
        assert steps == [0, 5, 10, STEPS]  # the first, every 5th and the last
        sums, counts = f["divergence_sum"][()], f["divergence_count"][()]
    s_now, c_now = solver.divergence_accumulation()
    np.testing.assert_array_equal(sums, s_now)
    np.testing.assert_array_equal(counts, c_now)


def test_probe_summary_is_computed_from_the_run(probe_run):
    path, history, solver, _ = probe_run
    s = probe_file_summary(path, history, solver)
    sums, counts = solver.divergence_accumulation()
    mean_d = np.where(counts > 0, sums / np.maximum(counts, 1), 0.0)
    assert s["file"] == path.name and s["fluid_particles"] == solver.fluid.capacity > 0
    assert s["boundary_particles"] == solver.boundary.count > 0
    assert s["retired"] == sum(h.retired for h in history)
    assert s["mean_particle_divergence"] == pytest.approx(float(mean_d.mean()))
    assert s["p95_particle_divergence"] == pytest.approx(float(np.percentile(mean_d, 95)))
    assert s["mean_density_iterations"] == pytest.approx(np.mean([h.density_iterations for h in history]))


def test_every_probe_gets_its_file_and_its_summary(probe_run, tmp_path):
    path, history, solver, cfg = probe_run
    solid = sphere_particles([0, 0, 0], 0.3, cfg.spacing, fill=True)
    probe = ProbeConfig(slab_thickness=0.2, margin=0.1, padding=0.2, directions=("-x",))
    seen = []
    summary = probes_to_h5(solid, cfg, probe, STEPS, tmp_path, "sphere", on_probe=lambda d, s: seen.append((d, s)))
    assert summary["solid"] == "sphere" and summary["solid_particles"] == len(solid) and summary["steps"] == STEPS
    assert (summary["particle_radius"], summary["dt"]) == (cfg.particle_radius, cfg.dt)
    assert seen == list(summary["probes"].items()) and list(summary["probes"]) == ["-x"]
    assert (tmp_path / "probe_-x.h5").is_file()
    # the same run as the fixture's single probe: the same summary
    assert summary["probes"]["-x"] == probe_file_summary(path, history, solver)


class _Stop:
    signum = None


def test_a_stop_request_ends_the_run_with_an_interrupted_file(tmp_path):
    import signal

    from fluidsim.probes import build_probe_solver, probe_setup

    cfg = SolverConfig(particle_radius=0.05)
    solid = sphere_particles([0, 0, 0], 0.3, cfg.spacing, fill=True)
    probe = ProbeConfig(slab_thickness=0.2, margin=0.1, padding=0.2, directions=("-x",))
    solver = build_probe_solver(solid, probe_setup(solid, "-x", probe, cfg.spacing), cfg, probe)
    stop = _Stop()
    stop.signum = signal.SIGTERM  # asked before the first step ends: stops after step 1
    with pytest.raises(Interrupted) as err:
        simulate_to_h5(solver, {"probe": "-x"}, tmp_path / "o.h5", 50, 10, "t", progress=False, stop=stop)
    assert err.value.step == 1 and err.value.exit_code == 143
    with h5py.File(tmp_path / "o.h5") as f:
        assert f.attrs["status"] == "interrupted"
        assert max(int(g.attrs["step"]) for g in f["frames"].values()) == 1
