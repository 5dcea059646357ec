"""The oracle study's statistics (``fluidgs study oracle``, :mod:`nbv.study.oracle`): per rule the mean Spearman
with the oracle gain and its bootstrap interval over (scene, seed), the regret inside FisherRF's top-K, the paired
differences of the physics rules against their coverage controls, and the calibration means; and the Markdown
summary (``oracle.md``)."""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Sequence
from typing import Any

import numpy as np

from nbv.ranking import spearman
from nbv.study.oracle_config import OracleConfig, rule_of
from nbv.study.paired import format_p, paired_stats


# ---- statistics --------------------------------------------------------------------------------------
def bootstrap_interval(
    groups: Sequence[Sequence[float]], resamples: int, seed: int = 0, level: float = 0.95
) -> tuple[float, float, float]:
    """(mean, low, high): the mean of all values and its percentile bootstrap interval over the groups.

    Each resample draws the groups (here the (scene, seed) pairs) with replacement and takes the mean of all their
    values, so values within a group move together. NaN values are dropped first.
    """
    clean = [[float(x) for x in g if x is not None and math.isfinite(float(x))] for g in groups]
    clean = [g for g in clean if g]
    if not clean:
        return math.nan, math.nan, math.nan
    flat = [x for g in clean for x in g]
    mean = float(np.mean(flat))
    if len(clean) == 1:
        return mean, math.nan, math.nan
    rng = np.random.default_rng(seed)
    sums = np.array([sum(g) for g in clean])
    counts = np.array([len(g) for g in clean])
    picks = rng.integers(len(clean), size=(resamples, len(clean)))
    means = sums[picks].sum(axis=1) / counts[picks].sum(axis=1)
    lo, hi = np.quantile(means, [(1 - level) / 2, 1 - (1 - level) / 2])
    return mean, float(lo), float(hi)


def regret(scores: Sequence[float], gains: Sequence[float], shortlist: Sequence[int]) -> float:
    """Best gain in the shortlist minus the gain of the rule's pick there (ties: the shortlist's order)."""
    if not shortlist:
        return math.nan
    pick = max(range(len(shortlist)), key=lambda j: (float(scores[shortlist[j]]), -j))
    return max(float(gains[i]) for i in shortlist) - float(gains[shortlist[pick]])


def summarise(config: OracleConfig, states: list[dict]) -> dict[str, Any]:
    """Per rule: mean Spearman with the oracle gain (PSNR, SSIM) and regret with intervals; physics rules against
    their coverage controls; the calibration means."""
    labels = config.scored_rules()
    groups: dict[tuple[str, int], list[dict]] = defaultdict(list)
    for st in states:
        groups[(st["scene"], st["seed"])].append(st)
    keys = sorted(groups)
    b = config.bootstrap

    def per_state(fn) -> list[list[float]]:
        return [[fn(st) for st in groups[key]] for key in keys]

    rows = {}
    for label in labels:
        rho = per_state(lambda st, label=label: spearman(st["scores"][label], st["oracle"]["gain_psnr"]))
        rho_ssim = per_state(lambda st, label=label: spearman(st["scores"][label], st["oracle"]["gain_ssim"]))
        reg = per_state(lambda st, label=label: regret(st["scores"][label], st["oracle"]["gain_psnr"], st["shortlist"]))
        rows[label] = {
            "spearman": bootstrap_interval(rho, b),
            "spearman_ssim": bootstrap_interval(rho_ssim, b),
            "regret": bootstrap_interval(reg, b),
            "states": sum(len(g) for g in rho),
            "per_state": [x for g in rho for x in g],
            # per seed, over that seed's scenes: a seed's initial views make its own states, and the spread between
            # seeds can be as large as a rule's effect
            "per_seed": {
                str(seed): bootstrap_interval([g for key, g in zip(keys, rho, strict=True) if key[1] == seed], b)
                for seed in sorted({key[1] for key in keys})
            },
        }

    def versus(label: str, control: str, gain: str = "gain_psnr") -> dict[str, Any]:
        diff = [
            [a - c for a, c in zip(ga, gc, strict=True)]
            for ga, gc in zip(
                per_state(lambda st: spearman(st["scores"][label], st["oracle"][gain])),
                per_state(lambda st: spearman(st["scores"][control], st["oracle"][gain])),
                strict=True,
            )
        ]
        flat = [x for g in diff for x in g if math.isfinite(x)]
        st = paired_stats(flat, [0.0] * len(flat), True) if flat else None
        return {
            "rule": label,
            "control": control,
            "difference": bootstrap_interval(diff, b),
            "better": None if st is None else st.wins,
            "worse": None if st is None else st.losses,
            "sign_p": None if st is None else st.sign_p,
            "wilcoxon_p": None if st is None else st.wilcoxon_p,
            "wilcoxon_note": "" if st is None else st.wilcoxon_note,
        }

    paired = {}
    for label in config.physics_rules():
        rule = rule_of(label)
        paired[label] = versus(label, rule.control)
        if rule.own_control is not None:  # D_g against the coverage of its own mask
            own = f"{rule.own_control}:{label.partition(':')[2]}"
            paired[f"{label} vs {own}"] = versus(label, own)
    calib = _summarise_calibration(groups, keys, b, labels)
    gains = [st["oracle"]["gain_psnr"] for st in states]
    functional = None
    if states and all("gain_functional" in st["oracle"] for st in states):
        functional = _summarise_functional(config, states, labels, per_state, versus, b)
    return {
        "functional": functional,
        "states": len(states),
        "pairs": [list(k) for k in keys],
        "rules": rows,
        "paired": paired,
        "calibration": calib,
        "oracle": {
            "mean_gain_psnr": float(np.mean([np.mean(g) for g in gains])) if gains else math.nan,
            "mean_best_gain_psnr": float(np.mean([max(g) for g in gains])) if gains else math.nan,
            "mean_base_psnr": float(np.mean([st["oracle"]["psnr_base"] for st in states])) if states else math.nan,
        },
    }


