"""Render the frames of a simulation output file (``OUT.h5``) to PNG images or an MP4 video.

No paper equations are implemented here; this is a viewer for the file the fluid simulation writes:

- ``/frames/<k>/x`` (N_k, 3) particle positions [m, Y-up], ``/frames/<k>/v`` (N_k, 3) velocities [m/s],
  ``/frames/<k>/divergence`` (N_k,) per-particle |div v| [1/s]; each frame group carries the
  attributes ``time`` [s] and ``step``. Keys ``<k>`` are decimal strings, sorted numerically.
- optional ``/boundary/x`` (M, 3) static boundary particles: the solid (inside the domain box) and the walls
  (outside it, :func:`fluidsim.sources.wall_particles`); at most 400,000 solid and 50,000 wall particles are
  drawn (a uniform random subset beyond that, logged).
- root attribute ``scene``: the scene JSON; its ``domain.min`` / ``domain.max`` give the domain box. Without a
  usable domain every boundary particle counts as solid and the box is fitted to the particles.

Drawing model. Each view is an orthographic camera given by an orthonormal basis (right, up, forward):
screen coordinates are (p . right, p . up) and the depth is p . forward, larger meaning farther.

====== ================ ======== =========== ==========================================
view   forward (looks)  right    up          note
====== ================ ======== =========== ==========================================
front  -z               +x       +y          camera on the +z side
side   +x               +z       +y          camera on the -x side (not mirrored)
top    -y               +x       -z          camera above; +z points down the image
iso    -(1,1,1)/sqrt3   (1,0,-1) (-1,2,-1)   camera at the (+x,+y,+z) corner, normalised
====== ================ ======== =========== ==========================================

The camera box (:func:`camera_box`: with ``frame="object"``, the default, the solid's bounding box with a margin,
so that the object fills the picture; otherwise the domain box, whose edges are then drawn) is fitted into the
scene viewport (the frame minus a header line and a colour-bar panel, :func:`scene_viewport`) keeping the aspect
ratio. Dots are splatted with a z-buffer: the nearest particle wins each pixel. The solid and the fluid share one
z-buffer, so the object hides the fluid behind it and fluid in front of it shows. The solid is drawn in ivory
(:func:`solid_colors`), which no colour of the TURBO map comes near; the walls (``FrameStyle.walls``, hidden by
default) in grey behind everything. Fluid is coloured with the TURBO colormap on a fixed scale [0, vmax] shared
by all frames; values above vmax take the top colour.

Output: an ``.mp4`` (H.264 in yuv420p with the index at the front, which web browsers play;
:func:`viz.video.write_mp4`) or a folder of PNG frames, every file written atomically (:mod:`fluidsim.files`).
This module never imports Taichi or torch; the command line is ``fluidgs render-frames`` (:mod:`apps.render_frames`).

Example:
    >>> from viz.frames import FrameStyle, render_frames
    >>> render_frames("out/demo/OUT.h5", "out/demo/frames.mp4", FrameStyle(view="iso"))  # doctest: +SKIP
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import h5py
import numpy as np
from tqdm import tqdm

from fluidsim.files import atomic_files, check_writable, write_bytes_atomic

from .colors import TURBO_BGR
from .frame_source import FrameSource, box_corners, check_domain, check_frames_file
from .frame_style import COLOR_BY, VIEWS, FrameStyle
from .video import check_encoder, write_mp4

logger = logging.getLogger(__name__)

OBJECT_MARGIN = 0.35  # the object's box grows by this fraction of its largest extent on every side
MAX_SOLID_RADIUS = 24  # px

_ISO = np.array([[1.0, 0.0, -1.0], [-1.0, 2.0, -1.0], [-1.0, -1.0, -1.0]])
# rows: right, up, forward (viewing direction); right x up = -forward, so no view is mirrored.
_VIEW_BASES = {
    "front": np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]]),
    "side": np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]),
    "top": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, -1.0, 0.0]]),
    "iso": _ISO / np.linalg.norm(_ISO, axis=1, keepdims=True),
}
_BOX_EDGES = [(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1]

_BACKGROUND = (28, 28, 28)  # BGR
_BOX_COLOR = (200, 200, 200)
_TEXT_COLOR = (240, 240, 240)
_BOUNDARY_GREY_NEAR, _BOUNDARY_GREY_FAR = 170, 80
_FAINT_GREY_NEAR, _FAINT_GREY_FAR = 58, 42  # faint walls: just above the background
SOLID_BGR = np.array([200, 228, 240], dtype=np.float64)  # ivory; the far side of the object is drawn at 45 %
_SOLID_FAR = 0.45
_FONT = cv2.FONT_HERSHEY_SIMPLEX
_COLORMAP_LUT = TURBO_BGR  # (256, 3) uint8 BGR
DEFAULT_STYLE = FrameStyle()  # frozen: one default for every call


def view_basis(view: str) -> np.ndarray:
    """Orthonormal camera basis of a named view.

    Returns:
        (3, 3) float64 array whose rows are right, up and forward (the viewing direction).
    """
    if view not in _VIEW_BASES:
        raise ValueError(f"view={view!r} is unknown; use one of {list(VIEWS)}")
    return _VIEW_BASES[view].copy()


def default_margin(width: int, height: int) -> int:
    """Margin [px] kept between the fitted domain box and the edge of the canvas."""
    return max(2, round(0.04 * min(width, height)))


def project(
    points: np.ndarray,
    domain_min,
    domain_max,
    view: str,
    width: int,
    height: int,
    margin: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Orthographic projection of world points into a width x height canvas fitted to the domain box.

    The box's projected bounding rectangle is scaled uniformly (aspect ratio kept) so that it spans
    pixel centres ``margin`` .. ``width - 1 - margin`` along its limiting axis and is centred along
    the other. Image rows grow downwards. Points outside the box may land outside the canvas; nothing
    is clipped here.

    Args:
        points: (N, 3) finite world positions [m].
        domain_min, domain_max: (3,) corners of the domain box [m], min < max on every axis.
        view: "front", "side", "top" or "iso".
        width, height: canvas size [px].
        margin: [px]; None uses :func:`default_margin`.

    Returns:
        uv: (N, 2) int64 pixel coordinates (column, row), rounded to the nearest pixel centre.
        depth: (N,) float64 distance along the viewing direction [m]; larger is farther.

    Example:
        >>> uv, depth = project(np.array([[0.0, 0.0, 0.0]]), [0, 0, 0], [4, 3, 1], "front", 421, 321, 10)
        >>> uv.tolist(), depth.tolist()
        ([[10, 310]], [-0.0])
    """
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {points.shape}")
    if not np.isfinite(points).all():
        raise ValueError("points contain NaN or inf; drop them before projecting")
    lo, hi = check_domain(domain_min, domain_max)
    basis = view_basis(view)
    margin = default_margin(width, height) if margin is None else margin
    avail_w, avail_h = width - 1 - 2 * margin, height - 1 - 2 * margin
    if avail_w <= 0 or avail_h <= 0:
        raise ValueError(f"canvas {width}x{height} px leaves no room inside a margin of {margin} px")

    corners = box_corners(lo, hi) @ basis[:2].T  # (8, 2) screen coordinates [m]
    c_lo, c_hi = corners.min(axis=0), corners.max(axis=0)
    scale = min(avail_w / (c_hi[0] - c_lo[0]), avail_h / (c_hi[1] - c_lo[1]))  # [px/m]
    mid = 0.5 * (c_lo + c_hi)

    screen = points @ basis[:2].T
    u = 0.5 * (width - 1) + scale * (screen[:, 0] - mid[0])
    v = 0.5 * (height - 1) - scale * (screen[:, 1] - mid[1])
    uv = np.rint(np.stack([u, v], axis=1)).astype(np.int64)
    return uv, points @ basis[2]


