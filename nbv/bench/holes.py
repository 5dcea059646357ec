"""A hole punched in a Gaussian set, and what it does to the solid and to D_g at its rim.

The paper's premise (Sec. 3.3): where the reconstruction is wrong, the probes' flow is disturbed, so D_g is high
there and the views that see it score high. The check on a real capture punches a hole in its surface and
compares the rim's D_g with the intact capture's.

Geometry, in simulation metres (Y-up) around a surface point p with unit normal n: a centre x has the axial
coordinate t = (x - p) . n and the radial distance r = |(x - p) - t n| from the hole's axis.

- The *hole* removes the Gaussians whose centres lie in the cylinder r < R, |t| < depth (depth = inf: a tunnel
  through the whole object).
- The *rim* is the Gaussians left around its edge: R <= r < R + band, |t| < depth (the same slab); when more
  than the cylinder was removed (a see-through hole), the band starts at the nearest centre left.
- The *axis opacity* is what a 3DGS render along the axis would show through the hole: every Gaussian enters a
  ray at its peak on the ray (as rasterisation composites it), 1 - prod_g (1 - o_g max_s exp(-d_g(p + s n)^2 / 2)),
  s over the ray's segment.

The rim ratio of a probe is the rim's mean D_g^(IC) on the holed set over the same Gaussians' mean on the intact set
(matched by index); the max-combined ratio does the same with D_g = max over the probes (paper Eq. 3).

:func:`locate_hole` places the hole from a point or a side of the object, :func:`measure_shift` measures it at one
lattice shift, and :func:`shift_lines` and :func:`shifts_line` report the figures as text.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np
import torch

from nbv.physics.forces import flow_axis
from nbv.physics.plan import ProbeRunContext, RunFrame
from nbv.physics.run import simulate_gaussians, simulate_solid
from nbv.physics.scene_frame import gaussian_arrays_in_sim, inverse_covariances_in_sim
from nbv.physics.solidify import MAX_ALPHA, SolidLattice, gaussians_to_solid


@dataclass(frozen=True)
class Hole:
    """A cylindrical hole through a surface.

    Attributes:
        point: (3,) simulation metres, a point of the surface on the hole's axis.
        normal: (3,) unit outward normal, the hole's axis.
        radius: R, m (an 11 cm hole has R = 0.055).
        depth: half-length of the cylinder along the normal, m; math.inf cuts through the whole object.
        band: width of the rim annulus beyond R, m.
    """

    point: tuple[float, float, float]
    normal: tuple[float, float, float]
    radius: float = 0.055
    depth: float = 0.06
    band: float = 0.055

    def __post_init__(self) -> None:
        p = np.asarray(self.point, np.float64).reshape(-1)
        n = np.asarray(self.normal, np.float64).reshape(-1)
        if p.shape != (3,) or not np.isfinite(p).all():
            raise ValueError(f"Hole.point must be 3 finite coordinates (sim metres), got {self.point!r}")
        if n.shape != (3,) or not np.isfinite(n).all() or np.linalg.norm(n) < 1e-12:
            raise ValueError(f"Hole.normal must be a finite non-zero 3-vector, got {self.normal!r}")
        for name in ("radius", "band"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"Hole.{name} must be a finite length > 0 m, got {v!r}")
        if not (isinstance(self.depth, (int, float)) and self.depth > 0):
            raise ValueError(f"Hole.depth must be a length > 0 m (inf: through the object), got {self.depth!r}")
        object.__setattr__(self, "point", tuple(p.tolist()))
        object.__setattr__(self, "normal", tuple((n / np.linalg.norm(n)).tolist()))

    def describe(self) -> str:
        """The hole in words: its point and normal (to the millimetre), radius, half-depth and rim band."""
        return (
            f"hole at {np.round(self.point, 3).tolist()} m, normal {np.round(self.normal, 3).tolist()}, radius "
            f"{self.radius} m, half-depth {self.depth} m, rim band {self.band} m"
        )

    def coordinates(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """[N] axial t and radial r (m) of ``points`` [N, 3] m, about the hole's axis."""
        d = np.asarray(points, np.float64).reshape(-1, 3) - np.asarray(self.point)
        n = np.asarray(self.normal)
        t = d @ n
        return t, np.linalg.norm(d - t[:, None] * n, axis=1)

    def removed(self, means: np.ndarray) -> np.ndarray:
        """[N] bool, the Gaussians whose centres (``means`` [N, 3] m) lie in the hole's cylinder."""
        t, r = self.coordinates(means)
        return (r < self.radius) & (np.abs(t) < self.depth)

    def rim(self, means: np.ndarray, kept: np.ndarray | None = None) -> np.ndarray:
        """[N] bool, the Gaussians around the hole's edge, in the same slab |t| < depth.

        The edge is at R, or, given ``kept`` ([N] bool, the Gaussians left by the hole), at the smallest radius of a
        kept centre in the slab when that is larger (a see-through hole removes more than the cylinder). The rim is
        the centres within ``band`` beyond the edge (kept ones only, when ``kept`` is given).
        """
        t, r = self.coordinates(means)
        slab = np.abs(t) < self.depth
        edge = self.radius
        if kept is not None:
            kept = np.asarray(kept, bool)
            left = slab & kept & (r >= self.radius)
            edge = max(edge, float(r[left].min())) if left.any() else edge
            slab &= kept
        return slab & (r >= edge) & (r < edge + self.band)


