"""Space carving (nbv.physics.carve): surface depth maps against the compositing they come from, carving against
analytic depth maps of a sphere, and a thin shell with a hole that filling alone cannot close."""

import math

import numpy as np
import pytest
import torch

from nbv.physics.carve import carve_outside, seen_empty, surface_depths
from nbv.physics.solidify import SceneTransform, SolidifyConfig, gaussians_to_solid
from recon.camera import Camera
from recon.render import render

from helpers.shells import SPACING, flat_gaussians, sphere_shell


def ring_cameras(n: int, radius: float = 3.0, heights=(0.0,), size: int = 96) -> list[Camera]:
    cams = []
    for h in heights:
        for k in range(n):
            a = 2 * math.pi * (k + 0.5 * (h != 0)) / n
            eye = (radius * math.cos(a), h, radius * math.sin(a))
            cams.append(Camera.look_at(eye, (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), size, size, 0.9, name=f"c{h}_{k}"))
    return cams


def sphere_depths(cameras, radius: float) -> list[np.ndarray]:
    """View depth z of the first hit of each pixel's centre ray on the sphere |x| = radius (inf: miss)."""
    out = []
    for cam in cameras:
        jj, ii = np.meshgrid(np.arange(cam.width) + 0.5, np.arange(cam.height) + 0.5)
        rays = np.stack([(jj - cam.cx) / cam.fx, (ii - cam.cy) / cam.fy, np.ones_like(jj)], -1)  # z = 1
        c2w = cam.camera_to_world.numpy()
        d = rays @ c2w[:3, :3].T
        o = c2w[:3, 3]
        b = d @ o
        a = (d * d).sum(-1)
        disc = b * b - a * (o @ o - radius**2)
        t = np.where(disc >= 0, (-b - np.sqrt(np.maximum(disc, 0))) / a, np.inf)
        out.append(t)  # with d's z = 1 in camera axes, t is the view depth
    return out


def test_surface_depth_is_where_the_opacity_reaches_one_half():
    """A half-transparent disc in front of an opaque one: the surface is the front disc (1 - T = 0.6 there),
    where the alpha-weighted mean depth of recon.render lies between the two."""
    means = np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 3.0]])
    g = flat_gaussians(means, np.array([[0, 0, 1.0], [0, 0, 1.0]]), sigma_t=0.5, sigma_n=0.01, opacity=0.6)
    g.opacity_logits[1] = math.log(0.95 / 0.05)
    cam = Camera.look_at((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, -1.0, 0.0), 32, 32, 0.5)
    depth = surface_depths(g, [cam])[0]
    assert depth.shape == (32, 32)
    assert np.allclose(depth[12:20, 12:20], 2.0)
    out = render(g, cam)
    mean = (out.depth / out.alpha.clamp_min(1e-9)).detach().numpy()
    assert (mean[12:20, 12:20] > 2.2).all() and (mean[12:20, 12:20] < 3.0).all()
    thin = flat_gaussians(means[:1], np.array([[0, 0, 1.0]]), sigma_t=0.5, sigma_n=0.01, opacity=0.4)
    assert np.isinf(surface_depths(thin, [cam])[0]).all()  # 1 - T never reaches 0.5
    with pytest.raises(ValueError, match="level"):
        surface_depths(g, [cam], level=1.0)


def test_carving_a_sphere_from_analytic_depths_gives_its_visual_hull():
    cams = ring_cameras(8, heights=(0.0, 2.0, -2.0))
    depths = sphere_depths(cams, 0.5)
    sp = 0.05
    shape = (41, 41, 41)
    lattice_min = np.full(3, -1.0)
    carved = carve_outside(np.zeros(shape, bool), lattice_min, sp, cams, depths, SceneTransform(), margin=0.0)
    idx = np.stack(np.meshgrid(*[np.arange(d) for d in shape], indexing="ij"), -1)
    r = np.linalg.norm(lattice_min + sp * idx, axis=-1)
    assert carved[r < 0.5].all()  # nothing inside the sphere is seen empty
    assert not carved[r > 0.75].any()  # the hull of 24 views hugs the sphere
    ratio = carved.sum() / (r < 0.5).sum()
    assert 1.0 <= ratio < 1.25
    # the margin keeps more in front of the surface; solid points always stay
    wide = carve_outside(np.zeros(shape, bool), lattice_min, sp, cams, depths, SceneTransform(), margin=1.0)
    assert (wide >= carved).all() and wide.sum() > carved.sum()
    seed = np.zeros(shape, bool)
    seed[0, 0, 0] = True
    assert carve_outside(seed, lattice_min, sp, cams, depths, SceneTransform(), margin=0.0)[0, 0, 0]


