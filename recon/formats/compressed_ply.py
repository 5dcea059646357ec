"""Reading the SuperSplat / PlayCanvas compressed ``.ply`` (the ``*.compressed.ply`` that SuperSplat exports).

Layout (binary PLY, little-endian as written by SuperSplat and splat-transform)::

    element chunk  ceil(N / 256)     float min_x min_y min_z max_x max_y max_z
                                     float min_scale_x min_scale_y min_scale_z max_scale_x max_scale_y max_scale_z
                                     [float min_r min_g min_b max_r max_g max_b]      (newer exports)
    element vertex N                 uint packed_position packed_rotation packed_scale packed_color
    [element sh N                    uchar f_rest_0 .. f_rest_{M-1}, M = 9, 24 or 45]

Splat ``i`` belongs to chunk ``i // 256``. With ``u(v, shift, bits) = ((v >> shift) & (2^bits - 1)) / (2^bits - 1)``:

- position: ``t = (u(p, 21, 11), u(p, 11, 10), u(p, 0, 11))``, ``x = min + t (max - min)`` per axis;
- log-scale: the same 11-10-11 split of ``packed_scale``, lerped between ``min_scale_*`` and ``max_scale_*``;
- colour: ``(r, g, b, a) = (u(c, 24, 8), u(c, 16, 8), u(c, 8, 8), u(c, 0, 8))``; ``r, g, b`` are lerped between
  ``min_r..max_r`` etc. when the chunk has colour bounds (else used as they are) and give the SH DC term
  ``(rgb - 0.5) / SH_C0``; ``a`` is the opacity itself, returned as its logit;
- rotation: the top 2 bits of ``packed_rotation`` name the largest component of the unit quaternion
  ``(rot_0, rot_1, rot_2, rot_3) = (w, x, y, z)`` (made positive); the other three follow in index order as
  10-bit codes ``v = (u - 0.5) * sqrt(2)`` (bits 20-29, 10-19, 0-9), and the largest is ``sqrt(1 - sum v^2)``;
- SH rest: ``f_rest_k`` codes ``q`` map to ``n = 0`` (q = 0), ``1`` (q = 255) or ``(q + 0.5) / 256`` and the
  coefficient is ``(n - 0.5) * 8``; ``f_rest`` is channel-major as in the standard 3DGS .ply.

The frame is the file's own (the standard 3DGS .ply frame); nothing is flipped. Every layout problem raises
``ValueError`` naming the file, before the data is read: element sizes against the file size, the chunk count
against ``ceil(N / 256)``, property types, and the ``sh`` element against the vertex count.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..gaussians import SH_C0, GaussianSet
from .arrays import gaussians_from_arrays, opacity_logits_from_unit
from .ply import PlyLayout, parse_ply_header, read_binary_elements

CHUNK_SIZE = 256
CHUNK_BOUNDS = (
    "min_x",
    "min_y",
    "min_z",
    "max_x",
    "max_y",
    "max_z",
    "min_scale_x",
    "min_scale_y",
    "min_scale_z",
    "max_scale_x",
    "max_scale_y",
    "max_scale_z",
)
CHUNK_COLORS = ("min_r", "min_g", "min_b", "max_r", "max_g", "max_b")
PACKED = ("packed_position", "packed_rotation", "packed_scale", "packed_color")
SH_REST_COUNTS = {9: 1, 24: 2, 45: 3}  # f_rest columns -> SH degree
GAUSSIAN_ELEMENTS = ("chunk", "vertex", "sh")
# slots[w] = the three quaternion indices other than the largest one w, in the order they are packed
_SMALL_SLOTS = np.array([[j for j in range(4) if j != w] for w in range(4)])


def is_compressed_layout(layout: PlyLayout) -> bool:
    """Whether a PLY header is the compressed layout: a ``chunk`` element and ``packed_*`` vertex properties."""
    vertex = layout.element("vertex")
    if layout.element("chunk") is None or vertex is None:
        return False
    names = {p for p, _ in vertex.properties}
    return all(p in names for p in PACKED)


def load_compressed_ply(path: str | Path) -> GaussianSet:
    """Read a compressed ``.ply`` (layout in the module docstring) as a :class:`~recon.gaussians.GaussianSet`.

    Args:
        path: the file.
    Returns:
        A float32 GaussianSet on the CPU: means [N, 3], (w, x, y, z) quats [N, 4], log-scales [N, 3], opacity
        logits [N] and SH [N, K, 3] (K = 1 without an ``sh`` element, else 4, 9 or 16).
    Raises:
        ValueError: not the compressed layout, wrong property types, a chunk count other than ceil(N / 256), SH
            data that does not match the header, truncated data, or decoded values that fail the set's check.
    """
    source = str(path)
    with open(path, "rb") as fh:
        layout = parse_ply_header(fh, source)
    sh_count = _check_layout(layout, source)
    names = tuple(n for n in GAUSSIAN_ELEMENTS if layout.element(n) is not None)
    _, rows = read_binary_elements(path, names)
    chunk, vertex = rows["chunk"], rows["vertex"]
    n = vertex.shape[0]
    index = np.arange(n) // CHUNK_SIZE
    bounds = {p: chunk[p].astype(np.float32)[index] for p in CHUNK_BOUNDS + CHUNK_COLORS if p in chunk.dtype.names}
    means = _lerp_111011(vertex["packed_position"], bounds, ("x", "y", "z"), "{}_{}")
    log_scales = _lerp_111011(vertex["packed_scale"], bounds, ("x", "y", "z"), "{}_scale_{}")
    dc, opacity = _decode_color(vertex["packed_color"], bounds)
    sh = np.zeros((n, 1 + (sh_count // 3 if sh_count else 0), 3), np.float32)
    sh[:, 0] = dc
    if sh_count:
        sh[:, 1:] = _decode_sh(rows["sh"], sh_count)
    return gaussians_from_arrays(
        source, means, decode_rotation(vertex["packed_rotation"]), log_scales, opacity_logits_from_unit(opacity), sh
    )


def _check_layout(layout: PlyLayout, source: str) -> int:
    """Validate the header; return the number of SH rest columns (0 when there is no ``sh`` element)."""
    if not is_compressed_layout(layout):
        raise ValueError(
            f"{source}: not a compressed .ply: it needs a 'chunk' element and vertex properties {list(PACKED)}"
        )
    chunk, vertex = layout.element("chunk"), layout.element("vertex")
    chunk_types = dict(chunk.properties)
    missing = [p for p in CHUNK_BOUNDS if p not in chunk_types]
    colors = [p for p in CHUNK_COLORS if p in chunk_types]
    if missing or colors and len(colors) != len(CHUNK_COLORS):
        need = missing or [p for p in CHUNK_COLORS if p not in chunk_types]
        raise ValueError(f"{source}: the compressed .ply chunk element lacks {need}; re-export it from SuperSplat")
    wrong = [p for p, t in chunk.properties if p in CHUNK_BOUNDS + CHUNK_COLORS and t not in ("f4", "f8")]
    wrong += [p for p, t in vertex.properties if p in PACKED and t != "u4"]
    if wrong:
        raise ValueError(
            f"{source}: compressed .ply properties {wrong} have the wrong type (chunk bounds are float, "
            f"packed_* are uint)"
        )
    expected_chunks = math.ceil(vertex.count / CHUNK_SIZE)
    if chunk.count != expected_chunks:
        raise ValueError(
            f"{source}: the compressed .ply has {chunk.count} chunks for {vertex.count} splats; "
            f"expected ceil({vertex.count} / {CHUNK_SIZE}) = {expected_chunks} (corrupt header)"
        )
    sh = layout.element("sh")
    if sh is None:
        return 0
    names = [p for p, _ in sh.properties]
    if (
        len(names) not in SH_REST_COUNTS
        or names != [f"f_rest_{i}" for i in range(len(names))]
        or any(t != "u1" for _, t in sh.properties)
        or sh.count != vertex.count
    ):
        raise ValueError(
            f"{source}: SH data does not match the header: the 'sh' element has {sh.count} rows of "
            f"{len(names)} properties; expected {vertex.count} rows (one per splat) of uchar "
            f"f_rest_0..f_rest_{{8, 23 or 44}}; re-export the file"
        )
    return len(names)


def unpack_unorm(words: np.ndarray, shift: int, bits: int) -> np.ndarray:
    """The ``bits``-bit field at ``shift`` of uint32 ``words`` as a float32 in [0, 1]."""
    top = (1 << bits) - 1
    return ((words >> np.uint32(shift)) & np.uint32(top)).astype(np.float32) / np.float32(top)


def _lerp_111011(words: np.ndarray, bounds: dict[str, np.ndarray], axes: tuple[str, ...], key: str) -> np.ndarray:
    """Decode 11-10-11 words [N] between per-splat bounds ``key.format('min'|'max', axis)`` -> [N, 3]."""
    out = np.empty((words.shape[0], 3), np.float32)
    for j, (axis, (shift, bits)) in enumerate(zip(axes, ((21, 11), (11, 10), (0, 11)), strict=True)):
        t = unpack_unorm(words, shift, bits)
        lo, hi = bounds[key.format("min", axis)], bounds[key.format("max", axis)]
        with np.errstate(invalid="ignore", over="ignore"):  # NaN/Inf bounds: reported by the set's check
            out[:, j] = lo * (1 - t) + hi * t
    return out


def _decode_color(words: np.ndarray, bounds: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """SH DC [N, 3] and opacity [N] in [0, 1] from 8-8-8-8 colour words."""
    rgb = np.stack([unpack_unorm(words, s, 8) for s in (24, 16, 8)], 1)
    if "min_r" in bounds:
        for j, c in enumerate("rgb"):
            lo, hi = bounds[f"min_{c}"], bounds[f"max_{c}"]
            rgb[:, j] = lo * (1 - rgb[:, j]) + hi * rgb[:, j]
    return (rgb - 0.5) / np.float32(SH_C0), unpack_unorm(words, 0, 8)


def decode_rotation(words: np.ndarray) -> np.ndarray:
    """Unit (w, x, y, z) quaternions [N, 4] from 2-10-10-10 "largest index + smallest three" uint32 words [N]."""
    small = np.stack([(unpack_unorm(words, s, 10) - 0.5) * np.float32(math.sqrt(2.0)) for s in (20, 10, 0)], 1)
    largest = (words >> np.uint32(30)).astype(np.int64)
    quats = np.empty((words.shape[0], 4), np.float32)
    rows = np.arange(words.shape[0])
    quats[rows[:, None], _SMALL_SLOTS[largest]] = small
    quats[rows, largest] = np.sqrt(np.maximum(0.0, 1.0 - (small * small).sum(1)))
    return quats


def _decode_sh(table: np.ndarray, count: int) -> np.ndarray:
    """SH rest coefficients [N, K-1, 3] from the uchar ``sh`` rows (channel-major f_rest columns)."""
    q = np.stack([table[f"f_rest_{i}"] for i in range(count)], 1).astype(np.float32)
    unit = np.where(q == 0, 0.0, np.where(q == 255, 1.0, (q + 0.5) / 256.0))
    values = ((unit - 0.5) * 8.0).astype(np.float32)
    return values.reshape(q.shape[0], 3, count // 3).transpose(0, 2, 1)
