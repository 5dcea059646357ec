"""Shared splat formats: compressed .ply, .spz (v2-v4), .splat and the content-based dispatch (recon.formats).

Round trips through encoders written from each format's definition (tests/helpers/format_encoders.py) hold within the
format's quantisation; single records written byte by byte decode to the values the definition gives; bad files
raise ValueError naming the file, before any large allocation; the real capture exported both ways decodes to the
same Gaussians.
"""

import gzip
import io
import math
import os
import struct
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

from recon import formats
from recon.formats import ply
from recon.formats.compressed_ply import CHUNK_BOUNDS, CHUNK_COLORS
from recon.formats.spz import RUB_TO_RDF_SH_SIGNS
from recon.gaussians import SH_C0, GaussianSet
from recon.sh import eval_sh

from helpers.format_encoders import encode_compressed_ply, encode_splat, encode_spz
from helpers.paths import BIKER_COMPRESSED_PLY, BIKER_SPZ, REAL_SPLATS
from helpers.splat_sets import assert_within, random_splats, refused_load, sign_aligned

SQRT2 = math.sqrt(2.0)


def _chunk_span(x: torch.Tensor) -> torch.Tensor:
    """Per-splat max - min of ``x`` [N, C] over its 256-splat chunk."""
    idx = torch.arange(x.shape[0]) // 256
    span = torch.zeros_like(x)
    for c in range(int(idx.max()) + 1):
        m = idx == c
        span[m] = x[m].max(0).values - x[m].min(0).values
    return span


# ---- round trips -----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("degree,chunk_colors", [(0, True), (1, False), (3, True)])
def test_compressed_ply_round_trip_within_quantisation(tmp_path, degree, chunk_colors):
    g = random_splats(700, degree)  # 3 chunks, the last one partial
    path = encode_compressed_ply(g, tmp_path / "g.compressed.ply", chunk_colors=chunk_colors)
    back, fmt = formats.load_gaussians_with_format(path)
    assert fmt == "compressed_ply" and back.num == g.num and back.sh_degree == degree
    steps = torch.tensor([2047.0, 1023.0, 2047.0])
    assert_within(back.means, g.means, _chunk_span(g.means) / steps / 2, "means")
    assert_within(back.log_scales, g.log_scales, _chunk_span(g.log_scales) / steps / 2, "log-scales")
    rgb = g.sh[:, 0] * SH_C0 + 0.5
    rgb_tol = (_chunk_span(rgb) if chunk_colors else torch.ones_like(rgb)) / 255 / 2
    assert_within(back.sh[:, 0] * SH_C0 + 0.5, rgb, rgb_tol, "colour")
    assert_within(back.opacities, g.opacities, 0.5 / 255, "opacity")
    assert_within(sign_aligned(back.quats, g.quats), g.quats, 3e-3, "rotation")
    if degree:
        assert_within(back.sh[:, 1:], g.sh[:, 1:], 8 / 256 / 2, "SH rest")


@pytest.mark.parametrize("version,degree", [(2, 1), (3, 0), (3, 2), (4, 0), (4, 3)])
def test_spz_round_trip_within_quantisation(tmp_path, version, degree):
    g = random_splats(500, degree, seed=version, min_w=0.5 if version == 2 else 0.0)
    back, fmt = formats.load_gaussians_with_format(encode_spz(g, tmp_path / "g.spz", version=version))
    assert fmt == "spz" and back.num == g.num and back.sh_degree == degree
    assert_within(back.means, g.means, 0.5 / 4096, "means")
    assert_within(back.log_scales, g.log_scales, 0.5 / 16, "log-scales")
    assert_within(back.opacities, g.opacities, 0.5 / 255, "opacity")
    assert_within(back.sh[:, 0], g.sh[:, 0], 0.5 / (0.15 * 255), "SH DC")
    assert_within(sign_aligned(back.quats, g.quats), g.quats, 3e-3 if version >= 3 else 2e-2, "rotation")
    if degree:
        assert_within(back.sh[:, 1:], g.sh[:, 1:], 0.5 / 128, "SH rest")


