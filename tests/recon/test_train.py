"""Tests of 3DGS training: LR schedule, Adam with state surgery, density control, config, trainer, CLI."""

import math

import pytest
import torch

from recon.densify import DensityStats, densify_and_prune, ndc_gradient, reset_opacity, split_samples
from recon.gaussians import GaussianSet
from recon.optim import GroupedAdam, expon_lr
from recon.train import (
    TrainConfig,
    composite_target,
    default_init_box,
    knn_mean_sq_dist,
    knn_mean_sq_dist_reference,
    look_at_point,
    scene_extent,
)

# ---- learning-rate schedule ------------------------------------------------------------------------


def reference_expon_lr(step, lr_init, lr_final, max_steps, delay_steps=0, delay_mult=1.0):
    """The formula of the reference trainer's get_expon_lr_func, written independently with numpy-like steps."""
    if delay_steps > 0:
        delay = delay_mult + (1 - delay_mult) * math.sin(0.5 * math.pi * min(max(step / delay_steps, 0), 1))
    else:
        delay = 1.0
    t = min(max(step / max_steps, 0), 1)
    return delay * lr_init ** (1 - t) * lr_final**t


@pytest.mark.parametrize("step", [0, 1, 7500, 15000, 29999, 30000, 45000])
def test_expon_lr_matches_reference_formula(step):
    assert expon_lr(step, 1.6e-4, 1.6e-6, 30000) == pytest.approx(
        reference_expon_lr(step, 1.6e-4, 1.6e-6, 30000), rel=1e-12
    )
    assert expon_lr(step, 1.6e-4, 1.6e-6, 30000, 1000, 0.01) == pytest.approx(
        reference_expon_lr(step, 1.6e-4, 1.6e-6, 30000, 1000, 0.01), rel=1e-12
    )


def test_expon_lr_known_values():
    assert expon_lr(0, 1.6e-4, 1.6e-6, 30000) == pytest.approx(1.6e-4)
    assert expon_lr(15000, 1.6e-4, 1.6e-6, 30000) == pytest.approx(1.6e-5)  # geometric mean half-way
    assert expon_lr(30000, 1.6e-4, 1.6e-6, 30000) == pytest.approx(1.6e-6)
    assert expon_lr(90000, 1.6e-4, 1.6e-6, 30000) == pytest.approx(1.6e-6)  # stays at the final rate
    assert expon_lr(0, 1.6e-4, 1.6e-6, 30000, 100, 0.01) == pytest.approx(1.6e-6)  # delay: 0.01 x init
    assert expon_lr(-1, 1.6e-4, 1.6e-6, 30000) == 0.0


# ---- Adam ------------------------------------------------------------------------------------------


def test_grouped_adam_equals_torch_adam():
    gen = torch.Generator().manual_seed(0)
    a0, b0 = torch.randn(5, 3, generator=gen), torch.randn(5, generator=gen)
    ours = GroupedAdam({"a": a0, "b": b0}, {"a": 0.01, "b": 0.1}, eps=1e-15)
    ta, tb = a0.clone().requires_grad_(True), b0.clone().requires_grad_(True)
    theirs = torch.optim.Adam([{"params": [ta], "lr": 0.01}, {"params": [tb], "lr": 0.1}], eps=1e-15)
    for _ in range(6):
        for a, b, opt in ((ours.params["a"], ours.params["b"], ours), (ta, tb, theirs)):
            loss = (a.sin() * 3).sum() + (b**3).sum()
            loss.backward()
            opt.step()
            opt.zero_grad()
    torch.testing.assert_close(ours.params["a"], ta, rtol=1e-6, atol=1e-7)
    torch.testing.assert_close(ours.params["b"], tb, rtol=1e-6, atol=1e-7)
    torch.testing.assert_close(ours.state["a"].exp_avg_sq, theirs.state[ta]["exp_avg_sq"], rtol=1e-6, atol=1e-12)
    assert not torch.equal(ours.params["a"], a0)


