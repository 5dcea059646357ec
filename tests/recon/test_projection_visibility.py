"""Screen radii and visibility from the projection alone (recon.projection.project_visibility) against the renderer.

The batched path must give the renderer's integer radii and visibility masks exactly (not to a tolerance),
for Gaussians in front of, behind and straddling the near plane, inside, outside and at the edge of the
frustum, in float32 and float64, whatever the block size.
"""

import math

import pytest
import torch

from recon.camera import Camera
from recon.camera_paths import random_sphere
from recon.gaussians import GaussianSet
from recon.projection import (
    MAX_RADIUS,
    NEAR_PLANE,
    GaussianTerms,
    iter_visibility,
    project_gaussians,
    project_visibility,
    project_visibility_reference,
    view_blocks,
)
from recon.render import render
from recon.render_reference import project_gaussians_reference

F64 = torch.float64


def _random_set(n: int, seed: int, spread: float = 4.0, dtype=torch.float32) -> GaussianSet:
    """Anisotropic, rotated Gaussians in a cube of side ``spread`` around the origin (cameras sit inside it)."""
    gen = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=gen, dtype=F64) - 0.5) * spread
    quats = torch.randn(n, 4, generator=gen, dtype=F64)
    log_scales = torch.randn(n, 3, generator=gen, dtype=F64) * 0.8 - 3.0
    logits = torch.randn(n, generator=gen, dtype=F64)
    sh = 0.3 * torch.randn(n, 1, 3, generator=gen, dtype=F64)
    return GaussianSet(means, quats, log_scales, logits, sh).to(dtype=dtype)


def _cameras(seed: int) -> list[Camera]:
    """Cameras of several sizes and fields of view at 1.5-2.5 units: some Gaussians are behind each of them."""
    cams = random_sphere(3, 1.5, 40, 30, math.radians(60), seed=seed)
    cams += random_sphere(2, 2.5, 33, 47, math.radians(90), seed=seed + 1)
    skew = Camera(37, 29, 30.0, 41.0, 15.3, 16.9, cams[0].world_to_camera, name="off-centre")
    return cams + [skew]


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_radii_and_masks_equal_the_renderer(dtype):
    gaussians = _random_set(1200, seed=1, dtype=dtype)
    cams = _cameras(seed=2)
    radii, visible = project_visibility(gaussians, cams, block=257)  # blocks that do not divide N
    assert radii.dtype == torch.int32 and visible.dtype == torch.bool and radii.shape == (len(cams), 1200)
    for k, cam in enumerate(cams):
        out = render(gaussians, cam, 1.0)
        assert torch.equal(radii[k], out.radii), f"camera {k}: {(radii[k] != out.radii).sum()} radii differ"
        assert torch.equal(visible[k], out.visible)
    # the scene exercises every case: culled behind the camera, outside the image, and visible
    depths = torch.stack([project_gaussians(gaussians, c).depths for c in cams])
    assert (depths <= NEAR_PLANE).sum() > 100 and ((depths > NEAR_PLANE) & ~visible).sum() > 100
    assert visible.sum() > 1000


def test_equal_to_the_per_gaussian_twin():
    gaussians = _random_set(300, seed=3, dtype=F64)
    cams = _cameras(seed=4)
    radii, visible = project_visibility(gaussians, cams)
    for k, cam in enumerate(cams):
        slow = project_gaussians_reference(gaussians, cam)  # explicit 3x3 matrices and eigvalsh, one by one
        assert torch.equal(radii[k], slow.radii)
    ref_radii, ref_visible = project_visibility_reference(gaussians, cams)
    assert torch.equal(radii, ref_radii) and torch.equal(visible, ref_visible)


def test_block_size_does_not_change_a_bit():
    gaussians = _random_set(500, seed=5)
    cams = _cameras(seed=6)
    expected = project_visibility(gaussians, cams)
    for block in (1, 7, 64, 499, 500, 4096):
        radii, visible = project_visibility(gaussians, cams, block=block)
        assert torch.equal(radii, expected[0]) and torch.equal(visible, expected[1])


