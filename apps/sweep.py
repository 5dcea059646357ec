"""`fluidgs sweep GAUSSIANS.ply --velocities 3,4,5,...`: D-bar against the inflow speed U and Re = rho U L / mu.

Delta t is CFL-constant: Delta t = Delta t_base * U_base / U over the same physical duration as the base
setting (``--steps`` x ``--dt`` at U_base = ``--speed``, default 3 m/s), so high speeds take many steps.
With ``--compare`` both sets use the scale resolved on the first (D-bar scales with its fourth power).
L of Re is the object's extent along the flow by default (``--re-length object|domain|VALUE``; printed and
stored). Before the first speed it prints the probe-steps per speed and an estimate in minutes from a short
calibration (:func:`nbv.study.sweep.calibrate`); its progress bar counts probe-steps. Writes a CSV (U, Re, L,
Delta t, steps, D-bar, the empty scene's D-bar, and with ``--compare OTHER.ply`` D-bar of OTHER and the gap
D-bar(OTHER) - D-bar) and a PNG plot drawn with matplotlib (:mod:`viz.plots`): D-bar against U (log x) and a
table of Re, Delta t and steps.
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
    p.add_argument(
        "gaussians",
        type=Path,
        help="Gaussians (.ply, .compressed.ply, .spz, .splat, .npz, .sog or "
        "meta.json folder, .ksplat, a gsplat or nerfstudio checkpoint), scene units",
    )
    add_gaussian_file_arguments(p)
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
    p.add_argument(
        "-o",
        "--output",
        type=Path,
        default=Path("sweep.csv"),
        help="CSV file (written atomically); the plot goes next to it as .png",
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


def print_estimate(plan, work, seconds, calibration) -> None:
    """The upfront estimate: probe-steps and minutes per speed, and the total."""
    empty = "" if calibration.empty_step_s is None else f" ({calibration.empty_step_s:.3g} s in the empty scene)"
    print(
        f"calibration: {calibration.steps} steps of one probe took {calibration.step_s:.3g} s per probe-step{empty}, "
        f"plus {calibration.run_s:.1f} s per simulation (the solid, the setup)"
    )
    print(f"{'U m/s':>7} {'dt s':>10} {'steps':>7} {'probe-steps':>12} {'est. min':>9}")
    for st, n, sec in zip(plan, work, seconds, strict=True):
        print(f"{st.speed:>7g} {st.dt:>10.3g} {st.steps:>7} {n:>12,} {sec / 60:>9.1f}")
    print(
        f"estimate: {sum(work):,} probe-steps, about {sum(seconds) / 60:.1f} min ({sum(seconds):.0f} s) on this "
        "machine",
        flush=True,
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
        {"-o": output, "plot": output.with_suffix(".png")}, {"GAUSSIANS": args.gaussians, "--compare": args.compare}
    )
    check_writable(output.with_suffix(".png"))
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
    print(
        f"Re = rho U L / mu with L = {points[0].re_length:.4g} m ({_length_words(points[0].re_length_from)}), "
        f"rho = {config.rest_density:g} kg/m^3, mu = {config.viscosity:g} Pa s"
    )
    print(
        f"{'U m/s':>7} {'Re':>10} {'dt s':>10} {'steps':>6} {'D-bar':>12} {'D-bar empty':>12}"
        + ("  D-bar OTHER         gap" if other is not None else "")
    )
    for p in points:
        extra = f" {p.dbar_other:>12.4g} {p.gap:>11.4g}" if p.dbar_other is not None else ""
        empty = "n/a" if p.dbar_empty is None else f"{p.dbar_empty:.4g}"
        print(f"{p.speed:>7g} {p.reynolds:>10.4g} {p.dt:>10.3g} {p.steps:>6} {p.dbar:>12.4g} {empty:>12}{extra}")
    print(
        f"took {took:.0f} s = {took / 60:.1f} min (estimated {sum(seconds):.0f} s = {sum(seconds) / 60:.1f} min, "
        f"x{took / max(sum(seconds), 1e-9):.2f})"
    )
    print(f"csv: {output}\nplot: {plot}")
    return 0


def _length_words(source: str) -> str:
    return {
        "object": "the object's extent along the flow",
        "domain": "the probe domain's largest extent",
        "given": "given by --re-length",
    }[source]
