"""``fluidgs render-dataset MESH -o DIR``: render a mesh into a Blender-format dataset (CPU ray casting).

Replaces the paper's Blender + BlenderNeRF rendering of DrivAerNet++ (appendix): the object fitted to a
bounding box of 4, cameras at radius 6, 200 train / candidate and 100 test views in random order, grey
#909090 on a transparent background. See :mod:`recon.mesh_render` for the shading and the output layout.
Rendering runs on the CPU (open3d's multithreaded ray casting), so there is no ``--device`` option.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from .options.common import add_output_option
from .options.numbers import seed

FIELDS = (
    "n_train",
    "n_test",
    "resolution",
    "fov_x",
    "box_size",
    "radius",
    "color",
    "ambient",
    "up_axis",
    "hemisphere",
    "supersample",
    "seed",
)
OVERRIDES = {
    "n_train": {"flags": ("--train",)},
    "n_test": {"flags": ("--test",)},
    "resolution": {"flags": ("--res",)},
    "fov_x": {"flags": ("--fov",)},
    "box_size": {"flags": ("--box",)},
    "seed": {"type": seed},  # 0 to recon.train_config.MAX_SEED, refused when parsed
    "up_axis": {
        "flags": ("--up", "--up-axis"),
        "dest": "up",
        "metavar": "UP",
        "help": "the mesh's up axis, y or z (+y, +z accepted; kept up in the images; recorded in dataset.json)",
    },
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    from recon.mesh_render import MeshDatasetConfig

    from .options import add_config_options

    p.add_argument("mesh", type=Path, help="input triangle mesh (.obj, .stl or .ply; any units, it is normalised)")
    add_output_option(p, "dataset folder to create (written atomically; must be empty unless --overwrite)")
    add_config_options(p, MeshDatasetConfig, FIELDS, OVERRIDES)
    p.add_argument("--overwrite", action="store_true", help="replace a non-empty output folder")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")


def mesh_up_axis(text: str) -> str:
    """``--up`` of render-dataset -> "y" or "z" (the renderer's lights and orbits are built for those two)."""
    from nbv.physics.scene_frame import parse_up, up_label

    label = up_label(parse_up(text))
    if label not in ("+y", "+z"):
        raise ValueError(
            f"--up {text!r}: render-dataset renders y-up or z-up meshes (--up y or --up z); rotate the "
            "mesh first, or render it and pass --up to the commands that read the Gaussians"
        )
    return label[1]


def make_parents(out: Path) -> None:
    """Create the missing folders above the dataset folder ``out`` (as ``sim`` does for its file).

    Raises:
        OutputError: a parent is a file, or a folder cannot be created (naming it and the fix).
    """
    from fluidsim.files import OutputError

    parent = out.absolute().parent
    if parent.is_dir():
        return
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError) as exc:
        raise OutputError(
            f"-o {out}: a parent of the output is a file, not a folder ({exc.filename}); choose another -o"
        ) from exc
    except OSError as exc:
        raise OutputError(
            f"cannot create the folder {parent} for -o {out}: {exc.strerror}; choose a writable path"
        ) from exc


def run_command(args: argparse.Namespace) -> int:
    from recon.mesh_render import MeshDatasetConfig, render_mesh_dataset

    from .options import config_from_args

    config = config_from_args(
        MeshDatasetConfig,
        args,
        FIELDS,
        OVERRIDES,
        up_axis=mesh_up_axis(args.up if args.up is not None else MeshDatasetConfig.up_axis),
    )
    from fluidsim.files import check_not_input

    check_not_input({"-o": args.output}, {"MESH": args.mesh}, replaced={"-o": args.output})
    if args.mesh.is_file():  # a missing mesh is reported by the renderer, before any folder is made
        make_parents(args.output)
    out = render_mesh_dataset(args.mesh, args.output, config, overwrite=args.overwrite, progress=not args.no_progress)
    print(f"wrote {out} ({config.n_train} train, {config.n_test} test views at {config.resolution} px)")
    if config.n_test == 0:
        print("note: no test views; `fluidgs eval` and `experiment` measure on them (pass --test N to render some)")
    return 0
