"""Gaussians -> solid particles: the Taichi lattice passes (combined opacity, cut edges) against their
brute-force twins, the whole occupancy against a twin built from loops (BFS fill), transforms, filling,
specks, and the errors (empty solid, size guard, bad config)."""

import math
from collections import deque

import numpy as np
import pytest
import torch

from nbv.physics import solidify
from nbv.physics.fill import connected_components, fill_enclosed, outside_region
from nbv.physics.lattice import estimate_lattice_points
from nbv.physics.scene_frame import gaussian_arrays_in_sim, inverse_covariances_in_sim
from nbv.physics.solidify import (
    MAX_ALPHA,
    SceneTransform,
    SolidifyConfig,
    combined_opacity_reference,
    edge_log_transmittance_reference,
    gaussians_to_solid,
    lattice_cut_edges,
    lattice_edge_log_transmittance,
    lattice_log_transmittance,
)
from recon.gaussians import GaussianSet

from helpers.spheres import fibonacci_sphere


def random_gaussians(n: int, seed: int, extent: float = 0.3, scale_range=(0.02, 0.12)) -> GaussianSet:
    rng = np.random.default_rng(seed)
    lo, hi = np.log(scale_range[0]), np.log(scale_range[1])
    return GaussianSet(
        torch.tensor(rng.uniform(-extent, extent, (n, 3))),
        torch.tensor(rng.normal(size=(n, 4))),
        torch.tensor(rng.uniform(lo, hi, (n, 3))),
        torch.tensor(rng.normal(0.5, 1.5, n)),
        torch.zeros(n, 1, 3, dtype=torch.float64),
    )


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
    assert fast.max() > 0.9 and (fast < 1e-3).mean() > 0.05  # the lattice sees solid and empty space
    assert np.abs(fast - cut).max() < 2e-5  # same sum, f32 accumulation
    # The cut drops only points with d_g >= 3: at most -log(1 - o_g e^-4.5) per Gaussian in log T.
    bound = 1.0 - math.exp(np.log1p(-np.minimum(opac * math.exp(-4.5), MAX_ALPHA)).sum())
    assert np.abs(fast - full).max() <= bound + 2e-5
    assert np.abs(fast - full).max() > 1e-6  # the cut does drop something


def test_solid_mask_equals_twin_away_from_tau():
    g = random_gaussians(40, seed=1)
    cfg = SolidifyConfig(spacing=0.05, opacity_threshold=0.3, thin=False, fill_cavities=False)  # test 1 only
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
    assert np.allclose(tr.to_sim([[0.0, 0.0, 1.0]]), [[0.0, 2.0, 0.0]])  # +z -> +y
    assert np.allclose(tr.to_sim([[0.0, 1.0, 0.0]]), [[0.0, 0.0, -2.0]])  # +y -> -z
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
    g.log_scales[:, 2] = math.log(0.3)  # a needle along scene +z, centred at z = 1
    solid = gaussians_to_solid(g, SolidifyConfig(spacing=0.05), SceneTransform("z", 1.0))
    assert solid.counts["opacity"] > 0 and solid.counts["total"] == len(solid.points)
    extent = solid.points.max(0) - solid.points.min(0)
    assert extent[1] > 3 * max(extent[0], extent[2])  # along sim y
    assert np.allclose(solid.points.mean(0), [0.0, 1.0, 0.0], atol=0.03)


