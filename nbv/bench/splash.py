"""The SPlisHSPlasH peer: the reference C++ DFSPH (Bender & Koschier 2017) on the same scene as this engine.

:class:`PeerScene` describes a sphere-impact scene independently of either engine. :func:`peer_solver` builds it
for :class:`fluidsim.DFSPHSolver`; :func:`splash_scene_json` writes it in SPlisHSPlasH's scene format (with the
meshes of :func:`icosphere` and :func:`unit_box`), and :func:`run_splash` runs SPlisHSPlasH on it and times every
step. ``fluidgs bench sim`` (:mod:`apps.bench.sim`) prints the two engines side by side.

SPlisHSPlasH (PyPI ``pysplishsplash``) is a bench/test extra, never a runtime dependency: it is imported only by
the child process :mod:`nbv.bench.splash_worker` (``python nbv/bench/splash_worker.py --worker JOB.json``), because

* ``import pysplishsplash`` segfaults when the wheel's bundled ``libGLdispatch`` is loaded first; the
  worker preloads the system copy (``ctypes.CDLL("libGLdispatch.so.0", RTLD_GLOBAL)``) before importing,
  and a crash there must not take the caller down;
* SPlisHSPlasH keeps process-global singletons (``Simulation``, ``TimeManager``, ``SceneConfiguration``),
  so one simulation per process is the only clean way to run several scenes;
* ``OMP_NUM_THREADS`` must be set before its OpenMP runtime starts.

Install::

    apt-get install -y libgl1 libx11-6        # provides /lib/x86_64-linux-gnu/libGLdispatch.so.0
    .venv/bin/pip install pysplishsplash

Units: lengths in metres, times in seconds, velocities in m/s, densities in kg/m^3, dynamic viscosity
in Pa*s, wall-clock timings in milliseconds.
"""

from __future__ import annotations

import json
import logging
import math
import os
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fluidsim.config import SolverConfig
from fluidsim.scene import lattice_in_box
from fluidsim.solver import DFSPHSolver
from fluidsim.sources import sphere_particles, wall_particles

from .splash_worker import EXIT_NO_SPLASH

log = logging.getLogger(__name__)

WORKER = Path(__file__).resolve().with_name("splash_worker.py")  # run as a script in a child process
BOX_MESH = "box.obj"  # the unit box the walls scale
INSTALL_HINT = (
    "Install it with `.venv/bin/pip install pysplishsplash` (bench/test extra) and make sure the system "
    "OpenGL dispatch library exists (`apt-get install -y libgl1 libx11-6`, which provides "
    "libGLdispatch.so.0; it is preloaded before the import because the copy bundled in the wheel "
    "segfaults)."
)


