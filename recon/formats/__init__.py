"""One loader for the Gaussian-splat file formats people share, recognised by content; one module per format.

- ``ply``: the standard 3DGS .ply (:mod:`.ply`): a ``ply`` first line and no ``chunk`` element;
- ``compressed_ply``: the SuperSplat / PlayCanvas compressed .ply (:mod:`.compressed_ply`): a ``ply`` first
  line, a ``chunk`` element and ``packed_*`` vertex properties;
- ``spz``: Niantic .spz, versions 2-4 (:mod:`.spz`): the gzip magic ``1f 8b`` or ``NGSP``;
- ``splat``: antimatter15 .splat (:mod:`.dotsplat`): no header, so the ``.splat`` suffix (its reader checks
  that the size is a whole number of 32-byte records);
- ``npz``: the arrays of a GaussianSet or a gsplat checkpoint's arrays (:mod:`.npz`): the zip magic ``PK``;
- ``sog``: PlayCanvas SOG versions 1-2 (:mod:`.sog`): a zip holding ``meta.json`` (a ``.sog`` bundle), a
  ``meta.json`` file or a folder holding one;
- ``ksplat``: mkkellogg GaussianSplats3D .ksplat, compression modes 0-2 (:mod:`.ksplat`): no magic, so the
  ``.ksplat`` suffix and a header of version 0.x;
- ``checkpoint``: a gsplat ``ckpt_*.pt`` or nerfstudio splatfacto ``step-*.ckpt`` (:mod:`.checkpoints`): a
  ``torch.save`` zip (a ``data.pkl`` member), read with ``weights_only=True``; the trainer's normalisation is
  undone when its transform is known (:class:`LoadOptions`).

The content decides, not the suffix (a compressed .ply is a .ply too); the suffix only names the format of a file
whose content is recognised as none of them, for a sharper message. Every reader returns the 3DGS .ply frame
(an .spz, stored right-up-back by Niantic's definition but in the .ply frame by SuperSplat, is turned to it or not
as ``LoadOptions.spz_frame`` says; "auto", the default, decides from a file of the same capture in another format
beside it, :func:`spz_frame_evidence`, and warns when nothing decides) and compares the sizes a
header declares with the file size and the memory budget (:mod:`recon.inflate`) before allocating anything.
:func:`load_gaussians_framed` also says which frame it assumed (:class:`SourceFrame`), for the log and
RESULT.h5. Writing stays the standard .ply or .npz (:func:`.ply.save_gaussians`).

Example:
    >>> g, fmt = load_gaussians_with_format("biker.spz")  # doctest: +SKIP
    >>> fmt, g.num  # doctest: +SKIP
    ('spz', 152746)
"""

from __future__ import annotations

import json
import logging
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..gaussians import GaussianSet
from . import compressed_ply, dotsplat, ksplat, npz, ply, sog, spz

log = logging.getLogger(__name__)

FORMATS: dict[str, str] = {
    "ply": "standard 3DGS .ply",
    "compressed_ply": "SuperSplat/PlayCanvas compressed .ply",
    "spz": "Niantic .spz (versions 2, 3, 4)",
    "splat": "antimatter15 .splat",
    "npz": ".npz (GaussianSet arrays or a gsplat checkpoint's arrays)",
    "sog": "PlayCanvas SOG (versions 1, 2: .sog bundle or meta.json folder)",
    "ksplat": "mkkellogg .ksplat (compression modes 0, 1, 2)",
    "checkpoint": "gsplat ckpt_*.pt or nerfstudio splatfacto step-*.ckpt",
}
SUPPORTED = "supported formats: " + "; ".join(FORMATS.values())


def gaussians_help(what: str = "Gaussians") -> str:
    """The help text of a command's Gaussian file argument: every format of :data:`FORMATS`, so that no command's
    list falls behind the readers."""
    return f"{what} in scene units; the formats read: {'; '.join(FORMATS.values())}"


READERS: dict[str, Callable[[Path], GaussianSet]] = {
    "ply": ply.load_standard_ply,
    "compressed_ply": compressed_ply.load_compressed_ply,
    "spz": spz.load_spz,
    "splat": dotsplat.load_splat,
    "npz": npz.load_npz,
    "sog": sog.load_sog,
    "ksplat": ksplat.load_ksplat,
}
SUFFIXES = (".ply", ".spz", ".splat", ".npz", ".sog", ".ksplat", ".pt", ".ckpt")
MAX_ZIP_NAMES = 100_000
ZIP_MAGICS = (b"PK\x03\x04", b"PK\x05\x06")


