"""`fluidgs experiment CONFIG.json`: methods x scenes x seeds of `active` + `eval`, and the paper's tables.

Writes OUTPUT/runs/..., OUTPUT/results.json, OUTPUT/tables.md, OUTPUT/tables/*.md|.csv and OUTPUT/plots/*.png
(see :mod:`nbv.study.experiment` for the config keys and the tables). Finished jobs are skipped, so re-running
resumes. ``--executor local`` uses a process pool on this machine; ``--executor ray --address ADDR`` sends the
jobs to an existing Ray cluster (optional dependency: pip install ray).
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from .options.common import add_executor_arguments
from .options.executor import make_executor, study_config_from_args


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", type=Path, help="experiment JSON (scenes, methods, seeds, preset, output, ...)")
    add_executor_arguments(p, "hide the progress bar")


def job_exit_code(cause: BaseException | None) -> int:
    """`fluidgs`'s exit code for a job that raised ``cause``: 4 an output, 2 bad input, 3 a divergence, else 1."""
    from fluidsim.simulation import SimulationDiverged

    from .exit_codes import EXIT_BAD_INPUT, EXIT_DIVERGED, EXIT_OUTPUT, is_output_error

    if cause is not None and is_output_error(cause):
        return EXIT_OUTPUT
    if isinstance(cause, SimulationDiverged):
        return EXIT_DIVERGED
    if isinstance(cause, (ValueError, OSError)):
        return EXIT_BAD_INPUT
    return 1


def run_command(args: argparse.Namespace) -> int:
    from nbv.study.experiment import JobFailed, run_experiment
    from nbv.study.experiment_config import ExperimentConfig

    written = ("experiment.json", "results.json", "tables.md")
    config = study_config_from_args(args, ExperimentConfig, (*written, "tables", "runs"), written)
    precision = config.active_config(config.methods[0], config.seeds[0]).physics.precision
    executor = make_executor(args.executor, args.workers, args.threads, args.address, precision)
    try:
        out = run_experiment(config, executor, progress=not args.no_progress, threads=args.threads)
    except JobFailed as exc:  # one line naming the job and its error, with the exit code of that error
        logging.getLogger("fluidgs").error("%s", exc)
        return job_exit_code(exc.__cause__)
    print(out["tables"]["visual"])
    print(out["tables"]["physics"])
    print(f"wrote {Path(config.output) / 'tables.md'} and {len(out['files'])} table / plot files")
    return 0
