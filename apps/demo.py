"""`fluidgs demo`: the project's main job on the bundled Ahmed body, in about two minutes on a 2-core CPU.

Default: the Gaussians of ``assets/ahmed_gaussians.ply`` (when the bundled asset is missing: Gaussians sampled
on the surface of the Ahmed body mesh of :mod:`recon.ahmed`, said so in the log and in summary.json) go
through the five probes of the paper at the quick preset (r = 0.05 m, 300 steps per probe), then

- ``result.h5`` (per-probe and combined D_g, D-bar; :func:`nbv.physics.save_result`),
- ``gaussians_divergence.ply``: the Gaussians coloured by D_g (opens in 3DGS viewers),
- ``scores.json`` and ``views/``: the candidate cameras ranked by S(T) (paper Eq. 4-5), one PNG per view
  (render | D_g heat-map). The cameras: ``--cameras`` (``orbit:N`` or a camera file); without it
  ``assets/ahmed_cameras.json`` for the bundled Gaussians, and for any other Gaussians (``--gaussians``, or the
  surface samples) ``orbit:12`` around their robust object box, said so in the log and written to ``cameras.json``,
- ``probe_-x.mp4``: the -x probe, coloured by divergence,
- ``summary.json``: D-bar, per-probe figures, timings.

``--solid MESH`` keeps the earlier demo: five probes against a sampled mesh (``assets/torus.obj``), one HDF5
per probe, ``summary.json`` and an MP4 of the -x probe.
"""

from __future__ import annotations

import argparse
import logging
import os
import time
from pathlib import Path

from fluidsim.directions import DIRECTIONS
from fluidsim.files import write_json_atomic

from .options import (
    CAMERAS_HELP,
    add_config_options,
    add_frame_arguments,
    add_gaussian_file_arguments,
    add_orbit_arguments,
    add_runtime_arguments,
    camera_file_from_args,
    load_gaussians_checked,
    orbit_cameras_logged,
    orbit_from_args,
    physics_config_from_args,
    warn_frame,
)

log = logging.getLogger("fluidgs")
ASSETS = Path(__file__).resolve().parent.parent / "assets"
ASSET = ASSETS / "torus.obj"
GAUSSIANS = ASSETS / "ahmed_gaussians.ply"
CAMERAS = ASSETS / "ahmed_cameras.json"
MESH_RADIUS, MESH_STEPS = 0.04, 200  # the mesh demo (--solid): particle radius r in m, steps per probe
DEMO_ORBIT = 12  # cameras of the orbit scored on Gaussians other than the bundled ones


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("-o", "--output", type=Path, default=Path("out/demo"), help="output folder")
    p.add_argument(
        "--solid",
        type=Path,
        default=None,
        help=f"run the mesh demo on this solid mesh instead (.obj/.stl/.ply; e.g. assets/{ASSET.name})",
    )
    p.add_argument(
        "--gaussians",
        type=Path,
        default=None,
        help=f"Gaussian set (default: assets/{GAUSSIANS.name}, else Gaussians on the Ahmed body surface)",
    )
    p.add_argument(
        "--cameras",
        default=None,
        metavar="CAMERAS",
        help=f"{CAMERAS_HELP} (default: assets/{CAMERAS.name} for the bundled Gaussians, else orbit:{DEMO_ORBIT})",
    )
    add_orbit_arguments(p)
    add_gaussian_file_arguments(p)
    from nbv.physics import QUICK, PhysicsConfig

    add_frame_arguments(p, scale=False, crop=False)
    add_config_options(
        p,
        PhysicsConfig,
        ("particle_radius", "steps", "speed"),
        {
            "particle_radius": {
                "default_text": f"{QUICK['particle_radius']}, the quick preset; {MESH_RADIUS} for --solid"
            },
            "steps": {"default_text": f"{QUICK['steps']}, the quick preset; {MESH_STEPS} for --solid"},
        },
    )
    p.add_argument(
        "--render-width",
        type=int,
        default=240,
        help="width of the scored views in pixels (the cameras of a file are scaled to it, up as well as down, "
        "so the bundled 64 px cameras give sharp PNGs)",
    )
    p.add_argument("--no-video", action="store_true", help="skip the MP4 of the -x probe")
    add_runtime_arguments(p)


DEMO_FILES = (
    "result.h5",
    "gaussians_divergence.ply",
    "scores.json",
    "summary.json",
    "probe_-x.mp4",
    "cameras.json",
    *(f"probe_{d}.h5" for d in DIRECTIONS),
)


