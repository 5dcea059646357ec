"""How far view scores from the projection alone agree with scores from full renders (``fluidgs bench views``).

S(T) (paper Eq. 4-5) needs only the screen radii R_g and the visibility of each Gaussian, which
:func:`nbv.scores.projected_view_scores` computes without rendering. :func:`compare_with_renders` renders every
candidate in full (what scoring did before), scores it both ways (:func:`nbv.scores.view_scores` on the renders) and
reports the largest relative score difference, the Spearman rank correlation and whether the two orders are
identical. With ``occlusion`` it also compares the coarse depth buffer (:class:`nbv.scores.DepthBuffer`) with the
render-based depth test (:func:`nbv.scores.unoccluded`): the share of visible (view, Gaussian) pairs with the same
verdict, and the Spearman correlation of the two S(T).

The per-Gaussian metric D_g (1/s) comes from a RESULT.h5 of the Gaussians (:func:`load_divergence`), or from a seeded
log-normal stand-in (:func:`stand_in_divergence`): the check is about radii and visibility, not physics.

:func:`time_projected_scores` times the projection on a densified set; :func:`ranking_lines` and :func:`timing_lines`
report both as text, the timing against its targets (200 cameras x 1M Gaussians on a 2-core CPU, no PNGs:
``TARGET_S`` with frustum culling, ``TARGET_DEPTH_TEST_S`` with the coarse depth test).
"""

from __future__ import annotations

import resource
from pathlib import Path

import numpy as np
import torch

from nbv.bench import timed
from nbv.bench.dense_sets import jittered_to_count
from nbv.orbit import Orbit, orbit_cameras
from nbv.physics import check_result_matches, load_result
from nbv.physics.config import PhysicsConfig
from nbv.ranking import spearman
from nbv.scores import (
    DepthBuffer,
    coarse_unoccluded,
    projected_view_scores,
    projected_view_scores_reference,
    rank,
    unoccluded,
    view_scores,
)
from recon.projection import project_visibility
from recon.render import render

# targets for 200 cameras x 1M Gaussians, no PNGs, on a 2-core CPU: frustum culling, and the coarse depth test
TARGET_S = 5.0
TARGET_DEPTH_TEST_S = 15.0
TARGET_PAIRS = 200 * 1_000_000


def stand_in_divergence(n: int, seed: int) -> np.ndarray:
    """[n] a seeded log-normal per-Gaussian metric (1/s; mu = 0, sigma = 1) for when no RESULT.h5 is given."""
    return np.random.default_rng(seed).lognormal(0.0, 1.0, n)


def load_divergence(path: Path | None, gaussians, seed: int) -> tuple[np.ndarray, str]:
    """([N] D_g in 1/s, description): the max over probes of the RESULT.h5 at ``path`` (checked to belong to
    ``gaussians``), else :func:`stand_in_divergence`."""
    if path is None:
        return stand_in_divergence(gaussians.num, seed), f"seeded log-normal stand-in (seed {seed})"
    result = load_result(path)
    check_result_matches(result, gaussians.num, path)
    return np.asarray(result.divergence, np.float64), f"D_g (max over probes) of {path}"


def _occlusion_agreement(g, cams, renders, metric: torch.Tensor) -> dict:
    """The coarse depth buffer against the render-based depth test (see the module docstring)."""
    reach = 3.0 * g.max_radii().double().cpu()
    by_render = torch.stack([unoccluded(g.means, reach, c, o) for c, o in zip(cams, renders, strict=True)])
    coarse = coarse_unoccluded(g, cams, DepthBuffer()).cpu()
    visible = torch.stack([o.visible.cpu() for o in renders])
    s_render = view_scores(metric, renders, visible=by_render)
    s_coarse = projected_view_scores(metric, g, cams, depth_buffer=DepthBuffer()).scores
    top = set(rank(s_render)[:5].tolist())
    return {
        "verdict_agreement": float((coarse == by_render)[visible].double().mean()),
        "hidden_render": float((visible & ~by_render).sum() / visible.sum()),
        "hidden_coarse": float((visible & ~coarse).sum() / visible.sum()),
        "spearman": spearman(s_coarse, s_render),
        "same_best": int(rank(s_coarse)[0]) == int(rank(s_render)[0]),
        "top5_overlap": len(top & set(rank(s_coarse)[:5].tolist())),
    }


