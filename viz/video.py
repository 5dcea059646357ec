"""MP4 video in H.264 that web browsers play, written atomically through the FFmpeg of ``imageio-ffmpeg``.

OpenCV's ``mp4v`` (MPEG-4 Part 2) plays in desktop players but not in Chrome, Firefox or Safari. Browsers play
H.264 in an MP4 container with 4:2:0 chroma (``yuv420p``) and the index (``moov`` atom) at the front of the file
(``-movflags +faststart``, so playback starts before the download ends). The encoder is ``libx264`` at a constant
quality (CRF, 0 = lossless .. 51 = worst; 18 is visually lossless for these renders).

4:2:0 chroma halves both dimensions, so H.264 needs an even width and height. A frame of odd size is padded by
one edge pixel (the last column and/or row duplicated; the usual remedy) rather than cropped, so nothing drawn is
lost; the padding is logged once per video. No paper equations here.

Example:
    >>> frames = (np.full((120, 160, 3), k, np.uint8) for k in range(30))
    >>> write_mp4(frames, "ramp.mp4", fps=30)  # doctest: +SKIP
"""

from __future__ import annotations

import itertools
import logging
import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fluidsim.files import OutputError, atomic_output

logger = logging.getLogger(__name__)

CODEC = "libx264"
PIXEL_FORMAT = "yuv420p"
DEFAULT_CRF = 18
MAX_SIDE = 16384  # px: libx264 encodes no wider or taller frame (FFmpeg then writes an empty file and exits 0)


def even_size(height: int, width: int) -> tuple[int, int]:
    """(height, width) rounded up to even numbers: the frame size H.264 with 4:2:0 chroma encodes."""
    return height + height % 2, width + width % 2


