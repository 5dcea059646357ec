"""Regressions found by a new-user sweep of issues 14 (real captures in) and 18 (no data loss, no empty result).

Each test builds its own small files; none needs Taichi except where a CLI command runs.
"""

from __future__ import annotations

import gzip
import struct
import warnings

import numpy as np
import pytest
import torch

from recon import formats
from recon.formats.ply import ply_property_names, save_gaussians
from recon.gaussians import SH_C0, GaussianSet

from helpers.format_encoders import encode_compressed_ply, encode_splat, encode_spz
from helpers.paths import REPO
from helpers.splat_sets import refused_load


def _set(n: int, degree: int, seed: int = 0) -> GaussianSet:
    gen = torch.Generator().manual_seed(seed)
    quats = torch.randn(n, 4, generator=gen)
    k = (degree + 1) ** 2
    rgb = 0.05 + 0.9 * torch.rand(n, 3, generator=gen)
    sh = torch.cat([((rgb - 0.5) / SH_C0)[:, None], 1.6 * torch.rand(n, k - 1, 3, generator=gen) - 0.8], 1)
    return GaussianSet(
        means=2 * torch.rand(n, 3, generator=gen) - 1,
        quats=quats / quats.norm(dim=1, keepdim=True),
        log_scales=-3 - 2 * torch.rand(n, 3, generator=gen),
        opacity_logits=torch.randn(n, generator=gen),
        sh=sh,
    )


def _standard_ply(g: GaussianSet, fmt: str, before: list[str], before_bytes: bytes) -> bytes:
    """A 3DGS .ply of ``g`` with extra elements (header lines ``before``, data ``before_bytes``) ahead of vertex."""
    names = ply_property_names(g.sh_degree)
    n = g.num
    cols = {"x": g.means[:, 0], "y": g.means[:, 1], "z": g.means[:, 2], "opacity": g.opacity_logits}
    cols.update({f"f_dc_{c}": g.sh[:, 0, c] for c in range(3)})
    rest = g.sh[:, 1:].permute(0, 2, 1).reshape(n, -1)
    cols.update({f"f_rest_{i}": rest[:, i] for i in range(rest.shape[1])})
    cols.update({f"scale_{i}": g.log_scales[:, i] for i in range(3)})
    cols.update({f"rot_{i}": g.quats[:, i] for i in range(4)})
    table = np.stack([cols[p].numpy() if p in cols else np.zeros(n, np.float32) for p in names], 1).astype(np.float32)
    header = ["ply", f"format {fmt} 1.0", "comment sweep"] + before + [f"element vertex {n}"]
    header += [f"property float {p}" for p in names] + ["end_header"]
    if fmt == "ascii":
        body = "".join(" ".join(repr(float(v)) for v in row) + "\n" for row in table).encode()
    else:
        body = table.astype(">f4" if fmt == "binary_big_endian" else "<f4").tobytes()
    return ("\n".join(header) + "\n").encode() + before_bytes + body


@pytest.mark.parametrize("fmt", ["binary_little_endian", "binary_big_endian", "ascii"])
def test_standard_ply_with_an_element_before_vertex_loads(tmp_path, fmt):
    """A camera / metadata element ahead of 'vertex' used to be refused; its rows are now skipped."""
    g = _set(7, 1)
    before = ["element camera 2", "property float fx", "property uchar kind", "element empty 0", "property int a"]
    if fmt == "ascii":
        data = b"1.5 3\n2.5 4\n"
    else:
        order = ">" if fmt == "binary_big_endian" else "<"
        data = np.array([(1.5, 3), (2.5, 4)], dtype=[("fx", order + "f4"), ("kind", "u1")]).tobytes()
    path = tmp_path / "cam_first.ply"
    path.write_bytes(_standard_ply(g, fmt, before, data))
    back, fmt_name = formats.load_gaussians_with_format(path)
    assert fmt_name == "ply" and back.num == 7 and back.sh_degree == 1
    torch.testing.assert_close(back.means, g.means, rtol=0, atol=1e-6)
    torch.testing.assert_close(back.sh, g.sh, rtol=0, atol=1e-6)


def test_element_before_vertex_that_cannot_be_skipped(tmp_path):
    g = _set(3, 0)
    lists = _standard_ply(
        g,
        "binary_little_endian",
        ["element face 1", "property list uchar int idx"],
        bytes([3]) + struct.pack("<3i", 0, 1, 2),
    )
    (tmp_path / "list.ply").write_bytes(lists)
    refused_load(tmp_path / "list.ply", "'face'", "comes before 'vertex'", "list properties", "re-export")
    cut = _standard_ply(g, "binary_little_endian", ["element camera 1000", "property double fx"], b"")
    (tmp_path / "cut.ply").write_bytes(cut)
    refused_load(tmp_path / "cut.ply", "'camera'", "truncated or corrupt")


@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.parametrize("declared", [0, 1, 3])
def test_spz_sh_degree_not_matching_the_data_is_named(tmp_path, version, declared):
    """A gzip .spz whose header SH degree differs from the arrays: the message says which degree the data has."""
    actual = 2
    path = encode_spz(_set(40, actual), tmp_path / "g.spz", version=version)
    raw = bytearray(gzip.decompress(path.read_bytes()))
    raw[12] = declared
    bad = tmp_path / f"sh{declared}.spz"
    bad.write_bytes(gzip.compress(bytes(raw)))
    refused_load(bad, "SH data does not match the header", f"declares SH degree {declared}", f"SH degree {actual};")


