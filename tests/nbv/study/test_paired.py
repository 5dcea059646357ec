"""Paired comparisons (nbv.study.paired) and the experiment's paired table: the exact sign test against hand-computed
binomial tails, the Wilcoxon signed-rank p against an exhaustive enumeration of the sign flips, the wins and
differences of matched (scene, seed) pairs, the table's verdicts, and the single-direction form of the controls."""

import csv
import itertools
import math

import pytest

from nbv.study.experiment_config import split_method
from nbv.study.paired import (
    comparisons,
    min_pairs_for_sign_test,
    paired_stats,
    paired_table,
    paired_values,
    scipy_available,
    sign_test_p,
    wilcoxon_p,
)
from nbv.study.tables import build_tables

from helpers.study_rows import result_row as row


def test_sign_test_known_values():
    assert sign_test_p(11, 1) == pytest.approx(2 * (1 + 12) / 2**12)  # 0.00635: the README's 11 of 12
    assert sign_test_p(11, 1) == pytest.approx(0.00634765625, abs=1e-15)
    assert sign_test_p(5, 1) == pytest.approx(0.21875)  # 2 * (1 + 6) / 64
    assert sign_test_p(1, 5) == sign_test_p(5, 1)  # two-sided: symmetric
    assert sign_test_p(6, 0) == pytest.approx(0.03125)  # the smallest p six pairs can give
    assert sign_test_p(4, 2) == pytest.approx(0.6875)  # 2 * (1 + 6 + 15) / 64
    assert sign_test_p(3, 3) == 1.0 and sign_test_p(0, 0) == 1.0  # the tail sum exceeds 1/2: clipped
    assert sign_test_p(10, 0) == pytest.approx(2 / 1024)
    assert sign_test_p(15, 5) == pytest.approx(0.04138946533203125)  # R: binom.test(15, 20)$p.value
    with pytest.raises(ValueError, match="integers"):
        sign_test_p(-1, 2)


def _wilcoxon_exact(d: list[float]) -> float:
    """Two-sided exact Wilcoxon p by enumerating all 2^n sign patterns (distinct |d|, no zeros)."""
    ranks = {v: i + 1 for i, v in enumerate(sorted(abs(x) for x in d))}
    w_plus = sum(ranks[abs(x)] for x in d if x > 0)
    n = len(d)
    total = n * (n + 1) // 2
    stat = min(w_plus, total - w_plus)
    count = sum(
        1
        for signs in itertools.product((0, 1), repeat=n)
        if min(s := sum(r for r, b in zip(range(1, n + 1), signs, strict=True) if b), total - s) <= stat
    )
    return min(1.0, count / 2**n)


@pytest.mark.skipif(not scipy_available(), reason="scipy is not installed")
def test_wilcoxon_matches_the_exact_enumeration():
    assert wilcoxon_p([1, 2, 3, 4, 5, 6])[0] == pytest.approx(2 / 64)
    for d in (
        [0.3, -1.2, 2.5, 0.7, -0.1, 1.9, 3.3, -0.45],
        [1.0, -2.0, 3.5, 4.25, 5.5, -6.0, 7.0],
        [-0.2, -0.5, 0.9, -1.4, -2.2, -0.05, -3.0, 0.6, -1.1],
    ):
        assert wilcoxon_p(d)[0] == pytest.approx(_wilcoxon_exact(d), rel=1e-9)
    assert wilcoxon_p([0.0, 2.0, 1.0, 3.0])[0] == pytest.approx(_wilcoxon_exact([2.0, 1.0, 3.0]))  # zeros dropped
    p, note = wilcoxon_p([0.0, 0.0])
    assert p is None and "no non-zero" in note


def test_wilcoxon_without_scipy_says_so(monkeypatch):
    import nbv.study.paired as paired

    monkeypatch.setattr(paired, "scipy_available", lambda: False)
    assert paired.wilcoxon_p([1.0, 2.0]) == (None, "n/a (scipy not installed)")
    st = paired.paired_stats([1.0, 2.0, 3.0], [0.0, 0.0, 0.0], True)
    assert st.wilcoxon_p is None and st.wilcoxon_note == "n/a (scipy not installed)"
    assert st.significant() == "neither"  # 3 of 3: sign p = 0.25


def test_paired_stats_wins_follow_the_metric_direction():
    st = paired_stats([21.0, 22.0, 20.0, 23.0], [20.0, 22.0, 21.0, 20.0], higher_is_better=True)
    assert (st.n, st.wins, st.losses, st.ties) == (4, 2, 1, 1)
    assert st.mean_diff == pytest.approx(0.75) and st.median_diff == pytest.approx(0.5)
    assert st.sign_p == pytest.approx(1.0)
    low = paired_stats([1.0, 2.0, 3.0], [2.0, 3.0, 2.0], higher_is_better=False)  # D-bar: lower is better
    assert (low.wins, low.losses) == (2, 1) and low.median_diff == pytest.approx(-1.0)
    with pytest.raises(ValueError, match="finite"):
        paired_stats([1.0, math.nan], [1.0, 2.0], True)
    with pytest.raises(ValueError, match="one value per pair"):
        paired_stats([1.0], [1.0, 2.0], True)


