"""Cameras shared among CPU workers: the view scores and the centre counts run each worker's share of the cameras
side by side, the first share on the calling thread.

Each camera is a few hundred small torch operations, and a thread holds the interpreter lock between them: two threads
scored 60 views of a 1.09M-Gaussian capture in 0.91x the time of one, two forked processes in 0.60x (2026-12-06, the
2-core VM). So on Linux, where ``fork`` is safe for torch's CPU ops run inline, a large share runs in a forked child
that sends its result back pickled through a pipe; elsewhere, for small work, or with ``FLUIDGS_SCORING_PROCESSES=0``,
the shares run on threads. The work per camera is the same code either way, so the results are the same bits.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import signal
import sys
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from fluidsim.host import die_with_parent

PROCESSES_ENV = "FLUIDGS_SCORING_PROCESSES"
FORK_MIN_PAIRS = 20_000_000  # (Gaussian, camera) pairs below which a fork (milliseconds) is not worth it


def camera_shares(work: Callable[[range], Any], count: int, workers: int, name: str, pairs: int = 0) -> list:
    """``work`` of each of ``workers`` shares of ``count`` cameras, interleaved (similar views per share), in share
    order; ``pairs``: Gaussians x cameras, which decides between forked processes and threads (module docstring)."""
    shares = [range(i, count, workers) for i in range(workers)]
    if workers == 1:
        return [work(shares[0])]
    if pairs >= FORK_MIN_PAIRS and forking():
        return _forked(work, shares)
    with ThreadPoolExecutor(workers, thread_name_prefix=name) as pool:
        return list(pool.map(work, shares))


def forking() -> bool:
    """Whether large shares run in forked processes: on Linux, unless ``FLUIDGS_SCORING_PROCESSES=0``."""
    return sys.platform.startswith("linux") and os.environ.get(PROCESSES_ENV, "1").strip() != "0"


def _forked(work: Callable[[range], Any], shares: list[range]) -> list:
    """The first share here, each other one in a forked child; a child still running when this raises is killed."""
    children: list[tuple[int, int]] = []
    try:
        parent = os.getpid()
        for share in shares[1:]:
            read_end, write_end = os.pipe()
            pid = os.fork()
            if pid == 0:
                os.close(read_end)
                _child(work, share, write_end, parent)
            os.close(write_end)
            children.append((pid, read_end))
        first = work(shares[0])
        return [first, *(_receive(pid, fd) for pid, fd in children)]
    finally:
        for pid, fd in children:
            with contextlib.suppress(OSError):
                os.close(fd)
            with contextlib.suppress(ChildProcessError):
                if os.waitpid(pid, os.WNOHANG) == (0, 0):
                    os.kill(pid, signal.SIGKILL)
                    os.waitpid(pid, 0)


def _child(work: Callable[[range], Any], share: range, fd: int, parent: int) -> None:
    """In the child: ``work(share)`` (or the exception it raised), pickled into ``fd``; leaves with ``os._exit``, so
    none of the parent's exit handlers or buffered output runs twice. Interrupts are the parent's to handle, and the
    child dies with it (``PR_SET_PDEATHSIG``), so a killed parent leaves no child scoring on."""
    code = 1
    try:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        die_with_parent(signal.SIGKILL)
        if os.getppid() != parent:  # the parent died before the line above
            return
        try:
            payload = ("result", work(share))
        except BaseException as exc:  # noqa: BLE001 - sent to the parent, which raises it
            payload = ("error", exc)
        try:
            data = pickle.dumps(payload, pickle.HIGHEST_PROTOCOL)
        except Exception:  # noqa: BLE001 - an exception that does not pickle goes as its text
            data = pickle.dumps(("error", RuntimeError(f"{type(payload[1]).__name__}: {payload[1]}")))
        with os.fdopen(fd, "wb") as out:
            out.write(data)
        code = 0
    finally:
        os._exit(code)


def _receive(pid: int, fd: int) -> Any:
    """A child's result, read to the end of its pipe; its exception is raised here."""
    with os.fdopen(os.dup(fd), "rb") as pipe:
        data = pipe.read()
    _, status = os.waitpid(pid, 0)
    if not data:
        raise RuntimeError(
            f"a scoring process ended without its result ({_ended(status)}); set {PROCESSES_ENV}=0 to score on "
            f"threads instead"
        )
    kind, value = pickle.loads(data)
    if kind == "error":
        raise value
    return value


def _ended(status: int) -> str:
    if os.WIFSIGNALED(status):
        return f"killed by signal {os.WTERMSIG(status)}, perhaps for memory"
    return f"exit status {os.waitstatus_to_exitcode(status)}"
