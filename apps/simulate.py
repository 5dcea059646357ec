"""`fluidgs simulate GAUSSIANS.ply -o RESULT.h5`: the five probes against a Gaussian set, per-Gaussian D_g.

Writes RESULT.h5 (layout in :func:`nbv.physics.save_result`: per-probe and combined D_g, counts, D-bar,
the empty-scene D-bar, step statistics, solid particles), a ``.ply`` of the Gaussians coloured by D_g
(SH degree 0; opens in common 3DGS viewers) and, with ``--video``, an MP4 of one probe.

A probe that diverges ends the run with exit code 3: RESULT.h5 then holds the probes completed before it, with
status "diverged" and the probe, step and reason (no coloured .ply). No output may be one of the inputs.
"""

from __future__ import annotations

import argparse
import json
import logging
import tempfile
from pathlib import Path

from .runtime import positive_int

log = logging.getLogger("fluidgs")


def add_frame_arguments(g, cameras: bool = False, scale: bool = True, crop: bool = True) -> None:
    """--up (alias --up-axis), --scale and --crop: the scene -> simulation frame (:mod:`nbv.scene_frame`).

    ``cameras``: the command has cameras, so ``--up auto`` (their mean up vector) is offered."""
    auto = ", or 'auto': the cameras' mean up vector (logged)" if cameras else ""
    g.add_argument("--up", "--up-axis", dest="up", default="+y", metavar="UP",
                   help=f"the scene's up direction, rotated to simulation +y: +x, -x, +y, -y, +z, -z or a vector such "
                        f"as 0,-1,0 (COLMAP captures are often -y){auto} (default: +y)")
    if scale:
        g.add_argument("--scale", default="auto",
                       help="metres per scene unit, or 'auto': the robust object box's largest extent -> 2 m, the "
                            "paper's domain (default: auto)")
    if crop:
        g.add_argument("--crop", default=None, metavar="BOX",
                       help="keep only the Gaussians inside xmin,ymin,zmin,xmax,ymax,zmax (scene units), or 'auto': "
                            "the robust object box grown by 10 %% per side (default: keep all)")


def up_from_args(args: argparse.Namespace, cameras=None):
    """``args.up`` resolved: an up spec for PhysicsConfig ('auto' -> the cameras' mean up vector, logged)."""
    from nbv.scene_frame import describe_auto_up, parse_up

    if str(args.up).strip().lower() != "auto":
        parse_up(args.up)  # the error names --up
        return args.up
    if not cameras:
        raise ValueError("--up auto takes the up direction from cameras, and this command has none; give the up "
                         "direction (--up -y for a y-down COLMAP capture, --up +z for a z-up scene)")
    from recon.frames import up_from_cameras

    up = up_from_cameras(cameras)
    log.info("%s", describe_auto_up(up))
    return tuple(float(c) for c in up)


def add_physics_arguments(p: argparse.ArgumentParser, track_distinct: bool = False,
                          empty_reference: bool = True, cameras: bool = False) -> None:
    """The probe options shared by simulate, score, sweep, critical and bench score (``empty_reference``:
    offer --no-empty-reference; commands that never run the empty scene leave it out)."""
    g = p.add_argument_group("probes")
    g.add_argument("--quick", action="store_true",
                   help="quick preset: particle radius 0.05 m and 300 steps per probe (unless given explicitly)")
    g.add_argument("--particle-radius", type=float, default=None,
                   help="fluid particle radius r in m (default: 0.025, the paper's; 0.05 with --quick)")
    g.add_argument("--steps", type=int, default=None,
                   help="time steps per probe (default: 750, the paper's; 300 with --quick)")
    g.add_argument("--dt", type=float, default=0.002, help="time step in s")
    g.add_argument("--speed", type=float, default=3.0, help="inflow speed lambda of the horizontal probes in m/s")
    g.add_argument("--viscosity", type=float, default=10.0, help="dynamic viscosity mu in Pa s")
    g.add_argument("--directions", default=None,
                   help="comma list of probes out of -x,+x,-z,+z,-y (default: all five)" if not track_distinct else
                   "comma list of probes out of -x,+x,-z,+z,-y (default: -x)")
    g.add_argument("--accumulate-every", type=int, default=1, help="accumulate D_i onto the Gaussians every k steps")
    g.add_argument("--opacity-threshold", type=float, default=0.3,
                   help="tau: combined opacity at or above which a lattice point is solid (unitless, 0..1)")
    add_frame_arguments(g, cameras=cameras)
    g.add_argument("--no-fill", action="store_true",
                   help="keep the solid hollow: do not fill what the Gaussians enclose (filling is the default)")
    g.add_argument("--fill-cavities", action="store_true",
                   help="accepted for old scripts and does nothing: filling is now the default (see --no-fill)")
    if empty_reference:
        g.add_argument("--no-empty-reference", action="store_true",
                       help="skip the empty-scene D-bar reference (halves the run time)")
    g.add_argument("--max-memory-gb", type=float, default=None,
                   help="refuse to start above this estimated memory in GiB (default: the available memory)")
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                   help="compute device; cuda falls back to cpu with a logged warning")
    p.add_argument("--threads", type=positive_int, default=None, help="CPU threads (default: all cores)")


