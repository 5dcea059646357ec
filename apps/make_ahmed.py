"""`fluidgs ahmed`: write the procedural Ahmed body (Ahmed, Ramm & Faltin 1984) as a mesh file.

The geometry, frame and units are those of :mod:`recon.ahmed`: metres, nose at +x, Y up (or Z up with
``--up z``), ground at the stilts' feet.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

log = logging.getLogger("fluidgs")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("-o", "--output", type=Path, required=True,
                   help="output mesh: .obj, .stl, .ply, .off, .gltf or .glb (written atomically)")
    p.add_argument("--slant", type=float, default=25.0, help="rear slant angle in degrees, 0 to 40")
    p.add_argument("--no-stilts", action="store_true", help="leave out the four stilts (the body stays 50 mm up)")
    p.add_argument("--up", choices=("y", "z"), default="y", help="up axis of the written mesh")
    p.add_argument("--scale", type=float, default=1.0,
                   help="unitless factor on all coordinates (1 = metres, 1000 = millimetres)")
    p.add_argument("--resolution", type=float, default=0.01, help="target mesh edge length in metres, before --scale")


def run_command(args: argparse.Namespace) -> int:
    from recon.ahmed import MESH_SUFFIXES, ahmed_body, enclosed_volume, save_mesh

    if args.output.suffix.lower() not in MESH_SUFFIXES:  # refuse before building anything
        raise ValueError(f"{args.output}: unsupported mesh file type {args.output.suffix!r}; "
                         f"use one of {list(MESH_SUFFIXES)}")
    mesh = ahmed_body(args.slant, args.resolution, stilts=not args.no_stilts, up=args.up, scale=args.scale)
    path = save_mesh(mesh, args.output)
    extent = mesh.get_axis_aligned_bounding_box().get_extent()
    print(f"Ahmed body, slant {args.slant:g} deg, {len(mesh.vertices)} vertices, {len(mesh.triangles)} triangles, "
          f"extent {extent[0]:.4g} x {extent[1]:.4g} x {extent[2]:.4g}, volume {enclosed_volume(mesh):.5g} -> {path}")
    return 0