def detect_format(path: str | Path) -> str:
    """The format name of a Gaussian file (a key of :data:`FORMATS`), from its content.

    Args:
        path: the file.
    Returns:
        a key of :data:`FORMATS`.
    Raises:
        FileNotFoundError: nothing exists at ``path``.
        ValueError: ``path`` is a folder, an empty file, a malformed PLY header, or a format none of the readers
            knows (the message lists the supported formats).
    """
    path = Path(path)
    if path.is_dir():
        if sog.is_sog_folder(path):
            return "sog"
        raise ValueError(_folder_message(path))
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such Gaussian file")
    with open(path, "rb") as fh:
        head = fh.read(64)
        if head[:3] == b"ply" and head[3:4] in (b"\n", b"\r"):
            fh.seek(0)
            layout = ply.parse_ply_header(fh, str(path))
            return "compressed_ply" if compressed_ply.is_compressed_layout(layout) else "ply"
    suffix = path.suffix.lower()
    if head[:4] in ZIP_MAGICS:
        return _zip_format(path)
    if head[:2] == spz.GZIP_MAGIC or head[:4] == spz.NGSP_MAGIC:
        return "spz"
    if suffix == ".splat":
        return "splat"  # no magic: load_splat checks the size
    if suffix == ".ksplat":
        return "ksplat"  # no magic: load_ksplat checks the version and the mode
    if suffix == ".json" and head.lstrip()[:1] == b"{":
        return "sog"  # a SOG meta.json: load_sog says so when it is not one
    if suffix in (".pt", ".pth", ".ckpt") and head[:1] == b"\x80":
        return "checkpoint"  # a legacy (non-zip) torch.save file
    if not head:
        raise ValueError(f"{path}: the file is empty; {SUPPORTED}")
    expected = {
        ".ply": "not a PLY file (the first line is not 'ply')",
        ".npz": "not a readable .npz archive (no zip signature)",
        ".spz": "not an .spz file (neither gzip-wrapped nor starting with 'NGSP')",
    }
    what = expected.get(suffix, f"unrecognised Gaussian file format (suffix {path.suffix!r})")
    size = path.stat().st_size
    hint = (
        f" (its {size} bytes are a whole number of 32-byte records: if it is an antimatter15 .splat, which has "
        f"no header, rename it to {path.stem}.splat)"
        if size % dotsplat.RECORD_BYTES == 0
        else ""
    )
    raise ValueError(f"{path}: {what}; it starts with {head!r}{hint}; {SUPPORTED}")


def _zip_format(path: Path) -> str:
    """ "sog", "checkpoint" or "npz" for a zip archive, from its member names."""
    try:
        with zipfile.ZipFile(path) as archive:
            names = archive.namelist()[:MAX_ZIP_NAMES]
    except (zipfile.BadZipFile, OSError, EOFError):
        return "npz"  # load_npz names the problem
    if sog.is_sog_bundle(names):
        return "sog"
    from .checkpoints import is_torch_checkpoint  # noqa: PLC0415 - keeps torch.load paths out of the other formats

    return "checkpoint" if is_torch_checkpoint(names) else "npz"


@dataclass(frozen=True)
class LoadOptions:
    """What the content of a file cannot say (the command line's ``--spz-frame``, ``--colmap`` and
    ``--dataparser-transforms``).

    Attributes:
        spz_frame: "rub" (Niantic's definition: turned half a turn about x), "ply" (splat-transform's: kept) or
            "auto" (decided from a sibling file of the capture in another format, :func:`spz_frame_evidence`;
            Niantic's, with a warning, when there is none). A frame that the evidence contradicts is kept, with a
            warning naming the other.
        colmap: the COLMAP model a gsplat checkpoint was trained on (its normalisation is recomputed and undone).
        dataparser_transforms: nerfstudio's dataparser_transforms.json (default: found beside config.yml).
    """

    spz_frame: str = "auto"
    colmap: Path | None = None
    dataparser_transforms: Path | None = None


@dataclass(frozen=True)
class SourceFrame:
    """The frame a loaded file was assumed to be in, and the transform applied to its values.

    Attributes:
        format: the :func:`detect_format` name.
        description: one line for the log (which frame, which convention, how to choose the other).
        to_loaded: 4x4 matrix from the file's values to the returned ones (x_loaded = M [x_file, 1]).
        metric: False when the sizes are a trainer's normalised units (nothing could restore the frame).
    """

    format: str
    description: str
    to_loaded: np.ndarray
    metric: bool = True

    def to_json(self) -> str:
        """The record stored in RESULT.h5 (``source_frame``)."""
        return json.dumps(
            {
                "format": self.format,
                "description": self.description,
                "to_loaded": np.asarray(self.to_loaded, float).tolist(),
                "metric": self.metric,
            }
        )