def test_splat_round_trip_within_quantisation(tmp_path):
    g = random_splats(300, 0, seed=5)
    back, fmt = formats.load_gaussians_with_format(encode_splat(g, tmp_path / "g.splat"))
    assert fmt == "splat" and back.num == g.num and back.sh_degree == 0
    assert torch.equal(back.means, g.means)
    assert_within(back.log_scales, g.log_scales, 1e-5, "log-scales")
    assert_within(back.sh[:, 0] * SH_C0 + 0.5, g.sh[:, 0] * SH_C0 + 0.5, 0.5 / 255, "colour")
    assert_within(back.opacities, g.opacities, 0.5 / 255, "opacity")
    assert_within(sign_aligned(back.quats, g.quats), g.quats, 1.5 / 128, "rotation")


def test_spz_frame_is_decided_from_a_sibling_of_the_same_capture(tmp_path, caplog):
    """SuperSplat writes .spz in the .ply frame: beside the capture's .ply, "auto" reads it upright; an asked frame
    the sibling contradicts is kept with a WARNING naming the other; with nothing beside it, a WARNING."""
    g = random_splats(400, 0, seed=4)
    g = GaussianSet(g.means * 0.5 + torch.tensor([0.0, 1.5, 0.7]), g.quats, g.log_scales, g.opacity_logits, g.sh)
    spz_path = encode_spz(g, tmp_path / "guitar.v3.spz", version=3, frame="rub")  # stored as given: the .ply frame
    alone = tmp_path / "alone"
    alone.mkdir()
    (alone / "x.spz").write_bytes(spz_path.read_bytes())
    with caplog.at_level("WARNING", logger="recon.formats"):
        lone, _, frame = formats.load_gaussians_framed(alone / "x.spz")
    assert "--spz-frame ply" in caplog.text and "nothing tells" in frame.description
    assert_within(lone.means, g.means * torch.tensor([1.0, -1.0, -1.0]), 0.5 / 4096, "means")  # Niantic's turn
    ply.save_gaussians(g, tmp_path / "guitar.ply")
    caplog.clear()
    with caplog.at_level("WARNING", logger="recon.formats"):
        auto, _, frame = formats.load_gaussians_framed(spz_path)
        assert not caplog.text
        assert_within(auto.means, g.means, 0.5 / 4096, "means")  # upright: as the .ply
        assert "decided from the data: guitar.ply" in frame.description and np.allclose(frame.to_loaded, np.eye(4))
        asked, _, frame = formats.load_gaussians_framed(spz_path, formats.LoadOptions(spz_frame="rub"))
    assert "upside down; pass --spz-frame ply" in caplog.text  # the asked frame is kept, never flipped silently
    assert_within(asked.means, lone.means, 1e-6, "means")
    assert formats.spz_frame_evidence(spz_path, asked.means.numpy())[0] == "ply"
    with pytest.raises(ValueError, match="frame must be one of"):
        formats.load_gaussians_framed(spz_path, formats.LoadOptions(spz_frame="up"))


@pytest.mark.skipif(not BIKER_SPZ.is_file(), reason="the real captures are not on this machine")
def test_real_spz_frame_from_its_siblings():
    frame, why = formats.spz_frame_evidence(BIKER_SPZ, formats.load_gaussians(BIKER_SPZ).means.numpy())
    assert frame == "rub" and "biker." in why  # Niantic's frame: the .ply, .sog and .ksplat agree


def test_spz_frame_is_the_ply_frame(tmp_path):
    """Data stored as given (RUB) comes back turned half about x: means F mu, covariances F Sigma F, colours
    seen from F d equal to the stored ones seen from d."""
    g = random_splats(400, 3, seed=9)
    back = formats.load_gaussians(encode_spz(g, tmp_path / "rub.spz", frame="rub"))
    flip = torch.tensor([1.0, -1.0, -1.0])
    assert_within(back.means, g.means * flip, 0.5 / 4096, "means")
    turned = g.quats * torch.tensor([1.0, 1.0, -1.0, -1.0])  # F R F: w and x kept, y and z negated
    assert_within(sign_aligned(back.quats, turned), turned, 3e-3, "rotation")
    cov = g.covariances() * flip[:, None] * flip[None, :]
    scale = cov.flatten(1).norm(dim=1)[:, None, None]
    assert_within(back.covariances() / scale, cov / scale, 0.08, "covariances")  # log-scale steps of 1/16
    dirs = torch.nn.functional.normalize(torch.randn(g.num, 3), dim=1)
    assert_within(eval_sh(back.sh, dirs * flip), eval_sh(g.sh, dirs), 0.05, "view-dependent colour")


