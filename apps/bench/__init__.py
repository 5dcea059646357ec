"""`fluidgs bench WHAT`: benchmarks as commands (they print figures; they are not timed tests).

Each benchmark lives in its own module of this package with ``add_arguments(parser)`` and ``run_command(args)``:

- ``sim`` (:mod:`apps.bench.sim`): the paper-scale DFSPH probe, side by side with SPlisHSPlasH when installed (the
  peer harness is :mod:`nbv.bench.splash`);
- ``score`` (:mod:`apps.bench.score`): the probes on Gaussians, simulation and aggregation timed apart;
- ``render`` (:mod:`apps.bench.render`): forward + backward time of the torch rasterizer;
- ``views`` (:mod:`apps.bench.views`): view scores from the projection alone, and their ranking against renders.
- ``hole`` (:mod:`apps.bench.hole`): a hole punched in a capture's surface, its solid and its rim's D_g.
- ``forces`` (:mod:`apps.bench.forces`): the time-mean drag on the solid, this engine against SPlisHSPlasH.
- ``probes`` (:mod:`apps.bench.probes`): one probe run profiled (per probe and solver stage, when D_g converges, how
  much of the slab reaches a Gaussian) and early stops judged against the uncut run.
"""

from __future__ import annotations

import argparse
import importlib

from ..help_format import HelpFormatter

# name -> help; the benchmark is the module of that name in this package, imported when the parser is built.
BENCHMARKS = {
    "sim": "the paper-scale DFSPH probe (and SPlisHSPlasH when installed)",
    "score": "probes on Gaussians: simulation vs aggregation time, quick five-probe total",
    "render": "forward + backward time of the torch 3DGS rasterizer (5k@100x100, 20k@200x200)",
    "views": "view scores without renders: 200 cameras x 1M Gaussians; ranking vs full renders",
    "hole": "a hole punched in a capture's surface: solid points removed, rim D_g holed / intact",
    "forces": "time-mean drag on a sphere and the Ahmed body: this engine vs SPlisHSPlasH",
    "probes": "one probe run profiled per probe and stage; stop rules judged against it",
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="what", required=True, metavar="WHAT")
    for name, help_text in BENCHMARKS.items():
        module = importlib.import_module(f"{__name__}.{name}")
        q = sub.add_parser(
            name,
            help=help_text,
            description=(module.__doc__ or help_text).strip().splitlines()[0],
            formatter_class=HelpFormatter,
        )
        module.add_arguments(q)
        q.set_defaults(_bench=module)


def run_command(args: argparse.Namespace) -> int:
    return int(args._bench.run_command(args) or 0)