@dataclass(frozen=True)
class PeerScene:
    """A sphere-impact scene described independently of either engine.

    The defaults are the bench scene: a static solid sphere (radius 1 m, at the origin) and a fluid slab
    1 m thick on its +x side (0.1 m gap), spanning y, z in [-1.35, 1.35] m and moving at -3 m/s along x,
    inside closed box walls [-2.0, -1.6, -1.6]..[2.4, 1.6, 1.6] m (the fluid is >= 5 particle spacings
    from every wall, so the first steps do not start compressed).

    Attributes:
        particle_radius: fluid particle radius r, m; particle spacing is 2r, kernel support 4r.
        dt: fixed time step, s (CFL adaptivity is switched off).
        steps: number of time steps to run.
        sphere_center, sphere_radius: static solid sphere, m.
        fluid_min, fluid_max: axis-aligned slab box, m.  Particles sit on a cubic lattice at cell
            centres, ``fluid_min + (i + 0.5) * 2r``, so a box of length L holds ``round(L / 2r)`` particles
            per axis.
        fluid_velocity: initial fluid velocity, m/s.
        domain_min, domain_max: closed box walls, m.
        viscosity: dynamic viscosity mu, Pa*s; SPlisHSPlasH gets the kinematic nu = mu / rest_density.
        rest_density: rho0, kg/m^3.
        max_density_error_percent: DFSPH density solver tolerance, % of rho0 (average error).
        max_divergence_error_percent: DFSPH divergence solver tolerance, % of rho0 per second.
        min_iterations, max_iterations: iteration bounds for both DFSPH solvers.
        threads: OpenMP threads (OMP_NUM_THREADS) for the peer.
        gravity: gravitational acceleration, m/s^2.
    """

    particle_radius: float = 0.025
    dt: float = 0.002
    steps: int = 100
    sphere_center: tuple = (0.0, 0.0, 0.0)
    sphere_radius: float = 1.0
    fluid_min: tuple = (1.1, -1.35, -1.35)
    fluid_max: tuple = (2.1, 1.35, 1.35)
    fluid_velocity: tuple = (-3.0, 0.0, 0.0)
    domain_min: tuple = (-2.0, -1.6, -1.6)
    domain_max: tuple = (2.4, 1.6, 1.6)
    viscosity: float = 10.0
    rest_density: float = 1000.0
    max_density_error_percent: float = 0.01
    max_divergence_error_percent: float = 0.1
    min_iterations: int = 2
    max_iterations: int = 100
    threads: int = 2
    gravity: tuple = (0.0, -9.81, 0.0)

    def __post_init__(self) -> None:
        for name in (
            "particle_radius",
            "dt",
            "sphere_radius",
            "viscosity",
            "rest_density",
            "max_density_error_percent",
            "max_divergence_error_percent",
        ):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"PeerScene.{name} must be a finite number > 0, got {value!r}")
        for name in ("steps", "threads", "min_iterations"):
            if not (isinstance(getattr(self, name), int) and getattr(self, name) >= 1):
                raise ValueError(f"PeerScene.{name} must be an integer >= 1, got {getattr(self, name)!r}")
        if self.max_iterations < self.min_iterations:
            raise ValueError(
                f"PeerScene.max_iterations ({self.max_iterations}) must be >= min_iterations ({self.min_iterations})"
            )
        boxes = (("fluid", self.fluid_min, self.fluid_max), ("domain", self.domain_min, self.domain_max))
        for label, lo, hi in boxes:
            if len(lo) != 3 or len(hi) != 3 or not all(a < b for a, b in zip(lo, hi, strict=True)):
                raise ValueError(
                    f"PeerScene.{label}_min/{label}_max must be 3 numbers each with min < max per "
                    f"axis, got {lo} and {hi}"
                )
        if not all(
            d0 <= f0 and f1 <= d1
            for d0, f0, f1, d1 in zip(self.domain_min, self.fluid_min, self.fluid_max, self.domain_max, strict=True)
        ):
            raise ValueError(
                f"PeerScene: the fluid box {self.fluid_min}..{self.fluid_max} must lie inside the "
                f"domain {self.domain_min}..{self.domain_max}"
            )

    @property
    def spacing(self) -> float:
        """Particle spacing 2r, m."""
        return 2.0 * self.particle_radius

    @property
    def kinematic_viscosity(self) -> float:
        """Kinematic viscosity nu = mu / rho0, m^2/s (what SPlisHSPlasH's viscosity coefficient means)."""
        return self.viscosity / self.rest_density

    def expected_fluid_particles(self) -> int:
        """Number of fluid particles the cell-centred lattice puts into the slab box."""
        counts = [round((hi - lo) / self.spacing) for lo, hi in zip(self.fluid_min, self.fluid_max, strict=True)]
        return math.prod(counts)


@dataclass(frozen=True)
class PeerParticles:
    """The particles of a :class:`PeerScene` for this engine (all float64, metres or m/s).

    Attributes:
        fluid: (F, 3) the slab's cell-centred lattice. velocity: (F, 3) its initial velocity.
        solid: (S, 3) the filled sphere on the lattice ``center + spacing Z^3``. walls: (W, 3) two wall layers.
    """

    fluid: np.ndarray
    velocity: np.ndarray
    solid: np.ndarray
    walls: np.ndarray


