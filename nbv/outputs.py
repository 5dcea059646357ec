"""What a probe run (:class:`nbv.physics.PhysicsResult`) is written as beside RESULT.h5: a JSON-able summary, the
Gaussians coloured by D_g (a 3DGS .ply that opens in common viewers, with D_g as extra vertex properties), and an
MP4 of one probe.

The summary's D-bar is in m^4/s and D_g in 1/s (paper Eq. 2-3); the video re-runs one probe of the result
against its solid (the run keeps no particle frames), every step from the first to the last, and draws it
coloured by |div v| (paper Eq. 1), in H.264: the solid in ivory, the walls hidden, the camera on the object
(:mod:`viz.frames`), at a frame rate that makes the clip last about ``VIDEO_SECONDS``.
"""

from __future__ import annotations

import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from fluidsim.directions import DIRECTIONS
from fluidsim.recording import probe_to_h5
from nbv.heatmap import colored_gaussians
from recon.formats.ply import save_gaussians
from viz.frames import FrameStyle, render_frames

__all__ = ["divergence_columns", "probe_video", "result_summary", "save_colored_gaussians"]
VIDEO_STYLE = FrameStyle(view="iso", width=640, height=480)
VIDEO_SECONDS = 8.0
VIDEO_EVERY = 5  # steps between a probe video's frames
VIDEO_FPS = (8, 30)  # the automatic frame rate stays within these


def video_fps(frames: int, seconds: float = VIDEO_SECONDS) -> int:
    """Frames per second that play ``frames`` in about ``seconds``, within VIDEO_FPS."""
    return int(min(max(round(frames / seconds), VIDEO_FPS[0]), VIDEO_FPS[1]))


def result_summary(result) -> dict:
    """A JSON-able summary of a PhysicsResult: counts, scale (m per scene unit), D-bar and its mean-combined and
    empty-scene variants (m^4/s), per probe the mean and max D_g (1/s), the Gaussians reached, the mean solver
    iterations, the retired particles and the leaks, the timings (s) and the config."""
    probes = {}
    for i, d in enumerate(result.directions):
        st = result.stats[d]
        probes[d] = {
            "mean_D": float(result.per_probe[i].mean()),
            "max_D": float(result.per_probe[i].max()),
            "touched_gaussians": int((result.per_probe_counts[i] > 0).sum()),
            "mean_density_iterations": float(np.mean(st["density_iterations"])) if len(st) else 0.0,
            "mean_divergence_iterations": float(np.mean(st["divergence_iterations"])) if len(st) else 0.0,
            "retired": int(np.sum(st["retired"])) if len(st) else 0,
        }
        if d in result.leaks:
            lk = result.leaks[d]
            probes[d]["leaked"] = {"final": lk.final, "max": lk.max, "max_step": lk.max_step}
    return {
        "gaussians": result.num_gaussians,
        "solid_particles": int(len(result.solid)),
        "scale_m_per_unit": float(result.transform.scale),
        "dbar_m4_s": result.dbar,
        "dbar_mean_m4_s": result.dbar_mean,
        "dbar_empty_m4_s": result.dbar_empty,
        "probes": probes,
        "timings_s": result.timings,
        "config": result.config.to_dict(),
    }


def column_name(direction: str) -> str:
    """The .ply property name of one probe's D_g: ``D_neg_x`` for -x, ``D_pos_z`` for +z (PLY readers split
    names on spaces only, but many tools take ``-`` and ``+`` for operators)."""
    return f"D_{'neg' if direction[0] == '-' else 'pos'}_{direction[1:]}"


def divergence_columns(result) -> dict[str, np.ndarray]:
    """Per-Gaussian D_g of a PhysicsResult as .ply vertex properties (1/s): ``D_max`` (the max over the probes, the
    D_g of the paper), ``D_mean``, ``reached`` (1: some probe's fluid reached the Gaussian; 0: its D_g = 0 is
    unmeasured, not calm) and one ``D_neg_x`` ... ``D_pos_z`` per probe, in run order."""
    columns = {
        "D_max": result.divergence,
        "D_mean": result.divergence_mean,
        "reached": result.reached.astype(np.float32),
    }
    for i, d in enumerate(result.directions):
        columns[column_name(d)] = result.per_probe[i]
    return columns


def save_colored_gaussians(
    gaussians,
    divergence: np.ndarray,
    path: str | Path,
    columns: dict[str, np.ndarray] | None = None,
    reached: np.ndarray | None = None,
) -> Path:
    """The Gaussians coloured by D_g [N] (TURBO map, 99th percentile of the reached ones at the top; ``reached`` [N]
    bool: the others grey) as a 3DGS .ply, atomically, with ``columns`` (:func:`divergence_columns`) as extra float
    vertex properties after the standard ones."""
    return save_gaussians(colored_gaussians(gaussians, divergence, reached=reached), path, extra=columns)


def probe_video(
    result,
    direction: str,
    out: str | Path,
    every: int = VIDEO_EVERY,
    progress: bool = True,
    style: FrameStyle = VIDEO_STYLE,
    fps: int | None = None,
    saved: str | Path | None = None,
) -> Path:
    """An H.264 MP4 of probe ``direction`` of ``result``, one frame every ``every`` steps, drawn with ``style``
    (default: iso view, 640 x 480, coloured by divergence, the solid in ivory, the walls hidden, the camera on the
    object) at ``fps`` frames per second (None: :func:`video_fps`, about 8 s). Returns ``out``.

    Where the run recorded that probe every ``every`` steps and ``saved`` is the RESULT.h5 it was saved to, the
    frames are drawn from that recording (after steps k, 2k, ...: the run itself, no second one); otherwise the
    probe is re-run against the solid with the result's settings, every step from 0 to the last.

    Raises:
        ValueError: ``direction`` is not a probe name (naming --video, the option that asks for it).
    """
    if direction not in DIRECTIONS:
        raise ValueError(f"--video: unknown probe {direction!r}; use one of {','.join(DIRECTIONS)}")
    out = Path(out)
    cfg = result.config
    recorded = result.trajectories.get(direction)
    if saved is not None and recorded is not None and recorded.every == every and len(recorded.steps):
        render_frames(saved, out, replace(style, fps=fps or video_fps(len(recorded.steps))), progress, probe=direction)
        return out
    # the steps the probe ran: fewer than cfg.steps when it stopped early (nbv.physics.early_stop)
    steps = len(result.stats[direction]) if direction in result.stats else cfg.steps
    with tempfile.TemporaryDirectory(dir=out.parent) as tmp:
        h5, _, _ = probe_to_h5(
            result.solid,
            direction,
            cfg.solver_config(),
            cfg.probe_config(),
            steps,
            Path(tmp) / "probe.h5",
            every,
            progress=progress,
        )
        frames = steps // every + 1 + (steps % every > 0)
        render_frames(h5, out, replace(style, fps=fps or video_fps(frames)), progress=progress)
    return out
