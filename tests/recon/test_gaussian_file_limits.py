"""Gaussian files with extreme numbers or broken headers: each refused in one line naming the Gaussians or the header
(no overflowed count, no traceback)."""

import numpy as np
import pytest
import torch

from apps import cli
from recon.formats.ply import save_gaussians
from recon.gaussians import GaussianSet

from helpers.logs import error_text
from helpers.spheres import sphere_gaussians


@pytest.mark.parametrize(
    "field, value, what",
    [
        ("means", 1e38, "a centre coordinate beyond +-1e15 scene units"),
        ("log_scales", 88.0, "a log-scale beyond +-30"),
        ("log_scales", -88.0, "a log-scale beyond +-30"),
    ],
)
def test_extreme_means_and_scales_name_the_gaussians(tmp_path, caplog, capsys, field, value, what):
    """Means of 1e38 and log-scales of +-88 printed 113-digit counts from an int64 overflow (or passed silently)."""
    props = ("x", "y", "z") if field == "means" else ("scale_0", "scale_1", "scale_2")
    path = _patched_ply(save_gaussians(sphere_gaussians(), tmp_path / "x.ply"), [3, 7], props, value)
    assert cli.main(["inspect", str(path), "--threads", "1"]) == 2
    msg = error_text(caplog)
    assert f"2 Gaussians have {what}" in msg and "first rows [3, 7]" in msg and f"{value:.3g}" in msg
    assert ",000,000" not in msg and "Traceback" not in capsys.readouterr().err


def _patched_ply(path, rows, props, value):
    """``path`` (a binary float32 3DGS .ply) with ``props`` of ``rows`` set to ``value`` (the writer refuses it)."""
    raw = path.read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    names = [line.split()[-1].decode() for line in raw[:end].splitlines() if line.startswith(b"property")]
    table = np.frombuffer(raw[end:], np.float32).reshape(-1, len(names)).copy()
    for p in props:
        table[rows, names.index(p)] = value
    path.write_bytes(raw[:end] + table.tobytes())
    return path


def test_subnormal_centres_are_named_as_such_by_scale_auto(tmp_path, caplog):
    path = save_gaussians(sphere_gaussians(), tmp_path / "tiny.ply")
    raw = path.read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    names = [line.split()[-1].decode() for line in raw[:end].splitlines() if line.startswith(b"property")]
    table = np.frombuffer(raw[end:], np.float32).reshape(-1, len(names)).copy()
    table[:, :3] = sphere_gaussians().means.numpy() * 1e-39  # subnormal float32 centres (0 where Taichi flushes them)
    path.write_bytes(raw[:end] + table.tobytes())
    assert cli.main(["inspect", str(path), "--threads", "1"]) == 2
    assert "centres coincide or nearly" in error_text(caplog) and "pass --scale" in error_text(caplog)


@pytest.mark.parametrize(
    "body, what",
    [
        (b"\x00\x01\x02garbage" * 2000, "runs past 4,096 bytes"),
        (b"\xff\xfe\x80\n" * 10, "before the non-ASCII bytes at byte 70"),
        (b"comment a\n" * 20000, "within its first 10,000 lines"),
    ],
    ids=["binary", "non-ascii", "endless"],
)
def test_a_ply_header_that_never_ends_says_so(tmp_path, body, what):
    """A header with no end_header was reported as an unknown keyword (the data read as one)."""
    from recon import load_gaussians

    path = tmp_path / "noend.ply"
    path.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\n" + body)
    with pytest.raises(ValueError) as info:
        load_gaussians(path)
    assert "has no 'end_header' line" in str(info.value) and what in str(info.value)
    assert "unknown PLY header keyword" not in str(info.value)


def test_a_gaussian_set_with_1d_means_names_the_shape_not_n_minus_1():
    with pytest.raises(ValueError) as info:
        GaussianSet(torch.zeros(3), torch.zeros(1, 4), torch.zeros(1, 3), torch.zeros(1), torch.zeros(1, 1, 3))
    assert "GaussianSet.means must have shape (N, 3)" in str(info.value) and "-1" not in str(info.value)