# A SPlisHSPlasH scene run without its GUI and without any export (its own files are not read back).
HEADLESS = {
    "pause": False,
    "numberOfStepsPerRenderUpdate": 1,
    "enablePartioExport": False,
    "enableVTKExport": False,
    "enableRigidBodyExport": False,
    "enableRigidBodyVTKExport": False,
    "enableStateExport": False,
    "enableAsyncExport": False,
}


def peer_config(scene: PeerScene, divergence_warm_start: bool = True) -> SolverConfig:
    """This engine's solver settings for ``scene``: the same r, dt, mu, rho0, gravity, tolerances (in %) and
    iteration bounds as SPlisHSPlasH gets, and free slip at the walls (``boundary_viscosity = 0``, as the peer's
    zero boundary viscosity)."""
    return SolverConfig(
        particle_radius=scene.particle_radius,
        dt=scene.dt,
        viscosity=scene.viscosity,
        rest_density=scene.rest_density,
        gravity=tuple(scene.gravity),
        max_density_error=scene.max_density_error_percent,
        max_divergence_error=scene.max_divergence_error_percent,
        min_iterations=scene.min_iterations,
        max_iterations=scene.max_iterations,
        boundary_viscosity=0.0,
        divergence_warm_start=divergence_warm_start,
    )


def peer_particles(scene: PeerScene, spacing: float) -> PeerParticles:
    """Sample ``scene`` at ``spacing`` (m): the fluid slab, the filled sphere and two layers of closed walls."""
    fluid = lattice_in_box(scene.fluid_min, scene.fluid_max, spacing)
    return PeerParticles(
        fluid=fluid,
        velocity=np.broadcast_to(np.asarray(scene.fluid_velocity, np.float64), fluid.shape),
        solid=sphere_particles(scene.sphere_center, scene.sphere_radius, spacing, fill=True),
        walls=wall_particles(scene.domain_min, scene.domain_max, spacing, 2),
    )


def peer_solver(scene: PeerScene, particles: PeerParticles, config: SolverConfig) -> DFSPHSolver:
    """The solver of ``scene`` (Taichi must be initialised): the sphere and the walls are one boundary set."""
    return DFSPHSolver(
        config,
        scene.domain_min,
        scene.domain_max,
        particles.fluid,
        particles.velocity,
        np.concatenate([particles.solid, particles.walls]),
    )


# ----------------------------------------------------------------------------------------------------
# scene files (written by the parent, read by the worker)
# ----------------------------------------------------------------------------------------------------


def icosphere(subdivisions: int) -> tuple[list[tuple[float, float, float]], list[tuple[int, int, int]]]:
    """Unit icosphere (radius 1), faces wound counter-clockwise seen from outside (outward normals)."""
    t = (1.0 + math.sqrt(5.0)) / 2.0
    # the 12 vertices are the cyclic permutations of (+-1, +-t, 0)
    pairs = [(a, b) for b in (t, -t) for a in (-1, 1)]
    verts = [(a, b, 0) for a, b in pairs] + [(0, a, b) for a, b in pairs] + [(b, 0, a) for a, b in pairs]
    # the 5 faces around vertex 0, their 5 neighbours, the 5 around vertex 3 (opposite), and their 5 neighbours
    faces = (
        [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11)]
        + [(1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6), (7, 1, 8)]
        + [(3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9)]
        + [(4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    )

    def unit(v):
        n = math.sqrt(v[0] ** 2 + v[1] ** 2 + v[2] ** 2)
        return (v[0] / n, v[1] / n, v[2] / n)

    verts = [unit(v) for v in verts]
    for _ in range(subdivisions):
        cache: dict[tuple[int, int], int] = {}

        def midpoint(a: int, b: int, cache: dict[tuple[int, int], int] = cache) -> int:
            key = (min(a, b), max(a, b))
            if key not in cache:
                va, vb = verts[a], verts[b]
                verts.append(unit(((va[0] + vb[0]) / 2, (va[1] + vb[1]) / 2, (va[2] + vb[2]) / 2)))
                cache[key] = len(verts) - 1
            return cache[key]

        new_faces = []
        for a, b, c in faces:
            ab, bc, ca = midpoint(a, b), midpoint(b, c), midpoint(c, a)
            new_faces += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new_faces
    return verts, faces


def unit_box() -> tuple[list[tuple[float, float, float]], list[tuple[int, int, int]]]:
    """Unit cube [-0.5, 0.5]^3 as 12 triangles with outward normals."""
    verts = [(x, y, z) for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)]
    # vertex index = 4*ix + 2*iy + iz
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    faces = []
    for a, b, c, d in quads:
        faces += [(a, b, c), (a, c, d)]
    return verts, faces


