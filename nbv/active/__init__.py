"""The active-reconstruction loop: its config and the run (train, plan, add a view, repeat).
"""

from .config import CHECKPOINT_VERSION, MODES, PRESETS, RUN_FILES, ActiveConfig
from .loop import (
    ActiveRun,
    RunState,
    anchor_direction,
    biased_initial_views,
    config_differences,
    dataset_up,
    is_empty_solid,
    load_active_dataset,
    planner_seed,
    prepare_run_dir,
    run_active,
)

__all__ = [
    "ActiveConfig", "ActiveRun", "CHECKPOINT_VERSION", "MODES", "PRESETS", "RUN_FILES", "RunState",
    "anchor_direction", "biased_initial_views", "config_differences", "dataset_up", "is_empty_solid",
    "load_active_dataset", "planner_seed", "prepare_run_dir", "run_active",
]