def physics_config_from_args(args: argparse.Namespace, track_distinct: bool = False, default_directions=None,
                             cameras=None):
    """A validated :class:`nbv.physics.PhysicsConfig` from the shared options (``cameras`` for ``--up auto``)."""
    from nbv.physics import QUICK, PhysicsConfig, parse_directions
    from nbv.scene_frame import parse_crop

    radius = args.particle_radius if args.particle_radius is not None else \
        (QUICK["particle_radius"] if args.quick else 0.025)
    steps = args.steps if args.steps is not None else (QUICK["steps"] if args.quick else 750)
    if args.directions is not None:
        dirs = parse_directions(args.directions)
    else:
        dirs = default_directions or ("-x", "+x", "-z", "+z", "-y")
    scale = args.scale
    if scale != "auto":
        try:
            scale = float(scale)
        except ValueError as exc:
            raise ValueError(f"--scale must be 'auto' or a number of metres per scene unit, got {scale!r}") from exc
    return PhysicsConfig(particle_radius=radius, steps=steps, dt=args.dt, speed=args.speed, viscosity=args.viscosity,
                         directions=tuple(dirs), accumulate_every=args.accumulate_every,
                         opacity_threshold=args.opacity_threshold, up=up_from_args(args, cameras), scale=scale,
                         crop=parse_crop(args.crop),
                         fill_cavities=not getattr(args, "no_fill", False), track_distinct=track_distinct,
                         empty_reference=not getattr(args, "no_empty_reference", True),
                         max_memory_gb=args.max_memory_gb)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("gaussians", type=Path, help="Gaussians (.ply, .compressed.ply, .spz, .splat, .npz), scene units")
    p.add_argument("-o", "--output", type=Path, required=True, help="result HDF5 file (written atomically)")
    p.add_argument("--ply", type=Path, default=None,
                   help="Gaussians coloured by D_g (default: the output path with suffix _divergence.ply)")
    p.add_argument("--video", default=None, metavar="PROBE",
                   help="also draw this probe (e.g. -x) as an MP4 next to the output (re-runs that probe)")
    p.add_argument("--video-every", type=int, default=10, help="steps between video frames")
    add_record_arguments(p)
    add_physics_arguments(p)


def add_record_arguments(p: argparse.ArgumentParser) -> None:
    """--record-probe, --record-every, --record-max-gb: keep probes' fluid in RESULT.h5 for `fluidgs view`."""
    g = p.add_argument_group("trajectories (for `fluidgs view`)")
    g.add_argument("--record-probe", default=None, metavar="DIRS",
                   help="record these probes' fluid (positions, D_i, speed) every --record-every steps into RESULT.h5, "
                        "to replay them in `fluidgs view`: a probe (-x) or a comma list (default: none; the file stays "
                        "small)")
    g.add_argument("--record-every", type=int, default=10, metavar="K",
                   help="steps between recorded frames (default: 10); each frame costs 16 bytes per fluid particle")
    g.add_argument("--record-max-gb", type=float, default=2.0,
                   help="refuse, before simulating, a recording larger than this in GiB (default: 2)")