def test_rub_to_rdf_sh_signs_follow_the_basis():
    """Y_k(x, -y, -z) = sign_k Y_k(x, y, z) for every real SH basis function of degree 1-3, exactly."""
    sh = torch.randn(64, 16, 3, dtype=torch.float64)
    dirs = torch.nn.functional.normalize(torch.randn(64, 3, dtype=torch.float64), dim=1)
    flipped = sh.clone()
    flipped[:, 1:] *= torch.from_numpy(RUB_TO_RDF_SH_SIGNS).double()[:, None]
    flip = torch.tensor([1.0, -1.0, -1.0], dtype=torch.float64)
    torch.testing.assert_close(eval_sh(flipped, dirs * flip), eval_sh(sh, dirs), rtol=0, atol=1e-12)


# ---- records decoded by hand -----------------------------------------------------------------------------------
def _compressed_header(
    chunks: int, n: int, sh_props: int = 0, sh_rows: int | None = None, colors: bool = True
) -> bytes:
    names = list(CHUNK_BOUNDS) + (list(CHUNK_COLORS) if colors else [])
    lines = ["ply", "format binary_little_endian 1.0", f"element chunk {chunks}"]
    lines += [f"property float {p}" for p in names] + [f"element vertex {n}"]
    lines += [f"property uint packed_{p}" for p in ("position", "rotation", "scale", "color")]
    if sh_props:
        lines += [f"element sh {n if sh_rows is None else sh_rows}"]
        lines += [f"property uchar f_rest_{i}" for i in range(sh_props)]
    return ("\n".join(lines + ["end_header"]) + "\n").encode()


def test_compressed_ply_record_by_hand(tmp_path):
    bounds = [
        -1.0,
        0.0,
        2.0,
        3.0,
        1.0,
        4.0,  # position min xyz, max xyz
        -5.0,
        -4.0,
        -3.0,
        -1.0,
        0.0,
        1.0,  # log-scale min xyz, max xyz
        0.2,
        0.0,
        0.1,
        0.8,
        1.0,
        0.5,
    ]  # colour min rgb, max rgb
    position = (1023 << 21) | (256 << 11) | 2047
    rotation = (2 << 30) | (700 << 20) | (300 << 10) | 512  # largest: rot_2 (y); then w, x, z
    scale = (0 << 21) | (1023 << 11) | 1024
    color = (255 << 24) | (0 << 16) | (51 << 8) | 51
    sh = bytes([0, 255, 128] + [64] * 6)  # f_rest_0..8, channel-major
    path = tmp_path / "one.compressed.ply"
    path.write_bytes(
        _compressed_header(1, 1, 9)
        + struct.pack("<18f", *bounds)
        + struct.pack("<4I", position, rotation, scale, color)
        + sh
    )
    g = formats.load_gaussians(path)
    tx, ty, tz = 1023 / 2047, 256 / 1023, 1.0
    want_means = [-1 + 4 * tx, 0 + 1 * ty, 2 + 2 * tz]
    torch.testing.assert_close(g.means[0], torch.tensor(want_means), rtol=0, atol=1e-6)
    want_scales = [-5.0, -4 + 4 * 1023 / 1023, -3 + 4 * 1024 / 2047]
    torch.testing.assert_close(g.log_scales[0], torch.tensor(want_scales), rtol=0, atol=1e-6)
    w, x, z = ((c / 1023 - 0.5) * SQRT2 for c in (700, 300, 512))
    y = math.sqrt(1 - w * w - x * x - z * z)
    torch.testing.assert_close(g.quats[0], torch.tensor([w, x, y, z]), rtol=0, atol=1e-6)
    rgb = [0.8, 0.0, 0.1 + 0.4 * 51 / 255]
    torch.testing.assert_close(g.sh[0, 0], (torch.tensor(rgb) - 0.5) / SH_C0, rtol=0, atol=1e-5)
    assert g.opacities[0].item() == pytest.approx(51 / 255, abs=1e-6)
    rest = [(0 - 0.5) * 8, (1 - 0.5) * 8, ((128 + 0.5) / 256 - 0.5) * 8] + [((64 + 0.5) / 256 - 0.5) * 8] * 6
    want_rest = torch.tensor(rest).reshape(3, 3).T  # f_rest[c * 3 + j] -> coefficient j + 1, channel c
    torch.testing.assert_close(g.sh[0, 1:], want_rest, rtol=0, atol=1e-6)


