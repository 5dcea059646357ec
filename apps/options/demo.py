"""The options of `fluidgs demo` and its bundled inputs; the mesh demo of ``--solid MESH`` (five probes against a
sampled solid mesh, one HDF5 per probe, ``summary.json`` and an MP4 of the -x probe); and the writable output folder
both demos start from."""

from __future__ import annotations

import argparse
from pathlib import Path

from fluidsim.directions import DIRECTIONS
from fluidsim.files import write_json_atomic

from .cameras import CAMERAS_HELP, add_orbit_arguments
from .common import AHMED_CAMERAS as CAMERAS
from .common import AHMED_GAUSSIANS as GAUSSIANS
from .common import ASSETS, add_output_option
from .fields import add_config_options
from .files import add_gaussian_file_arguments, check_output_folder
from .groups import add_frame_arguments, add_runtime_arguments
from .numbers import image_width

MESH_RADIUS, MESH_STEPS = 0.04, 200  # the mesh demo (--solid): particle radius r in m, steps per probe
ASSET = ASSETS / "torus.obj"
DEMO_ORBIT = 12  # cameras of the orbit scored on Gaussians other than the bundled ones


def add_demo_arguments(p: argparse.ArgumentParser) -> None:
    """The options of `fluidgs demo`."""
    add_output_option(p, "output folder", default=Path("out/demo"))
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
        type=image_width,
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


def output_folder(path) -> Path:
    """The demo's output folder, made when missing; an OutputError (exit 4) naming -o when it cannot be written, and
    a ValueError (exit 2) when it holds anything the demo does not write: an earlier (or interrupted) demo's folder
    is written again, a folder of someone else's files is not written into (their result.h5 would be replaced)."""
    out = check_output_folder(path, "-o")
    if out.is_dir():
        from fluidsim.files import TEMP_PREFIX  # the atomic writers' temporary files are ours too

        ours = (*DEMO_FILES, "views")
        foreign = sorted(p.name for p in out.iterdir() if p.name not in ours and not p.name.startswith(TEMP_PREFIX))
        if foreign:
            shown = ", ".join(foreign[:3]) + (", ..." if len(foreign) > 3 else "")
            raise ValueError(
                f"-o {out} holds files the demo does not write ({shown}); give a new or empty folder, or an earlier "
                "demo's output folder"
            )
    out.mkdir(parents=True, exist_ok=True)
    return out


def run_mesh_demo(args: argparse.Namespace) -> int:
    """The mesh demo: five probes against a sampled solid mesh (``--solid``)."""
    from ..runtime import init_taichi

    out = output_folder(args.output)
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
