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
import time
from pathlib import Path

from fluidsim.files import write_json_atomic

from .options import load_gaussians_checked, physics_config_from_args, warn_frame
from .options.cameras import candidate_cameras_from_args, orbit_cameras_logged, write_orbit_cameras
from .options.demo import CAMERAS, DEMO_FILES, DEMO_ORBIT, GAUSSIANS, add_demo_arguments, output_folder, run_mesh_demo

log = logging.getLogger("fluidgs")


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_demo_arguments(p)


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
    from nbv.outputs import probe_video, result_summary
    from nbv.physics import QUICK
    from nbv.view_scoring import check_cameras_see, format_table, rows_agreement, score_views

    t0 = time.perf_counter()
    out = output_folder(args.output)
    gpath = args.gaussians or (GAUSSIANS if GAUSSIANS.is_file() else None)
    bundled = gpath is not None and Path(gpath).resolve() == GAUSSIANS.resolve()
    args = with_default_cameras(args, gpath, bundled)
    orbit, file_cams = candidate_cameras_from_args(args, args.render_width)
    cfg = physics_config_from_args(args, preset=QUICK, empty_reference=False, cameras=file_cams)
    gaussians, source = demo_gaussians(gpath, args)
    warn_frame(cfg, file_cams, up_given=args.up is not None or bundled)
    cpath = None if orbit is None else Path(args.output) / "cameras.json"
    if orbit is None:
        cams = [c.scaled(args.render_width / c.width) for c in file_cams]
    else:
        cams = orbit_cameras_logged(gaussians, cfg, orbit)
        write_orbit_cameras(cpath, cams, "demo", args.cameras, orbit)
    cameras_label = str(args.cameras) if orbit is None else f"{args.cameras} ({cpath})"
    centres = check_cameras_see(gaussians, cams, [c.name for c in cams])
    result = simulate_demo(gaussians, cfg, source, args, out)
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
        probe_video(result, "-x", out / "probe_-x.mp4", saved=out / "result.h5")  # drawn from the recorded run
    summary = result_summary(result)
    summary.update(source=source, cameras=cameras_label, wall_time_s=time.perf_counter() - t0)
    write_json_atomic(out / "summary.json", summary)
    print_outputs(out, result, source, rows, summary, gpath, args.no_video)
    return 0


def with_default_cameras(args: argparse.Namespace, gpath, bundled: bool) -> argparse.Namespace:
    """``args`` with --cameras filled in when not given: the bundled cameras for the bundled Gaussians only, else
    orbit:DEMO_ORBIT (logged)."""
    if args.cameras is not None:
        return args
    spec = str(CAMERAS) if bundled and CAMERAS.is_file() else f"orbit:{DEMO_ORBIT}"
    if not bundled:
        log.info(
            "no --cameras: scoring orbit:%d, an orbit around %s (pass --cameras for your own)",
            DEMO_ORBIT,
            gpath or "the Ahmed body samples",
        )
    return argparse.Namespace(**{**vars(args), "cameras": spec})


def demo_gaussians(gpath, args: argparse.Namespace) -> tuple:
    """(Gaussians, source text): the file ``gpath``, or when there is none Gaussians on the Ahmed body surface."""
    from recon.ahmed import ahmed_surface_gaussians

    if gpath is not None:
        return load_gaussians_checked(gpath, args), str(gpath)
    log.warning("%s is not there yet: using Gaussians sampled on the Ahmed body mesh surface", GAUSSIANS)
    return ahmed_surface_gaussians(), "Ahmed body surface samples (recon.ahmed)"


def print_outputs(out: Path, result, source: str, rows: list[dict], summary: dict, gpath, no_video: bool) -> None:
    """The closing lines: the forces on the solid, D-bar and the best view, the outputs, the `fluidgs view` command."""
    from nbv.physics.forces import force_lines

    print("\n".join(force_lines(result.forces)))
    print(f"{result.num_gaussians} Gaussians ({source}); D-bar {result.dbar:.2g} m^4/s; best view {rows[0]['name']}")
    print(
        f"outputs in {out}: result.h5, gaussians_divergence.ply, scores.json, views/, summary.json"
        + ("" if no_video else ", probe_-x.mp4")
        + f" ({summary['wall_time_s']:.0f} s)"
    )
    print(
        f"see them in a browser: fluidgs view {out / 'result.h5'}"
        + (f" --gaussians {gpath}" if gpath else "")
        + f" --scores {out / 'scores.json'}"
    )


def simulate_demo(gaussians, cfg, source: str, args: argparse.Namespace, out: Path):
    """The five probes (the -x probe's fluid recorded for `fluidgs view`, at the video's frame spacing unless
    --no-video), saved as result.h5 and the Gaussians coloured by D_g."""
    from nbv.outputs import divergence_columns, save_colored_gaussians
    from nbv.physics import save_result, simulate_gaussians

    from .options.scoring import empty_worker_setup
    from .runtime import init_taichi

    used = init_taichi(args.device, cfg.precision, args.threads)
    from nbv.outputs import VIDEO_EVERY
    from nbv.physics.trajectory import RecordConfig  # the -x probe's fluid, for `fluidgs view` and the video

    result = simulate_gaussians(
        gaussians,
        cfg,
        progress=True,
        source=source,
        record=RecordConfig(("-x",), every=max(1, cfg.steps // 30) if args.no_video else VIDEO_EVERY),
        source_frame=getattr(args, "source_frame", ""),
        empty_worker=empty_worker_setup(used, cfg.precision, args.threads),
    )
    save_result(out / "result.h5", result)
    save_colored_gaussians(
        gaussians, result.divergence, out / "gaussians_divergence.ply", divergence_columns(result), result.reached
    )
    return result
