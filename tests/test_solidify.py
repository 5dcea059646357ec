"""Gaussians -> solid particles: the Taichi lattice splat against its brute-force twin, transforms,
cavity filling, and the errors (empty solid, size guard, bad config)."""

import math
from collections import deque

import numpy as np
import pytest
import torch

from nbv import solidify
from nbv.solidify import (
    MAX_ALPHA,
    SceneTransform,
    SolidifyConfig,
    combined_opacity_reference,
    estimate_lattice_points,
    fill_enclosed,
    gaussian_arrays_in_sim,
    gaussians_to_solid,
    lattice_log_transmittance,
)
from recon.gaussians import GaussianSet


def random_gaussians(n: int, seed: int, extent: float = 0.3, scale_range=(0.02, 0.12)) -> GaussianSet:
    rng = np.random.default_rng(seed)
    lo, hi = np.log(scale_range[0]), np.log(scale_range[1])
    return GaussianSet(torch.tensor(rng.uniform(-extent, extent, (n, 3))), torch.tensor(rng.normal(size=(n, 4))),
                       torch.tensor(rng.uniform(lo, hi, (n, 3))), torch.tensor(rng.normal(0.5, 1.5, n)),
                       torch.zeros(n, 1, 3, dtype=torch.float64))


def lattice_points(lattice_min, shape, spacing):
    idx = np.stack(np.meshgrid(*[np.arange(d) for d in shape], indexing="ij"), -1).reshape(-1, 3)
    return lattice_min + spacing * idx


def test_lattice_opacity_matches_brute_force_twin():
    g = random_gaussians(60, seed=0)
    cfg = SolidifyConfig(spacing=0.04)
    tr = SceneTransform()
    lattice_min, log_t = lattice_log_transmittance(g, cfg, tr)
    assert np.allclose(lattice_min / cfg.spacing, np.round(lattice_min / cfg.spacing), atol=1e-9)  # aligned
    fast = 1.0 - np.exp(log_t.astype(np.float64).reshape(-1))
    pts = lattice_points(lattice_min, log_t.shape, cfg.spacing)
    means, covs, opac, _ = gaussian_arrays_in_sim(g, tr)
    cut = combined_opacity_reference(pts, means, covs, opac, sigma_cutoff=cfg.sigma_cutoff)
    full = combined_opacity_reference(pts, means, covs, opac)
    assert fast.max() > 0.9 and (fast < 1e-3).mean() > 0.05      # the lattice sees solid and empty space
    assert np.abs(fast - cut).max() < 2e-5                        # same sum, f32 accumulation
    # The cut drops only points with d_g >= 3: at most -log(1 - o_g e^-4.5) per Gaussian in log T.
    bound = 1.0 - math.exp(np.log1p(-np.minimum(opac * math.exp(-4.5), MAX_ALPHA)).sum())
    assert np.abs(fast - full).max() <= bound + 2e-5
    assert np.abs(fast - full).max() > 1e-6                       # the cut does drop something


def test_solid_mask_equals_twin_away_from_tau():
    g = random_gaussians(40, seed=1)
    cfg = SolidifyConfig(spacing=0.05, opacity_threshold=0.3)
    tr = SceneTransform("z", 1.5)
    solid = gaussians_to_solid(g, cfg, tr)
    pts = lattice_points(solid.lattice_min, solid.lattice_shape, cfg.spacing)
    means, covs, opac, _ = gaussian_arrays_in_sim(g, tr)
    ref = combined_opacity_reference(pts, means, covs, opac, sigma_cutoff=cfg.sigma_cutoff)
    mismatch = solid.occupancy.reshape(-1) != (ref >= cfg.opacity_threshold)
    assert np.all(np.abs(ref[mismatch] - cfg.opacity_threshold) < 2e-5)
    assert solid.occupancy.sum() == len(solid.points) > 100
    assert np.allclose(solid.points, pts[solid.occupancy.reshape(-1)])
    assert estimate_lattice_points(g, cfg, tr) == solid.occupancy.size


