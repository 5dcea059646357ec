"""`fluidgs bench forces`: the force on the solid, this engine against SPlisHSPlasH, on the same probe scene.

Cases: a sphere (a filled lattice ball, the -x probe) and the bundled Ahmed body Gaussians (the -x probe of
``PhysicsConfig.quick``'s setup at the chosen r); or, with ``--solid FILE``, your own mesh, Gaussian file or RESULT.h5,
whose solid is made as ``fluidgs compare`` makes its reference (a mesh: the lattice points inside it, scaled to the
probe domain's target extent). Each probe runs in this engine and in SPlisHSPlasH (pysplishsplash,
the ``bench`` extra) with the same r, dt, viscosity and boundary viscosity, tolerances, slab and walls
(:mod:`nbv.bench.splash_probe`); it prints both time-mean drags over the second half of the run, their ratio and the
settings. The default run length is the slab's passage over the solid
(:func:`nbv.bench.splash_probe.passage_steps`): later the fluid wraps round the solid's back and rebounds off the
downstream wall, a sloshing neither engine pins down.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..options.common import add_gaussians_option, add_json_option, add_up_option
from ..runtime import thread_count

CASES = ("sphere", "ahmed")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--case", choices=(*CASES, "both"), default="both", help="which solid (default: both)")
    p.add_argument(
        "--radius", type=float, default=0.035, help="particle radius r, m (default: 0.035, the --quick setting)"
    )
    p.add_argument(
        "--steps",
        type=int,
        default=None,
        help="time steps per probe (default: the slab's passage over the solid at the inflow speed: its front to the "
        "solid's far side or its tail to the near side, whichever comes first)",
    )
    p.add_argument("--dt", type=float, default=0.002, help="fixed time step of both engines, s (default: 0.002)")
    p.add_argument("--sphere-radius", type=float, default=0.5, help="the sphere case's radius, m (default: 0.5)")
    add_gaussians_option(p, "the ahmed case's Gaussians (default: assets/ahmed_gaussians.ply)")
    p.add_argument(
        "--solid",
        type=Path,
        default=None,
        help="check this mesh (.obj/.stl/.ply/.glb), Gaussian file or RESULT.h5 instead of the built-in cases, scaled "
        "as `fluidgs compare` scales its reference (default: none)",
    )
    add_up_option(p, "the ahmed case's (or --solid's) up axis in its own frame (default: +y)", alias=False)
    p.add_argument("--threads", type=thread_count, default=2, help="CPU threads for both engines (default: 2)")
    p.add_argument("--keep", type=Path, default=None, help="write the peer's scenes into this folder (default: none)")
    add_json_option(p, "also write the figures to this JSON file (default: none)")


def _cases(args: argparse.Namespace):
    """(name, solid points [M, 3] m, ProbeSetup, SolverConfig, ProbeConfig) per case asked for."""
    import numpy as np

    import nbv
    import recon
    from fluidsim.probes import ProbeConfig, probe_setup
    from fluidsim.sources import sphere_particles
    from nbv.physics.plan import ProbePlan, RunFrame

    names = CASES if args.case == "both" else (args.case,)
    if args.solid is not None:
        names = ("file",)
    for name in names:
        config = nbv.PhysicsConfig.quick(
            up=args.up, empty_reference=False, particle_radius=args.radius, dt=args.dt, directions=("-x",)
        )
        scfg = config.solver_config()
        if name == "sphere":
            probe = ProbeConfig(speed=config.speed, directions=("-x",))
            solid = sphere_particles((0.0, 0.0, 0.0), args.sphere_radius, scfg.spacing, fill=True)
            yield name, solid, probe_setup(solid, "-x", probe, scfg.spacing), scfg, probe
        elif name == "file":
            from nbv.functional.solids import reference_source

            source = reference_source(args.solid, config, None, recon.load_gaussians)
            solid = source.solid(scfg.spacing)
            yield args.solid.name, solid, ProbePlan.of(solid, config).setups["-x"], scfg, config.probe_config()
        else:
            frame = RunFrame.of(recon.load_gaussians(args.gaussians), config, source=str(args.gaussians))
            solid = np.asarray(frame.solidify().points, np.float64)
            yield name, solid, ProbePlan.of(solid, config).setups["-x"], scfg, config.probe_config()


def run_command(args: argparse.Namespace) -> int:
    from fluidsim.files import check_input_file, check_not_input, write_json_atomic
    from nbv.bench.splash import INSTALL_HINT, splash_available
    from nbv.bench.splash_probe import force_check, passage_steps
    from recon.formats import detect_format

    from ..options import check_output_file, check_output_folder
    from ..runtime import init_taichi

    if args.keep is not None:  # before any engine runs: an existing file here failed late, in the peer's writer
        check_output_folder(args.keep, "--keep")
    if args.json is not None:
        check_output_file(args.json, (".json",))
    if not (args.radius > 0 and args.dt > 0 and args.sphere_radius > 0):
        raise ValueError("--radius, --dt and --sphere-radius must be > 0")
    if args.steps is not None and args.steps < 2:
        raise ValueError(f"--steps must be >= 2, got {args.steps}")
    if args.solid is not None:  # what it is, before any engine runs: a device, a FIFO, a folder that holds no Gaussians
        check_input_file(args.solid, "--solid", "pass a mesh, a Gaussian file or a RESULT.h5", folder_ok=True)
        if args.solid.is_dir():  # a Gaussian folder (PlayCanvas SOG) or recon.formats says what the folder is
            detect_format(args.solid)
    inputs = {"--solid": args.solid} if args.solid is not None else {"--gaussians": args.gaussians}
    check_not_input({"--json": args.json}, inputs)
    if args.solid is None and args.case != "sphere":  # the Ahmed case's Gaussians are read before any engine runs
        from ..options import load_gaussians_checked

        load_gaussians_checked(args.gaussians)
    if not splash_available():
        raise RuntimeError(f"bench forces needs SPlisHSPlasH. {INSTALL_HINT}")
    init_taichi("cpu", "f32", args.threads)
    figures = []
    for name, solid, setup, scfg, probe in _cases(args):
        steps = args.steps if args.steps is not None else passage_steps(solid, setup, scfg.dt)
        keep = None if args.keep is None else args.keep / name
        check = force_check(solid, setup, scfg, probe, steps, args.threads, keep)
        row = {
            "case": name,
            "probe": setup.direction,
            "solid_particles": len(solid),
            "fluid_particles": check.ours.fluid_particles,
            "fluid_particles_splash": check.splash.fluid_particles,
            "particle_radius_m": scfg.particle_radius,
            "dt_s": scfg.dt,
            "steps": steps,
            "window_steps": [steps // 2, steps],
            "viscosity_Pa_s": scfg.viscosity,
            "boundary_viscosity_Pa_s": scfg.wall_viscosity,
            "speed_m_s": float(max(abs(c) for c in setup.velocity)),
            "drag_ours_N": check.drag_ours,
            "drag_splash_N": check.drag_splash,
            "ratio": check.ratio,
            "mean_ours_N": check.mean_ours.tolist(),
            "mean_splash_N": check.mean_splash.tolist(),
            "seconds_ours": check.ours.seconds,
            "seconds_splash": check.splash.seconds,
        }
        figures.append(row)
        print(
            f"{name} (probe {setup.direction}): {len(solid)} solid, {check.ours.fluid_particles} fluid particles "
            f"(SPlisHSPlasH {check.splash.fluid_particles}); r {scfg.particle_radius:g} m, dt {scfg.dt:g} s, "
            f"{steps} steps (mean over steps {steps // 2}-{steps}), mu {scfg.viscosity:g} Pa s, mu_b "
            f"{scfg.wall_viscosity:g} Pa s, U {row['speed_m_s']:g} m/s"
        )
        print(
            f"  time-mean drag: ours {check.drag_ours:.4g} N, SPlisHSPlasH {check.drag_splash:.4g} N, ratio "
            f"{check.ratio:.3f}; mean force ours {check.mean_ours.round(1).tolist()} N, SPlisHSPlasH "
            f"{check.mean_splash.round(1).tolist()} N ({check.ours.seconds:.0f} s / {check.splash.seconds:.0f} s)"
        )
    if args.json is not None:
        write_json_atomic(args.json, figures)
    return 0
