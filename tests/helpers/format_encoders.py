"""Writers of the shared splat formats, for the reader tests only (fluidgs itself writes standard .ply / .npz).

Each encoder follows the format's public definition (the writers of SuperSplat/splat-transform, the Niantic spz
library, antimatter15's viewer, the SOG specification and GaussianSplats3D's SplatBuffer), vectorised with
numpy: the tests decode what these write and compare with the quantisation steps of each format.
"""

from __future__ import annotations

import gzip
import io
import json
import math
import struct
import zipfile
from pathlib import Path

import numpy as np
import torch
import zstandard

from recon.formats.compressed_ply import CHUNK_BOUNDS, CHUNK_COLORS
from recon.gaussians import SH_C0, GaussianSet

RUB_FLIP_POSITION = np.array([1.0, -1.0, -1.0], np.float32)  # RDF <-> RUB, a half turn about x


def _arrays(g: GaussianSet) -> dict[str, np.ndarray]:
    g = g.detach().to(device="cpu", dtype=torch.float32)
    return {
        "means": g.means.numpy(),
        "quats": g.quats.numpy(),
        "log_scales": g.log_scales.numpy(),
        "logits": g.opacity_logits.numpy(),
        "sh": g.sh.numpy(),
    }


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-x.astype(np.float64)))


def _unit_quats(q: np.ndarray) -> np.ndarray:
    return q / np.linalg.norm(q, axis=1, keepdims=True)


# ---- SuperSplat / PlayCanvas compressed .ply ------------------------------------------------------------------
def pack_unorm(value: np.ndarray, bits: int) -> np.ndarray:
    top = (1 << bits) - 1
    return np.clip(np.floor(value * top + 0.5), 0, top).astype(np.uint32)


