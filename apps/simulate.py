"""`fluidgs simulate GAUSSIANS.ply -o RESULT.h5`: the five probes against a Gaussian set, per-Gaussian D_g.

Writes RESULT.h5 (layout in :func:`nbv.physics.save_result`: per-probe and combined D_g, counts, D-bar,
the empty-scene D-bar, step statistics, solid particles), a ``.ply`` of the Gaussians coloured by D_g
(SH degree 0; opens in common 3DGS viewers) and, with ``--video``, an MP4 of one probe.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import tempfile
from pathlib import Path

log = logging.getLogger("fluidgs")


def add_physics_arguments(p: argparse.ArgumentParser, track_distinct: bool = False,
                          empty_reference: bool = True) -> None:
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
    g.add_argument("--up-axis", choices=("y", "z"), default="y", help="the scene's up axis (z-up is rotated to Y-up)")
    g.add_argument("--scale", default="auto",
                   help="metres per scene unit, or 'auto' (largest object extent -> 2 m, the paper's domain)")
    g.add_argument("--fill-cavities", action="store_true", help="fill enclosed empty regions of the solid")
    if empty_reference:
        g.add_argument("--no-empty-reference", action="store_true",
                       help="skip the empty-scene D-bar reference (halves the run time)")
    g.add_argument("--max-memory-gb", type=float, default=None,
                   help="refuse to start above this estimated memory in GiB (default: the available memory)")
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                   help="compute device; cuda falls back to cpu with a logged warning")
    p.add_argument("--threads", type=int, default=None, help="CPU threads (default: all cores)")


def physics_config_from_args(args: argparse.Namespace, track_distinct: bool = False, default_directions=None):
    """A validated :class:`nbv.physics.PhysicsConfig` from the shared options."""
    from nbv.physics import QUICK, PhysicsConfig, parse_directions

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
                         opacity_threshold=args.opacity_threshold, up_axis=args.up_axis, scale=scale,
                         fill_cavities=args.fill_cavities, track_distinct=track_distinct,
                         empty_reference=not getattr(args, "no_empty_reference", True),
                         max_memory_gb=args.max_memory_gb)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("gaussians", type=Path, help="3DGS Gaussians (.ply or .npz), scene units")
    p.add_argument("-o", "--output", type=Path, required=True, help="result HDF5 file (written atomically)")
    p.add_argument("--ply", type=Path, default=None,
                   help="Gaussians coloured by D_g (default: the output path with suffix _divergence.ply)")
    p.add_argument("--video", default=None, metavar="PROBE",
                   help="also draw this probe (e.g. -x) as an MP4 next to the output (re-runs that probe)")
    p.add_argument("--video-every", type=int, default=10, help="steps between video frames")
    add_physics_arguments(p)


def load_gaussians_checked(path: Path):
    """Load a .ply/.npz Gaussian set; ValueError naming the file when it is missing or not 3DGS."""
    from recon.ply import load_gaussians

    if not Path(path).is_file():
        raise ValueError(f"Gaussian file {path} does not exist; pass a 3DGS .ply (or .npz)")
    return load_gaussians(path).check(str(path))


def default_ply_path(output: Path) -> Path:
    return output.with_name(output.stem + "_divergence.ply")


def write_colored_ply(gaussians, divergence, path: Path) -> Path:
    """The Gaussians coloured by D_g (TURBO map, 99th percentile at the top) as a 3DGS .ply."""
    from nbv.heatmap import colored_gaussians
    from recon.ply import save_gaussians

    return save_gaussians(colored_gaussians(gaussians, divergence), path)


def write_probe_video(result, direction: str, out: Path, every: int = 10, progress: bool = True) -> Path:
    """Re-run one probe of ``result`` against its solid and draw it as an MP4 coloured by divergence."""
    from fluidsim.probes import build_probe_solver, probe_setup

    from .render_frames import FrameStyle, render_frames
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
    """JSON, atomically (temporary file in the same folder, then rename)."""
    fd, tmp = tempfile.mkstemp(dir=Path(path).parent, prefix=f".{Path(path).name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as fh:
            json.dump(data, fh, indent=2)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return Path(path)


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
    return {"gaussians": result.num_gaussians, "solid_particles": int(len(result.solid)),
            "scale_m_per_unit": float(result.transform.scale), "dbar_m4_s": result.dbar,
            "dbar_mean_m4_s": result.dbar_mean, "dbar_empty_m4_s": result.dbar_empty, "probes": probes,
            "timings_s": result.timings, "config": result.config.to_dict()}


def run_command(args: argparse.Namespace) -> int:
    from nbv.physics import save_result, simulate_gaussians

    from .runtime import init_taichi

    config = physics_config_from_args(args)
    output = check_output_file(args.output, (".h5", ".hdf5"))
    ply = args.ply or default_ply_path(output)
    check_output_file(ply, (".ply",))
    if args.video is not None:
        from nbv.physics import parse_directions

        if len(parse_directions(args.video)) != 1:
            raise ValueError(f"--video takes one probe (e.g. -x), got {args.video!r}")
        if args.video_every < 1:
            raise ValueError(f"--video-every must be >= 1 step, got {args.video_every}")
    gaussians = load_gaussians_checked(args.gaussians)
    init_taichi(args.device, config.precision, args.threads)
    result = simulate_gaussians(gaussians, config, progress=True, source=str(args.gaussians))
    save_result(output, result)
    write_colored_ply(gaussians, result.divergence, ply)
    s = result_summary(result)
    print(f"{result.num_gaussians} Gaussians, {len(result.solid)} solid particles, scale {result.transform.scale:.4g} "
          "m/unit")
    for d, pr in s["probes"].items():
        print(f"  probe {d:>3}: mean D_g {pr['mean_D']:.4g} 1/s, max {pr['max_D']:.4g} 1/s, "
              f"{pr['touched_gaussians']} Gaussians reached, {pr['retired']} retired")
    empty = "n/a" if result.dbar_empty is None else f"{result.dbar_empty:.4g}"
    print(f"D-bar {result.dbar:.4g} m^4/s (mean-combined {result.dbar_mean:.4g}; empty scene {empty})")
    t = result.timings
    print(f"time: simulation {t['simulation']:.1f} s, aggregation {t['aggregation']:.2f} s, "
          f"empty reference {t['empty_reference']:.1f} s, total {t['total']:.1f} s")
    print(f"result: {output}\ncoloured Gaussians: {ply}")
    if args.video is not None:
        video = output.with_name(f"{output.stem}_probe{args.video}.mp4")
        write_probe_video(result, args.video, video, args.video_every)
        print(f"video: {video}")
    return 0
