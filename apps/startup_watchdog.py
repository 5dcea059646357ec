"""Start-up watchdog. Under heavy load, Taichi's start-up has been seen to deadlock in its thread pool (about one
start in 25 at a load of 6 on 2 cores), leaving the command frozen with no output. ``ti.init`` and a first
parallel kernel therefore run under :func:`startup_watchdog`: a small separate process that, when the start-up
has not ended within ``STARTUP_TIMEOUT_S`` seconds (the environment variable ``FLUIDGS_TAICHI_START_TIMEOUT``
changes it; 0 turns the watch off), writes one line saying so and how to retry, then stops the command (SIGTERM,
then SIGKILL 5 s later, since a thread stuck in C++ runs no Python signal handler). A separate process, because
a deadlocked start-up may hold the GIL, which a watchdog thread would need.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager

STARTUP_TIMEOUT_S = 120.0
TIMEOUT_ENV = "FLUIDGS_TAICHI_START_TIMEOUT"
# the watchdog process: argv = parent pid, timeout s, message; the parent writes a byte (or dies) when started
_WATCHDOG = """
import os, select, signal, sys, time
pid, timeout, message = int(sys.argv[1]), float(sys.argv[2]), sys.argv[3]
ready, _, _ = select.select([sys.stdin], [], [], timeout)
if not ready:
    sys.stderr.write(message + "\\n")
    sys.stderr.flush()
    os.kill(pid, signal.SIGTERM)
    time.sleep(5)
    try:
        os.kill(pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
"""


def startup_timeout() -> float:
    """Seconds the start-up may take: ``FLUIDGS_TAICHI_START_TIMEOUT`` when set (0: no watch), else
    STARTUP_TIMEOUT_S; a value that is not a number >= 0 is a ValueError naming the variable."""
    raw = os.environ.get(TIMEOUT_ENV)
    if raw is None or not raw.strip():
        return STARTUP_TIMEOUT_S
    try:
        value = float(raw)
    except ValueError:
        value = -1.0
    if not value >= 0:
        raise ValueError(f"{TIMEOUT_ENV}={raw!r} must be a number of seconds >= 0 (0: no start-up watch)")
    return value


@contextmanager
def startup_watchdog(timeout: float | None = None, what: str = "Taichi") -> Iterator[None]:
    """Run the block under the start-up watchdog (module docstring): when it has not ended within ``timeout``
    seconds (None: :func:`startup_timeout`; 0: no watch), one line on stderr says so and how to retry, and the
    process is stopped."""
    timeout = startup_timeout() if timeout is None else float(timeout)
    if timeout <= 0:
        yield
        return
    message = (
        f"ERROR fluidgs: {what} has not started within {timeout:g} s (its thread pool can deadlock under heavy "
        "load); the command is stopped: run it again, on a less loaded machine if it recurs "
        f"({TIMEOUT_ENV} sets the limit in seconds, 0 turns the watch off)"
    )
    watchdog = subprocess.Popen(
        [sys.executable, "-c", _WATCHDOG, str(os.getpid()), repr(timeout), message], stdin=subprocess.PIPE
    )
    try:
        yield
    finally:
        try:
            watchdog.stdin.write(b"1")
            watchdog.stdin.close()
        except OSError:
            pass
        watchdog.wait(timeout=30)