def _normalize(x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    span = hi - lo
    t = np.where(span < 1e-5, 0.0, (x - lo) / np.where(span < 1e-5, 1.0, span))
    return np.clip(t, 0.0, 1.0)


def pack_rotation(quats_wxyz: np.ndarray) -> np.ndarray:
    """2-10-10-10 words: index of the largest |component| (rot_0..rot_3 order), then the other three."""
    q = _unit_quats(quats_wxyz.astype(np.float64))
    largest = np.abs(q).argmax(1)
    q = np.where(q[np.arange(len(q)), largest][:, None] < 0, -q, q)
    word = largest.astype(np.uint32)
    for j in range(4):
        keep = largest != j
        code = pack_unorm(q[:, j] / math.sqrt(2.0) + 0.5, 10)
        word = np.where(keep, (word << np.uint32(10)) | code, word)
    return word


def encode_compressed_ply(g: GaussianSet, path: Path, chunk_colors: bool = True, with_sh: bool = True) -> Path:
    """Write ``g`` as a SuperSplat compressed .ply (chunk bounds per 256 splats, packed words, uchar SH)."""
    a = _arrays(g)
    n = a["means"].shape[0]
    chunks = math.ceil(n / 256)
    rgb = a["sh"][:, 0] * SH_C0 + 0.5
    index = np.arange(n) // 256

    def bounds(x):
        lo = np.array([x[index == c].min(0) for c in range(chunks)])
        hi = np.array([x[index == c].max(0) for c in range(chunks)])
        return lo, hi

    (plo, phi), (slo, shi), (clo, chi) = bounds(a["means"]), bounds(a["log_scales"]), bounds(rgb)
    slo, shi = np.clip(slo, -20, 20), np.clip(shi, -20, 20)

    def pack_111011(x, lo, hi):
        t = _normalize(x, lo[index], hi[index])
        return (
            (pack_unorm(t[:, 0], 11) << np.uint32(21))
            | (pack_unorm(t[:, 1], 10) << np.uint32(11))
            | pack_unorm(t[:, 2], 11)
        )

    t = _normalize(rgb, clo[index], chi[index]) if chunk_colors else rgb
    color = (
        (pack_unorm(t[:, 0], 8) << np.uint32(24))
        | (pack_unorm(t[:, 1], 8) << np.uint32(16))
        | (pack_unorm(t[:, 2], 8) << np.uint32(8))
        | pack_unorm(_sigmoid(a["logits"]), 8)
    )
    vertex = np.stack(
        [pack_111011(a["means"], plo, phi), pack_rotation(a["quats"]), pack_111011(a["log_scales"], slo, shi), color], 1
    ).astype("<u4")
    chunk_cols = [plo, phi, slo, shi] + ([clo, chi] if chunk_colors else [])
    chunk = np.concatenate(chunk_cols, 1).astype("<f4")
    names = list(CHUNK_BOUNDS)
    names += list(CHUNK_COLORS) if chunk_colors else []
    header = ["ply", "format binary_little_endian 1.0", "comment test encoder", f"element chunk {chunks}"]
    header += [f"property float {p}" for p in names]
    header += [f"element vertex {n}"] + [
        f"property uint packed_{p}" for p in ("position", "rotation", "scale", "color")
    ]
    body = chunk.tobytes() + vertex.tobytes()
    k = a["sh"].shape[1]
    if with_sh and k > 1:
        rest = a["sh"][:, 1:].transpose(0, 2, 1).reshape(n, 3 * (k - 1))  # channel-major f_rest
        codes = np.clip(np.floor((rest / 8.0 + 0.5) * 256.0), 0, 255).astype(np.uint8)
        header += [f"element sh {n}"] + [f"property uchar f_rest_{i}" for i in range(3 * (k - 1))]
        body += codes.tobytes()
    path.write_bytes(("\n".join(header + ["end_header"]) + "\n").encode() + body)
    return path


# ---- Niantic .spz -------------------------------------------------------------------------------------------
RUB_SH_SIGNS = np.array([-1, -1, 1, -1, 1, 1, -1, 1, -1, 1, -1, -1, 1, -1, 1], np.float32)


def _to_uint8(x: np.ndarray) -> np.ndarray:
    return np.clip(np.round(x), 0, 255).astype(np.uint8)


def spz_attributes(g: GaussianSet, version: int, frame: str = "rdf", fractional_bits: int = 12) -> dict[str, bytes]:
    """The six packed attribute arrays; ``frame='rdf'`` converts a .ply-frame set to SPZ's RUB first."""
    a = _arrays(g)
    n, k = a["sh"].shape[:2]
    flip = frame == "rdf"
    means = a["means"] * (RUB_FLIP_POSITION if flip else 1.0)
    fixed = np.round(means.astype(np.float64) * (1 << fractional_bits)).astype(np.int64) & 0xFFFFFF
    positions = np.stack([fixed & 0xFF, (fixed >> 8) & 0xFF, (fixed >> 16) & 0xFF], -1).astype(np.uint8)
    xyzw = _unit_quats(a["quats"][:, [1, 2, 3, 0]].astype(np.float64))
    if flip:
        xyzw[:, 1:3] *= -1
    if version >= 3:
        largest = np.abs(xyzw).argmax(1)
        negate = xyzw[np.arange(n), largest] < 0
        word = largest.astype(np.uint32)
        for j in range(4):
            keep = largest != j
            neg = ((xyzw[:, j] < 0) ^ negate).astype(np.uint32)
            mag = (511.0 * (np.abs(xyzw[:, j]) / math.sqrt(0.5)) + 0.5).astype(np.uint32)
            word = np.where(keep, (word << np.uint32(10)) | (neg << np.uint32(9)) | mag, word)
        rotations = word.astype("<u4").tobytes()
    else:
        s = np.where(xyzw[:, 3:4] < 0, -127.5, 127.5)
        rotations = _to_uint8(xyzw[:, :3] * s + 127.5).tobytes()
    rest = a["sh"][:, 1:] * (RUB_SH_SIGNS[: k - 1, None] if flip else 1.0)
    return {
        "positions": positions.tobytes(),
        "alphas": _to_uint8(_sigmoid(a["logits"]) * 255.0).tobytes(),
        "colors": _to_uint8(a["sh"][:, 0] * (0.15 * 255.0) + 127.5).tobytes(),
        "scales": _to_uint8((a["log_scales"] + 10.0) * 16.0).tobytes(),
        "rotations": rotations,
        "sh": _to_uint8(rest * 128.0 + 128.0).tobytes(),
    }


def encode_spz(
    g: GaussianSet,
    path: Path,
    version: int = 4,
    frame: str = "rdf",
    flags: int = 0,
    extension: bytes = b"",
    extension_first: bool = False,
) -> Path:
    """Write an .spz: versions 2-3 as one gzip stream, version 4 as header + TOC + zstd streams."""
    attrs = spz_attributes(g, version, frame)
    n, degree = g.num, g.sh_degree
    order = ("positions", "alphas", "colors", "scales", "rotations", "sh")
    if version < 4:
        header = struct.pack("<4sIIBBBB", b"NGSP", version, n, degree, 12, flags, 0)
        body = b"".join(attrs[k] for k in order)
        raw = header + (extension + body if extension_first else body + extension)
        path.write_bytes(gzip.compress(raw))
        return path
    streams = [zstandard.ZstdCompressor(level=3).compress(attrs[k]) for k in order if attrs[k]]
    sizes = [len(attrs[k]) for k in order if attrs[k]]
    toc = 32 + len(extension)
    header = struct.pack("<4sIIBBBBI12s", b"NGSP", version, n, degree, 12, flags, len(streams), toc, b"")
    table = b"".join(struct.pack("<QQ", len(s), u) for s, u in zip(streams, sizes, strict=True))
    path.write_bytes(header + extension + table + b"".join(streams))
    return path


# ---- antimatter15 .splat ------------------------------------------------------------------------------------
def encode_splat(g: GaussianSet, path: Path) -> Path:
    """Write ``g`` (DC colour only) as 32-byte .splat records."""
    a = _arrays(g)
    n = a["means"].shape[0]
    records = np.zeros(n, dtype=[("p", "<f4", (3,)), ("s", "<f4", (3,)), ("c", "u1", (4,)), ("r", "u1", (4,))])
    records["p"] = a["means"]
    records["s"] = np.exp(a["log_scales"])
    records["c"][:, :3] = _to_uint8((0.5 + SH_C0 * a["sh"][:, 0]) * 255.0)
    records["c"][:, 3] = _to_uint8(_sigmoid(a["logits"]) * 255.0)
    records["r"] = _to_uint8(_unit_quats(a["quats"]) * 128.0 + 128.0)
    path.write_bytes(records.tobytes())
    return path


# ---- PlayCanvas SOG -----------------------------------------------------------------------------------------
def _webp(pixels: np.ndarray) -> bytes:
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(pixels, np.uint8), "RGBA").save(buffer, "WEBP", lossless=True, exact=True)
    return buffer.getvalue()


