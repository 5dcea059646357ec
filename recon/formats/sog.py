"""Reading PlayCanvas SOG ("Spatially Ordered Gaussians"), versions 1 and 2: a ``.sog`` zip bundle or a
``meta.json`` folder (developer.playcanvas.com, "The SOG Format"; SuperSplat and splat-transform write it).

A SOG is a ``meta.json`` and 8-bit images (lossless WebP, decoded here with Pillow), every Gaussian i at pixel
``(i % W, i // W)`` of each per-Gaussian image; ``count <= W * H`` and trailing pixels are ignored.

**Version 2** (``"version": 2``, ``count``):

- positions: ``means_l`` / ``means_u`` hold the low / high byte of a 16-bit value q per axis (R, G, B);
  ``n = mins + (maxs - mins) q / 65535`` is the symmetric log ``sign(x) ln(1 + |x|)`` of the position, so
  ``x = sign(n) (exp|n| - 1)``;
- rotations: ``quats`` R, G, B are the three smaller components ``c / 255 * 2 - 1`` divided by sqrt 2, A = 252 + the
  index (in w, x, y, z order) of the largest one, which is ``sqrt(1 - sum)``; other A values are reserved (an error);
- log-scales: ``scales`` R, G, B index the 256-entry ``scales.codebook``;
- colour: ``sh0`` R, G, B index ``sh0.codebook`` (the SH DC coefficient), A is the opacity ``a / 255``;
- optional SH: ``shN_labels`` (R + 256 G: a palette entry < ``shN.count``) and ``shN_centroids``, 64 entries per row,
  entry e's coefficient j at pixel ``((e % 64) * C + j, e // 64)`` with C = 3, 8, 15 for ``shN.bands`` 1-3; its
  R, G, B index ``shN.codebook``.

**Version 1** (no ``version``; the count is ``means.shape[0]``): the same images, but linear ranges instead of
codebooks: ``scales`` lerps per axis between ``scales.mins`` and ``maxs``; ``sh0`` lerps R, G, B and A (the opacity
*logit*) between 4 ``mins`` and ``maxs``; the SH centroids lerp between the scalar ``shN.mins`` and ``maxs``, and
the band count follows from the centroid image's width (192, 512 or 960 pixels).

Version 3 is refused with a message (its definition was not public when this reader was written).

**Frame.** SOG stores the 3DGS .ply frame (the specification and splat-transform both say so); nothing is turned.
**Bounds.** Image sizes are read from the image headers and checked against ``count`` (at least ``count``, at most
:func:`max_image_pixels`) and the memory budget (:mod:`recon.inflate`) before any image is decoded; an image file
larger than its pixels can need (:func:`image_byte_limit`) is refused before it is inflated, and zip members are
inflated in bounded chunks.
"""

from __future__ import annotations

import io
import json
import math
import zipfile
from pathlib import Path

import numpy as np

from ..gaussians import GaussianSet
from ..inflate import check_budget, memory_budget_bytes, read_zip_member
from .arrays import gaussians_from_arrays, opacity_logits_from_unit