def surface_point(
    means: np.ndarray,
    opacities: np.ndarray,
    side: np.ndarray,
    height: float,
    lateral: float = 0.0,
    tube: float = 0.04,
    shell: float = 0.05,
) -> np.ndarray:
    """The outer surface of the object on ``side`` at simulation height ``height``.

    The centres (o_g >= 0.05) within ``tube`` of the horizontal line through (lateral offset, height) along ``side``
    are taken; of those, the ones within ``shell`` of the outermost along ``side`` form the surface, and their median
    is the point.

    Args:
        means: [N, 3] m. opacities: [N]. side: (3,) horizontal direction (its y is ignored), e.g. (1, 0, 0).
        height: y, m. lateral: offset along the horizontal direction perpendicular to ``side``, m.
    Returns:
        (3,) m.
    Raises:
        ValueError: no centre lies in the tube.
    """
    u = np.asarray(side, np.float64).copy()
    u[1] = 0.0
    if np.linalg.norm(u) < 1e-12:
        raise ValueError(f"the hole's side must be horizontal (x and/or z), got {tuple(side)}")
    u /= np.linalg.norm(u)
    w = np.cross(u, (0.0, 1.0, 0.0))
    m = np.asarray(means, np.float64)
    along, across = m @ u, m @ w
    sel = (np.abs(m[:, 1] - height) < tube) & (np.abs(across - lateral) < tube) & (np.asarray(opacities) >= 0.05)
    if not sel.any():
        raise ValueError(
            f"no Gaussian centre within {tube} m of the line at height {height} m, lateral {lateral} m "
            f"along {u.round(3).tolist()}: choose a height inside the object (sim y "
            f"{m[:, 1].min():.2f} - {m[:, 1].max():.2f} m)"
        )
    outer = sel & (along >= along[sel].max() - shell)
    return np.median(m[outer], axis=0)


def surface_normal(means: np.ndarray, point: np.ndarray, outward: np.ndarray, radius: float = 0.08) -> np.ndarray:
    """(3,) unit normal of the centres within ``radius`` of ``point`` (least principal axis), facing ``outward``.

    Raises:
        ValueError: fewer than 3 centres lie within the radius.
    """
    m = np.asarray(means, np.float64)
    near = m[np.linalg.norm(m - np.asarray(point), axis=1) < radius]
    if len(near) < 3:
        raise ValueError(
            f"fewer than 3 Gaussian centres within {radius} m of {np.round(point, 3).tolist()}: "
            f"give the hole's normal explicitly"
        )
    q = near - near.mean(0)
    _, vecs = np.linalg.eigh(q.T @ q)
    n = vecs[:, 0]
    return n if n @ np.asarray(outward, np.float64) >= 0 else -n