def load_gaussians_framed(path: str | Path, options: LoadOptions | None = None) -> tuple[GaussianSet, str, SourceFrame]:
    """Read a Gaussian file of any supported format, and say which frame it was assumed to be in.

    Returns:
        (the float32 GaussianSet on the CPU, the format name, its :class:`SourceFrame`).
    Raises:
        FileNotFoundError, ValueError: as :func:`load_gaussians_with_format`.
    """
    options = options or LoadOptions()
    fmt = detect_format(path)
    path = Path(path)
    undoing = (("--colmap", options.colmap), ("--dataparser-transforms", options.dataparser_transforms))
    given = [option for option, value in undoing if value is not None]
    if given and fmt != "checkpoint":  # it would be ignored: say so rather than run in the frame the user undid
        raise ValueError(
            f"{given[0]} applies to a trainer's checkpoint (gsplat, nerfstudio), whose normalisation it undoes; {path} "
            f"is a {FORMATS[fmt]} file, read in its own frame: drop {given[0]}"
        )
    identity = np.eye(4)
    if fmt == "spz":
        gaussians, chosen, description = _load_spz_decided(path, options.spz_frame)
        frame = SourceFrame(fmt, description, np.diag([1.0, -1.0, -1.0, 1.0]) if chosen == "rub" else identity)
    elif fmt == "checkpoint":
        from .checkpoints import load_trained_model, restore_metric_frame  # noqa: PLC0415 - torch.load only here

        model = load_trained_model(path)
        gaussians, undo, note = restore_metric_frame(model, options.colmap, options.dataparser_transforms)
        frame = SourceFrame(
            fmt,
            f"{path}: {model.trainer} checkpoint; {note}" if undo is not None else note,
            identity if undo is None else undo,
            metric=undo is not None,
        )
    else:
        gaussians = READERS[fmt](path)
        frame = SourceFrame(fmt, f"{path}: {FORMATS[fmt]} read in the file's own frame (the 3DGS .ply frame)", identity)
    log.debug("%s: %d Gaussians read as %s", path, gaussians.num, FORMATS[fmt])
    return gaussians, fmt, frame


# ---- the .spz frame, from the data -------------------------------------------------------------------------
SPZ_FRAME_CHOICES = ("auto", *spz.SPZ_FRAMES)
# the formats that keep the .ply frame of a capture (docs/formats.md), tried as evidence for an .spz's frame
PLY_FRAME_FORMATS = ("ply", "compressed_ply", "splat", "ksplat", "sog")
BOX_QUANTILES = (0.02, 0.98)  # the robust box compared: floaters do not count
SAME_CAPTURE = 0.05  # a sibling's box within this share of its size of one reading: the same capture
DECISIVE = 4.0  # the other reading must be this many times farther off for the evidence to decide


def _robust_box(means: np.ndarray) -> np.ndarray:
    return np.quantile(np.asarray(means, np.float64), BOX_QUANTILES, axis=0)


def _flip_box(box: np.ndarray) -> np.ndarray:
    """The robust box of the other .spz reading: (x, y, z) -> (x, -y, -z), so y's and z's bounds swap sides."""
    out = box.copy()
    out[:, 1:] = -box[::-1, 1:]
    return out


def spz_siblings(path: Path) -> list[Path]:
    """Files beside an .spz that may hold the same capture in a format that keeps the .ply frame: the same name
    up to its first dot (``guitar.v3.spz`` -> ``guitar.*``), smallest first."""
    root = path.name.split(".")[0]
    found = []
    for p in path.parent.glob(f"{root}.*"):
        if p == path or not p.is_file() or p.suffix.lower() not in (".ply", ".splat", ".ksplat", ".sog"):
            continue
        found.append(p)
    return sorted(found, key=lambda p: p.stat().st_size)


