"""`fluidgs ahmed`: write the procedural Ahmed body (Ahmed, Ramm & Faltin 1984) as a mesh file.

The geometry, frame and units are those of :mod:`recon.ahmed`: metres, nose at +x, Y up (or Z up with
``--up z``), ground at the stilts' feet.
"""

from __future__ import annotations

import argparse
import logging

from .options.common import add_output_option

log = logging.getLogger("fluidgs")


OVERRIDES = {
    "slant_deg": {"flags": ("--slant",)},
    "stilts": {
        "flags": ("--no-stilts",),
        "dest": "no_stilts",
        "negate": True,
        "default_text": "with stilts",
        "help": "leave out the four stilts (the body stays 50 mm up)",
    },
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_output_option(p, "output mesh: .obj, .stl, .ply, .off, .gltf or .glb (written atomically)")
    from recon.ahmed import AhmedBody

    from .options import add_config_options

    add_config_options(p, AhmedBody, ("slant_deg", "stilts"), OVERRIDES)
    p.add_argument("--up", choices=("y", "z"), default="y", help="up axis of the written mesh")
    p.add_argument(
        "--scale", type=float, default=1.0, help="unitless factor on all coordinates (1 = metres, 1000 = millimetres)"
    )
    add_config_options(
        p, AhmedBody, ("resolution",), {"resolution": {"help": "target mesh edge length, m, before --scale"}}
    )


def run_command(args: argparse.Namespace) -> int:
    from fluidsim.files import check_writable
    from recon.ahmed import MESH_SUFFIXES, AhmedBody, ahmed_body, enclosed_volume, save_mesh

    from .options import config_values
    from .options.fields import option_names, options_named

    if args.output.suffix.lower() not in MESH_SUFFIXES:  # refuse before building anything
        raise ValueError(
            f"{args.output}: unsupported mesh file type {args.output.suffix!r}; use one of {list(MESH_SUFFIXES)}"
        )
    check_writable(args.output)
    body = {
        **{f: getattr(AhmedBody, f) for f in ("slant_deg", "stilts", "resolution")},
        **config_values(AhmedBody, args, ("slant_deg", "stilts", "resolution"), OVERRIDES),
    }
    names = {**option_names(AhmedBody, ("slant_deg", "stilts", "resolution"), OVERRIDES), "scale": "--scale"}
    with options_named(names):
        mesh = ahmed_body(body["slant_deg"], body["resolution"], stilts=body["stilts"], up=args.up, scale=args.scale)
    path = save_mesh(mesh, args.output)
    extent = mesh.get_axis_aligned_bounding_box().get_extent()
    print(
        f"Ahmed body, slant {body['slant_deg']:g} deg, {len(mesh.vertices)} vertices, {len(mesh.triangles)} "
        f"triangles, extent {extent[0]:.4g} x {extent[1]:.4g} x {extent[2]:.4g}, "
        f"volume {enclosed_volume(mesh):.5g} -> {path}"
    )
    return 0
