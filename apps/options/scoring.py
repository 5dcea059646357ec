"""The options of the view-scoring commands (score, critical): the view images of score, the output files planned
before any work, the orbit cameras written beside the output, and the RESULT.h5 read or simulated."""

from __future__ import annotations

import argparse
import functools
import logging
import os
from pathlib import Path

from .cameras import check_visibility_arguments, write_orbit_cameras  # noqa: F401 - apps.score reads the second here
from .files import check_output_file, gaussian_file_inputs
from .results import record_config_from_args
from .solid_export import solid_export_outputs

log = logging.getLogger("fluidgs")
PNG_TOP = 5  # views rendered to PNG by default (the scores themselves need no render)


def add_view_image_arguments(p: argparse.ArgumentParser) -> None:
    """--png-dir, --no-png, --png-top, --png-all and --uncertainty-images: score's per-view PNGs."""
    p.add_argument(
        "--png-dir",
        type=Path,
        default=None,
        help="folder for the per-view PNGs (default: next to the output, <stem>_views)",
    )
    p.add_argument("--no-png", action="store_true", help="skip the per-view PNGs")
    p.add_argument(
        "--png-top",
        type=int,
        default=PNG_TOP,
        help="render PNGs of the best N views only (scores need no render; default: %(default)s)",
    )
    p.add_argument("--png-all", action="store_true", help="render a PNG of every candidate view")
    p.add_argument(
        "--uncertainty-images",
        action="store_true",
        help="also write, per PNG view, its physics-uncertainty image: D_g alpha-composited per pixel "
        "(1/s), as <view>_uncertainty.npy (float32) and a colour .png with its scale bar ('+': above "
        "the range) (default: off)",
    )


def check_score_arguments(args: argparse.Namespace) -> None:
    """The option combinations of score that cannot work, refused before any file is read or any probe runs."""

    check_visibility_arguments(args)
    if args.uncertainty_images and args.no_png:
        raise ValueError(
            "--uncertainty-images writes its images beside the view PNGs and --no-png turns those off; "
            "drop --no-png (--png-top N or --png-all choose the views)"
        )
    if args.top_k is not None and args.top_k < 1:
        raise ValueError(f"--top-k must be >= 1, got {args.top_k}")
    if args.png_top < 1:
        raise ValueError(f"--png-top must be >= 1 view, got {args.png_top}; use --no-png for no PNGs")


def score_outputs(args: argparse.Namespace, config, orbit) -> tuple:
    """score's outputs checked before any work: (scores JSON, PNG folder or None, orbit cameras file or None,
    RecordConfig or None)."""
    from fluidsim.files import check_not_input

    output = check_output_file(args.output, (".json",))
    png_dir = None if args.no_png else (args.png_dir or output.with_name(output.stem + "_views"))
    orbit_file = output.with_name(output.stem + "_cameras.json") if orbit is not None else None
    check_not_input(
        {
            "-o": output,
            "--save-result": args.save_result,
            "--png-dir": png_dir,
            "-o (orbit cameras)": orbit_file,
            **solid_export_outputs(args.export_solid),
        },
        [*gaussian_file_inputs(args), ("--cameras", None if orbit else args.cameras), ("--result", args.result)],
    )
    if png_dir is not None:
        check_output_file(png_dir / "view.png", (".png",))
    if args.save_result is not None:
        check_output_file(args.save_result, (".h5", ".hdf5"))
    if args.result is None and args.metric not in ("max", "mean") and args.metric not in config.directions:
        raise ValueError(f"--metric {args.metric} needs that probe in --directions ({','.join(config.directions)})")
    record = record_config_from_args(args, config)
    if record is not None and (args.result is not None or args.save_result is None):
        raise ValueError(
            "--record-probe records into the RESULT.h5 of a fresh simulation: pass --save-result "
            "RESULT.h5" + (" and drop --result" if args.result is not None else "")
        )
    return output, png_dir, orbit_file, record


def simulate_from_args(args, gaussians, config, record=None):
    """:func:`nbv.physics.simulate_gaussians` with a progress bar, on the device, precision and threads of ``args``,
    its source named as ``args.gaussians`` (and ``args.source_frame`` where given); ``record`` as in
    :func:`obtain_result`."""
    from nbv.physics import simulate_gaussians

    from ..runtime import init_taichi

    used = init_taichi(args.device, config.precision, args.threads)
    return simulate_gaussians(
        gaussians,
        config,
        progress=True,
        source=str(args.gaussians),
        source_frame=getattr(args, "source_frame", ""),
        record=record,
        empty_worker=empty_worker_setup(used, config.precision, args.threads),
    )


def empty_worker_setup(used: str, precision: str, threads: int | None):
    """The set-up of the empty-scene worker beside the probes (:mod:`nbv.physics.empty_worker`), for a run on the
    device ``used`` with ``threads`` (None: all cores), or None: on the CPU with two threads or more, the worker
    gets half as many (on two cores the probes leave about 0.6 of a core idle), in this runtime's debug mode."""
    import taichi as ti

    from .executor import init_empty_worker

    threads = threads or os.cpu_count() or 1
    if used != "cpu" or threads < 2:
        return None
    return functools.partial(init_empty_worker, precision, threads // 2, bool(ti.lang.impl.current_cfg().debug))


def obtain_result(args, gaussians, config, record=None):
    """PhysicsResult from --result, or a fresh simulation (then saved to --save-result when given; ``record``: the
    probes to record, :class:`nbv.physics.trajectory.RecordConfig`)."""
    from nbv.physics import check_result_matches, load_result, save_result

    if args.result is not None:
        result = load_result(args.result)
        check_result_matches(result, gaussians, args.result)
        for d, notes in result.warnings.items():  # a fresh simulation logs them as its probes end
            for note in notes:
                log.warning("%s, probe %s: %s", args.result, d, note)
        return result
    result = simulate_from_args(args, gaussians, config, record)
    if args.save_result is not None:
        save_result(args.save_result, result)
    return result