def write_obj(path: Path, verts, faces) -> None:
    """Write a triangle mesh as Wavefront OBJ (1-based indices)."""
    lines = [f"v {x:.9f} {y:.9f} {z:.9f}" for x, y, z in verts]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    path.write_text("\n".join(lines) + "\n")


def dfsph_scene(
    config: SolverConfig,
    domain: tuple,
    solid: dict,
    block: tuple,
    stop_at: float | None = None,
    box_mesh: str = BOX_MESH,
) -> dict:
    """SPlisHSPlasH's scene (its JSON scene format) with this engine's solver settings ``config``.

    DFSPH (simulationMethod 4) at a fixed dt (cflMethod 0), the density/divergence tolerances (%) and iteration bounds
    of ``config`` for both solvers, "Standard" viscosity (viscosityMethod 1, the Laplacian of :mod:`fluidsim.viscosity`)
    with the kinematic nu = mu / rho0 and nu_b = mu_b / rho0, Akinci et al. 2012 boundary particles
    (boundaryHandlingMethod 0); headless, no export.

    Args:
        config: the solver settings. domain: (min, max) of the closed walls, m: the unit box ``box_mesh`` scaled, a
            static inverted rigid body. solid: the second rigid body's entry. block: (start, end, initial velocity)
            of the ``denseMode 0`` fluid block. stop_at: the scene's ``stopAt``, s (None: not set).
    """
    lo, hi = np.asarray(domain[0], np.float64), np.asarray(domain[1], np.float64)
    nu = config.viscosity / config.rest_density
    nu_b = config.wall_viscosity / config.rest_density
    iterations = {
        "minIterations": config.min_iterations,
        "maxIterations": config.max_iterations,
        "maxError": config.max_density_error,
        "maxIterationsV": config.max_iterations,
        "maxErrorV": config.max_divergence_error,
        "enableDivergenceSolver": config.divergence_solver,
    }
    return {
        "Configuration": {
            "particleRadius": config.particle_radius,
            "sim2D": False,
            "simulationMethod": 4,  # DFSPH
            "boundaryHandlingMethod": 0,  # Akinci et al. 2012 boundary particles
            "gravitation": list(config.gravity),
            "timeStepSize": config.dt,
            "cflMethod": 0,  # no CFL adaptivity: fixed dt, as this engine's
            **({} if stop_at is None else {"stopAt": stop_at}),
            **HEADLESS,
            **iterations,
            "DFSPH": dict(iterations),
        },
        "Materials": [
            {
                "id": "Fluid",
                "density0": config.rest_density,
                "viscosityMethod": 1,  # "Standard"
                "viscosity": nu,
                "viscosityBoundary": nu_b,
                "Standard viscosity": {"viscosity": nu, "viscosityBoundary": nu_b},
                "surfaceTensionMethod": 0,
                "vorticityMethod": 0,
                "dragMethod": 0,
                "elasticityMethod": 0,
            }
        ],
        "RigidBodies": [
            {
                "geometryFile": box_mesh,
                "translation": ((lo + hi) / 2).tolist(),
                "rotationAxis": [1, 0, 0],
                "rotationAngle": 0,
                "scale": (hi - lo).tolist(),
                "isDynamic": False,
                "isWall": True,
                "mapInvert": True,
                "samplingMode": 1,  # regular triangle sampling
            },
            solid,
        ],
        "FluidBlocks": [
            {"id": "Fluid", "denseMode": 0, "start": block[0], "end": block[1], "initialVelocity": list(block[2])}
        ],
    }


