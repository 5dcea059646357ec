"""The run's outputs (nbv.outputs): a probe video drawn from the run's own recording when it holds one."""

import math

import numpy as np
import pytest
import torch

from nbv import outputs
from nbv.physics import PhysicsConfig, save_result, simulate_gaussians
from nbv.physics.trajectory import RecordConfig
from recon.gaussians import GaussianSet
from viz.video import video_info

CFG = PhysicsConfig(particle_radius=0.08, steps=10, dt=0.004, directions=("-x",), scale=1.0, empty_reference=False)


def _shell(n: int = 200, radius: float = 0.5) -> GaussianSet:
    i = np.arange(n) + 0.5
    phi, th = np.arccos(1 - 2 * i / n), math.pi * (1 + 5**0.5) * i
    pts = radius * np.stack([np.cos(th) * np.sin(phi), np.sin(th) * np.sin(phi), np.cos(phi)], 1)
    return GaussianSet.from_points(torch.tensor(pts, dtype=torch.float32), scale=0.12, opacity=0.9)


def test_a_recorded_probe_is_drawn_from_its_recording_without_a_second_run(tmp_path, monkeypatch):
    """The demo records -x at the video's spacing: the video is drawn from RESULT.h5 (frames after steps 2, 4, ...),
    and the probe is not run again; at another spacing, or with no saved file, it is."""
    res = simulate_gaussians(_shell(), CFG, progress=False, record=RecordConfig(("-x",), every=2))
    h5 = tmp_path / "result.h5"
    save_result(h5, res)
    reruns = []
    real = outputs.probe_to_h5

    def counted(*args, **kwargs):
        reruns.append(args[1])
        return real(*args, **kwargs)

    monkeypatch.setattr(outputs, "probe_to_h5", counted)
    out = outputs.probe_video(res, "-x", tmp_path / "a.mp4", every=2, progress=False, saved=h5)
    assert reruns == [] and video_info(out).frames == CFG.steps // 2
    outputs.probe_video(res, "-x", tmp_path / "b.mp4", every=5, progress=False, saved=h5)
    outputs.probe_video(res, "-x", tmp_path / "c.mp4", every=2, progress=False)
    assert reruns == ["-x", "-x"] and video_info(tmp_path / "c.mp4").frames == CFG.steps // 2 + 1


def test_an_unknown_probe_names_the_option(tmp_path):
    with pytest.raises(ValueError, match="--video: unknown probe"):
        outputs.probe_video(None, "+w", tmp_path / "v.mp4")