def test_transform_z_up_rotation_scale_and_inverse():
    tr = SceneTransform("z", 2.0)
    assert np.allclose(tr.to_sim([[0.0, 0.0, 1.0]]), [[0.0, 2.0, 0.0]])    # +z -> +y
    assert np.allclose(tr.to_sim([[0.0, 1.0, 0.0]]), [[0.0, 0.0, -2.0]])   # +y -> -z
    assert np.allclose(tr.to_sim([[1.0, 0.0, 0.0]]), [[2.0, 0.0, 0.0]])
    p = np.random.default_rng(2).normal(size=(20, 3))
    assert np.allclose(tr.to_scene(tr.to_sim(p)), p)
    assert np.allclose(SceneTransform().to_sim(p), p)
    # Covariances: those of the transformed samples.
    g = random_gaussians(5, seed=3)
    means, covs, _, radii = gaussian_arrays_in_sim(g, tr)
    assert np.allclose(means, tr.to_sim(g.means.numpy()))
    assert np.allclose(covs, tr.covariances_to_sim(g.covariances().numpy()))
    assert np.allclose(radii, 2.0 * g.max_radii().numpy())
    a = np.random.default_rng(4).normal(size=(3, 3))
    samples = np.random.default_rng(5).normal(size=(200_000, 3)) @ a.T
    sim = tr.to_sim(samples)
    assert np.allclose(np.cov(sim.T), tr.covariances_to_sim((a @ a.T)[None])[0], rtol=0.05, atol=0.05)


def test_z_up_scene_stands_up_along_y():
    g = GaussianSet.from_points(torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64), scale=0.05, opacity=0.9)
    g.log_scales[:, 2] = math.log(0.3)                  # a needle along scene +z, centred at z = 1
    solid = gaussians_to_solid(g, SolidifyConfig(spacing=0.05), SceneTransform("z", 1.0))
    extent = solid.points.max(0) - solid.points.min(0)
    assert extent[1] > 3 * max(extent[0], extent[2])    # along sim y
    assert np.allclose(solid.points.mean(0), [0.0, 1.0, 0.0], atol=0.03)


def test_single_gaussian_gives_ball_of_predicted_radius_and_scale_applies():
    o, sigma, tau, sp = 0.9, 0.1, 0.3, 0.02
    g = GaussianSet.from_points(torch.zeros(1, 3, dtype=torch.float64), scale=sigma, opacity=o)
    radius = sigma * math.sqrt(2.0 * math.log(o / tau))   # o exp(-r^2 / 2 sigma^2) = tau
    for scale in (1.0, 2.0):
        solid = gaussians_to_solid(g, SolidifyConfig(spacing=sp, opacity_threshold=tau), SceneTransform("y", scale))
        r = np.linalg.norm(solid.points, axis=1)
        assert r.max() <= scale * radius + 1e-9
        expected = 4.0 / 3.0 * math.pi * (scale * radius) ** 3 / sp ** 3
        assert abs(len(solid.points) / expected - 1.0) < 0.05


def fibonacci_sphere(n: int) -> np.ndarray:
    """[n, 3] nearly uniform unit vectors."""
    k = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * k / n)
    theta = math.pi * (1 + 5 ** 0.5) * k
    return np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], 1)


def shell_gaussians(radius: float, sigma: float, opacity: float) -> GaussianSet:
    n = int(4 * math.pi * radius ** 2 / (0.8 * sigma) ** 2)
    return GaussianSet.from_points(torch.tensor(radius * fibonacci_sphere(n)), scale=sigma, opacity=opacity)


def test_hollow_shell_fills_to_a_ball_only_with_fill_cavities():
    sp, radius = 0.05, 0.4
    g = shell_gaussians(radius, 0.03, 0.9)
    hollow = gaussians_to_solid(g, SolidifyConfig(spacing=sp), SceneTransform())
    filled = gaussians_to_solid(g, SolidifyConfig(spacing=sp, fill_cavities=True), SceneTransform())
    assert np.linalg.norm(hollow.points, axis=1).min() > radius - 0.1   # the interior stays empty
    pts = lattice_points(filled.lattice_min, filled.lattice_shape, sp)
    inner = np.linalg.norm(pts, axis=1) < radius - 0.05
    assert filled.occupancy.reshape(-1)[inner].all()                    # ... and is filled with the option
    assert (filled.occupancy >= hollow.occupancy).all()
    # Volume inside the outer surface (combined opacity = tau), radius found along 50 rays by the twin.
    dirs = fibonacci_sphere(50)
    radii = np.linspace(radius, radius + 0.15, 151)
    means, covs, opac, _ = gaussian_arrays_in_sim(g, SceneTransform())
    opacity = combined_opacity_reference((radii[:, None, None] * dirs[None]).reshape(-1, 3), means, covs, opac)
    solid_along = opacity.reshape(len(radii), -1) >= 0.3
    outer = radii[len(radii) - 1 - np.argmax(solid_along[::-1], axis=0)]   # outermost solid radius per ray
    expected = np.mean(4.0 / 3.0 * math.pi * outer ** 3) / sp ** 3
    assert abs(len(filled.points) / expected - 1.0) < 0.03
    r_in = np.linalg.norm(hollow.points, axis=1).min()
    cavity = (np.linalg.norm(pts, axis=1) < r_in - 1e-9).sum()
    assert len(filled.points) - len(hollow.points) >= cavity > 500


