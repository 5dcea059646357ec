"""EWA projection of 3D Gaussians to screen-space conics (Zwicker et al. 2001; Kerbl et al. 2023, Sec. 4).

With the world-to-camera rotation W, a camera-frame mean t = (t_x, t_y, t_z) and the Jacobian of the
pinhole map (u, v) = (f_x t_x / t_z + c_x, f_y t_y / t_z + c_y),

    J = [[f_x / t_z, 0, -f_x t_x / t_z^2], [0, f_y / t_z, -f_y t_y / t_z^2]],

the screen-space covariance is Sigma' = J W Sigma W^T J^T + 0.3 I (Kerbl et al. Eq. 5, plus the
reference rasterizer's 0.3 px^2 low-pass dilation). Conventions of the reference CUDA code
(diff-gaussian-rasterization, ``preprocessCUDA`` / ``computeCov2D``):

- a Gaussian is culled (radius 0) when t_z <= 0.2 (the near plane);
- inside J only, t_x / t_z and t_y / t_z are clamped to +-1.3 tan(fov / 2) (the frustum guard band), so
  Gaussians far outside the view do not get huge, ill-conditioned footprints;
- the conic is the inverse of Sigma', and the radius is r = ceil(3 sqrt(lambda_max(Sigma'))).

Deliberate differences from the reference, both small:

- lambda_max = mid + sqrt(max(mid^2 - det, 0)) exactly; the reference floors the discriminant at 0.1,
  which adds up to 0.32 px^2 to lambda_max of near-isotropic splats;
- the footprint is the set of pixels whose centres lie in the square [u - r, u + r] x [v - r, v + r]
  (pixel-granular), where the reference tests 16 x 16 tiles; a Gaussian whose square holds no pixel
  centre of the image is culled (radius 0).

Pixel centres are at integer + 0.5 (see :mod:`recon.camera`), so the projected mean equals
``Camera.project`` exactly, and ``cx = W / 2`` is the image centre.

Two entry points share one elementwise core (:func:`_screen_terms` for the centre, depth and Sigma',
:func:`_footprint_radii` for the radius and the culling):

- :func:`project_gaussians`: one view, differentiable, everything the rasterizer needs;
- :func:`project_visibility` / :func:`iter_visibility`: radii and visibility only (all that the view score
  S(T) of FluidGaussian Eq. 4-5 needs), for many cameras without rasterising, one camera at a time in
  blocks of Gaussians (bounded memory).

The core uses single elementwise tensor operations only (+, -, *, reciprocal, sqrt, ceil, abs, sign, min,
clamp), each of which IEEE 754 rounds correctly, so a value does not depend on the tensor's shape, its
position in a vectorised loop or the blocking; camera constants enter as 0-dim tensors of the Gaussians'
dtype in both paths, and the per-Gaussian covariance is computed once on the whole set in both. So the
batched radii and masks equal the renderer's bit for bit, not just to a tolerance. (Fused kernels such as
``addcmul`` or a matmul could round differently per position and are avoided on purpose.)
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass

import torch

from .camera import Camera
from .gaussians import GaussianSet

NEAR_PLANE = 0.2  # camera-frame depth below which a Gaussian is culled (reference: p_view.z <= 0.2)
GUARD_BAND = 1.3  # frustum guard band of the Jacobian, in units of tan(fov / 2)
DILATION = 0.3  # px^2 added to the diagonal of the 2-D covariance (anti-aliasing low-pass)
EXTENT_SIGMAS = 3.0  # footprint half-width in standard deviations
MAX_RADIUS = 2.0**30  # radii are clamped here so that they fit int32 (the boxes are clipped to the image anyway)
# Gaussians per block of the batched path (one camera at a time): on the CPU small enough that the ~30 live
# temporaries stay in cache and every op runs inline on its thread (torch's grain size is 32768 elements);
# on a GPU large enough to fill it
CPU_BLOCK = 1 << 15
GPU_BLOCK = 1 << 22


@dataclass
class Projection:
    """Screen-space Gaussians of one view.

    Attributes:
        means2d: [N, 2] projected centres in pixels (continuous; pixel i spans [i, i + 1)).
        conics: [N, 3] (A, B, C) of the inverse 2-D covariance [[A, B], [B, C]], 1/px^2.
        depths: [N] camera-frame depth t_z of the means (scene units).
        radii: [N] int32 footprint half-widths in pixels, ceil(3 sqrt(lambda_max)); 0 when culled.
        boxes: [N, 4] int32 (x0, y0, x1, y1) inclusive pixel ranges of the footprints clipped to the image
            (meaningless where radii == 0).
    """

    means2d: torch.Tensor
    conics: torch.Tensor
    depths: torch.Tensor
    radii: torch.Tensor
    boxes: torch.Tensor


@dataclass(frozen=True)
class ViewConstants:
    """The numbers of one camera that the projection core uses.

    Factors of products are 0-dim tensors in the Gaussians' dtype and device (an elementwise op with a
    0-dim operand is torch's scalar fast path, and the value is the same rounded number in every path);
    bounds of ``clamp`` are Python floats.

    Attributes:
        rot: the world-to-camera rotation, row-major, 9 0-dim tensors. trans: its translation, 3 of them.
        fx, fy, cx, cy: intrinsics, pixels; fxx, fxy, fyy: the products fx fx, fx fy, fy fy (0-dim tensors).
        mid_x, mid_y: W / 2 and H / 2; half_x, half_y: (W - 1) / 2 and (H - 1) / 2 (0-dim tensors).
        lim_x, lim_y: guard-band limits of t_x / t_z and t_y / t_z.
        near: the culling depth rounded to the Gaussians' dtype (float); ``near_up`` (0-dim tensor) the next
            representable value above it, so t_z > near  <=>  t_z - near_up >= 0, exactly.
    """

    rot: tuple[torch.Tensor, ...]
    trans: tuple[torch.Tensor, ...]
    fx: torch.Tensor
    fy: torch.Tensor
    cx: torch.Tensor
    cy: torch.Tensor
    fxx: torch.Tensor
    fxy: torch.Tensor
    fyy: torch.Tensor
    near_up: torch.Tensor
    mid_x: torch.Tensor
    mid_y: torch.Tensor
    half_x: torch.Tensor
    half_y: torch.Tensor
    lim_x: float
    lim_y: float
    near: float

    @classmethod
    def of(cls, camera: Camera, near_plane: float, like: torch.Tensor) -> ViewConstants:
        """The constants of ``camera`` in the dtype and on the device of ``like``."""
        w2c = camera.world_to_camera
        f, g = camera.fx, camera.fy
        near = torch.tensor(near_plane, dtype=like.dtype)
        near_up = torch.nextafter(near, torch.tensor(float("inf"), dtype=like.dtype))
        w, h = camera.width, camera.height
        values = (
            [float(v) for v in w2c[:3, :3].reshape(-1)]
            + [float(v) for v in w2c[:3, 3]]
            + [f, g, camera.cx, camera.cy, f * f, f * g, g * g, float(near_up), w / 2, h / 2, (w - 1) / 2, (h - 1) / 2]
        )
        k = torch.tensor(values, dtype=torch.float64).to(device=like.device, dtype=like.dtype).unbind(0)
        return cls(k[:9], k[9:12], *k[12:24], GUARD_BAND * 0.5 * w / f, GUARD_BAND * 0.5 * h / g, float(near))


def covariance_terms(gaussians: GaussianSet) -> tuple[torch.Tensor, ...]:
    """The upper triangle (S00, S01, S02, S11, S12, S22) of Sigma = R S S^T R^T, six [N] tensors (with grad).

    Both projection paths take it from here, on the whole set, so that they see the same bits.
    """
    cov = gaussians.covariances()
    return cov[:, 0, 0], cov[:, 0, 1], cov[:, 0, 2], cov[:, 1, 1], cov[:, 1, 2], cov[:, 2, 2]


def _screen_terms(x, y, z, sigma: Sequence[torch.Tensor], cam: ViewConstants):
    """The elementwise core: projected centre, depth and dilated 2-D covariance of N Gaussians in one view.

    With the clamped ratios s = t_x / t_z, t = t_y / t_z and the rotation rows r_0, r_1, r_2,
    J W = diag(f_x, f_y) / t_z [r_0 - s r_2; r_1 - t r_2], so Sigma' = J W Sigma W^T J^T + 0.3 I takes the
    quadratic forms e_a^T Sigma e_b of e_0 = r_0 - s r_2 and e_1 = r_1 - t r_2, scaled by f_a f_b / t_z^2.

    Args:
        x, y, z: [N] world means (scene units). sigma: the six covariance terms, [N] each.
        cam: the view.
    Returns:
        u, v (pixels), t_z (raw depth), A, B, C of Sigma' + 0.3 I (px^2), all [N]. Rows behind the near plane
        are projected from t_z = near instead (finite, unused; their gradients are 0).
    """
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = cam.rot
    s00, s01, s02, s11, s12, s22 = sigma
    tx = x * r00 + y * r01 + z * r02 + cam.trans[0]
    ty = x * r10 + y * r11 + z * r12 + cam.trans[1]
    tz = x * r20 + y * r21 + z * r22 + cam.trans[2]
    inv_z = tz.clamp_min(cam.near).reciprocal()
    xz, yz = tx * inv_z, ty * inv_z
    u, v = xz * cam.fx + cam.cx, yz * cam.fy + cam.cy
    sx, sy = xz.clamp(-cam.lim_x, cam.lim_x), yz.clamp(-cam.lim_y, cam.lim_y)
    e00, e01, e02 = r00 - sx * r20, r01 - sx * r21, r02 - sx * r22
    e10, e11, e12 = r10 - sy * r20, r11 - sy * r21, r12 - sy * r22
    p0, p1, p2 = s00 * e00 + s01 * e01 + s02 * e02, s01 * e00 + s11 * e01 + s12 * e02, s02 * e00 + s12 * e01 + s22 * e02
    q0, q1, q2 = s00 * e10 + s01 * e11 + s02 * e12, s01 * e10 + s11 * e11 + s12 * e12, s02 * e10 + s12 * e11 + s22 * e12
    inv_z2 = inv_z * inv_z
    a = (e00 * p0 + e01 * p1 + e02 * p2) * (inv_z2 * cam.fxx) + DILATION
    b = (e10 * p0 + e11 * p1 + e12 * p2) * (inv_z2 * cam.fxy)
    c = (e10 * q0 + e11 * q1 + e12 * q2) * (inv_z2 * cam.fyy) + DILATION
    return u, v, tz, a, b, c


def _screen_terms_in_place(x, y, z, sigma: Sequence[torch.Tensor], cam: ViewConstants, out=None):
    """:func:`_screen_terms` without gradients, in fewer and reused buffers (no new values: the same operations on
    the same operands in the same order, so the same bits; a test holds the two together).

    About 20 % faster on the CPU at 32k-element blocks, where the ~60 temporaries of :func:`_screen_terms` do not
    stay in the cache. ``out``: (u, v, t_z) tensors to write those three into (:func:`_centres_in_place`).
    """
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = cam.rot
    s00, s01, s02, s11, s12, s22 = sigma

    def dot(a0, b0, a1, b1, a2, b2):  # a0 b0 + a1 b1 + a2 b2
        out = a0 * b0
        out += a1 * b1
        out += a2 * b2
        return out

    def edge(r, s, q):  # r - s q
        out = s * q
        return torch.sub(r, out, out=out)

    u, v, tz, xz, yz, inv_z = _centres_in_place(x, y, z, cam, out)
    sx, sy = xz.clamp_(-cam.lim_x, cam.lim_x), yz.clamp_(-cam.lim_y, cam.lim_y)
    e00, e01, e02 = edge(r00, sx, r20), edge(r01, sx, r21), edge(r02, sx, r22)
    e10, e11, e12 = edge(r10, sy, r20), edge(r11, sy, r21), edge(r12, sy, r22)
    p0, p1, p2 = dot(s00, e00, s01, e01, s02, e02), dot(s01, e00, s11, e01, s12, e02), dot(s02, e00, s12, e01, s22, e02)
    q0, q1, q2 = dot(s00, e10, s01, e11, s02, e12), dot(s01, e10, s11, e11, s12, e12), dot(s02, e10, s12, e11, s22, e12)
    inv_z2 = inv_z.mul_(inv_z)
    a, b, c = dot(e00, p0, e01, p1, e02, p2), dot(e10, p0, e11, p1, e12, p2), dot(e10, q0, e11, q1, e12, q2)
    a *= inv_z2 * cam.fxx
    a += DILATION
    b *= inv_z2 * cam.fxy
    c *= inv_z2 * cam.fyy
    c += DILATION
    return u, v, tz, a, b, c


def _centres_in_place(x, y, z, cam: ViewConstants, out=None):
    """The projected centres of :func:`_screen_terms_in_place` (its first operations, the same bits): u, v
    (pixels), the raw depth t_z, the ratios t_x / t_z and t_y / t_z and 1 / max(t_z, near), all [N] and new, or u,
    v and t_z written into the three tensors of ``out``.

    The ratios and the reciprocal are handed on to the rest of the core, which overwrites them.
    """
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = cam.rot
    u_out, v_out, tz_out = (None, None, None) if out is None else out

    def row(a, b, c, t, into=None):  # x a + y b + z c + t
        acc = torch.mul(x, a, out=into) if into is not None else x * a
        acc += y * b
        acc += z * c
        acc += t
        return acc

    tx, ty = row(r00, r01, r02, cam.trans[0]), row(r10, r11, r12, cam.trans[1])
    tz = row(r20, r21, r22, cam.trans[2], tz_out)
    inv_z = tz.clamp_min(cam.near).reciprocal_()
    xz, yz = tx.mul_(inv_z), ty.mul_(inv_z)
    u = torch.mul(xz, cam.fx, out=u_out) if u_out is not None else xz * cam.fx
    v = torch.mul(yz, cam.fy, out=v_out) if v_out is not None else yz * cam.fy
    u += cam.cx
    v += cam.cy
    return u, v, tz, xz, yz, inv_z


def _footprint_radii(u, v, tz, a, c, det, cam: ViewConstants, out: torch.Tensor | None = None) -> torch.Tensor:
    """Float radii ceil(3 sqrt(lambda_max)) of visible footprints, 0 for culled ones, [N] (no gradient).

    ``det`` is a c - b^2 of Sigma'. Culled: behind the near plane, not finite, or no pixel centre of the
    image within [u - r, u + r] x [v - r, v + r] (:func:`_axis_margin`). Written with arithmetic only (the
    sign of one min over the margins) because torch's comparisons and ``where`` cost 5-50 times an
    arithmetic op on the CPU. ``out``: a tensor to write the radii into.
    """
    # in place on its own temporaries (the inputs are left alone): fewer buffers, the same operations and bits
    mid = a + c
    mid *= 0.5
    radii = (
        torch.mul(mid, mid, out=out) if out is not None else mid * mid
    )  # lambda_max = sqrt(max(mid^2 - det, 0)) + mid, then r = min(ceil(3 sqrt(lambda_max)), MAX)
    radii -= det
    radii.clamp_min_(0.0).sqrt_()
    radii += mid
    radii.sqrt_()
    radii *= EXTENT_SIGMAS
    radii.ceil_().clamp_max_(MAX_RADIUS)
    if _all_kept(u, v, tz, radii, cam):  # the culling below would multiply every radius by 1
        return radii
    margin = torch.minimum(_axis_margin(u, radii, cam.mid_x, cam.half_x), _axis_margin(v, radii, cam.mid_y, cam.half_y))
    below = radii - 1.0
    torch.minimum(below, tz - cam.near_up, out=below)
    torch.minimum(margin, below, out=margin)
    # sign(margin) + 1 is 0 exactly when some margin is < 0; NaN anywhere (non-finite input) culls too
    margin.sign_()
    margin += 1.0
    radii *= margin.clamp_max_(1.0)
    return radii.nan_to_num_(0.0)


def _all_kept(u, v, tz, radii, cam: ViewConstants) -> bool:
    """Whether :func:`_footprint_radii` culls none of these footprints, from five reductions: every centre lies in
    [0.5, W - 0.5] x [0.5, H - 0.5] (so |c - W / 2| <= (W - 1) / 2 and each :func:`_axis_margin` is >= r >= 0), every
    t_z >= the next value above the near plane and every radius >= 1, none of them NaN. Then every margin is >= 0 and
    the culling's factor is 1 exactly (the usual block of a view of an object in the middle of the image)."""
    if u.numel() == 0:
        return False
    for centre, mid, half in ((u, cam.mid_x, cam.half_x), (v, cam.mid_y, cam.half_y)):
        lo, hi = torch.aminmax(centre)
        if not (float(lo) >= float(mid - half) and float(hi) <= float(mid + half)):
            return False
    return bool(tz.min() >= cam.near_up) and bool(radii.min() >= 1.0)


