"""Velocity / Reynolds-number sweep of the geometry divergence D-bar (paper Sec. 4, "flow speed" study).

For each inflow speed U the probes run with a CFL-constant time step over the same physical duration:

- Delta t(U) = Delta t_base * U_base / U (U_base = the config's speed, by default the paper's lambda = 3 m/s;
  Delta t_base = the config's dt),
  so U Delta t / (2 r), the Courant number, stays that of the base setting;
- steps(U) = round(T / Delta t(U)) with T = steps_base * Delta t_base;
- Re = rho U L / mu with rho the rest density (kg/m^3), mu the dynamic viscosity (Pa s) and L the largest
  extent of the probe domain (m; the -x probe's domain, or the first probe's).

With a second Gaussian set ("OTHER") the gap Delta = D-bar(OTHER) - D-bar is reported per U. Both sets use
the same scene -> metre scale (with ``scale="auto"`` it is resolved on the first set), because D-bar grows
with the fourth power of the scale and a set with a missing part would otherwise be scaled differently.
"""

from __future__ import annotations

import csv
import logging
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from nbv.io import atomic_output
from nbv.lists import parse_list
from nbv.physics import PhysicsConfig, PhysicsResult, scene_transform, simulate_gaussians

log = logging.getLogger(__name__)

U_BASE = 3.0  # m/s, the paper's inflow speed lambda
PAPER_VELOCITIES = (3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 20.0, 50.0)  # m/s, the speeds of the paper's sweep


@dataclass(frozen=True)
class SweepStep:
    """One speed of the sweep: U (m/s), Delta t (s), steps, and the physical duration steps * Delta t (s)."""

    speed: float
    dt: float
    steps: int

    @property
    def duration(self) -> float:
        return self.steps * self.dt


@dataclass(frozen=True)
class SweepPoint:
    """A sweep result row: U m/s, Re, Delta t s, steps, D-bar m^4/s, D-bar of OTHER and the gap (or None)."""

    speed: float
    reynolds: float
    dt: float
    steps: int
    dbar: float
    dbar_other: float | None = None

    @property
    def gap(self) -> float | None:
        return None if self.dbar_other is None else self.dbar_other - self.dbar


def parse_velocities(text: str | Sequence[float]) -> tuple[float, ...]:
    """'3,4,5' or a list -> positive speeds in m/s (ValueError naming --velocities otherwise)."""
    return parse_list(text, float, "--velocities", positive=True, what="speed")


def schedule(velocities: Sequence[float], dt_base: float, steps_base: int, u_base: float = U_BASE) -> list[SweepStep]:
    """CFL-constant time steps over the base duration T = steps_base * dt_base.

    Args:
        velocities: speeds U, m/s (> 0).
        dt_base: Delta t at ``u_base``, s.
        steps_base: steps at ``u_base``.
        u_base: the reference speed, m/s.
    Returns:
        one SweepStep per speed, in the given order.
    """
    if dt_base <= 0 or steps_base < 1 or u_base <= 0:
        raise ValueError(f"sweep base must have dt > 0, steps >= 1, U > 0; got {dt_base}, {steps_base}, {u_base}")
    total = steps_base * dt_base
    out = []
    for u in velocities:
        if not u > 0:
            raise ValueError(f"sweep speeds must be > 0 m/s, got {u}")
        dt = dt_base * u_base / u
        out.append(SweepStep(float(u), dt, max(1, round(total / dt))))
    return out


def reynolds(speed: float, length: float, density: float, viscosity: float) -> float:
    """Re = rho U L / mu (density kg/m^3, speed m/s, length m, dynamic viscosity Pa s); inf for mu = 0."""
    return float("inf") if viscosity == 0 else density * speed * length / viscosity


def domain_length(result: PhysicsResult) -> float:
    """L: the largest extent of the -x probe's domain (else the first probe's), m."""
    d = "-x" if "-x" in result.domains else result.directions[0]
    lo, hi = result.domains[d]
    return float(np.max(np.asarray(hi) - np.asarray(lo)))


def run_sweep(gaussians, config: PhysicsConfig, velocities: Sequence[float], other=None,
              progress: bool = True) -> list[SweepPoint]:
    """D-bar (and D-bar of ``other`` and the gap) at each speed, CFL-constant Delta t, same duration.

    Args:
        gaussians: GaussianSet (scene units). other: an optional second GaussianSet, simulated at the
            scale resolved on ``gaussians``.
        config: the base settings (its dt and steps are the base at U_base = ``config.speed``); the
            empty-scene reference is not run.
        velocities: speeds, m/s.
        progress: a bar over the speeds (and the per-probe bars).
    Returns:
        one SweepPoint per speed.
    """
    plan = schedule(velocities, config.dt, config.steps, u_base=config.speed)
    if config.scale == "auto":
        config = replace(config, scale=scene_transform(gaussians, config).scale)
    points = []
    for st in tqdm(plan, desc="sweep", unit="speed", disable=not progress):
        cfg = replace(config, speed=st.speed, dt=st.dt, steps=st.steps, empty_reference=False)
        res = simulate_gaussians(gaussians, cfg, progress=progress)
        other_dbar = simulate_gaussians(other, cfg, progress=progress).dbar if other is not None else None
        re = reynolds(st.speed, domain_length(res), config.rest_density, config.viscosity)
        points.append(SweepPoint(st.speed, re, st.dt, st.steps, res.dbar, other_dbar))
        log.info("U = %g m/s: Re = %.4g, dt = %.3g s, %d steps, D-bar = %.4g", st.speed, re, st.dt, st.steps, res.dbar)
    return points


CSV_FIELDS = ("speed_m_s", "reynolds", "dt_s", "steps", "dbar_m4_s", "dbar_other_m4_s", "gap_m4_s")


def write_csv(path: str | Path, points: Sequence[SweepPoint]) -> Path:
    """Write the sweep as CSV atomically (columns: :data:`CSV_FIELDS`; empty cells where no OTHER)."""
    p = Path(path)
    with atomic_output(p) as tmp, open(tmp, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(CSV_FIELDS)
        for pt in points:
            w.writerow([f"{pt.speed:g}", f"{pt.reynolds:.6g}", f"{pt.dt:.6g}", pt.steps, f"{pt.dbar:.6g}",
                        "" if pt.dbar_other is None else f"{pt.dbar_other:.6g}",
                        "" if pt.gap is None else f"{pt.gap:.6g}"])
    return p