def test_adam_remap_keeps_survivor_moments_and_zeros_new_rows():
    adam = GroupedAdam({"x": torch.zeros(4, 2)}, {"x": 0.1})
    (adam.params["x"] * torch.arange(8.0).reshape(4, 2)).sum().backward()
    adam.step()
    old_m, old_v = adam.state["x"].exp_avg.clone(), adam.state["x"].exp_avg_sq.clone()
    assert (old_m[1:] != 0).all()
    origin = torch.tensor([3, 1, -1, -1])  # rows 0 and 2 removed, two new rows appended
    adam.remap({"x": torch.ones(4, 2)}, origin)
    torch.testing.assert_close(adam.state["x"].exp_avg[:2], old_m[[3, 1]])
    torch.testing.assert_close(adam.state["x"].exp_avg_sq[:2], old_v[[3, 1]])
    assert torch.equal(adam.state["x"].exp_avg[2:], torch.zeros(2, 2))
    assert torch.equal(adam.state["x"].exp_avg_sq[2:], torch.zeros(2, 2))
    assert adam.params["x"].requires_grad and adam.params["x"].is_leaf
    assert adam.state["x"].step == 1
    with pytest.raises(ValueError, match="x has shape"):
        adam.remap({"x": torch.ones(3, 2)}, origin)


def test_adam_reset_state_and_skip():
    adam = GroupedAdam({"x": torch.zeros(3), "y": torch.zeros(3)}, {"x": 0.1, "y": 0.1})
    (adam.params["x"].sum() + adam.params["y"].sum()).backward()
    adam.step(skip=("y",))
    assert (adam.params["x"] != 0).all() and (adam.params["y"] == 0).all()
    adam.reset_state("x", torch.full((3,), 5.0))
    assert torch.equal(adam.state["x"].exp_avg, torch.zeros(3)) and torch.equal(adam.params["x"], torch.full((3,), 5.0))


# ---- density control -------------------------------------------------------------------------------


def hand_made_set() -> GaussianSet:
    """Six Gaussians: sizes and opacities chosen to fall on known sides of each rule (extent 10)."""
    means = torch.arange(18.0).reshape(6, 3)
    scales = torch.tensor([0.05, 0.05, 0.5, 0.5, 0.05, 2.0])  # limit percent_dense x extent = 0.1; big > 1.0
    opac = torch.tensor([0.5, 0.5, 0.5, 0.5, 0.001, 0.5])
    g = GaussianSet.from_points(means, scale=scales, opacity=0.5)
    return GaussianSet(g.means, g.quats, g.log_scales, torch.log(opac / (1 - opac)), g.sh)


def hand_made_stats() -> DensityStats:
    # mean grads: 3e-4 (hot), 1e-4 (cold), 5e-4 (hot), 0 (never seen), 1e-3 (hot but transparent), 0
    return DensityStats(
        grad_accum=torch.tensor([6e-4, 1e-4, 1.5e-3, 0.0, 1e-3, 0.0]),
        denom=torch.tensor([2.0, 1.0, 3.0, 0.0, 1.0, 2.0]),
        max_radii2d=torch.tensor([3.0, 4.0, 30.0, 1.0, 2.0, 5.0]),
    )


def densify_hand_made(**over):
    """:func:`densify_and_prune` of the hand-made set and statistics: threshold 2e-4, percent_dense 0.01, extent 10,
    minimum opacity 0.005, no screen-size rule, big beyond 0.1 x extent, seed 0; ``over`` replaces any of these."""
    settings = dict(
        grad_threshold=2e-4,
        percent_dense=0.01,
        extent=10.0,
        min_opacity=0.005,
        max_screen_size=None,
        big_world_fraction=0.1,
        generator=torch.Generator().manual_seed(0),
    )
    return densify_and_prune(hand_made_set(), hand_made_stats(), **{**settings, **over})