def _axis_range(center: torch.Tensor, radii: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """First and last pixel index whose centre i + 0.5 lies in [center - r, center + r] (one axis, unclipped).

    i + 0.5 in [c - r, c + r]  <=>  i in [(c - 0.5) - r, (c - 0.5) + r]; c - 0.5 is exact below 2^22 pixels.
    """
    shifted = center - 0.5
    return torch.ceil(shifted - radii), torch.floor(shifted + radii)


def _axis_margin(center: torch.Tensor, radii: torch.Tensor, mid: torch.Tensor, half: torch.Tensor) -> torch.Tensor:
    """(r + (W - 1) / 2) - |c - W / 2| (one axis, W pixels): >= 0 exactly when a pixel centre of the image lies
    within [c - r, c + r], for integer radii r >= 1.

    For r >= 1 the range lo .. hi of :func:`_axis_range` is never empty, so it meets 0 .. W - 1 when
    hi >= 0 and lo <= W - 1, i.e. when 0.5 - r <= c <= W - 0.5 + r: an interval of centre W / 2 and half-width
    r + (W - 1) / 2. (Radii below 1 are culled by the caller. The rounding of c - W / 2 can move the verdict
    only for a centre within one ulp of that interval's ends; both projection paths evaluate this same
    expression, so they agree there too.)
    """
    out = radii + half
    out -= (center - mid).abs_()
    return out


def footprint_boxes(
    means2d: torch.Tensor, radii: torch.Tensor, width: int, height: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Pixel boxes covered by the footprints, clipped to the image, and whether they hold any pixel.

    A pixel (i, j) is covered when its centre (i + 0.5, j + 0.5) lies in [u - r, u + r] x [v - r, v + r].

    Args:
        means2d: [N, 2] centres (u, v), pixels (no gradient is taken).
        radii: [N] integer radii, pixels.
        width, height: image size, pixels.
    Returns:
        boxes [N, 4] int32 (x0, y0, x1, y1), inclusive; nonempty [N] bool.
    """
    uv = means2d.detach()
    r = radii.to(uv.dtype)
    x0, x1 = _axis_range(uv[:, 0], r)
    y0, y1 = _axis_range(uv[:, 1], r)
    nonempty = (x1 >= 0) & (x0 <= x1) & (x0 <= width - 1) & (y1 >= 0) & (y0 <= y1) & (y0 <= height - 1)
    boxes = torch.stack(
        [x0.clamp(0.0, width - 1), y0.clamp(0.0, height - 1), x1.clamp(0.0, width - 1), y1.clamp(0.0, height - 1)], -1
    ).to(torch.int32)
    return boxes, nonempty


def project_gaussians(gaussians: GaussianSet, camera: Camera, near_plane: float = NEAR_PLANE) -> Projection:
    """Project Gaussians to screen-space conics (differentiable w.r.t. means, quats and log_scales).

    Args:
        gaussians: N Gaussians (float32 or float64, any device).
        camera: the view.
        near_plane: culling depth, scene units (default 0.2, the reference's).
    Returns:
        :class:`Projection`; culled Gaussians get radius 0 and finite (unused) values elsewhere.

    Example:
        >>> cam = Camera.look_at((0, 0, -2.0), (0, 0, 0), (0, -1, 0), 64, 64, 1.0)
        >>> project_gaussians(GaussianSet.from_points(torch.zeros(1, 3), scale=0.05), cam).means2d
        tensor([[32., 32.]])
    """
    means = gaussians.means
    cam = ViewConstants.of(camera, near_plane, means)
    u, v, tz, a, b, c = _screen_terms(means[:, 0], means[:, 1], means[:, 2], covariance_terms(gaussians), cam)
    means2d = torch.stack([u, v], -1)
    det = a * c - b * b
    conics = torch.stack([c / det, -b / det, a / det], -1)
    with torch.no_grad():
        radii = _footprint_radii(u.detach(), v.detach(), tz.detach(), a.detach(), c.detach(), det.detach(), cam)
        radii = radii.to(torch.int32)
        boxes, _ = footprint_boxes(means2d, radii, camera.width, camera.height)
    return Projection(means2d, conics, tz, radii, boxes)


def view_directions(gaussians: GaussianSet, camera: Camera) -> torch.Tensor:
    """[N, 3] unit directions from the camera centre to the means (the SH view direction of 3DGS)."""
    center = camera.center.to(device=gaussians.device, dtype=gaussians.dtype)
    d = gaussians.means - center
    return d / d.norm(dim=-1, keepdim=True).clamp_min(1e-12)


@dataclass
class VisibilityBlock:
    """One block of :func:`iter_visibility`: one camera and a contiguous range of Gaussians.

    Attributes:
        camera: index of the camera in the list.
        gaussians: the block's Gaussians, a slice of the set (n of them).
        radii: [n] float screen-space radii in pixels, integer-valued, exactly ``project_gaussians(...).radii``
            (0 when culled).
        u, v: [n] projected centres, pixels. depths: [n] camera-frame depths t_z, scene units.
        dets: [n] determinants of the dilated 2-D covariances Sigma' + 0.3 I, px^4 (the footprint area is
            2 pi sqrt(det) px^2).
    """

    camera: int
    gaussians: slice
    radii: torch.Tensor
    u: torch.Tensor
    v: torch.Tensor
    depths: torch.Tensor
    dets: torch.Tensor

    @property
    def visible(self) -> torch.Tensor:
        """[n] bool, radii > 0 (the renderer's ``visible``: frustum culling)."""
        return self.radii > 0


def default_block(device: torch.device | str) -> int:
    """Gaussians per block of the batched projection on ``device``."""
    return GPU_BLOCK if torch.device(device).type == "cuda" else CPU_BLOCK


def check_batch(gaussians: GaussianSet, cameras, block: int | None) -> int:
    """Validate the arguments of the batched projection; returns the block size to use."""
    if not isinstance(gaussians, GaussianSet):
        raise ValueError(f"gaussians must be a recon.gaussians.GaussianSet, got {type(gaussians).__name__}")
    if gaussians.dtype not in (torch.float32, torch.float64):
        raise ValueError(f"Gaussians must be float32 or float64, got {gaussians.dtype}; convert with .to(dtype=...)")
    if isinstance(cameras, Camera) or not isinstance(cameras, Sequence) or len(cameras) == 0:
        raise ValueError("cameras must be a non-empty list of recon.camera.Camera (wrap a single camera in a list)")
    bad = [i for i, c in enumerate(cameras) if not isinstance(c, Camera)]
    if bad:
        raise ValueError(f"cameras[{bad[0]}] is a {type(cameras[bad[0]]).__name__}, not a recon.camera.Camera")
    size = default_block(gaussians.device) if block is None else block
    if isinstance(size, bool) or not isinstance(size, int) or size < 1:
        raise ValueError(f"block must be a positive int (Gaussians per block), got {block!r}")
    return size


@dataclass(frozen=True)
class GaussianTerms:
    """Camera-independent inputs of the batched projection, computed once per Gaussian set (no gradient).

    Attributes:
        xyz: [3, N] means, one contiguous row per axis. sigma: [6, N] covariance terms
            (:func:`covariance_terms`), one contiguous row each.
    """

    xyz: torch.Tensor
    sigma: torch.Tensor

    @classmethod
    def of(cls, gaussians: GaussianSet) -> GaussianTerms:
        # the covariances' bits do not depend on the thread count (checked at 1M Gaussians), so inline_ops is safe
        with torch.no_grad(), inline_ops(gaussians.device):
            g = gaussians.detach()
            return cls(g.means.T.contiguous(), torch.stack(covariance_terms(g)).contiguous())

    @property
    def num(self) -> int:
        return int(self.xyz.shape[1])


@contextmanager
def inline_ops(device: torch.device):
    """Run torch's CPU ops on the calling thread only, restoring the thread count afterwards.

    The blocks are small enough to run inline, but torch's vectorised math library (sqrt, ceil, floor)
    splits anything above 2048 elements over its OpenMP threads, and on a shared machine waiting for a
    descheduled thread cost about 25 ms per op (measured on the 2-core CPU: 10x the whole block).
    """
    threads = torch.get_num_threads()
    if device.type != "cpu" or threads == 1:
        yield
        return
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


def view_blocks(
    terms: GaussianTerms, camera: Camera, index: int, block: int, near_plane: float = NEAR_PLANE
) -> Iterator[VisibilityBlock]:
    """The blocks of one camera (see :func:`iter_visibility`); each block is computed under :func:`inline_ops`.

    On the CPU a block larger than CPU_BLOCK is projected in parts of CPU_BLOCK written into its five arrays (the
    same operations, so the same bits): the core's temporaries stay in the cache (about 12 % less time than whole
    128k blocks), while the caller's passes over the block keep the longer operations.
    """
    cam = ViewConstants.of(camera, near_plane, terms.xyz)
    part = CPU_BLOCK if terms.xyz.device.type == "cpu" else block
    with torch.no_grad():
        for n0 in range(0, terms.num, block):
            cols = slice(n0, min(n0 + block, terms.num))
            with inline_ops(terms.xyz.device):
                if cols.stop - cols.start <= part:
                    fields = _project_block(terms, cols, cam)
                else:
                    fields = torch.empty(5, cols.stop - cols.start, dtype=terms.xyz.dtype, device=terms.xyz.device)
                    for p0 in range(cols.start, cols.stop, part):
                        p = slice(p0, min(p0 + part, cols.stop))
                        _project_block(terms, p, cam, fields[:, p0 - cols.start : p.stop - cols.start])
                u, v, tz, det, radii = fields
            yield VisibilityBlock(index, cols, radii, u, v, tz, det)


def _project_block(terms: GaussianTerms, cols: slice, cam: ViewConstants, out: torch.Tensor | None = None):
    """(u, v, t_z, det Sigma', radii) of the Gaussians ``cols``: new tensors, or written into the rows of ``out``
    [5, n]."""
    rows = (None,) * 5 if out is None else out.unbind(0)
    u, v, tz, a, b, c = _screen_terms_in_place(*terms.xyz[:, cols], terms.sigma[:, cols].unbind(0), cam, rows[:3])
    det = torch.mul(a, c, out=rows[3]) if out is not None else a * c
    det -= b.mul_(b)
    radii = _footprint_radii(u, v, tz, a, c, det, cam, rows[4])
    return u, v, tz, det, radii


def view_centres(
    xyz: torch.Tensor, camera: Camera, block: int, near_plane: float = NEAR_PLANE
) -> Iterator[tuple[slice, torch.Tensor, torch.Tensor, torch.Tensor]]:
    """The projected centres of one camera, block by block: (the block's Gaussians, u, v, t_z), each [n], the first
    operations of :func:`view_blocks`'s core (the same bits), without the footprints; under :func:`inline_ops`.

    Args:
        xyz: [3, N] means, one contiguous row per axis (``GaussianTerms.xyz``). camera: the view.
        block: Gaussians per block. near_plane: the culling depth, scene units.
    """
    cam = ViewConstants.of(camera, near_plane, xyz)
    with torch.no_grad():
        for n0 in range(0, xyz.shape[1], block):
            cols = slice(n0, min(n0 + block, xyz.shape[1]))
            with inline_ops(xyz.device):
                u, v, tz = _centres_in_place(*xyz[:, cols], cam)[:3]
            yield cols, u, v, tz


def iter_visibility(
    gaussians: GaussianSet, cameras: Sequence[Camera], *, near_plane: float = NEAR_PLANE, block: int | None = None
) -> Iterator[VisibilityBlock]:
    """Screen radii and visibility of every (camera, Gaussian) pair, block by block, without rasterising.

    Camera by camera, Gaussians in blocks of ``block``: the working memory is O(block + N) whatever C is.

    Args:
        gaussians: N Gaussians (float32 or float64, any device; no gradient is taken).
        cameras: C cameras (each its own size and intrinsics).
        near_plane: culling depth, scene units.
        block: Gaussians per block (default :func:`default_block` of the Gaussians' device).
    Yields:
        :class:`VisibilityBlock`, on the Gaussians' device.
    """
    size = check_batch(gaussians, cameras, block)
    terms = GaussianTerms.of(gaussians)
    for k, cam in enumerate(cameras):
        yield from view_blocks(terms, cam, k, size, near_plane)


def project_visibility(
    gaussians: GaussianSet, cameras: Sequence[Camera], *, near_plane: float = NEAR_PLANE, block: int | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Screen radii and visibility of N Gaussians in C cameras, equal to the renderer's, without rasterising.

    The result holds C x N entries (5 bytes each: 1 GB for 200 cameras x 1M Gaussians); to reduce over
    the Gaussians on the fly instead (view scores), loop over :func:`iter_visibility`.

    Args:
        gaussians: N Gaussians (float32 or float64, any device; no gradient is taken).
        cameras: C cameras.
        near_plane: culling depth, scene units.
        block: Gaussians per block (bounds the working memory).
    Returns:
        radii [C, N] int32 pixels (``render(gaussians, cameras[c]).radii`` exactly; 0 when culled) and
        visible [C, N] bool (radii > 0), on the Gaussians' device.

    Example:
        >>> cams = [Camera.look_at((0, 0, -2.0), (0, 0, 0), (0, -1, 0), 64, 64, 1.0),
        ...         Camera.look_at((0, 0, 2.0), (0, 0, 5), (0, -1, 0), 64, 64, 1.0)]
        >>> radii, visible = project_visibility(GaussianSet.from_points(torch.zeros(1, 3), scale=0.05), cams)
        >>> radii.tolist(), visible.tolist()
        ([[5], [0]], [[True], [False]])
    """
    size = check_batch(gaussians, cameras, block)
    radii = torch.zeros(len(cameras), gaussians.num, dtype=torch.int32, device=gaussians.device)
    for blk in iter_visibility(gaussians, cameras, near_plane=near_plane, block=size):
        radii[blk.camera, blk.gaussians] = blk.radii.to(torch.int32)
    return radii, radii > 0


def project_visibility_reference(
    gaussians: GaussianSet, cameras: Sequence[Camera], near_plane: float = NEAR_PLANE
) -> tuple[torch.Tensor, torch.Tensor]:
    """One :func:`project_gaussians` per camera: the twin of :func:`project_visibility`, for tests."""
    with torch.no_grad():
        radii = torch.stack([project_gaussians(gaussians.detach(), cam, near_plane).radii for cam in cameras])
    return radii, radii > 0
