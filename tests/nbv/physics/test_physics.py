"""Probe runs on Gaussians (paper Eq. 2-3): orchestration vs a brute-force twin, D-bar, HDF5, guards, sweep."""

import csv
import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
import torch

import nbv.physics.empty_scene as empty_scene
from fluidsim.probes import build_probe_solver, probe_setup
from nbv import physics, scores
from nbv.physics import PhysicsConfig, load_result, save_result, simulate_gaussians
from nbv.physics.aggregate_reference import accumulate_reference
from nbv.study import sweep
from recon.gaussians import GaussianSet

from helpers.spheres import sphere_gaussians

# coarse settings: a unit sphere (after auto scaling) probed with 0.16 m particle spacing
COARSE = dict(particle_radius=0.08, steps=40, dt=0.004, empty_reference=False)


@pytest.fixture(scope="module")
def sphere() -> GaussianSet:
    return sphere_gaussians()


def test_config_validation_names_the_field():
    with pytest.raises(ValueError, match="particle_radius"):
        PhysicsConfig(particle_radius=-1)
    with pytest.raises(ValueError, match="steps"):
        PhysicsConfig(steps=0)
    with pytest.raises(ValueError, match="directions"):
        PhysicsConfig(directions=("-x", "up"))
    with pytest.raises(ValueError, match="scale"):
        PhysicsConfig(scale="big")
    with pytest.raises(ValueError, match="unknown SolverConfig keys"):
        PhysicsConfig(solver={"tolerance": 1})
    cfg = PhysicsConfig.quick(solver={"max_density_error": 0.05})
    assert (cfg.particle_radius, cfg.steps) == (0.035, 750)
    assert cfg.solver_config().max_density_error == 0.05
    assert PhysicsConfig.from_dict(cfg.to_dict()) == cfg
    with pytest.raises(ValueError, match="unknown PhysicsConfig keys"):
        PhysicsConfig.from_dict({"radius": 1})


def test_auto_scale_puts_largest_extent_at_two_metres(sphere):
    from nbv.physics.scene_frame import robust_box

    t = physics.scene_transform(sphere, PhysicsConfig())
    sim = t.to_sim(sphere.means.double().numpy())
    lo, hi = robust_box(sim, sphere.opacities.double().numpy(), 0.3)
    assert (hi - lo).max() == pytest.approx(2.0, rel=1e-6)  # the robust box's largest extent is 2 m
    assert 2.0 <= np.ptp(sim, axis=0).max() < 2.06  # the 0.5-99.5 % box is a little inside the raw one
    assert physics.scene_transform(sphere, PhysicsConfig(scale=3.0)).scale == 3.0


def test_simulation_matches_brute_force_twin(sphere):
    """The orchestrated run (grid accumulator, every 2nd step) equals stepping the same probe by hand and
    accumulating every particle against every Gaussian."""
    cfg = PhysicsConfig(**COARSE, directions=("-x", "+z"), accumulate_every=2, track_distinct=True)
    res = simulate_gaussians(sphere, cfg, progress=False)
    assert res.per_probe.shape == (2, sphere.num)
    np.testing.assert_array_equal(res.divergence, res.per_probe.max(0))
    np.testing.assert_allclose(res.divergence_mean, res.per_probe.mean(0))
    assert res.dbar == pytest.approx(
        scores.geometry_divergence(torch.from_numpy(res.covariances), torch.from_numpy(res.divergence))
    )
    assert res.dbar >= res.dbar_mean > 0
    # the flow reaches the upstream side of the sphere: many Gaussians get samples, not all
    touched = (res.per_probe_counts[0] > 0).mean()
    assert 0.1 < touched < 0.95

    scfg = cfg.solver_config()
    setup = probe_setup(res.solid, "+z", cfg.probe_config(), scfg.spacing)
    solver = build_probe_solver(res.solid, setup, scfg, cfg.probe_config())
    sums = np.zeros(sphere.num)
    counts = np.zeros(sphere.num, np.int64)
    seen = [set() for _ in range(sphere.num)]
    for step in range(cfg.steps):
        solver.step()
        if (step + 1) % 2:
            continue
        st = solver.fluid_state()
        s, c = accumulate_reference(
            res.means, res.reach, st["x"], st["divergence"], solver.domain_min, solver.domain_max
        )
        sums += s
        counts += c
        d = np.linalg.norm(st["x"][:, None] - res.means[None], axis=-1)
        for i, g in zip(*np.nonzero(d < res.reach[None]), strict=True):
            seen[g].add(int(st["ids"][i]))
    np.testing.assert_array_equal(res.per_probe_counts[1], counts)
    np.testing.assert_allclose(
        res.per_probe[1], np.where(counts > 0, sums / np.maximum(counts, 1), 0), rtol=1e-5, atol=1e-6
    )
    np.testing.assert_array_equal(res.per_probe_distinct[1], [len(s) for s in seen])


