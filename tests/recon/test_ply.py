"""3DGS .ply / .npz I/O: exact round trips, the reference trainer's channel-major f_rest layout, bad files."""

import re

import numpy as np
import pytest
import torch

from recon.formats import load_gaussians
from recon.formats.ply import ply_property_names, save_gaussians
from recon.gaussians import GaussianSet


def _random_set(n: int, degree: int, seed: int = 0) -> GaussianSet:
    gen = torch.Generator().manual_seed(seed)
    k = (degree + 1) ** 2
    return GaussianSet(
        torch.randn(n, 3, generator=gen),
        torch.randn(n, 4, generator=gen),
        torch.randn(n, 3, generator=gen),
        torch.randn(n, generator=gen),
        torch.randn(n, k, 3, generator=gen),
    )


def _reference_names(degree: int) -> list[str]:
    """Attribute list built the way the reference trainer's construct_list_of_attributes does."""
    rest = 3 * ((degree + 1) ** 2 - 1)
    names = ["x", "y", "z", "nx", "ny", "nz"]
    names += [f"f_dc_{i}" for i in range(3)]
    names += [f"f_rest_{i}" for i in range(rest)]
    names += ["opacity"]
    names += [f"scale_{i}" for i in range(3)]
    names += [f"rot_{i}" for i in range(4)]
    return names


def _write_ply(path, names, table, fmt="binary_little_endian", types=None, extra_header="", tail=b""):
    """A PLY written with numpy only: one vertex element with the given columns."""
    types = types or ["float"] * len(names)
    header = f"ply\nformat {fmt} 1.0\ncomment written by the test\nelement vertex {len(table)}\n"
    header += "".join(f"property {t} {p}\n" for t, p in zip(types, names, strict=True))
    header += extra_header + "end_header\n"
    np_types = {"float": "f4", "double": "f8", "uchar": "u1", "int": "i4"}
    if fmt == "ascii":
        body = "".join(
            " ".join(
                repr(float(v)) if t in ("float", "double") else str(int(v)) for v, t in zip(row, types, strict=True)
            )
            + "\n"
            for row in table
        ).encode()
    else:
        order = "<" if fmt == "binary_little_endian" else ">"
        rows = np.zeros(len(table), dtype=[(p, order + np_types[t]) for p, t in zip(names, types, strict=True)])
        for i, p in enumerate(names):
            rows[p] = table[:, i]
        body = rows.tobytes()
    path.write_bytes(header.encode() + body + tail)
    return path


def _reference_save(g: GaussianSet, path):
    """The reference trainer's save_ply, rebuilt with numpy: features_rest [N, K-1, 3] -> [N, 3, K-1] -> flat."""
    n = g.num
    f_dc = g.sh[:, :1].transpose(1, 2).flatten(start_dim=1).numpy()
    f_rest = g.sh[:, 1:].transpose(1, 2).flatten(start_dim=1).numpy()
    attrs = np.concatenate(
        [
            g.means.numpy(),
            np.zeros((n, 3), np.float32),
            f_dc,
            f_rest,
            g.opacity_logits[:, None].numpy(),
            g.log_scales.numpy(),
            g.quats.numpy(),
        ],
        axis=1,
    )
    return _write_ply(path, _reference_names(g.sh_degree), attrs)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
@pytest.mark.parametrize("suffix", [".ply", ".npz"])
def test_round_trip_is_exact(tmp_path, degree, suffix):
    g = _random_set(50, degree, seed=degree)
    path = save_gaussians(g, tmp_path / "sub" / f"g{suffix}")
    back = load_gaussians(path)
    assert back.sh_degree == degree and back.num == 50
    for a, b in zip(g.tensors(), back.tensors(), strict=True):
        assert a.dtype == b.dtype == torch.float32 and torch.equal(a, b)
    assert sorted(p.name for p in path.parent.iterdir()) == [f"g{suffix}"]  # no temporary left behind


