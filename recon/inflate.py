"""Bounded decompression for the Gaussian-file readers: a small crafted file never allocates gigabytes.

Every reader of a compressed format (.npz members, gzip and zstd .spz, the WebP images of SOG, zip bundles)
follows two rules:

1. **Check the declared sizes first.** The bytes a header declares (counts x record size) are compared with the
   memory budget (:func:`memory_budget_bytes`) before anything is inflated or allocated
   (:func:`check_budget`); a header that claims more is refused with a message naming the file.
2. **Inflate in bounded chunks.** Decompressors are asked for at most the declared size plus one byte
   (:func:`inflate_zstd`, :func:`read_zip_member`; the gzip .spz reader bounds its own stream), so a stream
   that expands beyond what its header declared is caught without ever holding the excess.

No paper equation: this is input hygiene.
"""

from __future__ import annotations

import io
import os
import zipfile
import zlib

from fluidsim.host import available_memory_bytes

BUDGET_ENV = "FLUIDGS_MAX_DECODE_GB"
BUDGET_FRACTION = 0.5  # of the memory available now: the decoded arrays are converted once more afterwards
BUDGET_CEILING_GB = 16.0  # without FLUIDGS_MAX_DECODE_GB, never more than this (about 60M Gaussians of SH degree 3)
CHUNK_BYTES = 1 << 24


def memory_budget_bytes() -> int:
    """The most bytes one Gaussian file may decode to: ``FLUIDGS_MAX_DECODE_GB`` GiB when set, else half of the
    memory available now and at most ``BUDGET_CEILING_GB`` GiB (a fixed ceiling, so a machine with much free memory
    does not let a small hostile file take it)."""
    text = os.environ.get(BUDGET_ENV)
    if text:
        try:
            return int(float(text) * 2**30)
        except ValueError:
            raise ValueError(f"{BUDGET_ENV}={text!r} is not a number of GiB") from None
    return int(min(available_memory_bytes() * BUDGET_FRACTION, BUDGET_CEILING_GB * 2**30))


def check_budget(source: str, what: str, declared: int) -> None:
    """Raise ``ValueError`` naming ``source`` when ``declared`` bytes (``what``) exceed the memory budget."""
    budget = memory_budget_bytes()
    if declared > budget:
        raise ValueError(
            f"{source}: {what} would decode to {declared / 2**30:.2f} GiB, more than the memory budget "
            f"of {budget / 2**30:.2f} GiB (half the memory available now, at most {BUDGET_CEILING_GB:g} GiB; "
            f"{BUDGET_ENV} sets it): a "
            f"corrupt or hostile file, or a capture too large for this machine"
        )


def inflate_zstd(frame: bytes, size: int, source: str, what: str) -> bytes:
    """Exactly ``size`` bytes from one zstd frame, read through a stream reader in bounded chunks (never more
    than ``size + 1`` bytes, whatever the frame claims)."""
    try:  # a dependency of the project (setup.cfg), imported here so that the other formats never need it
        import zstandard  # noqa: PLC0415 - only zstd-compressed files need it
    except ImportError:
        raise ValueError(
            f"{source}: the file is zstd-compressed and the 'zstandard' package is missing; install "
            f"the project again (pip install -e .) or run 'pip install zstandard'"
        ) from None
    parts, got = [], 0
    try:
        with zstandard.ZstdDecompressor().stream_reader(io.BytesIO(frame)) as reader:
            while got <= size:
                part = reader.read(min(CHUNK_BYTES, size + 1 - got))
                if not part:
                    break
                parts.append(part)
                got += len(part)
    except zstandard.ZstdError as exc:
        raise ValueError(f"{source}: corrupt zstd stream for {what} ({exc}); re-download the file") from None
    if got != size:
        raise ValueError(
            f"{source}: corrupt {what}: the zstd stream decompresses to "
            f"{'more than' if got > size else 'only'} {got} bytes, expected {size}"
        )
    return b"".join(parts)


def read_zip_member(archive: zipfile.ZipFile, info: zipfile.ZipInfo, source: str, limit: int) -> bytes:
    """The bytes of one zip member, read in bounded chunks; refused when its directory entry or its content
    exceeds ``limit`` bytes (checked against :func:`memory_budget_bytes` too)."""
    if info.file_size > limit:
        raise ValueError(
            f"{source}: member {info.filename!r} declares {info.file_size} bytes, more than the "
            f"{limit} bytes it may hold (corrupt or hostile archive)"
        )
    check_budget(source, f"member {info.filename!r}", info.file_size)
    parts, got = [], 0
    try:
        with archive.open(info) as fp:
            while got <= info.file_size:
                part = fp.read(min(CHUNK_BYTES, info.file_size + 1 - got))
                if not part:
                    break
                parts.append(part)
                got += len(part)
    except (zipfile.BadZipFile, OSError, EOFError, zlib.error, NotImplementedError) as exc:
        raise ValueError(
            f"{source}: member {info.filename!r} cannot be read ({exc}); re-download or re-export the file"
        ) from None
    if got != info.file_size:
        raise ValueError(
            f"{source}: member {info.filename!r} holds {got} bytes, its directory says "
            f"{info.file_size} (corrupt archive)"
        )
    return b"".join(parts)


H5_MAX_RATIO = 1100  # deflate cannot expand data more than ~1032:1: a larger claim is unwritten chunks or a bomb
H5_SLACK_BYTES = 1 << 20  # a dataset smaller than this is never refused (fill values of small arrays are fine)


def check_hdf5_sizes(file, source: str, skip: tuple[str, ...] = ()) -> None:
    """Refuse an open ``h5py.File`` whose datasets declare more than they can hold, before any is read.

    Every dataset's declared size (shape x item size) must be at most :data:`H5_MAX_RATIO` times the bytes it stores
    plus :data:`H5_SLACK_BYTES` (a dataset declared with unwritten chunks stores nothing, and would be read as
    gigabytes of fill values), and at most the memory budget (:func:`check_budget`). Only metadata is read.

    Groups named in ``skip`` (e.g. ``"trajectory"``, wherever it lies) are left out: their datasets are not read.

    Raises:
        ValueError: naming ``source``, the dataset, its shape and the bytes it stores.
    """
    import h5py  # noqa: PLC0415 - only the HDF5 readers need it

    def visit(name: str, obj) -> None:
        if not isinstance(obj, h5py.Dataset) or set(name.split("/")[:-1]) & set(skip):
            return
        declared = int(obj.size or 0) * int(obj.dtype.itemsize)
        stored = int(obj.id.get_storage_size())
        if declared > stored * H5_MAX_RATIO + H5_SLACK_BYTES:
            raise ValueError(
                f"{source}: /{name} declares {obj.shape} {obj.dtype} ({declared} bytes) but stores only {stored} "
                f"bytes (unwritten chunks or a corrupt file); write the file again with fluidgs"
            )
        check_budget(source, f"/{name} {obj.shape}", declared)

    file.visititems(visit)