def test_carving_follows_the_scene_transform():
    """The lattice lives in simulation metres, the cameras in the scene: to_scene maps between them."""
    cams = ring_cameras(6)
    depths = sphere_depths(cams, 0.5)
    pts_sim = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.8], [0.0, 1.8, 0.0]])
    tr = SceneTransform("z", 2.0)  # scene (x, y, z) -> sim 2 (x, z, -y)
    seen = seen_empty(tr.to_scene(pts_sim), cams, depths, 0.0)
    # sim (0, 0, 1.8) is scene (0, -0.9, 0): in front of the ring cameras' sphere, seen empty by one of them;
    # sim (0, 1.8, 0) is scene (0, 0, 0.9): seen as well; the centre never is
    assert seen.tolist() == [False, True, True]


def test_view_checks_name_the_problem():
    cams = ring_cameras(2, size=8)
    with pytest.raises(ValueError, match="2 cameras but 1 depth"):
        carve_outside(np.zeros((2, 2, 2), bool), np.zeros(3), 0.1, cams, [np.zeros((8, 8))], SceneTransform())
    with pytest.raises(ValueError, match="shape"):
        carve_outside(
            np.zeros((2, 2, 2), bool), np.zeros(3), 0.1, cams, [np.zeros((8, 8)), np.zeros((4, 8))], SceneTransform()
        )


def test_carving_closes_a_thin_shell_with_a_hole():
    """A sphere of thin discs with a cap cut away: the fill's outside runs in through the hole, so the solid is a
    one-point shell; carved from cameras that do not look into the hole, the unseen inside is solid."""
    shell = sphere_shell(0.6)
    means = shell.means.numpy()
    g = shell.subset(torch.from_numpy(means[:, 1] < 0.45))  # a hole of radius 0.4 m at the top
    cfg = SolidifyConfig(spacing=SPACING)
    open_solid = gaussians_to_solid(g, cfg, SceneTransform())
    volume = 4.0 / 3.0 * math.pi * 0.6**3 / SPACING**3
    assert open_solid.counts["enclosed"] == 0 and len(open_solid.points) < 0.3 * volume
    cams = ring_cameras(6, heights=(0.0, -2.0), size=128)  # around and below: none sees into the hole
    depths = surface_depths(g, cams)
    carved = gaussians_to_solid(g, cfg, SceneTransform(), cameras=cams, depths=depths)
    assert carved.counts["carved"] > 0.6 * volume
    assert abs(len(carved.points) / volume - 1.0) < 0.15
    r = np.linalg.norm(carved.points, axis=1)
    assert r.max() < 0.6 + 2 * SPACING and (r > 0.6 + SPACING / 2).sum() < 0.03 * volume  # hardly grown
    # A camera above looks in through the hole: what it sees inside is empty, as for a real cup.
    top = Camera.look_at((0.0, 3.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 128, 128, 0.9, name="top")
    cup = gaussians_to_solid(
        g, cfg, SceneTransform(), cameras=[*cams, top], depths=[*depths, *surface_depths(g, [top])]
    )
    axis = cup.points[np.linalg.norm(cup.points[:, [0, 2]], axis=1) < 0.1]
    assert len(cup.points) < len(carved.points) and (axis[:, 1] > -0.5).sum() == 0


def test_sphere_of_surface_gaussians_is_carved_like_the_analytic_sphere():
    """surface_depths of a closed thin shell equal the analytic sphere depths where both see the sphere."""
    g = sphere_shell(0.6)
    cams = ring_cameras(3, size=48)
    rendered = surface_depths(g, cams)
    exact = sphere_depths(cams, 0.6)
    for a, b in zip(rendered, exact, strict=True):
        both = np.isfinite(a) & np.isfinite(b)
        assert both.sum() > 0.1 * a.size  # the sphere covers ~15 % of the view
        assert (np.isfinite(a) >= np.isfinite(b)).all()  # the rendered silhouette holds the sphere's
        assert (a[both] <= b[both] + 0.01).all()  # never behind the sphere: carving never cuts it
        front = both & (b < 2.5)  # away from the rim, where splats overhang:
        assert np.abs(a[front] - b[front]).max() < 0.04  # the crossing disc's centre, within 2 sigma_t
        # The splats overhang the sphere's silhouette by at most two pixels: at 48 px a disc projects to a third
        # of a pixel, and the rasterizer's 0.3 px^2 low-pass spreads it over about one more.
        grown = np.pad(np.isfinite(b), 2)
        grown = np.max([grown[i : i + b.shape[0], j : j + b.shape[1]] for i in range(5) for j in range(5)], axis=0)
        assert not (np.isfinite(a) & ~grown).any()