def _image_of(rows: np.ndarray, width: int) -> np.ndarray:
    """[N, 4] pixel rows laid out row-major in an image ``width`` wide (trailing pixels zero)."""
    height = math.ceil(len(rows) / width)
    out = np.zeros((height * width, 4), np.uint8)
    out[: len(rows)] = rows
    return out.reshape(height, width, 4)


def sog_quats(quats_wxyz: np.ndarray) -> np.ndarray:
    """[N, 4] RGBA bytes: the three smaller components (w, x, y, z order) and 252 + the largest's index."""
    q = _unit_quats(quats_wxyz.astype(np.float64))
    largest = np.abs(q).argmax(1)
    q = np.where(q[np.arange(len(q)), largest][:, None] < 0, -q, q)
    others = np.array([[j for j in range(4) if j != i] for i in range(4)])[largest]
    small = q[np.arange(len(q))[:, None], others]
    codes = np.clip(np.round((small * math.sqrt(2.0) * 0.5 + 0.5) * 255.0), 0, 255)
    return np.concatenate([codes, 252 + largest[:, None]], 1).astype(np.uint8)


def _codebook_codes(values: np.ndarray) -> tuple[list[float], np.ndarray]:
    lo, hi = float(values.min()), float(values.max())
    book = np.linspace(lo, hi, 256)
    codes = np.clip(np.round((values - lo) / max(hi - lo, 1e-12) * 255.0), 0, 255).astype(np.uint8)
    return book.tolist(), codes