def scene_viewport(width: int, height: int) -> tuple[int, int, int, int]:
    """Where the scene is drawn inside a frame, below the header line and left of the colour bar.

    A rendered particle at world position p lands at ``project(p, ..., w, h)[0] + (x0, y0)``.

    Returns:
        (x0, y0, w, h) in pixels.
    """
    return _Layout.of(width, height).viewport


def render_frames(
    h5_path, out, style: FrameStyle = DEFAULT_STYLE, progress: bool = True, png: bool = False, probe: str | None = None
) -> list[Path]:
    """Render every frame of a simulation output file.

    All inputs are checked (file, frame groups, dataset shapes, output location, video encoder)
    before the first frame is drawn.

    Args:
        h5_path: simulation output file (``OUT.h5``), or a RESULT.h5 with a recorded probe (``--record-probe``).
        out: an ``.mp4`` video, or a directory that receives ``frame_000000.png``, ``frame_000001.png``, ... in
            frame order; :func:`output_is_video` tells which (any other suffix is an error).
        style: drawing options.
        progress: show a tqdm progress bar on stderr.
        png: write PNG frames into the directory ``out`` whatever its name (a folder named ``run.v2``).
        probe: the recorded probe of a RESULT.h5 to draw (None: the first recorded).

    Returns:
        The written paths: ``[video]`` or the PNGs in frame order.

    Raises:
        FileNotFoundError, ValueError: unreadable or malformed input, unsupported options.
        OSError: the output cannot be written.

    Example:
        >>> render_frames("OUT.h5", "frames/", FrameStyle(color_by="speed"))  # doctest: +SKIP
    """
    if not isinstance(style, FrameStyle):
        raise ValueError(f"style must be a FrameStyle, got {type(style).__name__}")
    h5_path, out = Path(h5_path), Path(out)
    is_video = output_is_video(out, png)
    check_frames_file(h5_path)
    with h5py.File(h5_path, "r") as f:
        from recon.inflate import check_hdf5_sizes  # noqa: PLC0415 - standard library and h5py only

        check_hdf5_sizes(f, str(h5_path))
        source = FrameSource.inspect(f, h5_path, style, probe)
        _prepare_output(out, is_video)
        vmax = style.vmax if style.vmax is not None else source.percentile_vmax()
        logger.info(
            "rendering %d frames of %s (%s, view %s, vmax %.4g %s) to %s",
            len(source.keys),
            h5_path,
            style.color_by,
            style.view,
            vmax,
            COLOR_BY[style.color_by][2],
            out,
        )
        renderer = _Renderer(source, style, vmax)
        frames = tqdm(renderer.frames(), total=len(source.keys), desc="render", unit="frame", disable=not progress)
        paths = [write_mp4(frames, out, style.fps, bgr=True)] if is_video else _write_pngs(frames, out)
        if source.dropped:
            logger.warning("%s: skipped %d particle positions that were NaN or inf", h5_path, source.dropped)
    return paths


