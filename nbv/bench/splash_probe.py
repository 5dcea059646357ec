"""A probe scene in SPlisHSPlasH's scene format, and the force on the solid in both engines.

A probe (:mod:`fluidsim.probes`, paper Sec. 3.2) is a static solid, a fluid slab moving at the inflow speed and the
closed walls of its domain. :func:`write_probe_scenes` writes it as a SPlisHSPlasH scene (JSON) with its meshes, so
that the reference engine (Bender & Koschier 2017 DFSPH, pysplishsplash) can rerun it:

- the **walls**: a static inverted box (``isWall``) spanning the probe's domain (our walls are two particle layers
  just outside it);
- the **fluid slab**: a ``FluidBlock`` (``denseMode 0``) whose lattice is ours particle for particle (its box widened
  by r per side and cut at our lattice's count, as in :func:`nbv.bench.splash.splash_scene_json`), with the
  probe's initial velocity;
- the **solid**: the surface through the centres of the solid's outer particles, written as ``solid.obj``: the
  union of the particles' cubes (side = one spacing) as a closed voxel surface mesh, moved inward by half a spacing
  (:func:`voxel_surface`). SPlisHSPlasH samples its boundary particles on the mesh, so they sit where ours are; on
  the cubes' faces they sat half a spacing outside ours, and its drag was 4-15 % above ours on blunt bodies (a
  tetrahedron, the Ahmed body). A rigid body with ``isWall: false``;
- the **settings**: this engine's (:func:`nbv.bench.splash.dfsph_scene`); SPlisHSPlasH samples the Akinci et al. 2012
  boundary particles on the meshes.

The force check (:func:`force_check`, ``fluidgs bench forces``) runs one probe in both engines and compares the
time-mean drag over the second half of the run (:func:`nbv.physics.forces.second_half_mean`). SPlisHSPlasH records a
boundary's force only for a dynamic body (``BoundaryModel::addForce``), and its Python binding cannot hand
``getForceAndTorque`` back, so the peer's copy of the scene makes the solid dynamic and its worker
(:mod:`nbv.bench.splash_worker`) reads the force from the body's velocity change over each rigid-body step,
F = m (dv / dt - g), then puts the body back at rest where it started: the fluid always sees a static solid.

Units: metres, seconds, m/s, kg/m^3, Pa s (dynamic viscosity; SPlisHSPlasH's coefficients are kinematic, m^2/s),
newtons.
"""

from __future__ import annotations

import json
import math
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fluidsim.config import SolverConfig
from fluidsim.probes import ProbeConfig, ProbeSetup, build_probe_solver
from fluidsim.scene import lattice_counts
from fluidsim.simulation import run

from . import timed
from .splash import BOX_MESH, dfsph_scene, run_worker, unit_box, write_obj

SOLID_MESH = "solid.obj"
SOLID_BODY = 1  # the solid's index among the scene's rigid bodies (the walls' box is 0)


