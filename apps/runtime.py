"""Runtime helpers of the command-line tools: argparse types, and the Taichi set-up of :mod:`apps.taichi_runtime`.

``init_taichi``, ``check_threads`` and ``release_unreachable_arrays`` are re-exported from :mod:`apps.taichi_runtime`
on first use (PEP 562 module ``__getattr__``): importing it loads Taichi, which ``fluidgs --help`` and the
argparse types here never need. The tools and test fixtures are the only callers of ``init_taichi``.
"""

from __future__ import annotations

import argparse
import logging
from contextlib import contextmanager

_FROM_TAICHI_RUNTIME = ("check_threads", "init_taichi", "release_unreachable_arrays")
__all__ = [
    *_FROM_TAICHI_RUNTIME,
    "deterministic_torch",
    "positive_int",
    "setup_runtime",
    "thread_count",
]
log = logging.getLogger("fluidgs")


def __getattr__(name: str):
    if name in _FROM_TAICHI_RUNTIME:
        from . import taichi_runtime

        return getattr(taichi_runtime, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def positive_int(text: str) -> int:
    """argparse type of a count that must be >= 1 (``--threads``): ``"4"`` -> 4; ``"-1"``, ``"0"``, ``"x"`` are
    usage errors (exit 2) that say so, before anything is loaded."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1, got {value}")
    return value


def thread_count(text: str) -> int:
    """argparse type of ``--threads``: an integer from 1 to ``apps.taichi_runtime.MAX_THREADS`` (1024); anything else
    is a usage error (exit 2) at once."""
    from .taichi_runtime import MAX_THREADS

    value = positive_int(text)
    if value > MAX_THREADS:
        raise argparse.ArgumentTypeError(
            f"must be at most {MAX_THREADS} CPU threads, got {value} (leave it out for all cores)"
        )
    return value


@contextmanager
def deterministic_torch():
    """Run the block with ``torch.use_deterministic_algorithms(True, warn_only=True)``, then restore the setting."""
    import torch

    before = torch.are_deterministic_algorithms_enabled()
    warn_before = torch.is_deterministic_algorithms_warn_only_enabled()
    torch.use_deterministic_algorithms(True, warn_only=True)
    try:
        yield
    finally:
        torch.use_deterministic_algorithms(before, warn_only=warn_before)


def setup_runtime(device: str, threads: int | None, precision: str) -> str:
    """torch threads, Taichi runtime; returns the torch device actually used."""
    import torch

    from recon.device import torch_device

    from .taichi_runtime import init_taichi

    if threads is not None:
        if threads < 1:
            raise ValueError(f"--threads must be >= 1, got {threads}")
        torch.set_num_threads(threads)
    used = torch_device(device)
    init_taichi(used, precision, threads)
    return used
