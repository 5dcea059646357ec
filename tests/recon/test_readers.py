"""SOG, .ksplat, trained checkpoints (gsplat, nerfstudio), the .spz frame choice and bounded decompression.

Round trips through encoders written from each definition (tests/helpers/format_encoders.py) hold within the
quantisation; records built byte by byte decode to the values the definition gives; checkpoints in the trainers'
normalised frames come back in the metric frame; hostile files fail fast with the file named; the real captures
decode to the compressed .ply's count and box.
"""

import gzip
import io
import json
import logging
import math
import struct
import zipfile

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from recon import formats
from recon.formats.checkpoints import gsplat_normalization, load_trained_model
from recon.gaussians import SH_C0, GaussianSet
from recon.sh import eval_sh
from recon.similarity import invert_similarity, transform_gaussians

from helpers.format_encoders import _webp, encode_ksplat, encode_sog, encode_spz
from helpers.paths import BIKER_COMPRESSED_PLY, REAL_SPLATS
from helpers.splat_sets import assert_within, random_splats, sign_aligned

SQRT2 = math.sqrt(2.0)


def _raises(path, *fragments, **options):
    with pytest.raises(ValueError) as info:
        formats.load_gaussians_framed(path, formats.LoadOptions(**options))
    message = str(info.value)
    assert str(path) in message, message
    for fragment in fragments:
        assert fragment in message, message
    return message


# ---- SOG ---------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("version,degree,bundle", [(2, 0, True), (2, 3, False), (1, 0, False), (1, 2, True)])
def test_sog_round_trip_within_quantisation(tmp_path, version, degree, bundle):
    g = random_splats(300, degree, seed=version + degree)
    path = encode_sog(g, tmp_path / ("g.sog" if bundle else "g"), version=version, bundle=bundle)
    for target in [path] if bundle else [path, path / "meta.json"]:
        back, fmt, frame = formats.load_gaussians_framed(target)
        assert fmt == "sog" and back.num == g.num and back.sh_degree == degree and frame.metric
        logs = torch.sign(g.means) * torch.log1p(g.means.abs())
        span = logs.max(0).values - logs.min(0).values
        got = torch.sign(back.means) * torch.log1p(back.means.abs())
        assert_within(got, logs, span / 65535 / 2 + 1e-6, "means (log domain)")
        step = (g.log_scales.max() - g.log_scales.min()) / 255
        tol = step / 2 if version == 2 else (g.log_scales.max(0).values - g.log_scales.min(0).values) / 255 / 2
        assert_within(back.log_scales, g.log_scales, tol, "log-scales")
        dc_tol = (
            (
                (g.sh[:, 0].max() - g.sh[:, 0].min())
                if version == 2
                else (g.sh[:, 0].max(0).values - g.sh[:, 0].min(0).values)
            )
            / 255
            / 2
        )
        assert_within(back.sh[:, 0], g.sh[:, 0], dc_tol, "SH DC")
        if version == 2:
            assert_within(back.opacities, g.opacities, 0.5 / 255, "opacity")
        else:  # the logit is quantised linearly
            logit_tol = (g.opacity_logits.max() - g.opacity_logits.min()) / 255 / 2
            assert_within(back.opacity_logits, g.opacity_logits, logit_tol, "opacity logits")
        assert_within(sign_aligned(back.quats, g.quats), g.quats / g.quats.norm(dim=1, keepdim=True), 6e-3, "rotation")
        if degree:
            rest_tol = (g.sh[:, 1:].max() - g.sh[:, 1:].min()) / 255 / 2
            assert_within(back.sh[:, 1:], g.sh[:, 1:], rest_tol, "SH rest")


def _sog_one(tmp_path, pixels: dict, meta: dict, name="one.sog"):
    path = tmp_path / name
    with zipfile.ZipFile(path, "w") as zf:
        for image, rgba in pixels.items():
            zf.writestr(image, _webp(np.array(rgba, np.uint8).reshape(1, -1, 4)))
        zf.writestr("meta.json", json.dumps(meta))
    return path


