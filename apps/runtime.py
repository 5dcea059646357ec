"""Taichi runtime set-up for the command-line tools (the only place, with test fixtures, that calls ti.init)."""

from __future__ import annotations

import logging
import os

log = logging.getLogger("fluidgs")


def init_taichi(device: str = "cpu", precision: str = "f32", threads: int | None = None, debug: bool = False) -> str:
    """Initialise Taichi once for this process; returns the device actually used ("cpu" or "cuda").

    Args:
        device: "cpu" or "cuda"; "cuda" falls back to the CPU with a logged notice when unavailable.
        precision: "f32" or "f64" (the default float type of every kernel).
        threads: CPU threads (None: all cores).
        debug: Taichi debug mode (bounds checks).
    """
    import taichi as ti

    if device not in ("cpu", "cuda"):
        raise ValueError(f"--device must be cpu or cuda, got {device!r}")
    if precision not in ("f32", "f64"):
        raise ValueError(f"--precision must be f32 or f64, got {precision!r}")
    fp = ti.f64 if precision == "f64" else ti.f32
    kwargs = dict(default_fp=fp, offline_cache=True, log_level=ti.WARN, debug=debug)
    if threads:
        kwargs["cpu_max_num_threads"] = int(threads)
    used = "cpu"
    if device == "cuda":
        try:
            ti.init(arch=ti.cuda, **kwargs)
            used = "cuda" if ti.lang.impl.current_cfg().arch == ti.cuda else "cpu"
        except Exception as exc:  # noqa: BLE001 - any CUDA start-up failure means "use the CPU"
            log.warning("CUDA unavailable (%s)", exc)
            used = "cpu"
        if used == "cpu":
            log.warning("--device cuda requested but no CUDA device is usable; falling back to the CPU")
            ti.init(arch=ti.cpu, **kwargs)
    else:
        ti.init(arch=ti.cpu, **kwargs)
    log.info("Taichi on %s, %s, %s threads", used, precision, threads or os.cpu_count())
    return used