def output_is_video(out: Path, png: bool = False) -> bool:
    """What ``-o`` asks for: True for an MP4 video (a path ending in .mp4), False for a directory of PNG frames
    (a path without a suffix, an existing directory, or ``png``).

    Raises:
        ValueError: any other suffix (.avi, .gif, .png, ...: only MP4 video is written, and silently making a
            directory named ``x.avi`` is not what was asked), or ``png`` with a path ending in .mp4.
    """
    out = Path(out)
    suffix = out.suffix.lower()
    if png:
        if suffix == ".mp4":
            raise ValueError(
                f"-o {out} ends in .mp4 but --png asks for a directory of PNG frames; drop --png for a "
                "video, or give a directory path"
            )
        return False
    if suffix == ".mp4":
        return True
    if not suffix or out.is_dir():
        return False
    raise ValueError(
        f"-o {out}: render-frames writes an MP4 video (a path ending in .mp4) or a directory of PNG "
        f"frames (a path without a suffix), not {out.suffix!r}; use -o {out.with_suffix('.mp4')} for "
        f"a video, or add --png to write the frames into the directory {out}"
    )


# ---------------------------------------------------------------------------------------------------
# Output


def _prepare_output(out: Path, is_video: bool) -> None:
    if is_video:
        check_encoder(out)
        if out.is_dir():
            raise ValueError(
                f"{out} is a directory; pass a file name ending in .mp4, or a directory path "
                "without the .mp4 suffix for PNG frames"
            )
    elif out.exists() and not out.is_dir():
        raise ValueError(
            f"{out} exists and is not a directory; PNG frames need a directory "
            "(or give a path ending in .mp4 for a video)"
        )
    check_writable(out if is_video else out / "frame_000000.png")  # creates the folders, tries a file: exit 4
    if not is_video and (stale := len(list(out.glob("frame_*.png")))):
        logger.warning("%s already holds %d frame_*.png files; those beyond this render stay as they are", out, stale)


