"""Probe runs on 3D Gaussians and D_g (paper Sec. 3.2-3.3): config, plan, solid, run, memory, result I/O and
aggregation."""

from fluidsim.lazy import lazy_exports

_EXPORTS = {
    **dict.fromkeys(
        ("ESTIMATOR_RADII", "QUICK", "PhysicsConfig", "kept_gaussians", "parse_directions", "scene_transform"), "config"
    ),
    **dict.fromkeys(
        (
            "BYTES_PER_BOUNDARY",
            "BYTES_PER_FLUID",
            "BYTES_PER_GAUSSIAN_PROBE",
            "BYTES_PER_GAUSSIAN_RUN",
            "BYTES_PER_LATTICE_POINT",
            "check_memory",
            "check_memory_bound",
            "estimate_memory",
            "memory_limit_bytes",
        ),
        "memory",
    ),
    **dict.fromkeys(("ProbePlan", "ProbeRunContext", "RunFrame", "expand_to_all", "probe_domains_union"), "plan"),
    "empty_scene_probes": "empty_scene",
    **dict.fromkeys(
        ("PhysicsResult", "ProbeDiverged", "check_result_matches", "gaussians_sha256", "load_result", "save_result"),
        "result",
    ),
    **dict.fromkeys(
        (
            "RETIRED_WARNING_FRACTION",
            "check_probe_time_steps",
            "probe_warnings",
            "simulate_gaussians",
            "simulate_solid",
        ),
        "run",
    ),
}
__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals())
