"""Solver configuration: one frozen dataclass, validated once (Bender & Koschier 2017 defaults).

Defaults follow SPlisHSPlasH's DFSPH and the paper's Table 2: particle radius 0.025 m, support radius
4 r, rest density 1000 kg/m^3, dynamic viscosity 10 Pa s, dt 0.002 s, average density error 0.01 %,
average divergence error 0.1 %, 2 to 100 density-solver iterations (at least 1 for the divergence
solver), warm start on.
"""

from __future__ import annotations

import math
from collections.abc import Collection
from dataclasses import dataclass, fields
from typing import Any

TIME_STEP_MODES = ("fixed", "cfl")
PRECISIONS = ("f32", "f64")
# The solver's grid extends 4 spacings + h past the domain box; fluid may go at most this far out.
RETIRE_MARGIN_MAX = 4.0
# the smallest time step, s: below it a run needs over 1e8 steps per simulated second and the pressure solver's
# 1 / dt^2 factors reach the float32 range's end (1 / dt^2 overflows below 5e-20 s)
MIN_DT = 1.0e-8
# the most time steps of one run: the paper's probes run 750; a million keeps a run's per-step statistics (a few
# hundred bytes a step, in memory and in its file) and its time within reach
MAX_STEPS = 1_000_000


def check_known_keys(config_type: type, keys, where: str = "") -> None:
    """Raises ValueError naming the ``keys`` that are no field of the dataclass ``config_type``, and the valid keys;
    ``where`` starts the message (the field that holds a nested dict, say). Pure Python, for every package's configs.

    Example:
        >>> check_known_keys(SolverConfig, ["dt", "viscosity"])
    """
    known = {f.name for f in fields(config_type)}
    bad = sorted(set(keys) - known)
    if bad:
        raise ValueError(f"{where}unknown {config_type.__name__} keys {bad}; valid keys: {sorted(known)}")


def check_choices(config: Any, choices: dict[str, Collection], owner: str = "") -> None:
    """Raises ValueError when a field of ``config`` holds a value that is not among its choices (``choices`` maps
    field names to the allowed values); the message starts with ``owner`` ("TrainConfig.", say), then the field.

    Example:
        >>> check_choices(SolverConfig(), {"time_step": TIME_STEP_MODES, "precision": PRECISIONS})
    """
    for name, allowed in choices.items():
        value = getattr(config, name)
        if value not in allowed:
            raise ValueError(f"{owner}{name} must be one of {list(allowed)}, got {value!r}")


