"""The plan of a probe run (nbv.physics.plan): each probe laid out once per run, the crop a subset of one run, and
one solidify configuration shared by the run, the memory estimate and the inspection."""

import math

import numpy as np
import pytest
import torch

from fluidsim import probes
from nbv.physics import PhysicsConfig, ProbePlan, RunFrame, floaters, memory, run, simulate_gaussians
from nbv.physics.trajectory import RecordConfig
from recon.gaussians import GaussianSet


def shell(n: int = 200, radius: float = 0.5) -> GaussianSet:
    i = np.arange(n) + 0.5
    phi, th = np.arccos(1 - 2 * i / n), math.pi * (1 + 5**0.5) * i
    pts = radius * np.stack([np.cos(th) * np.sin(phi), np.sin(th) * np.sin(phi), np.cos(phi)], 1)
    return GaussianSet.from_points(torch.tensor(pts, dtype=torch.float32), scale=0.12, opacity=0.9)


CFG = PhysicsConfig(particle_radius=0.08, steps=4, dt=0.004, directions=("-x", "-y"), scale=1.0)


@pytest.mark.parametrize("exact_memory", [False, True])
def test_a_run_lays_out_each_probe_once(monkeypatch, exact_memory):
    """Around the solid, every probe's setup is computed once per run, whatever reads it (memory, time step,
    recording, accumulator bounds, the probes, the empty scene); the cheap memory bound lays the probes out once more
    around the Gaussians' box (two points), before the solid exists."""
    calls = []
    original = probes.probe_setup

    def counted(points, direction, probe, spacing):
        calls.append((len(np.asarray(points).reshape(-1, 3)), direction))
        return original(points, direction, probe, spacing)

    monkeypatch.setattr(probes, "probe_setup", counted)
    if exact_memory:  # the box did not fit: the memory is checked again around the solid, with the plan's setups
        monkeypatch.setattr(run, "check_memory_bound", lambda frame: True)
    res = simulate_gaussians(shell(), CFG, progress=False, record=RecordConfig(("-x",), every=2))
    assert res.empty_per_probe is not None and len(res.solid) > 2
    assert [d for n, d in calls if n == len(res.solid)] == list(CFG.directions)
    assert [d for n, d in calls if n == 2] == ([] if exact_memory else list(CFG.directions))
    assert len(calls) == (1 if exact_memory else 2) * len(CFG.directions)


@pytest.mark.parametrize("replicas", [1, 2])
def test_a_run_sizes_the_solid_lattice_once(monkeypatch, replicas):
    """The lattice's extent (the boxes of the Gaussians that can make solid) is computed once per run, in its frame:
    the memory bound, the exact check around the solid and the solid of every replica read it."""
    calls = []
    original = floaters.lattice_extent

    def counted(lo, hi, keep):
        calls.append(len(lo))
        return original(lo, hi, keep)

    monkeypatch.setattr(floaters, "lattice_extent", counted)
    monkeypatch.setattr(run, "check_memory_bound", lambda frame: memory.check_memory_bound(frame) or True)
    res = simulate_gaussians(shell(), PhysicsConfig(**{**CFG.to_dict(), "replicas": replicas}), progress=False)
    assert len(res.solid) > 2 and (res.replicas is None) == (replicas == 1)
    assert calls == [200]


def test_the_crop_is_a_subset_of_one_run():
    """A crop simulates the kept Gaussians once (no second run) and gives every Gaussian its row: the kept rows are
    those of the kept Gaussians simulated alone at the same scale."""
    g = shell()
    means = g.means.detach().numpy()
    crop = (-1.0, -1.0, -1.0, 0.3, 1.0, 1.0)
    cfg = PhysicsConfig(**{**CFG.to_dict(), "crop": crop, "directions": ("-x",)})
    res = simulate_gaussians(g, cfg, progress=False)
    kept = means[:, 0] <= 0.3
    np.testing.assert_array_equal(res.kept, kept)
    alone = simulate_gaussians(
        g.subset(torch.from_numpy(np.nonzero(kept)[0])),
        PhysicsConfig(**{**cfg.to_dict(), "crop": None}),
        progress=False,
    )
    np.testing.assert_array_equal(res.per_probe[:, kept], alone.per_probe)
    assert (res.per_probe[:, ~kept] == 0).all() and res.dbar == alone.dbar and res.config.crop == crop


def test_one_solidify_config_for_the_run_the_estimate_and_the_inspection():
    cfg = PhysicsConfig(particle_radius=0.04, opacity_threshold=0.2, fill_cavities=False)
    scfg = cfg.solidify_config()
    assert (scfg.spacing, scfg.opacity_threshold, scfg.fill_cavities) == (0.08, 0.2, False)
    assert cfg.solidify_config(max_points=7).max_points == 7
    frame = RunFrame.of(shell(), CFG)
    assert frame.kept is None and frame.sim.num == 200
    np.testing.assert_array_equal(frame.reach, CFG.n_radius * frame.sim.radii)
    plan = ProbePlan.of(frame.solidify().points, CFG)
    assert tuple(plan.setups) == CFG.directions
    lo, hi = plan.bounds
    assert all((lo <= s.domain_min).all() and (hi >= s.domain_max).all() for s in plan.setups.values())