def run_command(args: argparse.Namespace) -> int:
    from fluidsim.files import check_not_input
    from nbv.orbit import orbit_count

    orbit_spec = args.cameras is not None and orbit_count(args.cameras) is not None
    check_not_input(
        [("-o (demo file)", Path(args.output) / name) for name in DEMO_FILES],
        {"--solid": args.solid, "--gaussians": args.gaussians, "--cameras": None if orbit_spec else args.cameras},
    )
    if args.solid is not None:
        return run_mesh_demo(args)
    from nbv.coverage import agreement_lines
    from nbv.outputs import divergence_columns, probe_video, result_summary, save_colored_gaussians
    from nbv.physics import QUICK, save_result, simulate_gaussians
    from nbv.view_scoring import check_cameras_see, format_table, rows_agreement, score_views
    from recon.ahmed import ahmed_surface_gaussians
    from recon.camera_files import transforms_json

    from .runtime import init_taichi

    t0 = time.perf_counter()
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    if not os.access(out, os.W_OK):
        raise OSError(f"output folder {out} is not writable; pass another -o")
    gpath = args.gaussians or (GAUSSIANS if GAUSSIANS.is_file() else None)
    bundled = gpath is not None and Path(gpath).resolve() == GAUSSIANS.resolve()
    if args.cameras is None:  # the bundled cameras belong to the bundled Gaussians only
        spec = str(CAMERAS) if bundled and CAMERAS.is_file() else f"orbit:{DEMO_ORBIT}"
        args = argparse.Namespace(**{**vars(args), "cameras": spec})
        if not bundled:
            log.info(
                "no --cameras: scoring orbit:%d, an orbit around %s (pass --cameras for your own)",
                DEMO_ORBIT,
                gpath or "the Ahmed body samples",
            )
    orbit = orbit_from_args(args, args.render_width)
    file_cams = None if orbit is not None else camera_file_from_args(args)
    cfg = physics_config_from_args(args, preset=QUICK, empty_reference=False, cameras=file_cams)
    if gpath is not None:
        gaussians, source = load_gaussians_checked(gpath, args), str(gpath)
    else:
        log.warning("%s is not there yet: using Gaussians sampled on the Ahmed body mesh surface", GAUSSIANS)
        gaussians, source = ahmed_surface_gaussians(), "Ahmed body surface samples (recon.ahmed)"
    warn_frame(cfg, file_cams, up_given=args.up is not None or bundled)
    cams = (
        [c.scaled(args.render_width / c.width) for c in file_cams]
        if orbit is None
        else orbit_cameras_logged(gaussians, cfg, orbit)
    )
    cpath = None if orbit is None else Path(args.output) / "cameras.json"
    if cpath is not None:
        write_json_atomic(cpath, transforms_json(cams, f"fluidgs demo --cameras {args.cameras}: {orbit.describe()}"))
    cameras_label = str(args.cameras) if orbit is None else f"{args.cameras} ({cpath})"
    centres = check_cameras_see(gaussians, cams, [c.name for c in cams])
    init_taichi(args.device, cfg.precision, args.threads)
    from nbv.physics.trajectory import RecordConfig  # the -x probe's fluid, for `fluidgs view`

    result = simulate_gaussians(
        gaussians,
        cfg,
        progress=True,
        source=source,
        record=RecordConfig(("-x",), every=max(1, cfg.steps // 30)),
        source_frame=getattr(args, "source_frame", ""),
    )
    save_result(out / "result.h5", result)
    save_colored_gaussians(
        gaussians, result.divergence, out / "gaussians_divergence.ply", divergence_columns(result), result.reached
    )
    rows = score_views(
        gaussians,
        cams,
        list(range(len(cams))),
        result,
        "max",
        out / "views",
        device=args.device,
        visible_centres=centres,
    )
    agreement = rows_agreement(rows)
    print(format_table(rows))
    print("\n".join(agreement_lines(agreement)))
    write_json_atomic(
        out / "scores.json",
        {
            "cameras": str(cpath or args.cameras),
            "gaussians": source,
            "views": rows,
            "agreement": agreement,
            "dbar_m4_s": result.dbar,
            "config": cfg.to_dict(),
        },
    )
    if not args.no_video:
        probe_video(result, "-x", out / "probe_-x.mp4")
    summary = result_summary(result)
    summary.update(source=source, cameras=cameras_label, wall_time_s=time.perf_counter() - t0)
    write_json_atomic(out / "summary.json", summary)
    print(f"{result.num_gaussians} Gaussians ({source}); D-bar {result.dbar:.2g} m^4/s; best view {rows[0]['name']}")
    print(
        f"outputs in {out}: result.h5, gaussians_divergence.ply, scores.json, views/, summary.json"
        + ("" if args.no_video else ", probe_-x.mp4")
        + f" ({summary['wall_time_s']:.0f} s)"
    )
    print(
        f"see them in a browser: fluidgs view {out / 'result.h5'}"
        + (f" --gaussians {gpath}" if gpath else "")
        + f" --scores {out / 'scores.json'}"
    )
    return 0


def run_mesh_demo(args: argparse.Namespace) -> int:
    """The mesh demo: five probes against a sampled solid mesh (``--solid``)."""
    from .runtime import init_taichi

    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    if not os.access(out, os.W_OK):
        raise OSError(f"output folder {out} is not writable; pass another -o")
    init_taichi(args.device, "f32", args.threads)
    steps = args.steps or MESH_STEPS
    from fluidsim import ProbeConfig, SolverConfig
    from fluidsim.recording import probes_to_h5
    from fluidsim.sources import mesh_particles

    def report(d: str, s: dict) -> None:
        print(
            f"probe {d}: {s['fluid_particles']} fluid particles, mean D_i {s['mean_particle_divergence']:.3f} 1/s "
            f"(p95 {s['p95_particle_divergence']:.3f}), {s['retired']} retired -> {out / s['file']}"
        )

    cfg = SolverConfig(particle_radius=args.particle_radius or MESH_RADIUS)
    solid = mesh_particles(args.solid, cfg.spacing, fill=True)
    probe = ProbeConfig(**({} if args.speed is None else {"speed": args.speed}))
    summary = probes_to_h5(solid, cfg, probe, steps, out, str(args.solid), on_probe=report)
    write_json_atomic(out / "summary.json", summary)
    if not args.no_video:
        from viz.frames import FrameStyle, render_frames

        render_frames(out / "probe_-x.h5", out / "probe_-x.mp4", FrameStyle(view="iso"), progress=True)
        print(f"video: {out / 'probe_-x.mp4'}")
    print(f"summary: {out / 'summary.json'}")
    return 0
