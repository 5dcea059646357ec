"""`fluidgs demo`: the project's main job on the bundled Ahmed body, in about two minutes on a 2-core CPU.

Default: the Gaussians of ``assets/ahmed_gaussians.ply`` (when the bundled asset is missing: Gaussians sampled
on the surface of the Ahmed body mesh of :mod:`recon.ahmed`, said so in the log and in summary.json) go
through the five probes of the paper at the quick preset (r = 0.05 m, 300 steps per probe), then

- ``result.h5`` (per-probe and combined D_g, D-bar; :func:`nbv.physics.save_result`),
- ``gaussians_divergence.ply``: the Gaussians coloured by D_g (opens in 3DGS viewers),
- ``scores.json`` and ``views/``: the candidate cameras (``assets/ahmed_cameras.json``, else an orbit of
  12) ranked by S(T) (paper Eq. 4-5), one PNG per view (render | D_g heat-map),
- ``probe_-x.mp4``: the -x probe, coloured by divergence,
- ``summary.json``: D-bar, per-probe figures, timings.

``--solid MESH`` keeps the earlier demo: five probes against a sampled mesh (``assets/torus.obj``), one HDF5
per probe, ``summary.json`` and an MP4 of the -x probe.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from .runtime import positive_int

log = logging.getLogger("fluidgs")
ASSETS = Path(__file__).resolve().parent.parent / "assets"
ASSET = ASSETS / "torus.obj"
GAUSSIANS = ASSETS / "ahmed_gaussians.ply"
CAMERAS = ASSETS / "ahmed_cameras.json"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("-o", "--output", type=Path, default=Path("out/demo"), help="output folder")
    p.add_argument("--solid", type=Path, default=None,
                   help=f"run the mesh demo on this solid mesh instead (.obj/.stl/.ply; e.g. assets/{ASSET.name})")
    p.add_argument("--gaussians", type=Path, default=None,
                   help=f"Gaussian set (default: assets/{GAUSSIANS.name}, else Gaussians on the Ahmed body surface)")
    p.add_argument("--cameras", type=Path, default=None,
                   help=f"candidate cameras, transforms.json (default: assets/{CAMERAS.name}, else an orbit of 12)")
    p.add_argument("--up", "--up-axis", dest="up", default="+y", metavar="UP",
                   help="the Gaussians' up direction: +x, -x, +y, -y, +z, -z or a vector such as 0,-1,0 "
                        "(default: +y)")
    p.add_argument("--particle-radius", type=float, default=None,
                   help="particle radius r in m (default: 0.05, the quick preset; 0.04 for --solid)")
    p.add_argument("--steps", type=int, default=None,
                   help="time steps per probe (default: 300, the quick preset; 200 for --solid), dt 0.002 s")
    p.add_argument("--speed", type=float, default=3.0, help="inflow speed lambda in m/s")
    p.add_argument("--render-width", type=int, default=240, help="width of the scored views in pixels")
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                   help="compute device; cuda falls back to cpu with a notice")
    p.add_argument("--threads", type=positive_int, default=None, help="CPU threads (default: all cores)")
    p.add_argument("--no-video", action="store_true", help="skip the MP4 of the -x probe")


def ahmed_surface_gaussians(count: int = 4000, sigma: float = 0.02, seed: int = 0):
    """Gaussians on the Ahmed body surface (metres, Y-up): ``count`` Poisson-disk samples, isotropic ``sigma`` m,
    opacity 0.9, coloured light grey; stands in for the trained asset when it is missing."""
    import open3d as o3d
    import torch

    from recon.ahmed import ahmed_body
    from recon.gaussians import GaussianSet

    o3d.utility.random.seed(seed)
    pcd = ahmed_body(resolution=0.02).sample_points_poisson_disk(count)
    pts = torch.tensor(np.asarray(pcd.points), dtype=torch.float32)
    return GaussianSet.from_points(pts, torch.full((len(pts), 3), 0.8), scale=sigma, opacity=0.9)


def demo_cameras(gaussians, path: Path | None, width: int):
    """Candidate cameras: the bundled transforms.json, or an orbit of 12 around the Gaussians' centre."""
    import math

    from recon.camera_paths import orbit

    from .score import load_cameras, render_size

    if path is not None:
        return [render_size(c, width) for c in load_cameras(path)]
    means = gaussians.means.detach().double()
    centre = ((means.min(0).values + means.max(0).values) / 2).tolist()
    extent = float((means.max(0).values - means.min(0).values).max())
    return orbit(12, 1.6 * extent, 20.0, width, int(width * 3 / 4), math.radians(50), target=tuple(centre))


DEMO_FILES = ("result.h5", "gaussians_divergence.ply", "scores.json", "summary.json", "probe_-x.mp4",
              *(f"probe_{d}.h5" for d in ("-x", "+x", "-z", "+z", "-y")))


