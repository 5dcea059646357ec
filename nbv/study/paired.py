"""Paired comparisons of two methods run on the same (scene, seed): wins, differences and their significance.

Two runs of an experiment that share scene and seed share the initial views, the training seed and the planner
seed, so the difference of a metric between two methods is measured per pair. For each pair of methods
and each metric this module gives:

- **wins / losses / ties**: pairs where the first method is better / worse / equal ("better" follows the
  metric's direction: higher PSNR and SSIM, lower Chamfer and D-bar);
- **mean and median difference** Δ = first − second, in the metric's units;
- an **exact sign test**: two-sided binomial test of wins against losses with p = 1/2, ties dropped,
  p = min(1, 2 · sum_{k <= min(w, l)} C(w + l, k) / 2^(w + l)) (no library needed);
- a **Wilcoxon signed-rank test** of the differences, two-sided, zero differences dropped
  (``scipy.stats.wilcoxon``: exact for small samples without tied ranks); "n/a (scipy not installed)"
  without scipy.

The comparisons (:func:`comparisons`) put each physics pick ``<visual>+fluid`` against the bare visual planner and
against both controls of the pick (``<visual>+area``: coverage alone; ``<visual>+shuffled``: D_g permuted), and the
coverage control against the bare planner, for the methods that ran.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

ALPHA = 0.05
VISUAL_PLANNERS = ("fisher", "variance", "random")
# (row key, label, higher is better)
PAIRED_METRICS = (
    ("psnr", "PSNR (dB)", True),
    ("ssim", "SSIM", True),
    ("chamfer", "Chamfer (scene units)", False),
    ("dbar", "D-bar (m^4/s)", False),
    ("critical_psnr", "critical PSNR (dB)", True),
    ("critical_dbar", "critical D-bar (m^4/s)", False),
    ("functional_error", "functional error (time-mean force, relative)", False),
)


def sign_test_p(wins: int, losses: int) -> float:
    """Exact two-sided sign test: p of a split at least as uneven as ``wins : losses`` under p = 1/2.

    Args:
        wins, losses: counts of positive and negative differences (ties already dropped), >= 0.
    Returns:
        p in (0, 1]; 1 when there is no non-tied pair.
    """
    if any(isinstance(x, bool) or not isinstance(x, int) or x < 0 for x in (wins, losses)):
        raise ValueError(f"sign_test_p: wins and losses must be integers >= 0, got {wins!r}, {losses!r}")
    n = wins + losses
    if n == 0:
        return 1.0
    tail = sum(math.comb(n, k) for k in range(min(wins, losses) + 1))
    return min(1.0, 2.0 * tail / 2.0**n)


def min_pairs_for_sign_test(alpha: float = ALPHA) -> int:
    """The fewest non-tied pairs with which the exact two-sided sign test can give p < ``alpha`` at all (every pair
    on one side: p = 2 / 2^n); 6 for alpha = 0.05."""
    if not 0 < alpha <= 1:
        raise ValueError(f"alpha must be in (0, 1], got {alpha}")
    n = 1
    while sign_test_p(n, 0) >= alpha:
        n += 1
    return n


def scipy_available() -> bool:
    try:
        import scipy.stats  # noqa: F401, PLC0415 - scipy.stats takes ~2 s to import; only the tables need it
    except ImportError:
        return False
    return True


def wilcoxon_p(differences: Sequence[float]) -> tuple[float | None, str]:
    """Two-sided Wilcoxon signed-rank p of paired differences (zeros dropped).

    Returns:
        (p, "") or (None, the reason shown in the tables: "n/a (scipy not installed)", "n/a (no non-zero
        difference)").
    """
    d = [float(x) for x in differences if float(x) != 0.0]
    if not scipy_available():
        return None, "n/a (scipy not installed)"
    if not d:
        return None, "n/a (no non-zero difference)"
    from scipy.stats import wilcoxon  # noqa: PLC0415 - slow to import, as in scipy_available

    return float(wilcoxon(d, zero_method="wilcox", alternative="two-sided").pvalue), ""


@dataclass(frozen=True)
class PairedStats:
    """One paired comparison of a metric (first method minus second).

    Attributes:
        n: pairs with a finite value for both methods.
        wins, losses, ties: pairs where the first method is better, worse, equal.
        mean_diff, median_diff: of Δ = first − second (metric units; NaN when n = 0).
        sign_p: exact two-sided sign test (ties dropped).
        wilcoxon_p: two-sided Wilcoxon signed-rank p, or None (then ``wilcoxon_note`` says why).
        wilcoxon_note: "" or the reason the Wilcoxon p is missing.
    """

    n: int
    wins: int
    losses: int
    ties: int
    mean_diff: float
    median_diff: float
    sign_p: float
    wilcoxon_p: float | None
    wilcoxon_note: str = ""

    def significant(self, alpha: float = ALPHA) -> str:
        """Which tests give p < alpha: "both tests", "sign test only", "Wilcoxon only" or "neither"."""
        sign = self.sign_p < alpha
        wil = self.wilcoxon_p is not None and self.wilcoxon_p < alpha
        return {
            (True, True): "both tests",
            (True, False): "sign test only",
            (False, True): "Wilcoxon only",
            (False, False): "neither",
        }[(sign, wil)]


def paired_stats(first: Sequence[float], second: Sequence[float], higher_is_better: bool) -> PairedStats:
    """Paired statistics of two equally long sequences of one metric (see the module docstring)."""
    if len(first) != len(second):
        raise ValueError(f"paired_stats: {len(first)} values against {len(second)}; pass one value per pair")
    diffs = [float(a) - float(b) for a, b in zip(first, second, strict=True)]
    if any(not math.isfinite(d) for d in diffs):
        raise ValueError("paired_stats: the values must be finite; drop the pairs with a missing metric first")
    sign = 1.0 if higher_is_better else -1.0
    wins = sum(1 for d in diffs if sign * d > 0)
    losses = sum(1 for d in diffs if sign * d < 0)
    p_w, note = wilcoxon_p(diffs)
    n = len(diffs)
    ordered = sorted(diffs)
    median = math.nan if n == 0 else (ordered[n // 2] if n % 2 else 0.5 * (ordered[n // 2 - 1] + ordered[n // 2]))
    return PairedStats(
        n=n,
        wins=wins,
        losses=losses,
        ties=n - wins - losses,
        mean_diff=math.fsum(diffs) / n if n else math.nan,
        median_diff=median,
        sign_p=sign_test_p(wins, losses),
        wilcoxon_p=p_w,
        wilcoxon_note=note,
    )


def _finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(float(v))


def paired_values(rows: Sequence[dict], first: str, second: str, key: str) -> tuple[list[float], list[float]]:
    """Values of ``key`` of two methods matched on (scene, seed), over the pairs where both are finite.

    Args:
        rows: experiment result rows (``kind``, ``scene``, ``method``, ``seed`` and the metrics).
    Returns:
        (first's values, second's values), in the rows' (scene, seed) order.
    """

    def values(method: str) -> dict[tuple[str, int], float]:
        return {
            (r["scene"], r["seed"]): float(r[key])
            for r in rows
            if r.get("kind", "method") == "method" and r["method"] == method and _finite(r.get(key))
        }

    a, b = values(first), values(second)
    keys = [k for k in a if k in b]
    return [a[k] for k in keys], [b[k] for k in keys]


def comparisons(methods: Sequence[str]) -> list[tuple[str, str]]:
    """(first, second) method pairs to compare, among ``methods``: each ``<visual>+fluid`` against ``<visual>``,
    ``<visual>+area`` and ``<visual>+shuffled``, and ``<visual>+area`` against ``<visual>``; then every other
    ``<visual>+<candidate>`` (``fisher+fluid-occ``, ``fisher+excess``, ...) against
    ``<visual>+area``, ``<visual>+fluid`` and, except the control itself, ``<visual>+area-occ``."""
    have = set(methods)
    out = []
    for v in VISUAL_PLANNERS:
        for pair in ((f"{v}+fluid", v), (f"{v}+fluid", f"{v}+area"), (f"{v}+fluid", f"{v}+shuffled"), (f"{v}+area", v)):
            if pair[0] in have and pair[1] in have:
                out.append(pair)
    for v in VISUAL_PLANNERS:
        base = {f"{v}+fluid", f"{v}+area", f"{v}+shuffled"}
        for m in dict.fromkeys(methods):
            if not m.startswith(f"{v}+") or m in base or "@" in m:
                continue
            for second in (f"{v}+area", f"{v}+fluid", f"{v}+area-occ"):
                if second in have and second != m:
                    out.append((m, second))
    return out


def format_diff(x: float) -> str:
    if not math.isfinite(x):
        return "n/a"
    return f"{x:+.2e}" if x != 0 and abs(x) < 1e-2 else f"{x:+.3f}"


def format_p(p: float | None, note: str = "") -> str:
    if p is None:
        return note or "n/a"
    return f"{p:.1e}" if p < 1e-4 else f"{p:.4f}"


def sign_test_power_line(pairs: int, alpha: float = ALPHA) -> str:
    """The line that says how many pairs a sign test needs to reach p < ``alpha`` at all, against the ``pairs``
    the table has (its largest comparison)."""
    need = min_pairs_for_sign_test(alpha)
    best = sign_test_p(pairs, 0) if pairs else 1.0
    verdict = (
        f"with {pairs} pair{'s' if pairs != 1 else ''} the best possible sign-test p is {format_p(best)}, so no "
        f"sign test here can clear p < {alpha:g}: add scenes or seeds"
        if pairs < need
        else f"this table has up to {pairs} pairs (best possible sign-test p {format_p(best)})"
    )
    return f"The sign test needs at least {need} pairs, all on one side, to reach p < {alpha:g}; {verdict}."


def _paired_comparison(
    rows: Sequence[dict], first: str, second: str, alpha: float
) -> tuple[list[list[str]], list[str], list[str]]:
    """One comparison of :func:`paired_table`: its body rows (one per metric with pairs), the metrics that clear
    ``alpha`` (with their direction and p values) and the names of those that do not."""
    label = f"{first} vs {second}"
    body, passed, failed = [], [], []
    for key, metric, higher in PAIRED_METRICS:
        a, b = paired_values(rows, first, second, key)
        if not a:
            continue
        st = paired_stats(a, b, higher)
        verdict = st.significant(alpha)
        wilcoxon = format_p(st.wilcoxon_p, st.wilcoxon_note)
        counts = [str(st.n), str(st.wins), str(st.losses), str(st.ties)]
        diffs = [format_diff(st.mean_diff), format_diff(st.median_diff)]
        body.append([label, metric, *counts, *diffs, format_p(st.sign_p), wilcoxon, verdict])
        if verdict == "neither":
            failed.append(metric)
        else:
            better = (
                "better" if st.wins > st.losses or (st.wins == st.losses and (st.mean_diff > 0) == higher) else "worse"
            )
            passed.append(
                f"{metric} ({better}, {st.wins}/{st.n} pairs better; {verdict}: sign p = "
                f"{format_p(st.sign_p)}, Wilcoxon p = {wilcoxon})"
            )
    return body, passed, failed


def _paired_summary(body: list[list[str]], clear: list[str], unclear: list[str], alpha: float) -> list[str]:
    """The Markdown lines under the paired table: how the tests were made, the sign test's power, and which
    comparisons clear ``alpha``."""
    summary = [
        f"Δ = first − second. Two-sided tests; ties and zero differences dropped; the Wilcoxon test is "
        f"{'scipy.stats.wilcoxon' if scipy_available() else 'n/a (scipy not installed)'}. No correction for "
        f"the {len(body)} comparisons: about {alpha * len(body):.1f} of them clear p < {alpha:g} by chance "
        "alone.",
        "",
        sign_test_power_line(max((int(r[2]) for r in body), default=0), alpha),
        "",
        f"**Clear p < {alpha:g}** (by at least one test):",
        "",
    ]
    summary += clear or ["- none"]
    summary += ["", f"**Do not clear p < {alpha:g}** (neither test):", ""]
    summary += unclear or ["- none"]
    return summary


def paired_table(
    rows: Sequence[dict], methods: Sequence[str] | None = None, alpha: float = ALPHA
) -> tuple[list[str], list[list[str]], list[str]] | None:
    """The paired comparison table of the experiment rows.

    Args:
        rows: experiment result rows.
        methods: methods to consider (default: those in ``rows``).
        alpha: significance level of the verdicts.
    Returns:
        (header, body rows, summary lines in Markdown) or None when no comparison of :func:`comparisons` has
        both methods.
    """
    names = (
        list(dict.fromkeys(r["method"] for r in rows if r.get("kind", "method") == "method"))
        if methods is None
        else list(methods)
    )
    pairs = comparisons(names)
    if not pairs:
        return None
    header = [
        "comparison",
        "metric",
        "pairs",
        "better",
        "worse",
        "ties",
        "mean Δ",
        "median Δ",
        "sign-test p",
        "Wilcoxon p",
        f"p < {alpha:g}",
    ]
    body, clear, unclear = [], [], []
    for first, second in pairs:
        label = f"{first} vs {second}"
        rows_of_pair, passed, failed = _paired_comparison(rows, first, second, alpha)
        body += rows_of_pair
        if passed:
            clear.append(f"- {label}: {'; '.join(passed)}")
        if failed:
            unclear.append(f"- {label}: {', '.join(failed)}")
    summary = _paired_summary(body, clear, unclear, alpha)
    return header, body, summary