def _sog_meta(**extra):
    book = [-5.0 + 0.04 * i for i in range(256)]
    meta = {
        "version": 2,
        "count": 1,
        "means": {"mins": [-1.0, 0.0, -2.0], "maxs": [1.0, 2.0, 2.0], "files": ["l.webp", "u.webp"]},
        "scales": {"codebook": book, "files": ["s.webp"]},
        "quats": {"files": ["q.webp"]},
        "sh0": {"codebook": book, "files": ["c.webp"]},
    }
    meta.update(extra)
    return meta


def _sog_pixels(quat_tag=254):
    q = (0x8000, 0xFFFF, 0x4000)  # x, y, z 16-bit codes
    return {
        "l.webp": [[v & 0xFF for v in q] + [255]],
        "u.webp": [[v >> 8 for v in q] + [255]],
        "s.webp": [[0, 100, 255, 255]],
        "q.webp": [[200, 60, 128, quat_tag]],
        "c.webp": [[10, 20, 30, 51]],
    }


def test_sog_record_by_hand(tmp_path):
    g = formats.load_gaussians(_sog_one(tmp_path, _sog_pixels(), _sog_meta()))
    logs = [-1.0 + 2.0 * 0x8000 / 65535, 2.0, -2.0 + 4.0 * 0x4000 / 65535]
    want = [math.copysign(math.expm1(abs(v)), v) for v in logs]
    torch.testing.assert_close(g.means[0], torch.tensor(want), rtol=0, atol=1e-5)
    torch.testing.assert_close(g.log_scales[0], torch.tensor([-5.0, -1.0, 5.2]), rtol=0, atol=1e-5)
    torch.testing.assert_close(g.sh[0, 0], torch.tensor([-4.6, -4.2, -3.8]), rtol=0, atol=1e-5)
    assert g.opacities[0].item() == pytest.approx(51 / 255, abs=1e-6)
    a, b, c = ((v / 255 * 2 - 1) / SQRT2 for v in (200, 60, 128))
    d = math.sqrt(1 - a * a - b * b - c * c)  # tag 254: y (index 2 of w, x, y, z) is the largest
    torch.testing.assert_close(g.quats[0], torch.tensor([a, b, d, c]), rtol=0, atol=1e-6)


def test_sog_bad_input(tmp_path):
    pixels = _sog_pixels()
    del pixels["s.webp"]
    _raises(_sog_one(tmp_path, pixels, _sog_meta(), "missing.sog"), "'s.webp'", "missing")
    _raises(
        _sog_one(tmp_path, _sog_pixels(), _sog_meta(count=5), "count.sog"),
        "fewer than the 5 Gaussians",
        "count larger than the images hold",
    )
    _raises(_sog_one(tmp_path, _sog_pixels(), _sog_meta(version=3), "v3.sog"), "SOG version 3 is not supported")
    _raises(_sog_one(tmp_path, _sog_pixels(quat_tag=17), _sog_meta(), "tag.sog"), "reserved mode byte")
    folder = encode_sog(random_splats(20, 1), tmp_path / "folder", bundle=False)
    (folder / "shN_labels.webp").unlink()
    _raises(folder, "'shN_labels.webp'", "missing")


# ---- .ksplat -----------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("mode,degree,sections", [(0, 0, 1), (0, 2, 2), (1, 1, 2), (2, 2, 1), (2, 0, 3)])
def test_ksplat_round_trip_within_quantisation(tmp_path, mode, degree, sections):
    g = random_splats(500, degree, seed=mode)
    path = encode_ksplat(g, tmp_path / "g.ksplat", mode=mode, sections=sections)
    back, fmt, _ = formats.load_gaussians_framed(path)
    assert fmt == "ksplat" and back.num == g.num and back.sh_degree == degree
    if mode == 0:
        assert torch.equal(back.means, g.means)
        assert_within(back.log_scales, g.log_scales, 1e-5, "log-scales")
    else:
        assert_within(back.means, g.means, 3e-4, "means (u16 in buckets)")  # block / 2 / 32767 / 2 with block < 4
        assert_within(back.log_scales, g.log_scales, 2.0**-11 + 1e-4, "log-scales (f16: relative 2^-11)")
    assert_within(back.sh[:, 0] * SH_C0 + 0.5, g.sh[:, 0] * SH_C0 + 0.5, 0.5 / 255, "colour")
    assert_within(back.opacities, g.opacities, 0.5 / 255, "opacity")
    assert_within(sign_aligned(back.quats, g.quats), g.quats, 1e-6 if mode == 0 else 1e-3, "rotation")
    if degree:
        tol = {0: 1e-6, 1: 1e-3, 2: 3.0 / 255 / 2}[mode]
        assert_within(back.sh[:, 1:], g.sh[:, 1:], tol, "SH rest")


