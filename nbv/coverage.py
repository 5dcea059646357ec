"""How much of a view ranking the physics decides: coverage beside S(T) (paper Eq. 4-5).

S(T) = sum over the Gaussians counted in view T of w_g D_g mixes two things: how much of the object the view
covers, the coverage A(T) = sum of w_g over the same counted Gaussians (S(T) with D_g = 1), and where the fluid
disturbs it, the physics part P(T) = S(T) / A(T), the area-weighted mean D_g the view sees. So S(T) = A(T) P(T).
Where S(T) orders the views as A(T) does, coverage decides the ranking and the probes add nothing a probe-free
count of the visible surface would not give (docs/results.md measures this: with frustum visibility S(T) follows
coverage at every probe setting).

:func:`view_parts` gives each view its coverage, physics part and the three ranks; :func:`ranking_agreement`
compares the S(T) ranking with the coverage ranking (the Spearman correlation over the views, and how many of the
top five both share); :func:`agreement_lines` says it in one plain line. The same applies to any per-Gaussian metric
M_g in place of D_g (the function-critical |P_g| of ``fluidgs critical``).
"""

from __future__ import annotations

import math

import numpy as np

from nbv.ranking import TOP_K, spearman

COVERAGE_DECIDES = 0.9  # Spearman(S, A) from which coverage is said to decide the ranking
SCORE_DIGITS = 2  # significant digits of S(T), A(T) and S/A in printed tables (see docs/results.md)


def _ranks(values: np.ndarray) -> list[int | None]:
    """1-based rank of each value, largest first (ties keep the lower index first); None for NaN."""
    v = np.asarray(values, np.float64)
    finite = np.flatnonzero(np.isfinite(v))
    order = finite[np.argsort(-v[finite], kind="stable")]
    out: list[int | None] = [None] * v.size
    for r, k in enumerate(order):
        out[int(k)] = r + 1
    return out


def view_parts(scores, coverage) -> list[dict]:
    """Per view (in the given order): coverage A(T), physics_mean P(T) = S / A (None where A = 0) and the ranks of
    S, A and P (``rank``, ``coverage_rank``, ``physics_rank``; 1 = largest, None where P is undefined).

    Args:
        scores: [C] S(T). coverage: [C] A(T) of the same counted Gaussians (>= 0).
    Returns:
        C dicts with the keys rank, coverage, coverage_rank, physics_mean, physics_rank.

    Example:
        >>> [p["physics_rank"] for p in view_parts([2.0, 3.0], [1.0, 3.0])]
        [1, 2]
    """
    s, a = np.asarray(scores, np.float64).reshape(-1), np.asarray(coverage, np.float64).reshape(-1)
    if s.shape != a.shape:
        raise ValueError(f"view_parts: {s.size} scores against {a.size} coverages; give one of each per view")
    with np.errstate(invalid="ignore", divide="ignore"):
        p = np.where(a > 0, s / np.where(a > 0, a, 1.0), np.nan)
    rs, ra, rp = _ranks(s), _ranks(a), _ranks(p)
    return [
        {
            "rank": rs[k],
            "coverage": float(a[k]),
            "coverage_rank": ra[k],
            "physics_mean": float(p[k]) if math.isfinite(p[k]) else None,
            "physics_rank": rp[k],
        }
        for k in range(s.size)
    ]


def _spread(values: np.ndarray) -> float | None:
    """Coefficient of variation (std / mean) of the finite values; None when undefined."""
    v = values[np.isfinite(values)]
    return float(v.std() / v.mean()) if v.size > 1 and v.mean() > 0 else None


def ranking_agreement(scores, coverage, top: int = TOP_K) -> dict:
    """How far the S(T) ranking is the coverage ranking.

    Args:
        scores: [C] S(T). coverage: [C] A(T). top: the size of the top set compared (5).
    Returns:
        a JSON-able dict: views; top (min(top, C)); spearman_score_coverage (S against A over the views; None
        for fewer than 3 views or a constant side); spearman_physics_coverage (S/A against A);
        top5_overlap_with_coverage (how many of the best ``top`` by S are also the best ``top`` by A; the key keeps
        its name when ``top`` is not 5); top5_changed_by_physics (top minus the overlap); coverage_decides
        (Spearman >= 0.9); coverage_spread and physics_mean_spread (std / mean of A and of S/A over the views).

    Example:
        >>> ranking_agreement([1.0, 2.0, 3.0, 4.0], [2.0, 4.0, 6.0, 8.0])["coverage_decides"]
        True
    """
    s, a = np.asarray(scores, np.float64).reshape(-1), np.asarray(coverage, np.float64).reshape(-1)
    if s.shape != a.shape:
        raise ValueError(f"ranking_agreement: {s.size} scores against {a.size} coverages")
    parts = view_parts(s, a)
    p = np.array([np.nan if q["physics_mean"] is None else q["physics_mean"] for q in parts])
    k = min(int(top), s.size)
    by_s = {i for i, q in enumerate(parts) if q["rank"] <= k}
    by_a = {i for i, q in enumerate(parts) if q["coverage_rank"] <= k}
    rho = spearman(s, a) if s.size >= 3 else math.nan
    finite = np.isfinite(p)
    rho_p = spearman(p[finite], a[finite]) if finite.sum() >= 3 else math.nan
    overlap = len(by_s & by_a)
    return {
        "views": int(s.size),
        "top": k,
        "spearman_score_coverage": None if math.isnan(rho) else round(rho, 4),
        "spearman_physics_coverage": None if math.isnan(rho_p) else round(rho_p, 4),
        "top5_overlap_with_coverage": overlap,
        "top5_changed_by_physics": k - overlap,
        "coverage_decides": bool(not math.isnan(rho) and rho >= COVERAGE_DECIDES),
        "coverage_spread": _spread(a),
        "physics_mean_spread": _spread(p),
    }