def encode_sog(g: GaussianSet, path: Path, version: int = 2, bundle: bool = True, width: int = 64) -> Path:
    """Write ``g`` as SOG (version 1 or 2): a zip bundle at ``path``, or a folder ``path`` holding meta.json and
    the images. Every Gaussian gets its own SH palette entry (N <= 65536)."""
    a = _arrays(g)
    n, k = a["sh"].shape[:2]
    logs = np.sign(a["means"]) * np.log1p(np.abs(a["means"]))
    mins, maxs = logs.min(0), logs.max(0)
    q16 = np.round((logs - mins) / np.where(maxs > mins, maxs - mins, 1.0) * 65535.0).astype(np.uint32)
    alpha = np.full((n, 1), 255, np.uint8)
    files = {
        "means_l.webp": np.concatenate([(q16 & 0xFF).astype(np.uint8), alpha], 1),
        "means_u.webp": np.concatenate([(q16 >> 8).astype(np.uint8), alpha], 1),
        "quats.webp": sog_quats(a["quats"]),
    }
    meta = {
        "means": {"mins": mins.tolist(), "maxs": maxs.tolist(), "files": ["means_l.webp", "means_u.webp"]},
        "quats": {"files": ["quats.webp"]},
    }
    opacity = _to_uint8(_sigmoid(a["logits"]) * 255.0)[:, None]
    if version == 2:
        book, codes = _codebook_codes(a["log_scales"])
        files["scales.webp"] = np.concatenate([codes, alpha], 1)
        meta["scales"] = {"codebook": book, "files": ["scales.webp"]}
        book, codes = _codebook_codes(a["sh"][:, 0])
        files["sh0.webp"] = np.concatenate([codes, opacity], 1)
        meta["sh0"] = {"codebook": book, "files": ["sh0.webp"]}
        meta = {"version": 2, "count": n, "antialias": False, **meta}
    else:
        lo, hi = a["log_scales"].min(0), a["log_scales"].max(0)
        files["scales.webp"] = np.concatenate([_to_uint8((a["log_scales"] - lo) / (hi - lo) * 255.0), alpha], 1)
        meta["scales"] = {"mins": lo.tolist(), "maxs": hi.tolist(), "files": ["scales.webp"]}
        colour = np.concatenate([a["sh"][:, 0], a["logits"][:, None]], 1)
        lo, hi = colour.min(0), colour.max(0)
        files["sh0.webp"] = _to_uint8((colour - lo) / (hi - lo) * 255.0)
        meta["sh0"] = {"mins": lo.tolist(), "maxs": hi.tolist(), "files": ["sh0.webp"]}
        meta["means"]["shape"] = [n, 3]
    images = {name: _image_of(rows, width) for name, rows in files.items()}
    if k > 1:
        coeffs = k - 1
        rest = a["sh"][:, 1:]  # [N, C, 3]
        if version == 2:
            book, codes = _codebook_codes(rest)
            meta["shN"] = {
                "count": n,
                "bands": int(round(math.sqrt(k))) - 1,
                "codebook": book,
                "files": ["shN_centroids.webp", "shN_labels.webp"],
            }
        else:
            lo, hi = float(rest.min()), float(rest.max())
            codes = _to_uint8((rest - lo) / (hi - lo) * 255.0)
            meta["shN"] = {"mins": lo, "maxs": hi, "files": ["shN_centroids.webp", "shN_labels.webp"]}
        rows = math.ceil(n / 64)
        centroids = np.zeros((rows * 64, coeffs, 4), np.uint8)
        centroids[:n, :, :3] = codes
        centroids[:, :, 3] = 255
        images["shN_centroids.webp"] = centroids.reshape(rows, 64 * coeffs, 4)
        labels = np.arange(n)
        label_rows = np.stack([labels & 0xFF, labels >> 8, np.zeros(n), np.full(n, 255)], 1).astype(np.uint8)
        images["shN_labels.webp"] = _image_of(label_rows, width)
    payload = {name: _webp(img) for name, img in images.items()}
    payload["meta.json"] = json.dumps(meta).encode()
    if bundle:
        with zipfile.ZipFile(path, "w") as zf:
            for name, data in payload.items():
                zf.writestr(name, data)
    else:
        path.mkdir(parents=True, exist_ok=True)
        for name, data in payload.items():
            (path / name).write_bytes(data)
    return path


# ---- mkkellogg .ksplat ----------------------------------------------------------------------------------------
KSPLAT_SH_RANGE = (-1.5, 1.5)


