"""Reading Niantic ``.spz`` files (github.com/nianticlabs/spz), versions 2, 3 and 4.

Containers:

- **versions 2 and 3**: one gzip stream holding a 16-byte header ``<u32 magic 0x5053474e ("NGSP"), u32 version,
  u32 numPoints, u8 shDegree, u8 fractionalBits, u8 flags, u8 reserved>`` and the attribute arrays back to back
  (a raw, un-gzipped stream of the same bytes is read too);
- **version 4**: a plain 32-byte header ``<u32 magic, u32 version, u32 numPoints, u8 shDegree, u8
  fractionalBits, u8 flags, u8 numStreams, u32 tocByteOffset, 12 reserved bytes>``, optional extension records
  up to ``tocByteOffset``, a table of ``numStreams`` pairs ``<u64 compressedSize, u64 uncompressedSize>``, then
  one zstd frame per non-empty attribute array, in the order below.

Attribute arrays, per point, in this order (N = numPoints, D = 0, 3, 8, 15 or 24 SH coefficients for degree 0-4):

- positions: N x 3 signed 24-bit little-endian fixed-point values, ``x = v / 2^fractionalBits``;
- alphas: N bytes, opacity ``a / 255`` (returned as its logit, half a step off 0 and 1);
- colors: N x 3 bytes, the SH DC term ``(c / 255 - 0.5) / 0.15``;
- scales: N x 3 bytes, log-scale ``s / 16 - 10``;
- rotations: version 2: N x 3 bytes ``(x, y, z) = r / 127.5 - 1`` of the unit quaternion with ``w >= 0``;
  version 3+: N little-endian uint32 "smallest three": bits 30-31 the index (in x, y, z, w order) of the
  largest component, then for the other three, the highest index in the lowest 10 bits, each as a sign bit
  (bit 9) and a 9-bit magnitude ``m``, value ``m / 511 / sqrt(2)``; the largest is ``sqrt(1 - sum v^2)``;
- SH: N x D x 3 bytes (coefficient outer, colour channel inner), ``(q - 128) / 128``.

Flag bit 0 marks antialiased training (ignored here); bit 1 marks extension records, which are skipped
(version 4: between the header and the table; versions 2-3: after the arrays, or, as some 2025 writers did,
between the header and the arrays). Degree-4 SH is cut to degree 3, the highest a GaussianSet holds.

**Frame.** SPZ stores right-up-back (RUB, the OpenGL convention); the standard 3DGS .ply frame is right-down-
front (RDF, COLMAP's). The two differ by a half turn about x: ``(x, y, z) -> (x, -y, -z)``, which keeps the
quaternion's ``w`` and ``x`` and negates ``y`` and ``z``, and flips the sign of the SH coefficients that are
odd in (y, z) (:data:`RUB_TO_RDF_SH_SIGNS`). :func:`load_spz` returns the RDF frame, as the reference
``spz_to_ply`` does, so a capture read from .spz lands where the same capture's .ply does (checked on a real
capture exported both ways: the same 152,746 Gaussians, positions within the two formats' quantisation).
splat-transform (and so SuperSplat) reads and writes .spz in the .ply frame without that turn, so files of both
kinds exist and nothing in the header tells them apart: ``frame="ply"`` reads the second kind as stored.
"""

from __future__ import annotations

import logging
import struct
import zlib
from pathlib import Path

import numpy as np

from ..gaussians import GaussianSet
from ..inflate import check_budget, inflate_zstd
from .arrays import check_declared_size, gaussians_from_arrays, opacity_logits_from_unit

log = logging.getLogger(__name__)

