"""The empty scene beside the probes: a second process simulates empty-scene probes while this one runs the probes
with the solid, and this one takes the rest once its own are done.

On two cores the probes use about 1.4 of them (small probes: launches and serial parts run on one core), and a first
run simulates as many empty-scene probes as probes with the solid. :class:`EmptyHelper` starts one worker process
(spawned; its Taichi runtime set up by the caller's initializer, as only ``apps`` calls ``ti.init``) when the first
probe's empty scene is found in no cache, and hands it one empty-scene probe at a time as the probes with the solid
end (each empty scene runs the steps its probe ran, so it is known only then). When this process has run its own
probes, it runs the empty-scene probes the worker has not started, between which the worker gets the next. Both
run the same code (:func:`nbv.physics.empty_scene.empty_probe_means`) on the same Gaussians and cell lists, and the
engine's sums do not depend on the thread count, so the result is the same bits as one process running them all.

The worker ignores Ctrl-C and hang-ups (its parent decides), dies with its parent (``PR_SET_PDEATHSIG``: SIGTERM,
on which it removes its unfinished files), stores what it simulated in the empty-scene cache, and sends back each
probe's [G] means or its exception (a diverged empty scene is raised here as before). A worker that ends without its
result is named in a warning, and its probe runs here.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
import pickle
import signal
import sys
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from fluidsim.host import die_with_parent, hangup_shielded
from fluidsim.simulation import SimulationDiverged
from nbv.physics.empty_cache import EmptyReference
from nbv.physics.empty_scene import empty_probe_config, empty_probe_means
from nbv.physics.memory import estimate_memory, memory_limit_bytes
from nbv.physics.progress import RunProgress
from nbv.physics.recorder import ProbeRecorder

log = logging.getLogger(__name__)

# FLUIDGS_EMPTY_PROCESS=0 runs the empty scene in this process, after the probes.
PROCESS_ENV = "FLUIDGS_EMPTY_PROCESS"
# Fluid particle-steps per probe (the mean) below which no worker starts: its start-up (imports, its runtime: about
# 4 s of one core) would outlast such probes, which this process then runs itself anyway.
MIN_PARTICLE_STEPS = 1e6
# Memory a worker takes besides its probe and cell lists: its interpreter, torch, Taichi and their libraries.
WORKER_BASE_BYTES = 600 * 2**20


def helper_wanted(initializer, config, cpus: int | None = None) -> bool:
    """Whether a run may use a worker: an initializer, an empty scene, at least two CPUs, Linux (where the worker
    can die with its parent), and ``FLUIDGS_EMPTY_PROCESS`` not 0."""
    if cpus is None:  # the CPUs this process may run on (a taskset or cgroup may allow fewer than the machine has)
        cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return (
        initializer is not None
        and config.empty_reference
        and (cpus or 1) >= 2
        and sys.platform.startswith("linux")
        and os.environ.get(PROCESS_ENV, "1").strip() != "0"
    )


def empty_helper(run, plan, bar) -> EmptyHelper | None:
    """The worker of a run (:class:`nbv.physics.plan.ProbeRunContext` ``run``, its probes ``plan``, its bar), or
    None: no initializer, no empty scene, one CPU, not Linux, ``FLUIDGS_EMPTY_PROCESS=0``, small probes
    (``MIN_PARTICLE_STEPS``), or a worker's probe, cell lists and interpreter would not fit in memory beside this
    process's run (logged)."""
    config = run.frame.config
    if not helper_wanted(run.empty_worker, config):
        return None
    work = sum(plan.fluid_counts(config.directions).values()) * config.steps / len(config.directions)
    if work < MIN_PARTICLE_STEPS:  # small probes end before a worker has started
        return None
    est = estimate_memory(run.frame, plan)
    need = est["bytes"] + est["probe_bytes"] + est["accumulator_bytes"] + WORKER_BASE_BYTES
    if need > memory_limit_bytes(config):
        log.info("empty scene: no worker process (%.3g GiB would not fit); it runs after the probes", need / 2**30)
        return None
    helper = EmptyHelper(run.empty_worker, plan, run.frame.means, run.frame.reach, config, bar)
    bar.poll = helper.poll
    return helper


def offer_empty(helper: EmptyHelper, reference, plan, config, direction: str, steps: int, centers, reach) -> None:
    """After probe ``direction`` ran ``steps`` steps: its empty scene goes to the worker unless ``reference`` holds
    it (its means or its fluid, which this process reads after the probes)."""
    probe_config = empty_probe_config(config, steps)
    if not reference.holds(plan.setups[direction], probe_config, centers, reach):
        helper.offer(direction, probe_config)