def spz_frame_evidence(path: str | Path, means_rub: np.ndarray) -> tuple[str | None, str]:
    """Which frame an .spz is stored in, decided from a sibling file of the same capture (:func:`spz_siblings`):
    the robust boxes (2-98 % quantiles of the centres) of the two readings against the sibling's.

    Args:
        path: the .spz. means_rub: [N, 3] its centres read as "rub" (Niantic's, turned to the .ply frame).
    Returns:
        ("rub" or "ply", the evidence in words), or (None, why nothing decides: no sibling, another capture, or a
        box symmetric about the origin, which both readings fit).
    """
    path = Path(path)
    rub = _robust_box(means_rub)
    for sibling in spz_siblings(path):
        try:
            fmt = detect_format(sibling)
            if fmt not in PLY_FRAME_FORMATS:
                continue
            ref = _robust_box(READERS[fmt](sibling).means.detach().cpu().numpy())
        except (ValueError, OSError):
            continue
        size = float((ref[1] - ref[0]).max()) or 1.0
        off = {"rub": float(np.abs(rub - ref).max()) / size, "ply": float(np.abs(_flip_box(rub) - ref).max()) / size}
        best, worse = sorted(off, key=off.get)
        if off[best] > SAME_CAPTURE:
            continue  # not the same capture (or cropped otherwise)
        if off[worse] < DECISIVE * max(off[best], 1e-3):
            return None, (
                f"{sibling.name} fits both readings (boxes off by {off['rub']:.1%} and {off['ply']:.1%}): the "
                "capture is symmetric about the origin"
            )
        return best, (
            f"{sibling.name} ({FORMATS[fmt]}, the .ply frame) has the box of the {best!r} reading (off by "
            f"{off[best]:.2%} of its size; the {worse!r} reading is off by {off[worse]:.0%})"
        )
    return None, "no file of the same capture in another format beside it"


def _load_spz_decided(path: Path, asked: str) -> tuple[GaussianSet, str, str]:
    """An .spz read in the frame ``asked`` ("auto": the one the evidence shows, else "rub"), with the description
    of what was assumed and why; a WARNING when the evidence contradicts an asked frame or nothing decides."""
    if asked not in SPZ_FRAME_CHOICES:
        raise ValueError(f"the .spz frame must be one of {list(SPZ_FRAME_CHOICES)}, got {asked!r}")
    gaussians = spz.load_spz(path, "rub" if asked == "auto" else asked)
    means = gaussians.means.detach().cpu().numpy()
    evidence, why = spz_frame_evidence(path, means if asked != "ply" else means * np.array([1.0, -1.0, -1.0]))
    chosen = evidence if asked == "auto" and evidence is not None else ("rub" if asked == "auto" else asked)
    if chosen != ("rub" if asked == "auto" else asked):
        gaussians = spz.load_spz(path, chosen)
    other = "ply" if chosen == "rub" else "rub"
    read = f"{path}: .spz read as {spz.SPZ_FRAMES[chosen]}"
    if evidence is None:
        description = (
            f"{read}; nothing tells this file's frame ({why}): SuperSplat and splat-transform write .spz in the .ply "
            f"frame, so if `fluidgs inspect --png` shows the capture upside down, pass --spz-frame {other}"
        )
        log.warning("%s", description)
    elif evidence != chosen:
        description = f"{read} as asked, but {why}: it likely stands upside down; pass --spz-frame {evidence}"
        log.warning("%s", description)
    else:
        how = "decided from the data" if asked == "auto" else "as asked, and the data agree"
        description = f"{read}, {how}: {why}"
    return gaussians, chosen, description


def load_gaussians_with_format(path: str | Path) -> tuple[GaussianSet, str]:
    """Read a Gaussian file of any supported format; also return the format name (for ``fluidgs inspect``).

    Returns:
        (a float32 :class:`GaussianSet` on the CPU in the 3DGS .ply frame, the :func:`detect_format` name).
    Raises:
        FileNotFoundError: nothing exists at ``path``.
        ValueError: a folder, an unsupported format, or any problem with the content; the message names the file.
    """
    gaussians, fmt, _ = load_gaussians_framed(path)
    return gaussians, fmt


def load_gaussians(path: str | Path) -> GaussianSet:
    """Read a Gaussian file of any supported format (see :func:`load_gaussians_with_format`)."""
    return load_gaussians_with_format(path)[0]


def _folder_message(path: Path) -> str:
    candidates = sorted(p.name for p in path.iterdir() if p.is_file() and p.suffix.lower() in SUFFIXES)[:5]
    hint = (
        f"it holds {', '.join(candidates)}"
        if candidates
        else "a 3DGS output folder keeps it in point_cloud/iteration_*/point_cloud.ply"
    )
    return f"{path}: is a folder, not a Gaussian file; pass the file itself ({hint}); {SUPPORTED}"
