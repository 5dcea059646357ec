"""The active loop's configuration (:class:`ActiveConfig`), its presets and the files of a run folder."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

from fluidsim.config import check_choices, check_known_keys
from nbv.physics.config import PhysicsConfig
from nbv.physics.scene_frame import parse_up
from recon.camera import MAX_IMAGE_SIDE
from recon.train_config import MAX_SEED, TrainConfig

MODES = ("continue", "reset")

CHECKPOINT_VERSION = 1

# Upper bounds of the counts that allocate (a list of rounds, a tuple of initial ids, one job per seed): far above
# any dataset or study, low enough that a mistyped number is refused at once instead of filling the memory.
MAX_VIEWS = 100_000

RUN_FILES = ("config.json", "rounds.json", "checkpoint.pt", "gaussians.ply", "eval.json", "eval.md")

# Presets: defaults of ActiveConfig fields ("train" and "physics" are TrainConfig / PhysicsConfig overrides).
# cpu-small is sized to run a full fisher+fluid loop (8 selections with 5 probes each) on a 64 px, 40-candidate
# dataset within 15 minutes on 2 CPU cores (measured when the preset was sized). It has no opacity resets (neither the
# periodic one nor the white-background one at densify_from_iter, which 0 disables): compressed to 1000 iterations
# they fall every 100 iterations, and a selection right after one sees an almost transparent reconstruction with no
# solid for the probes.
PRESETS: dict[str, dict[str, Any]] = {
    "paper": {
        "resolution": None,
        "total_iterations": 30000,
        "iterations_per_view": 100,
        "occlusion": False,
        "train": {},
        "physics": {},
    },
    "cpu-small": {
        "resolution": 64,
        "total_iterations": 1000,
        "iterations_per_view": 10,
        "train": {
            "init_points": 1000,
            "sh_degree": 1,
            "max_gaussians": 4000,
            "densify_from_iter": 0,
            "opacity_reset_interval": 1000000,
        },
        "physics": {"particle_radius": 0.05, "steps": 150, "empty_reference": False},
    },
}


@dataclass(frozen=True)
class ActiveConfig:
    """Settings of one active-reconstruction run.

    Attributes:
        method: planner name (a key of ``nbv.plan.PLANNERS``, e.g. "random", "fisher", "fisher+fluid").
        budget: view budget B, views (the paper: 10).
        initial_count: number of biased initial views.
        initial_ids: explicit initial candidate indices (train split); overrides the biased rule.
        initial_direction: anchor direction (x, y, z) of the biased rule; None: a unit vector drawn from ``seed``.
        mode: "continue" or "reset" (see the module docstring).
        iterations_per_view: training iterations per selected view before each selection (paper 100).
        total_iterations: total training iterations (paper 30000); in continue mode the schedule of the rounds is
            part of it.
        seed: seed of the training, the initial-view rule and the planners.
        resolution: image width the dataset is resized to, pixels (None: native).
        train: TrainConfig overrides as (key, value) pairs (``iterations`` and ``seed`` are set by the loop).
        physics: probe settings of the fused planners (its up direction is replaced by ``up``'s).
        up: the scene's up direction for the probes: None (the dataset's up axis), "auto" (the mean up vector of
            the training cameras, as nerfstudio orients) or anything :func:`nbv.physics.scene_frame.parse_up` takes.
        occlusion: S(T) and the coverage count only the Gaussians the coarse depth test finds unhidden
            (:class:`nbv.scores.DepthBuffer`; the default); False: the paper's frustum culling (the ``paper`` preset).
        planner: planner config overrides as (key, value) pairs (``seed`` is set per round).
        backend: renderer backend ("auto", "torch", "gsplat").
        preset: the preset the values came from (recorded only).
    """

    method: str = "fisher+fluid"
    budget: int = 10
    initial_count: int = 2
    initial_ids: tuple[int, ...] | None = None
    initial_direction: tuple[float, float, float] | None = None
    mode: str = "continue"
    iterations_per_view: int = 100
    total_iterations: int = 30000
    seed: int = 0
    resolution: int | None = None
    train: tuple[tuple[str, Any], ...] = field(default_factory=tuple)
    physics: PhysicsConfig = field(default_factory=PhysicsConfig)
    planner: tuple[tuple[str, Any], ...] = field(default_factory=tuple)
    backend: str = "auto"
    preset: str = "paper"
    up: str | tuple[float, float, float] | None = None
    occlusion: bool = True

    def __post_init__(self) -> None:
        if not isinstance(self.occlusion, bool):
            raise ValueError(f"ActiveConfig.occlusion must be a bool, got {self.occlusion!r}")
        if self.up is not None and self.up != "auto":
            parse_up(self.up, "ActiveConfig.up")
            if not isinstance(self.up, str):
                object.__setattr__(self, "up", tuple(float(c) for c in self.up))
        if not isinstance(self.method, str) or not self.method:
            raise ValueError(f"ActiveConfig.method must be a planner name, got {self.method!r}")
        for name, low in (
            ("budget", 1),
            ("initial_count", 1),
            ("iterations_per_view", 0),
            ("total_iterations", 1),
            ("seed", 0),
        ):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < low:
                raise ValueError(f"ActiveConfig.{name} must be an integer >= {low}, got {v!r}")
        for name, high, note in (
            ("budget", MAX_VIEWS, "a view count is at most the dataset's candidate views"),
            ("initial_count", MAX_VIEWS, "a view count is at most the dataset's candidate views"),
            ("seed", MAX_SEED, "a seed is a 32-bit integer"),
        ):
            if getattr(self, name) > high:
                raise ValueError(f"ActiveConfig.{name} must be at most {high:,}, got {getattr(self, name):,}; {note}")
        if self.initial_ids is not None:
            if isinstance(self.initial_ids, (str, bytes)) or len(self.initial_ids) > MAX_VIEWS:
                raise ValueError(f"ActiveConfig.initial_ids must be a list of at most {MAX_VIEWS:,} view indices")
            ids = tuple(int(i) for i in self.initial_ids)
            if not ids or len(set(ids)) != len(ids) or min(ids) < 0:
                raise ValueError(f"ActiveConfig.initial_ids must be distinct indices >= 0, got {self.initial_ids!r}")
            object.__setattr__(self, "initial_ids", ids)
            object.__setattr__(self, "initial_count", len(ids))
        if self.initial_count > self.budget:
            raise ValueError(
                f"ActiveConfig.initial_count ({self.initial_count}) must not exceed the budget ({self.budget})"
            )
        if self.initial_direction is not None:
            d = tuple(float(v) for v in self.initial_direction)
            if len(d) != 3 or not all(math.isfinite(v) for v in d) or math.hypot(*d) == 0:
                raise ValueError(
                    f"ActiveConfig.initial_direction must be a non-zero (x, y, z), got {self.initial_direction!r}"
                )
            object.__setattr__(self, "initial_direction", d)
        check_choices(self, {"mode": MODES}, "ActiveConfig.")
        if self.resolution is not None and (
            isinstance(self.resolution, bool) or not isinstance(self.resolution, int) or self.resolution < 8
        ):
            raise ValueError(f"ActiveConfig.resolution must be None or a width >= 8 pixels, got {self.resolution!r}")
        if self.resolution is not None and self.resolution > MAX_IMAGE_SIDE:
            raise ValueError(
                f"ActiveConfig.resolution must be at most {MAX_IMAGE_SIDE:,} pixels (the largest image side a camera "
                f"may have), got {self.resolution:,}"
            )
        if not isinstance(self.physics, PhysicsConfig):
            raise ValueError(f"ActiveConfig.physics must be a PhysicsConfig, got {type(self.physics).__name__}")
        for name in ("train", "planner"):
            raw = getattr(self, name)
            pairs = tuple((str(k), v) for k, v in (raw.items() if isinstance(raw, dict) else raw))
            object.__setattr__(self, name, pairs)
        check_known_keys(TrainConfig, (k for k, _ in self.train), "ActiveConfig.train: ")
        if self.mode == "continue" and self.schedule_iterations() > self.total_iterations:
            raise ValueError(
                f"ActiveConfig.total_iterations ({self.total_iterations}) is below the iterations of the "
                f"selection rounds ({self.schedule_iterations()} = iterations_per_view x sum of "
                f"n_selected); raise total_iterations or lower iterations_per_view"
            )
        self.train_config(self.total_iterations)  # validates the overrides now

    @classmethod
    def from_preset(cls, preset: str, **overrides: Any) -> ActiveConfig:
        """The preset's values ("paper" or "cpu-small") with ``overrides`` (``train``/``physics`` dicts merge)."""
        if preset not in PRESETS:
            raise ValueError(f"unknown preset {preset!r}; use one of {sorted(PRESETS)}")
        base = {k: v for k, v in PRESETS[preset].items() if k not in ("train", "physics")}
        train = {**PRESETS[preset]["train"], **dict(overrides.pop("train", {}) or {})}
        physics = overrides.pop("physics", None)
        if not isinstance(physics, PhysicsConfig):
            physics = PhysicsConfig.from_dict({**PRESETS[preset]["physics"], **dict(physics or {})})
        check_known_keys(cls, overrides)
        return cls(**{**base, **overrides, "train": train, "physics": physics, "preset": preset})

    def rounds(self) -> list[int]:
        """n_selected before each selection: initial_count, ..., budget - 1."""
        return list(range(self.initial_count, self.budget))

    def schedule_iterations(self) -> int:
        """Training iterations spent before the selections, sum of n_selected x iterations_per_view."""
        first, last = self.initial_count, self.budget - 1  # closed form of the sum over rounds()
        return self.iterations_per_view * max(last - first + 1, 0) * (first + last) // 2

    def train_config(self, iterations: int) -> TrainConfig:
        """The TrainConfig of a run of ``iterations`` (the reference schedule compressed to it)."""
        return TrainConfig.for_iterations(iterations, **{**dict(self.train), "seed": self.seed})

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dict (:meth:`from_dict` reads it back)."""
        d = asdict(self)
        d["physics"] = self.physics.to_dict()
        d["train"], d["planner"] = dict(self.train), dict(self.planner)
        for key in ("initial_ids", "initial_direction"):
            d[key] = None if d[key] is None else list(d[key])
        return d

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ActiveConfig:
        """Inverse of :meth:`to_dict`; unknown keys are errors naming the key."""
        check_known_keys(cls, data)
        d = dict(data)
        if "physics" in d and not isinstance(d["physics"], PhysicsConfig):
            d["physics"] = PhysicsConfig.from_dict(d["physics"])
        for key in ("initial_ids", "initial_direction"):
            if d.get(key) is not None:
                d[key] = tuple(d[key])
        if isinstance(d.get("up"), list):
            d["up"] = tuple(d["up"])
        return cls(**d)
