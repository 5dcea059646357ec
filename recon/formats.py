"""One loader for the Gaussian-splat file formats people share, recognised by content.

- ``ply``: the standard 3DGS .ply (:mod:`recon.ply`): a ``ply`` first line and no ``chunk`` element;
- ``compressed_ply``: the SuperSplat / PlayCanvas compressed .ply (:mod:`recon.compressed_ply`): a ``ply`` first
  line, a ``chunk`` element and ``packed_*`` vertex properties;
- ``spz``: Niantic .spz, versions 2-4 (:mod:`recon.spz`): the gzip magic ``1f 8b`` or ``NGSP``;
- ``splat``: antimatter15 .splat (:mod:`recon.dotsplat`): no header, so the ``.splat`` suffix (its reader checks
  that the size is a whole number of 32-byte records);
- ``npz``: the arrays of a GaussianSet or a gsplat checkpoint (:mod:`recon.ply`): the zip magic ``PK``.

The content decides, not the suffix (a compressed .ply is a .ply too); the suffix only names the format of a file
whose content is recognised as none of them, for a sharper message. Every reader returns the 3DGS .ply frame
(an .spz, stored right-up-back, is turned to it) and compares the sizes a header declares with the file size
before allocating anything. Writing stays the standard .ply or .npz (:func:`recon.ply.save_gaussians`).

Example:
    >>> g, fmt = load_gaussians_with_format("biker.spz")  # doctest: +SKIP
    >>> fmt, g.num  # doctest: +SKIP
    ('spz', 152746)
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

from . import compressed_ply, dotsplat, ply, spz
from .gaussians import GaussianSet

log = logging.getLogger(__name__)

FORMATS: dict[str, str] = {
    "ply": "standard 3DGS .ply",
    "compressed_ply": "SuperSplat/PlayCanvas compressed .ply",
    "spz": "Niantic .spz (versions 2, 3, 4)",
    "splat": "antimatter15 .splat",
    "npz": ".npz (GaussianSet arrays or a gsplat checkpoint)",
}
SUPPORTED = "supported formats: " + "; ".join(FORMATS.values())
READERS: dict[str, Callable[[Path], GaussianSet]] = {
    "ply": ply.load_standard_ply,
    "compressed_ply": compressed_ply.load_compressed_ply,
    "spz": spz.load_spz,
    "splat": dotsplat.load_splat,
    "npz": ply.load_npz,
}
SUFFIXES = (".ply", ".spz", ".splat", ".npz")
ZIP_MAGICS = (b"PK\x03\x04", b"PK\x05\x06")


def detect_format(path: str | Path) -> str:
    """The format name of a Gaussian file (a key of :data:`FORMATS`), from its content.

    Args:
        path: the file.
    Returns:
        "ply", "compressed_ply", "spz", "splat" or "npz".
    Raises:
        FileNotFoundError: nothing exists at ``path``.
        ValueError: ``path`` is a folder, an empty file, a malformed PLY header, or a format none of the readers
            knows (the message lists the supported formats).
    """
    path = Path(path)
    if path.is_dir():
        raise ValueError(_folder_message(path))
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such Gaussian file")
    with open(path, "rb") as fh:
        head = fh.read(8)
        if head[:3] == b"ply" and head[3:4] in (b"\n", b"\r"):
            fh.seek(0)
            layout = ply.parse_ply_header(fh, str(path))
            return "compressed_ply" if compressed_ply.is_compressed_layout(layout) else "ply"
    if head[:4] in ZIP_MAGICS:
        return "npz"
    if head[:2] == spz.GZIP_MAGIC or head[:4] == spz.NGSP_MAGIC:
        return "spz"
    suffix = path.suffix.lower()
    if suffix == ".splat":
        return "splat"  # no magic: load_splat checks the size
    if not head:
        raise ValueError(f"{path}: the file is empty; {SUPPORTED}")
    expected = {".ply": "not a PLY file (the first line is not 'ply')",
                ".npz": "not a readable .npz archive (no zip signature)",
                ".spz": "not an .spz file (neither gzip-wrapped nor starting with 'NGSP')"}
    what = expected.get(suffix, f"unrecognised Gaussian file format (suffix {path.suffix!r})")
    size = path.stat().st_size
    hint = (f" (its {size} bytes are a whole number of 32-byte records: if it is an antimatter15 .splat, which has "
            f"no header, rename it to {path.stem}.splat)" if size % dotsplat.RECORD_BYTES == 0 else "")
    raise ValueError(f"{path}: {what}; it starts with {head!r}{hint}; {SUPPORTED}")


def load_gaussians_with_format(path: str | Path) -> tuple[GaussianSet, str]:
    """Read a Gaussian file of any supported format; also return the format name (for ``fluidgs inspect``).

    Returns:
        (a float32 :class:`GaussianSet` on the CPU in the 3DGS .ply frame, the :func:`detect_format` name).
    Raises:
        FileNotFoundError: nothing exists at ``path``.
        ValueError: a folder, an unsupported format, or any problem with the content; the message names the file.
    """
    fmt = detect_format(path)
    gaussians = READERS[fmt](Path(path))
    log.debug("%s: %d Gaussians read as %s", path, gaussians.num, FORMATS[fmt])
    return gaussians, fmt


def load_gaussians(path: str | Path) -> GaussianSet:
    """Read a Gaussian file of any supported format (see :func:`load_gaussians_with_format`)."""
    return load_gaussians_with_format(path)[0]


def _folder_message(path: Path) -> str:
    candidates = sorted(p.name for p in path.iterdir() if p.is_file() and p.suffix.lower() in SUFFIXES)[:5]
    hint = (f"it holds {', '.join(candidates)}" if candidates
            else "a 3DGS output folder keeps it in point_cloud/iteration_*/point_cloud.ply")
    return f"{path}: is a folder, not a Gaussian file; pass the file itself ({hint}); {SUPPORTED}"
