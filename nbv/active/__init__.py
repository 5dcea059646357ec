"""The active-reconstruction loop: its config and the run (train, plan, add a view, repeat).
"""

import importlib

_EXPORTS = {
    **dict.fromkeys(("CHECKPOINT_VERSION", "MODES", "PRESETS", "RUN_FILES", "ActiveConfig"), "config"),
    **dict.fromkeys(("ActiveRun", "RunState", "anchor_direction", "biased_initial_views", "config_differences",
                     "dataset_up", "is_empty_solid", "load_active_dataset", "planner_seed", "prepare_run_dir",
                     "run_active"), "loop"),
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    """PEP 562: load a re-exported name's module on first use (``nbv.active.config`` alone loads no torch/Taichi)."""
    module = _EXPORTS.get(name)
    if module is None:
        try:  # a submodule reached as an attribute (``nbv.active.loop``) after ``import nbv.active``
            return importlib.import_module(f"{__name__}.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"{__name__}.{name}":
                raise
            raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_EXPORTS})
