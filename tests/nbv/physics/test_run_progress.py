"""The run's progress bar: "probe k of n" over the probes and the empty scene, weighted by each probe's fluid so
that one ETA holds across probes of different sizes."""

import io
from types import SimpleNamespace

from nbv.physics.progress import RunProgress


class _Plan:
    def fluid_counts(self, directions):
        return {"-x": 300, "-y": 100}


def _stats(step):
    return SimpleNamespace(step=step, density_iterations=2, divergence_iterations=1, max_speed=3.0, active=10)


def _bar(empty: bool) -> RunProgress:
    config = SimpleNamespace(directions=("-x", "-y"), steps=4, empty_reference=empty)
    progress = RunProgress(_Plan(), config, enabled=True)
    progress.bar.fp = io.StringIO()  # keep the test's output clean
    return progress


def test_probe_k_of_n_counts_the_empty_scene():
    bar = _bar(empty=True)
    assert bar.bar.total == 4 * (300 + 100) * 2
    seen = []
    for label in ("", "empty "):
        for d in ("-x", "-y"):
            bar.start(d, label)
            seen.append(bar.bar.desc)
            for s in range(4):
                bar.tick(_stats(s))
    assert seen == ["probe 1 of 4 (-x)", "probe 2 of 4 (-y)", "probe 3 of 4 (empty -x)", "probe 4 of 4 (empty -y)"]
    assert bar.bar.n == bar.bar.total
    bar.close()


def test_each_step_weighs_its_probes_fluid():
    bar = _bar(empty=False)
    bar.start("-x")
    for s in range(4):
        bar.tick(_stats(s))
    assert bar.bar.n / bar.bar.total == 0.75  # the -x probe has three quarters of the fluid particle-steps
    bar.skip("-y")  # a cached probe: the bar moves past it
    assert bar.bar.n == bar.bar.total
    assert bar.bar.desc == "probe 2 of 2 (-y)"
    bar.close()
