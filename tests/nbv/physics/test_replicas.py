"""Replicas of a probe run (nbv.physics.replicas): the shifted lattice and slab, one replica = one run bit for bit, the
combination rule, the agreement figures against a numpy twin, and the memory guard."""

import math
from dataclasses import replace

import h5py
import numpy as np
import pytest
import torch

from fluidsim.scene import lattice_in_box
from nbv import scores
from nbv.coverage import replicas_line
from nbv.physics import PhysicsConfig, estimate_memory, load_result, save_result, simulate_gaussians
from nbv.physics.plan import ProbePlan, RunFrame
from nbv.physics.replicas import (
    ReplicaRuns,
    pairwise_spearman,
    radical_inverse,
    replica_agreement,
    replica_offsets,
)
from nbv.physics.result import combine_replicas
from nbv.physics.scene_frame import SceneTransform
from nbv.physics.solidify import SolidifyConfig, gaussians_to_solid
from recon.gaussians import GaussianSet

COARSE = dict(particle_radius=0.08, steps=40, dt=0.004, empty_reference=False)


def sphere_gaussians(n: int = 300) -> GaussianSet:
    i = np.arange(n) + 0.5
    phi, th = np.arccos(1 - 2 * i / n), math.pi * (1 + 5**0.5) * i
    pts = np.stack([np.cos(th) * np.sin(phi), np.cos(phi), np.sin(th) * np.sin(phi)], 1) * 0.5
    return GaussianSet.from_points(torch.tensor(pts, dtype=torch.float32), scale=0.06, opacity=0.9)


@pytest.fixture(scope="module")
def sphere() -> GaussianSet:
    return sphere_gaussians()


@pytest.fixture(scope="module")
def runs(sphere):
    """One run and a run of two replicas of the same probes (distinct counts tracked)."""
    cfg = PhysicsConfig(**COARSE, directions=("-x", "-y"), track_distinct=True)
    return simulate_gaussians(sphere, cfg, progress=False), simulate_gaussians(
        sphere, replace(cfg, replicas=2), progress=False
    )


def test_offsets_are_the_halton_points():
    assert radical_inverse(6, 2) == 0.375  # 6 = 110 in binary -> 0.011
    assert radical_inverse(5, 3) == pytest.approx(2 / 3 + 1 / 9)  # 5 = 12 in base 3 -> 0.21
    off = replica_offsets(4)
    np.testing.assert_array_equal(off[0], 0.0)  # replica 0 is the unshifted run
    np.testing.assert_allclose(off[1:], [[1 / 2, 1 / 3, 1 / 5], [1 / 4, 2 / 3, 2 / 5], [3 / 4, 1 / 9, 3 / 5]])
    np.testing.assert_array_equal(replica_offsets(2), off[:2])  # N replicas extend N - 1
    with pytest.raises(ValueError, match="replicas"):
        replica_offsets(0)


def test_shifted_lattice_moves_the_solid_by_the_stated_fraction():
    o, sigma, tau, sp = 0.9, 0.1, 0.3, 0.02
    g = GaussianSet.from_points(torch.zeros(1, 3, dtype=torch.float64), scale=sigma, opacity=o)
    radius = sigma * math.sqrt(2.0 * math.log(o / tau))
    t = SceneTransform("y", 1.0)
    plain = gaussians_to_solid(g, SolidifyConfig(spacing=sp, opacity_threshold=tau, thin=False), t)
    zero = gaussians_to_solid(
        g, SolidifyConfig(spacing=sp, opacity_threshold=tau, thin=False, lattice_offset=(0, 0, 0)), t
    )
    np.testing.assert_array_equal(zero.points, plain.points)  # offset 0 is today's lattice, bit for bit
    offset = np.array([0.5, 1 / 3, 0.2])
    cfg = SolidifyConfig(spacing=sp, opacity_threshold=tau, thin=False, lattice_offset=tuple(offset))
    shifted = gaussians_to_solid(g, cfg, t)
    for solid, off in ((plain, np.zeros(3)), (shifted, offset)):
        cells = solid.points / sp - off  # every solid point is (offset + integer) spacings
        np.testing.assert_allclose(cells, np.round(cells), atol=1e-9)
        cells = solid.lattice_min / sp - off
        np.testing.assert_allclose(cells, np.round(cells), atol=1e-9)
        assert np.linalg.norm(solid.points, axis=1).max() <= radius + 1e-9  # still test 1's ball
        assert abs(len(solid.points) / (4.0 / 3.0 * math.pi * radius**3 / sp**3) - 1.0) < 0.05
    assert not ({tuple(p) for p in np.round(plain.points, 9)} & {tuple(p) for p in np.round(shifted.points, 9)})
    with pytest.raises(ValueError, match="lattice_offset"):
        SolidifyConfig(spacing=sp, lattice_offset=(1.0, 0.0, 0.0))


