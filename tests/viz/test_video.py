"""Tests for viz/video.py: H.264 MP4 that browsers play (codec, pixel format, index at the front), frame count,
pixels close to the input on a smooth frame, odd sizes padded by one edge pixel, and errors that leave no file."""

import numpy as np
import pytest

from viz.video import even_size, pad_to_even, read_mp4, video_info, write_mp4


def _smooth_frames(n: int, h: int, w: int) -> list[np.ndarray]:
    """RGB gradients that move a little each frame (smooth, so a lossy codec keeps them well)."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    return [
        np.stack(
            [40 + 160 * x / w + 2 * k, 30 + 180 * y / h, 120 + 60 * np.sin(x / 25.0 + y / 31.0 + 0.2 * k)], axis=-1
        )
        .round()
        .astype(np.uint8)
        for k in range(n)
    ]


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return float(10 * np.log10(255.0**2 / mse))


def _top_level_boxes(path) -> list[bytes]:
    """The names of the MP4's top-level boxes in file order (size-prefixed: 4-byte size, 4-byte type)."""
    data = path.read_bytes()
    boxes, at = [], 0
    while at + 8 <= len(data):
        size = int.from_bytes(data[at : at + 4], "big")
        boxes.append(data[at + 4 : at + 8])
        if size < 8:
            break
        at += size
    return boxes


def test_h264_yuv420p_faststart_and_close_to_the_input(tmp_path):
    frames = _smooth_frames(12, 120, 160)
    out = tmp_path / "clip.mp4"
    assert write_mp4(iter(frames), out, fps=24) == out
    info = video_info(out)
    assert (info.codec, info.pixel_format, info.width, info.height, info.frames) == ("h264", "yuv420p", 160, 120, 12)
    assert info.fps == pytest.approx(24.0)
    boxes = _top_level_boxes(out)
    assert b"avc1" in out.read_bytes()[:4096]  # the H.264 sample entry, in the index at the front
    assert boxes.index(b"moov") < boxes.index(b"mdat")  # +faststart: browsers start before the download ends
    decoded = read_mp4(out)
    assert decoded.shape == (12, 120, 160, 3)
    for k in range(12):
        assert _psnr(decoded[k], frames[k]) > 30.0, k
    assert [p.name for p in tmp_path.iterdir()] == ["clip.mp4"]  # the temporary file was renamed


def test_bgr_frames_are_swapped_to_rgb(tmp_path):
    red_rgb = np.zeros((64, 64, 3), np.uint8)
    red_rgb[..., 0] = 220
    write_mp4([red_rgb[..., ::-1].copy()], tmp_path / "bgr.mp4", bgr=True)
    r, g, b = read_mp4(tmp_path / "bgr.mp4")[0].reshape(-1, 3).mean(axis=0)
    assert r > 180 and g < 40 and b < 40


def test_odd_frames_are_padded_with_their_edge(tmp_path):
    frame = _smooth_frames(1, 121, 161)[0]
    padded = pad_to_even(frame)
    assert padded.shape == (122, 162, 3) and even_size(121, 161) == (122, 162)
    np.testing.assert_array_equal(padded[:121, :161], frame)
    np.testing.assert_array_equal(padded[:121, 161], frame[:, 160])
    np.testing.assert_array_equal(padded[121, :161], frame[120])
    even = frame[:120, :160]
    assert pad_to_even(even) is even
    write_mp4([frame, frame], tmp_path / "odd.mp4", fps=5)
    info = video_info(tmp_path / "odd.mp4")
    assert (info.width, info.height, info.frames) == (162, 122, 2)
    assert _psnr(read_mp4(tmp_path / "odd.mp4")[0][:121, :161], frame) > 30.0


def test_bad_frames_raise_and_leave_nothing(tmp_path):
    out = tmp_path / "bad.mp4"
    with pytest.raises(ValueError, match="no frames"):
        write_mp4([], out)
    with pytest.raises(ValueError, match=r"frame 0 must be an \(H, W, 3\) uint8"):
        write_mp4([np.zeros((32, 32, 3), np.float32)], out)
    with pytest.raises(ValueError, match="frame 1 is 48x32 px but frame 0 is 32x32 px"):
        write_mp4([np.zeros((32, 32, 3), np.uint8), np.zeros((32, 48, 3), np.uint8)], out)
    with pytest.raises(ValueError, match="fps"):
        write_mp4([np.zeros((32, 32, 3), np.uint8)], out, fps=0)
    with pytest.raises(ValueError, match="crf"):
        write_mp4([np.zeros((32, 32, 3), np.uint8)], out, crf=60)
    assert list(tmp_path.iterdir()) == []


def test_frames_too_large_for_h264_are_refused_and_an_empty_video_is_no_success(tmp_path, monkeypatch):
    """Frames over 16384 px a side made FFmpeg write an empty file and exit 0, so an empty .mp4 was renamed into place
    as a success: they are refused before FFmpeg starts, and a video FFmpeg leaves empty is an error (no file left)."""
    import imageio_ffmpeg

    out = tmp_path / "wide.mp4"
    with pytest.raises(ValueError, match="frames of 16386x16 px; H.264 encodes at most 16384 px a side"):
        write_mp4([np.zeros((16, 16386, 3), np.uint8)], out)

    def silent(path, *args, **kwargs):  # an FFmpeg that opens the file, takes every frame and writes nothing
        open(path, "wb").close()
        while True:
            yield

    monkeypatch.setattr(imageio_ffmpeg, "write_frames", silent)
    with pytest.raises(OSError, match="FFmpeg wrote no video"):
        write_mp4([np.zeros((32, 32, 3), np.uint8)], out)
    assert list(tmp_path.iterdir()) == []


def test_unwritable_folder_is_an_oserror_naming_the_file(tmp_path):
    with pytest.raises(OSError, match="missing.*out.mp4"):
        write_mp4([np.zeros((32, 32, 3), np.uint8)], tmp_path / "missing" / "out.mp4")