def _ksplat_sh_values(rest: np.ndarray, degree: int) -> np.ndarray:
    """[N, 3 (K-1)] SH values in the .ksplat record order (band, then channel, then coefficient)."""
    n = rest.shape[0]
    channel_major = rest.transpose(0, 2, 1).reshape(n, -1)  # f_rest order
    from recon.formats.ksplat import sh_component_order

    return np.ascontiguousarray(channel_major[:, sh_component_order(degree)])


def encode_ksplat(g: GaussianSet, path: Path, mode: int = 0, sections: int = 1, bucket_capacity: int = 64) -> Path:
    """Write ``g`` as a .ksplat of compression ``mode`` split into ``sections`` sections; modes 1 and 2 put the
    records of each section into buckets of ``bucket_capacity`` (the last one partial)."""
    a = _arrays(g)
    n, k = a["sh"].shape[:2]
    degree = int(round(math.sqrt(k))) - 1
    header = bytearray(4096)
    header[0], header[1] = 0, 1
    struct.pack_into("<II", header, 4, sections, sections)
    struct.pack_into("<II", header, 12, n, n)
    struct.pack_into("<H", header, 20, mode)
    struct.pack_into("<ff", header, 36, *KSPLAT_SH_RANGE)
    bounds = np.linspace(0, n, sections + 1).astype(int)
    section_headers, bodies = [], []
    f_type = "<f4" if mode == 0 else "<f2"
    for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
        m = hi - lo
        idx = np.arange(lo, hi)
        full, rem = divmod(m, bucket_capacity)
        partial = [rem] if rem else []
        buckets = full + len(partial)
        bucket_of = np.arange(m) // bucket_capacity
        centres = (
            np.array([a["means"][idx[bucket_of == b]].mean(0) for b in range(buckets)]) if mode else np.zeros((0, 3))
        )
        block = 2.0 * float(np.abs(a["means"][idx] - centres[bucket_of]).max()) * 1.01 + 1e-6 if mode else 1.0
        quant = 32767
        parts = []
        if mode == 0:
            parts.append(a["means"][idx].astype("<f4").view(np.uint8).reshape(m, -1))
        else:
            raw = np.round((a["means"][idx] - centres[bucket_of]) / (block / 2.0 / quant) + quant)
            parts.append(np.clip(raw, 0, 65535).astype("<u2").view(np.uint8).reshape(m, -1))
        parts.append(np.exp(a["log_scales"][idx]).astype(f_type).view(np.uint8).reshape(m, -1))
        parts.append(a["quats"][idx].astype(f_type).view(np.uint8).reshape(m, -1))
        rgba = np.concatenate(
            [
                _to_uint8((0.5 + SH_C0 * a["sh"][idx, 0]) * 255.0),
                _to_uint8(_sigmoid(a["logits"][idx]) * 255.0)[:, None],
            ],
            1,
        )
        parts.append(rgba)
        if degree:
            values = _ksplat_sh_values(a["sh"][idx, 1:], degree)
            if mode == 2:
                lo_sh, hi_sh = KSPLAT_SH_RANGE
                parts.append(_to_uint8((values - lo_sh) / (hi_sh - lo_sh) * 255.0))
            else:
                parts.append(values.astype(f_type).view(np.uint8).reshape(m, -1))
        records = np.concatenate(parts, 1)
        sh_header = bytearray(1024)
        struct.pack_into("<IIII", sh_header, 0, m, m, bucket_capacity if mode else 0, buckets if mode else 0)
        struct.pack_into("<f", sh_header, 16, block)
        struct.pack_into("<H", sh_header, 20, 12 if mode else 0)
        struct.pack_into("<I", sh_header, 24, quant if mode else 0)
        struct.pack_into("<II", sh_header, 32, full if mode else 0, len(partial) if mode else 0)
        struct.pack_into("<H", sh_header, 40, degree)
        section_headers.append(bytes(sh_header))
        bucket_bytes = (np.array(partial, "<u4").tobytes() + centres.astype("<f4").tobytes()) if mode else b""
        bodies.append(bucket_bytes + records.tobytes())
    path.write_bytes(bytes(header) + b"".join(section_headers) + b"".join(bodies))
    return path