def _ksplat_one(path, mode=1, version=(0, 1), records=None, count=1):
    header = bytearray(4096)
    header[0], header[1] = version
    struct.pack_into("<IIIII", header, 4, 1, 1, count, count, count)  # sections, -, max splats, splats
    struct.pack_into("<H", header, 20, mode)
    section = bytearray(1024)
    struct.pack_into("<IIIIfHHI", section, 0, count, count, 64, 1, 2.0, 12, 0, 1000)
    struct.pack_into("<IIH", section, 32, 0, 1, 0)  # no full bucket, one partial, SH degree 0
    body = struct.pack("<I", count) + struct.pack("<3f", 10.0, 20.0, 30.0)
    record = (
        records
        if records is not None
        else (
            struct.pack("<3H", 1000, 2000, 0)
            + np.array([0.5, 1.0, 2.0, 1.0, 0.0, 0.0, 0.0], "<f2").tobytes()
            + bytes([255, 0, 51, 102])
        )
    )
    path.write_bytes(bytes(header) + bytes(section) + body + record)
    return path


def test_ksplat_record_by_hand(tmp_path):
    g = formats.load_gaussians(_ksplat_one(tmp_path / "one.ksplat"))
    scale = 2.0 / 2.0 / 1000  # block / 2 / quantisation range
    torch.testing.assert_close(g.means[0], torch.tensor([10.0, 20.0 + 1000 * scale, 30.0 - 1000 * scale]))
    torch.testing.assert_close(g.log_scales[0], torch.tensor([math.log(0.5), 0.0, math.log(2.0)]))
    torch.testing.assert_close(g.quats[0], torch.tensor([1.0, 0.0, 0.0, 0.0]))
    torch.testing.assert_close(g.sh[0, 0], (torch.tensor([1.0, 0.0, 51 / 255]) - 0.5) / SH_C0)
    assert g.opacities[0].item() == pytest.approx(102 / 255, abs=1e-6)


def test_ksplat_bad_input(tmp_path):
    _raises(_ksplat_one(tmp_path / "v.ksplat", version=(1, 0)), "version 1.0 is not supported")
    _raises(_ksplat_one(tmp_path / "m.ksplat", mode=7), "compression mode 7 is unknown")
    whole = encode_ksplat(random_splats(100, 1), tmp_path / "whole.ksplat", mode=1)
    cut = tmp_path / "cut.ksplat"
    cut.write_bytes(whole.read_bytes()[:-10])
    _raises(cut, "truncated .ksplat", "section 0")
    short = tmp_path / "short.ksplat"
    short.write_bytes(whole.read_bytes()[:3000])
    _raises(short, "truncated .ksplat")


# ---- checkpoints and the metric frame ---------------------------------------------------------------------------
def _similarity(seed: int, scale: float) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = scale * Rotation.random(random_state=seed).as_matrix()
    m[:3, 3] = np.random.default_rng(seed).normal(size=3)
    return m


def test_transform_gaussians_moves_covariance_and_colour():
    g = random_splats(64, 3, seed=4).to(dtype=torch.float64)
    m = _similarity(3, 2.5)
    moved = transform_gaussians(g, m)
    a = torch.as_tensor(m[:3, :3])
    torch.testing.assert_close(moved.means, g.means @ a.T + torch.as_tensor(m[:3, 3]))
    torch.testing.assert_close(moved.covariances(), a @ g.covariances() @ a.T)
    dirs = torch.nn.functional.normalize(torch.randn(64, 3, dtype=torch.float64), dim=1)
    torch.testing.assert_close(eval_sh(moved.sh, dirs @ (a / 2.5).T), eval_sh(g.sh, dirs))
    back = transform_gaussians(moved, invert_similarity(m))
    torch.testing.assert_close(back.sh, g.sh)


