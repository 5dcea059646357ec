"""The one simulation-frame value of the Gaussians (nbv.physics.scene_frame.SimGaussians): equal to the conversion
it replaces, Sigma^-1 Sigma = I, reused as given, refused with another transform, and built once per run."""

import math

import numpy as np
import pytest
import torch

from nbv.physics import PhysicsConfig, scene_frame, simulate_gaussians, solidify
from nbv.physics.scene_frame import SceneTransform, SimGaussians, as_sim, gaussian_arrays_in_sim
from recon.gaussians import GaussianSet


def shell(n: int = 200, radius: float = 0.5) -> GaussianSet:
    i = np.arange(n) + 0.5
    phi, th = np.arccos(1 - 2 * i / n), math.pi * (1 + 5**0.5) * i
    pts = radius * np.stack([np.cos(th) * np.sin(phi), np.sin(th) * np.sin(phi), np.cos(phi)], 1)
    g = GaussianSet.from_points(torch.tensor(pts, dtype=torch.float32), scale=0.06, opacity=0.9)
    g.quats.data = torch.nn.functional.normalize(torch.randn(n, 4, generator=torch.Generator().manual_seed(0)), dim=1)
    g.log_scales.data = torch.log(torch.rand(n, 3, generator=torch.Generator().manual_seed(1)) * 0.05 + 0.01)
    return g


def test_sim_gaussians_equal_the_conversion_and_invert_exactly():
    g, tr = shell(), SceneTransform("z", 1.7)
    sim = SimGaussians.of(g, tr)
    means, covs, opac, radii = gaussian_arrays_in_sim(g, tr)
    assert np.array_equal(sim.means, means) and np.array_equal(sim.covariances, covs)
    assert np.array_equal(sim.opacities, opac) and np.array_equal(sim.radii, radii) and len(sim) == g.num
    eye = np.einsum("nij,njk->nik", sim.inverse_covariances(), sim.covariances)
    assert np.abs(eye - np.eye(3)).max() < 1e-9
    assert as_sim(sim, tr) is sim
    with pytest.raises(ValueError, match="converted with"):
        as_sim(sim, SceneTransform("y", 1.7))


def test_solid_from_the_value_equals_the_solid_from_the_set():
    g, tr = shell(), SceneTransform("y", 1.0)
    cfg = solidify.SolidifyConfig(spacing=0.1)
    a = solidify.gaussians_to_solid(g, cfg, tr)
    b = solidify.gaussians_to_solid(SimGaussians.of(g, tr), cfg, tr)
    assert np.array_equal(a.points, b.points) and a.counts == b.counts


def test_a_run_converts_its_gaussians_once(monkeypatch):
    calls = []
    original = scene_frame.gaussian_arrays_in_sim

    def counted(gaussians, transform):
        calls.append(gaussians.num)
        return original(gaussians, transform)

    monkeypatch.setattr(scene_frame, "gaussian_arrays_in_sim", counted)
    cfg = PhysicsConfig(particle_radius=0.08, steps=5, dt=0.004, empty_reference=False, directions=("-x",))
    result = simulate_gaussians(shell(), cfg, progress=False)
    assert len(result.solid) > 0
    assert calls == [200], f"the run converted its Gaussians {len(calls)} times"
