"""Atomic writes: the only code of the project that renames a finished output into place.

Every writer writes a temporary file of one short pattern in the output's folder (:func:`temp_path`,
``.fgs-<8 hex>.tmp<suffix>``), then renames it onto the output with ``os.replace`` (atomic within one folder):
a reader sees the old file or the new one, never half of one, and a failed write leaves no temporary file. The
pattern is short whatever the output's name, so an output name the file system accepts always has a temporary
name it accepts too (:func:`fluidsim.files.check_writable` tries exactly it before any work).

An ``OSError`` while writing becomes an :class:`OutputError` that names the output and keeps the errno (exit code 4
of `fluidgs`, docs/exit-codes.md).

- :func:`atomic_output`: a context manager yielding the temporary path, for writers that want a file name
  (h5py, open3d, FFmpeg, ``torch.save``).
- :class:`PendingFile`: the same for a file that stays open across calls (the frames of ``fluidgs sim``).
- :func:`write_bytes_atomic`, :func:`write_text_atomic`, :func:`write_json_atomic`: whole files at once.
- :func:`atomic_folder`: a folder written under a temporary name, then swapped in (a rendered dataset).
"""

from __future__ import annotations

import json
import math
import numbers
import os
import re
import shutil
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

PathLike = str | os.PathLike
TEMP_PREFIX = ".fgs-"
TEMP_NAME = re.compile(r"^\.fgs-[0-9a-f]{8}\.tmp")  # what temp_path makes (a suffix may follow)

# Temporary files and folders of this process that are not yet renamed into place or removed, and the output folders
# it created: what a signal handler removes before the process exits (remove_unfinished), so that neither a
# `.fgs-*.tmp` nor an empty folder outlives an interrupted or refused run.
_LIVE: set[Path] = set()
_CREATED: list[Path] = []
# The outputs this process has renamed into place, in order: when a later output fails, the message says which
# ones are complete (:func:`written_outputs`).
_WRITTEN: list[Path] = []
# h5py and other C libraries report the errno inside their text ("... errno = 28, error message = 'No space ...'")
_ERRNO_IN_TEXT = re.compile(r"errno\s*=\s*(\d+)")


class OutputError(OSError):
    """An output cannot be written: a full disk, a read-only or unwritable folder, a name too long, a parent
    that is a file, a folder where a file is wanted. The message names the path and the fix (`fluidgs`: exit 4);
    ``errno`` is that of the ``OSError`` it replaces, when there was one."""


def temp_path(path: PathLike, suffix: str = "") -> Path:
    """A fresh temporary name next to ``path``: ``.fgs-<8 hex>.tmp<suffix>`` in the same folder.

    ``suffix`` keeps an extension that a library needs to pick its format (".png" for OpenCV, ".mp4" for FFmpeg,
    ".obj" for open3d).
    """
    p = Path(path)
    return p.parent / f"{TEMP_PREFIX}{uuid.uuid4().hex[:8]}.tmp{suffix}"


@contextmanager
def output_errors(path: PathLike) -> Iterator[None]:
    """Turn an ``OSError`` raised while writing ``path`` into an :class:`OutputError` naming the path (errno kept)."""
    try:
        yield
    except OutputError:
        raise
    except OSError as exc:
        code = exc.errno
        if code is None:
            found = _ERRNO_IN_TEXT.search(str(exc))
            code = int(found.group(1)) if found else None
        reason = f"{os.strerror(code)} (errno {code})" if code else str(exc)
        err = OutputError(f"cannot write {path}: {reason}; free disk space or choose a writable output path")
        err.errno = code
        raise err from exc


def note_written(path: PathLike) -> None:
    """Note ``path`` as an output this process has completed (renamed into place)."""
    _WRITTEN.append(Path(path))


def written_outputs() -> list[Path]:
    """The outputs this process has completed so far, in order (each complete: they were renamed into place)."""
    return list(_WRITTEN)


class PendingFile:
    """An output written under a :func:`temp_path` name that becomes ``path`` on :meth:`commit`.

    For a file that stays open across calls; :func:`atomic_output` is the one-block form.

    Example:
        >>> pending = PendingFile("out.h5")          # doctest: +SKIP
        >>> f = h5py.File(pending.tmp, "w")          # doctest: +SKIP
        >>> ...; f.close(); pending.commit()         # doctest: +SKIP
    """

    def __init__(self, path: PathLike, suffix: str = ""):
        self.path = Path(path)
        self.tmp = temp_path(self.path, suffix)
        _LIVE.add(self.tmp.absolute())

    def commit(self) -> Path:
        """Rename the finished temporary file onto ``path`` (an ``OSError`` becomes an :class:`OutputError`)."""
        with output_errors(self.path):
            os.replace(self.tmp, self.path)
        _LIVE.discard(self.tmp.absolute())
        note_written(self.path)
        return self.path

    def discard(self) -> None:
        """Remove the temporary file, if any."""
        self.tmp.unlink(missing_ok=True)
        _LIVE.discard(self.tmp.absolute())


