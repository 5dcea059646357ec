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
    assert ti.lang.impl.get_runtime().prog is prog          # no ti.init: arrays and kernels stay
    _fill(kept, 2.0)
    assert np.all(kept.to_numpy() == 2.0)


def test_reinit_with_old_arrays_in_a_cycle_keeps_new_arrays_alive(taichi_settings):
    _, debug, threads = _current()
    arch = taichi_settings.arch
    enabled = gc.isenabled()
    gc.disable()                                            # the cycle survives until collected
    try:
        old = weakref.ref(_Cycle([ti.ndarray(ti.f32, shape=64) for _ in range(32)]))
        assert old() is not None                            # only a collection can free it
        init_taichi(arch, "f32", threads=threads, debug=not debug)       # other settings: a real ti.init
        assert old() is None, "the old runtime's arrays outlived ti.init (they would free by a stale address)"
        fresh = [ti.ndarray(ti.f32, shape=64) for _ in range(32)]
        gc.collect()                                        # the old arrays die now, under the new runtime
        for k, a in enumerate(fresh):
            _fill(a, float(k))
            assert np.all(a.to_numpy() == k), f"array {k} of the new runtime was freed by an old one"
    finally:
        if enabled:
            gc.enable()
        init_taichi(arch, "f32", threads=threads, debug=debug)           # back to the session's settings