def test_single_gaussian_gives_ball_of_predicted_radius_and_scale_applies():
    o, sigma, tau, sp = 0.9, 0.1, 0.3, 0.02
    g = GaussianSet.from_points(torch.zeros(1, 3, dtype=torch.float64), scale=sigma, opacity=o)
    radius = sigma * math.sqrt(2.0 * math.log(o / tau))  # o exp(-r^2 / 2 sigma^2) = tau
    for scale in (1.0, 2.0):
        centre = gaussians_to_solid(
            g, SolidifyConfig(spacing=sp, opacity_threshold=tau, thin=False), SceneTransform("y", scale)
        )
        r = np.linalg.norm(centre.points, axis=1)
        assert r.max() <= scale * radius + 1e-9  # test 1: the points inside the tau-sphere
        expected = 4.0 / 3.0 * math.pi * (scale * radius) ** 3 / sp**3
        assert abs(len(centre.points) / expected - 1.0) < 0.05
        # The edge test adds, where an edge between two outside points grazes the sphere, its end nearer the
        # centre: within the sagitta s^2 / (8 R) of the surface, a handful of points.
        solid = gaussians_to_solid(g, SolidifyConfig(spacing=sp, opacity_threshold=tau), SceneTransform("y", scale))
        r = np.linalg.norm(solid.points, axis=1)
        assert r.max() <= scale * radius + sp**2 / (8 * scale * radius) + 1e-9
        assert 0 <= len(solid.points) - len(centre.points) < 0.01 * expected
        assert solid.counts["thin"] == len(solid.points) - len(centre.points)


def shell_gaussians(radius: float, sigma: float, opacity: float) -> GaussianSet:
    n = int(4 * math.pi * radius**2 / (0.8 * sigma) ** 2)
    return GaussianSet.from_points(torch.tensor(radius * fibonacci_sphere(n)), scale=sigma, opacity=opacity)


def test_hollow_shell_fills_to_a_ball_unless_fill_is_off():
    sp, radius = 0.05, 0.4
    g = shell_gaussians(radius, 0.03, 0.9)
    hollow = gaussians_to_solid(g, SolidifyConfig(spacing=sp, fill_cavities=False), SceneTransform())
    filled = gaussians_to_solid(g, SolidifyConfig(spacing=sp), SceneTransform())  # filling is the default
    assert np.linalg.norm(hollow.points, axis=1).min() > radius - 0.1  # the interior stays empty
    pts = lattice_points(filled.lattice_min, filled.lattice_shape, sp)
    inner = np.linalg.norm(pts, axis=1) < radius - 0.05
    assert filled.occupancy.reshape(-1)[inner].all()  # ... and is filled with the option
    assert (filled.occupancy >= hollow.occupancy).all()
    # Volume inside the outer surface (combined opacity = tau), radius found along 50 rays by the twin.
    dirs = fibonacci_sphere(50)
    radii = np.linspace(radius, radius + 0.15, 151)
    means, covs, opac, _ = gaussian_arrays_in_sim(g, SceneTransform())
    opacity = combined_opacity_reference((radii[:, None, None] * dirs[None]).reshape(-1, 3), means, covs, opac)
    solid_along = opacity.reshape(len(radii), -1) >= 0.3
    outer = radii[len(radii) - 1 - np.argmax(solid_along[::-1], axis=0)]  # outermost solid radius per ray
    expected = np.mean(4.0 / 3.0 * math.pi * outer**3) / sp**3
    assert abs(len(filled.points) / expected - 1.0) < 0.03
    r_in = np.linalg.norm(hollow.points, axis=1).min()
    cavity = (np.linalg.norm(pts, axis=1) < r_in - 1e-9).sum()
    assert len(filled.points) - len(hollow.points) >= cavity > 500


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
    full = gaussians_to_solid(g, SolidifyConfig(spacing=0.05, thin=False, fill_cavities=False), SceneTransform())
    cfg = SolidifyConfig(spacing=0.05, thin=False, fill_cavities=False, bounds=((-0.1, -0.5, -0.5), (0.5, 0.5, 0.5)))
    clipped = gaussians_to_solid(g, cfg, SceneTransform())
    assert clipped.points[:, 0].min() >= -0.1 - 0.05
    kept = full.points[full.points[:, 0] >= clipped.lattice_min[0] - 1e-9]
    assert len(kept) == len(clipped.points)


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"spacing": 0.0}, "spacing"),
        ({"spacing": 0.05, "opacity_threshold": 1.0}, "opacity_threshold"),
        ({"spacing": 0.05, "sigma_cutoff": -1.0}, "sigma_cutoff"),
        ({"spacing": 0.05, "max_points": 0}, "max_points"),
        ({"spacing": 0.05, "bounds": ((0, 0, 0), (1, -1, 1))}, "bounds"),
        ({"spacing": 0.05, "fill_cavities": 1}, "fill_cavities"),
        ({"spacing": 0.05, "thin": "yes"}, "thin"),
        ({"spacing": 0.05, "carve_margin": -1.0}, "carve_margin"),
    ],
)
def test_config_validation_names_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        SolidifyConfig(**kwargs)


