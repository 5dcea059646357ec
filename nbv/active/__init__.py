"""The active-reconstruction loop: its config and the run (train, plan, add a view, repeat)."""

from fluidsim.lazy import lazy_exports

_EXPORTS = {
    **dict.fromkeys(("CHECKPOINT_VERSION", "MODES", "PRESETS", "RUN_FILES", "ActiveConfig"), "config"),
    **dict.fromkeys(
        (
            "ActiveRun",
            "Reached",
            "RunState",
            "anchor_direction",
            "biased_initial_views",
            "dataset_up",
            "load_active_dataset",
            "planner_seed",
            "run_active",
        ),
        "loop",
    ),
    **dict.fromkeys(("config_differences", "load_checkpoint", "prepare_run_dir"), "run_dir"),
    **dict.fromkeys(("ProbeRun", "is_empty_solid", "probe_run"), "probes"),
    **dict.fromkeys(("PARTS", "round_timing", "run_timing", "timing_line", "visual_name"), "timing"),
}
__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals())
