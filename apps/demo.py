"""`fluidgs demo`: five fluid probes against the bundled solid, with HDF5 results, a summary and a video.

Until the Gaussian-scoring commands land, this is the project's main job on bundled assets: it samples
``assets/torus.obj`` (a closed mesh with a hole, so flow goes through it), runs the five probes of the
paper (-x, +x, -z, +z at 3 m/s and -y from rest) in one Taichi runtime, writes one HDF5 file per probe,
``summary.json`` (particle counts, iterations, mean divergence D_i near the solid per probe) and an MP4
of the -x probe coloured by divergence.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import tempfile
from pathlib import Path

import numpy as np

log = logging.getLogger("fluidgs")
ASSET = Path(__file__).resolve().parent.parent / "assets" / "torus.obj"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("-o", "--output", type=Path, default=Path("out/demo"), help="output folder (default: out/demo)")
    p.add_argument("--solid", type=Path, default=ASSET, help=f"solid mesh (.obj/.stl/.ply; default: {ASSET.name})")
    p.add_argument("--particle-radius", type=float, default=0.04, help="particle radius r in m (default: 0.04)")
    p.add_argument("--steps", type=int, default=200, help="time steps per probe (default: 200, dt 0.002 s)")
    p.add_argument("--speed", type=float, default=3.0, help="inflow speed lambda in m/s (default: 3)")
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                   help="compute device (default: cpu); cuda falls back to cpu with a notice")
    p.add_argument("--threads", type=int, default=None, help="CPU threads (default: all cores)")
    p.add_argument("--no-video", action="store_true", help="skip the MP4 of the -x probe")


def run_command(args: argparse.Namespace) -> int:
    from .runtime import init_taichi

    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    if not os.access(out, os.W_OK):
        raise OSError(f"output folder {out} is not writable; pass another -o")
    init_taichi(args.device, "f32", args.threads)
    from fluidsim import ProbeConfig, SolverConfig
    from fluidsim.probes import build_probe_solver, probe_setup
    from fluidsim.sources import mesh_particles

    from .sim import simulate_to_h5

    cfg = SolverConfig(particle_radius=args.particle_radius)
    solid = mesh_particles(args.solid, cfg.spacing, fill=True)
    probe = ProbeConfig(speed=args.speed)
    summary = {"solid": str(args.solid), "solid_particles": len(solid), "particle_radius": cfg.particle_radius,
               "steps": args.steps, "dt": cfg.dt, "probes": {}}
    for d in probe.directions:
        setup = probe_setup(solid, d, probe, cfg.spacing)
        solver = build_probe_solver(solid, setup, cfg, probe)
        scene = {"probe": d, "velocity": list(setup.velocity), "domain": {"min": list(setup.domain_min),
                 "max": list(setup.domain_max), "walls": probe.walls}, "particle_radius": cfg.particle_radius,
                 "dt": cfg.dt, "steps": args.steps}
        path, history = simulate_to_h5(solver, scene, out / f"probe_{d}.h5", args.steps, 10, desc=f"probe {d}")
        sums, counts = solver.divergence_accumulation()
        mean_d = np.where(counts > 0, sums / np.maximum(counts, 1), 0.0)
        summary["probes"][d] = {
            "file": path.name, "fluid_particles": solver.fluid.capacity, "boundary_particles": solver.boundary.count,
            "retired": int(sum(h.retired for h in history)),
            "mean_density_iterations": float(np.mean([h.density_iterations for h in history])),
            "mean_divergence_iterations": float(np.mean([h.divergence_iterations for h in history])),
            "mean_particle_divergence": float(mean_d.mean()),
            "p95_particle_divergence": float(np.percentile(mean_d, 95)),
        }
        print(f"probe {d}: {solver.fluid.capacity} fluid particles, mean D_i {mean_d.mean():.3f} 1/s "
              f"(p95 {np.percentile(mean_d, 95):.3f}), {summary['probes'][d]['retired']} retired -> {path}")
    fd, tmp = tempfile.mkstemp(dir=out, prefix=".summary.", suffix=".json")
    with os.fdopen(fd, "w") as fh:
        json.dump(summary, fh, indent=2)
    os.replace(tmp, out / "summary.json")
    if not args.no_video:
        from .render_frames import FrameStyle, render_frames

        render_frames(out / "probe_-x.h5", out / "probe_-x.mp4", FrameStyle(view="iso"), progress=True)
        print(f"video: {out / 'probe_-x.mp4'}")
    print(f"summary: {out / 'summary.json'}")
    return 0
