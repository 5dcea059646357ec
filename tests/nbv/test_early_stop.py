"""The early stop of a probe (nbv.physics.early_stop): the rule, the relative change and the check's steps."""

import math

import numpy as np
import pytest

from nbv.physics.early_stop import ConvergenceCheck, StopRule, relative_change


def test_relative_change_is_the_l1_move_over_the_sum_and_inf_before_any_sample():
    assert relative_change([1.0, 2.0, 0.0], [1.0, 2.5, 0.5]) == pytest.approx(1.0 / 4.0)
    assert relative_change([1.0, -1.0], [0.0, 0.0]) == math.inf  # nothing reached yet
    assert relative_change([0.0, 0.0], [1.0, 1.0]) == math.inf  # the first samples arrived in this window


def test_the_check_reads_the_means_once_per_window_and_stops_when_the_change_is_small():
    rule = StopRule(tolerance=0.02, window=10, min_steps=30)
    values = iter([np.array([1.0, 1.0]), np.array([1.1, 1.0]), np.array([1.11, 1.0])])
    reads = []

    def means():
        reads.append(1)
        return next(values)

    check = ConvergenceCheck(rule, means)
    stop = next(n for n in range(1, 61) if check(n))
    # read at 20 (the baseline), 30 (change 0.1 / 2.1 > 0.02) and 40 (0.01 / 2.11 < 0.02): stops at 40
    assert stop == 40 and check.stopped_at == 40 and len(reads) == 3
    assert [n for n, _ in check.changes] == [30, 40]


def test_a_zero_tolerance_never_stops_and_bad_rules_are_refused():
    check = ConvergenceCheck(StopRule(), lambda: np.ones(3))
    assert not any(check(n) for n in range(1, 1000))
    with pytest.raises(ValueError, match="tolerance"):
        StopRule(tolerance=-0.1)
    with pytest.raises(ValueError, match="window"):
        StopRule(tolerance=0.1, window=0)