def test_written_header_and_f_rest_layout_match_the_reference(tmp_path):
    k = 16
    g = _random_set(4, 3)
    g.sh[:, 1:] = torch.tensor([[c * (k - 1) + j for c in range(3)] for j in range(k - 1)], dtype=torch.float32)
    path = save_gaussians(g, tmp_path / "g.ply")
    raw = path.read_bytes()
    header = (
        "ply\nformat binary_little_endian 1.0\nelement vertex 4\n"
        + "".join(f"property float {p}\n" for p in _reference_names(3))
        + "end_header\n"
    ).encode()
    assert raw.startswith(header) and ply_property_names(3) == _reference_names(3)
    rows = np.frombuffer(raw[len(header) :], dtype=[(p, "<f4") for p in _reference_names(3)])
    assert rows.shape == (4,)
    for i in range(45):
        assert np.all(rows[f"f_rest_{i}"] == i)
    assert np.all(rows["nx"] == 0) and np.array_equal(rows["rot_2"], g.quats[:, 2].numpy())
    assert np.array_equal(rows["opacity"], g.opacity_logits.numpy())


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_hand_built_file_reads_channel_major(tmp_path, degree):
    k = (degree + 1) ** 2
    names = _reference_names(degree)
    table = np.zeros((3, len(names)), np.float32)
    for i in range(3 * (k - 1)):
        table[:, names.index(f"f_rest_{i}")] = i
    table[:, names.index("rot_0")] = 1.0
    g = load_gaussians(_write_ply(tmp_path / "hand.ply", names, table))
    for c in range(3):
        for j in range(k - 1):
            assert torch.all(g.sh[:, j + 1, c] == c * (k - 1) + j)


def test_reads_a_reference_layout_degree_3_file(tmp_path):
    g = _random_set(30, 3, seed=7)
    back = load_gaussians(_reference_save(g, tmp_path / "point_cloud.ply"))
    for a, b in zip(g.tensors(), back.tensors(), strict=True):
        assert torch.equal(a, b)


@pytest.mark.parametrize("fmt", ["ascii", "binary_big_endian"])
def test_reads_ascii_big_endian_mixed_types_and_extra_elements(tmp_path, fmt):
    g = _random_set(6, 1, seed=3).map(lambda t: t.double().float())
    names = _reference_names(1) + ["red"]
    table = np.concatenate(
        [
            g.means.numpy(),
            np.zeros((6, 3)),
            g.sh[:, 0].numpy(),
            g.sh[:, 1:].transpose(1, 2).reshape(6, 9).numpy(),
            g.opacity_logits[:, None].numpy(),
            g.log_scales.numpy(),
            g.quats.numpy(),
            np.full((6, 1), 200),
        ],
        1,
    )
    types = ["double"] * 3 + ["float"] * (len(names) - 4) + ["uchar"]
    extra = "element face 1\nproperty list uchar int vertex_indices\n"
    tail = b"3 0 1 2\n" if fmt == "ascii" else bytes([3]) + np.array([0, 1, 2], ">i4").tobytes()
    back = load_gaussians(_write_ply(tmp_path / "g.ply", names, table, fmt, types, extra, tail))
    for a, b in zip(g.tensors(), back.tensors(), strict=True):
        assert torch.allclose(a, b, rtol=1e-6, atol=1e-6)


def test_reads_gsplat_style_npz(tmp_path):
    g = _random_set(8, 2)
    np.savez(
        tmp_path / "ckpt.npz",
        means=g.means.numpy(),
        quats=g.quats.numpy(),
        scales=g.log_scales.numpy(),
        opacities=g.opacity_logits.numpy(),
        sh0=g.sh[:, :1].numpy(),
        shN=g.sh[:, 1:].numpy(),
    )
    back = load_gaussians(tmp_path / "ckpt.npz")
    for a, b in zip(g.tensors(), back.tensors(), strict=True):
        assert torch.equal(a, b)


def _valid_table(n=3):
    names = _reference_names(0)
    table = np.zeros((n, len(names)), np.float32)
    table[:, names.index("rot_0")] = 1.0
    return names, table


