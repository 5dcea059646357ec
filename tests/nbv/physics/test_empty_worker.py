"""The empty scene beside the probes (nbv.physics.empty_worker): a worker process gives the same bits as this
process running the empty scene itself, fills the cache as it would, is replaced by this process when it dies,
its diverged probe is raised as this process's own would be, and it dies with a killed command."""

import functools
import logging
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import torch

from apps.options.executor import init_empty_worker
from apps.runtime import init_taichi
from fluidsim.simulation import SimulationDiverged
from nbv.physics import PhysicsConfig, empty_worker, simulate_gaussians
from nbv.physics.empty_worker import EmptyHelper, helper_wanted
from recon.gaussians import GaussianSet

from helpers.paths import REPO
from helpers.spheres import fibonacci_sphere

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the worker runs on Linux only")

CFG = PhysicsConfig(particle_radius=0.08, steps=60, dt=0.004, directions=("-x", "+x", "-z"), scale=1.0)


def _sphere() -> GaussianSet:
    pts = 0.5 * fibonacci_sphere(300)
    return GaussianSet.from_points(torch.tensor(pts, dtype=torch.float32), scale=0.06, opacity=0.9)


@pytest.fixture
def release_runtime():
    """The worker's runtime settings (debug off, 2 threads) in this process too: debug mode compiles other float
    code, so a worker must run in the parent's mode (``init_empty_worker``'s ``debug``); the session's settings come
    back after the test (conftest)."""
    init_taichi("cpu", "f32", 2)


@pytest.fixture
def patient(monkeypatch):
    """A worker for these small probes, and this process waiting for it to be set up before it takes an empty-scene
    probe itself (the small probes would all end before the worker's start-up): the worker surely gets one."""
    monkeypatch.setattr(empty_worker, "MIN_PARTICLE_STEPS", 0)
    real_take = EmptyHelper.take

    def take(self):
        deadline = time.monotonic() + 120
        while self._process is not None and not self._ready and not self._dead and time.monotonic() < deadline:
            self.poll()
            time.sleep(0.05)
        return real_take(self)

    monkeypatch.setattr(EmptyHelper, "take", take)


def _same(a, b):
    assert np.count_nonzero(a.empty_per_probe[:2]) > 100  # the side probes' empty scenes reach the Gaussians
    np.testing.assert_array_equal(a.per_probe, b.per_probe)
    np.testing.assert_array_equal(a.empty_per_probe, b.empty_per_probe)
    assert a.dbar_empty == b.dbar_empty and a.dbar_empty_mean == b.dbar_empty_mean


def test_the_worker_gives_the_bits_of_this_process(release_runtime, patient, monkeypatch, tmp_path, caplog):
    monkeypatch.setenv("FLUIDGS_CACHE_DIR", str(tmp_path / "beside"))
    g = _sphere()
    here = simulate_gaussians(g, PhysicsConfig(**{**CFG.to_dict(), "empty_cache": False}), progress=False)
    with caplog.at_level(logging.INFO, logger="nbv.physics.empty_worker"):
        beside = simulate_gaussians(g, CFG, progress=False, empty_worker=functools.partial(init_empty_worker, "f32", 1))
    assert "a worker process" in caplog.text  # it ran
    _same(here, beside)
    entries = sorted(p.name for p in (tmp_path / "beside").iterdir())
    assert len(entries) >= 2 and not any(".tmp" in name for name in entries)  # stored by the worker, whole
    caplog.clear()
    again = simulate_gaussians(g, CFG, progress=False, empty_worker=functools.partial(init_empty_worker, "f32", 1))
    assert "a worker process" not in caplog.text  # all cached: no worker started
    _same(here, again)


def test_a_worker_that_dies_is_replaced_by_this_process(release_runtime, patient, monkeypatch, tmp_path, caplog):
    """The worker is killed as soon as it holds a probe: this process names it and runs that probe itself."""
    monkeypatch.setenv("FLUIDGS_CACHE_DIR", str(tmp_path / "dies"))
    real_poll = EmptyHelper.poll

    def poll(self):
        real_poll(self)
        if self.running is not None and self._process.is_alive():
            os.kill(self._process.pid, signal.SIGKILL)

    g = _sphere()
    here = simulate_gaussians(g, PhysicsConfig(**{**CFG.to_dict(), "empty_cache": False}), progress=False)
    monkeypatch.setattr(EmptyHelper, "poll", poll)
    with caplog.at_level(logging.WARNING):
        beside = simulate_gaussians(g, CFG, progress=False, empty_worker=functools.partial(init_empty_worker, "f32", 1))
    assert "ended without its result (exit code -9)" in caplog.text
    _same(here, beside)


def test_a_diverged_empty_scene_in_the_worker_is_raised_as_its_own():
    helper = EmptyHelper(None, None, None, None, CFG, progress=None)
    helper.running = ("-x", CFG)
    helper._receive(("diverged", "-x", (12, "the fluid left the domain", "empty-scene -x")))
    with pytest.raises(SimulationDiverged, match="diverged at step 12: the fluid left") as err:
        helper.raise_error()
    assert err.value.probe == "empty-scene -x" and err.value.step == 12 and helper.running is None


def test_the_worker_is_used_only_where_it_can_help(monkeypatch):
    init = functools.partial(init_empty_worker, "f32", 1)
    assert helper_wanted(init, CFG, cpus=2)
    assert not helper_wanted(None, CFG, cpus=2)
    assert not helper_wanted(init, CFG, cpus=1)
    assert not helper_wanted(init, PhysicsConfig(**{**CFG.to_dict(), "empty_reference": False}), cpus=2)
    monkeypatch.setenv("FLUIDGS_EMPTY_PROCESS", "0")
    assert not helper_wanted(init, CFG, cpus=2)


def _children(pid: int) -> list[int]:
    out = []
    for task in os.listdir(f"/proc/{pid}/task"):
        with open(f"/proc/{pid}/task/{task}/children") as f:
            out += [int(c) for c in f.read().split()]
    return out


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] not in ("Z", "X")
    except FileNotFoundError:
        return False


def test_the_worker_dies_with_a_killed_command(tmp_path, assets_dir):
    """A SIGKILLed `simulate` leaves no worker simulating on (PR_SET_PDEATHSIG)."""
    env = {**os.environ, "FLUIDGS_CACHE_DIR": str(tmp_path / "cache"), "PYTHONPATH": str(REPO)}
    cmd = [sys.executable, "-m", "apps.cli", "-v", "simulate", str(assets_dir / "ahmed_gaussians.ply"), "--quick"]
    cmd += ["--threads", "2", "-o", str(tmp_path / "r.h5")]
    proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    worker, t0 = None, time.monotonic()
    try:
        for line in proc.stderr:  # the worker starts when the first probe ends
            if "a worker process (pid" in line:
                worker = int(line.split("(pid ")[1].split(")")[0])
                break
            assert time.monotonic() - t0 < 240, "no worker started"
        assert worker is not None and worker in _children(proc.pid)
        time.sleep(6.0)  # started and simulating (a probe takes longer than the deadline below)
        proc.send_signal(signal.SIGKILL)
        proc.wait(30)
        deadline = time.monotonic() + 5
        while _alive(worker) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not _alive(worker)
    finally:
        if proc.poll() is None:
            proc.kill()
        if worker is not None and _alive(worker):
            os.kill(worker, signal.SIGKILL)
    leftovers = [p.name for p in (tmp_path / "cache").glob("*")] if (tmp_path / "cache").exists() else []
    assert not any(".tmp" in name for name in leftovers)
