"""The `fluidgs` command: one entry point, one subcommand per job.

Exit codes (also in docs/exit-codes.md):

====  ==========================================================================================================
code  meaning
====  ==========================================================================================================
0     success
1     an unexpected error (a traceback): a bug, please report it
2     bad input: a file, an option or a combination of them is invalid, or an output would overwrite an input;
      nothing was computed, and the message names the file or option and the fix
3     a simulation diverged: the message names the probe (or `sim`'s scene) and the step; what was computed
      before it is saved (RESULT.h5 with status "diverged", OUT.h5 with the fault as status; `score` only
      with --save-result)
4     an output cannot be written: full disk (ENOSPC) or quota, read-only file system (EROFS), no permission,
      a name too long (ENAMETOOLONG), a parent that is a file, a folder where a file is wanted
130   interrupted by Ctrl-C (SIGINT); `sim` first saves its frames so far (status "interrupted")
143   `sim` stopped by SIGTERM (kill, timeout, a batch scheduler) after saving its frames so far
====  ==========================================================================================================
"""

from __future__ import annotations

import argparse
import errno
import logging
import sys

from fluidsim.files import OutputError

EXIT_INTERRUPTED = 130  # 128 + SIGINT, what shells report for a Ctrl-C
try:  # the subcommands import torch and Taichi: a Ctrl-C while they load gets one line too, not a traceback
    from . import (
        active,
        bench,
        critical,
        demo,
        evaluate,
        experiment,
        inspect_gaussians,
        make_ahmed,
        make_assets,
        render_dataset,
        render_frames,
        score,
        sim,
        simulate,
        study,
        sweep,
        train,
        view,
    )
except KeyboardInterrupt:
    sys.stderr.write("ERROR fluidgs: interrupted\n")
    raise SystemExit(EXIT_INTERRUPTED) from None
from .help_format import HelpFormatter  # noqa: E402 (after the guarded imports above)

EXIT_BAD_INPUT, EXIT_DIVERGED, EXIT_OUTPUT = 2, 3, 4
# errno values that only writing causes: full disk or quota, file too large, read-only file system, name too long
OUTPUT_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.ENAMETOOLONG})


def is_output_error(exc: BaseException) -> bool:
    """Whether ``exc`` means that an output could not be written (exit 4): an ``fluidsim.files.OutputError`` (from the
    checks before the work and from every atomic writer), or an ``OSError`` of :data:`OUTPUT_ERRNOS`."""
    return isinstance(exc, OutputError) or (isinstance(exc, OSError) and exc.errno in OUTPUT_ERRNOS)