def test_fluid_slab_moves_with_the_lattice(sphere):
    """The slab of a probe starts one gap past the solid's box on the side the flow comes from, so along the flow its
    particles sit on the shifted lattice too."""
    cfg = PhysicsConfig(**COARSE, directions=("-x", "-y"))
    frame = RunFrame.of(sphere, cfg)
    s = 2.0 * cfg.particle_radius
    for offset in replica_offsets(3):
        plan = ProbePlan.of(frame.solidify(tuple(offset)).points, cfg)
        for d, axis in (("-x", 0), ("-y", 1)):
            setup = plan.setups[d]
            fluid = lattice_in_box(setup.fluid_min, setup.fluid_max, s)
            cells = fluid[:, axis] / s - offset[axis]
            np.testing.assert_allclose(cells, np.round(cells), atol=1e-6)


def test_one_replica_is_the_run_bit_for_bit(runs, tmp_path):
    one, two = runs
    assert PhysicsConfig().replicas == 1 and one.replicas is None
    np.testing.assert_array_equal(two.replicas.per_probe[0], one.per_probe)  # replica 0 is the unshifted run
    np.testing.assert_array_equal(two.replicas.per_probe_distinct[0], one.per_probe_distinct)
    np.testing.assert_array_equal(two.solid, one.solid)  # the combined result keeps replica 0's solid
    assert not np.array_equal(two.replicas.per_probe[1], one.per_probe)  # the shifted lattice changes D_g
    with h5py.File(save_result(tmp_path / "one.h5", one), "r") as f:
        assert "replicas" not in f  # the file of one run is today's


def test_replicas_combine_by_the_documented_rule(runs, tmp_path):
    _, two = runs
    r = two.replicas
    np.testing.assert_allclose(two.per_probe, r.per_probe.mean(0), rtol=0, atol=0)  # D_g^(IC): the mean
    np.testing.assert_array_equal(two.divergence, two.per_probe.max(0))  # D_g: max over the probes (Eq. 3)
    np.testing.assert_array_equal(two.divergence_mean, two.per_probe.mean(0))
    np.testing.assert_array_equal(two.per_probe_distinct, r.per_probe_distinct.sum(0))  # |P_g|: the sum
    assert two.dbar == pytest.approx(
        scores.geometry_divergence(torch.from_numpy(two.covariances), torch.from_numpy(two.divergence)), rel=1e-12
    )
    assert r.count == 2 and len(r.solid_points) == 2 and two.config.replicas == 2
    back = load_result(save_result(tmp_path / "two.h5", two))
    np.testing.assert_array_equal(back.replicas.per_probe, r.per_probe)
    np.testing.assert_array_equal(back.replicas.reached, r.reached)
    np.testing.assert_array_equal(back.replicas.offsets, r.offsets)
    assert back.config.replicas == 2


def test_combine_replicas_on_known_values(runs):
    """Two made-up replicas: the means, sums and maxima by hand."""
    one, _ = runs
    a = replace(one, empty_per_probe=np.full_like(one.per_probe, 2.0), warnings={"-x": ["slow"], "-y": []})
    b = replace(
        a,
        per_probe=3.0 * one.per_probe + 1.0,
        per_probe_counts=one.per_probe_counts + 5,
        per_probe_distinct=2 * one.per_probe_distinct,
        empty_per_probe=np.full_like(one.per_probe, 4.0),
        solid=one.solid[:10],
        warnings={"-x": [], "-y": ["leaky"]},
    )
    both = combine_replicas([a, b], replica_offsets(2))
    mean = 0.5 * (one.per_probe + 3.0 * one.per_probe + 1.0)
    np.testing.assert_allclose(both.per_probe, mean)
    np.testing.assert_allclose(both.divergence, mean.max(0))
    np.testing.assert_array_equal(both.per_probe_counts, 2 * one.per_probe_counts + 5)
    np.testing.assert_array_equal(both.per_probe_distinct, 3 * one.per_probe_distinct)
    np.testing.assert_allclose(both.empty_per_probe, 3.0)
    covs = torch.from_numpy(one.covariances)
    assert both.dbar_empty == pytest.approx(scores.geometry_divergence(covs, torch.full((one.num_gaussians,), 3.0)))
    np.testing.assert_array_equal(both.solid, one.solid)  # replica 0's solid
    assert both.warnings == {"-x": ["slow"], "-y": ["replica 1: leaky"]}
    assert combine_replicas([a], replica_offsets(1)) is a