def splash_scene_json(scene: PeerScene, sphere_obj: str, box_obj: str) -> dict:
    """SPlisHSPlasH scene description (its JSON scene format, :func:`dfsph_scene`) for ``scene``.

    Fluid block: SPlisHSPlasH's ``denseMode 0`` lattice puts the first particle 2r inside ``start`` and
    fills ``round((end - start) / 2r) - 1`` particles per axis, so the block is widened by r on each side
    to reproduce our cell-centred lattice exactly.
    """
    r = scene.particle_radius
    sphere = {
        "geometryFile": sphere_obj,
        "translation": list(scene.sphere_center),
        "rotationAxis": [1, 0, 0],
        "rotationAngle": 0,
        "scale": [scene.sphere_radius] * 3,
        "isDynamic": False,
        "isWall": False,
        "mapInvert": False,
        "samplingMode": 1,
    }
    block = ([lo - r for lo in scene.fluid_min], [hi + r for hi in scene.fluid_max], scene.fluid_velocity)
    return dfsph_scene(peer_config(scene), (scene.domain_min, scene.domain_max), sphere, block, box_mesh=box_obj)


# ----------------------------------------------------------------------------------------------------
# parent side
# ----------------------------------------------------------------------------------------------------


def _worker_cmd(*args: str) -> list[str]:
    return [sys.executable, str(WORKER), *args]


def run_worker(folder: Path, job: dict, steps: int, threads: int, timeout_s: float) -> dict:
    """Run the worker (:mod:`nbv.bench.splash_worker`) on ``job`` for ``steps`` steps with ``threads`` OpenMP threads,
    its files in ``folder``, and return its result.

    Raises:
        RuntimeError: pysplishsplash is missing, crashes, or times out (the message says how to install).
    """
    job = {**job, "output_dir": str(folder / "output"), "result_file": str(folder / "result.json"), "steps": steps}
    job_file = folder / "job.json"
    job_file.write_text(json.dumps(job))
    env = dict(os.environ, OMP_NUM_THREADS=str(threads))
    if env.pop("FLUIDGS_OMP_POLICY_SET", None):  # the passive policy fluidgs set for torch: not the peer's
        env.pop("OMP_WAIT_POLICY", None)
    try:
        proc = subprocess.run(
            _worker_cmd("--worker", str(job_file)), env=env, capture_output=True, text=True, timeout=timeout_s
        )
    except subprocess.TimeoutExpired as exc:
        raise RuntimeError(f"SPlisHSPlasH run timed out after {timeout_s} s") from exc
    result_file = folder / "result.json"
    if proc.returncode == EXIT_NO_SPLASH:
        raise RuntimeError(f"pysplishsplash is not importable: {proc.stderr.strip()[-800:]}\n{INSTALL_HINT}")
    if proc.returncode != 0 or not result_file.exists():
        tail = (proc.stdout[-1500:] + "\n" + proc.stderr[-1500:]).strip()
        raise RuntimeError(
            f"SPlisHSPlasH worker failed (exit code {proc.returncode}"
            f"{', segfault' if proc.returncode == -11 else ''}).\n{tail}\n{INSTALL_HINT}"
        )
    return json.loads(result_file.read_text())