def compare_with_renders(gaussians, cams, d: np.ndarray, occlusion: bool, device) -> dict:
    """Score the candidates from full renders and from the projection, and compare.

    Args:
        gaussians: the GaussianSet (N). cams: the candidate cameras (C). d: [N] D_g, 1/s.
        occlusion: also compare the coarse depth buffer with the render-based depth test. device: torch device.
    Returns:
        views, render_s and projection_s (wall seconds), radii_equal (the projection's radii equal the renderer's in
        every view), max_relative_difference, spearman, identical_order, order (best first); with ``occlusion`` an
        "occlusion" dict: verdict_agreement, hidden_render, hidden_coarse (shares of the visible pairs), spearman,
        same_best, top5_overlap.
    """
    metric = torch.from_numpy(d)
    g = gaussians.detach().to(device)
    with torch.no_grad():
        renders, t_render, _ = timed(lambda: [render(g, c, 1.0) for c in cams])
    full = view_scores(metric, renders)
    scored, t_proj, _ = timed(projected_view_scores, metric, g, cams)
    fast = scored.scores
    radii = project_visibility(g, cams)[0].cpu()
    radii_equal = all(torch.equal(o.radii.cpu(), r) for o, r in zip(renders, radii, strict=True))
    out = {
        "views": len(cams),
        "render_s": t_render,
        "projection_s": t_proj,
        "radii_equal": radii_equal,
        "max_relative_difference": largest_relative_difference(fast, full),
        "spearman": spearman(fast, full),
        "identical_order": rank(fast).tolist() == rank(full).tolist(),
        "order": rank(fast).tolist(),
    }
    if occlusion:
        out["occlusion"] = _occlusion_agreement(g, cams, renders, metric)
    return out


def largest_relative_difference(got: torch.Tensor, expected: torch.Tensor) -> float:
    """max_c |got_c - expected_c| / |expected_c| of two [C] score vectors (0 / 0 counts as 0)."""
    diff = (got - expected).abs()
    return float(torch.where(diff > 0, diff / expected.abs().clamp_min(torch.finfo(torch.float64).tiny), 0.0).max())