def fill_enclosed_reference(occ: np.ndarray) -> np.ndarray:
    """Breadth-first flood fill of the empty cells from the padded border (6-connectivity)."""
    pad = np.pad(occ, 1)
    outside = np.zeros_like(pad)
    queue = deque([(0, 0, 0)])
    outside[0, 0, 0] = True
    while queue:
        c = queue.popleft()
        for axis in range(3):
            for step in (-1, 1):
                n = list(c)
                n[axis] += step
                n = tuple(n)
                if all(0 <= n[a] < pad.shape[a] for a in range(3)) and not pad[n] and not outside[n]:
                    outside[n] = True
                    queue.append(n)
    return ~outside[1:-1, 1:-1, 1:-1]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fill_enclosed_equals_flood_fill(seed):
    rng = np.random.default_rng(seed)
    occ = rng.random((14, 11, 9)) < 0.45
    occ[3:10, 3:8, 2:7] = True
    occ[4:9, 4:7, 3:6] = False                                 # a box cavity with a winding wall
    occ[5, 5, 4] = True
    got = fill_enclosed(occ)
    assert np.array_equal(got, fill_enclosed_reference(occ))
    assert got.sum() > occ.sum()


def test_empty_solid_suggests_lower_tau():
    g = shell_gaussians(0.3, 0.03, 0.05)
    with pytest.raises(ValueError, match="lower opacity_threshold"):
        gaussians_to_solid(g, SolidifyConfig(spacing=0.05, opacity_threshold=0.99), SceneTransform())


def test_size_guard_raises_before_allocating(monkeypatch):
    g = random_gaussians(10, seed=6)
    cfg = SolidifyConfig(spacing=0.001, max_points=1_000_000)
    assert estimate_lattice_points(g, cfg, SceneTransform()) > 1_000_000

    class NoTaichi:
        def __getattr__(self, name):
            raise AssertionError("allocated before the size guard")

    monkeypatch.setattr(solidify, "ti", NoTaichi())
    with pytest.raises(ValueError, match=r"larger spacing.*MiB|MiB.*larger spacing"):
        gaussians_to_solid(g, cfg, SceneTransform())


def test_bounds_clip_the_lattice():
    g = random_gaussians(30, seed=7)
    full = gaussians_to_solid(g, SolidifyConfig(spacing=0.05), SceneTransform())
    cfg = SolidifyConfig(spacing=0.05, bounds=((-0.1, -0.5, -0.5), (0.5, 0.5, 0.5)))
    clipped = gaussians_to_solid(g, cfg, SceneTransform())
    assert clipped.points[:, 0].min() >= -0.1 - 0.05
    kept = full.points[full.points[:, 0] >= clipped.lattice_min[0] - 1e-9]
    assert len(kept) == len(clipped.points)


@pytest.mark.parametrize("kwargs, field", [
    ({"spacing": 0.0}, "spacing"), ({"spacing": 0.05, "opacity_threshold": 1.0}, "opacity_threshold"),
    ({"spacing": 0.05, "sigma_cutoff": -1.0}, "sigma_cutoff"), ({"spacing": 0.05, "max_points": 0}, "max_points"),
    ({"spacing": 0.05, "bounds": ((0, 0, 0), (1, -1, 1))}, "bounds"),
])
def test_config_validation_names_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        SolidifyConfig(**kwargs)


def test_transform_validation():
    with pytest.raises(ValueError, match="up_axis"):
        SceneTransform("x")
    with pytest.raises(ValueError, match="scale"):
        SceneTransform("y", 0.0)