def splash_available(timeout_s: float = 120.0) -> bool:
    """True when ``pysplishsplash`` imports (with the libGLdispatch preload) in a child process.

    The check runs in a subprocess so that a segfault in the import cannot kill the caller.
    """
    try:
        proc = subprocess.run(_worker_cmd("--probe"), capture_output=True, text=True, timeout=timeout_s)
    except (OSError, subprocess.TimeoutExpired) as exc:
        log.warning("pysplishsplash probe failed: %s", exc)
        return False
    if proc.returncode != 0:
        log.info("pysplishsplash not available (rc=%s): %s", proc.returncode, proc.stderr.strip()[-500:])
    return proc.returncode == 0


def run_splash(scene: PeerScene, timeout_s: float = 1200) -> dict:
    """Run SPlisHSPlasH's DFSPH on ``scene`` in a subprocess and time every step.

    Setup: :func:`splash_scene_json`. SPlisHSPlasH's Viscosity_Standard is the Monaghan/Morris-type Laplacian
    ``a_i = 10 nu sum_j (m_j / rho_j) (v_ij . x_ij) / (|x_ij|^2 + 0.01 h^2) grad W_ij`` with the kinematic nu, and zero
    boundary viscosity (free slip at the walls and the sphere, as in SPlisHSPlasH's own scenes); no surface tension,
    vorticity, drag or elasticity. Note: SPlisHSPlasH applies ``min_iterations`` to the density solver only; its
    divergence solver stops after 1 iteration once converged. The sphere is a static rigid body made from a generated
    icosphere OBJ. No GUI, no boundary cache; the log file SPlisHSPlasH always writes goes to a temp dir that is
    deleted afterwards.

    Timing: ``time.perf_counter`` around each ``SimulatorBase.timeStepNoGUI()`` (DFSPH step + boundary
    update).  Step 1 is executed inside ``runSimulation()`` together with SPlisHSPlasH's deferred boundary
    initialisation; its entry is the C++ "SimStep" timer (falls back to the wall time including the init
    if that timer cannot be read), which is why the summary uses steps 2..n.

    Args:
        scene: the scene, in SI units.
        timeout_s: wall-clock limit for the child process, s.

    Returns:
        ``{"fluid_particles", "boundary_particles", "steps", "ms_per_step" (ms, one per step),
        "median_ms_steps_2_to_n" (ms), "pressure_iterations", "divergence_iterations" (per step),
        "threads", "version"}`` plus diagnostics: ``"init_s"`` (``initSimulation()``: fluid lattice and
        model setup, s), ``"step1_wall_ms_incl_init"`` (step 1 plus boundary sampling and first neighbour
        search, ms), ``"step1_source"``, ``"sim_time_s"``, ``"final_max_speed"``/``"final_mean_speed"``
        (m/s), ``"final_fluid_bbox"`` (m) and ``"config"`` (SPlisHSPlasH's parameters read back after
        setup, e.g. dt, tolerances in %, kinematic viscosity, active exporters).

    Raises:
        RuntimeError: pysplishsplash is missing, crashes, or times out (the message says how to install).
    """
    with tempfile.TemporaryDirectory(prefix="splash_peer_") as tmp:
        tmpdir = Path(tmp)
        write_obj(tmpdir / "sphere.obj", *icosphere(5))
        write_obj(tmpdir / BOX_MESH, *unit_box())
        scene_file = tmpdir / "scene.json"
        scene_file.write_text(json.dumps(splash_scene_json(scene, "sphere.obj", BOX_MESH), indent=1))
        log.info(
            "running SPlisHSPlasH DFSPH: %d steps, %d threads, ~%d fluid particles",
            scene.steps,
            scene.threads,
            scene.expected_fluid_particles(),
        )
        job = {"scene_file": str(scene_file), "dt": scene.dt}
        result = run_worker(tmpdir, job, scene.steps, scene.threads, timeout_s)
    log.info(
        "SPlisHSPlasH: %d fluid / %d boundary particles, median %.1f ms/step (steps 2..%d)",
        result["fluid_particles"],
        result["boundary_particles"],
        result["median_ms_steps_2_to_n"],
        result["steps"],
    )
    return result
