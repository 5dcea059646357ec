"""One policy for SIGINT, SIGTERM and SIGHUP in every `fluidgs` command: what a signal stops, and what it leaves behind.

- The first SIGINT (Ctrl-C), SIGTERM (``kill``, ``timeout``, a batch scheduler) or SIGHUP (a closed terminal, a dropped
  ssh session) raises :class:`Stopped` in the main thread, a ``KeyboardInterrupt`` that remembers the signal: every
  ``finally`` block of the command runs (temporary files are dropped, worker processes terminated), and `fluidgs` exits
  128 + the signal number (130 for SIGINT, 143 for SIGTERM, 129 for SIGHUP) with one line, no traceback. A SIGHUP that
  was ignored when the command started (``nohup``) stays ignored (:func:`handled_signals`). `fluidgs sim` first saves
  its frames so far (:class:`apps.sim.StopRequest`).
- A second signal while that clean-up runs is noted and ignored, so that it cannot interrupt the clean-up halfway and
  leave a half-written file; the exit code stays that of the first signal.
- A third signal removes this process's unfinished temporary files (:func:`fluidsim.files.remove_unfinished`) and
  exits at once, for a clean-up that hangs.

Whatever ends a command, `fluidgs` then removes the temporary files of this process that were never renamed into place
and the output folders it created that stayed empty. Worker processes (:func:`worker_signals`) leave SIGINT to their
parent (SIGHUP too: a closed terminal reaches the whole process group) and, on SIGTERM (their parent terminating them),
remove their unfinished files and exit at once.
"""

from __future__ import annotations

import logging
import os
import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager

log = logging.getLogger("fluidgs")
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def handled_signals() -> tuple[int, ...]:
    """The stop signals a command handles now: :data:`STOP_SIGNALS`, less SIGHUP when it is ignored (``nohup``: the
    user asked the command to outlive its terminal)."""
    return tuple(s for s in STOP_SIGNALS if not (s == signal.SIGHUP and signal.getsignal(s) == signal.SIG_IGN))


class Stopped(KeyboardInterrupt):
    """The command was stopped by ``signum`` (SIGINT, SIGTERM or SIGHUP); :attr:`exit_code` is 128 + ``signum``."""

    def __init__(self, signum: int) -> None:
        self.signum = int(signum)
        super().__init__(signal.Signals(self.signum).name)

    @property
    def exit_code(self) -> int:
        """130 for SIGINT, 143 for SIGTERM, 129 for SIGHUP (the shell's convention)."""
        return 128 + self.signum


def signal_name(signum: int) -> str:
    """ "SIGINT", "SIGTERM", ... for a signal number."""
    return signal.Signals(signum).name


class _State:
    first: int | None = None  # the first stop signal received
    lost: int | None = None  # a stop signal whose Stopped Python ignored (raised in a finalizer or weakref callback)
    count = 0
    exit_after = False  # set by the executable (apps.cli.entry): the process exits when the command returns


def exit_after_commands() -> None:
    """This process ends when its command returns (the executable, :func:`apps.cli.entry`): :func:`stop_signals`
    then leaves a handler that exits at once with the stop signal's code instead of restoring the previous ones, so a
    signal that lands during the exit (a second Ctrl-C after a quick save, a SIGTERM just after the end) gives 130 or
    143, not death by the signal."""
    _State.exit_after = True


def first_signal() -> int | None:
    """The first stop signal this process received (None: none yet)."""
    return _State.first


def lost_signal() -> int | None:
    """The stop signal whose :class:`Stopped` was raised where Python only reports an exception and goes on (a
    finalizer or weakref callback: h5py frees its objects there, so a Ctrl-C during HDF5 I/O can land in one), None
    when none was; the command then ends with that signal's code, not 0 (:func:`apps.exit_codes.run_module`)."""
    return _State.lost


def _note_unraisable(hook, unraisable) -> None:
    """sys.unraisablehook while a command runs: remember a lost :class:`Stopped`, then report as before."""
    if isinstance(unraisable.exc_value, Stopped) and _State.lost is None:
        _State.lost = unraisable.exc_value.signum
    hook(unraisable)


def note_signal(signum: int) -> int:
    """Record a stop signal; returns how many have arrived (1 for the first)."""
    _State.count += 1
    if _State.first is None:
        _State.first = int(signum)
    return _State.count


def _exit_now() -> None:
    from fluidsim.files import remove_unfinished

    remove_unfinished(created_folders=False)
    os._exit(128 + (_State.first or signal.SIGINT))


def _exit_at_once(signum: int, frame) -> None:
    """A stop signal after the command returned, while the process exits: its outputs are complete or removed
    already, so exit now, with the first stop signal's code (130 or 143), not killed with another status."""
    note_signal(signum)
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    _exit_now()


def handle(signum: int, frame) -> None:
    """The handler of :func:`stop_signals` (see the module docstring)."""
    count = note_signal(signum)
    name = signal.Signals(signum).name
    if count == 1:
        raise Stopped(signum)
    if count == 2:
        log.warning(
            "%s received again: already stopping and removing unfinished files (a third signal exits at once)", name
        )
        return
    _exit_now()


@contextmanager
def stop_signals() -> Iterator[None]:
    """While entered (in the main thread; elsewhere it does nothing), SIGINT, SIGTERM and SIGHUP (unless ignored, as
    under ``nohup``) follow :func:`handle`."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _State.first, _State.lost, _State.count = None, None, 0
    old = {sig: signal.signal(sig, handle) for sig in handled_signals()}
    hook = sys.unraisablehook
    sys.unraisablehook = lambda unraisable: _note_unraisable(hook, unraisable)
    try:
        yield
    finally:
        sys.unraisablehook = hook
        for sig, previous in old.items():  # in the executable, the process is ending: a late signal ends it now
            signal.signal(sig, _exit_at_once if _State.exit_after else previous)


def worker_signals() -> None:
    """In a worker process: ignore SIGINT and SIGHUP (a Ctrl-C or a closed terminal reaches the whole process group;
    the parent decides and terminates its workers), and on SIGTERM remove this process's unfinished files and exit at
    once (143)."""

    def on_term(signum: int, frame) -> None:
        note_signal(signum)
        _exit_now()

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGHUP, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, on_term)
