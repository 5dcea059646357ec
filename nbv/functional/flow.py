"""One probe's flow as a functional comparison sees it: the force on the solid per step and the fluid velocity field
sampled on a fixed grid at K times; and the errors between two such flows.

The velocity field at a point x is the SPH interpolation v(x) = sum_j V_f v_j W(|x - x_j|, h) (cubic spline, h the
support radius, V_f the fluid particle volume): about v where the fluid is, and going to 0 where there is none (inside
a solid, above the free surface), so a flow that misses a region shows as an error there. The grid
(:class:`SampleGrid`) spans the reference solid's box grown by a quarter of its largest extent on every side (within
the probe's domain), with a point every two particle spacings; the K sampling times are the ends of K equal parts of
the run.

Errors of a flow a against a reference flow b (:func:`flow_errors`):

- ``mean_force``: |F_a - F_b| / |F_b| of the time-mean force vectors (the second half of the run: drag, lift and
  side together), the headline of :mod:`nbv.functional`;
- ``force_l2``: ||F_a - F_b|| / ||F_b|| over the steps and the 3 components, after a moving mean of
  :data:`FORCE_WINDOW_S` over each series (one step's force is noisy; :mod:`nbv.physics.forces`);
- ``drag``: |D_a - D_b| / |D_b| of the time-mean drags (the second half of the run, along the flow);
- ``lift``: |L_a - L_b| / |F_b| of the time-mean lift (the side force for the -y probe), over the size of the
  reference's time-mean force (a lift near 0 would make its own relative error meaningless);
- ``velocity_l2``: ||v_a - v_b|| / ||v_b|| over the grid points, the K times and the 3 components.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fluidsim.kernels import cubic_w_np
from nbv.physics.forces import UP, flow_axis, moving_mean, second_half_mean

SAMPLE_TIMES = 8  # K
GRID_SPACINGS = 2  # grid step, in particle spacings
GRID_MARGIN = 0.25  # the grid's margin around the reference solid, in its largest extent


@dataclass(frozen=True)
class SampleGrid:
    """Where and when the velocity field is sampled.

    Attributes:
        points: (P, 3) m. step: the grid's spacing, m. lo, hi: (3,) its box, m. steps: the K completed step counts.
    """

    points: np.ndarray
    step: float
    lo: np.ndarray
    hi: np.ndarray
    steps: tuple[int, ...]

    @classmethod
    def around(cls, solid: np.ndarray, domain_min, domain_max, spacing: float, steps: int) -> SampleGrid:
        """The grid around ``solid`` (M, 3) within the probe's domain, sampled at the ends of K parts of ``steps``."""
        lo, hi = solid.min(0), solid.max(0)
        grow = GRID_MARGIN * float((hi - lo).max())
        lo = np.maximum(lo - grow, domain_min)
        hi = np.minimum(hi + grow, domain_max)
        step = GRID_SPACINGS * spacing
        axes = [np.arange(lo[d], hi[d] + 1e-9, step) for d in range(3)]
        points = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        count = min(SAMPLE_TIMES, steps)
        times = tuple(sorted({max(1, round(steps * (k + 1) / count)) for k in range(count)}))
        return cls(points, step, lo, hi, times)

    def describe(self, dt: float) -> str:
        """One line: the grid's box, step and size, and the sampling times."""
        dims = "x".join(str(len(np.arange(self.lo[d], self.hi[d] + 1e-9, self.step))) for d in range(3))
        return (
            f"velocity sampled on a {dims} grid every {self.step:.3g} m over "
            f"[{', '.join(f'{v:.2f}' for v in self.lo)}]-[{', '.join(f'{v:.2f}' for v in self.hi)}] m, after steps "
            f"{', '.join(map(str, self.steps))} (t = {', '.join(f'{s * dt:.2f}' for s in self.steps)} s at dt {dt:g} s)"
        )


@dataclass(frozen=True)
class FlowRecord:
    """A probe's flow: forces (S, 3) N and dt (S,) s per step; velocities (K, P, 3) m/s on the grid."""

    forces: np.ndarray
    dt: np.ndarray
    velocities: np.ndarray


