"""`fluidgs sweep GAUSSIANS.ply --velocities 3,4,5,...`: D-bar against the inflow speed U and Re = rho U L / mu.

Delta t is CFL-constant: Delta t = Delta t_base * U_base / U over the same physical duration as the base
setting (``--steps`` x ``--dt`` at U_base = ``--speed``, default 3 m/s), so high speeds take many steps.
With ``--compare`` both sets use the scale resolved on the first (D-bar scales with its fourth power).
L of Re is the object's extent along the flow by default (``--re-length object|domain|VALUE``; printed and
stored). Before the first speed it prints the probe-steps per speed and an estimate in minutes from a short
calibration (:func:`nbv.study.sweep.calibrate`); its progress bar counts probe-steps. Writes a CSV (U, Re, L,
Delta t, steps, D-bar, the empty scene's D-bar, and with ``--compare OTHER.ply`` D-bar of OTHER and the gap
D-bar(OTHER) - D-bar, then C_d, the drag in N and the probe they belong to) and a PNG plot drawn with matplotlib
(:mod:`viz.plots`): D-bar against U (log x) and a table of Re, Delta t and steps. C_d = 2 F / (rho U^2 A) is the
flow probe's (-x, else the first probe run: the probe L is measured along), from its time-mean drag over the second
half of each run; with C_d at every speed a second PNG, ``OUTPUT_cd.png``, draws C_d against Re (log x), each point
labelled by U.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from .options import (
    add_gaussians_input,
    add_physics_arguments,
    check_output_file,
    load_gaussians_checked,
    physics_config_from_args,
)
from .options.common import add_output_option
from .options.sweep_report import drag_words, length_words, print_estimate, print_points


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_gaussians_input(p)
    from nbv.study.sweep import PAPER_VELOCITIES

    p.add_argument(
        "--velocities",
        default=",".join(f"{u:g}" for u in PAPER_VELOCITIES),
        help="comma list of inflow speeds U in m/s (default: the paper's, %(default)s)",
    )
    p.add_argument(
        "--compare",
        type=Path,
        default=None,
        help="a second Gaussian set OTHER (same frame, simulated at the first set's scale); reports "
        "D-bar(OTHER) - D-bar per U",
    )
    add_output_option(
        p,
        "CSV file (written atomically); the plots go next to it: D-bar as .png, C_d against Re as _cd.png",
        default=Path("sweep.csv"),
    )
    p.add_argument(
        "--re-length",
        default="object",
        metavar="L",
        help="L of Re = rho U L / mu: object (the solid's extent along the flow of the -x probe), domain "
        "(the largest extent of that probe's domain) or a length in m (default: object)",
    )
    add_physics_arguments(p)


def plot_sweep(points, path: Path, title: str = "") -> Path:
    """Draw D-bar (and OTHER's) against U on a log-x axis, with a Re / Delta t table (:func:`viz.plots.plot_sweep`);
    PNG written atomically."""
    from viz.plots import plot_sweep as draw

    other = [p.dbar_other for p in points] if all(p.dbar_other is not None for p in points) else None
    empty = [p.dbar_empty for p in points] if all(p.dbar_empty is not None for p in points) else None
    return draw(
        path,
        [p.speed for p in points],
        [p.dbar for p in points],
        dbar_other=other,
        dbar_empty=empty,
        reynolds=[p.reynolds for p in points],
        dts=[p.dt for p in points],
        steps=[p.steps for p in points],
        title=title,
    )


def drag_plot_path(output: Path) -> Path:
    """Where the C_d-Re plot of the sweep written to ``output`` (CSV) goes: OUTPUT_cd.png beside it."""
    return output.with_name(output.stem + "_cd.png")


def plot_drag(points, path: Path, title: str = "") -> Path | None:
    """Draw C_d against Re (log x), points labelled by U (:func:`viz.plots.plot_drag_coefficient`), PNG written
    atomically; None (nothing drawn) when a speed has no C_d or no finite Re."""
    import math

    from viz.plots import plot_drag_coefficient

    if not all(p.drag_coefficient is not None and math.isfinite(p.reynolds) and p.reynolds > 0 for p in points):
        return None
    return plot_drag_coefficient(
        path, [p.reynolds for p in points], [p.drag_coefficient for p in points], [p.speed for p in points], title=title
    )


def run_command(args: argparse.Namespace) -> int:
    import time

    from fluidsim.files import check_not_input, check_writable
    from nbv.study.sweep import (
        calibrate,
        estimate,
        parse_re_length,
        parse_velocities,
        pinned,
        probe_steps,
        run_sweep,
        schedule,
        write_csv,
    )

    from .runtime import init_taichi

    config = physics_config_from_args(args)
    velocities = parse_velocities(args.velocities)
    re_length = parse_re_length(args.re_length)
    output = check_output_file(args.output, (".csv",))
    check_not_input(
        {"-o": output, "plot": output.with_suffix(".png"), "C_d plot": drag_plot_path(output)},
        {"GAUSSIANS": args.gaussians, "--compare": args.compare},
    )
    check_writable(output.with_suffix(".png"))
    check_writable(drag_plot_path(output))
    gaussians = load_gaussians_checked(args.gaussians, args)
    other = load_gaussians_checked(args.compare, args) if args.compare is not None else None
    init_taichi(args.device, config.precision, args.threads)
    config = pinned(gaussians, config)
    plan = schedule(velocities, config.dt, config.steps, u_base=config.speed)
    calibration = calibrate(gaussians, config)
    work = probe_steps(plan, config, other is not None)
    seconds = estimate(plan, config, calibration, other is not None)
    print_estimate(plan, work, seconds, calibration)
    t0 = time.perf_counter()
    points = run_sweep(gaussians, config, velocities, other=other, progress=True, re_length=re_length)
    took = time.perf_counter() - t0
    write_csv(output, points)
    plot = plot_sweep(points, output.with_suffix(".png"), title=f"D-bar vs U: {args.gaussians.name}")
    first = points[0]
    cd_plot = plot_drag(
        points,
        drag_plot_path(output),
        title=f"C_d vs Re: {args.gaussians.name} (probe {first.drag_probe}, L = {first.re_length:.3g} m)",
    )
    print(
        f"Re = rho U L / mu with L = {first.re_length:.4g} m "
        f"({length_words(first.re_length_from, first.drag_probe)}), "
        f"rho = {config.rest_density:g} kg/m^3, mu = {config.viscosity:g} Pa s"
    )
    print(drag_words(first))
    print_points(points, other is not None)
    print(
        f"took {took:.0f} s = {took / 60:.1f} min (estimated {sum(seconds):.0f} s = {sum(seconds) / 60:.1f} min, "
        f"x{took / max(sum(seconds), 1e-9):.2f})"
    )
    print(f"csv: {output}\nplot: {plot}")
    print(f"C_d plot: {cd_plot}" if cd_plot is not None else "C_d plot: not drawn (a speed has no C_d or no finite Re)")
    return 0
