"""The force of each probe's fluid on the solid: its time series, time mean, impulse, drag / lift / side parts and
coefficients.

The engine reports, per step, the mean force of the fluid on the solid (:mod:`fluidsim.forces`: the reactions of the
Akinci boundary's pressure and viscosity terms, N, simulation frame, Y up); it is stored in each probe's step
statistics (``solid_force_x/y/z``). Here, per probe:

- the **time mean** over the second half of the run, sum F dt / sum dt (the first half holds the impact);
- the **impulse** over the whole run, sum F dt, N s;
- its parts: **drag** along the probe's flow, **lift** along +y (up) and **side** along up x flow (the remaining
  horizontal axis). The ``-y`` probe falls along -y: its drag is the downward force, it has no lift, and its side
  part is the horizontal force's size;
- the **coefficients** C = 2 F / (rho_0 U^2 A) of each part, with U the probe's inflow speed and A the solid's
  projected area normal to the flow: the area of the cells of one particle spacing that the solid's particles occupy
  when projected along the flow (each particle stands for a cube of one spacing). The ``-y`` probe starts at rest, so
  it has no inflow speed and no coefficient.

The per-step force is noisy (a DFSPH step's pressure impulse depends on how many iterations met the tolerance; on a
settled tank its step-to-step spread is about the size of its mean), so read the time mean, not a step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fluidsim.directions import DIRECTIONS

FORCE_COLUMNS = ("solid_force_x", "solid_force_y", "solid_force_z")
FORCE_WINDOW_S = 0.05  # s: the moving mean of a force series (longer than the 20-step DFSPH pressure oscillation)
UP = np.array([0.0, 1.0, 0.0])


def flow_axis(direction: str) -> np.ndarray:
    """(3,) unit vector of a probe's flow, e.g. ``-x`` -> (-1, 0, 0)."""
    if direction not in DIRECTIONS:
        raise ValueError(f"unknown probe direction {direction!r}; use one of {DIRECTIONS}")
    v = np.zeros(3)
    v["xyz".index(direction[1])] = -1.0 if direction[0] == "-" else 1.0
    return v


def force_series(stats) -> np.ndarray | None:
    """(S, 3) float64 force on the solid per step, N, from a probe's structured step statistics; None for statistics
    written before the engine reported forces."""
    names = getattr(getattr(stats, "dtype", None), "names", None) or ()
    if not all(c in names for c in FORCE_COLUMNS):
        return None
    return np.stack([np.asarray(stats[c], np.float64) for c in FORCE_COLUMNS], axis=1).reshape(-1, 3)