def record_config_from_args(args: argparse.Namespace, config):
    """A :class:`nbv.trajectory.RecordConfig` from --record-probe (None without it), checked against the probes of
    ``config``."""
    if getattr(args, "record_probe", None) is None:
        return None
    from nbv.physics import parse_directions
    from nbv.trajectory import RecordConfig

    try:
        dirs = parse_directions(args.record_probe)
    except ValueError as exc:
        raise ValueError(str(exc).replace("--directions", "--record-probe", 1)) from None
    if not (args.record_max_gb and args.record_max_gb > 0):
        raise ValueError(f"--record-max-gb must be > 0, got {args.record_max_gb}")
    record = RecordConfig(dirs, args.record_every, args.record_max_gb * 2**30)
    record.check_probes(config.directions, config.steps)
    return record


def load_gaussians_checked(path: Path):
    """Load a Gaussian set of any supported format (recon.formats); ValueError naming the file when it is missing,
    a folder or unreadable."""
    from recon.formats import SUPPORTED, load_gaussians

    if not Path(path).exists():  # a folder exists: recon.formats says it is a folder
        raise ValueError(f"Gaussian file {path} does not exist; pass a Gaussian file ({SUPPORTED})")
    return load_gaussians(path).check(str(path))


def default_ply_path(output: Path) -> Path:
    return output.with_name(output.stem + "_divergence.ply")


def write_colored_ply(gaussians, divergence, path: Path) -> Path:
    """The Gaussians coloured by D_g (TURBO map, 99th percentile at the top) as a 3DGS .ply."""
    from nbv.heatmap import colored_gaussians
    from recon.ply import save_gaussians

    return save_gaussians(colored_gaussians(gaussians, divergence), path)


def write_probe_video(result, direction: str, out: Path, every: int = 10, progress: bool = True) -> Path:
    """Re-run one probe of ``result`` against its solid and draw it as an H.264 MP4 (plays in browsers) coloured by
    divergence."""
    from fluidsim.probes import build_probe_solver, probe_setup
    from viz.frames import FrameStyle, render_frames

    from .sim import simulate_to_h5

    cfg = result.config
    if direction not in cfg.directions and direction not in ("-x", "+x", "-z", "+z", "-y"):
        raise ValueError(f"--video: unknown probe {direction!r}; use one of -x,+x,-z,+z,-y")
    scfg, probe = cfg.solver_config(), cfg.probe_config()
    setup = probe_setup(result.solid, direction, probe, scfg.spacing)
    solver = build_probe_solver(result.solid, setup, scfg, probe)
    scene = {"probe": direction, "velocity": list(setup.velocity),
             "domain": {"min": list(setup.domain_min), "max": list(setup.domain_max), "walls": probe.walls},
             "particle_radius": scfg.particle_radius, "dt": scfg.dt, "steps": cfg.steps}
    with tempfile.TemporaryDirectory(dir=out.parent) as tmp:
        h5, _ = simulate_to_h5(solver, scene, Path(tmp) / "probe.h5", cfg.steps, every, desc=f"video {direction}",
                               progress=progress)
        render_frames(h5, out, FrameStyle(view="iso", width=640, height=480), progress=progress)
    return out


def check_output_file(path: Path, suffixes: tuple[str, ...]) -> Path:
    """Fail before any work when ``path`` has the wrong suffix or its folder is not writable."""
    from fluidsim.output import check_writable

    if suffixes and Path(path).suffix.lower() not in suffixes:
        raise ValueError(f"output {path} must end with {' or '.join(suffixes)}")
    return check_writable(path)


def write_json(path: Path, data) -> Path:
    """JSON, atomically (:func:`fluidsim.output.atomic_output`: a temporary file in the same folder, then rename)."""
    from fluidsim.output import atomic_output

    with atomic_output(path) as tmp:
        tmp.write_text(json.dumps(data, indent=2))
    return Path(path)


def save_diverged(exc, path: Path | None) -> int:
    """A probe diverged (:class:`nbv.physics.ProbeDiverged`): save the probes completed before it to ``path``
    (RESULT.h5 with status "diverged"; nothing when None), log one line naming the probe and the step; returns 3."""
    from nbv.physics import save_result

    if path is None:
        log.error("%s; nothing saved (pass --save-result to keep the completed probes)", exc)
        return 3
    save_result(path, exc.result)
    log.error("%s; the completed probes are saved to %s (status 'diverged'); reduce --dt or --speed", exc, path)
    return 3


