"""The command-line tools' Taichi set-up: a matching runtime is kept, and a re-initialisation never lets an
array of the old runtime free one of the new (Taichi frees ndarrays by address through the current runtime)."""

import gc
import weakref

import numpy as np
import taichi as ti

from apps.runtime import init_taichi


@ti.kernel
def _fill(a: ti.types.ndarray(ndim=1), value: ti.f32):
    for i in range(a.shape[0]):
        a[i] = value


class _Cycle:
    """Holds arrays in a reference cycle, so only the garbage collector frees them."""

    def __init__(self, arrays):
        self.arrays = arrays
        self.me = self


def _current():
    cfg = ti.lang.impl.current_cfg()
    return ti.lang.impl.get_runtime(), bool(cfg.debug), cfg.cpu_max_num_threads


def test_matching_runtime_is_kept(taichi_settings):
    runtime, debug, threads = _current()
    prog = runtime.prog
    kept = ti.ndarray(ti.f32, shape=8)
    arch = taichi_settings.arch  # the session's (FLUIDGS_TEST_ARCH)
    assert init_taichi(arch, "f32", threads=threads, debug=debug) == arch
    assert ti.lang.impl.get_runtime().prog is prog  # no ti.init: arrays and kernels stay
    _fill(kept, 2.0)
    assert np.all(kept.to_numpy() == 2.0)


def test_reinit_with_old_arrays_in_a_cycle_keeps_new_arrays_alive(taichi_settings):
    _, debug, threads = _current()
    arch = taichi_settings.arch
    enabled = gc.isenabled()
    gc.disable()  # the cycle survives until collected
    try:
        old = weakref.ref(_Cycle([ti.ndarray(ti.f32, shape=64) for _ in range(32)]))
        assert old() is not None  # only a collection can free it
        init_taichi(arch, "f32", threads=threads, debug=not debug)  # other settings: a real ti.init
        assert old() is None, "the old runtime's arrays outlived ti.init (they would free by a stale address)"
        fresh = [ti.ndarray(ti.f32, shape=64) for _ in range(32)]
        gc.collect()  # the old arrays die now, under the new runtime
        for k, a in enumerate(fresh):
            _fill(a, float(k))
            assert np.all(a.to_numpy() == k), f"array {k} of the new runtime was freed by an old one"
    finally:
        if enabled:
            gc.enable()
        init_taichi(arch, "f32", threads=threads, debug=debug)  # back to the session's settings


HANG = (
    "import time\nfrom apps.startup_watchdog import startup_watchdog\nwith startup_watchdog(1.0):\n"
    "    time.sleep(60)\nprint('not reached')\n"
)


def test_startup_watchdog_says_so_and_stops_a_hang():
    """A start-up that hangs (here a sleep) is stopped after the timeout with one line that says how to retry."""
    import os
    import signal
    import subprocess
    import sys
    import time

    from helpers.paths import REPO

    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])])}
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", HANG], capture_output=True, text=True, timeout=60, env=env)
    took = time.perf_counter() - t0
    assert proc.returncode == -signal.SIGTERM and took < 30, (proc.returncode, took)
    assert "not reached" not in proc.stdout
    lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("ERROR fluidgs:")]
    assert len(lines) == 1 and "has not started within 1 s" in lines[0] and "run it again" in lines[0]


def test_startup_watchdog_is_quiet_when_the_start_ends_and_reads_its_limit(monkeypatch, capfd):
    import pytest

    from apps.startup_watchdog import STARTUP_TIMEOUT_S, TIMEOUT_ENV, startup_timeout, startup_watchdog

    with startup_watchdog(30.0):
        pass
    assert "ERROR" not in capfd.readouterr().err
    monkeypatch.delenv(TIMEOUT_ENV, raising=False)
    assert startup_timeout() == STARTUP_TIMEOUT_S
    monkeypatch.setenv(TIMEOUT_ENV, "0")
    assert startup_timeout() == 0.0
    for bad in ("-1", "soon", "nan"):
        monkeypatch.setenv(TIMEOUT_ENV, bad)
        with pytest.raises(ValueError, match=TIMEOUT_ENV):
            startup_timeout()
