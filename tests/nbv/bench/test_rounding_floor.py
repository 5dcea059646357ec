"""The rounding floor of `fluidgs bench probes`: the nudged time steps, and what counts as within the floor."""

import math
from types import SimpleNamespace

import numpy as np
import pytest

import nbv.bench.probe_profile as profile
from nbv.bench.probe_profile import ROUNDING_NUDGE, RoundingFloor, rounding_dt


def test_rounding_dt_nudges_both_ways_by_growing_steps():
    dts = [rounding_dt(0.002, k) for k in range(1, 5)]
    assert dts == pytest.approx(
        [
            0.002 * (1 + ROUNDING_NUDGE),
            0.002 * (1 - ROUNDING_NUDGE),
            0.002 * (1 + 2 * ROUNDING_NUDGE),
            0.002 * (1 - 2 * ROUNDING_NUDGE),
        ],
        rel=1e-12,
    )
    # each nudge changes the float32 step the solver uses (else the replicas would repeat the uncut run's bits)
    assert len({np.float32(d) for d in [0.002, *dts]}) == 5
    with pytest.raises(ValueError, match="numbered from 1"):
        rounding_dt(0.002, 0)


def test_floor_holds_an_answer_no_worse_than_its_worst_replica():
    floor = RoundingFloor(views=(0.95, 0.99), dg=(0.78, 0.80), ratio=(0.001, 0.13))
    assert floor.holds(0.95, 0.78, 0.13)
    assert floor.holds(1.0, 1.0, 0.0)
    assert not floor.holds(0.949, 0.9, 0.0)  # the views below the worst replica
    assert not floor.holds(0.99, 0.779, 0.0)  # D_g below it
    assert not floor.holds(0.99, 0.9, 0.131)  # the ratio moved further than any replica's
    assert floor.holds(0.99, 0.9, float("nan"))  # no empty scene: no ratio to judge
    line = floor.line()
    assert "2 uncut runs" in line and "views 0.950-0.990" in line and "D_g 0.780-0.800" in line and "13 %" in line


def test_floor_of_answers_measures_each_replica_against_the_uncut_run():
    rng = np.random.default_rng(0)
    d_g, views = rng.random(50), rng.random(8)
    same = (d_g.copy(), 2.0, views.copy())
    reversed_ = (-d_g, 2.2, -views)
    floor = RoundingFloor.of((d_g, 2.0, views), [same, reversed_])
    assert floor.views == pytest.approx((1.0, -1.0)) and floor.dg == pytest.approx((1.0, -1.0))
    assert floor.ratio == pytest.approx((0.0, 0.1))
    no_empty = RoundingFloor.of((d_g, float("nan"), views), [same])
    assert math.isnan(no_empty.ratio[0]) and "ratio moved n/a" in no_empty.line()


def test_rounding_floor_runs_the_uncut_probes_at_the_nudged_steps(monkeypatch):
    """Each replica traces the same plan with only the frame's time step changed."""
    seen = []

    def trace_probes(frame, plan, solid_points, *, every, empty):
        seen.append((frame.config.dt, plan, every, empty))
        return [], {}

    monkeypatch.setattr(profile, "trace_probes", trace_probes)
    monkeypatch.setattr(profile, "answer", lambda traces, stops, covariances: (np.arange(5.0), 1.0))
    monkeypatch.setattr(profile, "replace", lambda obj, **kw: SimpleNamespace(**{**vars(obj), **kw}))
    frame = SimpleNamespace(config=SimpleNamespace(dt=0.002), covariances=None)
    plan = object()
    floor = profile.rounding_floor(
        frame, plan, np.zeros((1, 3)), (np.arange(5.0), 1.0, np.arange(3.0)), 2, lambda d: d[:3], every=10, empty=False
    )
    assert [s[0] for s in seen] == [rounding_dt(0.002, 1), rounding_dt(0.002, 2)]
    assert all(s[1] is plan and s[2] == 10 and s[3] is False for s in seen)
    assert floor.views == (1.0, 1.0) and floor.ratio == (0.0, 0.0)
    assert frame.config.dt == 0.002  # the uncut frame is left as it was
    seen.clear()
    assert profile.rounding_floor(frame, plan, np.zeros((1, 3)), (None, 1.0, None), 0, None) is None and not seen