def test_transform_validation():
    with pytest.raises(ValueError, match="up"):
        SceneTransform("sideways")
    with pytest.raises(ValueError, match="scale"):
        SceneTransform("y", 0.0)


# ---- test 2: cut edges --------------------------------------------------------------------------------
def thin_random_gaussians(n: int, seed: int) -> GaussianSet:
    """Random Gaussians from flat discs (normal sigma 1 mm) to blobs, random orientations and opacities."""
    rng = np.random.default_rng(seed)
    scales = np.exp(rng.uniform(np.log(0.01), np.log(0.08), (n, 3)))
    flat = rng.random(n) < 0.6
    scales[flat, 2] = rng.uniform(0.001, 0.004, flat.sum())
    return GaussianSet(
        torch.tensor(rng.uniform(-0.25, 0.25, (n, 3))),
        torch.tensor(rng.normal(size=(n, 4))),
        torch.tensor(np.log(scales)),
        torch.tensor(rng.normal(0.5, 1.5, n)),
        torch.zeros(n, 1, 3, dtype=torch.float64),
    )


def edge_twin(g, cfg, tr, lattice_min, shape, sigma_cutoff="config"):
    means, covs, opac, _ = gaussian_arrays_in_sim(g, tr)
    cut = cfg.sigma_cutoff if sigma_cutoff == "config" else sigma_cutoff
    return edge_log_transmittance_reference(
        lattice_min, shape, cfg.spacing, means, covs, inverse_covariances_in_sim(g, tr), opac, sigma_cutoff=cut
    )


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_edge_opacity_matches_brute_force_twin(seed):
    g = thin_random_gaussians(50, seed)
    cfg = SolidifyConfig(spacing=0.04)
    tr = SceneTransform("z", 1.3)
    lattice_min, edge_log_t = lattice_edge_log_transmittance(g, cfg, tr)
    lm2, log_t = lattice_log_transmittance(g, cfg, tr)
    assert np.array_equal(lattice_min, lm2) and edge_log_t.shape == (3, *log_t.shape)
    ref = edge_twin(g, cfg, tr, lattice_min, log_t.shape)
    fast = 1.0 - np.exp(edge_log_t.astype(np.float64))
    cut_ref = 1.0 - np.exp(ref)
    assert np.abs(fast - cut_ref).max() < 2e-5  # the same sum, f32 accumulation
    thr = cfg.opacity_threshold
    cuts = lattice_cut_edges(g, cfg, tr)[1]
    decided = np.abs(cut_ref - thr) > 1e-4
    assert decided.mean() > 0.999
    assert np.array_equal(cuts[decided], (cut_ref >= thr)[decided])  # integer result: exact where f32 cannot flip
    assert 0.001 < cuts.mean() < 0.5
    opaque = log_t.astype(np.float64) <= math.log1p(-thr)
    assert (cuts[0] & ~opaque & ~np.roll(opaque, -1, axis=0)).any()  # edges cut where test 1 sees nothing
    # The sigma-box cut drops Gaussians whose peak on the edge is at most o_g e^-4.5: the bound of test 1.
    full = 1.0 - np.exp(edge_twin(g, cfg, tr, lattice_min, log_t.shape, sigma_cutoff=None))
    _, _, opac, _ = gaussian_arrays_in_sim(g, tr)
    bound = 1.0 - math.exp(np.log1p(-np.minimum(opac * math.exp(-4.5), MAX_ALPHA)).sum())
    assert 1e-6 < np.abs(fast - full).max() <= bound + 2e-5
    # A point solid by test 1 cuts all its edges (each Gaussian peaks on the edge at least at the end point).
    assert cuts[0][:-1][opaque[:-1]].all() and cuts[1][:, :-1][opaque[:, :-1]].all()


