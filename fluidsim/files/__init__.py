"""fluidsim.files: how every output of FluidGaussian is written atomically, and checked before any work.

Standard library only, in the lowest layer: ``fluidsim/__init__`` loads nothing eagerly, so importing this
subpackage starts neither Taichi nor torch (the fixed design allows no further top-level package).

Every layer writes its files through these functions: ``fluidsim`` (the HDF5 of ``fluidgs sim``), ``recon``
(.ply/.npz Gaussians, meshes, rendered datasets), ``viz`` (PNG, MP4), ``nbv`` (through :mod:`nbv.io`, which adds
the HDF5, PNG and callable writers) and ``apps``. It imports neither Taichi nor torch, so each layer can use it
without breaking the layering (``fluidsim`` never imports torch, ``recon`` never Taichi, ``viz`` neither), and
it is the only code that renames a file into place (a test greps the sources for ``os.replace`` and renames).

=============================  ===============================================================================
name                           what
=============================  ===============================================================================
:func:`atomic_output`          ``with atomic_output(path) as tmp:`` write ``tmp``; renamed onto ``path`` at the end
:class:`PendingFile`           the same for a file kept open across calls (``commit()`` / ``discard()``)
:func:`write_bytes_atomic`     bytes, text and strict JSON (:func:`json_safe`) in one call
:func:`atomic_folder`          a whole folder under a temporary name, swapped in at the end
:func:`atomic_files`           a set of files into a folder, moved in together at the end (PNG frames)
:func:`check_writable`         before any work: folders, name lengths, the temporary name tried in the folder
:func:`check_not_input`        before any work: no output is an input or another output (links included)
:func:`check_input_file`       before reading: an input is a regular file (a FIFO, /dev/zero, a link loop named)
:func:`read_json`              a user's JSON file (cameras, scene, config), each way it can be bad in one message
:class:`OutputError`           an output cannot be written (exit code 4 of `fluidgs`)
:func:`remove_unfinished`      at a signal or an error: this process's temporary files and empty new folders go
:func:`remove_stale_temps`     a run folder's ``.fgs-*.tmp`` left by a process killed at once (SIGKILL)
:func:`written_outputs`        the outputs completed so far (a later failure names those that survived)
=============================  ===============================================================================

Temporary files are named ``.fgs-<8 hex>.tmp<suffix>`` in the output's folder (:func:`temp_path`).
"""

from .atomic import (
    TEMP_NAME,
    TEMP_PREFIX,
    OutputError,
    PendingFile,
    atomic_files,
    atomic_folder,
    atomic_output,
    json_safe,
    note_created_folder,
    output_errors,
    remove_stale_temps,
    remove_unfinished,
    temp_path,
    track_temp,
    untrack_temp,
    write_bytes_atomic,
    write_json_atomic,
    write_text_atomic,
    written_outputs,
)
from .checks import (
    check_distinct_outputs,
    check_input_file,
    check_not_input,
    check_writable,
    input_problem,
    read_json,
    same_file,
)

__all__ = [
    "TEMP_NAME",
    "TEMP_PREFIX",
    "OutputError",
    "PendingFile",
    "atomic_files",
    "atomic_folder",
    "atomic_output",
    "check_distinct_outputs",
    "check_input_file",
    "check_not_input",
    "check_writable",
    "input_problem",
    "json_safe",
    "note_created_folder",
    "output_errors",
    "read_json",
    "remove_stale_temps",
    "remove_unfinished",
    "same_file",
    "temp_path",
    "track_temp",
    "untrack_temp",
    "write_bytes_atomic",
    "write_json_atomic",
    "write_text_atomic",
    "written_outputs",
]