def _finite(values: Sequence[float]) -> bool:
    return all(math.isfinite(v) for v in values)


def _summarise_functional(config, states, labels, per_state, versus, b) -> dict[str, Any]:
    """The functional target (``gain_functional``: the functional error of the copy without the candidate minus
    with it): per rule its Spearman with the gain and its regret inside the shortlist, with intervals; each physics
    rule against its coverage control; the mean error and its noise floor. States whose copies have no finite error
    (no solid) are left out of the Spearman (NaN)."""

    def where_finite(value) -> list[list[float]]:
        """``value(st, gain)`` per state, NaN where the state's functional gain is not finite."""
        return per_state(
            lambda st: (
                value(st, st["oracle"]["gain_functional"]) if _finite(st["oracle"]["gain_functional"]) else math.nan
            )
        )

    rows = {}
    for label in labels:
        rho = where_finite(lambda st, gain, label=label: spearman(st["scores"][label], gain))
        reg = where_finite(lambda st, gain, label=label: regret(st["scores"][label], gain, st["shortlist"]))
        rows[label] = {
            "spearman": bootstrap_interval(rho, b),
            "regret": bootstrap_interval(reg, b),
            "per_state": [x for g in rho for x in g],
        }
    paired = {label: versus(label, rule_of(label).control, "gain_functional") for label in config.physics_rules()}
    errors = [st["oracle"]["functional_error_base"] for st in states]
    floors = [st["oracle"]["functional_floor_base"] for st in states]
    spread = [float(np.nanstd(np.asarray(st["oracle"]["gain_functional"], float))) for st in states]
    return {
        "rules": rows,
        "paired": paired,
        "mean_error": float(np.nanmean(errors)),
        "mean_floor": float(np.nanmean(floors)),
        "mean_gain_spread": float(np.nanmean(spread)),
        "states_above_floor": int(sum(e > 2 * f for e, f in zip(errors, floors, strict=True))),
    }


def _summarise_calibration(groups: dict, keys: list, resamples: int, labels: Sequence[str]) -> dict[str, Any]:
    """The calibration means over the states that hold one; a signal over the states that computed it; the rules'
    agreement with the missing geometry for the summarised rules ``labels`` only."""
    with_cal = [k for k in keys if any("calibration" in st for st in groups[k])]
    if not with_cal:
        return {}
    cals = [st["calibration"] for k in with_cal for st in groups[k] if "calibration" in st]

    def interval(value, has=lambda cal: True) -> tuple[float, float, float]:
        """The interval of ``value(calibration)`` over the pairs, from the states that hold one (and pass ``has``)."""
        return bootstrap_interval(
            [
                [value(st["calibration"]) for st in groups[k] if "calibration" in st and has(st["calibration"])]
                for k in with_cal
            ],
            resamples,
        )

    signals = {
        name: {
            field: interval(lambda cal, f=field, n=name: cal["signals"][n][f], lambda cal, n=name: n in cal["signals"])
            for field in ("spearman", "ause")
        }
        for name in dict.fromkeys(n for cal in cals for n in cal["signals"])
    }
    rules = dict.fromkeys(r for cal in cals for r in cal["rules_vs_missing"] if r in labels)
    missing = {r: interval(lambda cal, r=r: cal["rules_vs_missing"][r]) for r in rules}
    gain = interval(lambda cal: cal["gain_vs_missing"])
    share = interval(lambda cal: cal["missing"]["missing"] / cal["missing"]["samples"])
    return {"signals": signals, "rules_vs_missing": missing, "gain_vs_missing": gain, "missing_share": share}


# ---- tables ------------------------------------------------------------------------------------------
def _ci(t: Sequence[float], fmt: str = "+.2f") -> str:
    mean, lo, hi = t
    if not math.isfinite(mean):
        return "n/a"
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return f"{mean:{fmt}} (one pair: no interval)"
    return f"{mean:{fmt}} ({lo:{fmt}}..{hi:{fmt}})"