NGSP_MAGIC = b"NGSP"  # 0x5053474e little-endian
GZIP_MAGIC = b"\x1f\x8b"
LEGACY_HEADER = struct.Struct("<4sIIBBBB")  # 16 bytes
NGSP_HEADER = struct.Struct("<4sIIBBBBI12s")  # 32 bytes
TOC_ENTRY = struct.Struct("<QQ")
SUPPORTED_VERSIONS = (2, 3, 4)
SH_DIMS = {0: 0, 1: 3, 2: 8, 3: 15, 4: 24}  # SH degree -> coefficients per channel beyond DC
COLOR_SCALE = 0.15
FLAG_EXTENSIONS = 0x2
MAX_FRACTIONAL_BITS = 24
MAX_DEFLATE_RATIO = 1100  # deflate expands at most ~1032:1
MAX_ZSTD_RATIO = 1024  # the reference loader's bound on numPoints for a version-4 file of a given size
MAX_LEGACY_EXTENSION_BYTES = 1 << 20
# float32 arrays of the decoded set per point (means, quats, log-scales, opacity, SH up to degree 3)
DECODED_BYTES_PER_POINT = 4 * (3 + 4 + 3 + 1 + 16 * 3)
ATTRIBUTES = ("positions", "alphas", "colors", "scales", "rotations", "sh")
# sign of each real SH basis function (3DGS order, degrees 1-3) under (x, y, z) -> (x, -y, -z)
RUB_TO_RDF_SH_SIGNS = np.array(
    [
        -1,
        -1,
        1,  # y, z, x
        -1,
        1,
        1,
        -1,
        1,  # xy, yz, 3z^2-1, xz, x^2-y^2
        -1,
        1,
        -1,
        -1,
        1,
        -1,
        1,
    ],
    np.float32,
)  # y(3x^2-y^2), xyz, y(.), z(.), x(.), z(.), x(.)


SPZ_FRAMES = {
    "rub": "right-up-back as Niantic's specification defines it, turned half a turn about x to the .ply "
    "frame (Niantic's spz_to_ply does the same)",
    "ply": "the .ply frame, kept as stored (splat-transform and SuperSplat write and read .spz so)",
}


def load_spz(path: str | Path, frame: str = "rub") -> GaussianSet:
    """Read an ``.spz`` file (any of the containers in the module docstring) in the 3DGS .ply (RDF) frame.

    Args:
        path: the file.
        frame: what the file stores (:data:`SPZ_FRAMES`): "rub" (Niantic's definition, the default: turned half a
            turn about x) or "ply" (splat-transform's convention: kept). Nothing in the header tells them apart.
    Returns:
        A float32 GaussianSet on the CPU: means [N, 3] (scene units), (w, x, y, z) quats [N, 4], log-scales
        [N, 3], opacity logits [N] and SH [N, K, 3], K = 1, 4, 9 or 16.
    Raises:
        ValueError: not an .spz, an unsupported version, a corrupt gzip or zstd stream, a header whose sizes the
            file cannot hold, truncated data, or decoded values that fail the set's check.
    """
    source = str(path)
    if frame not in SPZ_FRAMES:
        raise ValueError(f"the .spz frame must be one of {sorted(SPZ_FRAMES)}, got {frame!r}")
    data = Path(path).read_bytes()
    if data[:2] == GZIP_MAGIC:
        header, arrays = _read_legacy(_gunzip_legacy(data, source), source)
    elif data[:4] == NGSP_MAGIC:
        version = struct.unpack_from("<I", data, 4)[0] if len(data) >= 8 else 0
        if version >= 4:
            header, arrays = _read_ngsp(data, source)
        else:
            header, arrays = _read_legacy(data, source)
    else:
        raise ValueError(f"{source}: not an .spz file (it starts with neither the gzip magic 1f 8b nor 'NGSP')")
    return _decode(arrays, header, source, turn=frame == "rub")


def _check_header(version: int, num_points: int, sh_degree: int, fractional_bits: int, source: str) -> None:
    if version not in SUPPORTED_VERSIONS:
        raise ValueError(
            f"{source}: .spz version {version} is not supported (versions {SUPPORTED_VERSIONS} are); "
            f"re-save it with a current spz library"
        )
    if sh_degree not in SH_DIMS:
        raise ValueError(f"{source}: .spz SH degree {sh_degree} is not 0-4 (corrupt header)")
    if fractional_bits > MAX_FRACTIONAL_BITS:
        raise ValueError(
            f"{source}: .spz fractionalBits {fractional_bits} exceeds {MAX_FRACTIONAL_BITS} (corrupt header)"
        )
    if num_points == 0:
        raise ValueError(f"{source}: the .spz holds 0 Gaussians")