def _finite(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    return float(value)


def _positive(name: str, value: Any) -> float:
    v = _finite(name, value)
    if v <= 0.0:
        raise ValueError(f"{name} must be > 0, got {value!r}")
    return v


def _vec3(name: str, value: Any) -> tuple[float, float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise ValueError(f"{name} must be a list of 3 numbers [x, y, z], got {value!r}")
    return tuple(_finite(f"{name}[{i}]", c) for i, c in enumerate(value))  # type: ignore[return-value]


def _int_at_least(name: str, value: Any, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
    return value


@dataclass(frozen=True)
class SolverConfig:
    """Physical and numerical parameters of a DFSPH run.

    Attributes:
        particle_radius: r, metres; particle spacing is 2 r.
        support_factor: h / r; the SPH support radius is h = support_factor * r (default 4).
        rest_density: rho_0, kg/m^3.
        viscosity: dynamic viscosity mu, Pa s, fluid-fluid.
        boundary_viscosity: dynamic viscosity for fluid-boundary friction, Pa s (None: same as viscosity).
        gravity: m/s^2, Y-up.
        dt: fixed time step, or the initial one in CFL mode, seconds.
        time_step: "fixed" or "cfl" (dt = cfl_factor * 2 r / max speed, clamped to [dt_min, dt_max]).
        max_density_error: average density error tolerance, percent of rho_0.
        max_divergence_error: average divergence error tolerance, percent of rho_0 per second of dt.
        min_iterations / max_iterations: iteration bounds of the density solver; max_iterations also
            bounds the divergence solver.
        min_divergence_iterations: minimum iterations of the divergence solver (SPlisHSPlasH runs at
            least one and applies min_iterations to the density solver only).
        divergence_solver: run the divergence-free solver (B&K 2017 Alg. 2).
        warm_start: warm-start both solvers from the previous step's stiffness.
        divergence_warm_start: with ``warm_start``, also warm-start the divergence solver (SPlisHSPlasH does).
            Off, that solve starts from the neighbourhood pass's source and saves two passes over the
            neighbour lists per step; on the paper's probes it still converges in its one minimum
            iteration (measured), so only set it off where that holds.
        estimator_radius: h_r of paper Eq. 1, metres (neighbours within this distance).
        estimator_kernel_radius: h_k of paper Eq. 1, metres (kernel support for grad W).
        max_speed: a fluid speed above this (m/s) stops the run as diverged.
        max_cfl: the largest CFL number v dt / (2 r) a run may reach, with v the speed bound of
            :func:`fluidsim.simulation.speed_bound` (inflow plus free fall); a run above it is refused before
            its first step. 1 = a particle may cross one spacing per step, twice the adaptive mode's cfl_factor.
        max_capped_steps: stop when a solver hits max_iterations this many steps in a row.
        max_neighbors: initial neighbour-list capacity per particle (None: from the rest lattice, the
            neighbours within h of a lattice point plus an eighth); the lists then follow the largest count
            (grow at once, shrink when much too large), because padded rows cost memory traffic in every
            list pass.
        retire_margin: fluid is retired once it is this many particle spacings outside the domain box
            (default 2: past both layers of the default walls; 0 retires at the box face). Fast splash
            particles cross the face by up to about 0.15 spacing before the wall pushes them back.
        precision: "f32" or "f64" for the particle arrays.
    """

    particle_radius: float = 0.025
    support_factor: float = 4.0
    rest_density: float = 1000.0
    viscosity: float = 10.0
    boundary_viscosity: float | None = None
    gravity: tuple[float, float, float] = (0.0, -9.81, 0.0)
    dt: float = 0.002
    time_step: str = "fixed"
    cfl_factor: float = 0.5
    dt_min: float = 1.0e-5
    dt_max: float = 0.005
    max_density_error: float = 0.01
    max_divergence_error: float = 0.1
    min_iterations: int = 2
    min_divergence_iterations: int = 1
    max_iterations: int = 100
    divergence_solver: bool = True
    warm_start: bool = True
    divergence_warm_start: bool = True
    estimator_radius: float = 0.1
    estimator_kernel_radius: float = 0.1
    max_speed: float = 200.0
    max_cfl: float = 1.0
    max_capped_steps: int = 20
    max_neighbors: int | None = None
    retire_margin: float = 2.0
    precision: str = "f32"

    def __post_init__(self) -> None:
        _positive("particle_radius", self.particle_radius)
        if _positive("support_factor", self.support_factor) < 2.0:
            raise ValueError(f"support_factor must be >= 2 (h >= one particle spacing), got {self.support_factor}")
        _positive("rest_density", self.rest_density)
        if _finite("viscosity", self.viscosity) < 0:
            raise ValueError(f"viscosity must be >= 0 Pa s, got {self.viscosity}")
        if self.boundary_viscosity is not None and _finite("boundary_viscosity", self.boundary_viscosity) < 0:
            raise ValueError(f"boundary_viscosity must be >= 0 Pa s, got {self.boundary_viscosity}")
        object.__setattr__(self, "gravity", _vec3("gravity", self.gravity))
        _positive("dt", self.dt)
        for name in ("dt", "dt_min"):
            if getattr(self, name) < MIN_DT:
                raise ValueError(
                    f"{name} must be at least {MIN_DT:g} s, got {getattr(self, name):g}: the time step is too small, "
                    f"not too large (a step below {MIN_DT:g} s needs more than {1 / MIN_DT:.0e} steps per simulated "
                    "second, and the pressure solver's 1/dt^2 overflows); use a dt of 1e-4 to 5e-3 s"
                )
        check_choices(self, {"time_step": TIME_STEP_MODES})
        _positive("cfl_factor", self.cfl_factor)
        if _positive("dt_min", self.dt_min) > _positive("dt_max", self.dt_max):
            raise ValueError(f"dt_min ({self.dt_min}) must be <= dt_max ({self.dt_max})")
        _positive("max_density_error", self.max_density_error)
        _positive("max_divergence_error", self.max_divergence_error)
        _int_at_least("min_iterations", self.min_iterations, 0)
        _int_at_least("min_divergence_iterations", self.min_divergence_iterations, 0)
        _int_at_least("max_iterations", self.max_iterations, 1)
        for name in ("min_iterations", "min_divergence_iterations"):
            if getattr(self, name) > self.max_iterations:
                raise ValueError(f"{name} ({getattr(self, name)}) must be <= max_iterations ({self.max_iterations})")
        for name in ("divergence_solver", "warm_start", "divergence_warm_start"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be true or false, got {getattr(self, name)!r}")
        _positive("estimator_radius", self.estimator_radius)
        _positive("estimator_kernel_radius", self.estimator_kernel_radius)
        _positive("max_speed", self.max_speed)
        _positive("max_cfl", self.max_cfl)
        _int_at_least("max_capped_steps", self.max_capped_steps, 1)
        if self.max_neighbors is not None:
            _int_at_least("max_neighbors", self.max_neighbors, 8)
        if not 0.0 <= _finite("retire_margin", self.retire_margin) <= RETIRE_MARGIN_MAX:
            raise ValueError(
                f"retire_margin must be in [0, {RETIRE_MARGIN_MAX}] particle spacings (the simulation "
                f"grid reaches {RETIRE_MARGIN_MAX} spacings past the domain), got {self.retire_margin}"
            )
        check_choices(self, {"precision": PRECISIONS})

    @property
    def spacing(self) -> float:
        """Particle spacing 2 r, metres."""
        return 2.0 * self.particle_radius

    @property
    def support_radius(self) -> float:
        """SPH support radius h = support_factor * r, metres."""
        return self.support_factor * self.particle_radius

    @property
    def wall_viscosity(self) -> float:
        """Fluid-boundary dynamic viscosity, Pa s."""
        return self.viscosity if self.boundary_viscosity is None else self.boundary_viscosity

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls) if not f.name.startswith("_"))
