"""Runtime helpers of the command-line tools: argparse types, and the Taichi set-up of :mod:`apps.taichi_runtime`.

``init_taichi``, ``check_threads`` and ``release_unreachable_arrays`` are re-exported from :mod:`apps.taichi_runtime`
on first use (PEP 562 module ``__getattr__``): importing it loads Taichi, which ``fluidgs --help`` and the
argparse types here never need. The tools and test fixtures are the only callers of ``init_taichi``.
"""

from __future__ import annotations

import argparse

_FROM_TAICHI_RUNTIME = ("check_threads", "init_taichi", "release_unreachable_arrays")
__all__ = [*_FROM_TAICHI_RUNTIME, "positive_int"]


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