def sph_velocity(points: np.ndarray, x: np.ndarray, v: np.ndarray, h: float, volume: float) -> np.ndarray:
    """(P, 3) the SPH interpolation sum_j V v_j W(|p - x_j|, h) at ``points`` (P, 3) from particles x, v (N, 3).

    Example:
        >>> sph_velocity(np.zeros((1, 3)), np.zeros((1, 3)), np.ones((1, 3)), 0.1, 1.0)[0, 0] > 0
        True
    """
    from scipy.spatial import cKDTree  # noqa: PLC0415

    points = np.asarray(points, np.float64)
    if len(x) == 0 or len(points) == 0:
        return np.zeros((len(points), 3))
    pairs = cKDTree(points).sparse_distance_matrix(cKDTree(np.asarray(x, np.float64)), h, output_type="coo_matrix")
    wv = (volume * cubic_w_np(pairs.data, h))[:, None] * np.asarray(v, np.float64)[pairs.col]
    return np.stack([np.bincount(pairs.row, weights=wv[:, d], minlength=len(points)) for d in range(3)], 1)


def sph_velocity_np(points: np.ndarray, x: np.ndarray, v: np.ndarray, h: float, volume: float) -> np.ndarray:
    """O(P N) twin of :func:`sph_velocity`."""
    r = np.linalg.norm(np.asarray(points)[:, None, :] - np.asarray(x)[None, :, :], axis=2)
    return volume * cubic_w_np(r, h) @ np.asarray(v, np.float64)


def relative_l2(a: np.ndarray, ref: np.ndarray) -> float:
    """||a - ref|| / ||ref|| (0 when both are 0, inf when only the reference is)."""
    den = float(np.linalg.norm(ref))
    num = float(np.linalg.norm(np.asarray(a, np.float64) - np.asarray(ref, np.float64)))
    if den == 0.0:
        return 0.0 if num == 0.0 else float("inf")
    return num / den


def _drag_lift(force: np.ndarray, direction: str) -> tuple[float, float]:
    flow = flow_axis(direction)
    drag = float(force @ flow)
    if abs(flow @ UP) > 0.5:
        return drag, float(np.hypot(force[0], force[2]))
    return drag, float(force @ UP)


def flow_errors(flow: FlowRecord, ref: FlowRecord, direction: str) -> dict[str, float]:
    """The relative errors of ``flow`` against ``ref`` (module docstring), and both time-mean drags and lifts, N."""
    if flow.forces.shape != ref.forces.shape or flow.velocities.shape != ref.velocities.shape:
        raise ValueError(f"flows of different runs: forces {flow.forces.shape} vs {ref.forces.shape}")
    mean_a, mean_b = second_half_mean(flow.forces, flow.dt), second_half_mean(ref.forces, ref.dt)
    drag_a, lift_a = _drag_lift(mean_a, direction)
    drag_b, lift_b = _drag_lift(mean_b, direction)
    size = float(np.linalg.norm(mean_b))
    return {
        "mean_force": relative_l2(mean_a, mean_b),
        "force_l2": relative_l2(moving_mean(flow.forces, flow.dt), moving_mean(ref.forces, ref.dt)),
        "drag": abs(drag_a - drag_b) / abs(drag_b) if drag_b != 0 else (0.0 if drag_a == 0 else float("inf")),
        "lift": abs(lift_a - lift_b) / size if size > 0 else (0.0 if lift_a == lift_b else float("inf")),
        "velocity_l2": relative_l2(flow.velocities, ref.velocities),
        "drag_N": drag_a,
        "reference_drag_N": drag_b,
        "lift_N": lift_a,
        "reference_lift_N": lift_b,
    }


def run_flow(solid: np.ndarray, setup, config, grid: SampleGrid, progress=None) -> FlowRecord:
    """Run one probe (``setup``, laid out around the reference) against ``solid`` (M, 3) and record its flow.

    Args:
        solid: sim metres. setup: :class:`fluidsim.probes.ProbeSetup`. config: :class:`nbv.physics.PhysicsConfig`.
        grid: where and when to sample the velocity. progress: called with each step's stats.
    """
    from fluidsim.probes import build_probe_solver  # noqa: PLC0415 - Taichi
    from fluidsim.simulation import run  # noqa: PLC0415

    solver = build_probe_solver(solid, setup, config.solver_config(), config.probe_config())
    wanted = set(grid.steps)
    samples = []

    def on_step(s, _stats) -> None:
        if s.step_index in wanted:
            state = s.fluid_state()
            samples.append(sph_velocity(grid.points, state["x"], state["v"], s.h, s.fluid_volume))

    history = run(solver, config.steps, on_step=on_step, progress=progress)
    return FlowRecord(
        forces=np.array([st.solid_force for st in history], np.float64).reshape(-1, 3),
        dt=np.array([st.dt for st in history], np.float64),
        velocities=np.stack(samples) if samples else np.zeros((0, len(grid.points), 3)),
    )