def test_densify_clone_split_prune_counts():
    g, res = hand_made_set(), densify_hand_made()
    # clone: 0 (small, hot) and 4 (small, hot, then pruned with its clone for opacity); split: 2.
    assert (res.cloned, res.split) == (2, 1)
    # old: 0, 1, 3, 5 survive (2 replaced by its children, 4 pruned); new: clones of 0 and 4 (4's pruned), 2 children
    assert res.origin.tolist() == [0, 1, 3, 5, -1, -1, -1]
    assert res.pruned == 2  # Gaussian 4 and its clone
    assert res.gaussians.num == 7
    torch.testing.assert_close(res.gaussians.means[4], g.means[0])  # the clone copies its parent
    children = res.gaussians.subset(slice(5, 7))
    torch.testing.assert_close(children.scales, torch.full((2, 3), 0.5 / 1.6))
    assert not torch.equal(children.means[0], children.means[1])
    torch.testing.assert_close(res.max_radii2d, torch.tensor([3.0, 4.0, 1.0, 5.0, 3.0, 30.0, 30.0]))


def test_prune_by_size_after_reset():
    res = densify_hand_made(max_screen_size=20.0, densify=False)
    # 2 is 30 px on screen, 4 is transparent, 5 has scale 2.0 > 0.1 x 10
    assert res.origin.tolist() == [0, 1, 3]
    assert (res.cloned, res.split, res.pruned) == (0, 0, 3)


def test_densify_respects_the_cap_by_gradient():
    res = densify_hand_made(min_opacity=1e-6, big_world_fraction=None, max_gaussians=8)
    # budget 2 among candidates 0 (3e-4), 2 (5e-4), 4 (1e-3): the two largest gradients win
    assert (res.cloned, res.split) == (1, 1)
    assert res.gaussians.num == 8


def test_split_samples_follow_the_covariance():
    g = GaussianSet.from_points(torch.zeros(1, 3), scale=1.0)
    g = GaussianSet(
        g.means,
        torch.tensor([[math.cos(0.3), 0, 0, math.sin(0.3)]]),
        torch.log(torch.tensor([[2.0, 0.5, 0.1]])),
        g.opacity_logits,
        g.sh,
    )
    many = GaussianSet(*(t.repeat(4000, *([1] * (t.dim() - 1))) for t in g.tensors()))
    kids = split_samples(many, torch.ones(4000, dtype=torch.bool), torch.Generator().manual_seed(1))
    cov = torch.cov(kids.means.T)
    torch.testing.assert_close(cov, g.covariances()[0], atol=0.12, rtol=0.06)
    assert kids.num == 8000


def test_density_stats_and_ndc_gradient():
    stats = DensityStats.zeros(3)
    grad = ndc_gradient(torch.tensor([[3.0, 4.0], [1.0, 0.0], [0.0, 1.0]]), width=2, height=2)  # x W/2, y H/2
    stats.update(grad, torch.tensor([5, 0, 2]), torch.tensor([True, False, True]))
    stats.update(
        torch.tensor([[0.0, 1.0], [1.0, 1.0], [0.0, 0.0]]), torch.tensor([2, 0, 7]), torch.tensor([True, False, True])
    )
    torch.testing.assert_close(stats.mean_grad(), torch.tensor([3.0, 0.0, 0.5]))
    torch.testing.assert_close(stats.max_radii2d, torch.tensor([5.0, 0.0, 7.0]))
    torch.testing.assert_close(ndc_gradient(torch.tensor([[1.0, 1.0]]), 64, 32), torch.tensor([[32.0, 16.0]]))


def test_reset_opacity_clamps_to_001():
    logits = torch.tensor([-10.0, 0.0, 3.0])
    out = torch.sigmoid(reset_opacity(logits))
    torch.testing.assert_close(out, torch.tensor([torch.sigmoid(torch.tensor(-10.0)).item(), 0.01, 0.01]))