def _write_pngs(frames: Iterator[np.ndarray], directory: Path) -> list[Path]:
    """The frames as ``directory/frame_NNNNNN.png``, moved in together once all are drawn (a render stopped midway
    leaves the frames of an earlier render as they were)."""
    names = []
    with atomic_files(directory) as tmp:
        for i, image in enumerate(frames):
            ok, data = cv2.imencode(".png", image)
            if not ok:
                raise OSError(f"OpenCV failed to encode frame {i} as PNG for {directory}")
            names.append(f"frame_{i:06d}.png")
            write_bytes_atomic(tmp / names[-1], data.tobytes())
    return [directory / name for name in names]


# ---------------------------------------------------------------------------------------------------
# Drawing


@dataclass(frozen=True)
class _Layout:
    """Pixel layout of a frame: header line on top, colour-bar panel on the right, scene elsewhere."""

    width: int
    height: int
    font_scale: float
    thickness: int
    text_h: int  # cap height of a text line [px]; putText places the baseline
    line_h: int  # text line pitch [px]
    pad: int
    header_h: int
    panel_w: int
    bar_w: int

    @staticmethod
    def of(width: int, height: int) -> _Layout:
        size = min(width / 960.0, height / 720.0)
        font_scale = max(0.35, 0.55 * size)
        thickness = 1 if size < 1.5 else 2
        (_, text_h), baseline = cv2.getTextSize("Ag", _FONT, font_scale, thickness)
        pad = max(3, round(8 * size))
        bar_w = max(8, round(16 * size))
        # widest labels the panel holds, independent of the data so that the viewport is fixed
        titles = [title for _, title, _ in COLOR_BY.values()]
        widest = max(cv2.getTextSize(s, _FONT, font_scale, thickness)[0][0] for s in ["-8.88e+88", *titles])
        panel_w = bar_w + widest + 3 * pad
        line_h = text_h + baseline + pad
        header_h = line_h + pad
        return _Layout(width, height, font_scale, thickness, text_h, line_h, pad, header_h, panel_w, bar_w)

    @property
    def viewport(self) -> tuple[int, int, int, int]:
        return 0, self.header_h, self.width - self.panel_w, self.height - self.header_h

    def put_text(self, image: np.ndarray, text: str, x: int, y_centre: int) -> None:
        cv2.putText(
            image,
            text,
            (x, y_centre + self.text_h // 2),
            _FONT,
            self.font_scale,
            _TEXT_COLOR,
            self.thickness,
            cv2.LINE_AA,
        )


class _Renderer:
    """Draws frames of one source with one style; the static layer (box, boundary) is drawn once."""

    def __init__(self, source: FrameSource, style: FrameStyle, vmax: float) -> None:
        self.source, self.style, self.vmax = source, style, vmax
        self.layout = _Layout.of(style.width, style.height)
        x0, y0, *self.viewport_size = self.layout.viewport
        self.offset = np.array([x0, y0], dtype=np.int64)
        solid = source.boundary if source.boundary is not None else np.zeros((0, 3))
        self.lo, self.hi = camera_box(solid, source.domain_min, source.domain_max, style.frame)
        self.draw_box = style.frame == "domain" or not len(solid)
        corner_uv, self.corner_depth = self._project(box_corners(source.domain_min, source.domain_max))
        self.corner_uv = [tuple(map(int, uv)) for uv in corner_uv]  # cv2 takes points as int tuples
        self.solid_uv, self.solid_depth = self._project(solid)
        ends, _ = self._project(np.stack([np.zeros(3), view_basis(style.view)[0]]))  # 1 m along the screen's x
        pixels_per_metre = float(np.linalg.norm(ends[1] - ends[0]))
        self.solid_radius = solid_radius(source.spacing(solid), pixels_per_metre, style.point_size)
        shape = (style.height, style.width)
        self.solid_zbuffer = depth_buffer(self.solid_uv, self.solid_depth, self.solid_radius, shape)
        self.background = self._static_layer()

    def _project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        uv, depth = project(points, self.lo, self.hi, self.style.view, *self.viewport_size)
        return uv + self.offset, depth

    def _box_edges(self, image: np.ndarray, front: bool) -> None:
        if not self.draw_box:
            return
        # an edge is in front when its midpoint is nearer than the box centre
        centre = float(self.corner_depth.mean())
        for a, b in _BOX_EDGES:
            if (0.5 * (self.corner_depth[a] + self.corner_depth[b]) < centre - 1e-12) == front:
                cv2.line(image, self.corner_uv[a], self.corner_uv[b], _BOX_COLOR, 1, cv2.LINE_AA)

    def _static_layer(self) -> np.ndarray:
        image = np.full((self.style.height, self.style.width, 3), _BACKGROUND, dtype=np.uint8)
        self._box_edges(image, front=False)
        walls = self.source.walls
        if walls is not None and len(walls) and self.style.walls != "hidden":
            uv, depth = self._project(walls)
            near, far = float(self.corner_depth.min()), float(self.corner_depth.max())
            t = np.clip((depth - near) / max(far - near, 1e-12), 0.0, 1.0)
            g_near, g_far = (
                (_FAINT_GREY_NEAR, _FAINT_GREY_FAR)
                if self.style.walls == "faint"
                else (_BOUNDARY_GREY_NEAR, _BOUNDARY_GREY_FAR)
            )
            grey = np.rint(g_near + t * (g_far - g_near)).astype(np.uint8)
            splat(image, uv, depth, np.repeat(grey[:, None], 3, axis=1), self.style.point_size)
        if len(self.solid_uv):
            splat(image, self.solid_uv, self.solid_depth, solid_colors(self.solid_depth), self.solid_radius)
        return image

    def frames(self) -> Iterator[np.ndarray]:
        return map(self.draw, range(len(self.source.keys)))

    def draw(self, i: int) -> np.ndarray:
        x, values, time, step = self.source.frame(i)
        image = self.background.copy()
        uv, depth = self._project(x)
        # the object hides the fluid behind it: a particle whose centre pixel lies behind the solid is not drawn
        h, w = self.solid_zbuffer.shape
        on = (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
        seen = ~on
        seen[on] = depth[on] <= self.solid_zbuffer[uv[on, 1], uv[on, 0]]
        splat(image, uv[seen], depth[seen], colorize(values[seen], self.vmax), self.style.point_size)
        self._box_edges(image, front=True)
        lay = self.layout
        image[: lay.header_h] = _BACKGROUND
        header = f"t = {time:.4f} s   step {step}   {len(x):,} fluid particles   frame {i + 1}/{len(self.source.keys)}"
        lay.put_text(image, header, lay.pad, lay.header_h // 2)
        self._colorbar(image)
        return image

    def _colorbar(self, image: np.ndarray) -> None:
        lay = self.layout
        _, title, unit = COLOR_BY[self.style.color_by]
        x0 = lay.width - lay.panel_w
        image[lay.header_h :, x0:] = _BACKGROUND
        x = x0 + lay.pad
        y = lay.header_h + lay.line_h // 2
        lay.put_text(image, title, x, y)
        lay.put_text(image, f"({unit})", x, y + lay.line_h)
        top = lay.header_h + 2 * lay.line_h + lay.pad
        bottom = lay.height - 1 - lay.line_h
        if bottom - top < 8:
            return
        rows = np.linspace(255, 0, bottom - top + 1).round().astype(np.intp)
        image[top : bottom + 1, x : x + lay.bar_w] = _COLORMAP_LUT[rows][:, None, :]
        cv2.rectangle(image, (x - 1, top - 1), (x + lay.bar_w, bottom + 1), _BOX_COLOR, 1)
        for label, y in ((f"{self.vmax:.3g}", top), (f"{0.5 * self.vmax:.3g}", (top + bottom) // 2), ("0", bottom)):
            lay.put_text(image, label, x + lay.bar_w + lay.pad, y)


def camera_box(solid: np.ndarray, domain_min, domain_max, frame: str = "object") -> tuple[np.ndarray, np.ndarray]:
    """The box the camera is fitted to: with ``frame="object"`` and a solid, the solid's bounding box grown by
    ``OBJECT_MARGIN`` of its largest extent on every side; otherwise the domain box.

    Args:
        solid: (M, 3) solid particles [m] (may be empty). domain_min, domain_max: (3,) the domain box [m].
        frame: "object" or "domain".
    Returns:
        (lo, hi), each (3,) float64 [m].
    """
    lo, hi = check_domain(domain_min, domain_max)
    solid = np.asarray(solid, dtype=np.float64).reshape(-1, 3)
    if frame == "domain" or not len(solid):
        return lo, hi
    s_lo, s_hi = solid.min(axis=0), solid.max(axis=0)
    grow = OBJECT_MARGIN * max(float((s_hi - s_lo).max()), 1e-6)
    return s_lo - grow, s_hi + grow


def solid_radius(spacing: float | None, pixels_per_metre: float, point_size: int) -> int:
    """Dot radius [px] of the solid particles: large enough that the dots of a lattice of ``spacing`` [m] close up
    into a surface (r + 1/2 >= the half-diagonal of a lattice cell on screen), never below ``point_size``, at most
    ``MAX_SOLID_RADIUS``; ``point_size`` when the spacing is unknown."""
    if spacing is None or not spacing > 0:
        return point_size
    d = spacing * pixels_per_metre
    return int(min(max(point_size, math.ceil(d / math.sqrt(2.0) - 0.5)), MAX_SOLID_RADIUS))


def depth_buffer(uv: np.ndarray, depth: np.ndarray, radius: int, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) float64: the smallest depth of the disks (:func:`disk_offsets`) covering each pixel; inf elsewhere."""
    h, w = shape
    zbuf = np.full(h * w, np.inf)
    for dx, dy in disk_offsets(radius).tolist():
        u, v = uv[:, 0] + dx, uv[:, 1] + dy
        ok = (u >= 0) & (u < w) & (v >= 0) & (v < h)
        np.minimum.at(zbuf, v[ok] * w + u[ok], depth[ok])
    return zbuf.reshape(h, w)


def solid_colors(depth: np.ndarray) -> np.ndarray:
    """(M, 3) uint8 BGR colours of the solid: ivory ``SOLID_BGR`` at its nearest point, ``_SOLID_FAR`` of it at its
    farthest, linear in depth between, so that the object's shape reads in the picture."""
    depth = np.asarray(depth, dtype=np.float64)
    if not len(depth):
        return np.zeros((0, 3), np.uint8)
    near, far = float(depth.min()), float(depth.max())
    t = (depth - near) / max(far - near, 1e-12)
    shade = 1.0 - (1.0 - _SOLID_FAR) * t
    return np.rint(SOLID_BGR[None, :] * shade[:, None]).astype(np.uint8)


def colorize(values: np.ndarray, vmax: float) -> np.ndarray:
    """TURBO colours for values on the scale [0, vmax]; above vmax (and NaN) takes the top colour.

    Args:
        values: (N,) non-negative values.
        vmax: top of the scale, > 0.

    Returns:
        (N, 3) uint8 BGR colours.
    """
    scaled = np.nan_to_num(np.asarray(values, dtype=np.float64) / vmax, nan=1.0, posinf=1.0, neginf=0.0)
    return _COLORMAP_LUT[np.rint(np.clip(scaled, 0.0, 1.0) * 255).astype(np.intp)]


def disk_offsets(radius: int) -> np.ndarray:
    """(K, 2) integer (dx, dy) pixel offsets of a dot of the given radius [px]: dx^2 + dy^2 <= (r + 1/2)^2."""
    dy, dx = np.mgrid[-radius : radius + 1, -radius : radius + 1]
    inside = dx * dx + dy * dy <= (radius + 0.5) ** 2
    return np.stack([dx[inside], dy[inside]], axis=1)


def splat(image: np.ndarray, uv: np.ndarray, depth: np.ndarray, colors: np.ndarray, radius: int) -> np.ndarray:
    """Draw one disk per point into ``image`` in place; at every pixel the nearest point wins.

    Equal to painting disks far to near (stable in the input order for equal depths), but vectorised:
    points sharing a centre pixel have identical disks, so only the nearest of them is kept, after which
    the centres are distinct and each of the K stencil offsets is one duplicate-free scatter of ranks
    into a z-buffer. About 30 ms for 60k points of radius 2 on a 960x720 image (one CPU core).

    Args:
        image: (H, W, 3) uint8 canvas.
        uv: (N, 2) int pixel coordinates (column, row); disks partly outside the image are clipped.
        depth: (N,) distance along the viewing direction; larger is farther.
        colors: (N, 3) uint8 colours.
        radius: dot radius [px], see :func:`disk_offsets`.

    Returns:
        ``image``.
    """
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3 or not image.flags.c_contiguous:
        raise ValueError(f"splat needs a C-contiguous (H, W, 3) uint8 image, got {image.shape} {image.dtype}")
    h, w = image.shape[:2]
    n = len(uv)
    if uv.shape != (n, 2) or depth.shape != (n,) or colors.shape != (n, 3):
        raise ValueError(
            f"splat needs uv (N, 2), depth (N,), colors (N, 3); got {uv.shape}, {depth.shape}, {colors.shape}"
        )
    if n == 0:
        return image
    r = radius
    # z-buffer padded by 2r: a centre up to r outside the image still reaches it, and its whole disk
    # stays inside the buffer, so flat offsets never wrap into the neighbouring row
    wp, hp = w + 4 * r, h + 4 * r
    order = np.argsort(-depth, kind="stable")  # far to near: rank grows towards the camera
    x, y = uv[order, 0] + 2 * r, uv[order, 1] + 2 * r
    ok = (x >= r) & (x < wp - r) & (y >= r) & (y < hp - r)
    rank = np.flatnonzero(ok)
    centre = y[ok] * wp + x[ok]
    # nearest point per centre pixel: first occurrence in the near-to-far (reversed) order
    _, first = np.unique(centre[::-1], return_index=True)
    keep = len(centre) - 1 - first
    centre, rank = centre[keep], rank[keep]

    zbuffer = np.full(hp * wp, -1, dtype=np.int64)
    for dx, dy in disk_offsets(r).tolist():
        idx = centre + (dy * wp + dx)
        zbuffer[idx] = np.maximum(zbuffer[idx], rank)
    winner = zbuffer.reshape(hp, wp)[2 * r : 2 * r + h, 2 * r : 2 * r + w].reshape(-1)
    hit = winner >= 0
    image.reshape(-1, 3)[hit] = colors[order][winner[hit]]
    return image
