"""`fluidgs simulate GAUSSIANS.ply -o RESULT.h5`: the five probes against a Gaussian set, per-Gaussian D_g.

Writes RESULT.h5 (layout in :func:`nbv.physics.save_result`: per-probe and combined D_g, counts, D-bar,
the empty-scene D-bar, step statistics, solid particles), a ``.ply`` of the Gaussians coloured by D_g
(SH degree 0; opens in common 3DGS viewers) and, with ``--video``, an MP4 of one probe.

A probe that diverges ends the run with exit code 3: RESULT.h5 then holds the probes completed before it, with
status "diverged" and the probe, step and reason (no coloured .ply). No output may be one of the inputs.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from .options import (
    add_gaussians_input,
    add_physics_arguments,
    add_record_arguments,
    check_output_file,
    gaussian_file_inputs,
    load_gaussians_checked,
    physics_config_from_args,
    record_config_from_args,
    save_diverged,
    warn_frame,
)
from .options.common import add_output_option
from .options.drawing import add_style_arguments, style_values
from .options.scoring import simulate_from_args
from .options.solid_export import add_solid_export_arguments, solid_export_outputs, write_solid_export


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_gaussians_input(p)
    add_output_option(p, "result HDF5 file (written atomically)")
    p.add_argument(
        "--ply",
        type=Path,
        default=None,
        help="Gaussians coloured by D_g (default: the output path with suffix _divergence.ply)",
    )
    p.add_argument(
        "--video",
        default=None,
        metavar="PROBE",
        help="also draw this probe (e.g. -x) as an MP4 next to the output (re-runs that probe, every step; "
        "the drawing options below apply)",
    )
    p.add_argument("--video-every", type=int, default=5, help="steps between video frames (default: 5)")
    add_record_arguments(p)
    add_solid_export_arguments(p)
    add_style_arguments(
        p,
        " by --video (as render-frames; here the defaults are --view iso, --width 640, "
        "--height 480, and --fps makes the clip last about 8 s)",
    )
    add_physics_arguments(p, replicas=True)


def default_ply_path(output: Path) -> Path:
    return output.with_name(output.stem + "_divergence.ply")


def run_command(args: argparse.Namespace) -> int:
    from fluidsim.files import check_not_input, check_writable
    from nbv.outputs import divergence_columns, probe_video, save_colored_gaussians
    from nbv.physics import ProbeDiverged, save_result

    config = physics_config_from_args(args)
    output = check_output_file(args.output, (".h5", ".hdf5"))
    ply = args.ply or default_ply_path(output)
    video = output.with_name(f"{output.stem}_probe{args.video}.mp4") if args.video is not None else None
    check_not_input(
        {"-o": output, "--ply": ply, "--video": video, **solid_export_outputs(args.export_solid)},
        gaussian_file_inputs(args),
    )
    check_output_file(ply, (".ply",))
    if args.video is not None:
        from nbv.physics import parse_directions

        if len(parse_directions(args.video)) != 1:
            raise ValueError(f"--video takes one probe (e.g. -x), got {args.video!r}")
        if args.video_every < 1:
            raise ValueError(f"--video-every must be >= 1 step, got {args.video_every}")
        check_writable(video)
    record = record_config_from_args(args, config)
    style_options = style_values(args)
    if style_options and args.video is None:
        raise ValueError(
            f"the drawing options ({', '.join(sorted(style_options))}) apply to --video; add --video -x "
            "(or another probe), or drop them"
        )
    gaussians = load_gaussians_checked(args.gaussians, args)
    warn_frame(config, up_given=args.up is not None)
    try:
        result = simulate_from_args(args, gaussians, config, record)
    except ProbeDiverged as exc:
        return save_diverged(exc, output)
    save_result(output, result)
    save_colored_gaussians(gaussians, result.divergence, ply, divergence_columns(result), result.reached)
    print_result(result)
    print(
        f"result: {output}\ncoloured Gaussians: {ply} (D_g as the vertex properties "
        f"{', '.join(divergence_columns(result))})"
    )
    write_solid_export(args.export_solid, result, args.export_frame)
    if video is not None:
        from dataclasses import replace

        from nbv.outputs import VIDEO_STYLE

        style = replace(VIDEO_STYLE, **style_options)
        fps = style_options.get("fps")
        probe_video(result, args.video, video, args.video_every, style=style, fps=fps, saved=output)
        print(f"video: {video}")
    print(f"see it in a browser: fluidgs view {output} --gaussians {args.gaussians}")
    return 0


def print_result(result) -> None:
    """Per probe: mean and max D_g, the Gaussians reached, retired and leaked particles, warnings; the forces, D-bar,
    the replicas' agreement and the timings. D_g and D-bar to two digits, as far as a rerun reproduces them."""
    from nbv.outputs import result_summary
    from nbv.physics.forces import force_lines
    from nbv.physics.replicas import replicas_gaussian_line

    s = result_summary(result)
    print(
        f"{result.num_gaussians} Gaussians, {len(result.solid)} solid particles, scale {result.transform.scale:.4g} "
        "m/unit"
    )
    for d, pr in s["probes"].items():
        print(
            f"  probe {d:>3}: mean D_g {pr['mean_D']:.2g} 1/s, max {pr['max_D']:.2g} 1/s, "
            f"{pr['touched_gaussians']} Gaussians reached, {pr['retired']} retired"
            + (
                f", leaked into the solid: {pr['leaked']['final']} at the end, at most {pr['leaked']['max']} "
                f"(step {pr['leaked']['max_step']})"
                if "leaked" in pr
                else ""
            )
        )
        for w in result.warnings.get(d, []):
            print(f"    WARNING: {w}")
    print("\n".join(force_lines(result.forces)))
    # two digits: the same run with other float roundings moves D-bar and its empty scene's by up to tens of per
    # cent (docs/performance.md, "The answer's rounding floor"); RESULT.h5 keeps every digit
    empty = "n/a" if result.dbar_empty is None else f"{result.dbar_empty:.2g}"
    print(f"D-bar {result.dbar:.2g} m^4/s (mean-combined {result.dbar_mean:.2g}; empty scene {empty})")
    if result.replicas is not None:
        print(replicas_gaussian_line(result.replicas))
    else:  # one run's D_g per Gaussian is noisy: say so before someone reads single Gaussians off the coloured PLY
        print(
            "one run's D_g per Gaussian repeats at Spearman 0.66-0.80 when only the float roundings change (--quick, "
            "three captures, docs/performance.md): read regions of the coloured Gaussians, not single ones; "
            "--replicas 2 measures it on yours"
        )
    t = result.timings
    print(
        f"time: simulation {t['simulation']:.1f} s, aggregation {t['aggregation']:.2f} s, "
        f"empty reference {t['empty_reference']:.1f} s, total {t['total']:.1f} s"
    )
