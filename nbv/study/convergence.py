"""Convergence of D_g and of the candidate-view ranking across probe settings.

Given several probe runs of the *same* Gaussian set at different settings (particle radius r, run length) and the
candidate cameras, this module measures how much the per-Gaussian divergence D_g and the view ranking it gives
change between settings, and how much of the view score is coverage:

- **D_g agreement**: Pearson and Spearman correlation of D_g between two settings, over the Gaussians that the
  fluid reached in both (at least one (particle, step) sample in some probe).
- **View terms** per setting, from the Eq. 5 weights W[c, g] = w_g(T_c) (0 where g is not visible in c):
  S(T) = sum_g W D_g, the coverage A(T) = sum_g W (S with D_g = 1, the same for every setting) and the
  area-weighted mean divergence a view sees, S(T) / A(T).
- **Ranking agreement** between two settings: Spearman correlation of S(T) and of S(T) / A(T) over the views, the
  rank at the second setting of the first setting's top view, and the overlap of the two top-k lists.
- **Coverage share** per setting: Spearman / Pearson of S(T) against A(T) (1 means coverage alone orders the views)
  and the coefficient of variation (std / mean) of S(T) / A(T) over the views, the part of S that coverage does not
  explain.

Ranks, Pearson and Spearman are those of :mod:`nbv.ranking`. :func:`study` runs everything; :func:`format_study`
gives Markdown tables.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from nbv.physics import load_result
from nbv.ranking import TOP_K, pearson, spearman
from nbv.scores import unoccluded, view_weights
from recon.render import render


@dataclass(frozen=True)
class ProbeSetting:
    """One probe run of the Gaussian set.

    Attributes:
        label: e.g. "r=0.05 m, 150 steps".
        particle_radius: m. steps: per probe.
        divergence: [G] D_g (max over the probes), 1/s.
        reached: [G] bool, the fluid reached g in at least one probe.
        dbar: D-bar, m^4/s.
        seconds: the run's total time (s), or None when unknown.
        fluid_particles: the largest fluid particle count of a probe, or None.
    """

    label: str
    particle_radius: float
    steps: int
    divergence: np.ndarray
    reached: np.ndarray
    dbar: float
    seconds: float | None = None
    fluid_particles: int | None = None

    def __post_init__(self) -> None:
        d, r = np.asarray(self.divergence), np.asarray(self.reached)
        if d.ndim != 1 or r.shape != d.shape:
            raise ValueError(
                f"ProbeSetting {self.label!r}: divergence and reached must be [G] arrays of one length, "
                f"got {d.shape} and {r.shape}"
            )
        if not np.isfinite(d).all():
            raise ValueError(f"ProbeSetting {self.label!r}: D_g has NaN or Inf values")


def load_setting(path: str | Path, label: str | None = None) -> ProbeSetting:
    """A :class:`ProbeSetting` from a RESULT.h5 of ``fluidgs simulate`` (:func:`nbv.physics.load_result`)."""
    res = load_result(path)
    cfg = res.config
    active = [int(s["active"].max()) for s in res.stats.values() if len(s)]
    return ProbeSetting(
        label=label or f"r={cfg.particle_radius:g} m, {cfg.steps} steps",
        particle_radius=float(cfg.particle_radius),
        steps=int(cfg.steps),
        divergence=np.asarray(res.divergence, np.float64),
        reached=np.asarray(res.per_probe_counts).sum(0) > 0,
        dbar=float(res.dbar),
        seconds=res.timings.get("total"),
        fluid_particles=max(active) if active else None,
    )


def view_weight_matrix(gaussians, cameras: Sequence, occlusion: bool = False) -> np.ndarray:
    """W [C, G]: the Eq. 5 weight w_g(T_c) where g is visible in camera c, else 0 (float64).

    Args:
        gaussians: the GaussianSet (scene units) the settings were computed on.
        cameras: C cameras (their size sets H x W).
        occlusion: count only Gaussians in front of the rendered surface (:func:`nbv.scores.unoccluded`);
            default: the paper's frustum culling.
    """
    g = gaussians.detach()
    reach = 3.0 * g.max_radii().double()
    rows = []
    with torch.no_grad():
        for cam in cameras:
            out = render(g, cam, background=1.0)
            vis = unoccluded(g.means, reach, cam, out) if occlusion else out.visible.cpu().bool()
            rows.append((view_weights(out.radii.cpu(), cam.height, cam.width) * vis.double()).numpy())
    return np.stack(rows)


@dataclass(frozen=True)
class SettingSummary:
    """The view terms of one setting (see the module docstring).

    Attributes:
        label, seconds, fluid_particles, dbar: as in :class:`ProbeSetting`.
        mean_divergence: mean D_g over the reached Gaussians, 1/s. reached: their fraction.
        score_vs_coverage_spearman, score_vs_coverage_pearson: S(T) against A(T) over the views.
        mean_seen_cv: coefficient of variation of S(T) / A(T) over the views (std / mean; 0 = coverage is all).
        mean_seen_vs_coverage_spearman: S(T) / A(T) against A(T) over the views (near 0: the physics part
            orders the views independently of coverage).
        top_view: position of the best view by S(T).
    """

    label: str
    seconds: float | None
    fluid_particles: int | None
    dbar: float
    mean_divergence: float
    reached: float
    score_vs_coverage_spearman: float
    score_vs_coverage_pearson: float
    mean_seen_cv: float
    mean_seen_vs_coverage_spearman: float
    top_view: int


@dataclass(frozen=True)
class PairSummary:
    """Agreement of two settings (see the module docstring).

    Attributes:
        first, second: labels.
        common: Gaussians reached in both. d_pearson, d_spearman: D_g over them.
        score_spearman: S(T) over the views. mean_seen_spearman: S(T) / A(T) over the views.
        top_view_rank: 1-based rank at ``second`` of the top view of ``first``.
        top_k_overlap: views in both top-k lists (k = :data:`TOP_K`).
    """

    first: str
    second: str
    common: int
    d_pearson: float
    d_spearman: float
    score_spearman: float
    mean_seen_spearman: float
    top_view_rank: int
    top_k_overlap: int


def _snapped(x: np.ndarray) -> np.ndarray:
    """``x`` rounded to 12 significant digits of its largest magnitude, so that round-off (a constant D_g gives
    S / A = const +- 1e-16) does not create a ranking."""
    scale = float(np.abs(x).max()) if x.size else 0.0
    return np.round(x / scale, 12) * scale if scale > 0 else x


def _descending(scores: np.ndarray) -> np.ndarray:
    return np.lexsort((np.arange(len(scores)), -scores))


def view_terms(weights: np.ndarray, divergence: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(S(T) [C], coverage A(T) [C], S(T) / A(T) [C], NaN where A = 0) from W [C, G] and D_g [G]."""
    w = np.asarray(weights, np.float64)
    d = np.asarray(divergence, np.float64).reshape(-1)
    if w.ndim != 2 or w.shape[1] != d.size:
        raise ValueError(
            f"view_terms: weights {w.shape} do not match {d.size} per-Gaussian values; score the "
            "Gaussian set the probes ran on"
        )
    score, cover = w @ d, w.sum(1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_seen = np.where(cover > 0, score / np.where(cover > 0, cover, 1.0), np.nan)
    return score, cover, mean_seen


def summarize_setting(setting: ProbeSetting, weights: np.ndarray) -> SettingSummary:
    score, cover, mean_seen = view_terms(weights, setting.divergence)
    seen = mean_seen[np.isfinite(mean_seen)]
    reached = np.asarray(setting.reached, bool)
    return SettingSummary(
        label=setting.label,
        seconds=setting.seconds,
        fluid_particles=setting.fluid_particles,
        dbar=setting.dbar,
        mean_divergence=float(setting.divergence[reached].mean()) if reached.any() else 0.0,
        reached=float(reached.mean()),
        score_vs_coverage_spearman=spearman(score, cover),
        score_vs_coverage_pearson=pearson(score, cover),
        mean_seen_cv=float(seen.std() / seen.mean()) if seen.size and seen.mean() > 0 else math.nan,
        mean_seen_vs_coverage_spearman=spearman(_snapped(seen), cover[np.isfinite(mean_seen)]),
        top_view=int(_descending(score)[0]),
    )


def compare_settings(a: ProbeSetting, b: ProbeSetting, weights: np.ndarray, top_k: int = TOP_K) -> PairSummary:
    """How far setting ``b`` agrees with setting ``a`` (same Gaussians, same weights)."""
    if a.divergence.shape != b.divergence.shape:
        raise ValueError(
            f"settings {a.label!r} and {b.label!r} hold D_g of {a.divergence.size} and "
            f"{b.divergence.size} Gaussians; compare runs of one Gaussian set"
        )
    common = np.asarray(a.reached, bool) & np.asarray(b.reached, bool)
    sa, _, ma = view_terms(weights, a.divergence)
    sb, _, mb = view_terms(weights, b.divergence)
    finite = np.isfinite(ma) & np.isfinite(mb)
    order_a, order_b = _descending(sa), _descending(sb)
    rank_b = {int(v): i + 1 for i, v in enumerate(order_b)}
    k = min(top_k, len(sa))
    return PairSummary(
        first=a.label,
        second=b.label,
        common=int(common.sum()),
        d_pearson=pearson(a.divergence[common], b.divergence[common]),
        d_spearman=spearman(a.divergence[common], b.divergence[common]),
        score_spearman=spearman(sa, sb),
        mean_seen_spearman=spearman(_snapped(ma[finite]), _snapped(mb[finite])),
        top_view_rank=rank_b[int(order_a[0])],
        top_k_overlap=len(set(order_a[:k].tolist()) & set(order_b[:k].tolist())),
    )


def study(
    settings: Sequence[ProbeSetting], weights: np.ndarray, top_k: int = TOP_K
) -> tuple[list[SettingSummary], list[PairSummary]]:
    """Every setting's summary and every pair's agreement (pairs in the order of ``settings``)."""
    if len(settings) < 1:
        raise ValueError("convergence study: pass at least one probe setting")
    summaries = [summarize_setting(s, weights) for s in settings]
    pairs = [compare_settings(a, b, weights, top_k) for a, b in itertools.combinations(settings, 2)]
    return summaries, pairs


def _f(x: float | None, digits: int = 3) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "n/a"
    return f"{x:.{digits}f}"


def format_study(summaries: Sequence[SettingSummary], pairs: Sequence[PairSummary], top_k: int = TOP_K) -> str:
    """Markdown: one table of the settings, one of the pairs."""
    lines = [
        "| setting | fluid particles | time (s) | D-bar (m^4/s) | reached | mean D_g (1/s) | "
        "S vs coverage Spearman | S vs coverage Pearson | CV of S/A over views | S/A vs coverage Spearman | "
        "top view |",
        "|" + "---|" * 11,
    ]
    for s in summaries:
        lines.append(
            f"| {s.label} | {s.fluid_particles if s.fluid_particles is not None else 'n/a'} | "
            f"{_f(s.seconds, 1)} | {s.dbar:.3e} | {s.reached:.1%} | {_f(s.mean_divergence)} | "
            f"{_f(s.score_vs_coverage_spearman)} | {_f(s.score_vs_coverage_pearson)} | "
            f"{s.mean_seen_cv:.2%} | {_f(s.mean_seen_vs_coverage_spearman)} | {s.top_view} |"
        )
    lines += [
        "",
        f"| first | second | common Gaussians | D_g Pearson | D_g Spearman | S(T) Spearman | "
        f"S/A Spearman | rank of first's top view | top-{top_k} overlap |",
        "|" + "---|" * 9,
    ]
    for p in pairs:
        lines.append(
            f"| {p.first} | {p.second} | {p.common} | {_f(p.d_pearson)} | {_f(p.d_spearman)} | "
            f"{_f(p.score_spearman)} | {_f(p.mean_seen_spearman)} | {p.top_view_rank} | "
            f"{p.top_k_overlap} |"
        )
    return "\n".join(lines) + "\n"