# ---- config, initialisation, geometry ----------------------------------------------------------------


def test_config_validation_names_the_field():
    with pytest.raises(ValueError, match="TrainConfig.iterations"):
        TrainConfig(iterations=0)
    with pytest.raises(ValueError, match="TrainConfig.background"):
        TrainConfig(background="green")
    with pytest.raises(ValueError, match="TrainConfig.lambda_dssim"):
        TrainConfig(lambda_dssim=1.5)
    with pytest.raises(ValueError, match="TrainConfig.init_box"):
        TrainConfig(init_box=(0, 0, 0, 1, -1, 1))
    with pytest.raises(ValueError, match="TrainConfig.sh_degree"):
        TrainConfig(sh_degree=4)
    with pytest.raises(ValueError, match=r"unknown TrainConfig keys \['bogus'\]"):
        TrainConfig.for_iterations(100, bogus=1)


def test_for_iterations_scales_the_schedule():
    c = TrainConfig.for_iterations(3000)
    assert (c.iterations, c.position_lr_max_steps, c.densify_from_iter, c.densify_until_iter) == (3000, 3000, 50, 1500)
    assert (c.densification_interval, c.opacity_reset_interval, c.sh_increase_interval) == (10, 300, 100)
    assert c.position_lr_init == TrainConfig().position_lr_init
    assert TrainConfig.for_iterations(30000) == TrainConfig()
    assert TrainConfig.for_iterations(30, sh_degree=1).sh_increase_interval == 1
    assert TrainConfig.for_iterations(30, sh_degree=1).sh_degree == 1


def test_knn_chunked_equals_reference():
    pts = torch.rand(300, 3, generator=torch.Generator().manual_seed(3))
    torch.testing.assert_close(knn_mean_sq_dist(pts, chunk=64), knn_mean_sq_dist_reference(pts))


def test_scene_extent_and_look_at():
    from recon.camera import Camera

    cams = [
        Camera.look_at([4.0 * math.cos(a), 0.5, 4.0 * math.sin(a)], [0.2, 0.1, -0.3], [0, 1, 0], 16, 16, 0.8)
        for a in torch.linspace(0, 2 * math.pi, 7)[:-1].tolist()
    ]
    centres = torch.stack([c.center for c in cams])
    expected = 1.1 * float((centres - centres.mean(0)).norm(dim=-1).max())
    assert scene_extent(cams) == pytest.approx(expected)
    torch.testing.assert_close(look_at_point(cams), torch.tensor([0.2, 0.1, -0.3], dtype=torch.float64))
    box = default_init_box(cams)
    assert box[3] - box[0] == pytest.approx(0.6 * expected)


def test_composite_target_recovers_other_backgrounds():
    gen = torch.Generator().manual_seed(0)
    rgb, alpha = torch.rand(4, 4, 3, generator=gen), torch.rand(4, 4, generator=gen)
    white = rgb * alpha[..., None] + (1 - alpha[..., None])
    bg = torch.tensor([0.2, 0.5, 0.9])
    torch.testing.assert_close(
        composite_target(white, alpha, torch.ones(3), bg), rgb * alpha[..., None] + bg * (1 - alpha[..., None])
    )
    with pytest.raises(ValueError, match="alpha"):
        composite_target(white, None, torch.ones(3), bg)


# ---- the trainer on a tiny scene (needs the renderer) ----------------------------------------------


@pytest.fixture(scope="module")
def tiny_scene():
    """Eight 16 x 16 views of a random 'ground truth' set of 200 Gaussians, rendered over white."""
    from recon.camera import Camera
    from recon.datasets import View
    from recon.render import render

    gen = torch.Generator().manual_seed(0)
    gt = GaussianSet.from_points(
        (torch.rand(200, 3, generator=gen) - 0.5) * 1.5, torch.rand(200, 3, generator=gen), scale=0.12, opacity=0.8
    )
    views = []
    angles = torch.linspace(0, 2 * math.pi, 9)[:-1].tolist()
    for i, a in enumerate(angles):
        cam = Camera.look_at(
            [3 * math.cos(a), math.sin(3 * a), 3 * math.sin(a)], [0, 0, 0], [0, 1, 0], 16, 16, 0.9, name=f"v{i}"
        )
        with torch.no_grad():
            out = render(gt, cam, torch.ones(3), backend="torch")
        views.append(View(cam, out.image, out.alpha, cam.name))
    return views