def voxel_surface(points: np.ndarray, spacing: float, inset: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The surface of the union of the cubes of side ``spacing`` centred on lattice points.

    Every cube face that no other cube covers becomes two triangles, wound counter-clockwise seen from outside;
    vertices are the lattice's cell corners, shared between faces, so the mesh is closed (every edge lies on an even
    number of faces; two cubes touching only along an edge give four). Its volume is M spacing^3.

    With ``inset``, each vertex moves inward by ``inset`` along every distinct normal of the faces it touches (a
    face's vertex along its normal, an edge's along both, a corner's along all three, convex or concave): at half a
    spacing the surface passes through the outer particles' centres (a box of n^3 particles gives a box of
    (n - 1)^3 spacing^3), and a part one particle thick becomes a double sheet through its centres.

    Args:
        points: (M, 3) points on one lattice of spacing ``spacing``, m (the solid of a probe run).
        spacing: the lattice spacing, m.
        inset: how far to move the surface inward, m, at most half a spacing (default 0).
    Returns:
        (vertices (V, 3) float64 m, faces (F, 3) int64).
    Raises:
        ValueError: no points, non-finite points or spacing, or points off the lattice (more than 1e-3 spacings).
    Example:
        >>> v, f = voxel_surface(np.zeros((1, 3)), 0.1)
        >>> len(v), len(f)
        (8, 12)
    """
    p = np.asarray(points, np.float64).reshape(-1, 3)
    if len(p) == 0 or not np.isfinite(p).all():
        raise ValueError(f"the solid needs finite points, got {len(p)} points")
    if not (math.isfinite(spacing) and spacing > 0):
        raise ValueError(f"the spacing must be > 0 m, got {spacing!r}")
    if not 0.0 <= inset <= 0.5 * spacing:
        raise ValueError(f"the inset must lie in [0, spacing / 2] m, got {inset!r}")
    origin = p.min(0)
    steps = (p - origin) / spacing
    cells = np.rint(steps).astype(np.int64)
    if np.abs(steps - cells).max() > 1e-3:
        raise ValueError("the solid's points are not on one lattice of the given spacing (2 r)")
    cells = np.unique(cells, axis=0) + 1  # one empty cell of margin on each side
    occupied = np.zeros(tuple(cells.max(0) + 2), bool)
    occupied[tuple(cells.T)] = True
    quads, normals = [], []
    for axis in range(3):
        u, w = (axis + 1) % 3, (axis + 2) % 3  # (axis, u, w) is right-handed
        for side in (1, -1):
            neighbour = np.roll(occupied, -side, axis=axis)
            faces = np.argwhere(occupied & ~neighbour)
            lo = faces.copy()
            lo[:, axis] += 1 if side > 0 else 0  # the corner plane of the face
            du, dw = np.zeros(3, np.int64), np.zeros(3, np.int64)
            du[u], dw[w] = 1, 1
            ring = [lo, lo + du, lo + du + dw, lo + dw]  # counter-clockwise about +axis
            quads.append(np.stack(ring if side > 0 else ring[::-1], axis=1))
            normals.append(np.full(len(faces), axis * 2 + (side > 0)))
    corners = np.concatenate(quads)  # (Q, 4, 3) corner indices
    keys, inverse = np.unique(corners.reshape(-1, 3), axis=0, return_inverse=True)
    q = inverse.reshape(-1, 4)
    faces = np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
    vertices = origin + (keys - 1.5) * spacing  # corner k of cell c sits at origin + (k - 1/2 - 1) spacing
    if inset:  # each vertex inward along every distinct normal of its faces (the docstring)
        pairs = np.unique(np.stack([q.reshape(-1), np.repeat(np.concatenate(normals), 4)], 1), axis=0)
        unit = np.zeros((6, 3))
        unit[np.arange(6), np.arange(6) // 2] = np.where(np.arange(6) % 2 == 1, 1.0, -1.0)
        shift = np.zeros_like(vertices)
        np.add.at(shift, pairs[:, 0], unit[pairs[:, 1]])
        vertices = vertices - inset * shift
    return vertices, faces.astype(np.int64)


def fluid_block(setup: ProbeSetup, particle_radius: float) -> tuple[list[float], list[float]]:
    """(start, end) of SPlisHSPlasH's ``denseMode 0`` block that holds our slab's lattice particle for particle: its
    first particle 2r inside ``start``, ``round((end - start) / 2r) - 1`` per axis; ours ``floor(L / 2r)`` from
    ``fluid_min + r``."""
    spacing = 2.0 * particle_radius
    counts = lattice_counts(setup.fluid_min, setup.fluid_max, spacing)
    start = np.asarray(setup.fluid_min, np.float64) - particle_radius
    return start.tolist(), (start + (counts + 1) * spacing).tolist()


def probe_scene_json(
    setup: ProbeSetup, config: SolverConfig, steps: int, solid_mesh: str = SOLID_MESH, dynamic: bool = False
) -> dict:
    """SPlisHSPlasH's scene (its JSON format, :func:`nbv.bench.splash.dfsph_scene`) for one probe (module docstring).

    Args:
        setup: the probe's domain, slab and inflow. config: this engine's solver settings of the probe.
        steps: time steps (the scene's ``stopAt`` is steps x dt). solid_mesh: the solid's OBJ, relative to the scene.
        dynamic: make the solid a dynamic rigid body (the force check's copy; SPlisHSPlasH records forces only on
            dynamic bodies, and the worker keeps it at rest).
    """
    solid = {
        "geometryFile": solid_mesh,
        "translation": [0.0, 0.0, 0.0],
        "rotationAxis": [1, 0, 0],
        "rotationAngle": 0,
        "scale": [1.0, 1.0, 1.0],
        "isDynamic": bool(dynamic),
        "isWall": False,
        "samplingMode": 1,  # regular triangle sampling
    }
    if dynamic:  # no collision geometry (the rigid-body solver never moves it: the worker keeps it at rest)
        solid.update({"density": float(config.rest_density), "collisionObjectType": 0})
    block = (*fluid_block(setup, config.particle_radius), setup.velocity)
    return dfsph_scene(config, (setup.domain_min, setup.domain_max), solid, block, stop_at=steps * config.dt)


def scene_name(direction: str) -> str:
    """The scene file of a probe, e.g. ``probe_-x.json``."""
    return f"probe_{direction}.json"


def write_probe_scenes(
    folder: Path,
    solid_points: np.ndarray,
    setups: dict[str, ProbeSetup],
    config: SolverConfig,
    steps: int,
    dynamic: bool = False,
) -> dict[str, Path]:
    """Write one SPlisHSPlasH scene per probe into ``folder``, with ``solid.obj`` (:func:`voxel_surface`, through the
    outer particles' centres) and ``box.obj`` (the unit box the walls scale) beside them.

    Args:
        folder: created when missing. solid_points: (M, 3) the solid, m. setups: {direction: ProbeSetup}.
        config: the probes' solver settings. steps: time steps per probe. dynamic: see :func:`probe_scene_json`.
    Returns:
        {direction: path of its scene}.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    write_obj(folder / SOLID_MESH, *voxel_surface(solid_points, config.spacing, 0.5 * config.spacing))
    write_obj(folder / BOX_MESH, *unit_box())
    out = {}
    for d, setup in setups.items():
        path = folder / scene_name(d)
        path.write_text(json.dumps(probe_scene_json(setup, config, steps, dynamic=dynamic), indent=1) + "\n")
        out[d] = path
    return out


# ----------------------------------------------------------------------------------------------------
# the force check
# ----------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ForceRun:
    """One engine's run of a probe: the force on the solid per step.

    Attributes:
        series: (S, 3) N per step. dt: (S,) s. fluid_particles: the slab's particles. seconds: wall time of the steps.
    """

    series: np.ndarray
    dt: np.ndarray
    fluid_particles: int
    seconds: float


def run_splash_forces(scene: Path, steps: int, threads: int = 2, timeout_s: float = 1800) -> ForceRun:
    """Run a dynamic-solid probe scene (:func:`write_probe_scenes` with ``dynamic=True``) in SPlisHSPlasH (a child
    process, :mod:`nbv.bench.splash_worker`) and read the force on its solid per step.

    Raises:
        RuntimeError: pysplishsplash is missing, crashes or times out (the message says how to install it).
    """
    scene = Path(scene).resolve()
    config = json.loads(scene.read_text())["Configuration"]
    dt = float(config["timeStepSize"])
    job = {"scene_file": str(scene), "dt": dt, "force_body": SOLID_BODY, "gravity": config["gravitation"]}
    with tempfile.TemporaryDirectory(prefix="splash_forces_") as tmp:
        result = run_worker(Path(tmp), job, int(steps), threads, timeout_s)
    series = np.asarray(result["forces"], np.float64).reshape(-1, 3)
    return ForceRun(series, np.full(len(series), dt), int(result["fluid_particles"]), result["steps_s"])


def run_our_forces(
    solid_points: np.ndarray, setup: ProbeSetup, config: SolverConfig, probe: ProbeConfig, steps: int
) -> ForceRun:
    """Run one probe in this engine (Taichi must be initialised) and return the force on the solid per step."""
    solver = build_probe_solver(solid_points, setup, config, probe)
    fluid = int(solver.fluid.active)  # the slab, before any particle retires
    stats, seconds, _ = timed(run, solver, steps)
    return ForceRun(
        np.array([s.solid_force for s in stats], np.float64).reshape(-1, 3),
        np.array([s.dt for s in stats], np.float64),
        fluid,
        seconds,
    )


def passage_steps(solid_points: np.ndarray, setup: ProbeSetup, dt: float) -> int:
    """Time steps of the slab's passage over the solid at the inflow speed: until its front has travelled to the
    solid's downstream side, or its tail to the solid's upstream side, whichever comes first (particle centres).
    The second half of that run is the flow past the solid while the slab still feeds it. Later, the slab's tail
    leaves the solid and the fluid wraps round its back, and the fluid piled up against the downstream wall rebounds
    onto it: a sloshing whose timing neither engine pins down (the two drags agree within about 10 % per 10 steps
    until then, and differ in size and sign once it reaches the window; measured on spheres, tori and turned boxes
    of 2 m, longer than the slab).

    Raises:
        ValueError: the probe has no inflow (the -y probe falls from rest).
    """
    v = np.asarray(setup.velocity, np.float64)
    speed = float(np.linalg.norm(v))
    if speed <= 0:
        raise ValueError(f"probe {setup.direction} has no inflow speed: the force check needs a horizontal probe")
    flow = v / speed
    along = np.asarray(solid_points, np.float64).reshape(-1, 3) @ flow
    ends = np.array([np.asarray(setup.fluid_min, np.float64) @ flow, np.asarray(setup.fluid_max, np.float64) @ flow])
    front, tail = float(ends.max()), float(ends.min())  # the slab's downstream and upstream faces, along the flow
    travel = min(float(along.max()) - front, float(along.min()) - tail)
    return max(2, round(travel / (speed * dt)))


@dataclass(frozen=True)
class ForceCheck:
    """One probe's force on the solid in both engines.

    Attributes:
        direction: the probe. ours, splash: the two runs. mean_ours, mean_splash: (3,) N, the time means over the
        second half of the run. drag_ours, drag_splash: their parts along the flow, N.
    """

    direction: str
    ours: ForceRun
    splash: ForceRun
    mean_ours: np.ndarray
    mean_splash: np.ndarray
    drag_ours: float
    drag_splash: float

    @property
    def ratio(self) -> float:
        """drag_ours / drag_splash (nan when the peer's drag is 0)."""
        return self.drag_ours / self.drag_splash if self.drag_splash != 0 else float("nan")


def force_check(
    solid_points: np.ndarray,
    setup: ProbeSetup,
    config: SolverConfig,
    probe: ProbeConfig,
    steps: int,
    threads: int = 2,
    keep: Path | None = None,
) -> ForceCheck:
    """Run one probe in this engine (Taichi must be initialised) and in SPlisHSPlasH, and compare the time-mean
    drag on the solid over the second half of the run.

    Args:
        solid_points: (M, 3) the solid, m. setup: the probe. config: its solver settings (both engines).
        probe: slab and wall parameters (this engine's walls). steps: time steps. threads: the peer's OpenMP threads.
        keep: write the peer's scene here (default: a temporary folder, deleted).
    """
    from nbv.physics.forces import flow_axis, second_half_mean  # noqa: PLC0415

    ours = run_our_forces(solid_points, setup, config, probe, steps)
    with tempfile.TemporaryDirectory(prefix="splash_probe_") as tmp:
        folder = Path(keep) if keep is not None else Path(tmp)
        scene = write_probe_scenes(folder, solid_points, {setup.direction: setup}, config, steps, dynamic=True)
        splash = run_splash_forces(scene[setup.direction], steps, threads)
    flow = flow_axis(setup.direction)
    mean_ours, mean_splash = second_half_mean(ours.series, ours.dt), second_half_mean(splash.series, splash.dt)
    return ForceCheck(
        setup.direction, ours, splash, mean_ours, mean_splash, float(mean_ours @ flow), float(mean_splash @ flow)
    )
