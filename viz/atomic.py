"""Atomic file writes for the viz package: a temporary name in the output's folder, renamed into place.

The pattern is that of :func:`fluidsim.output.temp_path` (``.fgs-<8 hex>.tmp<suffix>``), restated here because
importing ``fluidsim`` loads Taichi, which viz never needs; a test keeps the two equal. A reader never sees a
half-written PNG or MP4, and a failed write leaves no temporary file behind.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

TEMP_PREFIX = ".fgs-"


def temp_path(path: str | os.PathLike, suffix: str = "") -> Path:
    """A fresh temporary name next to ``path``: ``.fgs-<8 hex>.tmp<suffix>`` in the same folder (``suffix`` keeps
    an extension a writer needs, e.g. ".mp4" for FFmpeg's container choice)."""
    p = Path(path)
    return p.parent / f"{TEMP_PREFIX}{uuid.uuid4().hex[:8]}.tmp{suffix}"


@contextmanager
def atomic_output(path: str | os.PathLike, suffix: str = "") -> Iterator[Path]:
    """Yield a :func:`temp_path` next to ``path``; rename it onto ``path`` when the block ends normally, remove it
    when the block raises.

    Example:
        >>> with atomic_output("plot.png", ".png") as tmp:  # doctest: +SKIP
        ...     tmp.write_bytes(data)
    """
    tmp = temp_path(path, suffix)
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; returns ``Path(path)``. An ``OSError`` keeps its errno and names
    the path."""
    path = Path(path)
    try:
        with atomic_output(path, path.suffix) as tmp:
            tmp.write_bytes(data)
    except OSError as exc:
        raise OSError(exc.errno, f"cannot write {path}: {exc.strerror or exc}; free disk space or choose a "
                      "writable output path") from exc
    return path