def test_frustum_edge_row_matches_the_pixel_centre_rule():
    """A dense row of Gaussians crossing the left and right image borders: visible exactly when a pixel centre
    of the image lies within [u - r, u + r] (checked in float64 Python from the renderer's u and r)."""
    cam = Camera.look_at((0.0, 0.0, -2.0), (0.0, 0.0, 0.0), (0.0, -1.0, 0.0), 32, 24, math.radians(60))
    n = 801
    xs = torch.linspace(-2.2, 2.2, n, dtype=F64)
    means = torch.stack([xs, torch.full_like(xs, 0.3), torch.zeros_like(xs)], -1)
    gaussians = GaussianSet.from_points(means, scale=torch.linspace(0.004, 0.03, n, dtype=F64), opacity=0.5)
    radii, visible = project_visibility(gaussians, [cam])
    proj = project_gaussians(gaussians, cam)
    full = render(gaussians, cam, 1.0)
    assert torch.equal(radii[0], full.radii) and torch.equal(visible[0], full.visible)
    unclipped = torch.ceil(
        3.0
        * torch.sqrt(
            torch.linalg.eigvalsh(
                torch.stack(
                    [torch.linalg.inv(torch.tensor([[a, b], [b, c]], dtype=F64)) for a, b, c in proj.conics.tolist()]
                )
            )[:, -1]
        )
    )
    rule = []
    for (u, v), r in zip(proj.means2d.tolist(), unclipped.tolist(), strict=True):
        cols = [i for i in range(cam.width) if u - r <= i + 0.5 <= u + r]
        rows = [j for j in range(cam.height) if v - r <= j + 0.5 <= v + r]
        rule.append(bool(cols) and bool(rows))
    assert visible[0].tolist() == rule
    # both borders are crossed: the visible run starts and ends strictly inside the row
    inside = torch.nonzero(visible[0]).flatten()
    assert 0 < int(inside[0]) and int(inside[-1]) < n - 1
    assert bool(((proj.means2d[:, 0] < 0) & visible[0]).any())  # a centre left of the image, its footprint inside
    assert bool(((proj.means2d[:, 0] >= cam.width) & visible[0]).any())


def test_behind_the_camera_and_at_the_near_plane():
    cam = Camera.look_at((0.0, 0.0, -2.0), (0.0, 0.0, 0.0), (0.0, -1.0, 0.0), 32, 32, math.radians(60))
    # camera-frame depths 2, 0.2 + 1e-6, exactly 0.2, 0.1, -1 (behind), -3 (behind, on the optical axis)
    z = torch.tensor([0.0, NEAR_PLANE + 1e-6 - 2.0, NEAR_PLANE - 2.0, -1.9, -3.0, -5.0], dtype=F64)
    means = torch.stack([torch.zeros_like(z), torch.zeros_like(z), z], -1)
    gaussians = GaussianSet.from_points(means, scale=0.05, opacity=0.5)
    radii, visible = project_visibility(gaussians, [cam])
    assert visible[0].tolist() == [True, True, False, False, False, False]
    assert torch.equal(radii[0], render(gaussians, cam, 1.0).radii)


def test_extreme_scales_match_the_projection():
    """Huge and overflowing scales: clamped to MAX_RADIUS or culled, the same as the single-view projection."""
    gaussians = _random_set(40, seed=7)
    gaussians.log_scales[:5] = 20.0  # sigma ~ 5e8: radius clamped
    gaussians.log_scales[5:10] = 60.0  # sigma^2 overflows float32: NaN covariance, culled
    cams = _cameras(seed=8)
    radii, _ = project_visibility(gaussians, cams)
    ref, _ = project_visibility_reference(gaussians, cams)
    assert torch.equal(radii, ref)
    assert (radii[:, :5] == MAX_RADIUS).any() and (radii[:, 5:10] == 0).all()