def run_command(args: argparse.Namespace) -> int:
    from fluidsim.output import check_not_input

    check_not_input([("-o (demo file)", Path(args.output) / name) for name in DEMO_FILES],
                    {"--solid": args.solid, "--gaussians": args.gaussians, "--cameras": args.cameras})
    if args.solid is not None:
        return run_mesh_demo(args)
    from dataclasses import replace

    from nbv.physics import PhysicsConfig, save_result, simulate_gaussians

    from .runtime import init_taichi
    from .score import check_cameras_see, print_table, score_views
    from .simulate import load_gaussians_checked, result_summary, write_colored_ply, write_json, write_probe_video

    t0 = time.perf_counter()
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    if not os.access(out, os.W_OK):
        raise OSError(f"output folder {out} is not writable; pass another -o")
    cfg = PhysicsConfig.quick(speed=args.speed, up=args.up, fill_cavities=True, empty_reference=False)
    cfg = replace(cfg, **{k: v for k, v in (("particle_radius", args.particle_radius), ("steps", args.steps))
                          if v is not None})
    gpath = args.gaussians or (GAUSSIANS if GAUSSIANS.is_file() else None)
    if gpath is not None:
        gaussians, source = load_gaussians_checked(gpath), str(gpath)
    else:
        log.warning("%s is not there yet: using Gaussians sampled on the Ahmed body mesh surface", GAUSSIANS)
        gaussians, source = ahmed_surface_gaussians(), "Ahmed body surface samples (recon.ahmed)"
    cpath = args.cameras or (CAMERAS if CAMERAS.is_file() else None)
    cams = demo_cameras(gaussians, cpath, args.render_width)
    centres = check_cameras_see(gaussians, cams, [c.name for c in cams])
    init_taichi(args.device, cfg.precision, args.threads)
    from nbv.trajectory import RecordConfig  # the -x probe's fluid, for `fluidgs view`

    result = simulate_gaussians(gaussians, cfg, progress=True, source=source,
                                record=RecordConfig(("-x",), every=max(1, cfg.steps // 30)))
    save_result(out / "result.h5", result)
    write_colored_ply(gaussians, result.divergence, out / "gaussians_divergence.ply")
    rows = score_views(gaussians, cams, list(range(len(cams))), result, "max", out / "views",
                       device=args.device, visible_centres=centres)
    print_table(rows, None)
    write_json(out / "scores.json", {"cameras": str(cpath or "orbit of 12"), "gaussians": source, "views": rows,
                                     "dbar_m4_s": result.dbar, "config": cfg.to_dict()})
    if not args.no_video:
        write_probe_video(result, "-x", out / "probe_-x.mp4")
    summary = result_summary(result)
    summary.update(source=source, cameras=str(cpath or "orbit of 12"), wall_time_s=time.perf_counter() - t0)
    write_json(out / "summary.json", summary)
    print(f"{result.num_gaussians} Gaussians ({source}); D-bar {result.dbar:.4g} m^4/s; best view {rows[0]['name']}")
    print(f"outputs in {out}: result.h5, gaussians_divergence.ply, scores.json, views/, summary.json"
          + ("" if args.no_video else ", probe_-x.mp4") + f" ({summary['wall_time_s']:.0f} s)")
    print(f"see them in a browser: fluidgs view {out / 'result.h5'}" + (f" --gaussians {gpath}" if gpath else "")
          + (f" --scores {out / 'scores.json'}" if cpath else ""))
    return 0


def run_mesh_demo(args: argparse.Namespace) -> int:
    """The mesh demo: five probes against a sampled solid mesh (``--solid``)."""
    from .runtime import init_taichi

    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    if not os.access(out, os.W_OK):
        raise OSError(f"output folder {out} is not writable; pass another -o")
    init_taichi(args.device, "f32", args.threads)
    steps = args.steps or 200
    from fluidsim import ProbeConfig, SolverConfig
    from fluidsim.probes import build_probe_solver, probe_setup
    from fluidsim.sources import mesh_particles

    from .sim import simulate_to_h5

    cfg = SolverConfig(particle_radius=args.particle_radius or 0.04)
    solid = mesh_particles(args.solid, cfg.spacing, fill=True)
    probe = ProbeConfig(speed=args.speed)
    summary = {"solid": str(args.solid), "solid_particles": len(solid), "particle_radius": cfg.particle_radius,
               "steps": steps, "dt": cfg.dt, "probes": {}}
    for d in probe.directions:
        setup = probe_setup(solid, d, probe, cfg.spacing)
        solver = build_probe_solver(solid, setup, cfg, probe)
        scene = {"probe": d, "velocity": list(setup.velocity), "domain": {"min": list(setup.domain_min),
                 "max": list(setup.domain_max), "walls": probe.walls}, "particle_radius": cfg.particle_radius,
                 "dt": cfg.dt, "steps": steps}
        path, history = simulate_to_h5(solver, scene, out / f"probe_{d}.h5", steps, 10, desc=f"probe {d}")
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