def test_edge_peaks_agree_with_dense_sampling_of_each_edge():
    """Each Gaussian's exact peak along an edge against a dense sample of the edge (801 points)."""
    g = thin_random_gaussians(25, seed=5)
    cfg = SolidifyConfig(spacing=0.05)
    tr = SceneTransform()
    lattice_min, log_t = lattice_log_transmittance(g, cfg, tr)
    shape = log_t.shape
    exact = 1.0 - np.exp(edge_twin(g, cfg, tr, lattice_min, shape, sigma_cutoff=None))
    means, _, opac, _ = gaussian_arrays_in_sim(g, tr)
    inv = inverse_covariances_in_sim(g, tr)
    t = np.linspace(0.0, 1.0, 801)
    rng = np.random.default_rng(0)
    for axis in range(3):
        starts = np.argwhere(np.ones(shape, bool))
        starts = starts[starts[:, axis] < shape[axis] - 1]
        high = np.nonzero(exact[(axis, *starts.T)] > 0.3)[0]  # the edges that matter, and random ones
        starts = starts[
            np.concatenate(
                [rng.choice(high, min(150, len(high)), replace=False), rng.choice(len(starts), 150, replace=False)]
            )
        ]
        p = lattice_min + cfg.spacing * starts
        x = p[:, None, :] + cfg.spacing * t[None, :, None] * np.eye(3)[axis]  # [E, T, 3]
        d = x[:, :, None, :] - means[None, None]  # [E, T, G, 3]
        peak = np.minimum((opac * np.exp(-0.5 * np.einsum("etga,gab,etgb->etg", d, inv, d))).max(axis=1), MAX_ALPHA)
        sampled = 1.0 - np.exp(np.log1p(-peak).sum(axis=1))
        want = exact[(axis, *starts.T)]
        assert (sampled <= want + 1e-12).all()  # no sample beats the exact peak
        assert np.abs(sampled - want).max() < 0.01  # and the dense sample comes close to it
        assert (want > 0.3).sum() > 5


# ---- filling with cut edges ----------------------------------------------------------------------------
def outside_reference(occ: np.ndarray, cuts: np.ndarray | None) -> np.ndarray:
    """Breadth-first flood of the free points from the padded border across uncut edges (6-connectivity)."""
    shape = occ.shape
    pad = np.pad(occ, 1)
    seen = np.zeros_like(pad)
    queue = deque([(0, 0, 0)])
    seen[0, 0, 0] = True

    def cut(a, b):  # the edge between padded points a and b (neighbours)
        if cuts is None:
            return False
        lo = tuple(min(u, v) - 1 for u, v in zip(a, b, strict=True))
        axis = [i for i in range(3) if a[i] != b[i]][0]
        if any(c < 0 or c >= shape[i] for i, c in enumerate(lo)):
            return False
        return bool(cuts[(axis, *lo)])

    while queue:
        c = queue.popleft()
        for axis in range(3):
            for step in (-1, 1):
                n = list(c)
                n[axis] += step
                n = tuple(n)
                if all(0 <= n[a] < pad.shape[a] for a in range(3)) and not pad[n] and not seen[n] and not cut(c, n):
                    seen[n] = True
                    queue.append(n)
    return seen[1:-1, 1:-1, 1:-1]


