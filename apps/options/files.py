"""The files named on the command line: a Gaussian file and its loading options, the output files and folders
checked before any work, and the files of a dataset folder that no output may overwrite."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from fluidsim.files import check_input_file


def add_gaussians_input(p: argparse.ArgumentParser) -> None:
    """The positional GAUSSIANS file (its help lists the formats the readers know), then
    :func:`add_gaussian_file_arguments`."""
    from recon.formats import gaussians_help  # noqa: PLC0415 - the readers load torch: only when building the options

    p.add_argument("gaussians", type=Path, help=gaussians_help())
    add_gaussian_file_arguments(p)


def add_gaussian_file_arguments(p: argparse.ArgumentParser) -> None:
    """--spz-frame, --colmap and --dataparser-transforms: what a Gaussian file's content cannot say
    (:class:`recon.formats.LoadOptions`)."""
    g = p.add_argument_group("Gaussian file")
    g.add_argument(
        "--spz-frame",
        choices=("auto", "rub", "ply"),
        default="auto",
        help="what an .spz stores: 'auto', decided from a file of the same capture in a .ply-frame format beside it "
        "(else 'rub', with a warning); 'rub', Niantic's right-up-back, turned half a turn about x to the .ply "
        "frame; or 'ply', the .ply frame as splat-transform and SuperSplat write it (default: auto)",
    )
    g.add_argument(
        "--colmap",
        type=Path,
        default=None,
        metavar="DIR",
        help="for a gsplat checkpoint: the COLMAP model it was trained on (sparse/0 or its parent); its "
        "normalisation is recomputed and undone, so sizes are in scene units (default: none, the "
        "trainer's normalised units, with a warning)",
    )
    g.add_argument(
        "--dataparser-transforms",
        type=Path,
        default=None,
        metavar="FILE",
        help="for a nerfstudio checkpoint: its dataparser_transforms.json, undone so sizes are in scene "
        "units (default: the one beside the run's config.yml)",
    )


def load_gaussians_checked(path, args=None):
    """Load a Gaussian set of any supported format (recon.formats); ValueError naming the file when it is missing,
    a folder or unreadable. With the parsed ``args`` of :func:`add_gaussian_file_arguments`, their options apply,
    the assumed frame is logged and ``args.source_frame`` receives its record (for RESULT.h5)."""
    import logging

    from recon.formats import SUPPORTED, LoadOptions, load_gaussians_framed

    # a folder passes: recon.formats says it is a folder
    check_input_file(path, "Gaussian file", f"pass a Gaussian file ({SUPPORTED})", folder_ok=True)
    options = LoadOptions(
        spz_frame=getattr(args, "spz_frame", None) or "auto",
        colmap=getattr(args, "colmap", None),
        dataparser_transforms=getattr(args, "dataparser_transforms", None),
    )
    gaussians, fmt, frame = load_gaussians_framed(path, options)
    if fmt in ("spz", "checkpoint") and frame.metric:
        logging.getLogger(__name__).info("%s", frame.description)
    if args is not None:
        args.source_frame = frame.to_json()
    return gaussians.check(str(path))


def check_output_file(path, suffixes: tuple[str, ...]):
    """Fail before any work when ``path`` has the wrong suffix or its folder is not writable."""
    from fluidsim.files import check_writable

    if suffixes and Path(path).suffix.lower() not in suffixes:
        raise ValueError(f"output {path} must end with {' or '.join(suffixes)}")
    return check_writable(path)


def check_output_folder(folder, where: str, own: tuple[str, ...] = ()) -> Path:
    """Fail before any work when the results folder ``folder`` cannot be made or written: an
    :class:`~fluidsim.files.OutputError` (exit 4) that starts with ``where`` (the option or config key that gave
    it), never the file system's bare errno text. With ``own`` (the names this command writes at the folder's top),
    an existing folder that holds other files and none of those (``"output": "/etc"``) is refused (ValueError, exit
    2): the command would write its results among someone else's files."""
    from fluidsim.files import OutputError, check_writable

    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise OutputError(f"{where} {folder} is a file, not a folder; give a results folder that is not a file")
    if own and folder.is_dir():
        names = sorted(p.name for p in folder.iterdir())
        if names and not set(names) & set(own):
            shown = ", ".join(names[:3]) + (", ..." if len(names) > 3 else "")
            raise ValueError(
                f"{where} {folder} already holds other files ({shown}) and no results of an earlier run; give a new "
                "or empty results folder"
            )
    try:
        check_writable(folder / "results.json")
    except OutputError as exc:
        raise OutputError(f"{where} {folder}: {exc}") from None
    return folder