def test_result_roundtrip_and_empty_reference(sphere, tmp_path, tmp_path_factory, monkeypatch):
    # a fresh cache on disk and in the process, and a count of the solver runs (not a timing: other tests may
    # have filled the caches, and a cache hit is a question of which runs happen, not of how long they take)
    monkeypatch.setenv("FLUIDGS_CACHE_DIR", str(tmp_path_factory.mktemp("cache")))
    runs = []
    real = empty_scene.run_solver
    monkeypatch.setattr(empty_scene, "run_solver", lambda *a, **k: runs.append(1) or real(*a, **k))
    cfg = PhysicsConfig(**{**COARSE, "empty_reference": True}, directions=("-x",))
    res = simulate_gaussians(sphere, cfg, progress=False, source="sphere")
    assert len(runs) == 1  # the empty scene ran (the probe with the solid runs in fluidsim.probes)
    assert res.dbar_empty is not None and math.isfinite(res.dbar_empty)
    # the solid disturbs the flow: D-bar with the sphere is far above the walls-only reference
    assert res.dbar > 10 * res.dbar_empty
    again = simulate_gaussians(sphere, cfg, progress=False)  # the empty-scene runs are cached on disk
    assert again.dbar_empty == res.dbar_empty
    assert len(runs) == 1  # ... so the empty scene did not run again
    path = save_result(tmp_path / "r.h5", res)
    back = load_result(path)
    for key in (
        "per_probe",
        "per_probe_counts",
        "divergence",
        "divergence_mean",
        "solid",
        "means",
        "covariances",
        "reach",
        "empty_per_probe",
    ):
        np.testing.assert_array_equal(getattr(back, key), getattr(res, key))
    assert (back.dbar, back.dbar_empty, back.config, back.source) == (res.dbar, res.dbar_empty, res.config, "sphere")
    assert back.transform.scale == res.transform.scale
    np.testing.assert_array_equal(back.stats["-x"]["density_iterations"], res.stats["-x"]["density_iterations"])
    assert list(tmp_path.iterdir()) == [path]  # no temporary file left


def test_bad_inputs_fail_before_simulating(sphere, tmp_path):
    with pytest.raises(ValueError, match="GiB"):
        simulate_gaussians(sphere, PhysicsConfig(**COARSE, max_memory_gb=1e-6), progress=False)
    faint = GaussianSet.from_points(sphere.means, scale=0.06, opacity=0.01)
    with pytest.raises(ValueError):
        simulate_gaussians(faint, PhysicsConfig(**COARSE), progress=False)
    bad = tmp_path / "x.h5"
    bad.write_bytes(b"not hdf5")
    with pytest.raises(ValueError, match="x.h5"):
        load_result(bad)
    with pytest.raises(ValueError, match="does not exist"):
        load_result(tmp_path / "missing.h5")


def test_memory_estimate_grows_with_resolution(sphere):
    coarse = physics.estimate_memory(physics.RunFrame.of(sphere, PhysicsConfig(particle_radius=0.05)))
    fine = physics.estimate_memory(physics.RunFrame.of(sphere, PhysicsConfig(particle_radius=0.025)))
    assert 6 < fine["fluid_particles"] / coarse["fluid_particles"] < 10  # ~ 2^3
    assert fine["probe_bytes"] > 6 * coarse["probe_bytes"]  # the solver's part; the Gaussians' parts stay
    assert fine["bytes"] > 4 * coarse["bytes"]


def test_sweep_counts_probe_steps_and_parses_the_re_length():
    plan = sweep.schedule([3, 6, 50], dt_base=0.002, steps_base=750)
    cfg = PhysicsConfig()  # five probes and the empty scene
    assert sweep.probe_steps(plan, cfg) == [750 * 10, 1500 * 10, 12500 * 10]
    assert sweep.probe_steps(plan, replace(cfg, empty_reference=False), other=True) == [750 * 10, 1500 * 10, 12500 * 10]
    cal = sweep.Calibration(step_s=0.1, run_s=5.0, steps=40)
    assert sweep.estimate(plan, cfg, cal) == pytest.approx([755.0, 1505.0, 12505.0])
    # the empty scene at its own rate: 5 probes x steps x (0.1 + 0.02) s
    cal = sweep.Calibration(step_s=0.1, run_s=5.0, steps=40, empty_step_s=0.02)
    assert sweep.estimate(plan, cfg, cal) == pytest.approx([455.0, 905.0, 7505.0])
    assert sweep.estimate(plan, replace(cfg, empty_reference=False), cal, other=True) == pytest.approx(
        [760.0, 1510.0, 12510.0]
    )
    # probes weighted by their fluid particles against the timed one: 5 probes of weight 0.5 cost 2.5 timed ones
    cal = sweep.Calibration(step_s=0.1, run_s=5.0, steps=40, weights=dict.fromkeys(cfg.directions, 0.5))
    assert sweep.estimate(plan, cfg, cal) == pytest.approx([380.0, 755.0, 6255.0])
    assert sweep.parse_re_length("Object") == "object" and sweep.parse_re_length("0.8") == 0.8
    for bad in ("0", "-1", "nan", "inf", "car"):
        with pytest.raises(ValueError, match="--re-length"):
            sweep.parse_re_length(bad)


