"""Where the jobs of an experiment run: a local process pool or an existing Ray cluster.

No paper equation here. Both executors take a picklable job function, a list of picklable jobs and an
``initializer`` (called with ``initargs`` in every worker before its first job: e.g. set the torch threads and
initialise Taichi, which only ``apps`` may do) and yield ``(job, result)`` pairs as jobs finish.

- :class:`LocalExecutor`: ``concurrent.futures.ProcessPoolExecutor`` with the *spawn* start method (fork would copy a
  live Taichi / OpenMP runtime into the children).
- :class:`RayExecutor`: ``ray.init(address=...)`` connects to a running cluster (``address=None`` starts a new local
  one on this machine, with ``local_cpus`` CPUs, even when another Ray instance runs here; Ray 2.x no longer has the
  serial "local mode", so tests start such a small local instance). Ray is an optional dependency, imported only
  here; without it the error says ``pip install ray``. The initializer runs inside every task (Ray may place
  consecutive tasks in different worker processes). Tasks are spread over the cluster's nodes; a task whose worker
  process or node dies is run again up to ``max_retries`` times, and past that the error names the job
  (:class:`JobLost`). A job's own exception is never retried (the jobs are deterministic).
"""

from __future__ import annotations

import logging
import multiprocessing
import signal
import threading
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any

from fluidsim.host import hangup_shielded

log = logging.getLogger(__name__)


def _noop(*_args: Any) -> None:
    """Initializer that does nothing."""


class LocalExecutor:
    """A process pool on this machine.

    Args:
        workers: worker processes (>= 1).
        initializer: called as ``initializer(*initargs)`` once in every worker.
        initargs: its arguments (picklable).
    """

    name = "local"

    def __init__(
        self, workers: int = 1, initializer: Callable[..., None] | None = None, initargs: Sequence[Any] = ()
    ) -> None:
        if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
            raise ValueError(f"--workers must be an integer >= 1, got {workers!r}")
        self.workers = workers
        self.initializer = initializer or _noop
        self.initargs = tuple(initargs)

    def map(self, fn: Callable[[Any], Any], jobs: Sequence[Any]) -> Iterator[tuple[Any, Any]]:
        """Run ``fn(job)`` for every job; yields (job, result) in completion order.

        The first job that fails cancels the jobs not yet started (those running finish) and its error is raised
        with the job attached as ``error.job``.
        """
        if not jobs:
            return
        ctx = multiprocessing.get_context("spawn")
        with hangup_shielded():  # the resource tracker starts here
            pool = ProcessPoolExecutor(
                max_workers=min(self.workers, len(jobs)),
                mp_context=ctx,
                initializer=self.initializer,
                initargs=self.initargs,
            )
        with pool:
            try:
                with hangup_shielded():  # the workers start here
                    futures = {pool.submit(fn, job): job for job in jobs}
                for fut in as_completed(futures):
                    try:
                        result = fut.result()
                    except Exception as exc:
                        pool.shutdown(wait=False, cancel_futures=True)
                        exc.job = futures[fut]
                        raise
                    yield futures[fut], result
            except (KeyboardInterrupt, SystemExit, GeneratorExit):
                terminate_workers(pool)  # a signal or an abandoned map: no worker may outlive it
                raise


def terminate_workers(pool: ProcessPoolExecutor, grace_s: float = 10.0) -> None:
    """Stop every worker process of ``pool`` now: SIGTERM (a worker set up by ``apps.signals.worker_signals`` removes
    its unfinished files and exits), SIGKILL for one still alive after ``grace_s`` seconds; the queued jobs are
    cancelled. The pool's manager thread is waited for: Python 3.11's exit hook writes to that thread's wake-up pipe
    while the thread may be closing it (an "OSError: Bad file descriptor" traceback at exit, one stop in ~25 under
    load), and ``shutdown(wait=False)`` forgets the thread. With the last worker the resource tracker ends."""
    processes = list((getattr(pool, "_processes", None) or {}).values())  # the standard library keeps them here
    manager = getattr(pool, "_executor_manager_thread", None)
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in processes:
        if proc.is_alive():
            proc.terminate()
    for proc in processes:
        proc.join(grace_s)
        if proc.is_alive():
            log.warning("worker %d did not stop on SIGTERM within %.0f s; killing it", proc.pid, grace_s)
            proc.kill()
            proc.join(grace_s)
    if manager is not None:
        manager.join(grace_s)


def _ray_task(fn: Callable[[Any], Any], job: Any, initializer: Callable[..., None], initargs: tuple) -> Any:
    initializer(*initargs)
    return fn(job)


# Ray's errors for a task whose worker process or node died (not the job's own exception); some Ray versions
# lack one of them.
_LOST = ("WorkerCrashedError", "NodeDiedError", "LocalRayletDiedError")


