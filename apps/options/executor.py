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