def _to_trainer(g: GaussianSet, normalization: np.ndarray) -> GaussianSet:
    return transform_gaussians(g, normalization)


def _write_colmap(folder, rng):
    """A text COLMAP model: 12 cameras on a ring looking at a cloud of 400 points."""
    folder.mkdir(parents=True)
    (folder / "cameras.txt").write_text("1 PINHOLE 64 48 50.0 50.0 32.0 24.0\n")
    lines, c2ws = [], []
    for i in range(12):
        angle = 2 * math.pi * i / 12
        centre = np.array([4 * math.cos(angle), 0.5 * math.sin(3 * angle), 4 * math.sin(angle)]) + [1.0, -2.0, 0.5]
        forward = np.array([1.0, -2.0, 0.5]) - centre
        forward /= np.linalg.norm(forward)
        down = np.array([0.0, 1.0, 0.0]) - forward * forward[1]
        down /= np.linalg.norm(down)
        right = np.cross(down, forward)
        c2w = np.eye(4)
        c2w[:3, :3] = np.stack([right, down, forward], 1)
        c2w[:3, 3] = centre
        c2ws.append(c2w)
        w2c = np.linalg.inv(c2w)
        qx, qy, qz, qw = (float(v) for v in Rotation.from_matrix(w2c[:3, :3]).as_quat())
        tx, ty, tz = (float(v) for v in w2c[:3, 3])
        lines += [f"{i + 1} {qw!r} {qx!r} {qy!r} {qz!r} {tx!r} {ty!r} {tz!r} 1 im{i:02d}.png", ""]
    (folder / "images.txt").write_text("\n".join(lines) + "\n")
    points = rng.normal(size=(400, 3)) * [1.0, 0.4, 0.6] + [1.0, -2.0, 0.5]
    rows = [" ".join(repr(float(v)) for v in p) for p in points]
    (folder / "points3D.txt").write_text("".join(f"{i + 1} {r} 128 128 128 0.5\n" for i, r in enumerate(rows)))
    return np.stack(c2ws), points


def test_gsplat_ranks_restored_to_the_metric_frame(tmp_path):
    rng = np.random.default_rng(0)
    c2ws, points = _write_colmap(tmp_path / "data" / "sparse" / "0", rng)
    from recon.colmap import read_colmap_model

    model = read_colmap_model(tmp_path / "data" / "sparse" / "0")
    normalization = gsplat_normalization(np.linalg.inv(np.stack([w for _, w, _, _ in model.images])), model.points)
    # gsplat's scale: 1 / the median distance of the cameras from the focus point (the centre of this ring)
    assert np.cbrt(np.linalg.det(normalization[:3, :3])) == pytest.approx(1 / 4.0, rel=0.05)
    metric = random_splats(200, 1, seed=7)
    trained = _to_trainer(metric, normalization)
    ckpts = tmp_path / "results" / "ckpts"
    ckpts.mkdir(parents=True)
    for rank, part in enumerate((slice(0, 120), slice(120, 200))):
        sub = trained.subset(torch.arange(200)[part])
        splats = {
            "means": sub.means,
            "quats": sub.quats * 3.0,
            "scales": sub.log_scales,
            "opacities": sub.opacity_logits,
            "sh0": sub.sh[:, :1],
            "shN": sub.sh[:, 1:],
        }
        torch.save({"step": 6999, "splats": splats}, ckpts / f"ckpt_6999_rank{rank}.pt")
    raw = load_trained_model(ckpts / "ckpt_6999_rank1.pt")
    assert raw.trainer == "gsplat" and raw.gaussians.num == 200 and len(raw.files) == 2
    back, fmt, frame = formats.load_gaussians_framed(
        ckpts / "ckpt_6999_rank0.pt", formats.LoadOptions(colmap=tmp_path / "data")
    )
    assert fmt == "checkpoint" and frame.metric and "gsplat" in frame.description
    torch.testing.assert_close(back.means, metric.means, rtol=0, atol=1e-4)
    torch.testing.assert_close(back.covariances(), metric.covariances(), rtol=1e-3, atol=1e-5)
    torch.testing.assert_close(back.sh, metric.sh, rtol=0, atol=1e-4)
    torch.testing.assert_close(back.opacity_logits, metric.opacity_logits)
    json.loads(frame.to_json())