def time_projected_scores(
    gaussians,
    d: np.ndarray,
    count: int,
    views: int,
    width: int,
    seed: int,
    occlusion: bool,
    device,
    *,
    threads: int | None = None,
    reference_views: int = 0,
) -> dict:
    """Time :func:`nbv.scores.projected_view_scores` on ``gaussians`` densified to ``count`` (``fluidgs bench views``).

    The set is densified by jittered copies (:func:`nbv.bench.dense_sets.jittered_to_count`), its metric is ``d`` [G]
    repeated, and it is scored from an orbit of ``views`` cameras around it (:func:`nbv.orbit.orbit_cameras`: the
    candidates of ``--cameras orbit:N``, ``width`` x 3/4 ``width`` pixels, no PNGs). With ``reference_views`` > 0
    the one-thread twin (:func:`nbv.scores.projected_view_scores_reference`) and the fast path score the first
    ``reference_views`` cameras one after the other: the ratio of their times and the largest relative difference
    of their scores.

    Returns:
        ``gaussians``, ``views``, ``width``, ``height``, ``threads``, ``total_s`` (wall), ``cpu_s``,
        ``per_view_ms``, ``ns_per_pair``, ``gaussian_views_per_s``, ``visible_fraction`` of the (camera, Gaussian)
        pairs, ``peak_rss_mib`` / ``rss_before_mib`` (MiB); with ``occlusion`` the same scoring with the coarse
        :class:`nbv.scores.DepthBuffer`: ``occlusion_total_s``, ``occlusion_cpu_s``,
        ``occlusion_gaussian_views_per_s``, ``counted_fraction``; with ``reference_views``, ``reference``: a list of
        {``depth_test``, ``views``, ``reference_s``, ``fast_s``, ``speedup``, ``max_relative_difference``}.
    """
    big = jittered_to_count(gaussians, count, seed).to(device)
    metric = torch.from_numpy(np.resize(d, count))
    cams = orbit_cameras(big, PhysicsConfig(), Orbit(views, width=width))
    workers = threads or torch.get_num_threads()
    pairs = len(cams) * big.num
    rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    scored, total, cpu = timed(projected_view_scores, metric, big, cams, threads=workers)
    out = {
        "gaussians": big.num,
        "views": len(cams),
        "width": cams[0].width,
        "height": cams[0].height,
        "threads": workers,
        "total_s": total,
        "cpu_s": cpu,
        "per_view_ms": 1e3 * total / len(cams),
        "ns_per_pair": 1e9 * total / pairs,
        "gaussian_views_per_s": pairs / total,
        "visible_fraction": float(scored.counted.sum()) / pairs,
    }
    if occlusion:
        hidden, total, cpu = timed(
            projected_view_scores, metric, big, cams, depth_buffer=DepthBuffer(), threads=workers
        )
        out.update(
            occlusion_total_s=total,
            occlusion_cpu_s=cpu,
            occlusion_gaussian_views_per_s=pairs / total,
            counted_fraction=float(hidden.counted.sum()) / pairs,
        )
    if reference_views > 0:
        few = cams[: min(reference_views, len(cams))]
        out["reference"] = []
        for config in (None, DepthBuffer()) if occlusion else (None,):
            expected, ref_s, _ = timed(projected_view_scores_reference, metric, big, few, depth_buffer=config)
            got, fast_s, _ = timed(projected_view_scores, metric, big, few, depth_buffer=config, threads=workers)
            out["reference"].append(
                {
                    "depth_test": config is not None,
                    "views": len(few),
                    "reference_s": ref_s,
                    "fast_s": fast_s,
                    "speedup": ref_s / fast_s,
                    "max_relative_difference": largest_relative_difference(got.scores, expected.scores),
                    "counted_equal": bool(torch.equal(got.counted, expected.counted)),
                }
            )
    out["peak_rss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    out["rss_before_mib"] = rss_before
    return out


def ranking_lines(r: dict, source: str) -> list[str]:
    """The report of :func:`compare_with_renders`' figures ``r`` (D_g from ``source``): times, radii, the largest
    score difference, the rank agreement, and with ``occlusion`` the two depth tests' agreement."""
    lines = [
        f"ranking check: {r['views']} candidate views, {source}",
        f"  full renders {r['render_s']:.2f} s ({1e3 * r['render_s'] / r['views']:.0f} ms/view), projection "
        f"{r['projection_s']:.3f} s ({1e3 * r['projection_s'] / r['views']:.1f} ms/view)",
        f"  radii equal to the renderer's in every view: {r['radii_equal']}; largest relative score difference "
        f"{r['max_relative_difference']:.2e}",
        f"  Spearman {r['spearman']:.6f}; identical order: {r['identical_order']}",
        f"  order (best first): {r['order']}",
    ]
    if "occlusion" in r:
        o = r["occlusion"]
        lines.append(
            f"  --occlusion: coarse depth buffer vs render-based depth test: {100 * o['verdict_agreement']:.1f} % of "
            f"the visible (view, Gaussian) pairs agree (hidden: {100 * o['hidden_coarse']:.2f} % vs "
            f"{100 * o['hidden_render']:.2f} %); S(T) Spearman {o['spearman']:.4f}, same best view: "
            f"{o['same_best']}, top-5 overlap {o['top5_overlap']}/5"
        )
    return lines


def _target_line(total_s: float, cpu_s: float, scale: float, target: float) -> str:
    return (
        f"target <= {target:.0f} s for 200 cameras x 1M Gaussians: {total_s * scale:.1f} s wall "
        f"({'met' if total_s * scale <= target else 'NOT met'}; {cpu_s * scale:.1f} s of CPU time)"
        + ("" if scale == 1 else ", scaled from this run")
    )


def timing_lines(t: dict) -> list[str]:
    """The report of :func:`time_projected_scores`' figures ``t``: each scoring's times against its target (scaled
    to 200 cameras x 1M Gaussians), the reference path's speed-up and score difference, and the peak memory."""
    scale = TARGET_PAIRS / (t["views"] * t["gaussians"])
    lines = [
        f"timing: {t['views']} orbit cameras x {t['gaussians']:,} Gaussians at {t['width']} x {t['height']} px on "
        f"{t['threads']} thread(s), no PNGs ({100 * t['visible_fraction']:.0f} % of the pairs visible)",
        f"  frustum culling: {t['total_s']:.2f} s wall ({t['cpu_s']:.2f} s of CPU time), {t['per_view_ms']:.1f} "
        f"ms/view, {t['gaussian_views_per_s'] / 1e6:.1f} M Gaussian-views/s; "
        + _target_line(t["total_s"], t["cpu_s"], scale, TARGET_S),
    ]
    if "occlusion_total_s" in t:
        lines.append(
            f"  depth test (--occlusion): {t['occlusion_total_s']:.2f} s wall ({t['occlusion_cpu_s']:.2f} s of CPU "
            f"time), {t['occlusion_gaussian_views_per_s'] / 1e6:.1f} M Gaussian-views/s, "
            f"{100 * t['counted_fraction']:.0f} % of the pairs counted; "
            + _target_line(t["occlusion_total_s"], t["occlusion_cpu_s"], scale, TARGET_DEPTH_TEST_S)
        )
    for r in t.get("reference", []):
        lines.append(
            f"  reference path (one thread{', depth test on whole arrays' if r['depth_test'] else ''}) on the first "
            f"{r['views']} cameras: {r['reference_s']:.2f} s vs {r['fast_s']:.2f} s, {r['speedup']:.2f}x faster; "
            f"largest relative score difference {r['max_relative_difference']:.1e}, same counts: {r['counted_equal']}"
        )
    lines.append(f"  peak RSS {t['peak_rss_mib']:.0f} MiB (before scoring {t['rss_before_mib']:.0f} MiB)")
    return lines
