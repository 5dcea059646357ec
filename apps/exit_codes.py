"""The exit codes of every `fluidgs` command (also in docs/exit-codes.md), and which exceptions give them.

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
      a name too long (ENAMETOOLONG), a parent that is a file, a folder where a file is wanted; the message names
      the outputs written before the failure (complete), or says that none was
129   stopped by SIGHUP (a closed terminal, a dropped ssh session), with the same clean-up as 130; under nohup
      (SIGHUP ignored when the command starts) the command goes on
130   interrupted by Ctrl-C (SIGINT); `sim` first saves its frames so far (status "interrupted"); every command
      removes its unfinished temporary files and stops its worker processes (apps.signals)
143   stopped by SIGTERM (kill, timeout, a batch scheduler), with the same clean-up as 130; also any command whose
      Taichi start-up did not end within FLUIDGS_TAICHI_START_TIMEOUT (120 s), after one line saying so
====  ==========================================================================================================

`fluidgs view` serves until it is stopped: a signal once it serves is its normal end (exit 0).
"""

from __future__ import annotations

import argparse
import errno
import logging

from fluidsim.files import OutputError, written_outputs

from .signals import Stopped, first_signal, lost_signal, signal_name

EXIT_BAD_INPUT, EXIT_DIVERGED, EXIT_OUTPUT = 2, 3, 4
EXIT_INTERRUPTED = 130  # 128 + SIGINT, what shells report for a Ctrl-C
# errno values that only writing causes: full disk or quota, file too large, read-only file system, name too long
OUTPUT_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.ENAMETOOLONG})


def is_output_error(exc: BaseException) -> bool:
    """Whether ``exc`` means that an output could not be written (exit 4): an ``fluidsim.files.OutputError`` (from the
    checks before the work and from every atomic writer), or an ``OSError`` of :data:`OUTPUT_ERRNOS`."""
    return isinstance(exc, OutputError) or (isinstance(exc, OSError) and exc.errno in OUTPUT_ERRNOS)


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


def run_module(args: argparse.Namespace) -> int:
    """Run the parsed command; returns its exit code (one logged line for every expected failure)."""
    module = args._module
    runner = getattr(module, "run_command", None) or module.run
    before = len(written_outputs())
    try:
        code = int(runner(args) or 0)
        late = lost_signal()
        if code == 0 and late is not None:  # a Stopped lost where Python ignores exceptions (h5py's weakref callbacks)
            logging.getLogger("fluidgs").error(
                "interrupted by %s (the command's outputs were complete when it was noticed)", signal_name(late)
            )
            return 128 + late
        return code
    except Stopped as exc:  # SIGINT, SIGTERM or SIGHUP (apps.signals): one line, what is already written stays written
        logging.getLogger("fluidgs").error("interrupted by %s", signal_name(exc.signum))
        return exc.exit_code
    except (ValueError, OSError, FileNotFoundError) as exc:
        if not is_output_error(exc):
            logging.getLogger("fluidgs").error("%s", exc)
            return EXIT_BAD_INPUT
        done = written_outputs()[before:]
        kept = f"; written before it, complete: {', '.join(map(str, done))}" if done else "; no output was written"
        logging.getLogger("fluidgs").error("%s%s", exc, kept)
        return EXIT_OUTPUT
    except RuntimeError as exc:
        from fluidsim.simulation import SimulationDiverged

        if not isinstance(exc, SimulationDiverged):
            raise
        logging.getLogger("fluidgs").error("%s", exc)
        return EXIT_DIVERGED
    except KeyboardInterrupt:  # Ctrl-C: one line, no traceback (what is already written stays written)
        first = first_signal()  # an extension (Ray) may turn the handler's Stopped into a plain KeyboardInterrupt
        if first is not None:
            logging.getLogger("fluidgs").error("interrupted by %s", signal_name(first))
            return 128 + first
        logging.getLogger("fluidgs").error("interrupted")
        return EXIT_INTERRUPTED
    except ImportError as exc:  # a Ctrl-C inside a C extension's import (open3d, torch) surfaces as an ImportError
        if not interrupted_import(exc):
            raise
        logging.getLogger("fluidgs").error("interrupted")
        return EXIT_INTERRUPTED
