"""The machine this process runs on: the memory it may still allocate (standard library only, so that ``fluidsim``,
``recon`` and ``nbv`` share one answer without importing Taichi or torch).

No paper equation: the memory checks before a run (:mod:`fluidsim.memory`, :mod:`nbv.physics.memory`) and the
decode budget of the Gaussian-file readers (:mod:`recon.inflate`) read it.
"""

from __future__ import annotations

import os
import resource


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
