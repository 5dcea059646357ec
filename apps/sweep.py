"""`fluidgs sweep GAUSSIANS.ply --velocities 3,4,5,...`: D-bar against the inflow speed U and Re = rho U L / mu.

Delta t is CFL-constant: Delta t = Delta t_base * U_base / U over the same physical duration as the base
setting (``--steps`` x ``--dt`` at U_base = ``--speed``, default 3 m/s), so high speeds take many steps.
With ``--compare`` both sets use the scale resolved on the first (D-bar scales with its fourth power).
L is the largest extent of the -x probe's domain (m). Writes a CSV (U, Re, Delta t, steps, D-bar, and
with ``--compare OTHER.ply`` D-bar of OTHER and the gap D-bar(OTHER) - D-bar) and a PNG plot drawn with
matplotlib (:mod:`viz.plots`): D-bar against U (log x) and a table of Re, Delta t and steps.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from .options import (
    add_gaussian_file_arguments,
    add_physics_arguments,
    check_output_file,
    load_gaussians_checked,
    physics_config_from_args,
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("gaussians", type=Path, help="Gaussians (.ply, .compressed.ply, .spz, .splat, .npz, .sog or "
                   "meta.json folder, .ksplat, a gsplat or nerfstudio checkpoint), scene units")
    add_gaussian_file_arguments(p)
    from nbv.study.sweep import PAPER_VELOCITIES

    p.add_argument("--velocities", default=",".join(f"{u:g}" for u in PAPER_VELOCITIES),
                   help="comma list of inflow speeds U in m/s (default: the paper's, %(default)s)")
    p.add_argument("--compare", type=Path, default=None,
                   help="a second Gaussian set OTHER (same frame, simulated at the first set's scale); reports "
                        "D-bar(OTHER) - D-bar per U")
    p.add_argument("-o", "--output", type=Path, default=Path("sweep.csv"),
                   help="CSV file (written atomically); the plot goes next to it as .png")
    add_physics_arguments(p, empty_reference=False)  # the sweep compares D-bar across speeds, never the empty scene


def plot_sweep(points, path: Path, title: str = "") -> Path:
    """Draw D-bar (and OTHER's) against U on a log-x axis, with a Re / Delta t table (:func:`viz.plots.plot_sweep`);
    PNG written atomically."""
    from viz.plots import plot_sweep as draw

    other = [p.dbar_other for p in points] if all(p.dbar_other is not None for p in points) else None
    return draw(path, [p.speed for p in points], [p.dbar for p in points], dbar_other=other,
                reynolds=[p.reynolds for p in points], dts=[p.dt for p in points], steps=[p.steps for p in points],
                title=title)


def run_command(args: argparse.Namespace) -> int:
    from fluidsim.files import check_not_input, check_writable
    from nbv.study.sweep import parse_velocities, run_sweep, write_csv

    from .runtime import init_taichi

    config = physics_config_from_args(args)
    velocities = parse_velocities(args.velocities)
    output = check_output_file(args.output, (".csv",))
    check_not_input({"-o": output, "plot": output.with_suffix(".png")},
                    {"GAUSSIANS": args.gaussians, "--compare": args.compare})
    check_writable(output.with_suffix(".png"))
    gaussians = load_gaussians_checked(args.gaussians, args)
    other = load_gaussians_checked(args.compare) if args.compare is not None else None
    init_taichi(args.device, config.precision, args.threads)
    points = run_sweep(gaussians, config, velocities, other=other, progress=True)
    write_csv(output, points)
    plot = plot_sweep(points, output.with_suffix(".png"), title=f"D-bar vs U: {args.gaussians.name}")
    print(f"{'U m/s':>7} {'Re':>10} {'dt s':>10} {'steps':>6} {'D-bar':>12}" + ("  D-bar OTHER         gap"
                                                                                 if other is not None else ""))
    for p in points:
        extra = f" {p.dbar_other:>12.4g} {p.gap:>11.4g}" if p.dbar_other is not None else ""
        print(f"{p.speed:>7g} {p.reynolds:>10.4g} {p.dt:>10.3g} {p.steps:>6} {p.dbar:>12.4g}{extra}")
    print(f"csv: {output}\nplot: {plot}")
    return 0