def _average_ranks_twin(x: np.ndarray) -> np.ndarray:
    """1-based ranks, ties sharing their mean rank, by counting (O(n^2))."""
    less = (x[None, :] < x[:, None]).sum(1)
    equal = (x[None, :] == x[:, None]).sum(1)
    return less + 0.5 * (equal + 1)


def _spearman_twin(a, b) -> float:
    return float(np.corrcoef(_average_ranks_twin(np.asarray(a)), _average_ranks_twin(np.asarray(b)))[0, 1])


def test_agreement_figures_match_a_numpy_twin():
    rng = np.random.default_rng(3)
    d = rng.gamma(2.0, size=(3, 400))
    d[1] = 0.7 * d[0] + 0.3 * d[1]
    d[:, :50] = np.round(d[:, :50])  # ties
    reached = rng.random((3, 400)) > 0.2
    pairs = pairwise_spearman(d, reached)
    for i, j, rho in pairs:
        keep = reached[i] & reached[j]
        assert rho == pytest.approx(_spearman_twin(d[i][keep], d[j][keep]), abs=1e-12)
    runs = ReplicaRuns(
        offsets=replica_offsets(3),
        per_probe=d[:, None, :],
        per_probe_distinct=None,
        reached=reached,
        solid_points=np.array([5, 5, 6]),
        seconds=np.ones(3),
    )
    views = rng.random((3, 7))
    views[2] = views[0] + 0.1 * views[2]
    out = replica_agreement(runs, views, candidates=[10, 11, 12, 13, 14, 15, 16])
    rho_views = [_spearman_twin(views[i], views[j]) for i, j in ((0, 1), (0, 2), (1, 2))]
    rho_g = [rho for _, _, rho in pairs]
    assert out["count"] == 3
    assert out["spearman_views_mean"] == pytest.approx(np.mean(rho_views), abs=1e-4)
    assert out["spearman_views_min"] == pytest.approx(min(rho_views), abs=1e-4)
    assert out["spearman_gaussians_mean"] == pytest.approx(np.mean(rho_g), abs=1e-4)
    assert out["spearman_gaussians_min"] == pytest.approx(min(rho_g), abs=1e-4)
    assert out["top_views"] == [10 + int(np.argmax(v)) for v in views]
    with pytest.raises(ValueError, match="one row per replica"):
        replica_agreement(runs, views[:2], candidates=list(range(7)))
    # with the coverage A(T): the physics parts S/A too, over the views with A > 0
    coverage = np.array([1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 0.0])
    scores = coverage * (1.0 + 0.3 * rng.random((3, 7)))
    out = replica_agreement(runs, scores, list(range(7)), coverage=coverage)
    ratios = scores[:, :6] / coverage[:6]
    rho_p = [_spearman_twin(ratios[i], ratios[j]) for i, j in ((0, 1), (0, 2), (1, 2))]
    assert out["spearman_physics_mean"] == pytest.approx(np.mean(rho_p), abs=1e-4)
    assert out["spearman_views_mean"] > 0.9 > out["spearman_physics_mean"]  # coverage carries S(T), not S/A
    line = replicas_line(out)
    assert f"the view ranking S(T) {out['spearman_views_mean']:.2f}" in line
    assert f"its physics part S/A {out['spearman_physics_mean']:.2f}" in line
    assert "S(T) agrees more than S/A because the coverage A(T)" in line
    assert "D_g per Gaussian" in line and "mostly lattice noise" in line  # random D_g: no agreement
    assert "spearman_physics_mean" not in replica_agreement(runs, scores, list(range(7)))


def test_memory_check_counts_the_replicas(sphere):
    one = estimate_memory(RunFrame.of(sphere, PhysicsConfig(**COARSE)))
    three = estimate_memory(RunFrame.of(sphere, PhysicsConfig(**COARSE, replicas=3)))
    assert one["replica_bytes"] == 0
    assert three["replica_bytes"] == 3 * sphere.num * (128 + 48 * 5)
    assert three["bytes"] == one["bytes"] + three["replica_bytes"]
    with pytest.raises(ValueError, match="--replicas 1000000000 is too many.*--replicas [0-9]+ or fewer"):
        simulate_gaussians(sphere, PhysicsConfig(**COARSE, replicas=10**9, max_memory_gb=1.0), progress=False)
    with pytest.raises(ValueError, match="replicas"):
        PhysicsConfig(replicas=0)


def test_config_records_replicas_only_when_more_than_one():
    one, two = PhysicsConfig(), PhysicsConfig(replicas=2)
    assert "replicas" not in one.to_dict()  # the record of one run is the one written before replicas existed
    assert two.to_dict()["replicas"] == 2
    assert PhysicsConfig.from_dict(one.to_dict()) == one and PhysicsConfig.from_dict(two.to_dict()) == two
