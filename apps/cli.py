"""The `fluidgs` command: one entry point, one subcommand per job.

The exit codes, and the exceptions that give them, are in :mod:`apps.exit_codes` (and docs/exit-codes.md).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import signal
import sys

from fluidsim.files import remove_unfinished

from .exit_codes import (
    EXIT_BAD_INPUT,
    EXIT_INTERRUPTED,
    EXIT_OUTPUT,  # noqa: F401 (a name of apps.cli that callers read)
    interrupted_import,
    run_module,
)
from .help_format import HelpFormatter
from .options.argv import join_dash_tokens, non_utf8_argument
from .progress_log import line_progress
from .signals import STOP_SIGNALS, exit_after_commands, stop_signals

# name -> (module of apps, help). A command's module (torch, Taichi, viz...) is imported only when its parser is
# built: `fluidgs score` loads score's, not the viewer's or the trainer's
COMMANDS = {
    "inspect": ("inspect_gaussians", "what the fluid will see: format, boxes, frame, solid count; PNG of three views"),
    "sim": ("sim", "run a scene JSON and write OUT.h5 (frames, per-step stats, divergence)"),
    "render-frames": ("render_frames", "draw the frames of OUT.h5 as an MP4 or PNGs, coloured by divergence or speed"),
    "bench": ("bench", "benchmarks: sim (DFSPH probe vs SPlisHSPlasH), and the others listed by `bench --help`"),
    "demo": ("demo", "the main job on the bundled Ahmed Gaussians: five quick probes, D_g, view scores, PNGs, video"),
    "render-dataset": ("render_dataset", "render an .obj/.stl/.ply mesh into a Blender-format dataset"),
    "train": ("train", "train 3D Gaussians on a dataset: OUT.ply plus OUT.json (config, timings, test PSNR/SSIM)"),
    "make-assets": ("make_assets", "regenerate the bundled trained Ahmed-body Gaussians and candidate cameras"),
    "simulate": ("simulate", "five probes against a Gaussian set: per-Gaussian D_g, D-bar -> RESULT.h5, coloured .ply"),
    "score": ("score", "rank candidate cameras by the view score S(T) of D_g (paper Eq. 4-5); JSON, table, PNGs"),
    "sweep": ("sweep", "D-bar against inflow speed U and Reynolds number (CFL-constant dt): CSV and PNG plot"),
    "cameras": ("cameras", "candidate cameras for a capture without any: rings around the object -> transforms.json"),
    "compare": (
        "compare",
        "the functional error: reconstruction vs reference in the same probes, with its noise floor",
    ),
    "critical": ("critical", "function-critical views: C(T) from distinct particle counts, top-20 subset"),
    "ahmed": ("make_ahmed", "write the procedural Ahmed body (Ahmed et al. 1984, slant 0-40 deg) as .obj/.stl/.ply"),
    "active": ("active", "active reconstruction: biased initial views, one planner pick per round up to the budget"),
    "eval": ("evaluate", "evaluate an active run: test PSNR/SSIM/LPIPS, D-bar, Chamfer, critical-view PSNR and D-bar"),
    "experiment": ("experiment", "methods x scenes x seeds of active + eval; paper-shaped tables and plots"),
    "export": (
        "export",
        "particle frames as VTK (.vtu per frame, .pvd series) for ParaView; the solid as mesh + voxels",
    ),
    "study": ("study", "measurement studies: oracle (every rule's scores against the candidates' real PSNR gain)"),
    "view": ("view", "see RESULT.h5 in a browser: splat coloured by D_g, solid, probe fluid over time, ranked cameras"),
}


def package_version() -> str:
    """The installed distribution's version (setup.cfg), or "unknown" when run from a tree that is not installed."""
    from importlib.metadata import PackageNotFoundError, version  # noqa: PLC0415 - only for --version

    try:
        return version("fluidgaussian")
    except PackageNotFoundError:
        return "unknown (not installed: pip install -e .)"


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``fluidgs`` parser. With ``command``, only that subcommand's options are built (the others are listed
    by name and help): options come from the config dataclasses, whose modules load torch or Taichi, so
    ``fluidgs --help`` builds none and ``fluidgs simulate ...`` only simulate's. Without it, every subcommand's
    (the tests and the CLI reference walk them all)."""
    parser = argparse.ArgumentParser(prog="fluidgs", description="FluidGaussian: fluid probes for 3DGS geometry.")
    parser.add_argument("-v", "--verbose", action="store_true", help="log more (default: warnings and info)")
    parser.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (module_name, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text, formatter_class=HelpFormatter)
        if command is None or name == command:
            module = importlib.import_module(f"apps.{module_name}")
            module.add_arguments(p)
            p.set_defaults(_module=module)
    return parser


def command_of(argv: list[str]) -> str | None:
    """The subcommand named in ``argv`` (the first token that is one, after the global options), or None."""
    for tok in argv:
        if tok in COMMANDS:
            return tok
        if not tok.startswith("-"):
            return None
    return None


def join_dash_values(argv: list[str], parser: argparse.ArgumentParser | None = None) -> list[str]:
    """:func:`apps.options.argv.join_dash_tokens` (``--opt -x`` read as ``--opt=-x``) with ``parser`` by default
    :func:`build_parser` of the command ``argv`` names."""
    return join_dash_tokens(argv, parser if parser is not None else build_parser(command_of(argv) or ""))


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:  # building a command's options imports its config module (torch, Taichi): Ctrl-C there is one line too
        parser = build_parser(command_of(argv) or "")
        args = parser.parse_args(join_dash_values(argv, parser))
    except KeyboardInterrupt:
        sys.stderr.write("ERROR fluidgs: interrupted\n")
        return EXIT_INTERRUPTED
    except ImportError as exc:
        if not interrupted_import(exc):
            raise
        sys.stderr.write("ERROR fluidgs: interrupted\n")
        return EXIT_INTERRUPTED
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO, format="%(levelname)s %(name)s: %(message)s"
    )
    bad_name = non_utf8_argument(parser, args)
    if bad_name is not None:  # before any work: the name would fail where a result records it, after the run
        logging.getLogger("fluidgs").error("%s", bad_name)
        return EXIT_BAD_INPUT
    code = EXIT_INTERRUPTED
    try:
        with stop_signals(), line_progress():  # in a log (no terminal): progress as lines, one per few seconds
            code = run_module(args)
    finally:  # whatever ended the command: no temporary file, and no empty new folder of a failed run, stays
        remove_unfinished(created_folders=code != 0)
    return code


def entry() -> None:
    """The ``fluidgs`` executable: :func:`main`, then the process exit. After a stop signal the process ends with
    that signal's code (130 or 143). A stop signal that lands once the command has returned (a second Ctrl-C after a
    quick save, a SIGTERM just after the end) does not change the exit code: until the command's handlers are gone it
    exits at once with its code (:func:`apps.signals.exit_after_commands`), and during the interpreter's shutdown,
    where Python restores the default handlers, it is ignored (the outputs are complete or removed by then)."""
    exit_after_commands()
    code = main()
    for sig in STOP_SIGNALS:
        signal.signal(sig, signal.SIG_IGN)
    sys.exit(code)


if __name__ == "__main__":
    entry()
