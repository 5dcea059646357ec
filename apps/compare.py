"""`fluidgs compare RECON --reference REF`: does the reconstruction behave like the object in the fluid?

Runs the same probes (default -x, head-on, the paper's functional direction) against the reference's solid and the
reconstruction's, with the setups laid out once around the reference, in the reference's frame, and prints per probe
and in all the relative errors of the force time series, of the time-mean drag and lift and of the velocity field,
each beside its noise floor (the reference against itself on a shifted lattice), and the solids' IoU and Chamfer
distance (:mod:`nbv.functional`). Writes a JSON record and a PNG of the drag over time.

RECON and REF may each be a mesh (.obj, .stl, .ply with faces, .glb), a Gaussian file or a RESULT.h5. Solids that do
not overlap are refused before any probe runs.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from .options import (
    add_gaussian_file_arguments,
    add_physics_arguments,
    check_output_file,
    gaussian_file_inputs,
    load_gaussians_checked,
    physics_config_from_args,
)
from .options.common import add_output_option


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("recon", type=Path, help="the reconstruction: Gaussians, a mesh or a RESULT.h5 (scene units)")
    p.add_argument(
        "--reference",
        type=Path,
        required=True,
        help="the object: a mesh (.obj, .stl, .ply, .glb; watertight, or it is sampled on its surface), Gaussians "
        "or a RESULT.h5; its frame and scale are used for both",
    )
    p.add_argument(
        "--reference-transform",
        default=None,
        metavar="M",
        help="4 x 4 matrix taking a mesh reference into the reconstruction's scene frame: 16 numbers, row-major, or a "
        ".npy/.txt/.json file (default: none, the two share a frame, as a render-dataset mesh and Gaussians trained "
        "on it do)",
    )
    add_output_option(p, "JSON record (default: compare.json)", default=Path("compare.json"))
    p.add_argument(
        "--plot", type=Path, default=None, help="PNG of the drag over time (default: the output with suffix .png)"
    )
    p.add_argument(
        "--no-cache",
        action="store_true",
        help="run the reference's probes even when its flows are cached (default: cached in $FLUIDGS_CACHE_DIR)",
    )
    add_gaussian_file_arguments(p)
    add_physics_arguments(p, empty_reference=False)


def run_command(args: argparse.Namespace) -> int:
    from fluidsim.files import atomic_output, check_input_file, check_not_input
    from nbv.functional import (
        DEFAULT_DIRECTIONS,
        FlowCache,
        compare,
        comparison_lines,
        overlap_line,
        plot_forces,
    )
    from nbv.functional.solids import matrix_file, parse_matrix, reconstruction_source, reference_source

    from .runtime import init_taichi

    config = physics_config_from_args(args, default_directions=DEFAULT_DIRECTIONS)
    matrix = parse_matrix(args.reference_transform)
    plot = args.plot or args.output.with_suffix(".png")
    check_output_file(args.output, (".json",))
    check_output_file(plot, (".png",))
    if args.output.resolve() == plot.resolve():
        raise ValueError(f"--plot {plot} is the JSON output too; give two different paths")
    inputs = {"RECON": args.recon, "--reference": args.reference}
    check_not_input(
        {"-o": args.output, "--plot": plot},
        [
            *gaussian_file_inputs(args, "RECON", args.recon),
            ("--reference", args.reference),
            ("--reference-transform", matrix_file(args.reference_transform)),
        ],
    )
    for name, path in inputs.items():
        check_input_file(path, name, "pass a mesh, a Gaussian file or a RESULT.h5", folder_ok=True)

    def load(path):
        return load_gaussians_checked(path, args)

    init_taichi(args.device, config.precision, args.threads)
    reference = reference_source(args.reference, config, matrix, load)
    recon = reconstruction_source(args.recon, config, reference.transform, load)
    print(
        f"frame: the reference's, up {reference.transform.up_label}, {reference.transform.scale:.4g} m per scene unit; "
        f"r = {config.particle_radius} m, {config.steps} steps, probes {', '.join(config.directions)}"
    )
    result = compare(
        reference,
        recon,
        config,
        config.directions,
        progress=True,
        cache=FlowCache.from_environment(not args.no_cache),
        on_overlap=lambda o, f: print(overlap_line(o, f)),
    )
    for w in result.warnings:
        print(f"WARNING: {w}")
    print("\n".join(comparison_lines(result)))
    for d, g in result.grids.items():
        print(f"  {d}: {g.describe(config.dt)}")
    s = result.settings
    print(f"{s['probe_runs']} probe runs ({s['cached_runs']} of the reference's from the cache), {s['seconds']} s")
    with atomic_output(args.output) as tmp:
        tmp.write_text(json.dumps(result.record(), indent=2, allow_nan=True))
    plot_forces(result, plot)
    print(f"record: {args.output}\nplot: {plot}")
    return 0