def _experiment_rows() -> list[dict]:
    """fisher+fluid beats fisher on PSNR in all 8 pairs; fisher+area matches fisher+fluid (+-0.1 dB)."""
    rows = []
    for i, (scene, seed) in enumerate(itertools.product(("a", "b"), range(4))):
        base = 20.0 + i
        rows += [
            row("fisher", scene, seed, base, 4e-3),
            row("fisher+fluid", scene, seed, base + 1.0 + 0.01 * i, 3e-3),
            row("fisher+area", scene, seed, base + 1.0 + (0.1 if i % 2 else -0.1), 3e-3),
        ]
    rows.append(row("fisher+fluid", "c", 0, 30.0, 1e-3))  # no partner: not paired
    rows.append(row("reference-20views", "a", 0, 40.0, 1e-3, kind="reference"))
    return rows


def test_paired_values_match_scene_and_seed():
    rows = _experiment_rows()
    a, b = paired_values(rows, "fisher+fluid", "fisher", "psnr")
    assert len(a) == len(b) == 8
    assert all(x - y == pytest.approx(1.0 + 0.01 * i) for i, (x, y) in enumerate(zip(a, b, strict=True)))
    rows[0]["psnr"] = None  # a missing metric drops that pair only
    assert len(paired_values(rows, "fisher+fluid", "fisher", "psnr")[0]) == 7
    assert comparisons(["fisher", "fisher+fluid", "fisher+area", "random"]) == [
        ("fisher+fluid", "fisher"),
        ("fisher+fluid", "fisher+area"),
        ("fisher+area", "fisher"),
    ]
    assert comparisons(["random", "fisher+fluid"]) == []


def test_experiment_paired_table_states_what_clears_p_005():
    tables = build_tables(_experiment_rows())
    md, text = tables["paired"]
    body = {(r[0], r[1]): r for r in csv.reader(text.splitlines())}
    head = body[("comparison", "metric")]
    tests = ["mean Δ", "median Δ", "sign-test p", "Wilcoxon p", "p < 0.05"]
    assert head[2:] == ["pairs", "better", "worse", "ties", *tests]
    vs_fisher = body[("fisher+fluid vs fisher", "PSNR (dB)")]
    assert vs_fisher[2:6] == ["8", "8", "0", "0"]
    assert vs_fisher[6] == "+1.035" and float(vs_fisher[8]) == pytest.approx(2 / 256, abs=1e-4)
    vs_area = body[("fisher+fluid vs fisher+area", "PSNR (dB)")]
    assert vs_area[3:6] == ["4", "4", "0"] and vs_area[8] == "1.0000" and vs_area[10] == "neither"
    dbar = body[("fisher+fluid vs fisher", "D-bar (m^4/s)")]
    assert dbar[3] == "8" and dbar[6] == "-1.00e-03"  # lower D-bar counts as better
    ties = body[("fisher+fluid vs fisher+area", "SSIM")]
    assert ties[3:6] == ["0", "0", "8"] and ties[8] == "1.0000"
    if scipy_available():
        assert vs_fisher[10] == "both tests" and float(vs_fisher[9]) == pytest.approx(2 / 256, abs=1e-4)
        assert "n/a (no non-zero difference)" in ties[9]
    else:
        assert vs_fisher[10] == "sign test only" and vs_fisher[9] == "n/a (scipy not installed)"
    clear = md.split("**Clear p < 0.05**")[1].split("**Do not clear")[0]
    unclear = md.split("**Do not clear p < 0.05**")[1]
    assert "fisher+fluid vs fisher: PSNR (dB) (better, 8/8 pairs better" in clear
    assert "fisher+fluid vs fisher+area: PSNR (dB), SSIM" in unclear
    assert "reference" not in text
    assert "The sign test needs at least 6 pairs, all on one side, to reach p < 0.05; this table has up to 8" in md


def test_the_paired_table_says_when_too_few_pairs_can_never_clear_p_005():
    assert min_pairs_for_sign_test(0.05) == 6 and sign_test_p(5, 0) >= 0.05 > sign_test_p(6, 0)
    assert min_pairs_for_sign_test(0.01) == 8
    rows = [row("fisher", "a", 0, 20.0, 1e-3), row("fisher+fluid", "a", 0, 23.0957, 1e-3)]  # one pair
    md = build_tables(rows)["paired"][0]
    assert "with 1 pair the best possible sign-test p is 1.0000, so no sign test here can clear p < 0.05" in md
    # without a comparable pair there is no paired table
    assert "paired" not in build_tables([row("fisher", "a", 0, 20.0, 1e-3), row("random", "a", 0, 20.0, 1e-3)])
    assert paired_table([row("fisher", "a", 0, 20.0, 1e-3)]) is None


def test_shuffled_controls_have_single_direction_variants_and_area_ones_do_not():
    assert split_method("fisher+shuffled@-x") == ("fisher+shuffled", "-x")
    with pytest.raises(ValueError, match="run no probe"):
        split_method("fisher+area@-x")


def test_ablation_table_names_what_re_ranks_the_shortlist():
    rows = [
        row(m, "a", 0, 20.0, 1e-3) for m in ("random+area", "fisher", "fisher+shuffled", "fisher+area", "fisher+fluid")
    ]
    body = {r[0]: r for r in csv.reader(build_tables(rows)["ablation_random"][1].splitlines())}
    assert list(body)[1:] == ["random+area", "fisher", "fisher+fluid", "fisher+area", "fisher+shuffled"]
    assert body["fisher+area"][1:3] == ["fisher top-K", "no: coverage sum w_g (D_g = 1)"]
    assert body["fisher+shuffled"][2] == "D_g shuffled across the Gaussians"
    assert (
        body["random+area"][1] == "random K"
        and body["fisher+fluid"][2] == "yes"
        and body["fisher"][1:3] == ["all", "no"]
    )