def tiny_config(**overrides):
    base = dict(init_points=200, sh_degree=1, opacity_reset_interval=1000, init_opacity=0.5, max_gaussians=600)
    return TrainConfig.for_iterations(overrides.pop("iterations", 50), **{**base, **overrides})


def test_loss_decreases_and_density_control_runs(tiny_scene):
    from recon.losses import photometric_loss
    from recon.render import render
    from recon.train import initial_gaussians, train

    cfg = tiny_config()
    views = tiny_scene[:6]

    def mean_loss(gaussians):
        with torch.no_grad():
            return sum(
                float(photometric_loss(render(gaussians, v.camera, 1.0, backend="torch").image, v.image)) for v in views
            ) / len(views)

    g, log = train(views, cfg, backend="torch")
    before, after = mean_loss(initial_gaussians(cfg, [v.camera for v in views])), mean_loss(g)
    assert after < 0.75 * before, (before, after)  # measured: 0.34 -> 0.20
    assert any(e["kind"] == "densify" for e in log.events)
    assert g.num == log.num_gaussians[-1] and g.sh_degree == 1


def test_training_is_deterministic(tiny_scene):
    from dataclasses import replace

    from recon.train import train

    cfg = tiny_config(iterations=30, background="random")
    g1, log1 = train(tiny_scene[:6], cfg, backend="torch")
    g2, log2 = train(tiny_scene[:6], cfg, backend="torch")
    assert log1.losses == log2.losses
    for a, b in zip(g1.tensors(), g2.tensors(), strict=True):
        assert torch.equal(a, b)
    g3, _ = train(tiny_scene[:6], replace(cfg, iterations=12, seed=1), backend="torch")
    g1_short, _ = train(tiny_scene[:6], replace(cfg, iterations=12), backend="torch")
    assert not torch.equal(g3.means[:10], g1_short.means[:10])  # the seed matters


def test_checkpoint_resume_equals_uninterrupted_run(tiny_scene):
    from recon.train import Trainer, initial_gaussians

    cfg = tiny_config(iterations=24, background="random")
    views = tiny_scene[:6]
    extent = scene_extent([v.camera for v in views])
    init = initial_gaussians(cfg, [v.camera for v in views])
    straight = Trainer(init, cfg, extent=extent, backend="torch")
    straight.train(views, 24)
    first = Trainer(init, cfg, extent=extent, backend="torch")
    first.train(views, 15)  # past a density step (every 10 from 1), so the state has been remapped
    resumed = Trainer(init, cfg, extent=extent, backend="torch")
    resumed.load_state_dict(first.state_dict())
    resumed.train(views, 9)
    assert resumed.iteration == straight.iteration == 24
    for a, b in zip(resumed.gaussians.tensors(), straight.gaussians.tensors(), strict=True):
        assert torch.equal(a, b)


