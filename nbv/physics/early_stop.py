"""Stopping a probe once its running D_g^(IC) has converged (paper Eq. 2-3: D_g^(IC) is a running mean over the
steps, so once the fluid has passed the object the later steps barely move it).

No paper equation is changed: the paper runs every probe for a fixed 750 steps. This module decides, every
``window`` steps, whether the steps since the last check moved the probe's per-Gaussian means by less than
``tolerance`` of their sum (:func:`relative_change`, an L1 norm over the Gaussians, so changes of opposite sign never
cancel); a probe that passes stops there, and records the step it stopped at. ``fluidsim.simulation.run`` takes the
check as its ``stop`` predicate.

The rule and its tolerance were chosen against the uncut run (``fluidgs bench probes``, docs/performance.md "Stopping
a probe early"): the view ranking, the per-Gaussian D_g and D-bar / D-bar_empty of the stopped probes against the
probes run to the end.

Example:
    >>> rule = StopRule(tolerance=0.01, window=50, min_steps=150)
    >>> check = ConvergenceCheck(rule, lambda: acc.means())  # doctest: +SKIP
    >>> run(solver, 750, on_step=..., stop=lambda s, st: check(st.step + 1))  # doctest: +SKIP
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class StopRule:
    """When a probe's running D_g^(IC) counts as converged.

    Attributes:
        tolerance: the largest relative L1 change of the running means over one window (:func:`relative_change`);
            0: never stop early (every probe runs its full steps).
        window: steps between two checks (and the span the change is measured over).
        min_steps: no check before this many steps (the slab has not reached the object yet).
    """

    tolerance: float = 0.0
    window: int = 50
    min_steps: int = 150

    def __post_init__(self) -> None:
        if not (math.isfinite(self.tolerance) and self.tolerance >= 0):
            raise ValueError(f"stop tolerance must be a finite number >= 0 (0: off), got {self.tolerance!r}")
        for name in ("window", "min_steps"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"stop {name} must be an integer >= 1 (steps), got {v!r}")

    @property
    def enabled(self) -> bool:
        return self.tolerance > 0

    def checks_at(self, steps_run: int) -> bool:
        """Whether a check falls after ``steps_run`` steps (a multiple of ``window`` from ``min_steps`` on)."""
        return self.enabled and steps_run >= self.min_steps and steps_run % self.window == 0


def relative_change(previous: np.ndarray, current: np.ndarray) -> float:
    """sum_g |D_g(now) - D_g(before)| / sum_g D_g(now): how much a window moved the running means (inf while no
    Gaussian has a sample yet, or had none at the previous check).

    Args:
        previous, current: [G] running means D_g^(IC), 1/s.
    """
    prev = np.asarray(previous, np.float64)
    cur = np.asarray(current, np.float64)
    total = float(np.abs(cur).sum())
    if total <= 0 or not np.any(prev):
        return math.inf
    return float(np.abs(cur - prev).sum()) / total


class ConvergenceCheck:
    """The stop predicate of one probe: called with the steps run so far, it reads the running means
    (``means()``, [G]) at each check of ``rule`` and returns True once a window changed them by at most the
    tolerance. ``stopped_at`` holds the steps run when it did (None: it never stopped the probe)."""

    def __init__(self, rule: StopRule, means: Callable[[], np.ndarray]):
        self.rule = rule
        self.means = means
        self.previous: np.ndarray | None = None
        self.changes: list[tuple[int, float]] = []  # (steps run, relative change) at each check
        self.stopped_at: int | None = None

    def __call__(self, steps_run: int) -> bool:
        rule = self.rule
        if not rule.enabled or steps_run % rule.window or steps_run < rule.min_steps - rule.window:
            return False
        current = np.asarray(self.means(), np.float64)
        previous, self.previous = self.previous, current
        if previous is None or steps_run < rule.min_steps:
            return False
        change = relative_change(previous, current)
        self.changes.append((steps_run, change))
        if change <= rule.tolerance:
            self.stopped_at = steps_run
            return True
        return False
