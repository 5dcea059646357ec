"""The fault a run stops with (:class:`SimulationDiverged`), in a module of its own that loads no Taichi: a stored
result or a command's error handling names it without starting the engine (:mod:`fluidsim.simulation` raises it)."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .solver import StepStats


class SimulationDiverged(RuntimeError):
    """The simulation became unphysical at ``step``; the message says why and what to change."""

    def __init__(self, step: int, reason: str):
        super().__init__(f"simulation diverged at step {step}: {reason}")
        self.step = step
        self.reason = reason
        self.history: list[StepStats] = []