@pytest.mark.parametrize("layout", ["gauss_params", "ddp", "old"])
def test_nerfstudio_restored_with_dataparser_transforms(tmp_path, layout, caplog):
    metric = random_splats(150, 2, seed=2)
    m = _similarity(5, 0.3)
    s = 0.3
    doc = {"transform": (m[:3] / s).tolist(), "scale": s}
    run = tmp_path / "outputs" / "cap" / "splatfacto" / "2025"
    (run / "nerfstudio_models").mkdir(parents=True)
    (run / "config.yml").write_text("method_name: splatfacto\n")
    (run / "dataparser_transforms.json").write_text(json.dumps(doc))
    trained = _to_trainer(metric, m)
    prefix = {"gauss_params": "_model.gauss_params.", "ddp": "module._model.gauss_params.", "old": "_model."}[layout]
    params = {
        "means": trained.means,
        "quats": trained.quats,
        "scales": trained.log_scales,
        "opacities": trained.opacity_logits[:, None],
        "features_dc": trained.sh[:, 0],
        "features_rest": trained.sh[:, 1:],
    }
    pipeline = {prefix + k: v for k, v in params.items()}
    pipeline["_model.field.some_mlp.weight"] = torch.zeros(2, 2)
    ckpt = run / "nerfstudio_models" / "step-000029999.ckpt"
    torch.save({"step": 29999, "pipeline": pipeline, "optimizers": {}}, ckpt)
    back, fmt, frame = formats.load_gaussians_framed(ckpt)
    assert fmt == "checkpoint" and frame.metric and "dataparser_transforms.json" in frame.description
    torch.testing.assert_close(back.means, metric.means, rtol=0, atol=1e-4)
    torch.testing.assert_close(back.covariances(), metric.covariances(), rtol=1e-3, atol=1e-6)
    torch.testing.assert_close(back.sh, metric.sh, rtol=0, atol=1e-4)
    # without the transforms: a warning naming the units and the fix, values left as trained
    (run / "dataparser_transforms.json").rename(tmp_path / "elsewhere.json")
    with caplog.at_level(logging.WARNING):
        raw, _, frame = formats.load_gaussians_framed(ckpt)
    assert not frame.metric and "normalised units" in caplog.text and "--dataparser-transforms" in caplog.text
    torch.testing.assert_close(raw.means, trained.means.float())
    given, _, frame = formats.load_gaussians_framed(
        ckpt, formats.LoadOptions(dataparser_transforms=tmp_path / "elsewhere.json")
    )
    assert frame.metric
    torch.testing.assert_close(given.means, metric.means, rtol=0, atol=1e-4)


def test_degenerate_normalisations_name_their_file(tmp_path):
    """A dataparser_transforms.json whose scale overflows or vanishes (1e308, 1e-300) said only "transform is not a
    similarity", and a COLMAP model whose cameras all stand in one place "Eigenvalues did not converge": no file, no
    fix. Each names its file (or --colmap) and the fix."""
    g = random_splats(20, 0)
    params = {"means": g.means, "quats": g.quats, "scales": g.log_scales, "opacities": g.opacity_logits[:, None]}
    params["features_dc"] = g.sh[:, 0]
    ckpt = tmp_path / "step-000000001.ckpt"
    torch.save({"step": 1, "pipeline": {"_model.gauss_params." + k: v for k, v in params.items()}}, ckpt)
    doc = tmp_path / "dataparser_transforms.json"
    for scale in (1e308, 1e-300):
        doc.write_text(json.dumps({"transform": np.eye(4)[:3].tolist(), "scale": scale}))
        with pytest.raises(ValueError) as info:
            formats.load_gaussians_framed(ckpt)
        assert f"{doc}: 'scale' times 'transform' is not a similarity" in str(info.value)
        assert "pass the one written beside the run's config.yml" in str(info.value)
    splats = {"means": g.means, "quats": g.quats, "scales": g.log_scales, "opacities": g.opacity_logits}
    torch.save({"step": 1, "splats": {**splats, "sh0": g.sh[:, :1]}}, tmp_path / "ckpt_1_rank0.pt")
    model = tmp_path / "sparse"
    model.mkdir()
    (model / "cameras.txt").write_text("1 PINHOLE 100 100 50 50 50 50\n")
    (model / "images.txt").write_text("1 1 0 0 0 0 0 0 1 a.png\n\n2 1 0 0 0 0 0 0 1 b.png\n\n")  # both at the origin
    (model / "points3D.txt").write_text("".join(f"{i} {i % 2} {i // 2} {i} 1 1 1 0\n" for i in range(1, 5)))
    with pytest.raises(ValueError, match="the cameras stand in one place") as info:
        formats.load_gaussians_framed(tmp_path / "ckpt_1_rank0.pt", formats.LoadOptions(colmap=model))
    assert f"--colmap {model}" in str(info.value) and "gsplat was trained on" in str(info.value)


