"""The probes' forces on the solid (nbv.physics.forces): area, parts, coefficients, the result file and the lines."""

import h5py
import numpy as np
import pytest
import torch

from fluidsim.output import stats_table
from fluidsim.scene import lattice_in_box
from fluidsim.solver import StepStats
from nbv.physics import PhysicsConfig, load_result, save_result, simulate_gaussians
from nbv.physics.forces import force_lines, probe_forces, projected_area, second_half_mean
from recon.gaussians import GaussianSet

COARSE = dict(particle_radius=0.08, steps=40, dt=0.004, empty_reference=False)  # a 2 m sphere at 0.16 m spacing


def sphere_gaussians(n: int = 300, radius: float = 0.5) -> GaussianSet:
    """Gaussians on a Fibonacci sphere (as tests/nbv/physics/test_physics.py makes them)."""
    i = np.arange(n) + 0.5
    phi, th = np.arccos(1 - 2 * i / n), np.pi * (1 + 5**0.5) * i
    pts = np.stack([np.cos(th) * np.sin(phi), np.cos(phi), np.sin(th) * np.sin(phi)], 1) * radius
    return GaussianSet.from_points(torch.tensor(pts, dtype=torch.float32), scale=0.06, opacity=0.9)


def _stats(forces, dt=0.002):
    return stats_table(
        [
            StepStats(k, dt * (k + 1), dt, 2, 0.0, 1, 0.0, 3.0, 0, 0, 10, 20, 5, *map(float, f))
            for k, f in enumerate(forces)
        ]
    )


def test_projected_area_is_the_silhouette_in_spacing_cells():
    box = lattice_in_box([0, 0, 0], [0.4, 0.2, 0.6], 0.05)  # 8 x 4 x 12 particles
    assert projected_area(box, np.array([-1.0, 0, 0]), 0.05) == pytest.approx(0.2 * 0.6)
    assert projected_area(box, np.array([0, 0, 1.0]), 0.05) == pytest.approx(0.4 * 0.2)
    assert projected_area(box, np.array([0, -1.0, 0]), 0.05) == pytest.approx(0.4 * 0.6)
    assert projected_area(np.zeros((0, 3)), np.array([1.0, 0, 0]), 0.05) == 0.0


def test_time_mean_is_over_the_second_half_weighted_by_dt():
    series = np.array([[100.0, 0, 0]] * 5 + [[2.0, 0, 0], [4.0, 0, 0], [4.0, 0, 0], [4.0, 0, 0], [4.0, 0, 0]])
    dt = np.array([1.0] * 5 + [3.0, 1.0, 1.0, 1.0, 1.0])
    assert second_half_mean(series, dt)[0] == pytest.approx((2 * 3 + 4 * 4) / 7)


def test_parts_and_coefficients_of_a_horizontal_and_the_falling_probe():
    solid = lattice_in_box([0, 0, 0], [0.2, 0.2, 0.2], 0.05)
    f = [(-30.0, 6.0, 1.5)] * 10  # pushed along -x, up and along +z
    pf = probe_forces("-x", _stats(f), solid, 0.05, 3.0, 1000.0)
    parts = pf.parts()
    assert parts["drag"] == pytest.approx(30.0) and parts["lift"] == pytest.approx(6.0)
    # side axis = up x flow = (0,1,0) x (-1,0,0) = (0,0,1)
    assert parts["side"] == pytest.approx(1.5)
    c = pf.coefficients()
    q = 0.5 * 1000.0 * 9.0 * 0.04
    assert c["drag"] == pytest.approx(30.0 / q) and c["lift"] == pytest.approx(6.0 / q)
    np.testing.assert_allclose(pf.impulse, np.array(f).sum(0) * 0.002)
    down = probe_forces("-y", _stats([(3.0, -40.0, 4.0)] * 4), solid, 0.05, 3.0, 1000.0)
    assert down.parts() == {"drag": pytest.approx(40.0), "lift": None, "side": pytest.approx(5.0)}
    assert down.coefficients() is None  # it falls from rest: no inflow speed
    lines = force_lines({"-x": pf, "-y": down})
    assert "drag 30, lift 6, side 1.5 N" in lines[1] and "A 0.04 m^2" in lines[1]
    assert "no inflow speed" in lines[2] and "lift n/a" in lines[2]


def test_a_coefficient_with_zero_area_is_refused_and_an_unreached_probe_warns():
    pf = probe_forces("+z", _stats([(0.0, 0.0, 0.0)] * 4), np.zeros((0, 3)), 0.05, 3.0, 1000.0)
    assert not pf.reached and np.all(pf.mean == 0.0)
    with pytest.raises(ValueError, match="projected area is 0"):
        pf.coefficients()
    solid = lattice_in_box([0, 0, 0], [0.2, 0.2, 0.2], 0.05)
    quiet = probe_forces("+z", _stats([(0.0, 0.0, 0.0)] * 4), solid, 0.05, 3.0, 1000.0)
    assert any("never reached the solid: its force is 0" in line for line in force_lines({"+z": quiet}))


def test_a_probe_run_reports_a_drag_along_its_flow_and_stores_it(tmp_path):
    cfg = PhysicsConfig(**{**COARSE, "steps": 60}, directions=("-x", "+z"))
    res = simulate_gaussians(sphere_gaussians(), cfg, progress=False)
    forces = res.forces
    assert set(forces) == {"-x", "+z"}
    for d, pf in forces.items():
        assert pf.series.shape == (60, 3) and np.isfinite(pf.series).all()
        assert pf.parts()["drag"] > 0, d  # the flow pushes the sphere downstream
        assert 0.1 < pf.coefficients()["drag"] < 10.0
    path = save_result(tmp_path / "r.h5", res)
    with h5py.File(path) as f:
        ds = f["probes/-x/force"]
        np.testing.assert_array_equal(ds[()], forces["-x"].series)
        np.testing.assert_allclose(ds.attrs["mean"], forces["-x"].mean)
        assert ds.attrs["C_d"] == pytest.approx(forces["-x"].coefficients()["drag"])
    back = load_result(path).forces
    np.testing.assert_array_equal(back["+z"].series, forces["+z"].series)