SUPPORTED_VERSIONS = (1, 2)
SH_COEFFS = {1: 3, 2: 8, 3: 15}  # bands -> coefficients per channel beyond DC
V1_BANDS_BY_WIDTH = {64 * c: b for b, c in SH_COEFFS.items()}
MAX_META_BYTES = 1 << 22
CENTROID_MAX_PIXELS = 64 * SH_COEFFS[3] * (65536 // 64 + 4)  # 65536 palette entries of 3 bands, rows padded
DECODED_BYTES_PER_GAUSSIAN = 4 * (3 + 4 + 3 + 1 + 16 * 3) + 7 * 4  # float32 set + the RGBA pixels in flight
FIX = "re-export it with splat-transform or SuperSplat"


def is_sog_folder(path: Path) -> bool:
    """Whether ``path`` is a folder holding a SOG ``meta.json``."""
    return path.is_dir() and (path / "meta.json").is_file()


def is_sog_bundle(names: list[str]) -> bool:
    """Whether a zip archive's member ``names`` are those of a SOG bundle (a ``meta.json`` at the root)."""
    return "meta.json" in names


def load_sog(path: str | Path) -> GaussianSet:
    """Read a SOG: a ``.sog`` bundle, a ``meta.json`` file with its images beside it, or the folder holding them.

    Returns:
        A float32 GaussianSet on the CPU in the 3DGS .ply frame: means [N, 3], (w, x, y, z) quats [N, 4],
        log-scales [N, 3], opacity logits [N], SH [N, K, 3] (K = 1, 4, 9 or 16).
    Raises:
        ValueError: naming the file: not a SOG, an unsupported version, a missing image, a count larger than the
            images hold, a palette index out of range, a reserved quaternion tag, or sizes over the memory budget.
    """
    path = Path(path)
    if path.is_dir():
        return _decode(_FolderFiles(path), str(path))
    with open(path, "rb") as fh:
        zipped = fh.read(2) == b"PK"
    if zipped:
        try:
            archive = zipfile.ZipFile(path)
        except (zipfile.BadZipFile, OSError, EOFError) as exc:
            raise ValueError(f"{path}: not a readable .sog bundle ({exc}); {FIX}") from None
        with archive:
            return _decode(_ZipFiles(archive, str(path)), str(path))
    return _decode(_FolderFiles(path.parent, path.name), str(path))


class _FolderFiles:
    """The files of an unbundled SOG: ``meta.json`` (or another name) and images beside it."""

    def __init__(self, folder: Path, meta_name: str = "meta.json"):
        self.folder, self.meta_name = folder, meta_name

    def where(self) -> str:
        return f"the folder {self.folder}"

    def names(self) -> list[str]:
        return sorted(p.name for p in self.folder.iterdir() if p.is_file())

    def read(self, name: str, source: str, limit: int) -> bytes:
        target = self.folder / name
        if Path(name).name != name or not target.is_file():
            raise _missing(source, name, self)
        size = target.stat().st_size
        if size > limit:
            raise ValueError(f"{source}: {name} holds {size} bytes, more than the {limit} a SOG file may hold")
        return target.read_bytes()


class _ZipFiles:
    """The members of a ``.sog`` bundle, read in bounded chunks."""

    def __init__(self, archive: zipfile.ZipFile, source: str):
        self.archive, self.source, self.meta_name = archive, source, "meta.json"
        self.infos = {i.filename: i for i in archive.infolist()}
        size = Path(source).stat().st_size
        if sum(i.compress_size for i in self.infos.values()) > size:
            raise ValueError(f"{source}: corrupt .sog bundle: its directory lists more data than the file holds")

    def where(self) -> str:
        return "the bundle"

    def names(self) -> list[str]:
        return sorted(self.infos)

    def read(self, name: str, source: str, limit: int) -> bytes:
        info = self.infos.get(name)
        if info is None:
            raise _missing(source, name, self)
        return read_zip_member(self.archive, info, source, limit)


def _missing(source: str, name: str, files) -> ValueError:
    held = ", ".join(files.names()[:12]) or "nothing"
    return ValueError(
        f"{source}: the SOG image {name!r} named in meta.json is missing from {files.where()} (it holds "
        f"{held}); copy every file that meta.json names next to it, or {FIX}"
    )


def _meta(files, source: str) -> dict:
    raw = files.read(files.meta_name, source, MAX_META_BYTES)
    try:
        meta = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise ValueError(f"{source}: the SOG meta.json is not valid JSON ({exc}); {FIX}") from None
    if not isinstance(meta, dict) or not all(
        isinstance(meta.get(k), dict) for k in ("means", "quats", "scales", "sh0")
    ):
        raise ValueError(
            f"{source}: not a SOG meta.json (it lacks the 'means', 'quats', 'scales' and 'sh0' entries); {FIX}"
        )
    return meta


def _field(meta: dict, path: str, source: str, length: int | None = None) -> list[float] | float:
    value = meta
    for key in path.split("."):
        value = value.get(key) if isinstance(value, dict) else None
    ok = (
        isinstance(value, list)
        and (length is None or len(value) == length)
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)
    )
    if length is None and isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value):
        ok = True
    if not ok:
        want = f"a list of {length} finite numbers" if length else "a finite number"
        raise ValueError(f"{source}: SOG meta.json '{path}' must be {want}, got {str(value)[:80]}; {FIX}")
    return value


def _files(meta: dict, key: str, count: int, source: str) -> list[str]:
    names = meta[key].get("files")
    if not isinstance(names, list) or len(names) < count or not all(isinstance(n, str) for n in names[:count]):
        raise ValueError(f"{source}: SOG meta.json '{key}.files' must list {count} image name(s), got {names!r}")
    return names[:count]


def max_image_pixels(count: int) -> int:
    """The most pixels a per-Gaussian image of ``count`` Gaussians may have: splat-transform lays them out in
    ``ceil(sqrt(count) / 4) * 4`` columns and rows rounded up to 4, so twice the count plus a margin is generous."""
    return 2 * count + 4096


def image_byte_limit(pixels: int) -> int:
    """The most bytes the file of an image of ``pixels`` pixels may hold: lossless WebP never needs much more than
    the raw RGBA, so a larger member (a zip bomb, a padded file) is refused before it is inflated."""
    return 8 * pixels + (1 << 20)