def pad_to_even(frame: np.ndarray) -> np.ndarray:
    """A (H, W, 3) frame padded to :func:`even_size` by duplicating its last row and/or column (itself if even)."""
    h, w = frame.shape[:2]
    if not (h % 2 or w % 2):
        return frame
    return np.pad(frame, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")


def check_encoder(path: str | os.PathLike) -> Path:
    """The FFmpeg executable that :func:`write_mp4` runs (the one in the ``imageio-ffmpeg`` wheel, or
    ``IMAGEIO_FFMPEG_EXE``); OSError naming ``path`` when there is none, so a render fails before its first frame."""
    try:
        import imageio_ffmpeg  # noqa: PLC0415 - loaded only when a video is written or read (~0.1 s)

        return Path(imageio_ffmpeg.get_ffmpeg_exe())
    except (ImportError, RuntimeError) as exc:
        raise OSError(
            f"cannot write the video {path}: no FFmpeg ({exc}); install imageio-ffmpeg "
            "(pip install imageio-ffmpeg), or write PNG frames instead"
        ) from exc


def _check_frame(frame, i: int, size: tuple[int, int] | None, path: Path) -> np.ndarray:
    frame = np.asarray(frame)
    if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3:
        raise ValueError(f"{path}: video frame {i} must be an (H, W, 3) uint8 array, got {frame.shape} {frame.dtype}")
    if size is not None and frame.shape[:2] != size:
        raise ValueError(
            f"{path}: video frame {i} is {frame.shape[1]}x{frame.shape[0]} px but frame 0 is "
            f"{size[1]}x{size[0]} px; every frame needs the same size"
        )
    return frame


def _first_frame(first: np.ndarray | None, path: Path) -> np.ndarray:
    """The checked first frame of a video, which fixes its size: at most MAX_SIDE px a side once padded to even (the
    padding logged)."""
    if first is None:
        raise ValueError(f"{path}: no frames to write; a video needs at least one frame")
    first = _check_frame(first, 0, None, path)
    h, w = first.shape[:2]
    out_h, out_w = even_size(h, w)
    if max(out_h, out_w) > MAX_SIDE:
        raise ValueError(f"{path}: frames of {w}x{h} px; H.264 encodes at most {MAX_SIDE} px a side")
    if (out_h, out_w) != (h, w):
        note = "%s: padding %dx%d px frames to %dx%d px (H.264 with 4:2:0 chroma needs an even size)"
        logger.info(note, path, w, h, out_w, out_h)
    return first


def write_mp4(
    frames: Iterable[np.ndarray], path: str | os.PathLike, fps: float = 30, *, bgr: bool = False, crf: int = DEFAULT_CRF
) -> Path:
    """Encode frames as a browser-playable H.264 MP4 (yuv420p, faststart), written atomically.

    Args:
        frames: (H, W, 3) uint8 images, all of one size; RGB, or BGR (OpenCV's order) with ``bgr=True``. Read
            lazily, so a long render never sits in memory.
        path: the .mp4 file; its folder must exist. The video goes to ``.fgs-<8 hex>.tmp.mp4`` in that folder
            first and is renamed onto ``path`` once FFmpeg has finished; on any error the temporary file is removed
            and ``path`` is left as it was.
        fps: frames per second, > 0.
        bgr: the frames are in BGR order.
        crf: libx264 constant rate factor, 0 (lossless) .. 51.

    Returns:
        ``Path(path)``.

    Raises:
        ValueError: no frames, frames of the wrong shape or dtype, of changing size or over 16384 px a side, bad
            fps or crf.
        fluidsim.files.OutputError: (an OSError, exit code 4) FFmpeg is missing or fails, or the file cannot be written
            (the message names ``path``).
    """
    import imageio_ffmpeg  # noqa: PLC0415 - loaded only when a video is written or read (~0.1 s)

    path = Path(path)
    if not (isinstance(fps, (int, float)) and not isinstance(fps, bool) and np.isfinite(fps) and fps > 0):
        raise ValueError(f"{path}: fps must be a number > 0, got {fps!r}")
    if isinstance(crf, bool) or not isinstance(crf, int) or not 0 <= crf <= 51:
        raise ValueError(f"{path}: crf must be an integer in 0..51, got {crf!r}")
    it = iter(frames)
    first = _first_frame(next(it, None), path)
    size = first.shape[:2]
    out_h, out_w = even_size(*size)
    try:
        with atomic_output(path, ".mp4") as tmp:  # FFmpeg picks the container from the extension
            writer = imageio_ffmpeg.write_frames(
                str(tmp),
                (out_w, out_h),
                pix_fmt_in="bgr24" if bgr else "rgb24",
                pix_fmt_out=PIXEL_FORMAT,
                fps=fps,
                codec=CODEC,
                quality=None,
                macro_block_size=1,
                ffmpeg_log_level="error",
                output_params=["-crf", str(crf), "-movflags", "+faststart"],
            )
            writer.send(None)  # starts FFmpeg
            try:
                for i, frame in enumerate(itertools.chain([first], it)):
                    frame = _check_frame(frame, i, size, path)
                    writer.send(np.ascontiguousarray(pad_to_even(frame)))
            finally:
                writer.close()  # waits for FFmpeg to finish the file (or stops it after an error)
            if tmp.stat().st_size == 0:  # FFmpeg gave up on the stream but exited 0
                raise RuntimeError("FFmpeg wrote no video")
    except (OSError, RuntimeError) as exc:  # FFmpeg's failures, and fluidsim.files' OutputError around an OSError
        cause = exc.__cause__ if isinstance(exc, OutputError) and exc.__cause__ is not None else exc
        err = OutputError(
            f"cannot write the video {path}: {cause}; check that its folder is writable and has "
            "space, or write PNG frames instead"
        )
        err.errno = getattr(cause, "errno", None)
        raise err from cause
    return path


@dataclass(frozen=True)
class VideoInfo:
    """What a video file holds: codec name (FFmpeg's, e.g. "h264"), pixel format (e.g. "yuv420p"), size [px],
    frame rate [1/s], frame count."""

    codec: str
    pixel_format: str
    width: int
    height: int
    fps: float
    frames: int


def video_info(path: str | os.PathLike) -> VideoInfo:
    """Read the stream header and count the frames of a video file (decodes it once)."""
    import imageio_ffmpeg  # noqa: PLC0415 - loaded only when a video is written or read (~0.1 s)

    path = Path(path)
    reader = imageio_ffmpeg.read_frames(str(path))
    try:
        meta = next(reader)
    finally:
        reader.close()
    n_frames, _ = imageio_ffmpeg.count_frames_and_secs(str(path))
    codec, pixel_format = (str(meta.get(k) or "").split("(")[0].split(" ")[0] for k in ("codec", "pix_fmt"))
    width, height = (int(v) for v in meta["size"])
    return VideoInfo(codec, pixel_format, width, height, float(meta["fps"]), int(n_frames))


def read_mp4(path: str | os.PathLike) -> np.ndarray:
    """All frames of a video as a (K, H, W, 3) uint8 RGB array (for tests and small clips)."""
    import imageio_ffmpeg  # noqa: PLC0415 - loaded only when a video is written or read (~0.1 s)

    reader = imageio_ffmpeg.read_frames(str(path))
    try:
        meta = next(reader)
        w, h = (int(v) for v in meta["size"])
        return np.stack([np.frombuffer(b, np.uint8).reshape(h, w, 3) for b in reader])
    finally:
        reader.close()
