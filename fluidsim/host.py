"""The machine this process runs on: the memory it may still allocate, and how its child processes are tied to it
(standard library only, so that ``fluidsim``, ``recon`` and ``nbv`` share one answer without importing Taichi or
torch).

No paper equation: the memory checks before a run (:mod:`fluidsim.memory`, :mod:`nbv.physics.memory`) and the
decode budget of the Gaussian-file readers (:mod:`recon.inflate`) read it; the process pools of the studies, the
empty-scene worker and the forked scoring shares use the rest.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import resource
import signal
from collections.abc import Iterator

PR_SET_PDEATHSIG = 1  # Linux prctl option: the signal a child gets when its parent dies


def die_with_parent(signum: int) -> None:
    """In a child process: receive ``signum`` when the parent dies (Linux ``PR_SET_PDEATHSIG``; elsewhere nothing).
    The caller then checks ``os.getppid()``: a parent that died before this call is not signalled."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signum)


@contextlib.contextmanager
def hangup_shielded() -> Iterator[None]:
    """While entered, SIGHUP is blocked in this thread, so the processes it starts inherit the block: a closed terminal
    sends SIGHUP to the whole process group, and workers (and a resource tracker, which ignores only SIGINT and
    SIGTERM) must be stopped by their parent, not killed halfway. A SIGHUP that arrives meanwhile is delivered to this
    process when the block ends."""
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGHUP})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def available_memory_bytes() -> int:
    """The memory this process may still allocate, bytes: ``MemAvailable`` of /proc/meminfo (else the physical
    memory), lowered to what an address-space limit (``ulimit -v``, RLIMIT_AS) leaves above the process's current
    size.

    Example:
        >>> available_memory_bytes() > 0
        True
    """
    available = None
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    available = int(line.split()[1]) * 1024
    except OSError:
        pass
    if available is None:
        available = int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    limit = resource.getrlimit(resource.RLIMIT_AS)[0]
    if limit != resource.RLIM_INFINITY:
        available = min(available, max(0, limit - virtual_size_bytes()))
    return available


def virtual_size_bytes() -> int:
    """This process's address space now (``VmSize`` of /proc/self/status), bytes; 0 where it cannot be read."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmSize:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0