def test_blocks_are_bounded_and_carry_the_projection():
    gaussians = _random_set(1000, seed=9)
    cams = _cameras(seed=10)[:2]
    seen = torch.zeros(len(cams), gaussians.num, dtype=torch.int64)
    for blk in iter_visibility(gaussians, cams, block=300):
        n = blk.gaussians.stop - blk.gaussians.start
        assert 1 <= n <= 300 and blk.radii.shape == blk.u.shape == blk.depths.shape == blk.dets.shape == (n,)
        proj = project_gaussians(gaussians, cams[blk.camera])
        assert torch.equal(blk.u, proj.means2d[blk.gaussians, 0]) and torch.equal(blk.v, proj.means2d[blk.gaussians, 1])
        assert torch.equal(blk.depths, proj.depths[blk.gaussians])
        assert torch.equal(blk.visible, proj.radii[blk.gaussians] > 0)
        seen[blk.camera, blk.gaussians] += 1
    assert (seen == 1).all()
    terms = GaussianTerms.of(gaussians)
    assert terms.xyz.shape == (3, 1000) and terms.sigma.shape == (6, 1000)
    assert len(list(view_blocks(terms, cams[0], 0, 1000))) == 1


def test_gradients_of_the_renderer_still_flow():
    gaussians = _random_set(60, seed=11, spread=1.0, dtype=F64)
    for t in (gaussians.means, gaussians.quats, gaussians.log_scales):
        t.requires_grad_(True)
    cam = Camera.look_at((0.0, 0.0, -3.0), (0.0, 0.0, 0.0), (0.0, -1.0, 0.0), 24, 24, math.radians(50))
    proj = project_gaussians(gaussians, cam)
    (proj.conics.sum() + proj.means2d.sum()).backward()
    for t in (gaussians.means, gaussians.quats, gaussians.log_scales):
        assert t.grad is not None and torch.isfinite(t.grad).all() and t.grad.abs().sum() > 0


def test_bad_input_raises_value_errors():
    gaussians = _random_set(10, seed=12)
    cam = _cameras(seed=13)[0]
    with pytest.raises(ValueError, match="non-empty list"):
        project_visibility(gaussians, [])
    with pytest.raises(ValueError, match="wrap a single camera"):
        project_visibility(gaussians, cam)
    with pytest.raises(ValueError, match="not a recon.camera.Camera"):
        project_visibility(gaussians, [cam, "front"])
    with pytest.raises(ValueError, match="block must be a positive int"):
        project_visibility(gaussians, [cam], block=0)
    with pytest.raises(ValueError, match="GaussianSet"):
        project_visibility(gaussians.means, [cam])
    with pytest.raises(ValueError, match="float32 or float64"):
        project_visibility(gaussians.to(dtype=torch.float16), [cam])


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_in_place_core_gives_the_same_bits(dtype):
    """The batched path's in-place core and footprint equal the differentiable core and the out-of-place footprint
    (the formulas of the module docstring written as plain expressions) bit for bit, NaN and clamped radii included."""
    from recon.projection import (
        EXTENT_SIGMAS,
        ViewConstants,
        _footprint_radii,
        _screen_terms,
        _screen_terms_in_place,
        covariance_terms,
    )

    gaussians = _random_set(3000, seed=11, dtype=dtype)
    gaussians.log_scales[:5] = 20.0  # radius clamped to MAX_RADIUS
    gaussians.log_scales[5:10] = 60.0  # overflowing covariance: NaN, culled
    sigma = [t.detach() for t in covariance_terms(gaussians)]
    x, y, z = gaussians.means.detach().T
    checked = 0
    for cam in _cameras(seed=12):
        k = ViewConstants.of(cam, NEAR_PLANE, gaussians.means)
        u, v, tz, a, b, c = _screen_terms(x, y, z, sigma, k)
        got = _screen_terms_in_place(x, y, z, sigma, k)
        for name, want, have in zip("u v tz a b c".split(), (u, v, tz, a, b, c), got, strict=True):
            assert torch.equal(want.nan_to_num(7.0), have.nan_to_num(7.0)), name
        det = a * c - b * b
        mid = (a + c) * 0.5
        radii = torch.ceil(torch.sqrt(torch.sqrt((mid * mid - det).clamp_min(0.0)) + mid) * EXTENT_SIGMAS)
        radii = radii.clamp_max(MAX_RADIUS)
        margins = [
            (radii + half) - (w - centre).abs() for w, centre, half in ((u, k.mid_x, k.half_x), (v, k.mid_y, k.half_y))
        ]
        margin = torch.minimum(torch.minimum(*margins), torch.minimum(radii - 1.0, tz - k.near_up))
        expected = (radii * (torch.sign(margin) + 1.0).clamp_max(1.0)).nan_to_num(0.0)
        inputs = [t.clone() for t in (u, v, tz, a, c, det)]
        assert torch.equal(_footprint_radii(u, v, tz, a, c, det, k), expected)
        for before, after in zip(inputs, (u, v, tz, a, c, det), strict=True):  # the inputs are left alone
            assert torch.equal(before.nan_to_num(7.0), after.nan_to_num(7.0))
        checked += int((expected > 0).sum())
    assert checked > 1000