def _functional_lines(f: dict[str, Any] | None) -> list[str]:
    """The functional target's tables (:func:`_summarise_functional`), or nothing without it."""
    if not f:
        return []
    lines = [
        "",
        "Functional target: the gain is the functional error (relative error of the time-mean force on the solid "
        "against the dataset's mesh) of the copy without the candidate minus with it. Mean error of the copies "
        f"without a candidate {f['mean_error']:.3g} against a noise floor of {f['mean_floor']:.3g} "
        f"({f['states_above_floor']} states above twice their floor); mean spread of the gains within a state "
        f"{f['mean_gain_spread']:.3g}.",
        "",
        "| rule | Spearman with the functional gain | regret in FisherRF's top-K (relative error) |",
        "| --- | --- | --- |",
    ]
    for label in _by_spearman(f["rules"]):
        lines.append(f"| {label} | {_ci(f['rules'][label]['spearman'])} | {_ci(f['rules'][label]['regret'], '.3f')} |")
    return lines + _paired_lines(f["paired"], "physics rule (functional gain)", wilcoxon=False)


def _by_spearman(rules: dict[str, Any]) -> list[str]:
    """The rule labels, the highest Spearman first (a NaN one last)."""
    return sorted(rules, key=lambda r: -(rules[r]["spearman"][0] if math.isfinite(rules[r]["spearman"][0]) else -9))


def _paired_lines(paired: dict[str, Any], title: str, wilcoxon: bool) -> list[str]:
    """The table of each physics rule against its control (:func:`summarise`'s ``paired``), or nothing without one;
    ``wilcoxon`` adds the Wilcoxon signed-rank p."""
    if not paired:
        return []
    columns = [title, "against", "Δ Spearman", "better / worse states", "sign-test p"]
    columns += ["Wilcoxon p"] if wilcoxon else []
    lines = ["", "| " + " | ".join(columns) + " |", "|" + " --- |" * len(columns)]
    for label, row in paired.items():
        cells = [row.get("rule", label), row["control"], _ci(row["difference"]), f"{row['better']} / {row['worse']}"]
        cells.append(format_p(row["sign_p"]))
        if wilcoxon:
            cells.append(format_p(row["wilcoxon_p"], row["wilcoxon_note"]))
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def format_summary(summary: dict[str, Any]) -> str:
    """Markdown tables of :func:`summarise`."""
    o = summary["oracle"]
    lines = [
        f"States: {summary['states']} over {len(summary['pairs'])} (scene, seed) pairs. Intervals: 95 % "
        "bootstrap over the (scene, seed) pairs.",
        "",
        f"Mean base test PSNR {o['mean_base_psnr']:.2f} dB; mean oracle gain {o['mean_gain_psnr']:+.3f} dB, "
        f"best candidate's {o['mean_best_gain_psnr']:+.3f} dB.",
        "",
        "| rule | Spearman with the PSNR gain | Spearman with the SSIM gain | regret in FisherRF's top-K (dB) | "
        "states |",
        "| --- | --- | --- | --- | --- |",
    ]
    order = _by_spearman(summary["rules"])
    for label in order:
        row = summary["rules"][label]
        lines.append(
            f"| {label} | {_ci(row['spearman'])} | {_ci(row['spearman_ssim'])} | "
            f"{_ci(row['regret'], '.3f')} | {row['states']} |"
        )
    seeds = next(iter(summary["rules"].values()))["per_seed"] if summary["rules"] else {}
    if len(seeds) > 1:
        lines += [
            "",
            "By seed (intervals over that seed's scenes):",
            "",
            "| rule | " + " | ".join(f"seed {seed}" for seed in seeds) + " |",
            "| --- |" + " --- |" * len(seeds),
        ]
        for label in order:
            per = summary["rules"][label]["per_seed"]
            lines.append(f"| {label} | " + " | ".join(_ci(per[seed]) for seed in seeds) + " |")
    lines += _paired_lines(summary["paired"], "physics rule", wilcoxon=True)
    lines += _functional_lines(summary.get("functional"))
    cal_ = summary.get("calibration") or {}
    if cal_:
        lines += [
            "",
            "Per-Gaussian calibration against the distance to the mesh (signals oriented as uncertainty; "
            "Spearman > 0 and a small AUSE are good):",
            "",
            "| signal | Spearman with the distance | AUSE |",
            "| --- | --- | --- |",
        ]
        for name, row in cal_["signals"].items():
            lines.append(f"| {name} | {_ci(row['spearman'])} | {_ci(row['ause'], '.3f')} |")
        lines += [
            "",
            f"Missing geometry (mesh samples outside every Gaussian's 2-sigma ellipsoid): "
            f"{_ci(cal_['missing_share'], '.2f')} of the samples. Spearman of each rule's scores with the "
            f"missing samples a view sees (the oracle gain's: {_ci(cal_['gain_vs_missing'])}):",
            "",
            "| rule | Spearman with the missing samples seen |",
            "| --- | --- |",
        ]
        for name, t in cal_["rules_vs_missing"].items():
            lines.append(f"| {name} | {_ci(t)} |")
    return "\n".join(lines) + "\n"


# ---- the study ---------------------------------------------------------------------------------------
