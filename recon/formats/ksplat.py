"""Reading mkkellogg GaussianSplats3D ``.ksplat`` files (its ``SplatBuffer``, version 0.1), compression modes 0-2.

Layout, little-endian:

- a 4096-byte main header: ``u8 major (0), u8 minor (>= 1)``, ``u32 maxSectionCount`` at byte 4, ``u32
  splatCount`` at 16, ``u16 compressionLevel`` at 20, ``f32 minSH, maxSH`` at 36 and 40 (mode 2's SH range; 0
  means the default -1.5 / 1.5);
- ``maxSectionCount`` section headers of 1024 bytes: ``u32 splatCount, maxSplatCount, bucketCapacity,
  bucketCount``, ``f32 spatialBlockSize`` at 16, ``u16 bucketStorageSize`` at 20, ``u32 quantizationRange`` at 24
  (0: the mode's default, 1 or 32767), ``u32 fullBucketCount, partialBucketCount`` at 32 and 36, ``u16 shDegree``
  at 40;
- per section, back to back: ``partialBucketCount`` u32 sizes of the partial buckets, ``bucketCount`` bucket
  centres (``bucketStorageSize`` bytes each, 3 f32), then ``maxSplatCount`` records.

A record holds the centre, the linear scales, the (w, x, y, z) quaternion, RGBA bytes and the SH coefficients
beyond DC: mode 0 as f32 (12 + 12 + 16 + 4 + 4 S bytes), modes 1 and 2 as f16 (6 + 6 + 8 + 4 bytes), with SH as
f16 (mode 1) or bytes ``minSH + b / 255 (maxSH - minSH)`` (mode 2). In modes 1 and 2 the centre is a u16 per
axis: ``x = (u - range) * blockSize / 2 / range + bucketCentre``, the bucket of record i being ``i //
bucketCapacity`` for the full buckets, then the partial buckets in order. Colour is ``rgb = 0.5 + SH_C0 f_dc``
and alpha the opacity, both times 255. The SH values of a record are grouped by band, then by colour channel
within a band (band 1: r0 r1 r2 g0 g1 g2 b0 b1 b2; band 2: r3..r7, g3..g7, b3..b7), as splat-transform reads them.

**Frame.** The file keeps the .ply frame of the capture it was converted from; nothing is turned.
**Bounds.** Every section's size is computed from its header and compared with the file size, and the count
with the memory budget (:mod:`recon.inflate`), before any array is allocated.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from ..gaussians import SH_C0, GaussianSet
from ..inflate import check_budget
from .arrays import check_positive_scales, gaussians_from_arrays, opacity_logits_from_unit

MAIN_HEADER_BYTES = 4096
SECTION_HEADER_BYTES = 1024
MODES = {
    0: {"center": 12, "scale": 12, "rotation": 16, "sh": 4, "range": 1},
    1: {"center": 6, "scale": 6, "rotation": 8, "sh": 2, "range": 32767},
    2: {"center": 6, "scale": 6, "rotation": 8, "sh": 1, "range": 32767},
}
SH_COMPONENTS = {0: 0, 1: 9, 2: 24, 3: 45}
DEFAULT_SH_RANGE = (-1.5, 1.5)
DECODED_BYTES_PER_SPLAT = 4 * (3 + 4 + 3 + 1 + 16 * 3)
FIX = "re-export it (gaussforge, splat-transform or the GaussianSplats3D converter write .ksplat)"


def sh_component_order(degree: int) -> np.ndarray:
    """[3 (K-1)] the channel-major ``f_rest`` index of each stored SH value of a record of SH degree ``degree``."""
    order = []
    for start, width in ((0, 3), (3, 5), (8, 7))[:degree]:
        for channel in range(3):
            for j in range(width):
                order.append(channel * (SH_COMPONENTS[degree] // 3) + start + j)
    return np.array(order, np.int64)


def load_ksplat(path: str | Path) -> GaussianSet:
    """Read a ``.ksplat`` file (layout in the module docstring).

    Returns:
        A float32 GaussianSet on the CPU in the file's frame: means [N, 3], (w, x, y, z) quats [N, 4],
        log-scales [N, 3], opacity logits [N], SH [N, K, 3] (the highest SH degree of any section; a section of a
        lower degree gets zeros for the higher bands).
    Raises:
        ValueError: naming the file: an unknown version or compression mode, a truncated header or section, counts
            that disagree, or sizes over the memory budget.
    """
    source = str(path)
    data = Path(path).read_bytes()
    if len(data) < MAIN_HEADER_BYTES:
        raise ValueError(
            f"{source}: truncated .ksplat: {len(data)} bytes, less than its {MAIN_HEADER_BYTES}-byte header; {FIX}"
        )
    major, minor = data[0], data[1]
    if major != 0 or minor < 1:
        raise ValueError(f"{source}: .ksplat version {major}.{minor} is not supported (0.1 and later 0.x are); {FIX}")
    (max_sections,) = struct.unpack_from("<I", data, 4)
    (n,) = struct.unpack_from("<I", data, 16)
    (mode,) = struct.unpack_from("<H", data, 20)
    if mode not in MODES:
        raise ValueError(f"{source}: .ksplat compression mode {mode} is unknown (modes 0, 1 and 2 are defined); {FIX}")
    if n == 0:
        raise ValueError(f"{source}: the .ksplat holds 0 Gaussians")
    sh_lo, sh_hi = struct.unpack_from("<ff", data, 36)
    sh_lo, sh_hi = (sh_lo or DEFAULT_SH_RANGE[0]), (sh_hi or DEFAULT_SH_RANGE[1])
    headers_end = MAIN_HEADER_BYTES + max_sections * SECTION_HEADER_BYTES
    if headers_end > len(data):
        raise ValueError(
            f"{source}: truncated .ksplat: {max_sections} section headers need {headers_end} bytes, the "
            f"file has {len(data)}; {FIX}"
        )
    check_budget(source, f"{n} .ksplat splats", n * DECODED_BYTES_PER_SPLAT)
    sections = [_section_header(data, i) for i in range(max_sections)]
    degrees = [s["degree"] for s in sections if s["count"]]
    for i, s in enumerate(sections):
        if s["degree"] not in SH_COMPONENTS:
            raise ValueError(
                f"{source}: .ksplat section {i} declares SH degree {s['degree']} (0-3 are possible); {FIX}"
            )
    if sum(s["count"] for s in sections) != n:
        raise ValueError(
            f"{source}: corrupt .ksplat: its sections hold {sum(s['count'] for s in sections)} splats, "
            f"the header declares {n}; {FIX}"
        )
    degree = max(degrees, default=0)
    parts, offset = [], headers_end
    for i, s in enumerate(sections):
        decoded, offset = _read_section(data, offset, i, s, mode, (sh_lo, sh_hi), degree, source)
        if decoded is not None:
            parts.append(decoded)
    arrays = [np.concatenate([p[k] for p in parts]) for k in range(5)]
    return gaussians_from_arrays(source, *arrays)


def _section_header(data: bytes, index: int) -> dict[str, float]:
    at = MAIN_HEADER_BYTES + index * SECTION_HEADER_BYTES
    count, capacity_max, bucket_capacity, bucket_count = struct.unpack_from("<IIII", data, at)
    (block,) = struct.unpack_from("<f", data, at + 16)
    (bucket_bytes,) = struct.unpack_from("<H", data, at + 20)
    (quant,) = struct.unpack_from("<I", data, at + 24)
    full, partial = struct.unpack_from("<II", data, at + 32)
    (degree,) = struct.unpack_from("<H", data, at + 40)
    return {
        "count": count,
        "max": capacity_max,
        "capacity": bucket_capacity,
        "buckets": bucket_count,
        "block": block,
        "bucket_bytes": bucket_bytes,
        "quant": quant,
        "full": full,
        "partial": partial,
        "degree": degree,
    }


def _read_section(
    data: bytes, offset: int, index: int, s: dict, mode: int, sh_range: tuple[float, float], degree: int, source: str
):
    """The decoded arrays of one section and the offset after it."""
    m = MODES[mode]
    components = SH_COMPONENTS[s["degree"]]
    record = m["center"] + m["scale"] + m["rotation"] + 4 + components * m["sh"]
    if s["count"] > s["max"]:
        raise ValueError(
            f"{source}: corrupt .ksplat section {index}: {s['count']} splats, more than its capacity {s['max']}; {FIX}"
        )
    bucket_meta = 4 * s["partial"]
    bucket_storage = s["bucket_bytes"] * s["buckets"] + bucket_meta
    end = offset + bucket_storage + record * s["max"]
    if end > len(data):
        raise ValueError(
            f"{source}: truncated .ksplat: section {index} ({s['max']} records of {record} bytes and "
            f"{bucket_storage} bytes of buckets) ends at byte {end}, the file has {len(data)}; {FIX}"
        )
    n = s["count"]
    if n == 0:
        return None, end
    rows = np.frombuffer(data, np.uint8, count=record * n, offset=offset + bucket_storage).reshape(n, record)
    float_type = "<f4" if mode == 0 else "<f2"
    width = 4 if mode == 0 else 2

    def floats(start: int, count: int) -> np.ndarray:
        return np.ascontiguousarray(rows[:, start : start + count * width]).view(float_type).astype(np.float32)

    if mode == 0:
        means = floats(0, 3)
    else:
        means = _bucketed_means(data, offset, rows, s, m, index, source)
    scales = floats(m["center"], 3)
    quats = floats(m["center"] + m["scale"], 4)
    colour_at = m["center"] + m["scale"] + m["rotation"]
    rgba = rows[:, colour_at : colour_at + 4].astype(np.float32) / 255.0
    what = f".ksplat splats of section {index}"
    check_positive_scales(source, scales, what, f"a .ksplat stores positive standard deviations; {FIX}")
    dc = (rgba[:, :3] - 0.5) / np.float32(SH_C0)
    sh = np.zeros((n, (degree + 1) ** 2, 3), np.float32)
    sh[:, 0] = dc
    if components:
        at = colour_at + 4
        if mode == 2:
            raw = rows[:, at : at + components].astype(np.float32)
            values = sh_range[0] + raw / 255.0 * (sh_range[1] - sh_range[0])
        else:
            values = floats(at, components)
        flat = np.zeros((n, components), np.float32)
        flat[:, sh_component_order(s["degree"])] = values
        k = components // 3
        sh[:, 1 : k + 1] = flat.reshape(n, 3, k).transpose(0, 2, 1)  # channel-major f_rest -> [N, K-1, 3]
    logits = opacity_logits_from_unit(rgba[:, 3])
    return (means, quats, np.log(scales), logits, sh), end


def _bucketed_means(
    data: bytes, offset: int, rows: np.ndarray, s: dict, m: dict, index: int, source: str
) -> np.ndarray:
    """Centres of a mode-1/2 section: u16 offsets from the centre of each record's bucket."""
    n = rows.shape[0]
    quant = s["quant"] or m["range"]
    partial_sizes = np.frombuffer(data, "<u4", count=s["partial"], offset=offset).astype(np.int64)
    centres = np.frombuffer(data, "<f4", count=3 * s["buckets"], offset=offset + 4 * s["partial"]).reshape(-1, 3)
    if s["bucket_bytes"] != 12:
        raise ValueError(
            f"{source}: .ksplat section {index} stores buckets of {s['bucket_bytes']} bytes; 12 (three "
            f"f32) are defined; {FIX}"
        )
    full_splats = s["full"] * s["capacity"]
    ends = full_splats + np.cumsum(partial_sizes)
    if s["full"] + s["partial"] > s["buckets"] or (n > full_splats and (len(ends) == 0 or ends[-1] < n)):
        raise ValueError(
            f"{source}: corrupt .ksplat section {index}: its {s['full']} full and {s['partial']} partial "
            f"buckets do not cover its {n} splats ({s['buckets']} buckets stored); {FIX}"
        )
    i = np.arange(n)
    bucket = np.where(i < full_splats, i // max(s["capacity"], 1), s["full"] + np.searchsorted(ends, i, side="right"))
    raw = np.ascontiguousarray(rows[:, :6]).view("<u2").astype(np.float32)
    return (raw - quant) * np.float32(s["block"] / 2.0 / quant) + centres[bucket]