def _spz_v3_record() -> bytes:
    pos = [2048, -2048, 4096]  # 0.5, -0.5, 1.0 at 12 fractional bits
    positions = b"".join(struct.pack("<i", v)[:3] for v in pos)
    rotation = (3 << 30) | (256 << 20) | ((1 << 9 | 128) << 10) | 0  # w largest; x +256, y -128, z 0
    return positions + bytes([255]) + bytes([128, 0, 255]) + bytes([160, 0, 255]) + struct.pack("<I", rotation)


def test_spz_record_by_hand(tmp_path):
    raw = struct.pack("<4sIIBBBB", b"NGSP", 3, 1, 0, 12, 0, 0) + _spz_v3_record()
    path = tmp_path / "one.spz"
    path.write_bytes(gzip.compress(raw))
    g = formats.load_gaussians(path)
    # RUB (0.5, -0.5, 1.0) -> RDF (0.5, 0.5, -1.0)
    torch.testing.assert_close(g.means[0], torch.tensor([0.5, 0.5, -1.0]), rtol=0, atol=0)
    assert g.opacity_logits[0].item() == pytest.approx(math.log((1 - 0.5 / 255) / (0.5 / 255)), rel=1e-5)
    want_dc = [(128 / 255 - 0.5) / 0.15, -0.5 / 0.15, 0.5 / 0.15]
    torch.testing.assert_close(g.sh[0, 0], torch.tensor(want_dc), rtol=0, atol=1e-5)
    torch.testing.assert_close(g.log_scales[0], torch.tensor([0.0, -10.0, 255 / 16 - 10]), rtol=0, atol=1e-6)
    x, y = 256 / 511 / SQRT2, -128 / 511 / SQRT2
    w = math.sqrt(1 - x * x - y * y)
    torch.testing.assert_close(g.quats[0], torch.tensor([w, x, -y, 0.0]), rtol=0, atol=1e-6)  # y, z negated


def test_spz_version4_record_by_hand(tmp_path):
    import zstandard

    record = _spz_v3_record()
    parts = [record[:9], record[9:10], record[10:13], record[13:16], record[16:20]]
    streams = [zstandard.ZstdCompressor().compress(p) for p in parts]
    header = struct.pack("<4sIIBBBBI12s", b"NGSP", 4, 1, 0, 12, 0, 5, 32, b"")
    table = b"".join(struct.pack("<QQ", len(s), len(p)) for s, p in zip(streams, parts, strict=True))
    path = tmp_path / "one4.spz"
    path.write_bytes(header + table + b"".join(streams))
    g4 = formats.load_gaussians(path)
    path3 = tmp_path / "one3.spz"
    path3.write_bytes(gzip.compress(struct.pack("<4sIIBBBB", b"NGSP", 3, 1, 0, 12, 0, 0) + record))
    for a, b in zip(g4.tensors(), formats.load_gaussians(path3).tensors(), strict=True):
        assert torch.equal(a, b)


def test_spz_version2_rotation_by_hand(tmp_path):
    g = random_splats(1, 0)
    path = encode_spz(g, tmp_path / "v2.spz", version=2)
    raw = bytearray(gzip.decompress(path.read_bytes()))
    raw[16 + 16 : 16 + 19] = bytes([191, 127, 64])  # after 9 + 1 + 3 + 3 bytes: x, y, z = c / 127.5 - 1
    path.write_bytes(gzip.compress(bytes(raw)))
    x, y, z = 191 / 127.5 - 1, 127 / 127.5 - 1, 64 / 127.5 - 1
    w = math.sqrt(1 - x * x - y * y - z * z)
    back = formats.load_gaussians(path).quats[0]
    torch.testing.assert_close(back, torch.tensor([w, x, -y, -z]), rtol=0, atol=1e-6)  # RUB -> RDF


