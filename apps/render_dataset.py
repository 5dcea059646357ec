"""``fluidgs render-dataset MESH -o DIR``: render a mesh into a Blender-format dataset (CPU ray casting).

Replaces the paper's Blender + BlenderNeRF rendering of DrivAerNet++ (appendix): the object fitted to a
bounding box of 4, cameras at radius 6, 200 train / candidate and 100 test views in random order, grey
#909090 on a transparent background. See :mod:`recon.mesh_render` for the shading and the output layout.
Rendering runs on the CPU (open3d's multithreaded ray casting), so there is no ``--device`` option.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from recon.mesh_render import MeshDatasetConfig, render_mesh_dataset

_DEFAULTS = MeshDatasetConfig()


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("mesh", type=Path, help="input triangle mesh (.obj, .stl or .ply; any units, it is normalised)")
    p.add_argument("-o", "--output", type=Path, required=True,
                   help="dataset folder to create (written atomically; must be empty unless --overwrite)")
    p.add_argument("--train", type=int, default=_DEFAULTS.n_train, help="number of train / candidate views")
    p.add_argument("--test", type=int, default=_DEFAULTS.n_test, help="number of test views")
    p.add_argument("--res", type=int, default=_DEFAULTS.resolution,
                   help="image width = height, pixels (the paper used 800)")
    p.add_argument("--fov", type=float, default=_DEFAULTS.fov_x, help="horizontal = vertical field of view, degrees")
    p.add_argument("--box", type=float, default=_DEFAULTS.box_size,
                   help="largest extent of the normalised object, scene units (centred at the origin)")
    p.add_argument("--radius", type=float, default=_DEFAULTS.radius,
                   help="camera distance from the centre, scene units")
    p.add_argument("--color", default=_DEFAULTS.color, help="object colour, '#RRGGBB'")
    p.add_argument("--ambient", type=float, default=_DEFAULTS.ambient, help="ambient shading term, in [0, 1]")
    p.add_argument("--up", "--up-axis", dest="up", default=_DEFAULTS.up_axis, metavar="UP",
                   help="the mesh's up axis, y or z (+y, +z accepted; kept up in the images; recorded in dataset.json; "
                        f"default: {_DEFAULTS.up_axis})")
    p.add_argument("--hemisphere", action="store_true",
                   help="cameras on the upper hemisphere only (e.g. a car on a road) instead of the full sphere")
    p.add_argument("--supersample", type=int, default=_DEFAULTS.supersample,
                   help="s x s rays per pixel for anti-aliased edges and alpha (1 = one ray per pixel)")
    p.add_argument("--seed", type=int, default=_DEFAULTS.seed, help="random seed of the camera positions")
    p.add_argument("--overwrite", action="store_true", help="replace a non-empty output folder")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")


def mesh_up_axis(text: str) -> str:
    """``--up`` of render-dataset -> "y" or "z" (the renderer's lights and orbits are built for those two)."""
    from nbv.scene_frame import parse_up, up_label

    label = up_label(parse_up(text))
    if label not in ("+y", "+z"):
        raise ValueError(f"--up {text!r}: render-dataset renders y-up or z-up meshes (--up y or --up z); rotate the "
                         "mesh first, or render it and pass --up to the commands that read the Gaussians")
    return label[1]


def make_parents(out: Path) -> None:
    """Create the missing folders above the dataset folder ``out`` (as ``sim`` does for its file).

    Raises:
        OutputError: a parent is a file, or a folder cannot be created (naming it and the fix).
    """
    from fluidsim.output import OutputError

    parent = out.absolute().parent
    if parent.is_dir():
        return
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError) as exc:
        raise OutputError(f"-o {out}: a parent of the output is a file, not a folder ({exc.filename}); choose "
                          "another -o") from exc
    except OSError as exc:
        raise OutputError(f"cannot create the folder {parent} for -o {out}: {exc.strerror}; choose a writable "
                          "path") from exc


def run_command(args: argparse.Namespace) -> int:
    args.up = mesh_up_axis(args.up)
    config = MeshDatasetConfig(n_train=args.train, n_test=args.test, resolution=args.res, fov_x=args.fov,
                               box_size=args.box, radius=args.radius, color=args.color, ambient=args.ambient,
                               up_axis=args.up, hemisphere=args.hemisphere, seed=args.seed,
                               supersample=args.supersample)
    from fluidsim.output import check_not_input

    check_not_input({"-o": args.output}, {"MESH": args.mesh}, replaced={"-o": args.output})
    if args.mesh.is_file():  # a missing mesh is reported by the renderer, before any folder is made
        make_parents(args.output)
    out = render_mesh_dataset(args.mesh, args.output, config, overwrite=args.overwrite,
                              progress=not args.no_progress)
    print(f"wrote {out} ({config.n_train} train, {config.n_test} test views at {config.resolution} px)")
    return 0
