"""The experiment's cost model (nbv.study.cost): each part scales with the work of the job's own protocol."""

from dataclasses import replace

import pytest

from nbv.active import ActiveConfig
from nbv.study.cost import MEASURED, REF_RADIUS, Scene, job_seconds, minutes, reference_steps


def test_the_job_cost_scales_with_its_protocol():
    def seconds(scene=None, **active):
        a = ActiveConfig.from_preset("cpu-small", **active)
        return job_seconds(a, replace(a.physics, empty_reference=True), scene or Scene(40, 64 * 64))

    base = seconds(method="fisher+fluid")
    double = seconds(Scene(40, 128 * 128), method="fisher+fluid")  # twice the resolution: four times the pixels
    for part in ("training", "visual"):
        assert double[part] == pytest.approx(4 * base[part])
    for part in ("probes", "eval", "rounds"):
        assert double[part] == pytest.approx(base[part])
    assert seconds(method="fisher+fluid", total_iterations=2000)["training"] == pytest.approx(2 * base["training"])
    assert seconds(method="fisher")["probes"] == 0 and seconds(method="random")["visual"] == 0
    # the probes: rounds x (reference steps x probe_step_s + Gaussians x probe_gaussian_s)
    a = ActiveConfig.from_preset("cpu-small")
    assert reference_steps(a.physics) == a.physics.steps * 5
    half = replace(a.physics, particle_radius=REF_RADIUS / 2)
    assert reference_steps(half) == pytest.approx(8 * reference_steps(a.physics))  # (2 r / r)^3 more particles
    assert reference_steps(replace(a.physics, empty_reference=True)) == 2 * reference_steps(a.physics)
    per_run = 750 * MEASURED.probe_step_s + 4000 * MEASURED.probe_gaussian_s
    assert base["probes"] == pytest.approx(8 * per_run)  # budget 10 from 2 initial views: 8 selections
    assert seconds(method="fisher+fluid", budget=4)["probes"] == pytest.approx(2 * per_run)
    # FisherRF ranks every candidate left: 38 + 37 + ... + 31 views
    assert base["visual"] == pytest.approx(MEASURED.visual_s["fisher"] * sum(range(31, 39)) * 64 * 64)


def test_minutes_reads_as_seconds_minutes_or_hours():
    assert minutes(42) == "42 s" and minutes(95) == "1.6 min" and minutes(7200) == "2.0 h"