def test_schedules_inside_the_trainer(tiny_scene):
    from recon.optim import expon_lr
    from recon.train import Trainer, initial_gaussians

    cfg = tiny_config(
        iterations=60,
        sh_degree=2,
        sh_increase_interval=10,
        opacity_reset_interval=7,
        densify_until_iter=8,
        densify_from_iter=100,
    )
    views = tiny_scene[:4]
    extent = scene_extent([v.camera for v in views])
    trainer = Trainer(initial_gaussians(cfg, [v.camera for v in views]), cfg, extent=extent, backend="torch")
    degrees = []
    for i in range(25):
        trainer.train_step(views[i % 4])
        degrees.append(trainer.active_sh_degree)
        if trainer.iteration == 7:  # opacity reset: every opacity is at most 0.01 right after it
            assert float(trainer.gaussians.opacities.max()) <= 0.01 + 1e-6
    assert degrees[8] == 0 and degrees[9] == 1 and degrees[19] == 2 and degrees[24] == 2
    assert trainer.adam.lrs["means"] == pytest.approx(extent * expon_lr(25, 1.6e-4, 1.6e-6, cfg.position_lr_max_steps))
    assert trainer.adam.lrs["sh_rest"] == pytest.approx(cfg.feature_lr / 20)


def test_train_rejects_bad_views(tiny_scene):
    from dataclasses import replace

    from recon.train import train

    no_alpha = [replace(v, alpha=None) for v in tiny_scene[:2]]
    with pytest.raises(ValueError, match="no alpha"):
        train(no_alpha, tiny_config(background="black"), backend="torch")
    with pytest.raises(ValueError, match="no training views"):
        train([], tiny_config(), backend="torch")


# ---- CLI ------------------------------------------------------------------------------------------


def test_train_cli_smoke(tmp_path):
    import json

    from apps.cli import main
    from recon.formats import load_gaussians
    from recon.mesh_render import MeshDatasetConfig, render_mesh_dataset

    from helpers.paths import TORUS

    data = render_mesh_dataset(
        TORUS, tmp_path / "ds", MeshDatasetConfig(n_train=4, n_test=2, resolution=16, supersample=1), progress=False
    )
    out = tmp_path / "g.ply"
    assert (
        main(
            [
                "train",
                str(data),
                "-o",
                str(out),
                "--iters",
                "20",
                "--res",
                "16",
                "--init-points",
                "300",
                "--sh-degree",
                "1",
                "--views",
                "0,1,3",
                "--background",
                "random",
                "--threads",
                "1",
                "--device",
                "cuda",
            ]
        )
        == 0
    )  # falls back to the CPU where CUDA is missing
    report = json.loads(out.with_suffix(".json").read_text())
    assert report["train_views"] == ["r_000", "r_001", "r_003"]
    assert math.isfinite(report["test"]["psnr"]) and report["config"]["iterations"] == 20
    assert load_gaussians(out).num == report["num_gaussians"]
    # bad input fails before training, and nothing is written
    assert main(["train", str(data), "-o", str(tmp_path / "x.ply"), "--views", "0,9"]) == 2
    assert main(["train", str(data), "-o", str(tmp_path / "missing" / "x.ply")]) == 2
    assert not (tmp_path / "x.ply").exists()


def test_make_assets_smoke(tmp_path):
    import json

    from apps.cli import main
    from apps.make_assets import read_cameras_json
    from recon.formats import load_gaussians

    out = tmp_path / "assets"
    assert (
        main(
            [
                "make-assets",
                "-o",
                str(out),
                "--res",
                "16",
                "--candidates",
                "3",
                "--test",
                "1",
                "--train-views",
                "2",
                "--iters",
                "10",
                "--max-gaussians",
                "400",
                "--seed",
                "3",
            ]
        )
        == 0
    )
    report = json.loads((out / "ahmed_asset.json").read_text())
    g = load_gaussians(out / "ahmed_gaussians.ply")
    assert g.num == report["num_gaussians"] <= 400 and g.sh_degree == 0
    cams = read_cameras_json(out / "ahmed_cameras.json")
    assert len(cams) == 3 and cams[0].width == 16
    assert all(abs(float(c.center.norm()) - 6.0) < 1e-6 for c in cams)  # render-dataset's camera radius
    assert math.isfinite(report["test_psnr_db"]) and "--seed 3" in report["command"]
    assert main(["make-assets", "-o", str(out), "--train-views", "5", "--candidates", "3"]) == 2