def test_spz_missing_gzip_trailer_says_so(tmp_path):
    path = encode_spz(_set(30, 1), tmp_path / "g.spz", version=3)
    cut = tmp_path / "cut.spz"
    cut.write_bytes(path.read_bytes()[:-4])  # the CRC32 and length trailer incomplete, all data there
    message = refused_load(cut, "truncated .spz", "trailer", "re-download")
    assert " of " not in message.split("(")[-1], message  # no "N of N bytes" that reads as complete


def test_spz_v4_truncated_names_the_fix(tmp_path):
    path = encode_spz(_set(30, 1), tmp_path / "g.spz", version=4)
    cut = tmp_path / "cut.spz"
    cut.write_bytes(path.read_bytes()[:-7])
    refused_load(cut, "truncated .spz", "re-download")


def test_splat_with_another_suffix_suggests_renaming(tmp_path):
    path = encode_splat(_set(2, 0), tmp_path / "g.splat")
    wrong = tmp_path / "g.ply"
    wrong.write_bytes(path.read_bytes())
    refused_load(wrong, "antimatter15 .splat", "rename it to g.splat")
    odd = tmp_path / "h.ply"
    odd.write_bytes(path.read_bytes()[:-1])
    assert "rename" not in refused_load(odd, "not a PLY file")


def test_non_finite_chunk_bounds_warn_nothing(tmp_path):
    """NaN / Inf chunk bounds: one ValueError, no numpy RuntimeWarning on the way."""
    path = encode_compressed_ply(_set(300, 0), tmp_path / "c.ply")
    data = bytearray(path.read_bytes())
    start = data.index(b"end_header\n") + len(b"end_header\n")
    data[start + 4 : start + 8] = struct.pack("<f", float("inf"))  # chunk 0 min_y
    bad = tmp_path / "inf.ply"
    bad.write_bytes(bytes(data))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        refused_load(bad, "NaN or Inf in means")


def test_formats_agree_on_count_and_box(tmp_path):
    """One set through standard .ply, compressed .ply (N not a multiple of 256), .splat and .spz v2/v3/v4."""
    g = _set(1000, 0)
    paths = {
        "ply": tmp_path / "g.ply",
        "compressed_ply": encode_compressed_ply(g, tmp_path / "g.compressed.PLY"),
        "splat": encode_splat(g, tmp_path / "g.SPLAT"),
    }
    save_gaussians(g, paths["ply"])
    for v in (2, 3, 4):
        paths[f"spz{v}"] = encode_spz(g, tmp_path / f"g{v}.spz", version=v)
    lo, hi = g.means.min(0).values, g.means.max(0).values
    for name, path in paths.items():
        back, fmt = formats.load_gaussians_with_format(path)
        assert fmt == name.rstrip("234") and back.num == 1000, name
        step = 2.0**-12 if fmt == "spz" else 2.0 / 1023  # spz fixed point; 10-bit y of the packed position
        torch.testing.assert_close(back.means.min(0).values, lo, rtol=0, atol=step, msg=name)
        torch.testing.assert_close(back.means.max(0).values, hi, rtol=0, atol=step, msg=name)


@pytest.mark.parametrize(
    ("spec", "expected"),
    [
        ("1e200,0,0", [1, 0, 0]),
        ("0,-1e300,1e300", [0, -(0.5**0.5), 0.5**0.5]),
        ("1e-200,0,0", [1, 0, 0]),
        ("0,-1e-300,0", [0, -1, 0]),
    ],
)
def test_up_vectors_of_any_finite_size_give_their_direction(spec, expected):
    """A huge --up used to overflow the norm and come back as the zero vector (silently no up at all)."""
    from nbv.physics.scene_frame import parse_up

    np.testing.assert_allclose(parse_up(spec), expected, atol=1e-12)


@pytest.mark.parametrize("spec", ["0,0,0", "w", "1,2", "nan,1,0", "0,inf,0", "0,-0,0"])
def test_bad_up_vectors_still_refused(spec):
    from nbv.physics.scene_frame import parse_up

    with pytest.raises(ValueError, match="--up"):
        parse_up(spec)


def test_ctrl_c_inside_an_extension_import_is_one_line(monkeypatch, caplog):
    """Ctrl-C while open3d/torch load inside a command: an ImportError caused by KeyboardInterrupt -> exit 130."""
    from apps import cli, inspect_gaussians

    def interrupted_import(args):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as ki:
            raise ImportError("initialization failed") from ki

    monkeypatch.setattr(inspect_gaussians, "run_command", interrupted_import)
    assert cli.main(["inspect", "g.ply"]) == 130
    assert "interrupted" in caplog.text

    def broken_import(args):
        raise ImportError("no module named nowhere")

    monkeypatch.setattr(inspect_gaussians, "run_command", broken_import)
    with pytest.raises(ImportError):  # a real import failure stays a traceback (a bug to report)
        cli.main(["inspect", "g.ply"])


def test_ctrl_c_while_the_cli_loads_is_one_line(tmp_path):
    """Ctrl-C while the chosen command's module loads (importing torch/Taichi, seconds; `fluidgs` imports only that
    command's module, inside main): exit 130, no traceback."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "class Stop:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name == 'apps.active':\n"
        "            raise KeyboardInterrupt\n"
        "sys.meta_path.insert(0, Stop())\n"
        "from apps.cli import main\n"
        "sys.exit(main(['active', '--help']))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert done.returncode == 130, done.stderr
    assert "Traceback" not in done.stderr and "interrupted" in done.stderr, done.stderr