def test_sweep_schedule_is_cfl_constant():
    plan = sweep.schedule([3, 6, 50], dt_base=0.002, steps_base=750)
    assert [p.steps for p in plan] == [750, 1500, 12500]
    for p in plan:
        assert p.speed * p.dt == pytest.approx(3 * 0.002)  # U dt constant (Courant number)
        assert p.duration == pytest.approx(1.5)
    assert sweep.reynolds(3.0, 3.0, 1000.0, 10.0) == pytest.approx(900.0)
    assert sweep.parse_velocities("3, 4,50") == (3.0, 4.0, 50.0)
    with pytest.raises(ValueError, match="velocities"):
        sweep.parse_velocities("3,-1")


def test_sweep_schedule_bounds_the_steps_a_speed_makes():
    """`sweep --velocities 1e308` ended in a ZeroDivisionError traceback (dt underflowed to 0), `--dt 1e308` in
    "cannot convert float NaN to integer", and --velocities 1e6 planned 250,000,000 steps a probe; `3,3` ran twice."""
    assert sweep.schedule([4000.0], dt_base=0.002, steps_base=750)[0].steps == 1_000_000  # the largest allowed
    for speeds in ([1e308], [4001.0]):
        with pytest.raises(ValueError, match=r"^--velocities: U = .* more than the 1,000,000 a probe may run"):
            sweep.schedule(speeds, dt_base=0.002, steps_base=750)
    with pytest.raises(ValueError, match=r"^--dt 1e\+308 s x 750 steps is not a finite duration"):
        sweep.schedule([3.0], dt_base=1e308, steps_base=750)
    with pytest.raises(ValueError, match=r"^--velocities: U = 1e-300 m/s makes the time step inf s"):
        sweep.schedule([1e-300], dt_base=1e300, steps_base=1)
    with pytest.raises(ValueError, match="more than once"):
        sweep.parse_velocities("3,3")


def test_sweep_runs_and_writes_csv(sphere, tmp_path):
    cfg = PhysicsConfig(**COARSE, directions=("-x",))
    pts = sweep.run_sweep(sphere, cfg, [3.0, 6.0], other=sphere_gaussians(200), progress=False)
    assert [p.steps for p in pts] == [40, 80]
    assert all(p.dbar > 0 and p.gap is not None for p in pts)
    assert pts[1].reynolds == pytest.approx(2 * pts[0].reynolds)
    # L is the object's extent along the flow (-x: along x): the sphere's solid is about 2 m across at "auto"
    assert pts[0].re_length_from == "object" and 1.5 < pts[0].re_length < 2.6
    assert pts[0].reynolds == pytest.approx(cfg.rest_density * 3.0 * pts[0].re_length / cfg.viscosity)
    # C_d of the flow probe (-x, the probe L is measured along), from its time-mean drag: finite and positive
    assert all(p.drag_probe == "-x" and p.drag > 0 and p.area > 0 for p in pts)
    assert all(math.isfinite(p.drag_coefficient) and p.drag_coefficient > 0 for p in pts)
    assert pts[0].drag_coefficient == pytest.approx(2 * pts[0].drag / (cfg.rest_density * 3.0**2 * pts[0].area))
    text = (sweep.write_csv(tmp_path / "s.csv", pts)).read_text().splitlines()
    assert text[0].split(",") == list(sweep.CSV_FIELDS) and len(text) == 3
    assert list(sweep.CSV_FIELDS[-3:]) == ["C_d", "drag_N", "drag_probe"]  # appended: old readers keep working
    rows = list(csv.DictReader(text))
    assert float(rows[1]["C_d"]) == pytest.approx(pts[1].drag_coefficient, rel=5e-3) and rows[1]["drag_probe"] == "-x"