COMMANDS = {
    "inspect": (inspect_gaussians, "what the fluid will see: format, boxes, frame, solid count; PNG of three views"),
    "sim": (sim, "run a scene JSON and write OUT.h5 (frames, per-step stats, divergence)"),
    "render-frames": (render_frames, "draw the frames of OUT.h5 as an MP4 or PNGs, coloured by divergence or speed"),
    "bench": (bench, "benchmarks: sim (DFSPH probe vs SPlisHSPlasH), and the others listed by `bench --help`"),
    "demo": (demo, "the main job on the bundled Ahmed Gaussians: five quick probes, D_g, view scores, PNGs, video"),
    "render-dataset": (render_dataset, "render an .obj/.stl/.ply mesh into a Blender-format dataset"),
    "train": (train, "train 3D Gaussians on a dataset: OUT.ply plus OUT.json (config, timings, test PSNR/SSIM)"),
    "make-assets": (make_assets, "regenerate the bundled trained Ahmed-body Gaussians and candidate cameras"),
    "simulate": (simulate, "five probes against a Gaussian set: per-Gaussian D_g, D-bar -> RESULT.h5, coloured .ply"),
    "score": (score, "rank candidate cameras by the view score S(T) of D_g (paper Eq. 4-5); JSON, table, PNGs"),
    "sweep": (sweep, "D-bar against inflow speed U and Reynolds number (CFL-constant dt): CSV and PNG plot"),
    "critical": (critical, "function-critical views: C(T) from distinct particle counts, top-20 subset"),
    "ahmed": (make_ahmed, "write the procedural Ahmed body (Ahmed et al. 1984, slant 0-40 deg) as .obj/.stl/.ply"),
    "active": (active, "active reconstruction: biased initial views, one planner pick per round up to the budget"),
    "eval": (evaluate, "evaluate an active run: test PSNR/SSIM/LPIPS, D-bar, Chamfer, critical-view PSNR and D-bar"),
    "experiment": (experiment, "methods x scenes x seeds of active + eval; paper-shaped tables and plots"),
    "study": (study, "measurement studies: oracle (every rule's scores against the candidates' real PSNR gain)"),
    "view": (view, "see RESULT.h5 in a browser: splat coloured by D_g, solid, probe fluid over time, ranked cameras"),
}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``fluidgs`` parser. With ``command``, only that subcommand's options are built (the others are listed
    by name and help): options come from the config dataclasses, whose modules load torch or Taichi, so
    ``fluidgs --help`` builds none and ``fluidgs simulate ...`` only simulate's. Without it, every subcommand's
    (the tests and the CLI reference walk them all)."""
    parser = argparse.ArgumentParser(prog="fluidgs", description="FluidGaussian: fluid probes for 3DGS geometry.")
    parser.add_argument("-v", "--verbose", action="store_true", help="log more (default: warnings and info)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (module, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text,
                           formatter_class=HelpFormatter)
        if command is None or name == command:
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


# Options whose values may start with '-' (an up direction "-y", a crop box "-1,-1,-1,1,1,1", a vector "-0.1,1,0"):
# argparse would read such a value as an option, so "--up -y" is rewritten to "--up=-y" before parsing.
DASH_VALUE_OPTIONS = ("--up", "--up-axis", "--crop", "--initial-direction", "--record-probe", "--probe")


def join_dash_values(argv: list[str], options: tuple[str, ...] = DASH_VALUE_OPTIONS) -> list[str]:
    """``[..., "--up", "-y", ...]`` -> ``[..., "--up=-y", ...]`` for ``options`` (other tokens unchanged)."""
    out: list[str] = []
    i = 0
    while i < len(argv):
        tok = argv[i]
        if tok in options and i + 1 < len(argv) and argv[i + 1].startswith("-") and argv[i + 1] != "--" \
                and not argv[i + 1].startswith("--"):
            out.append(f"{tok}={argv[i + 1]}")
            i += 2
            continue
        out.append(tok)
        i += 1
    return out


def main(argv: list[str] | None = None) -> int:
    argv = join_dash_values(list(sys.argv[1:] if argv is None else argv))
    try:  # building a command's options imports its config module (torch, Taichi): Ctrl-C there is one line too
        args = build_parser(command_of(argv) or "").parse_args(argv)
    except KeyboardInterrupt:
        sys.stderr.write("ERROR fluidgs: interrupted\n")
        return EXIT_INTERRUPTED
    except ImportError as exc:
        if not interrupted_import(exc):
            raise
        sys.stderr.write("ERROR fluidgs: interrupted\n")
        return EXIT_INTERRUPTED
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(levelname)s %(name)s: %(message)s")
    module = args._module
    runner = getattr(module, "run_command", None) or module.run
    try:
        return int(runner(args) or 0)
    except (ValueError, OSError, FileNotFoundError) as exc:
        logging.getLogger("fluidgs").error("%s", exc)
        return EXIT_OUTPUT if is_output_error(exc) else EXIT_BAD_INPUT
    except RuntimeError as exc:
        from fluidsim.simulation import SimulationDiverged

        if not isinstance(exc, SimulationDiverged):
            raise
        logging.getLogger("fluidgs").error("%s", exc)
        return EXIT_DIVERGED
    except KeyboardInterrupt:  # Ctrl-C: one line, no traceback (what is already written stays written)
        logging.getLogger("fluidgs").error("interrupted")
        return EXIT_INTERRUPTED
    except ImportError as exc:  # a Ctrl-C inside a C extension's import (open3d, torch) surfaces as an ImportError
        if not interrupted_import(exc):
            raise
        logging.getLogger("fluidgs").error("interrupted")
        return EXIT_INTERRUPTED


def interrupted_import(exc: ImportError) -> bool:
    """Whether an ImportError was caused by a Ctrl-C (its ``__cause__`` or ``__context__`` chain holds one)."""
    seen: BaseException | None = exc
    for _ in range(16):
        seen = seen.__cause__ or seen.__context__
        if seen is None:
            return False
        if isinstance(seen, KeyboardInterrupt):
            return True
    return False


if __name__ == "__main__":
    sys.exit(main())
