"""Reading Gaussian sets from a plain ``.npz`` (written by :func:`recon.formats.ply.save_gaussians`).

The ``.npz`` layout holds the five tensors of a GaussianSet under their field names, as float32 arrays::

    means [N, 3]   quats [N, 4] (w, x, y, z)   log_scales [N, 3]   opacity_logits [N]   sh [N, K, 3]

and, on reading only, the naming of gsplat's trainer checkpoints is accepted too: ``means``, ``quats``,
``scales`` (log), ``opacities`` (logits), ``sh0`` [N, 1, 3] and ``shN`` [N, K-1, 3].

Every problem raises ``ValueError`` whose message starts with the file name. Each ``.npy`` shape is compared with
its member's size before anything is allocated, and the archive is read member by member without ever unpickling.

Example:
    >>> load_npz("gaussians.npz").sh.shape  # doctest: +SKIP
    torch.Size([10, 16, 3])
"""

from __future__ import annotations

import zipfile
import zlib
from pathlib import Path

import numpy as np

from ..gaussians import GaussianSet
from ..inflate import CHUNK_BYTES, check_budget
from .arrays import gaussians_from_arrays

NPZ_KEYS = ("means", "quats", "log_scales", "opacity_logits", "sh")
GSPLAT_KEYS = ("means", "quats", "scales", "opacities", "sh0", "shN")


def load_npz(path: str | Path) -> GaussianSet:
    """Read Gaussians from an ``.npz`` (layout in the module docstring), never unpickling anything.

    Every member's ``.npy`` header is read first: object arrays are refused, and each declared array size is
    compared with the member's size before any array is allocated.

    Raises:
        ValueError: not a zip archive, a member that is not a plain numeric ``.npy`` array, truncated members,
            missing keys, wrong shapes, or values that fail :meth:`GaussianSet.check`.
    """
    source = str(path)
    arrays = _read_npz_arrays(Path(path), source)
    if all(k in arrays for k in NPZ_KEYS):
        tensors = {k: arrays[k] for k in NPZ_KEYS}
    else:  # _read_npz_arrays returns one of the two key sets, or refuses the file
        sh0, shn = arrays["sh0"], arrays["shN"]
        if sh0.ndim != 3 or shn.ndim != 3:
            raise ValueError(
                f"{source}: sh0 and shN must be [N, 1, 3] and [N, K-1, 3], got {sh0.shape} and {shn.shape}"
            )
        tensors = {
            "means": arrays["means"],
            "quats": arrays["quats"],
            "log_scales": arrays["scales"],
            "opacity_logits": arrays["opacities"],
            "sh": np.concatenate([sh0, shn], 1),
        }
    for key, value in tensors.items():
        if not np.issubdtype(value.dtype, np.number) or np.issubdtype(value.dtype, np.complexfloating):
            raise ValueError(f"{source}: array {key!r} has non-numeric dtype {value.dtype}")
    return gaussians_from_arrays(source, *(tensors[k] for k in NPZ_KEYS))


NPZ_MAX_DEFLATE_RATIO = 1100  # deflate cannot expand data more than ~1032:1; a larger claim is a corrupt directory


def _read_npz_arrays(path: Path, source: str) -> dict[str, np.ndarray]:
    """The Gaussian arrays of an .npz (the ``NPZ_KEYS`` or the ``GSPLAT_KEYS`` members, nothing else), checking the
    member names before any member is inflated and each .npy header against the member size before reading."""
    fix = "save it again with save_gaussians (or numpy.savez)"
    try:
        archive = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError, EOFError) as exc:
        raise ValueError(f"{source}: not a readable .npz archive ({exc}); {fix}") from None
    arrays = {}
    with archive:
        infos = archive.infolist()
        if sum(i.compress_size for i in infos) > path.stat().st_size:
            raise ValueError(
                f"{source}: not a readable .npz archive (its directory lists more data than the file "
                f"holds: truncated or corrupt); {fix}"
            )
        for info in infos:  # the directory alone: nothing is inflated before the keys are known
            if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
                raise ValueError(
                    f"{source}: not a readable .npz archive (member {info.filename!r} uses zip "
                    f"compression method {info.compress_type}; numpy writes only stored or deflated "
                    f"members); {fix}"
                )
            if not info.filename.endswith(".npy"):
                raise ValueError(
                    f"{source}: not a readable .npz archive (member {info.filename!r} is not a .npy array); {fix}"
                )
            if info.file_size > max(info.compress_size, 1) * NPZ_MAX_DEFLATE_RATIO:
                raise ValueError(
                    f"{source}: not a readable .npz archive (member {info.filename!r} claims "
                    f"{info.file_size} bytes from {info.compress_size}: corrupt); {fix}"
                )
        members = {i.filename[:-4]: i for i in infos if i.filename.endswith(".npy")}
        keys = next((keys for keys in (NPZ_KEYS, GSPLAT_KEYS) if all(k in members for k in keys)), None)
        if keys is None:  # decided from the names alone: nothing has been inflated yet
            missing = [k for k in NPZ_KEYS if k not in members]
            raise ValueError(
                f"{source}: the .npz lacks the Gaussian arrays {missing} (it has {sorted(members)[:12]}); "
                f"save it with save_gaussians or use the keys {list(NPZ_KEYS)}"
            )
        infos = [members[k] for k in keys]
        check_budget(source, f"the {len(infos)} arrays of the .npz", sum(i.file_size for i in infos))
        for info in infos:
            arrays[info.filename[:-4]] = _read_npy_member(archive, info, source, fix)
    return arrays


def _read_npy_member(archive: zipfile.ZipFile, info: zipfile.ZipInfo, source: str, fix: str) -> np.ndarray:
    name = info.filename[:-4]
    try:
        with archive.open(info) as fp:
            version = np.lib.format.read_magic(fp)
            if version == (1, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_1_0(fp)
            elif version == (2, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_2_0(fp)
            else:
                raise ValueError(f".npy format version {version} is not supported")
            if dtype.hasobject:
                raise ValueError("it holds Python objects, which are never loaded from a Gaussian file")
            declared = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
            available = info.file_size - fp.tell()
            if declared > available:
                raise ValueError(
                    f"the header declares {shape} {dtype} ({declared} bytes) but only {available} "
                    f"bytes follow: truncated or corrupt"
                )
            data, got = bytearray(declared), 0  # one buffer, filled in bounded chunks: peak = the array itself
            view = memoryview(data)
            while got < declared:  # a member never yields more than its header declared
                n = fp.readinto(view[got : got + min(CHUNK_BYTES, declared - got)])
                if not n:
                    break
                got += n
            view.release()
    except (zipfile.BadZipFile, OSError, EOFError, ValueError, zlib.error) as exc:
        raise ValueError(f"{source}: not a readable .npz archive (array {name!r}: {exc}); {fix}") from None
    if got != declared:
        raise ValueError(f"{source}: not a readable .npz archive (array {name!r} is truncated); {fix}")
    return np.frombuffer(data, dtype=dtype).reshape(shape, order="F" if fortran else "C")
