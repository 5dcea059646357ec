"""nbv's file outputs, all atomic: RESULT.h5, PNGs, JSON, text, checkpoints (through :mod:`fluidsim.files`).

Every writer here, and every writer of the layers below, goes through :mod:`fluidsim.files`: a temporary
``.fgs-<8 hex>.tmp<suffix>`` file in the output's folder, renamed onto the output when it is complete, removed
when writing fails; an ``OSError`` becomes :class:`fluidsim.files.OutputError` naming the output (exit code 4 of
`fluidgs`). ``fluidsim.files`` holds the primitives: standard-library code in the lowest layer, importable
without Taichi (``fluidsim/__init__`` loads nothing eagerly) or torch, so ``fluidsim``, ``recon`` and ``viz`` use
them too; this module adds the writers that need h5py, OpenCV or a caller's own serialiser, and
re-exports the primitives, so nbv and the apps import their writers from one place.

Example:
    >>> with atomic_h5("result.h5") as f:                  # doctest: +SKIP
    ...     f["D"] = divergence
    >>> write_png_atomic("views.png", image_bgr)           # doctest: +SKIP
    >>> write_atomic("checkpoint.pt", lambda tmp: torch.save(state, tmp))  # doctest: +SKIP
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import cv2
import h5py
import numpy as np

from fluidsim.files import (
    OutputError,
    atomic_output,
    check_not_input,
    check_writable,
    json_safe,
    write_bytes_atomic,
    write_json_atomic,
    write_text_atomic,
)

__all__ = [
    "OutputError",
    "atomic_h5",
    "atomic_output",
    "check_not_input",
    "check_writable",
    "json_safe",
    "write_atomic",
    "write_bytes_atomic",
    "write_json_atomic",
    "write_png_atomic",
    "write_text_atomic",
]


def write_atomic(path: str | Path, write: Callable[[Path], None], suffix: str = "") -> Path:
    """Call ``write(tmp)`` on a temporary file next to ``path``, then rename it over ``path``; returns the path.

    The temporary file is removed when ``write`` raises, so no half-written file is ever left. ``suffix`` keeps
    an extension that ``write`` needs to pick its format.
    """
    with atomic_output(path, suffix) as tmp:
        write(tmp)
    return Path(path)


@contextmanager
def atomic_h5(path: str | Path) -> Iterator[h5py.File]:
    """An HDF5 file opened for writing that appears at ``path`` only when the block ends normally.

    :func:`fluidsim.files.check_writable` runs first (missing folders are created; an unwritable folder or a name too
    long raises :class:`OutputError` before anything is written).
    """
    p = check_writable(path)
    with atomic_output(p) as tmp, h5py.File(tmp, "w") as f:
        yield f


def write_png_atomic(path: str | Path, image: np.ndarray) -> Path:
    """Encode ``image`` as PNG with OpenCV and write it atomically; returns the path.

    Args:
        path: the .png file.
        image: (H, W) or (H, W, 3) BGR (or (H, W, 4) BGRA) uint8 or uint16, OpenCV's layout.
    Raises:
        ValueError: OpenCV cannot encode the image (its shape or dtype).
        OutputError: the file cannot be written.
    """
    image = np.ascontiguousarray(image)
    shape_ok = image.ndim == 2 or (image.ndim == 3 and image.shape[2] in (1, 3, 4))
    ok = shape_ok and image.dtype in (np.uint8, np.uint16) and image.size > 0
    if ok:
        ok, data = cv2.imencode(".png", image)
    if not ok:
        raise ValueError(
            f"{path}: OpenCV cannot encode an image of shape {image.shape} and dtype {image.dtype} as "
            "PNG; pass (H, W), (H, W, 3) or (H, W, 4) uint8 or uint16"
        )
    return write_bytes_atomic(path, data.tobytes())
