"""Output checks before any work: an output the file system refuses, and an output that is one of the inputs.

:func:`check_writable` creates the missing folders, checks the name lengths and tries the very temporary name of
the atomic writers (:func:`fluidsim.files.atomic.temp_path`), so a read-only, full or unwritable folder is found
before a simulation, not after it (:class:`~fluidsim.files.atomic.OutputError`, exit code 4).
Then :func:`check_not_input` refuses an output that would overwrite an input or another output, also through a
symbolic or a hard link (``ValueError``, exit code 2).
Inputs: :func:`check_input_file` refuses what is not a regular file before it is opened, and :func:`read_json` reads
every JSON file a user hands in (cameras, scenes, configs, transforms) with one message for each way it can be bad.
"""

from __future__ import annotations

import errno
import itertools
import json
import os
import stat
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from .atomic import OutputError, PathLike, note_created_folder, temp_path, track_temp, untrack_temp


def _first_existing(p: Path) -> Path:
    """``p`` or its nearest ancestor that exists."""
    p = p.absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def _check_name_lengths(p: Path, folder: Path) -> None:
    try:
        name_max = os.pathconf(folder, "PC_NAME_MAX")
        path_max = os.pathconf(folder, "PC_PATH_MAX")
    except (OSError, ValueError):
        name_max, path_max = 255, 4096
    for part in p.absolute().parts[1:]:
        if len(os.fsencode(part)) > name_max:
            raise OutputError(
                f"output path {p}: the name {part[:40]}... is {len(os.fsencode(part))} bytes, longer "
                f"than the {name_max} bytes this file system allows; choose a shorter name"
            )
    if len(os.fsencode(str(p.absolute()))) >= path_max:
        raise OutputError(
            f"output path {p} is longer than the {path_max} bytes this system allows; choose a shorter path"
        )


def check_writable(path: PathLike) -> Path:
    """Fail early, before any work, when ``path`` cannot be written as an output file.

    Creates the missing parent folders, checks the name lengths against the file system's limits, then
    creates and removes a temporary file of the writers' own pattern (:func:`temp_path`) in the folder, so
    that a read-only, full or unwritable folder is found now, not after the simulation.

    Raises:
        OutputError: naming the path and the fix (a parent is a file, the output is a folder, a name is too
            long, the folder cannot be created or written).
    """
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    blocker = _first_existing(parent)
    if not blocker.is_dir():
        raise OutputError(
            f"output path {p}: {blocker} is a file, not a folder; choose an output path whose folders are folders"
        )
    _check_name_lengths(p, blocker)
    if not parent.exists():
        missing = [parent, *[q for q in parent.parents if not q.exists()]]
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OutputError(f"cannot create the output folder {parent}: {exc}; choose a writable path") from exc
        for folder in missing:
            note_created_folder(folder)
    if p.is_dir():
        raise OutputError(f"output path {p} is a folder; give a file name such as {p / 'out.h5'}")
    probe = track_temp(temp_path(p))
    try:
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except OSError as exc:
        untrack_temp(probe)
        what = "is not writable" if exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS) else "takes no new files"
        raise OutputError(f"output folder {parent} {what} ({exc.strerror}); choose another output path") from exc
    os.close(fd)
    probe.unlink()
    untrack_temp(probe)
    return p


# ---- inputs must be readable files ------------------------------------------------------------------------------
def input_problem(path: PathLike, folder_ok: bool = False) -> str | None:
    """What makes ``path`` unfit as an input file, in words ("does not exist", "is a FIFO (named pipe) ...", "is a
    symbolic link loop ..."), or None for a regular file (and, with ``folder_ok``, a folder). Decided from the file's
    type alone, before anything is opened: a FIFO would block the reader and /dev/zero never ends."""
    p = Path(path)
    try:
        mode = os.stat(p).st_mode
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return "is a symbolic link loop (the link leads back to itself)"
        if exc.errno == errno.ENOENT and os.path.lexists(p):
            return f"is a broken symbolic link (to {os.readlink(p)}, which does not exist)"
        if exc.errno in (errno.ENOENT, errno.ENOTDIR):
            return "does not exist"
        if exc.errno == errno.ENAMETOOLONG:
            return "is a name longer than this system allows"
        return f"cannot be read ({exc.strerror})"
    if stat.S_ISREG(mode) or (folder_ok and stat.S_ISDIR(mode)):
        return None
    kinds = (
        (stat.S_ISDIR, "is a folder, not a file"),
        (stat.S_ISFIFO, "is a FIFO (named pipe), not a file: reading it would wait for a writer"),
        (stat.S_ISCHR, "is a character device (such as /dev/zero), not a file"),
        (stat.S_ISBLK, "is a block device, not a file"),
        (stat.S_ISSOCK, "is a socket, not a file"),
    )
    return next((text for test, text in kinds if test(mode)), "is not a regular file")


def check_input_file(path: PathLike, label: str, fix: str = "", folder_ok: bool = False) -> Path:
    """``Path(path)`` when it is a regular file (or a folder, with ``folder_ok``); else ValueError
    "``label`` ``path`` <what it is>; ``fix``" (:func:`input_problem`), before anything reads it."""
    problem = input_problem(path, folder_ok)
    if problem is not None:
        raise ValueError(f"{label} {path} {problem}" + (f"; {fix}" if fix else ""))
    return Path(path)