class EmptyHelper:
    """This process's side of the worker (module docstring).

    Args:
        initializer: sets up the worker (logging, signals, its own Taichi runtime on the CPU); picklable.
        plan: the run's probes (:class:`nbv.physics.plan.ProbePlan`). centers, reach: [G, 3], [G] sim metres.
        config: the run's settings (:class:`nbv.physics.config.PhysicsConfig`).
        progress: the run's bar (:class:`nbv.physics.progress.RunProgress`), moved as the worker's probes end.
    """

    def __init__(self, initializer: Callable[[], None], plan, centers: np.ndarray, reach: np.ndarray, config, progress):
        self.initializer = initializer
        self.plan, self.centers, self.reach, self.config, self.progress = plan, centers, reach, config, progress
        self.pending: list[tuple[str, object]] = []  # (direction, config of its steps), not handed out yet
        self.running: tuple[str, object] | None = None  # handed to the worker
        self.means: dict[str, np.ndarray] = {}
        self.errors: list[BaseException] = []  # raised by raise_error, after this process's own probes
        self.offered: set[str] = set()
        self._process = None
        self._conn = None
        self._ready = False  # the worker said it is set up (its imports and runtime take seconds)
        self._dead = False

    def offer(self, direction: str, config) -> None:
        """Queue ``direction``'s empty scene (``config`` with the steps its probe ran) for the worker; not when the
        worker died (it is not in ``offered`` then, and this process runs it)."""
        if self._dead:
            return
        if self._process is None:
            self._start()
        self.pending.append((direction, config))
        self.offered.add(direction)
        self.poll()

    def poll(self) -> None:
        """Read the worker's finished probe, if any, and hand it the next pending one when it is idle. Cheap enough
        for every step: one ``poll`` of a pipe."""
        if self._conn is None or self._dead:
            return
        try:
            while (self.running is not None or not self._ready) and self._conn.poll():
                self._receive(self._conn.recv())
        except (EOFError, OSError):
            self._lost()
            return
        if self.running is None and self.pending and self._ready:
            self.running = self.pending.pop(0)
            try:
                self._conn.send(self.running)
            except (BrokenPipeError, OSError):
                self._lost()

    def take(self) -> tuple[str, object] | None:
        """A pending probe for this process to run itself (None: none left)."""
        self.poll()
        return self.pending.pop(0) if self.pending else None

    def wait(self) -> None:
        """Wait for the worker's probe in hand; its exception (a diverged empty scene) is raised here."""
        while self.running is not None and not self._dead:
            try:
                if self._conn.poll(0.2):
                    self._receive(self._conn.recv())
                elif not self._process.is_alive() and not self._conn.poll():
                    self._lost()
            except (EOFError, OSError):
                self._lost()

    def lost(self) -> list[tuple[str, object]]:
        """The probes the worker took and never finished, to run here (after a warning)."""
        out = [] if self.running is None or not self._dead else [self.running]
        if out:
            self.running = None
        return out

    def close(self) -> None:
        """Stop the worker: a clean end when idle, else SIGTERM (it removes its unfinished files), SIGKILL after 10
        s."""
        if self._process is None:
            return
        idle = self._ready and self.running is None and not self._dead
        with contextlib.suppress(OSError, ValueError):
            if idle:
                self._conn.send(None)
        self._process.join(5.0 if idle else 0.0)  # one still starting or simulating is stopped at once
        if self._process.is_alive():
            self._process.terminate()
            self._process.join(10.0)
        if self._process.is_alive():
            self._process.kill()
            self._process.join(10.0)
        with contextlib.suppress(OSError):
            self._conn.close()
        self._process = None

    # -- internals ------------------------------------------------------------------------------------------------
    def _start(self) -> None:
        ctx = multiprocessing.get_context("spawn")
        here, there = ctx.Pipe()
        config = replace(self.config, track_distinct=False)
        self._process = ctx.Process(
            target=_worker_main,
            args=(there, self.initializer, self.plan, self.centers, self.reach, config, os.getpid()),
            name="fluidgs-empty-scene",
            daemon=True,
        )
        with hangup_shielded():  # a closed terminal is the parent's to handle, also while the worker starts
            self._process.start()
        there.close()
        self._conn = here
        log.info("empty scene: a worker process (pid %d) runs it beside the probes", self._process.pid)

    def _receive(self, message) -> None:
        kind, direction, value = message
        if kind == "ready":  # set up: it may take a probe
            self._ready = True
            return
        self.running = None
        if kind == "means":
            self.means[direction] = value
            self.progress.done_elsewhere(direction)
            return
        if kind == "diverged":  # rebuilt here: SimulationDiverged does not unpickle from its message alone
            step, reason, probe = value
            value = SimulationDiverged(step, reason)
            value.probe = probe
        self.errors.append(value)

    def raise_error(self) -> None:
        """Raise the first exception a worker's probe ended with (a diverged empty scene: ``SimulationDiverged`` with
        ``probe`` set, as this process's own would be)."""
        if self.errors:
            raise self.errors[0]

    def _lost(self) -> None:
        if self._dead:
            return
        self._dead = True
        code = None if self._process is None else self._process.exitcode
        log.warning(
            "the empty-scene worker process ended without its result (exit code %s); this process runs the rest "
            "(%s=0 keeps it here from the start)",
            code,
            PROCESS_ENV,
        )


def _worker_main(conn, initializer, plan, centers, reach, config, parent: int) -> None:
    """The worker: set up, then simulate each empty-scene probe it is sent until it gets None."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    die_with_parent(signal.SIGTERM)
    if os.getppid() != parent:  # the parent died before the line above
        return
    initializer()
    reference = EmptyReference.of(config)
    bar = RunProgress(plan, config, enabled=False)
    rec = ProbeRecorder(centers, reach, config, bar, "empty ", grid_bounds=plan.bounds)
    conn.send(("ready", None, None))
    while True:
        job = conn.recv()
        if job is None:
            return
        direction, probe_config = job
        try:
            means = empty_probe_means(direction, plan.setups[direction], probe_config, rec, reference)
            message = ("means", direction, means)
        except SimulationDiverged as exc:
            info = (exc.step, exc.reason, getattr(exc, "probe", f"empty-scene {direction}"))
            message = ("diverged", direction, info)
        except Exception as exc:  # noqa: BLE001 - sent to the parent, which raises it
            message = ("error", direction, _portable(exc))
        conn.send(message)


def _portable(exc: BaseException) -> BaseException:
    """``exc`` if it survives pickling, else a RuntimeError with its type and text."""
    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:  # noqa: BLE001 - any failure to pickle or rebuild
        return RuntimeError(f"{type(exc).__name__}: {exc}")
