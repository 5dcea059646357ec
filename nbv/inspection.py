"""What the fluid will see: a Gaussian set's statistics, its simulation frame and its solid (no simulation).

No paper equation is implemented here; the solid is the one of :mod:`nbv.physics.solidify` (paper Sec. 3.2) at the
probes' spacing, and the frame is :mod:`nbv.physics.scene_frame`'s. :func:`inspect_gaussians` gathers the figures
that ``fluidgs inspect`` prints and writes as JSON; :func:`inspection_views` draws three orthographic views
of the Gaussian centres in simulation axes (front: x right, y up; side: z right, y up; top: x right,
-z up), with the solid particles drawn over them, so a person sees whether the object stands upright
and is solid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from nbv.physics import PhysicsConfig
from nbv.physics.plan import RunFrame
from nbv.physics.scene_frame import robust_box

QUANTILES = (0.01, 0.05, 0.25, 0.5, 0.75, 0.95, 0.99)


@dataclass(frozen=True)
class Inspection:
    """The figures of one Gaussian set under one PhysicsConfig.

    Attributes:
        summary: JSON-able dict (``format``, ``count``, ``sh_degree``, ``bbox_min``/``bbox_max`` and
            ``robust_min``/``robust_max`` in scene units, ``up``, ``scale_m_per_unit``, ``solid_particles``, ...).
        means_sim: [G', 3] centres of the kept Gaussians, simulation metres.
        solid: [M, 3] solid particles, simulation metres.
    """

    summary: dict
    means_sim: np.ndarray
    solid: np.ndarray


def _quantiles(values: np.ndarray) -> dict[str, float]:
    q = np.quantile(values, QUANTILES) if len(values) else np.full(len(QUANTILES), np.nan)
    return {f"p{round(100 * k):02d}": float(v) for k, v in zip(QUANTILES, q, strict=True)}


def inspect_gaussians(gaussians, config: PhysicsConfig, file_format: str = "") -> Inspection:
    """Statistics, frame and solid of ``gaussians`` (scene units) under ``config`` (up, scale, crop, tau, r).

    Needs an initialised Taichi runtime (the solid is computed by :func:`nbv.physics.solidify.gaussians_to_solid`).

    Args:
        gaussians: a ``recon.gaussians.GaussianSet``.
        config: the probe settings whose frame and solid are shown.
        file_format: the reader's format name, recorded as ``summary["format"]``.
    Returns:
        :class:`Inspection`.
    Raises:
        ValueError: an empty crop or an empty solid (the solidifier's message), before anything long.
    """
    g = gaussians.detach().to("cpu").check("Gaussians")
    means = g.means.double().numpy()
    opacities = g.opacities.double().numpy()
    sigmas = g.scales.double().numpy()
    lo, hi = robust_box(means, opacities, config.opacity_threshold)
    outside = ~np.all((means >= lo) & (means <= hi), axis=1)
    frame = RunFrame.of(g, config)  # the probe run's frame, crop and solid
    kept, transform = frame.kept, frame.transform
    spacing = 2.0 * config.particle_radius
    solid = frame.solidify()
    means_sim, radii = frame.sim.means, frame.sim.radii
    summary = {
        "format": file_format,
        "count": int(g.num),
        "sh_degree": int(g.sh_degree),
        "bbox_min": means.min(0).tolist(),
        "bbox_max": means.max(0).tolist(),
        "robust_min": lo.tolist(),
        "robust_max": hi.tolist(),
        "outside_robust_box_share": float(outside.mean()),
        "opacity_quantiles": _quantiles(opacities),
        "opacity_at_or_above_tau_share": float((opacities >= config.opacity_threshold).mean()),
        "largest_sigma_quantiles": _quantiles(sigmas.max(1)),
        "smallest_sigma_quantiles": _quantiles(sigmas.min(1)),
        "up": list(transform.up),
        "up_label": transform.up_label,
        "scale_m_per_unit": float(transform.scale),
        "scene_to_sim": transform.matrix.tolist(),
        "crop": None if config.crop is None else (config.crop if isinstance(config.crop, str) else list(config.crop)),
        "kept": int(g.num if kept is None else kept.sum()),
        "particle_radius_m": float(config.particle_radius),
        "spacing_m": spacing,
        "opacity_threshold": float(config.opacity_threshold),
        "solid_particles": int(len(solid.points)),
        "solid_min_m": solid.points.min(0).tolist(),
        "solid_max_m": solid.points.max(0).tolist(),
        "object_extent_m": (np.ptp(means_sim, axis=0)).tolist(),
        "largest_sigma_m_median": float(np.median(radii)),
    }
    return Inspection(summary=summary, means_sim=means_sim, solid=np.asarray(solid.points, np.float64))


# ---- the picture -----------------------------------------------------------------------------------
# (horizontal axis, sign), (vertical axis, sign), title: vertical +1 means "up on the page"
VIEWS = (
    ((0, 1.0), (1, 1.0), "front (x right, y up)"),
    ((2, -1.0), (1, 1.0), "side (-z right, y up)"),
    ((0, 1.0), (2, -1.0), "top (x right, -z up)"),
)
_POINTS_DRAWN = 200_000


def inspection_views(inspection: Inspection, panel: int = 420, seed: int = 0) -> np.ndarray:
    """Three orthographic panels side by side: Gaussian centres (grey) and solid particles (red), sim metres.

    Args:
        inspection: what :func:`inspect_gaussians` returned.
        panel: panel size in pixels (square).
        seed: for the subsample when there are more than 200k centres.
    Returns:
        [panel + 60, 3 panel, 3] uint8 BGR image (simulation up points up in the front and side panels).
    """
    means, solid = inspection.means_sim, inspection.solid
    if len(means) > _POINTS_DRAWN:
        means = means[np.random.default_rng(seed).choice(len(means), _POINTS_DRAWN, replace=False)]
    pts = np.concatenate([means, solid]) if len(solid) else means
    center = 0.5 * (pts.min(0) + pts.max(0))
    half = 0.55 * float(np.ptp(pts, axis=0).max()) or 1.0
    margin = 30
    spacing_px = inspection.summary["spacing_m"] * 0.5 * (panel - 1) / half
    image = np.full((panel + 2 * margin, 3 * panel, 3), 255, np.uint8)
    s = inspection.summary
    for k, ((ha, hs), (va, vs), title) in enumerate(VIEWS):
        x0 = k * panel

        def to_px(p: np.ndarray, ha=ha, hs=hs, va=va, vs=vs, x0=x0) -> np.ndarray:
            u = hs * (p[:, ha] - center[ha]) / half
            v = vs * (p[:, va] - center[va]) / half
            return (
                np.stack([x0 + (0.5 + 0.5 * u) * (panel - 1), margin + (0.5 - 0.5 * v) * (panel - 1)], 1)
                .round()
                .astype(np.int64)
            )

        canvas = image[:, x0 : x0 + panel]
        canvas[margin : margin + panel] = 248
        _scatter(image, to_px(means), (150, 150, 150), alpha=0.25, radius=1)
        if len(solid):
            dot = max(1, int(0.35 * spacing_px))
            _scatter(image, to_px(solid), (40, 40, 220), alpha=0.45, radius=dot)
        cv2.putText(image, title, (x0 + 8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
        cv2.rectangle(image, (x0, margin), (x0 + panel - 1, margin + panel - 1), (200, 200, 200), 1)
    foot = (
        f"{s['count']:,} Gaussians ({s['format'] or 'Gaussians'}), up {s['up_label']}, "
        f"{s['scale_m_per_unit']:.4g} m/unit; {s['solid_particles']:,} solid particles (red) at "
        f"{s['spacing_m']:.3g} m; grey: centres"
    )
    cv2.putText(image, foot, (8, panel + 2 * margin - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    bar = max(1, int(round((panel - 1) * 0.5 / half)))  # 1 m in pixels
    x1 = 3 * panel - 12
    cv2.line(image, (x1 - bar, panel + 2 * margin - 14), (x1, panel + 2 * margin - 14), (0, 0, 0), 2)
    cv2.putText(
        image,
        "1 m",
        (x1 - bar - 34, panel + 2 * margin - 10),
        cv2.FONT_HERSHEY_SIMPLEX,
        0.45,
        (0, 0, 0),
        1,
        cv2.LINE_AA,
    )
    return image


def _scatter(image: np.ndarray, px: np.ndarray, color: tuple[int, int, int], alpha: float, radius: int) -> None:
    """Blend ``color`` into ``image`` over discs of ``radius`` pixels at ``px`` [N, 2] (x, y), once per pixel."""
    h, w = image.shape[:2]
    r = np.arange(-radius + 1, radius) if radius > 1 else np.arange(0, 2)
    dy, dx = np.meshgrid(r, r, indexing="ij")
    disc = (dy**2 + dx**2 <= max(radius - 1, 1) ** 2 + 1) if radius > 1 else np.ones_like(dy, bool)
    cells = px[:, None, :] + np.stack([dx[disc], dy[disc]], 1)[None]
    cells = cells.reshape(-1, 2)
    ok = (cells[:, 0] >= 0) & (cells[:, 0] < w) & (cells[:, 1] >= 0) & (cells[:, 1] < h)
    flat = np.unique(cells[ok, 1] * w + cells[ok, 0])
    yy, xx = np.divmod(flat, w)
    image[yy, xx] = ((1 - alpha) * image[yy, xx] + alpha * np.asarray(color)).astype(np.uint8)


def describe(summary: dict) -> list[str]:
    """The lines ``fluidgs inspect`` prints."""

    def vec(v) -> str:
        return "(" + ", ".join(f"{c:.4g}" for c in v) + ")"

    q = summary["opacity_quantiles"]
    sq = summary["largest_sigma_quantiles"]
    nq = summary["smallest_sigma_quantiles"]
    lines = [
        f"format: {summary['format']}",
        f"Gaussians: {summary['count']:,}, SH degree {summary['sh_degree']}",
        f"bounding box (scene units): {vec(summary['bbox_min'])} - {vec(summary['bbox_max'])}",
        f"robust box (opacity-weighted 0.5-99.5 %, opacity >= tau): {vec(summary['robust_min'])} - "
        f"{vec(summary['robust_max'])}",
        f"outside the robust box: {100 * summary['outside_robust_box_share']:.2f} % of the Gaussians",
        "opacity quantiles 1/5/25/50/75/95/99 %: " + ", ".join(f"{v:.3g}" for v in q.values()),
        f"opacity >= tau = {summary['opacity_threshold']}: {100 * summary['opacity_at_or_above_tau_share']:.1f} %",
        "largest sigma (scene units) quantiles: " + ", ".join(f"{v:.3g}" for v in sq.values()),
        "smallest sigma (scene units) quantiles: " + ", ".join(f"{v:.3g}" for v in nq.values()),
        f"scene -> simulation: up {summary['up_label']} -> +y, {summary['scale_m_per_unit']:.6g} m per unit; "
        "matrix rows " + "; ".join(vec(r[:3]) for r in summary["scene_to_sim"][:3]),
    ]
    if summary["crop"] is not None:
        lines.append(f"crop {summary['crop']}: kept {summary['kept']:,} of {summary['count']:,} Gaussians")
    ext = summary["object_extent_m"]
    lines += [
        f"object extent (sim m, x/y/z): {ext[0]:.3g} / {ext[1]:.3g} / {ext[2]:.3g}",
        f"solid: {summary['solid_particles']:,} particles at spacing {summary['spacing_m']:.3g} m "
        f"(r = {summary['particle_radius_m']:.3g} m), {vec(summary['solid_min_m'])} - "
        f"{vec(summary['solid_max_m'])} m",
    ]
    if not math.isfinite(summary["largest_sigma_m_median"]):
        lines.append("warning: non-finite Gaussian scales")
    return lines
