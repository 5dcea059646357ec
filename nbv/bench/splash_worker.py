"""The child process of the SPlisHSPlasH peer (:mod:`nbv.bench.splash`): the only place ``pysplishsplash`` is imported.

Run as a script by :func:`nbv.bench.splash.run_worker` and :func:`nbv.bench.splash.splash_available`, never imported by
the engine::

    python nbv/bench/splash_worker.py --worker JOB.json   # set up the scene, time every step, write the result JSON
    python nbv/bench/splash_worker.py --probe             # exit 0 when pysplishsplash imports, 17 when it cannot

It imports only the standard library at module level (running it as a script must not load Taichi), preloads the
system ``libGLdispatch`` before ``import pysplishsplash`` (the copy bundled in the wheel segfaults) and leaves with
``os._exit`` so that SPlisHSPlasH's destructors neither print nor crash. It implements no equation of its own: the
DFSPH of Bender & Koschier 2017 runs inside SPlisHSPlasH.

Units: seconds for ``dt``, milliseconds for the step timings, m/s for the end-state speeds, m for the fluid box.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import time
from pathlib import Path

#: Exit code of the worker when ``import pysplishsplash`` fails (ImportError, or libGLdispatch missing).
EXIT_NO_SPLASH = 17
_HERE = Path(__file__).resolve().parent


def _import_splash():
    """Preload the system libGLdispatch, then import pysplishsplash (exit 17 if impossible)."""
    import ctypes  # noqa: PLC0415 - the preload must come before the import below

    # As a script, this folder is sys.path[0]: drop it so that no engine module can shadow a package name.
    sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _HERE]
    try:
        ctypes.CDLL("libGLdispatch.so.0", mode=ctypes.RTLD_GLOBAL)
        import pysplishsplash as sph  # noqa: PLC0415 - only after the libGLdispatch preload
    except (OSError, ImportError) as exc:
        sys.stderr.write(f"cannot import pysplishsplash: {exc}\n")
        sys.exit(EXIT_NO_SPLASH)
    return sph


def _splash_version() -> str:
    from importlib.metadata import PackageNotFoundError, version  # noqa: PLC0415 - child side only

    try:
        return version("pysplishsplash")
    except PackageNotFoundError:
        return "unknown"


def _simstep_total_ms(sph) -> float | None:
    """Total time of SPlisHSPlasH's internal "SimStep" timer so far, ms (None if absent/unreadable).

    The timer wraps ``Simulation::getTimeStep()->step()`` only (not the negligible static-boundary update);
    it appears in ``Utilities.Timing.m_averageTimes`` after the first step.
    """
    try:
        for entry in dict(sph.Utilities.Timing.m_averageTimes).values():
            if entry.name == "SimStep":
                return float(entry.totalTime)
    except Exception:  # noqa: BLE001 - optional diagnostic; binding layout differs between versions
        return None
    return None


def _to_builtin(obj):
    """json.dumps fallback for numpy scalars/arrays returned by the bindings."""
    if hasattr(obj, "tolist"):
        return obj.tolist()
    raise TypeError(f"not JSON serializable: {type(obj).__name__}")


def _read_config(sph, base) -> dict:
    """SPlisHSPlasH's parameters read back after set-up (dt, tolerances in %, kinematic viscosity, exporters)."""
    sim = sph.Simulation.getCurrent()
    tm = sph.TimeManager.getCurrent()
    ts = sim.getTimeStep()
    fluid = sim.getFluidModel(0)
    visco = fluid.getViscosityBase()
    return {
        "method": ts.getMethodName() if hasattr(ts, "getMethodName") else type(ts).__name__,
        "simulationMethod": sim.getValueInt(sim.SIMULATION_METHOD),
        "boundaryHandlingMethod": sim.getValueInt(sim.BOUNDARY_HANDLING_METHOD),
        "cflMethod": sim.getValueInt(sim.CFL_METHOD),
        "dt": tm.getTimeStepSize(),
        "gravitation": [float(g) for g in sim.getVec3ValueReal(sim.GRAVITATION)],
        "particleRadius": sim.getValueFloat(sim.PARTICLE_RADIUS),
        "minIterations": ts.getValueUInt(ts.MIN_ITERATIONS),
        "maxIterations": ts.getValueUInt(ts.MAX_ITERATIONS),
        "maxIterationsV": ts.getValueUInt(ts.MAX_ITERATIONS_V),
        "maxError_percent": ts.getValueFloat(ts.MAX_ERROR),
        "maxErrorV_percent": ts.getValueFloat(ts.MAX_ERROR_V),
        "density0": fluid.getDensity0(),
        "viscosityMethod": fluid.getValueInt(fluid.VISCOSITY_METHOD),
        "viscosityMethodName": visco.getMethodName() if hasattr(visco, "getMethodName") else None,
        "viscosity_kinematic": visco.getValueFloat(visco.VISCOSITY_COEFFICIENT),
        "viscosityBoundary": visco.getValueFloat(visco.VISCOSITY_COEFFICIENT_BOUNDARY)
        if hasattr(visco, "VISCOSITY_COEFFICIENT_BOUNDARY")
        else None,
        "exporters_active": [
            e.name for e in [*base.getParticleExporters(), *base.getRigidBodyExporters()] if e.exporter.getActive()
        ],
    }