def test_splat_record_by_hand(tmp_path):
    path = tmp_path / "one.splat"
    path.write_bytes(
        struct.pack("<6f", 1.0, -2.0, 3.5, 0.5, 1.0, 2.0) + bytes([255, 0, 128, 64]) + bytes([255, 128, 100, 128])
    )
    g = formats.load_gaussians(path)
    assert g.means[0].tolist() == [1.0, -2.0, 3.5]
    torch.testing.assert_close(g.log_scales[0], torch.tensor([math.log(0.5), 0.0, math.log(2.0)]))
    torch.testing.assert_close(g.sh[0, 0], (torch.tensor([1.0, 0.0, 128 / 255]) - 0.5) / SH_C0)
    assert g.opacities[0].item() == pytest.approx(64 / 255, abs=1e-6)
    torch.testing.assert_close(g.quats[0], torch.tensor([127 / 128, 0.0, -28 / 128, 0.0]))


# ---- detection and dispatch --------------------------------------------------------------------------------
def test_detection_is_by_content(tmp_path):
    g = random_splats(10, 1)
    std = ply.save_gaussians(g, tmp_path / "g.ply")
    assert formats.detect_format(std) == "ply"
    assert formats.detect_format(ply.save_gaussians(g, tmp_path / "g.npz")) == "npz"
    assert formats.detect_format(encode_compressed_ply(g, tmp_path / "g.ply.bin")) == "compressed_ply"
    assert formats.detect_format(encode_spz(g, tmp_path / "g4.bin", version=4)) == "spz"
    assert formats.detect_format(encode_spz(g, tmp_path / "g3.bin", version=3)) == "spz"
    assert formats.detect_format(encode_splat(g, tmp_path / "g.splat")) == "splat"
    misnamed = tmp_path / "really_a_ply.spz"
    misnamed.write_bytes(std.read_bytes())
    assert formats.detect_format(misnamed) == "ply"
    assert torch.equal(formats.load_gaussians(misnamed).means, g.means)


def test_the_dispatcher_reads_every_format(tmp_path):
    assert not hasattr(ply, "load_gaussians")  # one name: recon.formats.load_gaussians (recon.load_gaussians)
    g = random_splats(20, 0)
    assert formats.load_gaussians(encode_spz(g, tmp_path / "a.spz")).num == 20


def test_unrecognised_format_lists_the_supported_ones(tmp_path):
    path = tmp_path / "cloud.xyz"
    path.write_bytes(b"1 2 3\n4 5 6\n")
    with pytest.raises(ValueError) as info:
        formats.load_gaussians(path)
    message = str(info.value)
    assert str(path) in message and "unrecognised" in message and "'.xyz'" in message
    for name in ("3DGS .ply", "compressed .ply", ".spz", ".splat", ".npz"):
        assert name in message, message


def test_folder_and_missing_file(tmp_path):
    (tmp_path / "point_cloud.ply").write_bytes(b"")
    with pytest.raises(ValueError, match="is a folder.*point_cloud.ply"):
        formats.load_gaussians(tmp_path)
    with pytest.raises(FileNotFoundError, match="no such Gaussian file"):
        formats.load_gaussians(tmp_path / "absent.spz")


def test_cli_loader_says_folder_and_missing(tmp_path):
    from apps.options import load_gaussians_checked

    with pytest.raises(ValueError, match="is a folder"):
        load_gaussians_checked(tmp_path)
    with pytest.raises(ValueError, match="does not exist"):
        load_gaussians_checked(tmp_path / "absent.ply")


# ---- bad input -------------------------------------------------------------------------------------------------
def test_truncated_files(tmp_path):
    g = random_splats(600, 1)
    for name, path in [
        ("compressed", encode_compressed_ply(g, tmp_path / "c.ply")),
        ("spz4", encode_spz(g, tmp_path / "g4.spz", version=4)),
        ("splat", encode_splat(g, tmp_path / "g.splat")),
    ]:
        cut = tmp_path / f"cut_{name}{path.suffix}"
        cut.write_bytes(path.read_bytes()[:-7])
        refused_load(cut, "truncated")
    raw = gzip.decompress(encode_spz(g, tmp_path / "g3.spz", version=3).read_bytes())
    short = tmp_path / "short3.spz"
    short.write_bytes(gzip.compress(raw[:-100]))
    refused_load(short, "truncated")
    cut_stream = tmp_path / "cut3.spz"
    cut_stream.write_bytes((tmp_path / "g3.spz").read_bytes()[:-400])
    refused_load(cut_stream, "truncated", "ends early")