def coverage_line(agreement: dict, physics: str = "physics", symbol: str = "S") -> str:
    """The one plain line that says how much of the ranking ``physics`` (the per-Gaussian metric) decides
    (``symbol``: the score's name, S or C)."""
    rho, k, views = agreement["spearman_score_coverage"], agreement["top"], agreement["views"]
    if rho is None:
        return (
            f"coverage vs {physics}: cannot say which decides the ranking ({views} views; the Spearman "
            "correlation needs 3 or more views with differing scores)"
        )
    spread = agreement["physics_mean_spread"]
    varies = "" if spread is None else f"; the {physics} part {symbol}/A varies {spread:.0%} between views"
    if agreement["coverage_decides"]:
        return (
            f"coverage decides the ranking at this setting: {symbol}(T) follows the coverage A(T) "
            f"(Spearman {rho:.2f} over {views} views; {agreement['top5_overlap_with_coverage']} of the top {k} "
            f"are coverage's top {k}){varies}"
        )
    return (
        f"the {physics} changed {agreement['top5_changed_by_physics']} of the top {k} views against coverage "
        f"alone ({symbol}(T) against the coverage A(T): Spearman {rho:.2f} over {views} views){varies}"
    )


def replicas_line(replicas: dict, symbol: str = "S") -> str:
    """The printed line on how far the replicas of a probe run agree (``agreement["replicas"]``,
    :func:`nbv.physics.replicas.replica_agreement`): the Spearman correlation between replicas (pairwise mean, and
    min) of the view ranking ``symbol``(T), of its physics part ``symbol``/A, and of D_g per Gaussian, each named,
    with what a gap between the first two means and what a low D_g agreement means."""

    def figure(name: str, key: str) -> str | None:
        mean = replicas.get(f"spearman_{key}_mean")
        return None if mean is None else f"{name} {mean:.2f} (min {replicas[f'spearman_{key}_min']:.2f})"

    n = replicas["count"]
    parts = [
        figure(f"the view ranking {symbol}(T)", "views"),
        figure(f"its physics part {symbol}/A", "physics"),
        figure("D_g per Gaussian", "gaussians"),
    ]
    shown = [p for p in parts if p is not None]
    line = f"replicas: {n} shifted lattices, {symbol}(T) from their mean; between them (Spearman, pairwise mean) " + (
        "; ".join(shown) if shown else "nothing can be compared (fewer than 3 views or Gaussians)"
    )
    views, physics = replicas.get("spearman_views_mean"), replicas.get("spearman_physics_mean")
    if views is not None and physics is not None and views > physics + 0.05:
        line += (
            f". {symbol}(T) agrees more than {symbol}/A because the coverage A(T), the same in every replica, "
            "carries part of it"
        )
    gaussians = replicas.get("spearman_gaussians_mean")
    if gaussians is not None and gaussians < 0.5:
        line += "; one Gaussian's D_g is mostly lattice noise: read it over regions, not Gaussian by Gaussian"
    return line


def one_run_line(symbol: str = "S") -> str:
    """The printed line of a ranking from one probe run: its reproducibility over lattice positions is unmeasured."""
    return (
        f"replicas: 1 lattice position, so how far {symbol}(T) depends on where the lattice lies is not measured; "
        "--replicas N runs N shifted lattices, averages over them and says how far their rankings agree"
    )


def agreement_lines(agreement: dict, physics: str = "physics", symbol: str = "S") -> list[str]:
    """The printed verdict on a ranking: the :func:`coverage_line`, and with replicas the :func:`replicas_line`."""
    lines = [coverage_line(agreement, physics, symbol)]
    if agreement.get("replicas") is not None:
        lines.append(replicas_line(agreement["replicas"], symbol))
    return lines


def format_number(value: float | None, digits: int = SCORE_DIGITS) -> str:
    """``value`` rounded to ``digits`` significant digits, written plainly from 1e-3 to 1e6 (360, 4.9, 0.012) and
    in exponent form outside ("-" for None)."""
    if value is None or not math.isfinite(value):
        return "-"
    rounded = float(f"{value:.{digits}g}")
    return f"{rounded:.{digits}g}" if rounded and not 1e-3 <= abs(rounded) < 1e6 else f"{rounded:g}"
