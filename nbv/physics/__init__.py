"""Probe runs on 3D Gaussians and D_g (paper Sec. 3.2-3.3): config, solid, run, memory, result I/O, aggregation.
"""

from .config import ESTIMATOR_RADII, QUICK, PhysicsConfig, kept_gaussians, parse_directions, scene_transform
from .memory import (
    BYTES_PER_BOUNDARY,
    BYTES_PER_FLUID,
    BYTES_PER_GAUSSIAN_PROBE,
    BYTES_PER_GAUSSIAN_RUN,
    BYTES_PER_LATTICE_POINT,
    check_memory,
    estimate_memory,
    memory_limit_bytes,
)
from .result import PhysicsResult, ProbeDiverged, check_result_matches, gaussians_sha256, load_result, save_result
from .run import (
    RETIRED_WARNING_FRACTION,
    check_probe_time_steps,
    empty_scene_probes,
    expand_to_all,
    probe_domains_union,
    probe_warnings,
    simulate_gaussians,
)

__all__ = [
    "BYTES_PER_BOUNDARY", "BYTES_PER_FLUID", "BYTES_PER_GAUSSIAN_PROBE", "BYTES_PER_GAUSSIAN_RUN",
    "BYTES_PER_LATTICE_POINT", "ESTIMATOR_RADII", "PhysicsConfig", "PhysicsResult", "ProbeDiverged", "QUICK",
    "RETIRED_WARNING_FRACTION", "check_memory", "check_probe_time_steps", "check_result_matches",
    "empty_scene_probes", "estimate_memory", "expand_to_all", "gaussians_sha256", "kept_gaussians",
    "load_result", "memory_limit_bytes", "parse_directions", "probe_domains_union", "probe_warnings",
    "save_result", "scene_transform", "simulate_gaussians",
]
