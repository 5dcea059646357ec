"""The executors of experiment and study: a process pool here or a Ray cluster (:mod:`nbv.study.executors`), whose
workers each set up logging, torch threads and their own Taichi runtime."""

from __future__ import annotations

import logging


def init_worker(threads: int, precision: str) -> None:
    """Worker set-up: logging, torch threads and the worker's own Taichi runtime (CPU)."""
    import torch

    from ..runtime import init_taichi
    from ..signals import worker_signals

    worker_signals()  # Ctrl-C is the parent's to handle; its SIGTERM ends this worker without leftovers
    quiet_progress_lock()
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    torch.set_num_threads(threads)
    init_taichi("cpu", precision, threads)


def init_empty_worker(precision: str, threads: int, debug: bool = False) -> None:
    """The empty-scene worker's set-up (:mod:`nbv.physics.empty_worker`): the signals of a worker, warnings only (the
    parent's bar and log speak for the run), one torch thread and ``threads`` Taichi threads on the CPU, in the
    parent's precision and debug mode (debug mode compiles other float code: the bits would differ)."""
    import torch

    from ..runtime import init_taichi
    from ..signals import worker_signals

    worker_signals()
    quiet_progress_lock()
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s (empty-scene worker): %(message)s")
    torch.set_num_threads(1)
    init_taichi("cpu", precision, threads, debug=debug)


def quiet_progress_lock() -> None:
    """Give tqdm a thread lock in this worker. Its default lock holds a multiprocessing semaphore, for bars shared with
    processes this one would start (it starts none); a semaphore made in a spawned worker is registered with the
    resource tracker and unlinked only at a normal exit, so a worker ended by SIGTERM (``os._exit``, see
    :func:`apps.signals.worker_signals`) left it behind and the tracker printed a "leaked semaphore" warning."""
    import threading

    from tqdm import tqdm

    tqdm.set_lock(threading.RLock())


def make_executor(
    kind: str, workers: int, threads: int, address: str | None, precision: str = "f32", local_cpus: int | None = None
):
    """A :mod:`nbv.study.executors` executor whose workers run :func:`init_worker`."""
    from nbv.study.executors import LocalExecutor, RayExecutor

    if threads < 1:
        raise ValueError(f"--threads must be >= 1 per worker, got {threads}")
    if kind == "local":
        return LocalExecutor(workers, init_worker, (threads, precision))
    return RayExecutor(address, init_worker, (threads, precision), num_cpus=threads, local_cpus=local_cpus)


def study_config_from_args(args, config_class, own: tuple[str, ...], written: tuple[str, ...]):
    """The study config of ``args.config`` (``config_class.load``), its output replaced by ``--output`` when given,
    with its results folder checked before any work: a folder that is a file, cannot be made or holds other files
    (none of ``own``) is named as the option or key that gave it, and no file of ``written`` may be the config."""
    from dataclasses import replace
    from pathlib import Path

    from fluidsim.files import check_not_input

    from .files import check_output_folder

    config = config_class.load(args.config)
    if args.output is not None:
        config = replace(config, output=str(args.output))
    where = "--output" if args.output is not None else f"the 'output' of {args.config}"
    check_output_folder(config.output, where, own)
    check_not_input([("output file", Path(config.output) / name) for name in written], {"CONFIG": args.config})
    return config
