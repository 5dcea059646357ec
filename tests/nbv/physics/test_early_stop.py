"""The early stop of a probe (nbv.physics.early_stop): the rule, the relative change and the check's steps."""

import math

import numpy as np
import pytest

from nbv.physics.early_stop import ConvergenceCheck, StopRule, relative_change


def test_relative_change_is_the_l1_move_over_the_sum_and_inf_before_any_sample():
    assert relative_change([1.0, 2.0, 0.0], [1.0, 2.5, 0.5]) == pytest.approx(1.0 / 4.0)
    assert relative_change([1.0, -1.0], [0.0, 0.0]) == math.inf  # nothing reached yet
    assert relative_change([0.0, 0.0], [1.0, 1.0]) == math.inf  # the first samples arrived in this window


def test_the_check_reads_the_means_once_per_window_and_stops_when_the_change_is_small():
    rule = StopRule(tolerance=0.02, window=10, min_steps=30)
    values = iter([np.array([1.0, 1.0]), np.array([1.1, 1.0]), np.array([1.11, 1.0])])
    reads = []

    def means():
        reads.append(1)
        return next(values)

    check = ConvergenceCheck(rule, means)
    stop = next(n for n in range(1, 61) if check(n))
    # read at 20 (the baseline), 30 (change 0.1 / 2.1 > 0.02) and 40 (0.01 / 2.11 < 0.02): stops at 40
    assert stop == 40 and check.stopped_at == 40 and len(reads) == 3
    assert [n for n, _ in check.changes] == [30, 40]


def test_a_zero_tolerance_never_stops_and_bad_rules_are_refused():
    check = ConvergenceCheck(StopRule(), lambda: np.ones(3))
    assert not any(check(n) for n in range(1, 1000))
    with pytest.raises(ValueError, match="tolerance"):
        StopRule(tolerance=-0.1)
    with pytest.raises(ValueError, match="window"):
        StopRule(tolerance=0.1, window=0)


def test_a_stopped_probe_equals_a_run_of_its_steps_and_its_empty_scene_stops_with_it(tmp_path, monkeypatch):
    import h5py
    import torch

    import nbv.physics.empty_scene as empty_scene
    from nbv.physics import PhysicsConfig, save_result, simulate_gaussians
    from recon.gaussians import GaussianSet

    monkeypatch.setenv("FLUIDGS_CACHE_DIR", str(tmp_path / "cache"))
    empty_steps = []
    real = empty_scene.run_solver
    monkeypatch.setattr(empty_scene, "run_solver", lambda s, n, **k: empty_steps.append(n) or real(s, n, **k))
    golden = np.pi * (3.0 - np.sqrt(5.0))
    k = np.arange(200) + 0.5
    y = 1 - 2 * k / 200
    pts = np.stack([np.cos(golden * k) * np.sqrt(1 - y * y), y, np.sin(golden * k) * np.sqrt(1 - y * y)], 1) * 0.5
    sphere = GaussianSet.from_points(torch.tensor(pts, dtype=torch.float32), scale=0.06, opacity=0.9)
    base = dict(particle_radius=0.08, dt=0.004, directions=("-x", "-y"), empty_cache=False)
    cfg = PhysicsConfig(**base, steps=400, stop_tolerance=0.2)
    res = simulate_gaussians(sphere, cfg, progress=False)
    ran = {d: len(res.stats[d]) for d in cfg.directions}
    assert all(150 <= n <= 400 and n % 50 == 0 for n in ran.values()) and min(ran.values()) < 400
    assert empty_steps == [ran["-x"], ran["-y"]]  # each empty-scene probe ran as long as its probe with the solid
    for i, d in enumerate(cfg.directions):  # stopped at n: the same bits as a run of n steps
        alone = simulate_gaussians(sphere, PhysicsConfig(**{**base, "directions": (d,)}, steps=ran[d]), progress=False)
        np.testing.assert_array_equal(res.per_probe[i], alone.per_probe[0])
        np.testing.assert_array_equal(res.empty_per_probe[i], alone.empty_per_probe[0])
        assert len(res.forces[d].series) == ran[d]
    path = save_result(tmp_path / "r.h5", res)
    with h5py.File(path) as f:
        for d in cfg.directions:
            assert f[f"probes/{d}"].attrs["steps_run"] == ran[d]
            assert bool(f[f"probes/{d}"].attrs["stopped_early"]) == (ran[d] < 400)