@contextmanager
def atomic_output(path: PathLike, suffix: str = "") -> Iterator[Path]:
    """Write ``path`` atomically: yields a :func:`temp_path` in the same folder, renamed onto ``path`` when the
    block ends normally and removed when it raises; an ``OSError`` becomes an :class:`OutputError`.

    Example:
        >>> with atomic_output("out.json") as tmp:          # doctest: +SKIP
        ...     tmp.write_text("{}")
    """
    pending = PendingFile(path, suffix)
    try:
        with output_errors(path):
            yield pending.tmp
        pending.commit()
    finally:
        pending.discard()


def write_bytes_atomic(path: PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; returns ``Path(path)``."""
    with atomic_output(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def write_text_atomic(path: PathLike, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; returns ``Path(path)``."""
    return write_bytes_atomic(path, text.encode("utf-8"))


def json_safe(value: Any) -> Any:
    """``value`` as strict JSON data: non-finite floats become None, tuples lists, numpy scalars Python numbers
    (numpy registers its scalar types with :mod:`numbers`) and paths strings."""
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, bool):
        return value
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real):
        return float(value) if math.isfinite(float(value)) else None
    if isinstance(value, Path):
        return str(value)
    return value


def write_json_atomic(path: PathLike, data: Any) -> Path:
    """Indented strict JSON (:func:`json_safe`: NaN and infinities become null), atomically; returns the path."""
    return write_text_atomic(path, json.dumps(json_safe(data), indent=2) + "\n")


@contextmanager
def atomic_folder(path: PathLike) -> Iterator[Path]:
    """Write the folder ``path`` atomically: yields an empty :func:`temp_path` folder next to it, which replaces
    ``path`` (an existing folder is moved aside, then deleted) when the block ends normally and is deleted when
    it raises. The caller checks beforehand that an existing ``path`` may be replaced.
    """
    path = Path(path).absolute()
    tmp = temp_path(path)
    _LIVE.add(tmp)
    with output_errors(path):
        tmp.mkdir()
    try:
        with output_errors(path):
            yield tmp
            if path.exists():
                old = temp_path(path, ".old")
                os.replace(path, old)
                _LIVE.add(old)
                os.replace(tmp, path)
                if old.is_symlink():  # a link to a folder is replaced as a file is; rmtree refuses links
                    old.unlink()
                else:
                    shutil.rmtree(old, ignore_errors=True)
                _LIVE.discard(old)
            else:
                os.replace(tmp, path)
            note_written(path)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        _LIVE.discard(tmp)


@contextmanager
def atomic_files(folder: PathLike) -> Iterator[Path]:
    """Write a set of files into the folder ``folder`` all or none, keeping what else it holds: yields an empty
    :func:`temp_path` folder inside it; when the block ends normally, each file written there is renamed into
    ``folder`` (replacing a file of the same name), and the temporary folder is deleted either way. A block stopped
    midway (a signal, an error) leaves ``folder`` as it was, never half of an earlier set and half of a new one.
    """
    folder = Path(folder).absolute()
    tmp = temp_path(folder / "files")
    _LIVE.add(tmp)
    with output_errors(folder):
        tmp.mkdir()
    try:
        with output_errors(folder):
            yield tmp
            for p in sorted(tmp.iterdir()):
                os.replace(p, folder / p.name)
                note_written(folder / p.name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        _LIVE.discard(tmp)


def track_temp(path: PathLike) -> Path:
    """Note ``path`` as a temporary file or folder of this process (:func:`remove_unfinished` removes it)."""
    p = Path(path).absolute()
    _LIVE.add(p)
    return p


def untrack_temp(path: PathLike) -> None:
    """Forget ``path`` (renamed into place or removed)."""
    _LIVE.discard(Path(path).absolute())


def note_created_folder(path: PathLike) -> None:
    """Note an output folder this process created (:func:`remove_unfinished` removes it when it stayed empty)."""
    _CREATED.append(Path(path).absolute())


def remove_unfinished(created_folders: bool = True) -> list[Path]:
    """Remove this process's temporary files and folders that were never renamed into place and, with
    ``created_folders``, the output folders it created that are still empty (deepest first); returns what was
    removed. The list of created folders starts again empty either way. Called when a command ends (with
    ``created_folders`` when it failed or was stopped), so that it leaves nothing behind."""
    removed = []
    for p in sorted(_LIVE, key=lambda q: len(q.parts), reverse=True):
        try:
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p)
            else:
                p.unlink()
            removed.append(p)
        except FileNotFoundError:
            pass
        except OSError:
            continue
        _LIVE.discard(p)
    if created_folders:
        for folder in sorted(set(_CREATED), key=lambda q: len(q.parts), reverse=True):
            try:
                folder.rmdir()  # only an empty folder goes
                removed.append(folder)
            except OSError:
                pass
    _CREATED.clear()
    return removed


def remove_stale_temps(folder: PathLike) -> list[Path]:
    """Remove the ``.fgs-*.tmp`` files and folders (:func:`temp_path`'s pattern) that another process left in
    ``folder`` (not below it) when it was killed at once (SIGKILL, a power cut). Only for a folder that one run owns
    (an active run's folder): in a shared folder such a name may be another live process's file. Returns them."""
    removed = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for entry in entries:
        p = Path(entry.path).absolute()
        if not TEMP_NAME.match(entry.name) or p in _LIVE:
            continue
        try:
            if entry.is_dir(follow_symlinks=False):
                shutil.rmtree(p)
            else:
                p.unlink()
            removed.append(p)
        except OSError:
            pass
    return removed