def test_corrupt_streams(tmp_path):
    g = random_splats(300, 0)
    data = bytearray(encode_spz(g, tmp_path / "g3.spz", version=3).read_bytes())
    data[-8] ^= 0xFF  # the CRC-32 of the gzip trailer
    (tmp_path / "crc.spz").write_bytes(bytes(data))
    refused_load(tmp_path / "crc.spz", "corrupt gzip stream")
    data = bytearray((tmp_path / "g3.spz").read_bytes())
    data[30:60] = b"\xff" * 30  # the middle of the deflate data
    (tmp_path / "mid.spz").write_bytes(bytes(data))
    with pytest.raises(ValueError, match="corrupt|truncated"):
        formats.load_gaussians(tmp_path / "mid.spz")
    data = bytearray(encode_spz(g, tmp_path / "g4.spz", version=4).read_bytes())
    first_stream = 32 + 5 * 16
    data[first_stream : first_stream + 4] = b"\x00\x00\x00\x00"  # the zstd frame magic of the positions
    (tmp_path / "z.spz").write_bytes(bytes(data))
    refused_load(tmp_path / "z.spz", "corrupt zstd stream", "positions")
    gz = tmp_path / "notspz.spz"
    gz.write_bytes(gzip.compress(b"ply\nformat ascii 1.0\n" * 4))
    refused_load(gz, "not an .spz")


def test_spz_header_problems(tmp_path):
    g = random_splats(50, 0)
    good = encode_spz(g, tmp_path / "g4.spz", version=4).read_bytes()
    v9 = tmp_path / "v9.spz"
    v9.write_bytes(good[:4] + struct.pack("<I", 9) + good[8:])
    refused_load(v9, "version 9 is not supported")
    v1 = tmp_path / "v1.spz"
    v1.write_bytes(gzip.compress(struct.pack("<4sIIBBBB", b"NGSP", 1, 1, 0, 12, 0, 0) + b"\0" * 20))
    refused_load(v1, "version 1 is not supported")
    streams = tmp_path / "streams.spz"
    streams.write_bytes(good[:15] + bytes([6]) + good[16:])
    refused_load(streams, "6 streams")


def test_spz_extensions_are_skipped(tmp_path):
    g = random_splats(40, 1)
    ext = struct.pack("<II", 0xADBE0002, 12) + struct.pack("<3f", 0.0, 1.0, 2.0)
    plain = formats.load_gaussians(encode_spz(g, tmp_path / "plain.spz", version=3))
    for name, kwargs in [
        ("v4", {"version": 4}),
        ("tail", {"version": 3}),
        ("front", {"version": 3, "extension_first": True}),
    ]:
        path = encode_spz(g, tmp_path / f"{name}.spz", flags=0x2, extension=ext, **kwargs)
        for a, b in zip(formats.load_gaussians(path).tensors(), plain.tensors(), strict=True):
            assert torch.equal(a, b), name


def test_compressed_ply_header_problems(tmp_path):
    bounds = struct.pack("<18f", *([0.0] * 6 + [-1.0] * 3 + [0.0] * 3 + [0.0] * 3 + [1.0] * 3))
    words = struct.pack("<4I", 0, 3 << 30, 0, 0xFFFFFFFF)
    cases = {
        "wrong_count.ply": (
            _compressed_header(1, 1, 10) + bounds + words + b"\x80" * 10,
            "SH data does not match the header",
        ),
        "wrong_rows.ply": (
            _compressed_header(1, 1, 9, sh_rows=2) + bounds + words + b"\x80" * 18,
            "SH data does not match the header",
        ),
        "chunks.ply": (_compressed_header(2, 1) + bounds * 2 + words, "expected ceil(1 / 256) = 1"),
    }
    for name, (content, fragment) in cases.items():
        (tmp_path / name).write_bytes(content)
        refused_load(tmp_path / name, fragment)
    nan = struct.pack("<18f", *([float("nan")] + [0.0] * 5 + [-1.0] * 3 + [0.0] * 3 + [0.0] * 3 + [1.0] * 3))
    (tmp_path / "nan.ply").write_bytes(_compressed_header(1, 1) + nan + words)
    refused_load(tmp_path / "nan.ply", "NaN or Inf in means")