def _attribute_sizes(n: int, version: int, sh_degree: int) -> dict[str, int]:
    """Bytes of each attribute array for ``n`` points."""
    return {
        "positions": 9 * n,
        "alphas": n,
        "colors": 3 * n,
        "scales": 3 * n,
        "rotations": (4 if version >= 3 else 3) * n,
        "sh": 3 * SH_DIMS[sh_degree] * n,
    }


def _check_sh_matches(source: str, n: int, version: int, degree: int, data_bytes: int) -> None:
    """Raise ``ValueError`` when ``data_bytes`` of arrays fit another SH degree than the header's ``degree``."""
    fits = [d for d in SH_DIMS if d != degree and sum(_attribute_sizes(n, version, d).values()) == data_bytes]
    if fits:
        raise ValueError(
            f"{source}: SH data does not match the header: it declares SH degree {degree} for {n} "
            f"points, but the {data_bytes} bytes of arrays are those of SH degree {fits[0]}; "
            f"re-export the .spz (or set the header's SH degree byte to {fits[0]})"
        )


def _check_fits(source: str, n: int, payload: int, file_bytes: int, ratio: int) -> None:
    """Reject a header whose ``n`` points could not come out of ``file_bytes`` compressed bytes (before inflating)."""
    if payload > file_bytes * ratio:
        raise ValueError(
            f"{source}: corrupt or truncated .spz: the header declares {n} points ({payload} bytes), "
            f"more than a {file_bytes}-byte file can hold even at a {ratio}:1 compression ratio"
        )


def _gunzip_legacy(data: bytes, source: str) -> bytes:
    """The decompressed bytes of a gzip-wrapped .spz, bounded by what its header declares."""
    stream = zlib.decompressobj(16 + zlib.MAX_WBITS)
    try:
        head = stream.decompress(data, LEGACY_HEADER.size)
        if len(head) < LEGACY_HEADER.size or head[:4] != NGSP_MAGIC:
            raise ValueError(f"{source}: a gzip stream whose content is not an .spz (no 'NGSP' header inside)")
        _, version, n, degree, bits, flags, _ = LEGACY_HEADER.unpack(head)
        _check_header(version, n, degree, bits, source)
        payload = sum(_attribute_sizes(n, version, degree).values())
        _check_fits(source, n, payload, len(data), MAX_DEFLATE_RATIO)
        check_budget(source, f"{n} points of SH degree {degree}", payload + n * DECODED_BYTES_PER_POINT)
        limit = payload + (MAX_LEGACY_EXTENSION_BYTES if flags & FLAG_EXTENSIONS else 0)
        body = stream.decompress(stream.unconsumed_tail, limit + 1)
    except zlib.error as exc:
        raise ValueError(f"{source}: corrupt gzip stream ({exc}); re-download or re-export the .spz") from None
    if len(body) > limit:
        most = max(sum(_attribute_sizes(n, version, d).values()) for d in SH_DIMS)
        try:
            rest = stream.decompress(stream.unconsumed_tail, max(0, most - len(body)) + 1)
        except zlib.error:
            rest = b""
        if not flags & FLAG_EXTENSIONS:
            _check_sh_matches(source, n, version, degree, len(body) + len(rest))
        raise ValueError(f"{source}: the gzip stream holds more data than the .spz header declares (corrupt)")
    if not stream.eof:
        where = (
            f"{len(body)} of {payload} bytes after the header"
            if len(body) < payload
            else "the gzip trailer with its checksum is missing"
        )
        raise ValueError(f"{source}: truncated .spz: the gzip stream ends early ({where}); re-download the file")
    if stream.unused_data:
        raise ValueError(f"{source}: {len(stream.unused_data)} stray bytes after the gzip stream (corrupt .spz)")
    return head + body