def _plane_axes(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors spanning the plane perpendicular to ``normal`` (a right-handed frame with it)."""
    n = np.asarray(normal, np.float64)
    a = np.cross(n, (0.0, 1.0, 0.0)) if abs(n[1]) < 0.9 else np.cross(n, (1.0, 0.0, 0.0))
    a /= np.linalg.norm(a)
    return a, np.cross(n, a)


def disc_offsets(hole: Hole, step: float) -> np.ndarray:
    """[K, 2] in-plane offsets (m) of the rays through the hole's disc: a square grid of pitch ``step``, r < R."""
    k = np.arange(-math.floor(hole.radius / step), math.floor(hole.radius / step) + 1) * step
    a, b = (m.ravel() for m in np.meshgrid(k, k, indexing="ij"))
    inside = a * a + b * b < hole.radius**2
    return np.stack([a[inside], b[inside]], 1)


def ray_peaks(
    hole: Hole, means: np.ndarray, inv_covs: np.ndarray, opacities: np.ndarray, offset: tuple[float, float] = (0.0, 0.0)
) -> np.ndarray:
    """[N] each Gaussian's peak opacity a_g = o_g max_s exp(-d_g(x(s))^2 / 2) on a ray parallel to the hole's axis.

    The ray is x(s) = p + offset + s n, s in the hole's slab, +-depth (an infinite depth: the whole line). d_g^2 is a
    convex quadratic in s, so the peak is exact (clamped to 1 - 1e-6 as the solid's tests).

    Args:
        hole: the hole (its axis). means: [N, 3] m. inv_covs: [N, 3, 3] 1/m^2. opacities: [N].
        offset: the ray's offset from the axis, along the two in-plane axes of :func:`_plane_axes`, m.
    """
    n = np.asarray(hole.normal)
    a, b = _plane_axes(n)
    origin = np.asarray(hole.point) + offset[0] * a + offset[1] * b
    inv = np.asarray(inv_covs, np.float64)
    d = origin - np.asarray(means, np.float64)
    an = inv @ n  # [N, 3]: A n, with n^T A n > 0
    s = np.clip(-np.einsum("ni,ni->n", d, an) / (an @ n), -hole.depth, hole.depth)
    y = d + s[:, None] * n
    return np.minimum(
        np.asarray(opacities, np.float64) * np.exp(-0.5 * np.einsum("ni,nij,nj->n", y, inv, y)), MAX_ALPHA
    )


def axis_opacity(
    hole: Hole, means: np.ndarray, inv_covs: np.ndarray, opacities: np.ndarray, offset: tuple[float, float] = (0.0, 0.0)
) -> tuple[float, float]:
    """What a 3DGS render along a ray parallel to the hole's axis shows (:func:`ray_peaks`).

    Returns:
        (combined opacity 1 - prod_g (1 - a_g), the largest single a_g).
    """
    alpha = ray_peaks(hole, means, inv_covs, opacities, offset)
    if not len(alpha):
        return 0.0, 0.0
    return float(1.0 - np.exp(np.log1p(-alpha).sum())), float(alpha.max())


def open_fraction(
    hole: Hole, means: np.ndarray, inv_covs: np.ndarray, opacities: np.ndarray, tau: float, step: float = 0.01
) -> tuple[float, float]:
    """The fraction of the disc's rays (:func:`disc_offsets`) a render sees through: (combined opacity < tau, and
    no single Gaussian reaching tau, the per-Gaussian test of the hole premise)."""
    rays = [axis_opacity(hole, means, inv_covs, opacities, tuple(o)) for o in disc_offsets(hole, step)]
    c, single = np.array(rays).T
    return float((c < tau).mean()), float((single < tau).mean())


def covering(
    hole: Hole, means: np.ndarray, inv_covs: np.ndarray, opacities: np.ndarray, eps: float, step: float = 0.005
) -> np.ndarray:
    """[N] bool, the Gaussians whose peak on some ray through the disc exceeds ``eps`` (a see-through hole also
    removes these: its footprint crosses the disc)."""
    out = np.zeros(len(means), dtype=bool)
    for o in disc_offsets(hole, step):
        out |= ray_peaks(hole, means, inv_covs, opacities, tuple(o)) > eps
    return out


def rim_ratios(intact: np.ndarray, holed: np.ndarray, kept: np.ndarray, rim: np.ndarray) -> dict[str, float]:
    """The rim's mean D_g on the holed set over the intact set, per probe and max-combined.

    Args:
        intact: [P, G] D_g^(IC) of the intact set. holed: [P, G'] of the holed set (its rows the kept Gaussians).
        kept: [G'] int, the intact index of each holed row. rim: [G] bool, the rim Gaussians (intact indices).
    Returns:
        ``probe k`` -> ratio for each row k, and ``max`` (D_g = max over the probes); nan where the intact rim reads 0.
    Raises:
        ValueError: the shapes do not match.
    """
    intact, holed = np.atleast_2d(intact), np.atleast_2d(holed)
    kept, rim = np.asarray(kept, np.int64), np.asarray(rim, bool)
    if intact.shape[0] != holed.shape[0] or holed.shape[1] != len(kept) or intact.shape[1] != len(rim):
        raise ValueError(
            f"rim_ratios: intact {intact.shape}, holed {holed.shape}, kept {kept.shape} and rim "
            f"{rim.shape} do not match (holed rows are the kept Gaussians of the intact set)"
        )
    rows = rim[kept]  # holed rows on the rim
    if not rows.any():
        raise ValueError("rim_ratios: no rim Gaussian is left in the holed set; widen the rim band")
    mine = kept[rows]

    def ratio(a: np.ndarray, b: np.ndarray) -> float:
        base = float(a[mine].mean())
        return float(b[rows].mean()) / base if base > 0 else float("nan")

    out = {f"probe {k}": ratio(intact[k], holed[k]) for k in range(intact.shape[0])}
    out["max"] = ratio(intact.max(0), holed.max(0))
    return out


def cut_cylinder(solid: SolidLattice, hole: Hole) -> SolidLattice:
    """``solid`` without the lattice points inside the hole's cylinder (r < R, |t| < depth): an ideal hole at lattice
    resolution, whatever the Gaussians around it (``fluidgs bench hole --ideal``, a measurement of what D_g can resolve;
    no capture's solid is made this way).

    Args:
        solid: a :class:`nbv.physics.solidify.SolidLattice`. hole: the :class:`Hole`, in the solid's frame
            (simulation metres).
    Returns:
        the lattice with those points removed from ``points`` and ``occupancy``; ``counts["ideal_cut"]`` = how many,
        and ``counts["total"]`` the points left.
    """
    cut = hole.removed(solid.points)
    occupancy = solid.occupancy.copy()
    if cut.any():
        ijk = np.rint((solid.points[cut] - solid.lattice_min) / solid.spacing).astype(np.int64)
        occupancy[ijk[:, 0], ijk[:, 1], ijk[:, 2]] = False
    counts = {**solid.counts, "ideal_cut": int(cut.sum()), "total": int((~cut).sum())}
    return replace(solid, points=solid.points[~cut], occupancy=occupancy, counts=counts)


def _shifted(gaussians, transform, delta_sim: np.ndarray):
    """The set moved by ``delta_sim`` [3] simulation metres (its means only)."""
    d = torch.as_tensor(transform.to_scene(delta_sim[None])[0], dtype=gaussians.means.dtype)
    return replace(gaussians, means=gaussians.means + d)


def head_on_probe(directions, normal) -> str:
    """The probe whose flow runs most against the hole's outward normal (the fluid meets the hole head-on)."""
    return min(directions, key=lambda d: float(flow_axis(d) @ np.asarray(normal)))


def lattice_keys(points: np.ndarray, spacing: float) -> set[tuple[int, int, int]]:
    """The lattice sites of ``points`` [N, 3] (m) on a lattice of ``spacing`` m, as integer (i, j, k) keys."""
    return {tuple(k) for k in np.round(np.asarray(points) / spacing).astype(np.int64).tolist()}


def probe_figures(intact, holed, kept: np.ndarray, rim: np.ndarray, normal) -> dict:
    """Per probe and max-combined: the rim's mean D_g on both sets, the ratio, the fraction of rim Gaussians reached.

    Args:
        intact, holed: the two ``PhysicsResult``. kept: [G'] intact index of each holed row. rim: [G] bool (intact
            indices). normal: the hole's axis (for the head-on probe).
    """
    ratios = rim_ratios(intact.per_probe, holed.per_probe, kept, rim)
    rows = rim[kept]
    probes = {
        d: {
            "intact": float(intact.per_probe[k][rim].mean()),
            "holed": float(holed.per_probe[k][rows].mean()),
            "ratio": ratios[f"probe {k}"],
            "reached_intact": float((intact.per_probe_counts[k][rim] > 0).mean()),
            "reached_holed": float((holed.per_probe_counts[k][rows] > 0).mean()),
            "leaked_holed": int(holed.leaks[d].final),
        }
        for k, d in enumerate(intact.directions)
    }
    return {
        "probes": probes,
        "head_on": head_on_probe(intact.directions, normal),
        "max_intact": float(intact.divergence[rim].mean()),
        "max_holed": float(holed.divergence[rows].mean()),
        "max_ratio": ratios["max"],
        "dbar_intact": float(intact.dbar),
        "dbar_holed": float(holed.dbar),
    }


def simulate_with_hole(gaussians, cfg, hole: Hole | None = None):
    """:func:`nbv.physics.simulate_gaussians` of ``gaussians``, with ``hole``'s lattice points cut out of their solid
    before the probes (:func:`cut_cylinder`; None: their own solid), without progress bars."""
    if hole is None:
        return simulate_gaussians(gaussians, cfg, progress=False)
    frame = RunFrame.of(gaussians, cfg)
    return simulate_solid(ProbeRunContext(frame, progress=False), cut_cylinder(frame.solidify(), hole))


def measure_shift(
    gaussians,
    cfg,
    transform,
    hole,
    shift: float,
    solid_only: bool,
    see_through: float | None = None,
    ideal: bool = False,
) -> dict:
    """One lattice shift: the solids of the intact and the holed set, then (unless ``solid_only``) the probes.

    Args:
        gaussians: the intact ``GaussianSet`` (scene frame). cfg: the ``PhysicsConfig`` (its ``scale`` fixed to
            ``transform.scale``, so both sets share it). transform: the intact set's ``SceneTransform``. hole: the
            :class:`Hole` in the unshifted simulation frame. shift: fraction of the spacing 2 r the whole capture
            moves along x, y and z. see_through: also remove the Gaussians covering the disc above this opacity.
            ideal: also cut the cylinder's lattice points out of the holed set's solid (:func:`cut_cylinder`).

    Returns:
        the figures of ``fluidgs bench hole`` for this shift (counts, axis opacities, solid points, seconds, and
        without ``solid_only`` those of :func:`probe_figures`).
    """
    spacing = 2.0 * cfg.particle_radius
    delta = np.full(3, shift * spacing)
    moved = _shifted(gaussians, transform, delta) if shift else gaussians
    h = replace(hole, point=tuple(np.asarray(hole.point) + delta))
    means, _, opacities, _ = gaussian_arrays_in_sim(moved, transform)
    inv = inverse_covariances_in_sim(moved, transform)
    removed = h.removed(means)
    if see_through is not None:
        removed |= covering(h, means, inv, opacities, see_through)
    kept = np.nonzero(~removed)[0]
    holed = moved.subset(torch.from_numpy(kept))
    rim = h.rim(means, ~removed)
    tau = cfg.opacity_threshold
    out = {
        "shift": shift,
        "ideal": ideal,
        "gaussians_removed": int(removed.sum()),
        "rim_gaussians": int(rim.sum()),
        "axis_opacity_intact": axis_opacity(h, means, inv, opacities),
        "axis_opacity_holed": axis_opacity(h, means[kept], inv[kept], opacities[kept]),
        "open_fraction_holed": open_fraction(h, means[kept], inv[kept], opacities[kept], tau),
    }
    t0 = time.perf_counter()
    if solid_only:
        scfg = cfg.solidify_config()
        intact_solid, holed_solid = (gaussians_to_solid(s, scfg, transform) for s in (moved, holed))
        solids = [intact_solid.points, (cut_cylinder(holed_solid, h) if ideal else holed_solid).points]
    else:
        res = [simulate_gaussians(moved, cfg, progress=False), simulate_with_hole(holed, cfg, h if ideal else None)]
        solids = [r.solid for r in res]
    a, b = (lattice_keys(s, spacing) for s in solids)
    out.update(
        solid_intact=len(a),
        solid_holed=len(b),
        solid_removed=len(a - b),
        solid_added=len(b - a),
        seconds=time.perf_counter() - t0,
    )
    if not solid_only:
        out.update(probe_figures(res[0], res[1], kept, rim, h.normal))
    return out


def locate_hole(
    means: np.ndarray,
    opacities: np.ndarray,
    *,
    point=None,
    side=(1.0, 0.0, 0.0),
    height: float | None = None,
    lateral: float = 0.0,
    normal=None,
    radius: float = 0.055,
    depth: float = 0.06,
    band: float = 0.055,
) -> Hole:
    """The :class:`Hole` at ``point`` (3,) m, or, without it, at the surface point on ``side`` (the outward unit axis)
    of the object at ``height`` (default: the centres' median y) and ``lateral`` m across the side
    (:func:`surface_point`); along ``normal``, or the surface normal of the centres around the point, facing out
    (:func:`surface_normal`). ``means`` [N, 3] m and ``opacities`` [N] are the set's, in the simulation frame."""
    if point is not None:
        point = np.asarray(point)
        outward = point - np.median(means, axis=0)
    else:
        height = height if height is not None else float(np.median(means[:, 1]))
        outward = np.asarray(side)
        point = surface_point(means, opacities, outward, height, lateral)
    normal = np.asarray(normal) if normal is not None else surface_normal(means, point, outward)
    return Hole(tuple(point), tuple(normal), radius=radius, depth=depth, band=band)


def shift_lines(r: dict) -> list[str]:
    """The report of one :func:`measure_shift`: solids and axis opacity, then per probe (``*`` the head-on one) and
    max-combined the rim's D_g intact -> holed."""
    ai, ah = r["axis_opacity_intact"], r["axis_opacity_holed"]
    lines = [
        f"shift {r['shift']:g} spacing: {'ideal hole, ' if r.get('ideal') else ''}{r['gaussians_removed']} "
        f"Gaussians removed, rim {r['rim_gaussians']}; solid "
        f"{r['solid_intact']} -> {r['solid_holed']} ({r['solid_removed']} removed, {r['solid_added']} added); axis "
        f"opacity {ai[0]:.2f} -> {ah[0]:.2f} (largest single Gaussian {ai[1]:.2f} -> {ah[1]:.2f}); open to a "
        f"render: {100 * r['open_fraction_holed'][0]:.0f} % of the disc (per Gaussian "
        f"{100 * r['open_fraction_holed'][1]:.0f} %); {r['seconds']:.0f} s"
    ]
    for d, p in r.get("probes", {}).items():
        label = d + ("*" if d == r["head_on"] else "")
        lines.append(
            f"  {label:>4}: rim D_g {p['intact']:.4g} -> {p['holed']:.4g} 1/s  x{p['ratio']:.3f}  (reached "
            f"{p['reached_intact']:.2f} -> {p['reached_holed']:.2f}, leaked {p['leaked_holed']})"
        )
    if "max_ratio" in r:
        lines.append(
            f"  max: rim D_g {r['max_intact']:.4g} -> {r['max_holed']:.4g} 1/s  x{r['max_ratio']:.3f}; D-bar "
            f"{r['dbar_intact']:.4g} -> {r['dbar_holed']:.4g} (x{r['dbar_holed'] / r['dbar_intact']:.3f})"
        )
    return lines


def shifts_line(results: list[dict]) -> str:
    """The spread of the rim ratio over several shifts with probes: max-combined and the head-on probe's."""
    ratios = np.array([r["max_ratio"] for r in results])
    head = np.array([r["probes"][r["head_on"]]["ratio"] for r in results])
    return (
        f"rim ratio over {len(results)} shifts: max-combined {ratios.min():.3f} - {ratios.max():.3f}, head-on "
        f"probe ({results[0]['head_on']}) {head.min():.3f} - {head.max():.3f}"
    )
