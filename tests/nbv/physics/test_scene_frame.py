"""The scene -> simulation frame: up directions, rotations, the robust object box, crops (nbv.physics.scene_frame)."""

import numpy as np
import pytest
import torch

from apps.cli import build_parser, join_dash_values
from nbv import physics
from nbv.physics import PhysicsConfig
from nbv.physics.scene_frame import (
    SceneTransform,
    crop_box,
    inside_box,
    parse_crop,
    parse_up,
    robust_box,
    rotation_to_y_up,
    up_label,
    weighted_quantiles,
)
from recon.gaussians import GaussianSet


@pytest.mark.parametrize(
    ("spec", "vec"),
    [
        ("y", (0, 1, 0)),
        ("+y", (0, 1, 0)),
        ("-y", (0, -1, 0)),
        ("z", (0, 0, 1)),
        ("-X", (-1, 0, 0)),
        ("0,-2,0", (0, -1, 0)),
        ((0.0, 0.0, 3.0), (0, 0, 1)),
        ("[1, 1, 0]", (2**-0.5, 2**-0.5, 0)),
    ],
)
def test_parse_up_axes_and_vectors(spec, vec):
    assert np.allclose(parse_up(spec), vec)


@pytest.mark.parametrize("spec", ["w", "up", "0,0,0", "1,2", "nan,0,1", "1,0,0,0", ""])
def test_parse_up_refuses_what_is_no_direction(spec):
    with pytest.raises(ValueError, match="--up"):
        parse_up(spec)