def _image(
    files, name: str, source: str, need: int, what: str, max_pixels: int | None = None
) -> tuple[np.ndarray, int]:
    """[H * W, 4] uint8 RGBA pixels of one image, after checking its declared size (header only) against ``need``
    Gaussians, ``max_pixels`` (default :func:`max_image_pixels` of ``need``) and the memory budget."""
    from PIL import Image  # noqa: PLC0415 - only SOG needs Pillow

    max_pixels = max_image_pixels(need) if max_pixels is None else max_pixels
    data = files.read(name, source, min(image_byte_limit(max_pixels), memory_budget_bytes()))
    try:
        image = Image.open(io.BytesIO(data))
        width, height = image.size
    except Exception as exc:  # noqa: BLE001 - Pillow raises many types for a bad image
        raise ValueError(f"{source}: the SOG image {name!r} cannot be read ({exc}); {FIX}") from None
    if width * height > max_pixels:
        raise ValueError(
            f"{source}: the SOG {what} image {name!r} is {width} x {height} = {width * height} pixels, more than "
            f"the {max_pixels} that {need} Gaussians need (a corrupt or hostile file, refused before decoding); {FIX}"
        )
    if width * height < need:
        raise ValueError(
            f"{source}: the SOG {what} image {name!r} is {width} x {height} = {width * height} pixels, "
            f"fewer than the {need} Gaussians meta.json declares (a count larger than the images "
            f"hold); {FIX}"
        )
    check_budget(source, f"the SOG image {name!r} ({width} x {height})", 4 * width * height)
    try:
        pixels = np.asarray(image.convert("RGBA"), dtype=np.uint8)
    except Exception as exc:  # noqa: BLE001
        raise ValueError(f"{source}: the SOG image {name!r} cannot be decoded ({exc}); {FIX}") from None
    return pixels.reshape(-1, 4), width


def _version(meta: dict, source: str) -> int:
    version = meta.get("version")
    if version is None:
        return 1
    if version not in SUPPORTED_VERSIONS or isinstance(version, bool):
        raise ValueError(
            f"{source}: SOG version {version!r} is not supported (versions 1 and 2 are); re-export it "
            f"as version 2 (splat-transform writes it for viewers that predate version 3)"
        )
    return int(version)


def _count(meta: dict, version: int, source: str) -> int:
    if version == 2:
        count = meta.get("count")
    else:
        shape = meta["means"].get("shape")
        count = shape[0] if isinstance(shape, list) and shape else None
    if not isinstance(count, int) or isinstance(count, bool) or count <= 0:
        where = "'count'" if version == 2 else "'means.shape[0]'"
        raise ValueError(f"{source}: SOG meta.json {where} must be a positive integer, got {count!r}; {FIX}")
    check_budget(source, f"{count} SOG Gaussians", count * DECODED_BYTES_PER_GAUSSIAN)
    return count


def _decode(files, source: str) -> GaussianSet:
    meta = _meta(files, source)
    version = _version(meta, source)
    n = _count(meta, version, source)
    lo_name, hi_name = _files(meta, "means", 2, source)
    lo, _ = _image(files, lo_name, source, n, "means_l")
    hi, _ = _image(files, hi_name, source, n, "means_u")
    q = lo[:n, :3].astype(np.float64) + 256.0 * hi[:n, :3]
    mins = np.array(_field(meta, "means.mins", source, 3), np.float64)
    spans = np.array(_field(meta, "means.maxs", source, 3), np.float64) - mins
    spans[spans == 0] = 1.0  # as splat-transform: a flat axis decodes to its min (q = 0)
    logs = mins + spans * q / 65535.0
    means = np.sign(logs) * np.expm1(np.abs(logs))
    quats = decode_quats(_image(files, _files(meta, "quats", 1, source)[0], source, n, "quats")[0][:n], source)
    scales_px = _image(files, _files(meta, "scales", 1, source)[0], source, n, "scales")[0][:n]
    sh0_px = _image(files, _files(meta, "sh0", 1, source)[0], source, n, "sh0")[0][:n]
    if version == 2:
        log_scales = _codebook(meta, "scales", source)[scales_px[:, :3]]
        dc = _codebook(meta, "sh0", source)[sh0_px[:, :3]]
        logits = opacity_logits_from_unit(sh0_px[:, 3].astype(np.float32) / 255.0)
    else:
        log_scales = _lerp(meta, "scales", 3, scales_px[:, :3], source)
        colour = _lerp(meta, "sh0", 4, sh0_px, source)
        dc, logits = colour[:, :3], colour[:, 3]
    rest = _sh_rest(files, meta, version, n, source)
    sh = dc[:, None, :] if rest is None else np.concatenate([dc[:, None, :], rest], 1)
    return gaussians_from_arrays(source, means.astype(np.float32), quats, log_scales, logits, sh)


