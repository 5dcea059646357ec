"""The planner registry: the method names of every command, and the factory that builds a planner by name.

The names are those of :data:`nbv.plan.rules.PLANNER_NAMES`: the planners that score views on their own, and the
fused rules of :data:`nbv.plan.rules.FUSED_RULES`, all run by :class:`nbv.plan.fused.FusedPlanner`.
"""

from __future__ import annotations

from fluidsim.config import check_known_keys
from nbv.plan.base import Planner
from nbv.plan.fisher import FisherPlanner
from nbv.plan.fused import VISUAL_TYPES, FusedPlanner
from nbv.plan.fvs import FVSPlanner
from nbv.plan.physics import PhysicsPlanner
from nbv.plan.random import RandomPlanner
from nbv.plan.rules import FUSED, PLANNER_NAMES, FusedRule
from nbv.plan.variance import VariancePlanner

# name -> the planner class, or the fused rule that FusedPlanner runs
PLANNERS: dict[str, type | FusedRule] = {
    "random": RandomPlanner,
    "fisher": FisherPlanner,
    "variance": VariancePlanner,
    "physics": PhysicsPlanner,
    "fvs": FVSPlanner,
    **FUSED,
}
if tuple(PLANNERS) != PLANNER_NAMES:
    raise RuntimeError(f"nbv.plan.registry lists {tuple(PLANNERS)}, nbv.plan.rules {PLANNER_NAMES}")


def _entry(name: str) -> type | FusedRule:
    if name not in PLANNERS:
        raise ValueError(f"unknown planner {name!r}; choose one of {sorted(PLANNERS)}")
    return PLANNERS[name]


def config_type(name: str) -> type:
    """The config dataclass of the registered planner ``name`` (a fused planner takes its visual planner's)."""
    entry = _entry(name)
    return VISUAL_TYPES[entry.visual].config_type if isinstance(entry, FusedRule) else entry.config_type


def uses_physics(name: str) -> bool:
    """Whether the registered planner ``name`` runs the probes for its pick (physics, +fluid, +shuffled)."""
    entry = _entry(name)
    return entry.uses_physics if isinstance(entry, FusedRule) else entry is PhysicsPlanner


def reads_empty_scene(name: str) -> bool:
    """Whether the registered planner ``name`` reads the empty-scene probes for its pick (fisher+excess); the others
    never look at them, so a run for their picks can leave the empty scene out."""
    entry = _entry(name)
    return isinstance(entry, FusedRule) and entry.reads_empty_scene


def make_planner(name: str, **overrides) -> Planner:
    """Build a registered planner from its config dataclass with ``overrides`` (e.g. ``seed=3``).

    Args:
        name: a key of :data:`PLANNERS`.
        overrides: fields of the planner's config (``RandomConfig``, ``FisherConfig``, ``VarianceConfig``,
            ``PhysicsPlannerConfig``; the fused planners take their visual planner's config).
    Returns:
        the planner.

    Example:
        >>> make_planner("fisher+fluid", seed=1).name
        'fisher+fluid'
    """
    entry, cfg_type = _entry(name), config_type(name)
    check_known_keys(cfg_type, overrides, f"planner {name!r}: ")
    config = cfg_type(**overrides)
    return FusedPlanner(entry, config) if isinstance(entry, FusedRule) else entry(config)
