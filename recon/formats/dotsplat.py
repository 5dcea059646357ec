"""Reading antimatter15 ``.splat`` files (the WebGL splat viewer's format, github.com/antimatter15/splat).

The file has no header: it is N records of 32 bytes, little-endian::

    float32 x, y, z          the mean, scene units
    float32 sx, sy, sz       the standard deviations (linear, not log)
    uint8   r, g, b, a       colour in [0, 255]: rgb = 0.5 + SH_C0 * f_dc, a = 255 * opacity
    uint8   q0, q1, q2, q3   the (w, x, y, z) unit quaternion, q = 128 + 128 * component (clipped to 255)

so the reader returns ``log(s)``, the DC term ``(rgb / 255 - 0.5) / SH_C0``, the opacity logit (half a step off
0 and 1) and ``(q - 128) / 128`` as the quaternion. There is no SH beyond DC. The frame is the file's own (the
.ply frame of the capture it was converted from); nothing is flipped. A file is recognised by its ``.splat``
suffix and a size that is a whole number of records.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..gaussians import SH_C0, GaussianSet
from .arrays import check_positive_scales, gaussians_from_arrays, opacity_logits_from_unit

RECORD = np.dtype([("position", "<f4", (3,)), ("scale", "<f4", (3,)), ("rgba", "u1", (4,)), ("rotation", "u1", (4,))])
RECORD_BYTES = 32


def load_splat(path: str | Path) -> GaussianSet:
    """Read an antimatter15 ``.splat`` file (layout in the module docstring).

    Args:
        path: the file.
    Returns:
        A float32 GaussianSet on the CPU of SH degree 0: means [N, 3], (w, x, y, z) quats [N, 4], log-scales
        [N, 3], opacity logits [N], SH [N, 1, 3].
    Raises:
        ValueError: an empty file, a size that is not a multiple of 32 bytes (truncated), non-positive or
            non-finite scales, or decoded values that fail the set's check (NaN, Inf, a zero quaternion).
    """
    source = str(path)
    size = Path(path).stat().st_size
    if size == 0:
        raise ValueError(f"{source}: the .splat file is empty (0 Gaussians)")
    if size % RECORD_BYTES:
        raise ValueError(
            f"{source}: truncated .splat: {size} bytes is not a whole number of {RECORD_BYTES}-byte "
            f"records ({size % RECORD_BYTES} bytes left over); re-export or re-download the file"
        )
    records = np.fromfile(path, dtype=RECORD, count=size // RECORD_BYTES)
    scale = records["scale"]
    check_positive_scales(source, scale, "Gaussians", "a .splat stores positive standard deviations")
    rgba = records["rgba"].astype(np.float32) / 255.0
    dc = (rgba[:, :3] - 0.5) / np.float32(SH_C0)
    quats = (records["rotation"].astype(np.float32) - 128.0) / 128.0
    logits = opacity_logits_from_unit(rgba[:, 3])
    return gaussians_from_arrays(source, records["position"], quats, np.log(scale), logits, dc[:, None, :])
