"""`fluidgs study WHAT CONFIG.json`: measurement studies of the view-scoring rules.

- ``oracle`` (:mod:`nbv.study.oracle`): at states of the active loop, the test-PSNR gain of every remaining candidate
  (a model copy trained with it), against every rule's score of it; per-Gaussian calibration against the mesh.

Each state is written to its own file, so re-running the same command resumes. ``--executor local`` uses a process
pool on this machine; ``--executor ray --address ADDR`` sends the states to a Ray cluster (pip install ray).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from .runtime import positive_int, thread_count


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="what", required=True, metavar="WHAT")
    q = sub.add_parser(
        "oracle",
        help="oracle gains of the candidates against every rule's scores (and calibration)",
        description="oracle gains of the candidates against every rule's scores (and calibration)",
    )
    q.add_argument("config", type=Path, help="oracle study JSON (scenes, seeds, states, rules, probes, horizon, ...)")
    q.add_argument(
        "--executor",
        choices=("local", "ray"),
        default="local",
        help="local: a process pool here; ray: tasks on a Ray cluster (default: %(default)s)",
    )
    q.add_argument("--workers", type=positive_int, default=1, help="local worker processes (default: %(default)s)")
    q.add_argument(
        "--threads", type=thread_count, default=1, help="torch and Taichi CPU threads per worker (default: %(default)s)"
    )
    q.add_argument(
        "--address",
        default=None,
        help="Ray cluster address for ray.init(address=...), e.g. auto or ray://head:10001 "
        "(default: start a local Ray instance)",
    )
    q.add_argument("--output", type=Path, default=None, help="results folder (default: the config's 'output')")
    q.add_argument("--no-progress", action="store_true", help="hide the progress bar (default: shown)")


def run_command(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from fluidsim.files import check_not_input
    from nbv.study.oracle import run_oracle
    from nbv.study.oracle_config import OracleConfig

    from .experiment import make_executor
    from .options import check_output_folder

    config = OracleConfig.load(args.config)
    if args.output is not None:
        config = replace(config, output=str(args.output))
    check_output_folder(
        config.output, "--output" if args.output is not None else f"the 'output' of {args.config}"
    )  # before any work: a folder that is a file, or cannot be made, is named as the option or key that gave it
    check_not_input(
        [("output file", Path(config.output) / name) for name in ("oracle.json", "oracle.md")], {"CONFIG": args.config}
    )
    precision = config.probe_config(next(iter(config.probes))).precision
    executor = make_executor(args.executor, args.workers, args.threads, args.address, precision)
    out = run_oracle(config, executor, progress=not args.no_progress)
    print(out["markdown"])
    print(f"wrote {', '.join(out['files'])}")
    return 0