def _read_legacy(raw: bytes, source: str) -> tuple[tuple[int, ...], dict[str, np.ndarray]]:
    """Header fields and attribute byte arrays of a version 2-3 payload (16-byte header + arrays)."""
    if len(raw) < LEGACY_HEADER.size:
        raise ValueError(f"{source}: truncated .spz: {len(raw)} bytes, less than its 16-byte header")
    _, version, n, degree, bits, flags, _ = LEGACY_HEADER.unpack_from(raw)
    _check_header(version, n, degree, bits, source)
    sizes = _attribute_sizes(n, version, degree)
    payload = sum(sizes.values())
    available = len(raw) - LEGACY_HEADER.size
    if payload > available:
        _check_sh_matches(source, n, version, degree, available)
    check_declared_size(source, f"{n} points of SH degree {degree}", payload, available)
    offset = LEGACY_HEADER.size
    if flags & FLAG_EXTENSIONS and _is_extension_chain(raw, offset, available - payload):
        offset += available - payload  # extensions written between the header and the arrays
    return (version, n, degree, bits), _split(raw, offset, sizes)


def _is_extension_chain(raw: bytes, start: int, length: int) -> bool:
    """Whether ``raw[start:start + length]`` is exactly a run of ``<u32 type, u32 byteLength, payload>`` records."""
    end, pos = start + length, start
    while length > 0 and pos + 8 <= end:
        kind, size = struct.unpack_from("<II", raw, pos)
        if kind == 0:
            return False
        pos += 8 + size
    return length > 0 and pos == end


def _read_ngsp(data: bytes, source: str) -> tuple[tuple[int, ...], dict[str, np.ndarray]]:
    """Header fields and attribute byte arrays of a version-4 file (plain header, TOC, zstd streams)."""
    if len(data) < NGSP_HEADER.size:
        raise ValueError(f"{source}: truncated .spz: {len(data)} bytes, less than its 32-byte header")
    _, version, n, degree, bits, _, num_streams, toc, _ = NGSP_HEADER.unpack_from(data)
    _check_header(version, n, degree, bits, source)
    _check_fits(source, n, 9 * n, len(data), MAX_ZSTD_RATIO)
    sizes = {k: v for k, v in _attribute_sizes(n, version, degree).items() if v > 0}
    check_budget(source, f"{n} points of SH degree {degree}", sum(sizes.values()) + n * DECODED_BYTES_PER_POINT)
    if num_streams != len(sizes) or toc < NGSP_HEADER.size:
        raise ValueError(
            f"{source}: corrupt .spz header: {num_streams} streams at offset {toc}; expected "
            f"{len(sizes)} streams ({', '.join(sizes)}) after the 32-byte header"
        )
    streams_at = toc + num_streams * TOC_ENTRY.size
    check_declared_size(source, f"a table of {num_streams} streams", streams_at, len(data))
    entries = [TOC_ENTRY.unpack_from(data, toc + i * TOC_ENTRY.size) for i in range(num_streams)]
    for (name, size), (_, raw_size) in zip(sizes.items(), entries, strict=True):
        if raw_size != size:
            raise ValueError(
                f"{source}: corrupt .spz: the {name} stream holds {raw_size} bytes; {n} points need {size}"
            )
    total = streams_at + sum(c for c, _ in entries)
    if total != len(data):
        what = "truncated .spz" if total > len(data) else "corrupt .spz"
        raise ValueError(
            f"{source}: {what}: the stream table adds up to {total} bytes, the file has {len(data)}; "
            f"re-download or re-export the file"
        )
    arrays, offset = {}, streams_at
    for (name, size), (compressed, _) in zip(sizes.items(), entries, strict=True):
        arrays[name] = np.frombuffer(_unzstd(data[offset : offset + compressed], size, name, source), np.uint8)
        offset += compressed
    arrays.setdefault("sh", np.zeros(0, np.uint8))
    return (version, n, degree, bits), arrays


