"""`fluidgs bench hole`: a hole punched in a capture's surface, and what it does to the solid and to its rim's D_g.

The check of the paper's premise (Sec. 3.3) on real captures. The hole removes the Gaussians whose centres lie in a
cylinder of radius ``--radius`` and half-depth ``--depth`` along the surface normal (:class:`nbv.bench.holes.Hole`). The
rim is the Gaussians left within ``--band`` of its edge, in the same slab. For each lattice shift in ``--shifts``
(the whole capture moved by that fraction of the spacing along x, y and z, to see how the answer depends on where
the lattice falls), the intact and the holed set are solidified and probed at the same scale, and it prints:

- the Gaussians removed, the solid points of both sets and how many the hole removed and added;
- the axis opacity: what a 3DGS render along the hole's axis still shows through it, combined and the largest single
  Gaussian (:func:`nbv.bench.holes.axis_opacity`; the solid can only open where this falls below tau);
- per probe, the rim's mean D_g^(IC) on both sets and the ratio holed / intact, with the fraction of rim Gaussians
  that any fluid sample reached (``*`` marks the head-on probe, whose flow runs most against the hole's normal); then
  the max-combined ratio (D_g = max over the probes, paper Eq. 3) and D-bar.

``--solid-only`` stops after the solids (seconds, no probes). ``--ideal`` also cuts every lattice point inside the
cylinder out of the holed set's solid (:func:`nbv.bench.holes.cut_cylinder`): what the rim's D_g shows for a hole
that is open at lattice resolution, whatever the Gaussians around it cover.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from pathlib import Path

from ..options.common import add_device_option, add_json_option, add_probe_size_options, add_up_option
from ..runtime import thread_count

SIDES = {"+x": (1.0, 0.0, 0.0), "-x": (-1.0, 0.0, 0.0), "+z": (0.0, 0.0, 1.0), "-z": (0.0, 0.0, -1.0)}


def _vector(text: str) -> tuple[float, float, float]:
    try:
        v = tuple(float(c) for c in text.split(","))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected X,Y,Z (three numbers), got {text!r}") from exc
    if len(v) != 3 or not all(math.isfinite(c) for c in v):
        raise argparse.ArgumentTypeError(f"expected X,Y,Z (three finite numbers), got {text!r}")
    return v


def _shifts(text: str) -> tuple[float, ...]:
    try:
        v = tuple(float(c) for c in text.split(","))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected a comma list of fractions of the spacing, got {text!r}") from exc
    if not v or not all(math.isfinite(c) for c in v):
        raise argparse.ArgumentTypeError(f"expected finite fractions of the spacing, got {text!r}")
    return v


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("gaussians", type=Path, help="the capture (any supported Gaussian format)")
    add_up_option(p, "the capture's up direction (axis or X,Y,Z vector; default: %(default)s)")
    p.add_argument("--scale", default="auto", help="metres per scene unit, or auto (2 m largest extent)")
    where = p.add_mutually_exclusive_group()
    where.add_argument(
        "--point",
        type=_vector,
        default=None,
        metavar="X,Y,Z",
        help="a surface point on the hole's axis, simulation metres (Y-up)",
    )
    where.add_argument(
        "--side",
        choices=sorted(SIDES),
        default="+x",
        help="find the point on this side of the object at --height (default: %(default)s)",
    )
    p.add_argument(
        "--height",
        type=float,
        default=None,
        help="--side: simulation height y of the point, m (default: the middle of the object)",
    )
    p.add_argument(
        "--lateral",
        type=float,
        default=0.0,
        help="--side: offset across the side, m (z for the x sides, x for the z sides; default 0)",
    )
    p.add_argument(
        "--normal",
        type=_vector,
        default=None,
        metavar="X,Y,Z",
        help="the hole's axis (default: the surface normal of the centres within 8 cm, facing out)",
    )
    p.add_argument("--radius", type=float, default=0.055, help="hole radius, m (default: %(default)s, 11 cm wide)")
    p.add_argument(
        "--depth",
        type=float,
        default=0.06,
        help="half-depth of the hole's cylinder along the normal, m; inf cuts through the object "
        "(default: %(default)s)",
    )
    p.add_argument("--band", type=float, default=0.055, help="rim width beyond the radius, m (default: %(default)s)")
    p.add_argument(
        "--see-through",
        type=float,
        default=None,
        metavar="EPS",
        help="also remove every Gaussian whose peak opacity on a ray through the disc (within the slab) "
        "exceeds EPS, so that a render sees through the hole (default: centres only)",
    )
    p.add_argument(
        "--ideal",
        action="store_true",
        help="also cut every lattice point inside the hole's cylinder out of the holed set's solid: an "
        "ideal hole at lattice resolution, to measure what the rim's D_g can resolve (default: off, "
        "the solid of the holed Gaussians)",
    )
    p.add_argument(
        "--shifts",
        type=_shifts,
        default=(0.0,),
        metavar="F,F,...",
        help="lattice shifts, fractions of the spacing along x, y and z (default: 0)",
    )
    p.add_argument("--paper", action="store_true", help="paper setting: r = 0.025 m, 750 steps (default: quick)")
    add_probe_size_options(
        p, "particle radius r, m (overrides the preset)", "steps per probe (default: 300, 750 with --paper)"
    )
    p.add_argument("--directions", default="-x,+x,-z,+z,-y", help="comma list of probes (default: all five)")
    p.add_argument("--solid-only", action="store_true", help="compare the solids only (no probes)")
    p.add_argument("--threads", type=thread_count, default=2, help="CPU threads (default: %(default)s)")
    add_device_option(p, "Taichi device (default: %(default)s)")
    add_json_option(p)


def run_command(args: argparse.Namespace) -> int:
    from fluidsim.files import write_json_atomic
    from nbv.bench.holes import locate_hole, measure_shift, shift_lines, shifts_line
    from nbv.physics import QUICK, PhysicsConfig, parse_directions, scene_transform
    from nbv.physics.scene_frame import gaussian_arrays_in_sim

    from ..options import check_output_file, load_gaussians_checked
    from ..runtime import init_taichi

    if args.see_through is not None and not 0.0 < args.see_through < 1.0:
        raise ValueError(f"--see-through must be an opacity in (0, 1), got {args.see_through}")
    for name in ("radius", "band", "depth"):
        v = getattr(args, name)
        if not (v > 0) or (name != "depth" and not math.isfinite(v)):
            raise ValueError(f"--{name} must be a length > 0 m{' (inf: through)' if name == 'depth' else ''}, got {v}")
    if args.json is not None:
        check_output_file(args.json, (".json",))
    gaussians = load_gaussians_checked(args.gaussians)
    radius = args.particle_radius or (0.025 if args.paper else QUICK["particle_radius"])
    steps = args.steps or (750 if args.paper else QUICK["steps"])
    scale = args.scale if args.scale == "auto" else float(args.scale)
    cfg = PhysicsConfig(
        particle_radius=radius,
        steps=steps,
        directions=parse_directions(args.directions),
        up=args.up,
        scale=scale,
        empty_reference=False,
    )
    init_taichi(args.device, cfg.precision, args.threads)
    transform = scene_transform(gaussians, cfg)  # fixed here: the holed set keeps the intact set's scale
    cfg = dataclasses.replace(cfg, scale=transform.scale)
    means, _, opacities, _ = gaussian_arrays_in_sim(gaussians, transform)
    where = {"side": SIDES[args.side], "height": args.height, "lateral": args.lateral, "normal": args.normal}
    hole = locate_hole(
        means, opacities, point=args.point, **where, radius=args.radius, depth=args.depth, band=args.band
    )
    print(
        f"{args.gaussians}: {gaussians.num:,} Gaussians, {transform.scale:.4g} m per unit; {hole.describe()}; "
        f"r = {radius} m, {steps} steps, probes {','.join(cfg.directions)}"
    )
    results = []
    for shift in args.shifts:
        results.append(
            measure_shift(gaussians, cfg, transform, hole, shift, args.solid_only, args.see_through, ideal=args.ideal)
        )
        print("\n".join(shift_lines(results[-1])))
    if len(results) > 1 and not args.solid_only:
        print(shifts_line(results))
    if args.json is not None:
        hole_doc = {**dataclasses.asdict(hole), "see_through": args.see_through, "ideal": args.ideal}
        write_json_atomic(
            args.json,
            {
                "source": str(args.gaussians),
                "hole": hole_doc,
                "particle_radius": radius,
                "steps": steps,
                "shifts": results,
            },
        )
    return 0