def result_summary(result) -> dict:
    """A JSON-able summary of a PhysicsResult (D-bar, per-probe statistics, timings)."""
    import numpy as np

    probes = {}
    for i, d in enumerate(result.directions):
        st = result.stats[d]
        probes[d] = {"mean_D": float(result.per_probe[i].mean()), "max_D": float(result.per_probe[i].max()),
                     "touched_gaussians": int((result.per_probe_counts[i] > 0).sum()),
                     "mean_density_iterations": float(np.mean(st["density_iterations"])) if len(st) else 0.0,
                     "mean_divergence_iterations": float(np.mean(st["divergence_iterations"])) if len(st) else 0.0,
                     "retired": int(np.sum(st["retired"])) if len(st) else 0}
        if d in result.leaks:
            lk = result.leaks[d]
            probes[d]["leaked"] = {"final": lk.final, "max": lk.max, "max_step": lk.max_step}
    return {"gaussians": result.num_gaussians, "solid_particles": int(len(result.solid)),
            "scale_m_per_unit": float(result.transform.scale), "dbar_m4_s": result.dbar,
            "dbar_mean_m4_s": result.dbar_mean, "dbar_empty_m4_s": result.dbar_empty, "probes": probes,
            "timings_s": result.timings, "config": result.config.to_dict()}


def run_command(args: argparse.Namespace) -> int:
    from fluidsim.output import check_not_input, check_writable
    from nbv.physics import ProbeDiverged, save_result, simulate_gaussians

    from .runtime import init_taichi

    config = physics_config_from_args(args)
    output = check_output_file(args.output, (".h5", ".hdf5"))
    ply = args.ply or default_ply_path(output)
    video = output.with_name(f"{output.stem}_probe{args.video}.mp4") if args.video is not None else None
    check_not_input({"-o": output, "--ply": ply, "--video": video}, {"GAUSSIANS": args.gaussians})
    check_output_file(ply, (".ply",))
    if args.video is not None:
        from nbv.physics import parse_directions

        if len(parse_directions(args.video)) != 1:
            raise ValueError(f"--video takes one probe (e.g. -x), got {args.video!r}")
        if args.video_every < 1:
            raise ValueError(f"--video-every must be >= 1 step, got {args.video_every}")
        check_writable(video)
    record = record_config_from_args(args, config)
    gaussians = load_gaussians_checked(args.gaussians)
    init_taichi(args.device, config.precision, args.threads)
    try:
        result = simulate_gaussians(gaussians, config, progress=True, source=str(args.gaussians), record=record)
    except ProbeDiverged as exc:
        return save_diverged(exc, output)
    save_result(output, result)
    write_colored_ply(gaussians, result.divergence, ply)
    s = result_summary(result)
    print(f"{result.num_gaussians} Gaussians, {len(result.solid)} solid particles, scale {result.transform.scale:.4g} "
          "m/unit")
    for d, pr in s["probes"].items():
        print(f"  probe {d:>3}: mean D_g {pr['mean_D']:.4g} 1/s, max {pr['max_D']:.4g} 1/s, "
              f"{pr['touched_gaussians']} Gaussians reached, {pr['retired']} retired"
              + (f", leaked into the solid: {pr['leaked']['final']} at the end, at most {pr['leaked']['max']} "
                 f"(step {pr['leaked']['max_step']})" if "leaked" in pr else ""))
        for w in result.warnings.get(d, []):
            print(f"    WARNING: {w}")
    empty = "n/a" if result.dbar_empty is None else f"{result.dbar_empty:.4g}"
    print(f"D-bar {result.dbar:.4g} m^4/s (mean-combined {result.dbar_mean:.4g}; empty scene {empty})")
    t = result.timings
    print(f"time: simulation {t['simulation']:.1f} s, aggregation {t['aggregation']:.2f} s, "
          f"empty reference {t['empty_reference']:.1f} s, total {t['total']:.1f} s")
    print(f"result: {output}\ncoloured Gaussians: {ply}")
    if video is not None:
        write_probe_video(result, args.video, video, args.video_every)
        print(f"video: {video}")
    print(f"see it in a browser: fluidgs view {output} --gaussians {args.gaussians}")
    return 0