def test_footprints_of_a_view_with_nothing_culled_skip_the_culling():
    """A block whose centres all lie in [0.5, W - 0.5] x [0.5, H - 0.5], in front, with radii >= 1 keeps every
    radius (the culling's factor is 1); the shortcut is taken exactly then, and the radii equal the full formula."""
    from recon.projection import (
        EXTENT_SIGMAS,
        ViewConstants,
        _all_kept,
        _footprint_radii,
        _screen_terms_in_place,
        covariance_terms,
    )

    cam = Camera.look_at((0.0, 0.0, -3.0), (0.0, 0.0, 0.0), (0.0, -1.0, 0.0), 40, 30, math.radians(60))
    k = ViewConstants.of(cam, NEAR_PLANE, torch.zeros(1))
    ones = torch.ones(4)
    u, v = torch.tensor([0.5, 39.5, 20.0, 3.0]), torch.tensor([0.5, 29.5, 7.0, 12.0])
    tz = torch.tensor([float(k.near_up), 1.0, 2.0, 3.0])
    assert _all_kept(u, v, tz, ones, k)
    below = torch.nextafter(torch.tensor(0.5), torch.tensor(0.0))
    for changed in (
        (torch.cat([below.reshape(1), u[1:]]), v, tz, ones),
        (u, torch.tensor([0.5, 29.5 + 1e-5, 7.0, 12.0]), tz, ones),
        (u, v, torch.tensor([NEAR_PLANE, 1.0, 2.0, 3.0]), ones),
        (u, v, tz, torch.tensor([1.0, 0.0, 1.0, 1.0])),
        (u, v, tz, torch.tensor([1.0, math.nan, 1.0, 1.0])),
        (torch.tensor([0.5, math.nan, 2.0, 3.0]), v, tz, ones),
    ):
        assert not _all_kept(*changed, k)
    assert not _all_kept(u[:0], v[:0], tz[:0], ones[:0], k)

    gaussians = _random_set(2000, seed=5, spread=0.8)  # all in front of the camera, centres inside the image
    sigma = [t.detach() for t in covariance_terms(gaussians)]
    x, y, z = gaussians.means.detach().T
    u, v, tz, a, b, c = _screen_terms_in_place(x, y, z, sigma, k)
    det = a * c - b * b
    mid = (a + c) * 0.5
    radii = torch.ceil(torch.sqrt(torch.sqrt((mid * mid - det).clamp_min(0.0)) + mid) * EXTENT_SIGMAS)
    assert _all_kept(u, v, tz, radii.clamp_max(MAX_RADIUS), k)
    assert torch.equal(_footprint_radii(u, v, tz, a, c, det, k), radii.clamp_max(MAX_RADIUS))