def test_decoded_nan_and_bad_scales_in_splat(tmp_path):
    record = struct.pack("<6f", 0.0, 0.0, 0.0, 1.0, 1.0, 1.0) + bytes([128, 128, 128, 255, 255, 128, 128, 128])
    bad_pos = struct.pack("<6f", float("nan"), 0.0, 0.0, 1.0, 1.0, 1.0) + record[24:]
    (tmp_path / "nan.splat").write_bytes(record + bad_pos)
    refused_load(tmp_path / "nan.splat", "NaN or Inf in means")
    zero = struct.pack("<6f", 0.0, 0.0, 0.0, 1.0, 0.0, 1.0) + record[24:]
    (tmp_path / "zero.splat").write_bytes(record * 2 + zero)
    refused_load(tmp_path / "zero.splat", "zero, negative or non-finite scale", "[2]")
    (tmp_path / "empty.splat").write_bytes(b"")
    refused_load(tmp_path / "empty.splat", "empty")


def test_huge_declared_sizes_fail_fast_without_allocating(tmp_path):
    """Headers declaring ~1e11 elements on a 1 KB file: ValueError before any allocation, in every reader."""
    n = 10**11
    std = tmp_path / "std.ply"
    std.write_bytes(
        f"ply\nformat binary_little_endian 1.0\nelement vertex {n}\n".encode()
        + b"".join(f"property float {p}\n".encode() for p in ply.ply_property_names(0))
        + b"end_header\n"
        + b"\0" * 1024
    )
    compressed = tmp_path / "huge.compressed.ply"
    compressed.write_bytes(_compressed_header(math.ceil(n / 256), n, 45) + b"\0" * 1024)
    spz4 = tmp_path / "huge4.spz"
    spz4.write_bytes(struct.pack("<4sIIBBBBI12s", b"NGSP", 4, 2**32 - 1, 3, 12, 0, 6, 32, b"") + b"\0" * 1024)
    spz3 = tmp_path / "huge3.spz"
    spz3.write_bytes(gzip.compress(struct.pack("<4sIIBBBB", b"NGSP", 3, 2**32 - 1, 3, 12, 0, 0) + b"\0" * 1024))
    npz = tmp_path / "huge.npz"
    with zipfile.ZipFile(npz, "w") as zf:
        header = b"\x93NUMPY\x01\x00" + struct.pack("<H", 118)
        meta = f"{{'descr': '<f4', 'fortran_order': False, 'shape': ({n}, 3), }}".encode()
        zf.writestr("means.npy", header + meta.ljust(118 - 1) + b"\n" + b"\0" * 1024)
        _other_keys(zf)
    start = time.perf_counter()
    for path in (std, compressed, spz4, spz3, npz):
        with pytest.raises(ValueError) as info:
            formats.load_gaussians(path)
        assert str(path) in str(info.value) and ("truncated" in str(info.value) or "corrupt" in str(info.value))
    assert time.perf_counter() - start < 5.0


OTHER_NPZ_KEYS = ("quats", "log_scales", "opacity_logits", "sh")


def _other_keys(zf: zipfile.ZipFile) -> None:
    """Small valid members for every Gaussian key but ``means``."""
    for key in OTHER_NPZ_KEYS:
        buffer = io.BytesIO()
        np.save(buffer, np.zeros(1, np.float32))
        zf.writestr(f"{key}.npy", buffer.getvalue())


def test_garbage_npz_is_never_called_pickled(tmp_path):
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(os.urandom(2000))
    objects = tmp_path / "objects.npz"
    others = {k: np.zeros(1, np.float32) for k in OTHER_NPZ_KEYS}  # the keys are checked before any member is read
    np.savez(objects, means=np.array([{"a": 1}, None], dtype=object), **others)
    not_npy = tmp_path / "text.npz"
    with zipfile.ZipFile(not_npy, "w") as zf:
        zf.writestr("means.txt", "1 2 3")
    bad_member = tmp_path / "badmember.npz"
    with zipfile.ZipFile(bad_member, "w") as zf:
        zf.writestr("means.npy", os.urandom(300))
        _other_keys(zf)
    for path, fragment in [
        (garbage, ".npz"),
        (objects, "Python objects"),
        (not_npy, "not a .npy array"),
        (bad_member, "not a readable .npz archive"),
    ]:
        message = refused_load(path, fragment)
        assert "pickle" not in message.lower(), message