def _unzstd(frame: bytes, size: int, name: str, source: str) -> bytes:
    """Exactly ``size`` bytes from one zstd frame (reads at most ``size + 1``, whatever the frame claims)."""
    return inflate_zstd(frame, size, source, f"the .spz {name} stream")


def _split(raw: bytes, offset: int, sizes: dict[str, int]) -> dict[str, np.ndarray]:
    arrays = {}
    for name in ATTRIBUTES:
        arrays[name] = np.frombuffer(raw, np.uint8, count=sizes[name], offset=offset)
        offset += sizes[name]
    return arrays


def _decode(arrays: dict[str, np.ndarray], header: tuple[int, ...], source: str, turn: bool = True) -> GaussianSet:
    """The GaussianSet of decoded attribute arrays (``turn``: RUB -> RDF, a half turn about x)."""
    version, n, degree, bits = header
    b = arrays["positions"].reshape(n, 3, 3).astype(np.int32)
    fixed = b[..., 0] | (b[..., 1] << 8) | (b[..., 2] << 16)
    means = ((fixed ^ 0x800000) - 0x800000).astype(np.float32) / np.float32(1 << bits)
    logits = opacity_logits_from_unit(arrays["alphas"].astype(np.float32) / 255.0)
    dc = (arrays["colors"].reshape(n, 3).astype(np.float32) / 255.0 - 0.5) / np.float32(COLOR_SCALE)
    log_scales = arrays["scales"].reshape(n, 3).astype(np.float32) / 16.0 - 10.0
    xyzw = (
        decode_smallest_three(arrays["rotations"].view("<u4"))
        if version >= 3
        else decode_first_three(arrays["rotations"].reshape(n, 3))
    )
    rest = (arrays["sh"].reshape(n, SH_DIMS[degree], 3).astype(np.float32) - 128.0) / 128.0
    if degree == 4:
        log.warning("%s: SH degree 4 cut to degree 3 (a GaussianSet holds degrees 0-3)", source)
        rest = rest[:, :15]
    sh = np.concatenate([dc[:, None, :], rest], 1)
    quats = np.stack([xyzw[:, 3], xyzw[:, 0], xyzw[:, 1], xyzw[:, 2]], 1)
    if turn:  # RUB -> RDF: a half turn about x
        means[:, 1:] *= -1
        quats[:, 2:] *= -1
        sh[:, 1:] *= RUB_TO_RDF_SH_SIGNS[: sh.shape[1] - 1, None]
    return gaussians_from_arrays(source, means, quats, log_scales, logits, sh)


def decode_smallest_three(words: np.ndarray) -> np.ndarray:
    """Unit (x, y, z, w) quaternions [N, 4] from version-3 "smallest three" uint32 words [N]."""
    words = words.astype(np.uint32)
    largest = (words >> np.uint32(30)).astype(np.int64)
    others = np.array([[j for j in range(4) if j != i] for i in range(4)])[largest]  # [N, 3] ascending
    xyzw = np.empty((words.shape[0], 4), np.float32)
    rows = np.arange(words.shape[0])
    sum_sq = np.zeros(words.shape[0], np.float32)
    for k, shift in enumerate((20, 10, 0)):  # the highest of the three indices sits in the lowest bits
        field = (words >> np.uint32(shift)) & np.uint32(0x3FF)
        value = (field & np.uint32(0x1FF)).astype(np.float32) / np.float32(511.0 * np.sqrt(2.0))
        value = np.where(field & np.uint32(0x200), -value, value)
        xyzw[rows, others[:, k]] = value
        sum_sq += value * value
    xyzw[rows, largest] = np.sqrt(np.maximum(0.0, 1.0 - sum_sq))
    return xyzw


def decode_first_three(codes: np.ndarray) -> np.ndarray:
    """Unit (x, y, z, w) quaternions [N, 4] from version-2 byte triples [N, 3] (``w >= 0`` derived)."""
    xyz = codes.astype(np.float32) / 127.5 - 1.0
    w = np.sqrt(np.maximum(0.0, 1.0 - (xyz * xyz).sum(1)))
    return np.concatenate([xyz, w[:, None]], 1)
