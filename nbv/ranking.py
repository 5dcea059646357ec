"""Rank correlation, the one owner of Spearman in ``nbv``: average ranks, Pearson, Spearman, and the top-k size the
ranking tables report (:data:`TOP_K`).

Ranks are average ranks (ties share the mean rank), so Spearman = Pearson of the average ranks, as in
``scipy.stats.spearmanr``. This module needs numpy only, so any layer of ``nbv`` may read it.

Example:
    >>> spearman([1, 2, 3], [10, 30, 20])
    0.5
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

TOP_K = 5  # the top-k lists that ranking agreements compare


def average_ranks(x: Sequence[float]) -> np.ndarray:
    """1-based ranks of ``x`` ascending, ties given their mean rank ([n] float64)."""
    a = np.asarray(x, np.float64).reshape(-1)
    order = np.argsort(a, kind="mergesort")
    sorted_a = a[order]
    starts = np.r_[0, np.flatnonzero(np.diff(sorted_a) != 0) + 1]
    ends = np.r_[starts[1:], len(a)]
    ranks = np.empty(len(a))
    ranks[order] = np.repeat(0.5 * (starts + ends - 1) + 1.0, ends - starts)
    return ranks


def pearson(a: Sequence[float], b: Sequence[float]) -> float:
    """Pearson correlation; NaN when either side is constant or has fewer than 2 values."""
    x, y = np.asarray(a, np.float64).reshape(-1), np.asarray(b, np.float64).reshape(-1)
    if x.shape != y.shape:
        raise ValueError(f"pearson: {x.size} values against {y.size}")
    if x.size < 2:
        return math.nan
    x, y = x - x.mean(), y - y.mean()
    den = math.sqrt(float(x @ x) * float(y @ y))
    return float(x @ y) / den if den > 0 else math.nan


def spearman(a: Sequence[float], b: Sequence[float]) -> float:
    """Spearman rank correlation (Pearson of the average ranks); NaN when either side is constant."""
    return pearson(average_ranks(a), average_ranks(b))