def test_sweep_pins_one_scale_and_uses_the_config_speed_as_base(sphere, monkeypatch):
    """--compare OTHER runs at the scale resolved on the first set (D-bar ~ scale^4), and U_base = config.speed."""
    seen = []

    def fake(gaussians, config, progress=True):
        seen.append((len(gaussians.means), config.scale, config.speed, config.dt, config.steps))
        return SimpleNamespace(dbar=1.0, dbar_empty=None, directions=("-x",), domains={}, forces={})

    monkeypatch.setattr(sweep, "simulate_gaussians", fake)
    monkeypatch.setattr(sweep, "reynolds_length", lambda res, spec: (3.0, "given"))
    shrunk = sphere_gaussians(200, radius=0.25)  # a smaller OTHER would get a 2x larger "auto" scale
    cfg = PhysicsConfig(**COARSE, directions=("-x",), speed=6.0)
    sweep.run_sweep(sphere, cfg, [6.0, 12.0], other=shrunk, progress=False)
    expected = physics.scene_transform(sphere, cfg).scale
    assert expected != pytest.approx(physics.scene_transform(shrunk, cfg).scale)
    assert [s[1] for s in seen] == [expected] * 4
    assert [s[2] for s in seen] == [6.0, 6.0, 12.0, 12.0]
    assert seen[0][3] == cfg.dt and seen[2][3] == pytest.approx(cfg.dt / 2) and seen[2][4] == 2 * cfg.steps


def test_memory_check_uses_the_real_solid_when_faint_gaussians_widen_the_box(sphere):
    # faint Gaussians (opacity 0.05 < tau = 0.3, yet above tau / 10) far from the sphere make no solid but
    # widen the cheap estimate's box; the run must go on when the solid itself fits, and refuse when not.
    # They come in overlapping pairs (combined opacity 0.0975 < tau): a lone faint one is clipped out of the box
    # (nbv.physics.floaters), a pair cannot be without computing the solid
    far = torch.tensor([[-4.0, -4.0, -4.0], [4.0, 4.0, 4.0], [4.0, -4.0, 4.0]]).repeat_interleave(2, 0)
    faint = GaussianSet.from_points(far, scale=0.05, opacity=0.05)
    from recon.gaussians import concat

    scene = concat([sphere, faint])
    cfg = PhysicsConfig(**{**COARSE, "steps": 5}, directions=("-x",), scale=1.0)
    cheap = physics.estimate_memory(physics.RunFrame.of(scene, cfg))
    only_sphere = physics.estimate_memory(physics.RunFrame.of(sphere, cfg))
    assert cheap["fluid_particles"] > 20 * only_sphere["fluid_particles"]
    limit_gb = (cheap["bytes"] + only_sphere["bytes"]) / 2 / 2**30  # between the real need and the cheap bound
    result = simulate_gaussians(
        scene,
        PhysicsConfig(**{**COARSE, "steps": 5}, directions=("-x",), scale=1.0, max_memory_gb=limit_gb),
        progress=False,
    )
    assert np.ptp(result.solid, axis=0).max() < 1.5  # the faint Gaussians made no solid
    with pytest.raises(ValueError, match="would need about"):
        simulate_gaussians(
            scene,
            PhysicsConfig(
                **{**COARSE, "steps": 5}, directions=("-x",), scale=1.0, max_memory_gb=only_sphere["bytes"] / 4 / 2**30
            ),
            progress=False,
        )


def test_reach_floor_widens_only_the_thin_gaussians_reach(sphere):
    # thin Gaussians (scale 0.02 -> n r_g well below h = 4 r after auto scaling) get reach max(n r_g, h): the same
    # fluid then counts for a superset of the particles, so no count falls and the thin ones gain samples
    thin = sphere_gaussians(scale=0.02)
    base = PhysicsConfig(**COARSE, directions=("-x",))
    floored = replace(base, reach_floor=1.0)
    h = base.solver_config().support_radius
    radii = np.array([0.01, 0.1, 1.0])
    np.testing.assert_array_equal(floored.reach(radii), np.maximum(3.0 * radii, h))
    np.testing.assert_array_equal(base.reach(radii), 3.0 * radii)
    assert "reach_floor" not in base.to_dict() and PhysicsConfig.from_dict(floored.to_dict()) == floored
    with pytest.raises(ValueError, match="reach_floor"):
        PhysicsConfig(reach_floor=-1.0)
    a = simulate_gaussians(thin, base, progress=False)
    b = simulate_gaussians(thin, floored, progress=False)
    assert (a.reach < h).all() and (b.reach == h).all()
    assert (b.per_probe_counts >= a.per_probe_counts).all()
    assert (b.per_probe_counts > 0).sum() > (a.per_probe_counts > 0).sum()