def fill_enclosed_reference(occ: np.ndarray) -> np.ndarray:
    return ~outside_reference(occ, None)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fill_enclosed_equals_flood_fill(seed):
    rng = np.random.default_rng(seed)
    occ = rng.random((14, 11, 9)) < 0.45
    occ[3:10, 3:8, 2:7] = True
    occ[4:9, 4:7, 3:6] = False  # a box cavity with a winding wall
    occ[5, 5, 4] = True
    got = fill_enclosed(occ)
    assert np.array_equal(got, fill_enclosed_reference(occ))
    assert got.sum() > occ.sum()


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_outside_region_with_cut_edges_equals_flood_fill(seed):
    rng = np.random.default_rng(seed)
    shape = (13, 10, 11)
    occ = rng.random(shape) < 0.15
    cuts = rng.random((3, *shape)) < 0.35
    # a closed box of cut edges with nothing solid on it: its inside is not outside
    cuts[:, 3:9, 3:8, 3:9] = False
    cuts[0, 2, 3:8, 3:9] = cuts[0, 8, 3:8, 3:9] = True
    cuts[1, 3:9, 2, 3:9] = cuts[1, 3:9, 7, 3:9] = True
    cuts[2, 3:9, 3:8, 2] = cuts[2, 3:9, 3:8, 8] = True
    occ[3:9, 3:8, 3:9] = False
    for axis in range(3):  # the last layer starts no edge
        last = [slice(None)] * 3
        last[axis] = -1
        cuts[(axis, *last)] = False
    got = outside_region(occ, cuts)
    ref = outside_reference(occ, cuts)
    assert np.array_equal(got, ref)
    assert not got[3:9, 3:8, 3:9].any() and got.sum() > 100
    assert np.array_equal(fill_enclosed(occ, cuts), ~ref)


def test_connected_components_equal_bfs_on_random_graphs():
    rng = np.random.default_rng(3)
    for n, e in ((1, 0), (50, 30), (400, 380), (1000, 3000)):
        u, v = rng.integers(0, n, e), rng.integers(0, n, e)
        roots = connected_components(n, u, v)
        adj = [[] for _ in range(n)]
        for a, b in zip(u, v, strict=True):
            adj[a].append(b)
            adj[b].append(a)
        comp = -np.ones(n, int)
        for s0 in range(n):
            if comp[s0] >= 0:
                continue
            comp[s0] = s0
            queue = deque([s0])
            while queue:
                c = queue.popleft()
                for m in adj[c]:
                    if comp[m] < 0:
                        comp[m] = s0
                        queue.append(m)
        # same partition: equal roots exactly where equal BFS components
        assert np.array_equal(roots[:, None] == roots[None], comp[:, None] == comp[None])
        assert (roots[roots] == roots).all()


def test_fill_of_a_long_winding_passage_is_fast_and_exact():
    """Nested shells with alternating holes: the outside winds through every one (the old line sweeps took a
    minute on such a lattice at 10^7 points)."""
    n = 40
    idx = np.indices((n, n, n)).astype(np.float64) - n / 2 + 0.5
    r = np.sqrt((idx**2).sum(0))
    occ = np.zeros((n, n, n), bool)
    for k, radius in enumerate(range(4, 19, 3)):
        shell = np.abs(r - radius) < 0.8
        hole = (idx[0] ** 2 + idx[1] ** 2 < 4) & ((idx[2] > 0) if k % 2 else (idx[2] < 0))
        occ |= shell & ~hole
    got = fill_enclosed(occ)
    assert np.array_equal(got, fill_enclosed_reference(occ))
    assert (got & ~occ).sum() == 0  # every shell has a hole: nothing is enclosed