class JobLost(RuntimeError):
    """A job whose Ray worker (or node) died on every try; ``job`` is the job."""

    def __init__(self, job: Any, tries: int, cause: BaseException) -> None:
        text = repr(job)
        text = text if len(text) <= 300 else text[:297] + "..."
        super().__init__(
            f"Ray lost job {text}: its worker died on {tries} {'try' if tries == 1 else 'tries'} "
            f"({type(cause).__name__}: "
            f"{str(cause).splitlines()[0] if str(cause) else 'no detail'}); check the nodes' memory and "
            "logs, or raise max_retries"
        )
        self.job = job


def import_ray():
    """The ``ray`` module, or ValueError telling how to install it."""
    try:
        import ray  # noqa: PLC0415 - the optional 'ray' extra
    except ImportError as exc:
        raise ValueError(
            "--executor ray needs the optional Ray package: pip install ray (or use --executor local)"
        ) from exc
    return ray


class RayExecutor:
    """Tasks on a Ray cluster.

    Args:
        address: cluster address for ``ray.init(address=...)`` (e.g. "ray://head:10001" or "auto"); None starts a
            local Ray instance.
        initializer, initargs: run inside every task before the job.
        num_cpus: CPUs Ray reserves per task.
        local_cpus: CPUs of the local instance started when ``address`` is None (None: all of this machine).
        max_retries: times a task whose worker process or node died is run again (>= 0), anywhere in the cluster.
        spread: place the tasks on as many nodes as possible (Ray's "SPREAD" strategy) rather than filling one
            node first.
    """

    name = "ray"

    def __init__(
        self,
        address: str | None = None,
        initializer: Callable[..., None] | None = None,
        initargs: Sequence[Any] = (),
        num_cpus: float = 1.0,
        local_cpus: int | None = None,
        max_retries: int = 2,
        spread: bool = True,
    ) -> None:
        if isinstance(max_retries, bool) or not isinstance(max_retries, int) or max_retries < 0:
            raise ValueError(f"max_retries must be an integer >= 0, got {max_retries!r}")
        self.ray = import_ray()
        self.max_retries = max_retries
        self.spread = bool(spread)
        self.address = address
        self.initializer = initializer or _noop
        self.initargs = tuple(initargs)
        self.num_cpus = float(num_cpus)
        if local_cpus is not None and (
            isinstance(local_cpus, bool) or not isinstance(local_cpus, int) or local_cpus < 1
        ):
            raise ValueError(f"local_cpus must be None or an integer >= 1, got {local_cpus!r}")
        self.local_cpus = local_cpus
        self.started = False

    def map(self, fn: Callable[[Any], Any], jobs: Sequence[Any]) -> Iterator[tuple[Any, Any]]:
        """Submit every job as a Ray task; yields (job, result) in completion order.

        A task whose worker died is retried (``max_retries``); the first task that fails for good cancels the
        others and its error is raised with the job as ``error.job``: the job's own exception, or
        :class:`JobLost` when its worker died on every try.
        """
        ray = self.ray
        if not jobs:
            return
        if not ray.is_initialized():
            kwargs: dict[str, Any] = {"include_dashboard": False}
            if self.address is None and self.local_cpus is not None:
                kwargs["num_cpus"] = self.local_cpus
            # "local": a new instance, never the last one started on this machine (ray.init's default). Ray installs
            # its own SIGTERM handler in the driver; the caller's handlers are put back, so that a signal ends the
            # tasks through the clean-up below instead of aborting the driver.
            handlers = (
                {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
                if threading.current_thread() is threading.main_thread()
                else {}
            )
            ray.init(address=self.address or "local", **kwargs)
            for sig, handler in handlers.items():
                signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
            self.started = self.address is None
            log.info("connected to Ray at %s", self.address or "a new local instance")
        task = ray.remote(
            num_cpus=self.num_cpus,
            max_retries=self.max_retries,
            retry_exceptions=False,
            scheduling_strategy="SPREAD" if self.spread else "DEFAULT",
        )(_ray_task)
        pending = {task.remote(fn, job, self.initializer, self.initargs): job for job in jobs}
        try:
            yield from self._collect(pending)
        except (KeyboardInterrupt, SystemExit, GeneratorExit):
            for ref in pending:  # a signal or an abandoned map: the tasks stop, and a local instance goes
                try:
                    ray.cancel(ref, force=True)
                except Exception as exc:  # noqa: BLE001 - a task that already ended cannot be cancelled
                    log.debug("ray.cancel: %s", exc)
            if self.started:
                ray.shutdown()
            raise

    def _collect(self, pending: dict) -> Iterator[tuple[Any, Any]]:
        ray = self.ray
        lost = tuple(getattr(ray.exceptions, name) for name in _LOST if hasattr(ray.exceptions, name))
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            ref = done[0]
            job = pending.pop(ref)
            try:
                result = ray.get(ref)
            except Exception as exc:
                for other in pending:
                    ray.cancel(other)
                if isinstance(exc, lost):
                    log.error("Ray lost job %r after %d tries: %s", job, self.max_retries + 1, exc)
                    raise JobLost(job, self.max_retries + 1, exc) from exc
                exc.job = job
                raise
            yield job, result
