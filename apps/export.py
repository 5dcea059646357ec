"""`fluidgs export FILE.h5 --vtk DIR`: a simulation's particles and solid in the formats other tools open.

``--vtk DIR`` writes one VTK point cloud (.vtu) per saved frame of an OUT.h5 (``fluidgs sim``), or per recorded
frame of a RESULT.h5 (``fluidgs simulate --record-probe``), with velocity, D_i and density as point data, the
solid (and the walls), and a ParaView ``.pvd`` series (:mod:`nbv.export.particles`). ``--solid PATH`` writes the
filled solid of a RESULT.h5 (or the solid of an OUT.h5) as a closed mesh and a voxel grid
(:mod:`nbv.export.solid`), as ``simulate --export-solid`` does. ``--splishsplash DIR`` writes the probe scenes of a
RESULT.h5 (or of a Gaussian file, through the same solid and probe setup) as SPlisHSPlasH scenes, one per probe, with
the solid as the surface through its outer particles' centres (:mod:`nbv.bench.splash_probe`), so that the
reference engine can rerun a probe. Nothing is simulated.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from .options.numbers import step_count
from .options.solid_export import FRAME_HELP, print_solid_export, solid_export_outputs


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "h5",
        type=Path,
        help="an OUT.h5 of `fluidgs sim` or a RESULT.h5 of `fluidgs simulate` (--splishsplash: a RESULT.h5 or a "
        "Gaussian file)",
    )
    p.add_argument(
        "--vtk",
        type=Path,
        default=None,
        metavar="DIR",
        help="write the particle frames as VTK (.vtu per frame, .pvd series, solid.vtu) into this folder, "
        "replaced as a whole (default: none)",
    )
    p.add_argument(
        "--probe",
        default=None,
        metavar="DIRS",
        help="RESULT.h5: comma list of the recorded probes to write, or with --splishsplash the probes to write "
        "scenes for (default: every recorded probe; with --splishsplash every probe of the run)",
    )
    p.add_argument(
        "--splishsplash",
        type=Path,
        default=None,
        metavar="DIR",
        help="write the probe scenes as SPlisHSPlasH scene files into this folder: probe_<dir>.json per probe, the "
        "solid as solid.obj (the surface through its outer particles' centres), the walls' box.obj (default: none)",
    )
    p.add_argument(
        "--steps",
        type=step_count,
        default=None,
        help="--splishsplash: time steps of each scene (stopAt = steps x dt, s) (default: the run's steps per probe)",
    )
    p.add_argument(
        "--quick",
        action="store_true",
        help="--splishsplash of a Gaussian file: the quick setting, r = 0.035 m, 750 steps (default: the paper's, "
        "r = 0.025 m, 750 steps)",
    )
    p.add_argument(
        "--up",
        default="+y",
        help="--splishsplash of a Gaussian file: its up axis, +x, -x, +y, -y, +z or -z (default: +y)",
    )
    p.add_argument(
        "--solid",
        type=Path,
        default=None,
        metavar="PATH",
        help="write the solid as a mesh (.ply, .obj, .glb, .stl; the voxel grid beside it as "
        ".voxels.h5) or as a voxel grid only (.h5) (default: none)",
    )
    p.add_argument("--export-frame", choices=("sim", "scene"), default="sim", help=f"{FRAME_HELP} (default: sim)")


def _probe_source(path: Path, is_hdf5: bool, quick: bool, up: str) -> tuple:
    """(solid points [M, 3] m, PhysicsConfig) of a RESULT.h5, or of a Gaussian file solidified as ``simulate`` does."""
    import numpy as np

    import nbv

    if is_hdf5:
        import h5py

        from recon.inflate import check_hdf5_sizes

        with h5py.File(path, "r") as f:
            check_hdf5_sizes(f, str(path))
            if "solid/x" not in f or "config" not in f.attrs:
                raise ValueError(f"--splishsplash: {path} is not a RESULT.h5 of `fluidgs simulate` (no /solid/x)")
            return np.asarray(f["solid/x"][()], np.float64), nbv.PhysicsConfig.from_dict(json.loads(f.attrs["config"]))
    import recon
    from nbv.physics.plan import RunFrame

    from .runtime import init_taichi

    init_taichi("cpu")  # the solidification runs Taichi kernels
    config = (nbv.PhysicsConfig.quick if quick else nbv.PhysicsConfig)(up=up, empty_reference=False)
    frame = RunFrame.of(recon.load_gaussians(path), config, source=str(path))
    return np.asarray(frame.solidify().points, np.float64), config


def write_splash_scenes(args: argparse.Namespace, is_hdf5: bool, probes: tuple | None) -> None:
    """``--splishsplash DIR``: one SPlisHSPlasH scene per probe (:func:`nbv.bench.splash_probe.write_probe_scenes`)."""
    from nbv.bench.splash_probe import write_probe_scenes
    from nbv.physics.plan import ProbePlan

    solid, config = _probe_source(args.h5, is_hdf5, args.quick, args.up)
    setups = ProbePlan.of(solid, config).setups
    missing = [d for d in probes or () if d not in setups]
    if missing:
        raise ValueError(f"--probe: {','.join(missing)} not among the run's probes {','.join(setups)}")
    chosen = {d: setups[d] for d in (probes or setups)}
    steps = args.steps if args.steps is not None else config.steps
    paths = write_probe_scenes(args.splishsplash, solid, chosen, config.solver_config(), steps)
    scfg = config.solver_config()
    print(
        f"splishsplash: {len(paths)} scene(s) in {args.splishsplash} ({', '.join(p.name for p in paths.values())}; "
        f"solid.obj from {len(solid)} solid particles; r {scfg.particle_radius:g} m, dt {scfg.dt:g} s, {steps} steps, "
        f"mu {scfg.viscosity:g} Pa s, mu_b {scfg.wall_viscosity:g} Pa s)"
    )


def run_command(args: argparse.Namespace) -> int:
    import h5py

    from fluidsim.files import check_input_file, check_not_input, check_writable
    from nbv.export.particles import check_recorded, check_vtk_folder, check_vtk_source, export_vtk
    from nbv.export.solid import solid_of_file

    check_input_file(args.h5, "H5", "pass an OUT.h5 (fluidgs sim) or a RESULT.h5 (fluidgs simulate)")
    is_hdf5 = h5py.is_hdf5(args.h5)
    if is_hdf5:  # an HDF5 signature on a truncated or damaged file: h5py says so only when it opens it
        try:
            h5py.File(args.h5, "r").close()
        except (OSError, RuntimeError) as exc:
            raise ValueError(
                f"H5 {args.h5} is a truncated or damaged HDF5 file ({exc}); pass a complete OUT.h5 or RESULT.h5, "
                "or write it again"
            ) from None
    if not is_hdf5 and args.splishsplash is None:  # the input first: a wrong file is named before a missing option
        raise ValueError(f"H5 {args.h5} is not an HDF5 file; pass an OUT.h5 (fluidgs sim) or a RESULT.h5")
    if args.vtk is None and args.solid is None and args.splishsplash is None:
        raise ValueError(
            "export: nothing to write; pass --vtk DIR (particle frames), --solid PATH (the solid) and/or "
            "--splishsplash DIR (SPlisHSPlasH scenes)"
        )
    if not is_hdf5 and (args.vtk is not None or args.solid is not None):
        raise ValueError(f"H5 {args.h5} is not an HDF5 file; pass an OUT.h5 (fluidgs sim) or a RESULT.h5")
    outputs = {"--vtk": args.vtk, "--splishsplash": args.splishsplash, **solid_export_outputs(args.solid)}
    outputs = {label.replace("--export-solid", "--solid"): path for label, path in outputs.items()}
    check_not_input(outputs, {"H5": args.h5}, replaced={"--vtk": args.vtk})
    probes = None
    if args.probe is not None:
        from fluidsim.directions import DIRECTIONS

        probes = tuple(d.strip() for d in args.probe.split(",") if d.strip())
        bad = [d for d in probes if d not in DIRECTIONS]
        if bad or not probes:
            raise ValueError(f"--probe {args.probe!r}: use a comma list of {','.join(DIRECTIONS)}")
    if args.vtk is not None:
        kind = check_vtk_source(args.h5)
        check_vtk_folder(args.vtk, outputs)
        if probes is not None and kind != "result":
            raise ValueError("--probe applies to a RESULT.h5 with recorded probes; drop it for an OUT.h5")
        if probes is not None:
            check_recorded(args.h5, probes)
    if args.splishsplash is not None:
        if args.splishsplash.exists() and not args.splishsplash.is_dir():
            raise ValueError(f"--splishsplash {args.splishsplash} exists and is not a folder; name a folder")
        check_writable(args.splishsplash / "solid.obj")  # before the solid is made
        write_splash_scenes(args, is_hdf5, probes)
    solid = solid_of_file(args.h5) if args.solid is not None else None
    if args.vtk is not None:
        info = export_vtk(args.h5, args.vtk, probes, progress=True)
        for name, n in info["series"].items():
            print(f"{name}: {n} frames -> {args.vtk / (name + '.pvd')}")
        print(f"vtk: {info['files']} files in {args.vtk} (open the .pvd in ParaView; solid.vtu is the solid)")
    if solid is not None:
        from nbv.export.solid import export_solid

        try:
            info = export_solid(args.solid, *solid, frame=args.export_frame)
        except ValueError as exc:
            raise ValueError(f"--solid {args.solid}: {exc}") from None
        print_solid_export(info)
    return 0