def test_splatfacto_degree_zero_colour_is_a_logit(tmp_path):
    rgb = torch.tensor([[0.2, 0.5, 0.9]])
    params = {
        "means": torch.zeros(1, 3),
        "quats": torch.tensor([[2.0, 0, 0, 0]]),
        "scales": torch.zeros(1, 3),
        "opacities": torch.zeros(1, 1),
        "features_dc": torch.logit(rgb),
        "features_rest": torch.zeros(1, 0, 3),
    }
    pipeline = {f"_model.gauss_params.{k}": v for k, v in params.items()}
    torch.save({"pipeline": pipeline}, tmp_path / "step-1.ckpt")
    g = load_trained_model(tmp_path / "step-1.ckpt").gaussians
    torch.testing.assert_close(g.sh[0, 0] * SH_C0 + 0.5, rgb[0])
    assert g.sh_degree == 0 and g.quats[0, 0].item() == 2.0  # unnormalised quaternions kept raw


def test_checkpoints_without_gaussians_and_unsafe_pickles(tmp_path):
    torch.save({"step": 5, "app_module": {"embeds.weight": torch.zeros(3, 4)}}, tmp_path / "ckpt_5_rank0.pt")
    _raises(tmp_path / "ckpt_5_rank0.pt", "without Gaussians")
    torch.save(
        {"step": 5, "splats": {"features": torch.zeros(3, 4), "colors": torch.zeros(3, 3)}},
        tmp_path / "ckpt_6_rank0.pt",
    )
    _raises(tmp_path / "ckpt_6_rank0.pt", "without Gaussians", "'means'")
    torch.save({"optimizers": {"means": {"state": {}}}}, tmp_path / "optim.ckpt")
    _raises(tmp_path / "optim.ckpt", "without Gaussians")
    torch.save({"pipeline": {"_model.field.w": torch.zeros(1)}}, tmp_path / "step-2.ckpt")
    _raises(tmp_path / "step-2.ckpt", "without Gaussians", "splatfacto")

    class Planted:
        def __reduce__(self):
            return (print, ("code ran",))

    torch.save({"splats": Planted()}, tmp_path / "evil.pt")
    _raises(tmp_path / "evil.pt", "weights_only=True")


# ---- the .spz frame ---------------------------------------------------------------------------------------------
def test_spz_frame_choice_keeps_the_ply_frame(tmp_path):
    g = random_splats(200, 2, seed=11)
    path = encode_spz(g, tmp_path / "kept.spz", version=3, frame="rub")  # stored exactly as given
    kept, _, frame = formats.load_gaussians_framed(path, formats.LoadOptions(spz_frame="ply"))
    assert_within(kept.means, g.means, 0.5 / 4096, "means")
    assert_within(sign_aligned(kept.quats, g.quats), g.quats, 3e-3, "rotation")
    assert_within(kept.sh[:, 1:], g.sh[:, 1:], 0.5 / 128, "SH rest")
    assert "kept as stored" in frame.description and "--spz-frame rub" in frame.description
    turned, _, frame = formats.load_gaussians_framed(path)
    assert_within(turned.means, g.means * torch.tensor([1.0, -1.0, -1.0]), 0.5 / 4096, "turned means")
    assert "right-up-back" in frame.description and "--spz-frame ply" in frame.description
    np.testing.assert_array_equal(frame.to_loaded, np.diag([1.0, -1.0, -1.0, 1.0]))