def _first_step(sph, base) -> tuple[float, float, str]:
    """Run the deferred boundary init plus step 1: (step-1 ms, wall ms including the init, which of the two the
    first is taken from)."""
    sim_before = _simstep_total_ms(sph)
    t1 = time.perf_counter()
    base.runSimulation()  # deferred init (boundary sampling, neighbour search) + step 1
    wall1_ms = (time.perf_counter() - t1) * 1e3
    sim_after = _simstep_total_ms(sph)
    if sim_after is not None and sim_after > (sim_before or 0.0):
        return sim_after - (sim_before or 0.0), wall1_ms, "SPlisHSPlasH SimStep timer"
    return wall1_ms, wall1_ms, "wall time incl. deferred boundary init"


def _end_state(sph) -> dict:
    """Particle counts and cheap end-state sanity numbers: max and mean speed (m/s), fluid bounding box (m)."""
    sim = sph.Simulation.getCurrent()
    fluid = sim.getFluidModel(0)
    n_boundary = sum(sim.getBoundaryModel(i).numberOfParticles() for i in range(sim.numberOfBoundaryModels()))
    n_fluid = sum(sim.getFluidModel(i).numActiveParticles() for i in range(sim.numberOfFluidModels()))
    speeds, lo, hi = [], [math.inf] * 3, [-math.inf] * 3
    for i in range(fluid.numActiveParticles()):
        v = fluid.getVelocity(i)
        x = fluid.getPosition(i)
        speeds.append(math.sqrt(float(v[0]) ** 2 + float(v[1]) ** 2 + float(v[2]) ** 2))
        lo = [min(a, float(b)) for a, b in zip(lo, x, strict=True)]
        hi = [max(a, float(b)) for a, b in zip(hi, x, strict=True)]
    return {
        "fluid_particles": int(n_fluid),
        "boundary_particles": int(n_boundary),
        "final_max_speed": max(speeds, default=0.0),
        "final_mean_speed": statistics.fmean(speeds) if speeds else 0.0,
        "final_fluid_bbox": [lo, hi],
    }


def _force_worker(sph, base, job: dict) -> dict:
    """Step a scene whose rigid body ``job["force_body"]`` is dynamic and read the fluid's force on it per step.

    SPlisHSPlasH accumulates a boundary's force only on a dynamic body, hands it to the rigid-body solver after the
    fluid step and clears it; the binding of ``getForceAndTorque`` cannot return it. So after each fluid step the
    rigid-body step runs once, the force is read from the body's velocity change, F = m (dv / dt - g) (it starts
    each step at rest), and the body is put back where it started, at rest, with its boundary particles: the fluid
    always sees a static solid. Returns ``{"forces": [[Fx, Fy, Fz] per step] (N), "steps_s"}`` and the counts.
    """
    import numpy as np  # noqa: PLC0415 - child side only (pysplishsplash needs numpy)

    sim = sph.Simulation.getCurrent()
    tm = sph.TimeManager.getCurrent()
    dt = float(job["dt"])
    tm.setTimeStepSize(dt)
    # runSimulation() does the deferred boundary initialisation, then steps until stopAt: with the clock past
    # stopAt it steps nothing; the steps below are driven one by one
    tm.setTime(1.0)
    base.setValueFloat(base.STOP_AT, 0.5)
    base.runSimulation()
    tm.setTime(0.0)
    ts = sim.getTimeStep()
    body = sim.getBoundaryModel(int(job["force_body"])).getRigidBodyObject()
    if not body.isDynamic():
        raise RuntimeError(f"rigid body {job['force_body']} is not dynamic: SPlisHSPlasH records no force on it")
    boundary = base.getBoundarySimulator()
    mass = float(body.getMass())
    gravity = np.asarray(job["gravity"], np.float64)
    x0 = np.array(body.getPosition(), np.float32)
    r0 = np.array(body.getRotation(), np.float32)
    rest = np.zeros(3, np.float32)
    forces = []
    t0 = time.perf_counter()
    for _ in range(int(job["steps"])):
        ts.step()  # the fluid step: the boundary accumulates the reactions of its pressure and viscosity terms
        boundary.timeStep()  # hands them to the body: dv = dt (F / m + g)
        dv = np.asarray(body.getVelocity(), np.float64)
        forces.append((mass * (dv / dt - gravity)).tolist())
        body.setVelocity(rest)
        body.setAngularVelocity(rest)
        body.setPosition(x0)
        body.setRotation(r0)
        base.updateBoundaryParticles(True)
    steps_s = time.perf_counter() - t0
    fluid = sim.getFluidModel(0)
    return {"forces": forces, "steps_s": steps_s, "fluid_particles": int(fluid.numActiveParticles()), "mass": mass}


