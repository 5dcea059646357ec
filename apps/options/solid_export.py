"""The ``--export-solid PATH`` and ``--export-frame`` options of simulate and score (and export's --solid): the
filled solid the probes used, written as a mesh and a voxel grid (:mod:`nbv.export.solid`)."""

from __future__ import annotations

import argparse
from pathlib import Path

FRAME_HELP = (
    "frame of the solid mesh: sim (simulation metres, Y-up, as RESULT.h5 and glTF) or scene (the "
    "Gaussians' own frame and units, to overlay the splat); the voxel grid is always in sim metres"
)


def add_solid_export_arguments(p: argparse.ArgumentParser) -> None:
    """``--export-solid PATH`` and ``--export-frame`` of simulate and score."""
    g = p.add_argument_group("solid export")
    g.add_argument(
        "--export-solid",
        type=Path,
        default=None,
        metavar="PATH",
        help="also write the filled solid the probes used: a mesh by marching cubes (.ply, .obj, .glb or "
        ".stl; the voxel grid beside it as <stem>.voxels.h5) or a voxel grid only (.h5): origin, "
        "spacing (m), occupancy (default: none)",
    )
    g.add_argument("--export-frame", choices=("sim", "scene"), default="sim", help=f"{FRAME_HELP} (default: sim)")


def solid_export_outputs(path: Path | None) -> dict[str, Path]:
    """The files ``--export-solid path`` writes, labelled for :func:`fluidsim.files.check_not_input`, after checking
    the suffix (a ValueError names the option and the suffixes) and that each can be written."""
    if path is None:
        return {}
    from fluidsim.files import check_writable
    from nbv.export.solid import check_export_path, export_paths

    mesh, grid = export_paths(check_export_path(path))
    out = {"--export-solid": mesh, "--export-solid voxels": grid} if mesh is not None else {"--export-solid": grid}
    for p in out.values():
        check_writable(p)
    return out


def write_solid_export(path: Path | None, result, frame: str = "sim") -> None:
    """Write the solid of a PhysicsResult to ``path`` (nothing when None) and print what was written."""
    if path is None:
        return
    from nbv.export.solid import export_solid

    info = export_solid(path, result.solid, 2.0 * result.config.particle_radius, result.transform.matrix, frame)
    print_solid_export(info)


def print_solid_export(info: dict) -> None:
    mesh = (
        ""
        if info["mesh"] is None
        else (
            f"mesh {info['mesh']} ({'watertight' if info['watertight'] else 'NOT watertight'}, "
            f"{info['mesh_volume_m3']:.4g} m^3), "
        )
    )
    print(f"solid: {mesh}voxels {info['voxels']} ({info['cells']} cells, {info['volume_m3']:.4g} m^3)")