def decode_quats(pixels: np.ndarray, source: str = "SOG") -> np.ndarray:
    """(w, x, y, z) unit quaternions [N, 4] from SOG ``quats`` RGBA pixels [N, 4] (module docstring)."""
    tags = pixels[:, 3].astype(np.int64) - 252
    bad = (tags < 0) | (tags > 3)
    if bad.any():
        rows = np.flatnonzero(bad)
        raise ValueError(
            f"{source}: {len(rows)} SOG rotations have a reserved mode byte (alpha not in 252-255; "
            f"first Gaussians {rows[:5].tolist()}): a corrupt or lossily compressed quats image; {FIX}"
        )
    small = (pixels[:, :3].astype(np.float32) / 255.0 * 2.0 - 1.0) / np.float32(math.sqrt(2.0))
    others = np.array([[j for j in range(4) if j != i] for i in range(4)])[tags]
    quats = np.zeros((len(pixels), 4), np.float32)
    rows = np.arange(len(pixels))[:, None]
    quats[rows, others] = small
    quats[rows[:, 0], tags] = np.sqrt(np.maximum(0.0, 1.0 - (small * small).sum(1)))
    return quats


def _codebook(meta: dict, key: str, source: str) -> np.ndarray:
    return np.array(_field(meta, f"{key}.codebook", source, 256), np.float32)


def _lerp(meta: dict, key: str, channels: int, pixels: np.ndarray, source: str) -> np.ndarray:
    lo = np.array(_field(meta, f"{key}.mins", source, channels), np.float32)
    hi = np.array(_field(meta, f"{key}.maxs", source, channels), np.float32)
    return lo + (hi - lo) * (pixels[:, :channels].astype(np.float32) / 255.0)


def _sh_rest(files, meta: dict, version: int, n: int, source: str) -> np.ndarray | None:
    """[N, C, 3] SH coefficients beyond DC, or None without ``shN``."""
    entry = meta.get("shN")
    if not isinstance(entry, dict):
        return None
    centroid_name, label_name = _files(meta, "shN", 2, source)
    labels_px, _ = _image(files, label_name, source, n, "shN_labels")
    labels = labels_px[:n, 0].astype(np.int64) + 256 * labels_px[:n, 1].astype(np.int64)
    from PIL import Image  # noqa: PLC0415

    data = files.read(centroid_name, source, image_byte_limit(CENTROID_MAX_PIXELS))
    try:
        width, height = Image.open(io.BytesIO(data)).size
    except Exception as exc:  # noqa: BLE001
        raise ValueError(f"{source}: the SOG image {centroid_name!r} cannot be read ({exc}); {FIX}") from None
    if version == 2:
        bands = entry.get("bands")
        if bands not in SH_COEFFS:
            raise ValueError(f"{source}: SOG meta.json 'shN.bands' must be 1, 2 or 3, got {bands!r}; {FIX}")
        palette = entry.get("count")
        if not isinstance(palette, int) or isinstance(palette, bool) or not 0 < palette <= 65536:
            raise ValueError(f"{source}: SOG meta.json 'shN.count' must be 1-65536, got {palette!r}; {FIX}")
    else:
        bands = V1_BANDS_BY_WIDTH.get(width)
        if bands is None:
            raise ValueError(
                f"{source}: the SOG SH centroid image {centroid_name!r} is {width} pixels wide; version 1 "
                f"expects 192, 512 or 960 (1-3 bands); {FIX}"
            )
        palette = 64 * height
    coeffs = SH_COEFFS[bands]
    if width != 64 * coeffs or 64 * height < palette or height > math.ceil(palette / 64) + 4:
        raise ValueError(
            f"{source}: the SOG SH centroid image {centroid_name!r} is {width} x {height} pixels; "
            f"{palette} palette entries of {bands} band(s) need {64 * coeffs} x {math.ceil(palette / 64)}"
            f"; {FIX}"
        )
    if (labels >= palette).any():
        rows = np.flatnonzero(labels >= palette)
        raise ValueError(
            f"{source}: {len(rows)} SOG SH labels point past the {palette}-entry palette (first "
            f"Gaussians {rows[:5].tolist()}); {FIX}"
        )
    centroids, _ = _image(files, centroid_name, source, 0, "shN_centroids", width * height)
    pixel = (labels // 64)[:, None] * width + (labels % 64)[:, None] * coeffs + np.arange(coeffs)[None, :]
    codes = centroids[pixel][..., :3]  # [N, C, 3]
    if version == 2:
        return _codebook(meta, "shN", source)[codes]
    lo, hi = float(_field(meta, "shN.mins", source)), float(_field(meta, "shN.maxs", source))
    return (lo + (hi - lo) * codes.astype(np.float32) / 255.0).astype(np.float32)