def test_rotation_takes_up_to_y_and_is_proper():
    rng = np.random.default_rng(0)
    ups = [parse_up(a) for a in ("+x", "-x", "+y", "-y", "+z", "-z")] + list(rng.normal(size=(20, 3)))
    for u in ups:
        u = np.asarray(u) / np.linalg.norm(u)
        r = rotation_to_y_up(u)
        assert np.allclose(r @ r.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(r) == pytest.approx(1.0)
        assert np.allclose(r @ u, [0, 1, 0], atol=1e-12)


def test_named_rotations_match_the_conventions():
    p = np.array([[1.0, 2.0, 3.0]])
    assert np.allclose(SceneTransform("z").to_sim(p), [[1, 3, -2]])  # the paper's z-up -> y-up: (x, z, -y)
    assert np.allclose(SceneTransform("-y").to_sim(p), [[1, -2, -3]])  # half turn about x
    assert np.allclose(SceneTransform("y", 2.0).to_sim(p), 2 * p)
    t = SceneTransform((0.3, -0.8, 0.5), 1.7)
    assert np.allclose(t.to_scene(t.to_sim(p)), p)
    assert np.allclose(t.matrix[:3, :3] @ p[0], t.to_sim(p)[0])
    assert up_label(parse_up("-z")) == "-z" and SceneTransform("y").up_label == "+y"
    with pytest.raises(ValueError, match="scale"):
        SceneTransform("y", 0.0)


def test_covariances_rotate_with_the_frame():
    t = SceneTransform("-z", 2.0)
    a = np.random.default_rng(1).normal(size=(3, 3))
    cov = a @ a.T
    x = np.array([0.2, -0.4, 0.9])
    # the Mahalanobis distance of a displacement is frame independent
    d_scene = x @ np.linalg.solve(cov, x)
    xs = t.to_sim(x[None])[0]
    cs = t.covariances_to_sim(cov[None])[0]
    assert xs @ np.linalg.solve(cs, xs) == pytest.approx(d_scene)


def test_weighted_quantiles_with_equal_weights_are_hazen_quantiles():
    v = np.random.default_rng(2).normal(size=101)
    q = (0.005, 0.25, 0.5, 0.9, 0.995)
    assert np.allclose(weighted_quantiles(v, np.ones_like(v), q), np.quantile(v, q, method="hazen"))
    # weight moves the quantile: a heavy sample pulls the median to itself
    assert weighted_quantiles(np.array([0.0, 1.0, 2.0]), np.array([1.0, 10.0, 1.0]), [0.5])[0] == 1.0


def _cloud(n=4000, seed=3):
    rng = np.random.default_rng(seed)
    means = rng.uniform(-1, 1, size=(n, 3)) * [0.5, 1.0, 0.25]
    opac = np.full(n, 0.9)
    return means, opac


def test_robust_box_ignores_a_far_floater_the_raw_box_does_not():
    means, opac = _cloud()
    means = np.vstack([means, [[500.0, 0, 0]]])
    opac = np.append(opac, 0.9)
    lo, hi = robust_box(means, opac, 0.3)
    assert np.all(hi - lo < [1.05, 2.05, 0.55]) and np.all(hi - lo > [0.95, 1.95, 0.45])
    assert np.ptp(means, axis=0)[0] > 500
    # faint Gaussians (under tau) do not count at all
    faint = np.vstack([means, np.full((3000, 3), 40.0)])
    lo2, hi2 = robust_box(faint, np.append(opac, np.full(3000, 0.05)), 0.3)
    assert np.allclose(lo2, lo) and np.allclose(hi2, hi)


def test_crop_parsing_and_auto_box():
    assert parse_crop(None) is None and parse_crop("AUTO") == "auto"
    assert parse_crop("-1,-1,-1,1,1,1") == (-1, -1, -1, 1, 1, 1)
    for bad in ("1,2,3", "0,0,0,-1,1,1", "a,b,c,d,e,f", "0,0,0,1,1,inf"):
        with pytest.raises(ValueError, match="--crop"):
            parse_crop(bad)
    means, opac = _cloud()
    means = np.vstack([means, [[50.0, 0, 0]]])
    lo, hi = crop_box("auto", means, np.append(opac, 0.9), 0.3)
    kept = inside_box(means, lo, hi)
    assert kept[:-1].all() and not kept[-1]


def _gaussians(means, opac=0.9, scale=0.05):
    return GaussianSet.from_points(torch.tensor(means, dtype=torch.float32), scale=scale, opacity=opac)


def test_physics_config_keeps_up_and_crop_and_reads_old_results():
    cfg = PhysicsConfig(up=(0.0, -1.0, 0.0), crop=(-1, -1, -1, 1, 1, 1))
    assert PhysicsConfig.from_dict(cfg.to_dict()) == cfg
    assert PhysicsConfig(up="z").up == "+z" and PhysicsConfig(crop="auto").crop == "auto"
    old = PhysicsConfig().to_dict()
    del old["up"], old["crop"]
    old["up_axis"] = "z"
    assert PhysicsConfig.from_dict(old).up == "+z"
    with pytest.raises(ValueError, match="up"):
        PhysicsConfig(up="sideways")


def test_crop_that_keeps_nothing_is_an_error_naming_the_fix():
    g = _gaussians(_cloud(200)[0])
    with pytest.raises(ValueError, match="keeps none"):
        physics.kept_gaussians(g, PhysicsConfig(crop=(10, 10, 10, 11, 11, 11)))
    kept = physics.kept_gaussians(g, PhysicsConfig(crop=(-0.25, -2, -2, 2, 2, 2)))
    assert 0 < kept.sum() < len(kept)


def test_auto_scale_uses_the_robust_box_not_a_floater():
    means, _ = _cloud()
    g = _gaussians(np.vstack([means, [[400.0, 0, 0]]]))
    t = physics.scene_transform(g, PhysicsConfig())
    assert t.scale == pytest.approx(1.0, rel=0.03)  # the 2-unit tall object -> 2 m


def test_an_upside_down_capture_stands_with_its_heavy_end_down():
    # a heavy block (the body) on a thin pole (the legs) above it is upside down; y-up it stands on the body
    rng = np.random.default_rng(4)
    body = rng.uniform([-0.4, -1.0, -0.4], [0.4, 0.0, 0.4], size=(3000, 3))
    legs = rng.uniform([-0.05, 0.0, -0.05], [0.05, 1.0, 0.05], size=(300, 3))
    means = np.vstack([body, legs])
    heavy = np.arange(len(means)) < len(body)
    t_right = physics.scene_transform(_gaussians(means), PhysicsConfig(up="+y"))
    sim = t_right.to_sim(means)
    assert sim[heavy, 1].mean() < sim[~heavy, 1].mean()  # the body is already at the bottom in a y-up scene
    flipped = means * [1, -1, 1]  # the same object in a y-down frame (COLMAP)
    t_flip = physics.scene_transform(_gaussians(flipped), PhysicsConfig(up="-y"))
    sim_flip = t_flip.to_sim(flipped)
    assert sim_flip[heavy, 1].mean() < sim_flip[~heavy, 1].mean()
    assert np.allclose(np.sort(sim_flip[:, 1]), np.sort(sim[:, 1]))


@pytest.mark.parametrize(
    "argv", [["--up", "-y"], ["--up=-y"], ["--up-axis", "-y"], ["--up", "0,-1,0"], ["--up", "-0.1,-1,0"]]
)
def test_up_on_the_command_line_as_typed(argv):
    args = build_parser().parse_args(join_dash_values(["simulate", "g.ply", "-o", "r.h5", *argv]))
    assert parse_up(args.up)[1] < -0.9


def test_crop_with_negative_corners_on_the_command_line():
    args = build_parser().parse_args(
        join_dash_values(["simulate", "g.ply", "-o", "r.h5", "--crop", "-1,-1,-1,1,1,1", "--up", "-z"])
    )
    assert args.crop == "-1,-1,-1,1,1,1" and args.up == "-z"


def test_every_gaussian_command_takes_up():
    parser = build_parser()
    cams = ["--cameras", "c.json"]
    for cmd, extra in (
        ("simulate", ["g.ply", "-o", "r.h5"]),
        ("score", ["g.ply", *cams, "-o", "s.json"]),
        ("sweep", ["g.ply", "-o", "s.csv"]),
        ("critical", ["g.ply", *cams, "-o", "c.json"]),
        ("inspect", ["g.ply"]),
        ("active", ["data", "-o", "run"]),
    ):
        args = parser.parse_args(join_dash_values([cmd, *extra, "--up", "-y"]))
        assert args.up == "-y", cmd


def test_auto_up_names_the_nearest_axis_and_its_angle():
    from nbv.physics.scene_frame import describe_auto_up, nearest_axis

    u = parse_up("0.1,-1,0")
    name, angle = nearest_axis(u)
    assert name == "-y" and angle == pytest.approx(np.degrees(np.arctan(0.1)))
    assert "--up -y" in describe_auto_up(u)


def test_a_cropped_simulation_gives_every_gaussian_a_row_and_records_the_crop(tmp_path):
    from nbv.physics import load_result, save_result, simulate_gaussians

    rng = np.random.default_rng(5)
    pts = rng.normal(size=(300, 3))
    pts = 0.5 * pts / np.linalg.norm(pts, axis=1, keepdims=True)
    g = _gaussians(np.vstack([pts, [[30.0, 0.0, 0.0]]]), scale=0.06)
    cfg = PhysicsConfig(
        particle_radius=0.08, steps=60, dt=0.004, empty_reference=False, directions=("-x",), crop=(-1, -1, -1, 1, 1, 1)
    )
    res = simulate_gaussians(g, cfg, progress=False)
    assert res.divergence.shape == (301,) and res.per_probe.shape == (1, 301)
    assert res.kept is not None and res.kept[:300].all() and not res.kept[300]
    assert res.divergence[300] == 0 and res.per_probe_counts[0, 300] == 0
    assert (res.per_probe_counts[0, :300] > 0).any()
    assert res.means.shape == (301, 3) and res.config.crop == (-1, -1, -1, 1, 1, 1)
    # the floater does not size the object: 1 unit across -> 2 m
    assert res.transform.scale == pytest.approx(2.0, rel=0.05)
    back = load_result(save_result(tmp_path / "r.h5", res))
    assert np.array_equal(back.kept, res.kept) and back.config == res.config
    assert np.allclose(back.transform.matrix, res.transform.matrix)