# ---- the whole occupancy against a twin made of loops -----------------------------------------------
def solid_reference(g: GaussianSet, cfg: SolidifyConfig, tr: SceneTransform, lattice_min, shape) -> np.ndarray:
    """Tests 1-3 and the specks from the twins: f64 combined opacity, brute-force edges, BFS fill, loops."""
    means, covs, opac, _ = gaussian_arrays_in_sim(g, tr)
    pts = lattice_points(lattice_min, shape, cfg.spacing)
    opacity = combined_opacity_reference(pts, means, covs, opac, sigma_cutoff=cfg.sigma_cutoff).reshape(shape)
    log_t = np.log1p(-opacity)
    opaque = opacity >= cfg.opacity_threshold
    edge_opacity = 1.0 - np.exp(edge_twin(g, cfg, tr, lattice_min, shape))
    cuts = edge_opacity >= cfg.opacity_threshold
    outside = outside_reference(opaque, cuts)
    solid = ~outside if cfg.fill_cavities else opaque.copy()
    eligible = outside if cfg.fill_cavities else ~opaque
    for a, i, j, k in np.argwhere(cuts):
        p, q = (i, j, k), tuple(c + (1 if b == a else 0) for b, c in enumerate((i, j, k)))
        if eligible[p] and eligible[q]:
            solid[p if log_t[p] <= log_t[q] else q] = True
    before = solid.copy()
    for mu, o in zip(means, opac, strict=True):
        rel = (mu - lattice_min) / cfg.spacing
        if o < cfg.opacity_threshold or (rel <= -0.5).any() or (rel >= np.array(shape) + 0.5).any():
            continue
        c = np.minimum(np.floor(rel + 0.5).astype(int), np.array(shape) - 1)
        lo, hi = np.maximum(c - 1, 0), c + 2
        if not before[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]].any():
            solid[tuple(c)] = True
    return solid, np.concatenate([opacity.reshape(-1), edge_opacity.reshape(-1)])


@pytest.mark.parametrize("seed, fill", [(2, True), (3, True), (7, False), (9, True)])
def test_occupancy_equals_loop_twin_exactly(seed, fill):
    g = thin_random_gaussians(40, seed)
    cfg = SolidifyConfig(spacing=0.04, fill_cavities=fill, min_points=1)
    tr = SceneTransform()
    solid = gaussians_to_solid(g, cfg, tr)
    ref, opacity = solid_reference(g, cfg, tr, solid.lattice_min, solid.lattice_shape)
    assert np.abs(opacity - cfg.opacity_threshold).min() > 1e-4  # nothing decided by f32 rounding (seed choice)
    assert np.array_equal(solid.occupancy, ref)
    assert solid.counts["thin"] > 0 and solid.counts["total"] == ref.sum()
    assert solid.counts["total"] > solid.counts["opacity"]


def test_lone_thin_gaussian_between_lattice_points_is_a_speck():
    sp = 0.05
    # a tiny flat disc in the middle of a lattice cell: no lattice point, no edge reaches it
    g = GaussianSet(
        torch.tensor([[0.03, 0.03, 0.03], [0.525, 0.525, 0.525]], dtype=torch.float64),
        torch.tensor([[1.0, 0, 0, 0]] * 2, dtype=torch.float64),
        torch.log(torch.tensor([[0.005, 0.005, 0.0005]] * 2, dtype=torch.float64)),
        torch.tensor([2.0, -2.0], dtype=torch.float64),
        torch.zeros(2, 1, 3, dtype=torch.float64),
    )
    solid = gaussians_to_solid(g, SolidifyConfig(spacing=sp, min_points=1), SceneTransform())
    assert solid.counts["opacity"] == solid.counts["thin"] == 0
    assert solid.counts["specks"] == 1  # the opaque one only (the other has o = 0.12)
    # the faint one cannot make solid alone, so it does not size the lattice (nbv.physics.floaters): the lattice is
    # the opaque one's box, whose only point takes the speck (within one spacing of the centre)
    assert solid.lattice_shape == (1, 1, 1) and np.allclose(solid.points, [[0.0, 0.0, 0.0]])
    off = gaussians_to_solid(
        g, SolidifyConfig(spacing=sp, min_points=1, thin=True, fill_cavities=False), SceneTransform()
    )
    assert len(off.points) == 1
    with pytest.raises(ValueError, match="empty"):
        gaussians_to_solid(g, SolidifyConfig(spacing=sp, min_points=1, thin=False), SceneTransform())
