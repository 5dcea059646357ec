"""How many Gaussian centres each camera sees (in front of the near plane and inside the image): the check that a
camera sees anything (:func:`projected_counts`), and the counts that come with the view scores (:class:`CentreCounter`,
used by :mod:`nbv.projected_scores` on the blocks it projects anyway).

The centres are projected as the projection core projects them (:func:`recon.projection.view_centres`, in the means'
dtype); the few within round-off of the image border or the near plane (:class:`CentreBand`) take the float64 test,
so the counts equal :func:`projected_counts_reference`'s, the twin, exactly. The public names are also importable
from :mod:`nbv.scores`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch

from nbv.camera_shares import camera_shares
from recon.camera import Camera
from recon.projection import CPU_BLOCK, NEAR_PLANE, inline_ops, view_centres

# Gaussians per block of the threaded CPU path: with the in-place projection core, 64k-128k cost no more per pair
# than the projection's 32k, and longer operations hand the interpreter lock between the threads less often
CPU_SCORING_BLOCK = 1 << 17


@dataclass(frozen=True)
class CentreBand:
    """Where one camera's centre test on the projection core's centres (u, v, t_z in the Gaussians' dtype) is sure to
    give the float64 verdict of :func:`projected_counts_reference` (z > near, 0 <= u < W, 0 <= v < H).

    With S = max_g (|x_g| + |y_g| + |z_g|) + |t|_1 + near (t: the camera's translation), each of t_x, t_y, t_z is
    within err = 8 (u_d + u_64) S of its exact value (u_d: the unit round-off of the dtype; the rotation's entries
    are at most 1), in the core as in the float64 test. A centre with t_z > near + 2 err is in front in both; there
    1 / t_z <= 1 / near, so |u - u_exact| <= k1 + k2 |u - W / 2| with k2 = 2 (err / near + 8 u_d) and
    k1 = 2 (f_x err / near + (err / near + 6 u_d) |c_x - W / 2| + 2 u_d |c_x|) + 4 u_d W (twice the bound, for
    the second-order terms). So |u - W / 2| < lo_u = (W / 2 - k1) / (1 + k2) is inside in both tests, and above
    hi_u = (W / 2 + k1) / (1 - k2) outside in both; the same along v. :func:`_count_centres` counts the sure
    ones and sends the few in between (a fraction of a pixel wide) to the float64 test.

    Attributes:
        mid_u, mid_v: W / 2 and H / 2, pixels. scale_u, scale_v: 1 / lo_u and 1 / lo_v.
        ceiling: max(hi_u / lo_u, hi_v / lo_v): a centre whose larger scaled distance is in [1, ceiling] is
            rechecked. front, behind: near +- 2 err (scene units).
    """

    mid_u: float
    mid_v: float
    scale_u: float
    scale_v: float
    ceiling: float
    front: float
    behind: float

    @classmethod
    def of(cls, camera: Camera, reach: float, dtype: torch.dtype, near: float) -> CentreBand | None:
        """The band of ``camera`` for centres whose |x| + |y| + |z| is at most ``reach``, computed in ``dtype``;
        None when the bounds are not finite or wider than the image (then every centre takes the float64 test)."""
        if not near > 0:
            return None
        unit = torch.finfo(dtype).eps / 2
        t = camera.world_to_camera[:3, 3].to(torch.float64).abs().sum().item()
        err = 8.0 * (unit + 2.0**-53) * (reach + t + near)
        k2 = 2.0 * (err / near + 8.0 * unit)
        bounds = []
        for size, focal, centre in ((camera.width, camera.fx, camera.cx), (camera.height, camera.fy, camera.cy)):
            half = size / 2
            k1 = 2.0 * (focal * err / near + (err / near + 6.0 * unit) * abs(centre - half) + 2.0 * unit * abs(centre))
            k1 += 4.0 * unit * size
            bounds.append(((half - k1) / (1.0 + k2), (half + k1) / (1.0 - k2)))
        (lo_u, hi_u), (lo_v, hi_v) = bounds
        values = (k2, lo_u, hi_u, lo_v, hi_v, err)
        if not all(math.isfinite(x) for x in values) or k2 >= 0.5 or min(lo_u, lo_v) <= 0:
            return None
        ceiling = max(hi_u / lo_u, hi_v / lo_v)
        return cls(camera.width / 2, camera.height / 2, 1.0 / lo_u, 1.0 / lo_v, ceiling, near + 2 * err, near - 2 * err)


def centre_reach(xyz: torch.Tensor) -> float:
    """max_g (|x_g| + |y_g| + |z_g|) of [3, N] means, rounded up (0 for none; inf or NaN when one is not finite)."""
    if xyz.shape[1] == 0:
        return 0.0
    return float(xyz.to(torch.float64).abs().sum(0).max()) * (1.0 + 1e-12)


def _centres_inside(points: torch.Tensor, camera: Camera, near: float) -> torch.Tensor:
    """[n] bool: the float64 centre test, z > near and the projected centre inside the image (0 <= u < W, 0 <= v < H)
    by ``Camera.project`` of [n, 3] float64 ``points``."""
    uv, z = camera.project(points)
    w, h = camera.width, camera.height
    return (z > near) & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)


def _count_centres(xyz, rows: slice, u, v, tz, band: CentreBand, camera: Camera, near: float) -> int:
    """How many of a block's centres (u, v, t_z [n] of the Gaussians ``rows`` of ``xyz`` [3, N]) lie inside the
    view: the sure ones from the band (:class:`CentreBand`), the others by the float64 test."""
    in_front = bool(tz.min() > band.front)  # False: some centre near or behind the near plane (or NaN)
    if in_front and _all_within(u, band.mid_u, band.scale_u) and _all_within(v, band.mid_v, band.scale_v):
        return u.shape[0]  # every centre of the block surely inside (the usual block of an object's orbit)
    s = (u - band.mid_u).abs_().mul_(band.scale_u)
    torch.maximum(s, (v - band.mid_v).abs_().mul_(band.scale_v), out=s)
    if not in_front:  # by t_z first
        unsure = torch.full_like(s, 1.0)
        s = torch.where(tz > band.front, s, torch.where(tz < band.behind, torch.full_like(s, math.inf), unsure))
    sure = int(torch.count_nonzero(s < 1.0))
    if int(torch.count_nonzero(s <= band.ceiling)) == sure:
        return sure
    rest = torch.nonzero((s >= 1.0) & (s <= band.ceiling)).reshape(-1) + rows.start
    points = xyz.index_select(1, rest).T.to(torch.float64)
    return sure + int(_centres_inside(points, camera, near).sum())


def _all_within(centres: torch.Tensor, mid: float, scale: float) -> bool:
    """Whether every centre lies strictly within (mid - 1 / scale, mid + 1 / scale), the sure half-width of a
    :class:`CentreBand` (narrowed by 1e-9 of itself for the float64 rounding of the bounds), from one aminmax."""
    half = (1.0 - 1e-9) / scale
    lo, hi = torch.aminmax(centres)
    return float(lo) > mid - half and float(hi) < mid + half


def _centre_count(xyz, camera: Camera, reach: float, block: int, near: float, at_most: int | None) -> int:
    """Centres of [3, N] means inside ``camera`` (:func:`projected_counts`), block by block; stops once the count
    reaches ``at_most``."""
    band = CentreBand.of(camera, reach, xyz.dtype, near)
    if band is None:
        count = int(_centres_inside(xyz.T.to(torch.float64), camera, near).sum())
        return count if at_most is None else min(count, at_most)
    count = 0
    for rows, u, v, tz in view_centres(xyz, camera, block, near):
        count += _count_centres(xyz, rows, u, v, tz, band, camera, near)
        if at_most is not None and count >= at_most:
            return at_most
    return count


def projected_counts(
    means: torch.Tensor,
    cameras: Sequence,
    near: float = NEAR_PLANE,
    *,
    at_most: int | None = None,
    block: int | None = None,
    threads: int | None = None,
) -> torch.Tensor:
    """How many Gaussian centres each camera sees (in front of the near plane and inside the image).

    A cheap pre-check before any simulation or rendering: a camera with 0 cannot score. The centres are projected
    block by block as the projection core projects them (:func:`recon.projection.view_centres`, in the means'
    dtype), the cameras shared among ``threads`` threads; the few centres within round-off of the image border or
    the near plane (:class:`CentreBand`) take the float64 test, so the counts equal
    :func:`projected_counts_reference`'s exactly.

    Args:
        means: [N, 3] Gaussian centres in the cameras' frame (scene units).
        cameras: C ``recon.camera.Camera``.
        near: near plane distance, scene units.
        at_most: stop counting a camera at this many (None: count them all); ``at_most=1`` asks only whether a
            camera sees any centre, usually from the first block.
        block: centres per block (default: CPU_SCORING_BLOCK, the projection's CPU_BLOCK with ``at_most``).
        threads: CPU threads sharing the cameras (default: torch's thread count).
    Returns:
        [C] int64 (each at most ``at_most`` when given).

    Example:
        >>> cam = Camera.look_at((0, 0, -2.0), (0, 0, 0), (0, -1, 0), 64, 64, 1.0)
        >>> projected_counts(torch.zeros(3, 3), [cam]).tolist()
        [3]
    """
    pts = torch.as_tensor(means).detach().cpu()
    pts = pts if pts.dtype in (torch.float32, torch.float64) else pts.to(torch.float64)
    xyz = pts.reshape(-1, 3).T.contiguous()
    size = (CPU_SCORING_BLOCK if at_most is None else CPU_BLOCK) if block is None else block
    reach = centre_reach(xyz)
    workers = max(1, min(threads or torch.get_num_threads(), len(cameras)))

    def count(ks: range) -> dict[int, int]:
        return {k: _centre_count(xyz, cameras[k], reach, size, near, at_most) for k in ks}

    with inline_ops(xyz.device):
        pairs = xyz.shape[1] * len(cameras) if at_most is None else 0  # a pre-check reads about one block a camera
        parts = camera_shares(count, len(cameras), workers, "centre-counts", pairs)
    counts = {k: c for part in parts for k, c in part.items()}
    return torch.tensor([counts[k] for k in range(len(cameras))], dtype=torch.int64)


def projected_counts_reference(means: torch.Tensor, cameras: Sequence, near: float = NEAR_PLANE) -> torch.Tensor:
    """The twin of :func:`projected_counts`: each camera's float64 test on all the centres at once, for tests."""
    pts = torch.as_tensor(means).detach().to(torch.float64).cpu().reshape(-1, 3)
    return torch.tensor([int(_centres_inside(pts, cam, near).sum()) for cam in cameras], dtype=torch.int64)


class CentreCounter:
    """The centres inside one view, counted from its projected blocks (:func:`_count_centres`; the float64 test on
    all of them when the view has no :class:`CentreBand`)."""

    def __init__(self, xyz: torch.Tensor, camera: Camera, reach: float, near: float = NEAR_PLANE):
        self.xyz, self.camera, self.near = xyz, camera, near
        self.band = CentreBand.of(camera, reach, xyz.dtype, near)
        self.total = 0
        if self.band is None:
            self.total = int(_centres_inside(xyz.T.to(torch.float64), camera, near).sum())

    def add(self, b) -> None:
        """Count the centres of a :class:`recon.projection.VisibilityBlock` of this view."""
        if self.band is not None:
            self.total += _count_centres(self.xyz, b.gaussians, b.u, b.v, b.depths, self.band, self.camera, self.near)
