"""The recorded probe the file and export tests read: the -x probe of a filled sphere, frames every 5 steps."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fluidsim import ProbeConfig, SolverConfig
from fluidsim.recording import probe_to_h5
from fluidsim.sources import sphere_particles


def sphere_probe_file(path: Path, steps: int) -> tuple[tuple, np.ndarray, SolverConfig]:
    """Record ``steps`` steps of the -x probe around a filled sphere of radius 0.3 m (r = 0.05 m; a 0.2 m slab,
    margin 0.1 m, padding 0.2 m) into ``path``, a frame every 5 steps. Returns what
    :func:`fluidsim.recording.probe_to_h5` returns, the sphere's particles and the solver config."""
    cfg = SolverConfig(particle_radius=0.05)
    solid = sphere_particles([0, 0, 0], 0.3, cfg.spacing, fill=True)
    probe = ProbeConfig(slab_thickness=0.2, margin=0.1, padding=0.2, directions=("-x",))
    return probe_to_h5(solid, "-x", cfg, probe, steps, path, save_every=5, progress=False), solid, cfg