def _timed_steps(sph, base, job: dict, t0: float) -> dict:
    """Step the scene, each step timed, and return the result (keys: :func:`nbv.bench.splash.run_splash`); ``t0``:
    when ``initSimulation()`` started."""
    steps = int(job["steps"])
    dt = float(job["dt"])
    config = _read_config(sph, base)
    ts = sph.Simulation.getCurrent().getTimeStep()
    pressure_its: list[int] = []
    divergence_its: list[int] = []

    def record_iterations() -> None:
        pressure_its.append(int(ts.getValueUInt(ts.SOLVER_ITERATIONS)))
        divergence_its.append(int(ts.getValueUInt(ts.SOLVER_ITERATIONS_V)))

    base.setTimeStepCB(record_iterations)
    # stopAt slightly above 0 (must be set after initSimulation(), which reads the scene's "stopAt"):
    # runSimulation() then does the deferred boundary init plus exactly one step.
    base.setValueFloat(base.STOP_AT, 0.5 * dt)
    init_s = time.perf_counter() - t0
    step1_ms, wall1_ms, step1_source = _first_step(sph, base)
    ms_per_step = [step1_ms]
    base.setValueFloat(base.STOP_AT, (steps + 10) * dt)
    for _ in range(steps - 1):
        t = time.perf_counter()
        if not base.timeStepNoGUI():
            break
        ms_per_step.append((time.perf_counter() - t) * 1e3)

    end = _end_state(sph)  # after the timing
    return {
        "fluid_particles": end.pop("fluid_particles"),
        "boundary_particles": end.pop("boundary_particles"),
        "steps": len(ms_per_step),
        "ms_per_step": ms_per_step,
        "median_ms_steps_2_to_n": statistics.median(ms_per_step[1:]) if len(ms_per_step) > 1 else None,
        "pressure_iterations": pressure_its or None,
        "divergence_iterations": divergence_its or None,
        "threads": int(os.environ.get("OMP_NUM_THREADS", "0") or 0),
        "version": _splash_version(),
        "init_s": init_s,
        "step1_wall_ms_incl_init": wall1_ms,
        "step1_source": step1_source,
        "sim_time_s": sph.TimeManager.getCurrent().getTime(),
        **end,
        "config": config,
    }


def _worker(job_file: str) -> int:
    """Child process: set up the scene, step it, write the result JSON (keys: :func:`nbv.bench.splash.run_splash`;
    with ``force_body`` in the job: :func:`_force_worker`)."""
    job = json.loads(Path(job_file).read_text())
    sph = _import_splash()
    base = sph.Exec.SimulatorBase()
    base.init(
        sceneFile=job["scene_file"], useCache=False, outputDir=job["output_dir"], initialPause=False, useGui=False
    )
    t0 = time.perf_counter()
    base.initSimulation()
    result = _force_worker(sph, base, job) if job.get("force_body") is not None else _timed_steps(sph, base, job, t0)
    Path(job["result_file"]).write_text(json.dumps(result, default=_to_builtin))
    sys.stdout.flush()
    # Skip SPlisHSPlasH's destructors (they print timing tables and can crash at interpreter exit).
    os._exit(0)


def main(argv: list[str] | None = None) -> None:
    """``--worker JOB.json`` or ``--probe`` (see the module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument("--worker", metavar="JOB_JSON", help="run the job file written by nbv.bench.splash.run_splash")
    group.add_argument("--probe", action="store_true", help="exit 0 when pysplishsplash imports, 17 otherwise")
    args = parser.parse_args(argv)
    if args.probe:
        _import_splash()
        os._exit(0)
    sys.exit(_worker(args.worker))


if __name__ == "__main__":
    main()