# ---- the real capture (measured data, skipped when absent) ---------------------------------------------------
def _real_splats() -> Path | None:
    return REAL_SPLATS if BIKER_SPZ.is_file() and BIKER_COMPRESSED_PLY.is_file() else None


def test_real_capture_decodes_the_same_from_both_formats():
    root = _real_splats()
    if root is None:
        pytest.skip("the real captures (shared/real-splats) are not present")
    timings = {}
    loaded = {}
    for name in ("biker.compressed.ply", "biker.spz"):
        start = time.perf_counter()
        loaded[name] = formats.load_gaussians_with_format(root / name)
        timings[name] = time.perf_counter() - start
    (c, cfmt), (s, sfmt) = loaded["biker.compressed.ply"], loaded["biker.spz"]
    assert (cfmt, sfmt) == ("compressed_ply", "spz")
    assert c.num == s.num == 152_746
    assert max(timings.values()) < 3.0, timings
    # the same Gaussians in the same order: positions within both quantisations (spz 1/8192, chunks 11-10-11)
    assert (c.means - s.means).abs().max().item() < 5e-4
    lo, hi = c.means.min(0).values, c.means.max(0).values
    assert (hi[1] - lo[1]).item() == pytest.approx(3.2, abs=0.1)  # the person is ~3.2 units tall
    assert lo[1].item() < -3.0 and hi[1].item() > -0.05  # y-down: head at -y, feet at y = 0 (the +y end)
    torch.testing.assert_close(s.means.min(0).values, lo, rtol=0, atol=5e-4)
    torch.testing.assert_close(s.means.max(0).values, hi, rtol=0, atol=5e-4)
    assert (c.opacities - s.opacities).abs().max().item() <= 1 / 255 + 1e-6
    inside = ((c.log_scales > -10 + 1 / 32) & (c.log_scales < 255 / 16 - 10 - 1 / 32)).all(1)
    assert inside.float().mean() > 0.99  # spz clamps log-scales to [-10, 5.94]
    assert (c.log_scales[inside] - s.log_scales[inside]).abs().max().item() < 1 / 32 + 1e-3
    assert (sign_aligned(s.quats, c.quats) - c.quats / c.quats.norm(dim=1, keepdim=True)).abs().max() < 5e-3
    assert (c.sh[:, 0] - s.sh[:, 0]).abs().max().item() < 0.5 / (0.15 * 255) + 1e-3


def test_ply_vertices_one_type_table_equals_mixed_records(tmp_path):
    """A PLY of one scalar type is read as one table (columns are views); the same values written with a mixed
    layout (a uchar column, big-endian doubles) are read record by record: both give the same float32 columns."""
    from recon.formats.ply import read_ply_vertices

    rng = np.random.default_rng(3)
    n, names = 257, ["x", "y", "z", "opacity"]
    values = rng.normal(size=(n, len(names))).astype(np.float32)

    def write(path, fmt, types, rows):
        props = "".join(f"property {t} {p}\n" for p, t in zip(names + ["red"][: len(types) - 4], types, strict=True))
        head = f"ply\nformat {fmt} 1.0\nelement vertex {n}\n{props}end_header\n".encode()
        path.write_bytes(head + rows.tobytes())

    write(tmp_path / "one.ply", "binary_little_endian", ["float"] * 4, values)
    mixed = np.zeros(n, [(p, ">f8") for p in names] + [("red", "u1")])
    for i, p in enumerate(names):
        mixed[p] = values[:, i]
    mixed["red"] = np.arange(n) % 256
    write(tmp_path / "mixed.ply", "binary_big_endian", ["double"] * 4 + ["uchar"], mixed)
    one, other = read_ply_vertices(tmp_path / "one.ply"), read_ply_vertices(tmp_path / "mixed.ply")
    assert list(one) == names and list(other) == names + ["red"]
    for p in names:
        assert one[p].dtype == np.float32 and np.array_equal(one[p], other[p])
    assert np.array_equal(other["red"], (np.arange(n) % 256).astype(np.float32))