def _bad_files(tmp_path):
    names, table = _valid_table()
    out = {}
    out["not a PLY"] = tmp_path / "text.ply"
    out["not a PLY"].write_text("hello\nworld\n")
    out["missing"] = _write_ply(
        tmp_path / "cloud.ply",
        ["x", "y", "z", "red", "green", "blue"],
        np.ones((3, 6)),
        types=["float"] * 3 + ["uchar"] * 3,
    )
    full = _write_ply(tmp_path / "full.ply", names, table).read_bytes()
    out["truncated"] = tmp_path / "cut.ply"
    out["truncated"].write_bytes(full[:-10])
    nan = table.copy()
    nan[1, names.index("scale_1")] = np.nan
    out["NaN or Inf"] = _write_ply(tmp_path / "nan.ply", names, nan)
    inf = table.copy()
    inf[2, names.index("x")] = np.inf
    out["NaN or Inf in means"] = _write_ply(tmp_path / "inf.ply", names, inf)
    zero = table.copy()
    zero[0, names.index("rot_0")] = 0.0
    out["zero rotation quaternion"] = _write_ply(tmp_path / "zeroquat.ply", names, zero)
    out["empty"] = _write_ply(tmp_path / "empty.ply", names, table[:0])
    rest = names[:9] + [f"f_rest_{i}" for i in range(10)] + names[9:]
    out["10 f_rest properties"] = _write_ply(tmp_path / "rest10.ply", rest, np.ones((3, len(rest))))
    out["binary_middle_endian"] = tmp_path / "fmt.ply"
    out["binary_middle_endian"].write_bytes(full.replace(b"binary_little_endian", b"binary_middle_endian"))
    out["comes before 'vertex'"] = tmp_path / "order.ply"
    face = b"element face 2\nproperty list uchar int vertex_indices\nelement vertex"  # list rows: cannot be skipped
    out["comes before 'vertex'"].write_bytes(full.replace(b"element vertex", face))
    out["no 'end_header'"] = tmp_path / "noend.ply"
    out["no 'end_header'"].write_bytes(full.split(b"end_header")[0])
    out["not a readable .npz"] = tmp_path / "junk.npz"
    out["not a readable .npz"].write_bytes(b"not a zip")
    out["lacks the Gaussian arrays"] = tmp_path / "keys.npz"
    np.savez(out["lacks the Gaussian arrays"], means=np.zeros((3, 3)))
    out["must have shape"] = tmp_path / "shape.npz"
    np.savez(
        out["must have shape"],
        means=np.zeros((3, 3)),
        quats=np.ones((3, 3)),
        log_scales=np.zeros((3, 3)),
        opacity_logits=np.zeros(3),
        sh=np.zeros((3, 1, 3)),
    )
    return out


def test_bad_files_raise_naming_the_file_and_problem(tmp_path):
    for problem, path in _bad_files(tmp_path).items():
        with pytest.raises(ValueError) as info:
            load_gaussians(path)
        message = str(info.value)
        assert str(path) in message, message
        assert problem in message, message


def test_missing_file_and_wrong_suffix(tmp_path):
    with pytest.raises(FileNotFoundError, match=re.escape(str(tmp_path / "none.ply"))):
        load_gaussians(tmp_path / "none.ply")
    (tmp_path / "g.txt").write_text("x y z\n")
    with pytest.raises(ValueError, match=r"\.txt"):
        load_gaussians(tmp_path / "g.txt")
    with pytest.raises(ValueError, match=r"\.obj"):
        save_gaussians(_random_set(2, 0), tmp_path / "g.obj")


def test_save_refuses_bad_sets_and_keeps_the_old_file(tmp_path):
    path = save_gaussians(_random_set(5, 0), tmp_path / "g.ply")
    before = path.read_bytes()
    bad = _random_set(5, 0)
    bad.means[3, 0] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        save_gaussians(bad, path)
    with pytest.raises(ValueError, match="empty"):
        save_gaussians(_random_set(5, 0).subset(torch.zeros(5, dtype=torch.bool)), path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["g.ply"]
