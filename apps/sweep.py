"""`fluidgs sweep GAUSSIANS.ply --velocities 3,4,5,...`: D-bar against the inflow speed U and Re = rho U L / mu.

Delta t is CFL-constant: Delta t = Delta t_base * U_base / U over the same physical duration as the base
setting (``--steps`` x ``--dt`` at U_base = ``--speed``, default 3 m/s), so high speeds take many steps.
With ``--compare`` both sets use the scale resolved on the first (D-bar scales with its fourth power).
L is the largest extent of the -x probe's domain (m). Writes a CSV (U, Re, Delta t, steps, D-bar, and
with ``--compare OTHER.ply`` D-bar of OTHER and the gap D-bar(OTHER) - D-bar) and a PNG plot drawn with
OpenCV: D-bar against U (log x) and a table of Re and Delta t.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from .simulate import add_physics_arguments, check_output_file, load_gaussians_checked, physics_config_from_args

PAPER_VELOCITIES = "3,4,5,6,7,8,9,10,20,50"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("gaussians", type=Path, help="3DGS Gaussians (.ply or .npz), scene units")
    p.add_argument("--velocities", default=PAPER_VELOCITIES, help="comma list of inflow speeds U in m/s")
    p.add_argument("--compare", type=Path, default=None,
                   help="a second Gaussian set OTHER (same frame, simulated at the first set's scale); reports "
                        "D-bar(OTHER) - D-bar per U")
    p.add_argument("-o", "--output", type=Path, default=Path("sweep.csv"),
                   help="CSV file (written atomically); the plot goes next to it as .png")
    add_physics_arguments(p, empty_reference=False)  # the sweep compares D-bar across speeds, never the empty scene


def _ticks_log(lo: float, hi: float) -> list[float]:
    out = []
    for e in range(math.floor(math.log10(lo)), math.ceil(math.log10(hi)) + 1):
        for m in (1, 2, 3, 5):
            v = m * 10.0**e
            if lo * 0.999 <= v <= hi * 1.001:
                out.append(v)
    return out or [lo, hi]


def plot_sweep(points, path: Path, title: str = "") -> Path:
    """Draw D-bar (and OTHER's) against U on a log-x axis, with a Re / Delta t table; PNG written atomically."""
    import cv2

    width, height, ml, mr, mt, mb = 900, 620, 90, 30, 50, 230
    img = np.full((height, width, 3), 255, np.uint8)
    font, black, grey = cv2.FONT_HERSHEY_SIMPLEX, (0, 0, 0), (200, 200, 200)
    us = np.array([p.speed for p in points])
    series = [("D-bar", np.array([p.dbar for p in points]), (200, 80, 0))]
    if all(p.dbar_other is not None for p in points):
        series.append(("D-bar OTHER", np.array([p.dbar_other for p in points]), (0, 0, 220)))
    ulo, uhi = (us.min() / 1.2, us.max() * 1.2) if len(us) else (1.0, 10.0)
    ymax = max(max(float(s.max()) for _, s, _ in series), 1e-30) * 1.1
    x0, x1, y0, y1 = ml, width - mr, height - mb, mt

    def px(u: float) -> int:
        return int(x0 + (math.log10(u) - math.log10(ulo)) / (math.log10(uhi) - math.log10(ulo)) * (x1 - x0))

    def py(v: float) -> int:
        return int(y0 - v / ymax * (y0 - y1))

    for t in _ticks_log(ulo, uhi):
        cv2.line(img, (px(t), y0), (px(t), y1), grey, 1)
        cv2.putText(img, f"{t:g}", (px(t) - 10, y0 + 18), font, 0.45, black, 1, cv2.LINE_AA)
    for k in range(6):
        v = ymax * k / 5
        cv2.line(img, (x0, py(v)), (x1, py(v)), grey, 1)
        cv2.putText(img, f"{v:.3g}", (4, py(v) + 4), font, 0.4, black, 1, cv2.LINE_AA)
    cv2.rectangle(img, (x0, y1), (x1, y0), black, 1)
    cv2.putText(img, "U (m/s, log scale)", ((x0 + x1) // 2 - 70, y0 + 40), font, 0.5, black, 1, cv2.LINE_AA)
    cv2.putText(img, "D-bar (m^4/s)", (4, y1 - 12), font, 0.5, black, 1, cv2.LINE_AA)
    cv2.putText(img, title or "geometry divergence vs inflow speed", (x0 + 120, 24), font, 0.6, black, 1, cv2.LINE_AA)
    for k, (name, vals, color) in enumerate(series):
        pts = np.array([[px(u), py(v)] for u, v in zip(us, vals, strict=True)], np.int32)
        cv2.polylines(img, [pts], False, color, 2, cv2.LINE_AA)
        for q in pts:
            cv2.circle(img, tuple(int(c) for c in q), 4, color, -1, cv2.LINE_AA)
        ly = y1 + 20 + 20 * k
        cv2.line(img, (x0 + 10, ly - 4), (x0 + 40, ly - 4), color, 2)
        cv2.putText(img, name, (x0 + 50, ly), font, 0.45, black, 1, cv2.LINE_AA)
    rows = [("U m/s", [f"{p.speed:g}" for p in points]), ("Re", [f"{p.reynolds:.3g}" for p in points]),
            ("dt s", [f"{p.dt:.2e}" for p in points]), ("steps", [str(p.steps) for p in points]),
            ("D-bar", [f"{p.dbar:.3g}" for p in points])]
    if series[1:]:
        rows.append(("gap", [f"{p.gap:.3g}" for p in points]))
    col = max(1, (width - 100) // max(1, len(points)))
    for r, (name, cells) in enumerate(rows):
        y = y0 + 70 + 24 * r
        cv2.putText(img, name, (8, y), font, 0.45, black, 1, cv2.LINE_AA)
        for c, text in enumerate(cells):
            cv2.putText(img, text, (90 + c * col, y), font, 0.4, black, 1, cv2.LINE_AA)
    from fluidsim.output import atomic_output

    with atomic_output(path, ".png") as tmp:  # OpenCV picks the format from the suffix
        if not cv2.imwrite(str(tmp), img):
            raise OSError("OpenCV could not write the plot; choose a writable output folder")
    return path


def run_command(args: argparse.Namespace) -> int:
    from fluidsim.output import check_not_input, check_writable
    from nbv.sweep import parse_velocities, run_sweep, write_csv

    from .runtime import init_taichi

    config = physics_config_from_args(args)
    velocities = parse_velocities(args.velocities)
    output = check_output_file(args.output, (".csv",))
    check_not_input({"-o": output, "plot": output.with_suffix(".png")},
                    {"GAUSSIANS": args.gaussians, "--compare": args.compare})
    check_writable(output.with_suffix(".png"))
    gaussians = load_gaussians_checked(args.gaussians)
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