# ---- decompression bombs ----------------------------------------------------------------------------------------
def test_npz_bomb_is_refused_before_inflating(tmp_path, monkeypatch):
    monkeypatch.setenv("FLUIDGS_MAX_DECODE_GB", "0.05")
    path = tmp_path / "bomb.npz"
    n = 8_000_000  # 96 MB of float32 means from ~100 KB of deflate
    header = np.lib.format.header_data_from_array_1_0(np.zeros((1, 3), np.float32))
    header["shape"] = (n, 3)
    buffer = io.BytesIO()
    np.lib.format.write_array_header_1_0(buffer, header)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        with zf.open("means.npy", "w", force_zip64=True) as fp:
            fp.write(buffer.getvalue())
            zero = bytes(1 << 20)
            for _ in range(12 * n // len(zero)):
                fp.write(zero)
        for key in ("quats", "log_scales", "opacity_logits", "sh"):  # the keys are checked first
            zf.writestr(f"{key}.npy", buffer.getvalue())
    assert path.stat().st_size < 200_000
    _raises(path, "memory budget")
    lzma = tmp_path / "lzma.npz"
    with zipfile.ZipFile(lzma, "w", zipfile.ZIP_LZMA) as zf:
        for key in ("means", "quats", "log_scales", "opacity_logits", "sh"):
            zf.writestr(f"{key}.npy", buffer.getvalue())
    _raises(lzma, "compression method")


def test_spz_bomb_is_refused_before_inflating(tmp_path, monkeypatch):
    monkeypatch.setenv("FLUIDGS_MAX_DECODE_GB", "0.05")
    n = 1_000_000  # SH degree 3: 65 bytes stored and 236 decoded per point, 300 MB in all
    raw = struct.pack("<4sIIBBBB", b"NGSP", 3, n, 3, 12, 0, 0) + bytes(65 * n)
    path = tmp_path / "bomb.spz"
    path.write_bytes(gzip.compress(raw, compresslevel=9))
    assert path.stat().st_size < 1_000_000
    _raises(path, "memory budget")


def test_sog_count_bomb_is_refused(tmp_path, monkeypatch):
    monkeypatch.setenv("FLUIDGS_MAX_DECODE_GB", "0.05")
    _raises(_sog_one(tmp_path, _sog_pixels(), _sog_meta(count=10**9), "huge.sog"), "memory budget")


def test_the_decode_budget_has_a_fixed_ceiling(monkeypatch):
    from recon import inflate

    monkeypatch.delenv("FLUIDGS_MAX_DECODE_GB", raising=False)
    monkeypatch.setattr(inflate, "available_memory_bytes", lambda: 2**40)  # a machine with 1 TiB free
    assert inflate.memory_budget_bytes() == inflate.BUDGET_CEILING_GB * 2**30
    monkeypatch.setenv("FLUIDGS_MAX_DECODE_GB", "64")  # an explicit budget may go beyond it
    assert inflate.memory_budget_bytes() == 64 * 2**30


def test_sog_images_larger_than_the_count_are_refused_before_decoding(tmp_path):
    from PIL import Image

    buffer = io.BytesIO()  # 4096 x 4096 pixels for one Gaussian: a few KB of WebP, 64 MiB decoded
    Image.new("RGBA", (4096, 4096), (0, 0, 0, 255)).save(buffer, "WEBP", lossless=True)
    path = tmp_path / "wide.sog"
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("l.webp", buffer.getvalue())
        zf.writestr("meta.json", json.dumps(_sog_meta()))
    assert path.stat().st_size < 100_000
    _raises(path, "4096 x 4096", "refused before decoding")


def test_sog_zip_bomb_member_is_refused_before_inflating(tmp_path):
    path = tmp_path / "bomb.sog"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        with zf.open("l.webp", "w", force_zip64=True) as fp:  # 64 MiB of zeros in ~64 KB
            zero = bytes(1 << 20)
            for _ in range(64):
                fp.write(zero)
        zf.writestr("meta.json", json.dumps(_sog_meta()))
    assert path.stat().st_size < 200_000
    _raises(path, "'l.webp' declares 67108864 bytes")


def test_zero_stride_checkpoint_tensors_are_refused_before_copying(tmp_path):
    n = 50_000_000  # 600 MB of means from a 4-byte storage
    splats = {
        "means": torch.zeros(1).expand(n, 3),
        "quats": torch.zeros(1).expand(n, 4),
        "scales": torch.zeros(1).expand(n, 3),
        "opacities": torch.zeros(1).expand(n),
        "sh0": torch.zeros(1).expand(n, 1, 3),
    }
    torch.save({"step": 1, "splats": splats}, tmp_path / "ckpt_1_rank0.pt")
    assert (tmp_path / "ckpt_1_rank0.pt").stat().st_size < 10_000
    _raises(tmp_path / "ckpt_1_rank0.pt", "stores only 4 bytes", "zero-stride")


def test_npz_keys_are_checked_before_any_member_is_inflated(tmp_path, monkeypatch):
    monkeypatch.setenv("FLUIDGS_MAX_DECODE_GB", "0.05")
    path = tmp_path / "junk.npz"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        with zf.open("junk.npy", "w", force_zip64=True) as fp:  # 96 MB of zeros, over the budget
            np.lib.format.write_array_header_1_0(fp, {"descr": "<f4", "fortran_order": False, "shape": (24 << 20,)})
            zero = bytes(1 << 20)
            for _ in range(96):
                fp.write(zero)
    _raises(path, "lacks the Gaussian arrays", "'junk'")  # not "memory budget": nothing was inflated


def test_fifo_beside_a_checkpoint_is_named_not_read(tmp_path):
    import os

    g = random_splats(10, 0)
    splats = {"means": g.means, "quats": g.quats, "scales": g.log_scales, "opacities": g.opacity_logits}
    torch.save({"step": 1, "splats": {**splats, "sh0": g.sh[:, :1]}}, tmp_path / "ckpt_1_rank0.pt")
    os.mkfifo(tmp_path / "ckpt_1_rank1.pt")
    with pytest.raises(ValueError, match="ckpt_1_rank1.pt is a FIFO"):
        formats.load_gaussians(tmp_path / "ckpt_1_rank0.pt")
    os.mkfifo(tmp_path / "dataparser.json")
    from recon.formats.checkpoints import nerfstudio_normalization

    with pytest.raises(ValueError, match="--dataparser-transforms .*is a FIFO"):
        nerfstudio_normalization(tmp_path / "dataparser.json")


# ---- the real captures (measured data, skipped when absent) -----------------------------------------------------
@pytest.mark.parametrize("name,fmt", [("biker.sog", "sog"), ("biker.ksplat", "ksplat")])
def test_real_capture_matches_the_compressed_ply(name, fmt):
    path = REAL_SPLATS / name
    if not (path.is_file() and BIKER_COMPRESSED_PLY.is_file()):
        pytest.skip("the real captures (shared/real-splats) are not present")
    g, got, _ = formats.load_gaussians_framed(path)
    ref = formats.load_gaussians(BIKER_COMPRESSED_PLY)
    assert got == fmt and g.num == ref.num == 152_746
    torch.testing.assert_close(g.means.min(0).values, ref.means.min(0).values, rtol=0, atol=1e-3)
    torch.testing.assert_close(g.means.max(0).values, ref.means.max(0).values, rtol=0, atol=1e-3)
    assert g.means[:, 1].max().item() > -0.05  # y-down, as the .ply: the feet at y = 0


@pytest.mark.parametrize("option", ["colmap", "dataparser_transforms"])
def test_a_checkpoint_option_on_another_format_is_refused(tmp_path, option):
    """--colmap / --dataparser-transforms undo a trainer checkpoint's normalisation; on a .ply they were ignored, and
    the run went on in the frame the user meant to undo."""
    from recon.formats import LoadOptions, load_gaussians_framed
    from recon.formats.ply import save_gaussians
    from recon.gaussians import GaussianSet

    ply = save_gaussians(GaussianSet.from_points(torch.zeros(4, 3), scale=0.1, opacity=0.5), tmp_path / "g.ply")
    with pytest.raises(ValueError, match="applies to a trainer's checkpoint.*g.ply is a standard 3DGS .ply file"):
        load_gaussians_framed(ply, LoadOptions(**{option: tmp_path}))