MAX_JSON_BYTES = 64 * 2**20  # a transforms.json of 10,000 frames is about 5 MB


def read_json(path: PathLike, label: str, fix: str, max_bytes: int = MAX_JSON_BYTES) -> Any:
    """The JSON value of the input file ``path``, or ValueError "``label`` ``path`` <the problem>; ``fix``".

    The one reader of the JSON files users hand in: the file must be a regular file (:func:`input_problem`) of at
    most ``max_bytes``, UTF-8 text and JSON, nested less deeply than Python's recursion limit (a file of
    ``[[[[...`` 100,000 deep) and without integers of more than 4,300 digits. Exit code 2 of `fluidgs`.

    Example:
        >>> read_json("scene.json", "scene file", "see the format in README.md")  # doctest: +SKIP
    """
    p = Path(path)
    problem = input_problem(p)
    if problem is None:
        size = p.stat().st_size
        if size == 0:
            problem = "is empty (0 bytes), not JSON"
        elif size > max_bytes:
            problem = f"is {size / 2**20:.0f} MiB, more than the {max_bytes / 2**20:.0f} MiB such a JSON file may be"
    if problem is None:
        try:
            return json.loads(p.read_bytes().decode("utf-8"))
        except UnicodeDecodeError as exc:
            problem = f"is not UTF-8 text (byte {exc.start}), so not JSON"
        except json.JSONDecodeError as exc:
            problem = f"is not valid JSON ({exc})"
        except RecursionError:
            problem = "nests its JSON too deeply (thousands of levels)"
        except ValueError:  # Python refuses to convert an integer of more than 4,300 digits
            problem = "holds an integer of more than 4,300 digits"
        except OSError as exc:
            problem = f"cannot be read ({exc.strerror or exc})"
    raise ValueError(f"{label} {p} {problem}; {fix}")


# ---- outputs must not be inputs -------------------------------------------------------------------------
def same_file(a: PathLike, b: PathLike) -> bool:
    """Whether two paths name the same file: the same inode on the same device (symbolic and hard links,
    ``..`` and relative spellings included), or, for a path that does not exist yet, the same real path."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.realpath(a) == os.path.realpath(b)


def _inside(path: PathLike, folder: PathLike) -> bool:
    real, top = os.path.realpath(path), os.path.realpath(folder)
    return real == top or real.startswith(top.rstrip(os.sep) + os.sep)


Labelled = Mapping[str, PathLike | None] | Iterable[tuple[str, PathLike | None]]


def _pairs(paths: Labelled | None) -> list[tuple[str, Path]]:
    items = (paths or {}).items() if isinstance(paths, Mapping) or paths is None else paths
    return [(k, Path(v)) for k, v in items if v is not None]


def check_distinct_outputs(outputs: Labelled) -> None:
    """Refuse, before any work, two outputs that are one file (the same path, a symbolic or a hard link): the one
    written last would replace the other without a word (``-o r.h5 --export-solid r.h5``).

    Raises:
        ValueError: naming both options and paths, and the fix.
    """
    for (first_label, first), (label, out) in itertools.combinations(_pairs(outputs), 2):
        if same_file(out, first):
            raise ValueError(
                f"{label} {out} is the same file as {first_label} {first}: one output would overwrite the "
                f"other; choose a different path for {label}"
            )


def check_not_input(outputs: Labelled, inputs: Labelled, replaced: Labelled | None = None) -> None:
    """Refuse, before any work, an output that would overwrite an input or another output
    (:func:`check_distinct_outputs`).

    Each argument is a mapping label -> path or (label, path) pairs (several paths may share a label); None
    paths are skipped.

    Args:
        outputs: label (the option, e.g. "--ply") -> a path the command writes.
        inputs: label (e.g. "GAUSSIANS") -> a file the command reads.
        replaced: label -> an output folder the command replaces or empties as a whole (``--overwrite``): no
            input may lie inside it.
    Raises:
        ValueError: naming both paths and the fix (an output resolves to an input or to another output: same
            real path, a symbolic link or a hard link to it).
    """
    check_distinct_outputs(outputs)
    ins = _pairs(inputs)
    for olabel, out in _pairs(outputs):
        for ilabel, inp in ins:
            if same_file(out, inp):
                how = (
                    " (a hard link to the same file)"
                    if os.path.realpath(out) != os.path.realpath(inp)
                    else " (through a symbolic link)"
                    if os.path.abspath(out) != os.path.abspath(inp)
                    else ""
                )
                raise ValueError(
                    f"{olabel} {out} is the input {ilabel} {inp}{how}: writing it would destroy the "
                    f"input; choose another output path for {olabel}"
                )
    for olabel, folder in _pairs(replaced):
        for ilabel, inp in ins:
            if _inside(inp, folder):
                raise ValueError(
                    f"{olabel} {folder} would be replaced, but the input {ilabel} {inp} lies inside "
                    f"it; choose another output folder for {olabel} or move the input out"
                )
