"""`fluidgs study WHAT CONFIG.json`: measurement studies of the view-scoring rules.

- ``oracle`` (:mod:`nbv.study.oracle`): at states of the active loop, the test-PSNR gain of every remaining candidate
  (a model copy trained with it), against every rule's score of it; per-Gaussian calibration against the mesh.
- ``oracle-pool`` (:mod:`nbv.study.oracle_pool`): the states of several oracle studies (more seeds, another rule
  set, held-out shapes) summarised together, over the rules every state scored.

Each state is written to its own file, so re-running the same command resumes. ``--executor local`` uses a process
pool on this machine; ``--executor ray --address ADDR`` sends the states to a Ray cluster (pip install ray).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from .options.common import add_executor_arguments
from .runtime import positive_int


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="what", required=True, metavar="WHAT")
    q = sub.add_parser(
        "oracle",
        help="oracle gains of the candidates against every rule's scores (and calibration)",
        description="oracle gains of the candidates against every rule's scores (and calibration)",
    )
    q.add_argument("config", type=Path, help="oracle study JSON (scenes, seeds, states, rules, probes, horizon, ...)")
    add_executor_arguments(q, "hide the progress bar (default: shown)")
    pool = sub.add_parser(
        "oracle-pool",
        help="summarise the states of several oracle studies together",
        description="Summarise the finished states of several `fluidgs study oracle` results folders together: "
        "they must agree on everything but scenes, seeds, states and rules; only the rules every state scored are "
        "summarised; a state found twice is taken from the first folder.",
    )
    pool.add_argument("folders", type=Path, nargs="+", help="results folders of `fluidgs study oracle`")
    pool.add_argument(
        "--output", type=Path, required=True, help="folder for the pooled oracle.json and oracle.md (required)"
    )
    pool.add_argument(
        "--bootstrap",
        type=positive_int,
        default=None,
        help="bootstrap resamples for the intervals (default: the first study's)",
    )


def run_command(args: argparse.Namespace) -> int:
    if args.what == "oracle-pool":
        return run_pool(args)
    from nbv.study.oracle import run_oracle
    from nbv.study.oracle_config import OracleConfig

    from .options.executor import make_executor, study_config_from_args

    own = ("oracle-config.json", "oracle.json", "oracle.md", "states")
    config = study_config_from_args(args, OracleConfig, own, ("oracle.json", "oracle.md"))
    precision = config.probe_config(next(iter(config.probes))).precision
    executor = make_executor(args.executor, args.workers, args.threads, args.address, precision)
    out = run_oracle(config, executor, progress=not args.no_progress)
    print(out["markdown"])
    print(f"wrote {', '.join(out['files'])}")
    return 0


def run_pool(args: argparse.Namespace) -> int:
    from nbv.io import json_safe, write_json_atomic, write_text_atomic
    from nbv.study.oracle_pool import pool_studies
    from nbv.study.oracle_summary import format_summary, summarise

    from .options import check_output_folder

    out = Path(args.output)
    for folder in args.folders:
        if folder.resolve() == out.resolve():
            raise ValueError(
                f"--output {out} is one of the pooled folders; give a new folder (it would overwrite "
                "that study's own summary)"
            )
    check_output_folder(out, "--output", ("oracle.json", "oracle.md"))
    pool = pool_studies(args.folders, args.bootstrap)
    summary = summarise(pool.config, pool.states)
    summary["pool"] = {
        "sources": pool.sources,
        "rules": list(pool.config.rules),
        "dropped_rules": pool.dropped_rules,
        "duplicates": pool.duplicates,
        "stale": pool.stale,
    }
    head = ["Pooled from " + ", ".join(f"{s['folder']} ({s['states']} states)" for s in pool.sources) + "."]
    if pool.dropped_rules:
        head.append(f"Rules not scored in every state, left out: {', '.join(pool.dropped_rules)}.")
    if pool.duplicates:
        head.append(f"States found twice, taken from the first folder: {len(pool.duplicates)}.")
    if pool.stale:
        head.append(f"State files of an earlier config of their folder, left out: {len(pool.stale)}.")
    markdown = "\n".join(head) + "\n\n" + format_summary(summary)
    out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out / "oracle.json", json_safe(summary))
    write_text_atomic(out / "oracle.md", markdown)
    print(markdown)
    print(f"wrote {out / 'oracle.json'}, {out / 'oracle.md'}")
    return 0
