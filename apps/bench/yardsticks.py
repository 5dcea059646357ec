"""The benchmarks' yardsticks of the machine: fixed matmul workloads timed next to the figures, and the peak memory.

Machines are shared, so a figure is quoted as a ratio, and these fixed workloads, timed before and after it, tell
whether the machine was slower meanwhile. Times in milliseconds, memory in bytes.
"""

from __future__ import annotations

import resource
import statistics
import time

import numpy as np
import torch


def reference_workload_ms(device: torch.device, repeats: int = 5) -> float:
    """Median ms of ten 512 x 512 float32 matmuls on ``device`` with the current torch threads, over ``repeats``
    timed rounds after one warm-up (`bench render`)."""
    gen = torch.Generator().manual_seed(0)
    a = torch.rand(512, 512, generator=gen).to(device)
    b = torch.rand(512, 512, generator=gen).to(device)
    times = []
    for _ in range(repeats + 1):
        t0 = time.perf_counter()
        for _ in range(10):
            a @ b
        if device.type == "cuda":
            torch.cuda.synchronize()
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times[1:])


def reference_ms() -> float:
    """Median ms of one single-thread 512 x 512 float32 matmul on the CPU, over 10 (`bench views`)."""
    a = torch.rand(512, 512)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        times = []
        for _ in range(10):
            t = time.perf_counter()
            a @ a
            times.append(1e3 * (time.perf_counter() - t))
    finally:
        torch.set_num_threads(threads)
    return float(np.median(times))


def peak_rss_bytes() -> int:
    """The process's peak resident memory so far, bytes (Linux reports KiB)."""
    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024
