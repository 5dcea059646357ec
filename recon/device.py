"""The torch device a command runs on: the one CUDA-to-CPU fallback of the torch side.

Taichi's runtime has its own check (whether Taichi itself can start on CUDA), in ``apps.taichi_runtime.init_taichi``;
every torch caller (training, rendering, view scoring, the benchmarks) asks :func:`torch_device`.
"""

from __future__ import annotations

import logging

import torch

log = logging.getLogger(__name__)

DEVICES = ("cpu", "cuda")


def torch_device(requested: str) -> str:
    """The torch device to use for ``requested``: "cuda" when asked for and torch sees a CUDA device, else "cpu"
    (with a logged warning when "cuda" was asked for).

    Args:
        requested: "cpu" or "cuda" (``--device``); anything else is a ValueError naming ``--device``.
    Returns:
        "cpu" or "cuda".
    Example:
        >>> torch_device("cpu")
        'cpu'
    """
    if requested not in DEVICES:
        raise ValueError(f"--device must be cpu or cuda, got {requested!r}")
    if requested == "cuda" and not torch.cuda.is_available():
        log.warning("--device cuda requested but torch sees no CUDA device; running on the CPU")
        return "cpu"
    return requested
