"""The planner registry: the method names of every command, and the factory that builds a planner by name."""

from __future__ import annotations

from dataclasses import fields

from nbv.plan.base import Planner
from nbv.plan.fisher import FisherPlanner
from nbv.plan.fused import (
    FisherAreaOccPlanner,
    FisherAreaPlanner,
    FisherBalancedOccPlanner,
    FisherBalancedPlanner,
    FisherExcessPlanner,
    FisherFluidOccPlanner,
    FisherFluidPlanner,
    FisherPerProbePlanner,
    FisherShuffledPlanner,
    RandomAreaPlanner,
    RandomFluidPlanner,
    RandomShuffledPlanner,
    VarianceAreaPlanner,
    VarianceFluidPlanner,
    VarianceShuffledPlanner,
    _FusedPlanner,
)
from nbv.plan.fvs import FVSPlanner
from nbv.plan.physics import PhysicsPlanner
from nbv.plan.random import RandomPlanner
from nbv.plan.variance import VariancePlanner

PLANNERS: dict[str, type] = {
    "random": RandomPlanner,
    "random+fluid": RandomFluidPlanner,
    "fisher": FisherPlanner,
    "variance": VariancePlanner,
    "physics": PhysicsPlanner,
    "fisher+fluid": FisherFluidPlanner,
    "variance+fluid": VarianceFluidPlanner,
    "fisher+area": FisherAreaPlanner,
    "fisher+shuffled": FisherShuffledPlanner,
    "variance+area": VarianceAreaPlanner,
    "variance+shuffled": VarianceShuffledPlanner,
    "random+area": RandomAreaPlanner,
    "random+shuffled": RandomShuffledPlanner,
    "fisher+fluid-occ": FisherFluidOccPlanner,
    "fisher+area-occ": FisherAreaOccPlanner,
    "fisher+excess": FisherExcessPlanner,
    "fisher+perprobe": FisherPerProbePlanner,
    "fisher+balanced": FisherBalancedPlanner,
    "fisher+balanced-occ": FisherBalancedOccPlanner,
    "fvs": FVSPlanner,
}



def uses_physics(name: str) -> bool:
    """Whether the registered planner ``name`` runs the probes for its pick (physics, +fluid, +shuffled)."""
    if name not in PLANNERS:
        raise ValueError(f"unknown planner {name!r}; choose one of {sorted(PLANNERS)}")
    cls = PLANNERS[name]
    return cls is PhysicsPlanner or (issubclass(cls, _FusedPlanner) and cls.control != "area")



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
    if name not in PLANNERS:
        raise ValueError(f"unknown planner {name!r}; choose one of {sorted(PLANNERS)}")
    cls = PLANNERS[name]
    known = {f.name for f in fields(cls.config_type)}
    unknown = sorted(set(overrides) - known)
    if unknown:
        raise ValueError(f"planner {name!r}: unknown config fields {unknown}; "
                         f"{cls.config_type.__name__} has {sorted(known)}")
    return cls(cls.config_type(**overrides))