# The files of a dataset folder that loading reads (cameras, points, normalisation), at the top, in sparse/ and in
# sparse/0/: no output may overwrite them. Images are left out: no command that reads a dataset writes images.
DATASET_FILES = (
    "transforms_*.json",
    "dataset.json",
    "mesh.ply",
    "cameras.txt",
    "cameras.bin",
    "images.txt",
    "images.bin",
    "points3D.txt",
    "points3D.bin",
    "points3D.ply",
)


def dataset_inputs(dataset) -> list[tuple[str, Path]]:
    """("DATASET file", path) for each existing :data:`DATASET_FILES` file of a dataset folder (or the
    transforms_*.json given), for :func:`fluidsim.files.check_not_input`."""
    root = Path(dataset)
    if root.is_file():
        return [("DATASET file", root)]
    return [
        ("DATASET file", f)
        for folder in (root, root / "sparse", root / "sparse" / "0")
        if folder.is_dir()
        for pattern in DATASET_FILES
        for f in sorted(folder.glob(pattern))
    ]


def gaussian_file_inputs(
    args: argparse.Namespace, label: str = "GAUSSIANS", path: Path | None = None
) -> list[tuple[str, Path]]:
    """The files read for the Gaussian file ``path`` (default ``args.gaussians``), labelled for
    :func:`fluidsim.files.check_not_input`: the file itself (as ``label``), --dataparser-transforms and the COLMAP
    model files of --colmap (the folder given, its sparse/0 and sparse), so that no output overwrites a file it needs
    (`-o dataparser_transforms.json`)."""
    from recon.colmap import BINARY_FILES, TEXT_FILES  # noqa: PLC0415 - the readers load torch: only when run

    found = [(label, Path(args.gaussians if path is None else path))]
    if getattr(args, "dataparser_transforms", None) is not None:
        found.append(("--dataparser-transforms", Path(args.dataparser_transforms)))
    if getattr(args, "colmap", None) is not None:
        root = Path(args.colmap)
        found += [
            ("--colmap", folder / name)
            for folder in (root, root / "sparse" / "0", root / "sparse")
            for name in (*BINARY_FILES, *TEXT_FILES)
            if (folder / name).is_file()
        ]
    return found


def check_outside_dataset(output: Path, dataset: Path) -> None:
    """Refuse an output folder that is the dataset folder or lies inside it: the run would write its files among the
    dataset's (a later `render-dataset --overwrite` or a copy of the dataset would take them along)."""
    root = Path(dataset).resolve()
    root = root.parent if root.is_file() else root
    out = Path(output).resolve()
    if out == root or root in out.parents:
        raise ValueError(
            f"-o {output} lies inside the dataset {dataset}: the run would write among the dataset's files; "
            "choose a run folder outside the dataset"
        )


def check_ply_output(path: Path) -> None:
    """Raise before any training when ``path`` is not a writable .ply destination."""
    if path.suffix.lower() != ".ply":
        raise ValueError(f"{path}: the output must be a .ply file (e.g. -o out/scene.ply)")
    parent = path.absolute().parent
    if not parent.is_dir():
        raise ValueError(f"{parent}: the output folder does not exist; create it first")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ValueError(f"{parent}: the output folder is not writable; choose another -o")
    if path.is_dir():
        raise ValueError(f"{path}: is a folder; give a .ply file name")