def projected_area(points: np.ndarray, flow: np.ndarray, spacing: float) -> float:
    """The area of the solid seen along ``flow``, m^2: the cells of one spacing, on the plane normal to the flow, that
    the particles' projections fall in, times spacing^2 (for a flow along an axis, exactly the lattice's silhouette).

    Args:
        points: (M, 3) solid particles, m. flow: (3,) unit vector. spacing: particle spacing, m.
    Example:
        >>> pts = np.stack(np.meshgrid(*[np.arange(4) * 0.1] * 3, indexing="ij"), -1).reshape(-1, 3)
        >>> round(projected_area(pts, np.array([1.0, 0, 0]), 0.1), 6)  # a 4 x 4 face of 0.1 m cells
        0.16
    """
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    if len(pts) == 0:
        return 0.0
    flow = np.asarray(flow, np.float64) / np.linalg.norm(flow)
    helper = np.eye(3)[int(np.argmin(np.abs(flow)))]
    e1 = np.cross(flow, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(flow, e1)
    uv = np.stack([pts @ e1, pts @ e2], axis=1)
    cells = np.round((uv - uv.min(0)) / spacing).astype(np.int64)  # a lattice's points fall on whole cells
    return float(len(np.unique(cells, axis=0))) * spacing * spacing


@dataclass(frozen=True)
class ProbeForces:
    """The force of one probe's fluid on the solid.

    Attributes:
        direction: the probe. series: (S, 3) N per step (the step's mean force). dt: (S,) s.
        mean: (3,) N, the time mean over the second half of the run. impulse: (3,) N s over the whole run.
        speed: the inflow speed U, m/s (0 for the -y probe). area: the projected area A, m^2. rest_density: kg/m^3.
        flow: (3,) the flow's unit vector.
    """

    direction: str
    series: np.ndarray
    dt: np.ndarray
    mean: np.ndarray
    impulse: np.ndarray
    speed: float
    area: float
    rest_density: float
    flow: np.ndarray

    def peak_drag(self) -> tuple[float, float]:
        """(the largest drag of the :data:`FORCE_WINDOW_S` moving mean, N; the time it ends at, s): the impact's drag,
        while the slab passes the solid (the second half of a long run holds the water left in the closed box)."""
        if len(self.series) == 0:
            return 0.0, 0.0
        drag = moving_mean(self.series, self.dt) @ self.flow
        k = int(np.argmax(drag))
        t = np.cumsum(self.dt)[len(self.dt) - len(drag) + k]
        return float(drag[k]), float(t)

    @property
    def reached(self) -> bool:
        """Whether the fluid ever pushed on the solid (a probe whose fluid never reaches it has a zero force)."""
        return bool(np.any(self.series != 0.0))

    def parts(self, force=None) -> dict[str, float | None]:
        """{"drag", "lift", "side"} of ``force`` (default the time mean), N; lift None for the -y probe."""
        f = self.mean if force is None else np.asarray(force, np.float64)
        drag = float(f @ self.flow)
        if abs(self.flow @ UP) > 0.5:  # the falling probe: no lift; the horizontal force as side
            return {"drag": drag, "lift": None, "side": float(np.hypot(f[0], f[2]))}
        side_axis = np.cross(UP, self.flow)
        return {"drag": drag, "lift": float(f @ UP), "side": float(f @ side_axis)}

    def coefficients(self) -> dict[str, float | None] | None:
        """C = 2 F / (rho_0 U^2 A) per part of the time mean; None without an inflow speed (the -y probe).

        Raises:
            ValueError: when the projected area is 0 (no solid particle): the coefficient is undefined.
        """
        if self.speed <= 0.0:
            return None
        if not self.area > 0.0:
            raise ValueError(
                f"probe {self.direction}: the solid's projected area is 0, so C = 2F / (rho U^2 A) is undefined"
            )
        q = 0.5 * self.rest_density * self.speed**2 * self.area
        return {k: (None if v is None else v / q) for k, v in self.parts().items()}

    def record(self) -> dict:
        """A JSON-able summary: mean, impulse, parts, coefficients, area, speed, steps."""
        return {
            "mean_N": self.mean.tolist(),
            "impulse_Ns": self.impulse.tolist(),
            "parts_N": self.parts(),
            "coefficients": self.coefficients(),
            "area_m2": self.area,
            "speed_m_s": self.speed,
            "steps": int(len(self.series)),
            "reached": self.reached,
        }


def moving_mean(series: np.ndarray, dt: np.ndarray, window_s: float = FORCE_WINDOW_S) -> np.ndarray:
    """(S - w + 1, 3) the moving mean of ``series`` (S, 3) over w = window_s / median dt steps."""
    series = np.asarray(series, np.float64)
    if len(series) == 0:
        return series
    w = int(min(max(1, round(window_s / float(np.median(dt)))), len(series)))
    c = np.cumsum(np.vstack([np.zeros((1, 3)), series]), axis=0)
    return (c[w:] - c[:-w]) / w


def second_half_mean(series: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """(3,) the dt-weighted mean of ``series`` (S, 3) over its steps S // 2 ..., N (zeros for no step)."""
    half = len(series) // 2
    w = np.asarray(dt, np.float64)[half:]
    if len(w) == 0 or w.sum() <= 0:
        return np.zeros(3)
    return (np.asarray(series, np.float64)[half:] * w[:, None]).sum(0) / w.sum()


def probe_forces(
    direction: str, stats, solid: np.ndarray, spacing: float, speed: float, rest_density: float
) -> ProbeForces | None:
    """The :class:`ProbeForces` of one probe from its step statistics (None when they hold no forces).

    Args:
        direction: the probe. stats: its structured step statistics. solid: (M, 3) solid particles, m.
        spacing: particle spacing, m. speed: the horizontal probes' inflow speed, m/s. rest_density: kg/m^3.
    """
    series = force_series(stats)
    if series is None:
        return None
    dt = np.asarray(stats["dt"], np.float64)
    flow = flow_axis(direction)
    return ProbeForces(
        direction=direction,
        series=series,
        dt=dt,
        mean=second_half_mean(series, dt),
        impulse=(series * dt[:, None]).sum(0),
        speed=0.0 if direction == "-y" else float(speed),
        area=projected_area(solid, flow, spacing),
        rest_density=float(rest_density),
        flow=flow,
    )


def result_forces(result) -> dict[str, ProbeForces]:
    """Per probe of a :class:`nbv.physics.result.PhysicsResult`, its :class:`ProbeForces` (probes without forces in
    their statistics are left out)."""
    cfg = result.config
    out = {}
    for d in result.directions:
        pf = probe_forces(d, result.stats[d], result.solid, 2.0 * cfg.particle_radius, cfg.speed, cfg.rest_density)
        if pf is not None:
            out[d] = pf
    return out


def _n(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.3g}"


def force_lines(forces: dict[str, ProbeForces]) -> list[str]:
    """The lines the commands print: per probe the time-mean drag, lift and side force (N) and their coefficients,
    with how A was taken, and a warning for a probe whose fluid never reached the solid."""
    if not forces:
        return []
    lengths = {len(pf.series) for pf in forces.values()}
    steps = max(lengths)
    # probes stopped early (nbv.physics.early_stop) ran fewer steps: each mean is over the second half of its own
    window = f"steps {steps // 2}-{steps}" if len(lengths) == 1 else "the second half of each probe's steps"
    lines = [
        f"forces on the solid (N, time mean over {window}; C = 2F / (rho0 U^2 A), A = the solid "
        "particles' projected area normal to the flow, in cells of one spacing; the peak drag is the largest of a "
        f"{FORCE_WINDOW_S:g} s moving mean, the impact: by the second half of a long run the slab has passed and the "
        "mean holds the water left in the closed box, its weight and its buoyancy):"
    ]
    for d, pf in forces.items():
        p = pf.parts()
        c = pf.coefficients()
        coef = (
            "no inflow speed, no C"
            if c is None
            else (
                f"C_d {_n(c['drag'])}, C_l {_n(c['lift'])}, C_s {_n(c['side'])}, A {pf.area:.3g} m^2, "
                f"U {pf.speed:g} m/s"
            )
        )
        ran = "" if len(lengths) == 1 else f" (steps {len(pf.series) // 2}-{len(pf.series)})"
        peak, at = pf.peak_drag()
        c_peak = "" if c is None else f", C_d {peak / (0.5 * pf.rest_density * pf.speed**2 * pf.area):.3g}"
        lines.append(
            f"  probe {d:>3}{ran}: drag {_n(p['drag'])}, lift {_n(p['lift'])}, side {_n(p['side'])} N; {coef}; "
            f"impulse {np.linalg.norm(pf.impulse):.3g} N s; peak drag {peak:.3g} N{c_peak} at t = {at:.2f} s"
        )
        if not pf.reached:
            lines.append(f"    WARNING: the fluid of probe {d} never reached the solid: its force is 0")
    return lines
