"""Taichi runtime set-up: one helper that initialises Taichi for a process, offered to the applications.

It lives in ``apps`` because only the command-line tools and the test fixtures may call ``ti.init`` (the library
packages never do); importing this module initialises nothing. It keeps a runtime that already has the wanted
settings, and works around Taichi 1.7 freeing ndarrays by address through the runtime that is current when they
die (:func:`release_unreachable_arrays`). No paper equations here.

The start-up runs under :func:`apps.startup_watchdog.startup_watchdog` (its docstring says why).
"""

from __future__ import annotations

import gc
import logging
import numbers
import os

from .startup_watchdog import startup_watchdog

log = logging.getLogger(__name__)

DEVICES = ("cpu", "cuda")
MAX_THREADS = 1024  # above any machine's cores; Taichi allocates per thread, so 100000 ran out of memory silently
PRECISIONS = ("f32", "f64")


def check_threads(threads: int | None, option: str = "--threads") -> int | None:
    """``threads`` unchanged when None (all cores) or an integer from 1 to :data:`MAX_THREADS`; else ValueError
    naming ``option``. More threads than cores is allowed, with a logged notice.

    Taichi takes any integer: 0 silently meant all cores and -1 failed inside its C++ runtime with
    ``vector::_M_default_append``."""
    if threads is None:
        return None
    if isinstance(threads, bool) or not isinstance(threads, numbers.Integral) or threads < 1:
        raise ValueError(f"{option} must be an integer >= 1 (CPU threads; leave it out for all cores), got {threads!r}")
    if threads > MAX_THREADS:
        raise ValueError(
            f"{option} must be at most {MAX_THREADS} CPU threads, got {threads}; this machine has "
            f"{os.cpu_count()} cores (leave {option} out for all of them)"
        )
    cores = os.cpu_count() or 1
    if threads > cores:
        log.warning(
            "%s %d is more than this machine's %d cores: the threads share them, which is slower, not "
            "faster; leave %s out for all cores",
            option,
            threads,
            cores,
            option,
        )
    return int(threads)


def init_taichi(device: str = "cpu", precision: str = "f32", threads: int | None = None, debug: bool = False) -> str:
    """Initialise Taichi once for this process; returns the device actually used ("cpu" or "cuda").

    A runtime that already runs with these settings is kept (no re-initialisation, no recompilation).
    Before a new ``ti.init`` the garbage collector runs, so that arrays of the old runtime that only cycles
    still hold are released by the runtime that owns them (:func:`release_unreachable_arrays`).

    Args:
        device: "cpu" or "cuda"; "cuda" falls back to the CPU with a logged notice when unavailable.
        precision: "f32" or "f64" (the default float type of every kernel).
        threads: CPU threads, >= 1 (None: all cores); anything else is a ValueError naming ``--threads``.
        debug: Taichi debug mode (bounds checks).

    Example:
        >>> init_taichi("cpu", "f32", threads=2)  # doctest: +SKIP
        'cpu'
    """
    import taichi as ti

    threads = check_threads(threads)
    if device not in DEVICES:
        raise ValueError(f"--device must be cpu or cuda, got {device!r}")
    if precision not in PRECISIONS:
        raise ValueError(f"--precision must be f32 or f64, got {precision!r}")
    fp = ti.f64 if precision == "f64" else ti.f32
    if _running_with(ti, device, fp, threads, debug):
        log.info("Taichi already running on %s, %s; kept", device, precision)
        return device
    release_unreachable_arrays()
    kwargs = dict(default_fp=fp, offline_cache=True, log_level=ti.WARN, debug=debug)
    if threads:
        kwargs["cpu_max_num_threads"] = int(threads)
    used = "cpu"
    with startup_watchdog():
        if device == "cuda":
            used = _init_cuda(ti, kwargs)
        else:
            ti.init(arch=ti.cpu, **kwargs)
        _first_kernel(ti)
    log.info("Taichi on %s, %s, %s threads", used, precision, threads or os.cpu_count())
    return used


def _first_kernel(ti) -> None:
    """One small parallel kernel, so that the thread pool starts inside the watchdog."""

    def fill(a):
        for i in a:
            a[i] = i

    fill.__annotations__ = {"a": ti.types.ndarray(dtype=ti.i32, ndim=1)}  # objects: this module's are strings
    ti.kernel(fill)(ti.ndarray(ti.i32, shape=64))
    ti.sync()


def _init_cuda(ti, kwargs: dict) -> str:
    """``ti.init`` on CUDA, or on the CPU with a logged notice when no CUDA device is usable; the arch used."""
    used = "cpu"
    try:
        ti.init(arch=ti.cuda, **kwargs)
        used = "cuda" if ti.lang.impl.current_cfg().arch == ti.cuda else "cpu"
    except Exception as exc:  # noqa: BLE001 - any CUDA start-up failure means "use the CPU"
        log.warning("CUDA unavailable (%s)", exc)
        used = "cpu"
    if used == "cpu":
        log.warning("--device cuda requested but no CUDA device is usable; falling back to the CPU")
        ti.init(arch=ti.cpu, **kwargs)
    return used


def _running_with(ti, device: str, fp, threads: int | None, debug: bool) -> bool:
    """Whether the current Taichi runtime already has these settings (arch, float type, threads, debug)."""
    runtime = ti.lang.impl.get_runtime()
    if runtime.prog is None:
        return False
    cfg = ti.lang.impl.current_cfg()
    arch_ok = cfg.arch == ti.cuda if device == "cuda" else cfg.arch in (ti.x64, ti.arm64)
    return (
        arch_ok
        and runtime.default_fp == fp
        and bool(cfg.debug) == bool(debug)
        and cfg.cpu_max_num_threads == int(threads or os.cpu_count() or 1)
    )


def release_unreachable_arrays() -> None:
    """Collect garbage before ``ti.init`` replaces the runtime.

    Taichi 1.7 frees an ndarray through the runtime that is current when the Python object dies, by the
    address of its C++ array. An array of the old runtime that a reference cycle kept alive past
    ``ti.init`` would hand the new runtime a stale address, which the allocator may already have given to
    a live array of the new runtime: that array is then freed under its owner's feet (seen as
    ``RuntimeError: argument not found`` at a later launch). Collecting first releases such arrays
    while their own runtime still exists.
    """
    gc.collect()
