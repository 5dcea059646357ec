"""An experiment's configuration (:class:`ExperimentConfig`: scenes x methods x seeds) and the method names."""

from __future__ import annotations

import difflib
import json
import re
from collections import Counter
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fluidsim.directions import DIRECTIONS
from fluidsim.files import check_input_file
from nbv.active import ActiveConfig
from nbv.active.config import MAX_SEED, MAX_VIEWS, PRESETS
from nbv.plan import PLANNERS, uses_physics
from nbv.study.evaluate import EvalConfig

# At most this many (scene, method, seed) jobs: a study of the paper's size has about a hundred; a larger list is a
# mistake that would otherwise plan for minutes before the first job.
MAX_JOBS = 10_000

CONFIG_KEYS = ("scenes", "methods", "seeds", "preset", "output", "reference_views", "active", "eval")

ABLATION_ORDER = (
    "random",
    "random+fluid",
    "random+area",
    "random+shuffled",
    "fisher",
    "fisher+fluid",
    "fisher+area",
    "fisher+shuffled",
    "variance",
    "variance+fluid",
    "variance+area",
    "variance+shuffled",
)

# what re-ranks the shortlist of a fused method <visual>+<pick> (the ablation table's "physics pick" column)
PICKS = {
    "fluid": "yes",
    "area": "no: coverage sum w_g (D_g = 1)",
    "shuffled": "D_g shuffled across the Gaussians",
    "fluid-occ": "yes, depth-tested visibility",
    "area-occ": "no: coverage of the unhidden Gaussians",
    "excess": "D_g minus the empty-scene D_g",
    "perprobe": "D_g normalised per probe",
    "balanced": "z(coverage) + z(S / coverage)",
    "balanced-occ": "z(coverage) + z(S / coverage), depth-tested",
    "thin-area": "no: coverage of the Gaussians where the solid is thin or open",
    "thin-area-occ": "no: the same, depth-tested",
}


@dataclass(frozen=True)
class ExperimentConfig:
    """An experiment (see the module docstring for the JSON form).

    Attributes:
        scenes: dataset folders.
        methods: planner names.
        seeds: run seeds.
        preset: ActiveConfig preset.
        output: results folder.
        reference_views: views of the many-view reference run (None: no reference).
        active: ActiveConfig overrides (``train`` and ``physics`` are dicts).
        eval: EvalConfig overrides (``physics`` a dict).
    """

    scenes: tuple[str, ...]
    methods: tuple[str, ...]
    seeds: tuple[int, ...] = (0,)
    preset: str = "cpu-small"
    output: str = "out/experiment"
    reference_views: int | None = 20
    active: dict = field(default_factory=dict)
    eval: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in ("scenes", "methods", "seeds"):
            v = getattr(self, name)
            if isinstance(v, (str, bytes)) or not isinstance(v, Sequence) or len(v) == 0:
                raise ValueError(f"experiment config: {name!r} must be a non-empty list, got {v!r}")
            object.__setattr__(self, name, tuple(v))
        jobs = len(self.scenes) * len(self.methods) * len(self.seeds)
        if jobs > MAX_JOBS:
            raise ValueError(
                f"experiment config: {len(self.scenes)} scenes x {len(self.methods)} methods x "
                f"{len(self.seeds)} seeds make {jobs:,} jobs, more than the {MAX_JOBS:,} an experiment "
                "may plan; list fewer seeds, methods or scenes (or split the study into several configs)"
            )
        if len(set(self.methods)) != len(self.methods) or len(set(self.seeds)) != len(self.seeds):
            raise ValueError("experiment config: 'methods' and 'seeds' must not repeat entries")
        folders = Counter(Path(s).resolve() for s in self.scenes)
        repeated = [s for s in self.scenes if folders[Path(s).resolve()] > 1]
        if repeated:
            # The same dataset twice would run every job twice and count it as two scenes in the tables.
            raise ValueError(
                f"experiment config: 'scenes' lists the dataset {repeated[0]} more than once; list it once"
            )
        bad_seeds = [s for s in self.seeds if isinstance(s, bool) or not isinstance(s, int) or not 0 <= s <= MAX_SEED]
        if bad_seeds:
            raise ValueError(
                f"experiment config: 'seeds' must be integers from 0 to {MAX_SEED}, got "
                f"{bad_seeds[:5]!r}{' ...' if len(bad_seeds) > 5 else ''}"
            )
        if self.reference_views is not None and (
            isinstance(self.reference_views, bool)
            or not isinstance(self.reference_views, int)
            or not 1 <= self.reference_views <= MAX_VIEWS
        ):
            raise ValueError(
                f"experiment config: 'reference_views' must be null or an integer from 1 to "
                f"{MAX_VIEWS:,} (the paper: >= 20; at most the scenes' candidate views), got "
                f"{self.reference_views!r}"
            )
        for name in ("active", "eval"):
            if not isinstance(getattr(self, name), dict):
                raise ValueError(f"experiment config: {name!r} must be an object of overrides")
        check_preset(self.preset)
        for method in self.methods:  # validates the names, the overrides and the preset before any job starts
            check_method(method)
            with config_keys(
                {"ActiveConfig": "active.", "TrainConfig": "active.train.", "PhysicsConfig": "active.physics."}
            ):
                self.active_config(method, self.seeds[0]).physics.check_inflow()
        with config_keys({"EvalConfig": "eval.", "PhysicsConfig": "eval.physics."}):
            self.eval_config()

    @classmethod
    def load(cls, path: str | Path) -> ExperimentConfig:
        """Read a JSON config; relative scene and output paths are taken relative to the file."""
        path = Path(path)
        check_input_file(path, "experiment config")
        try:
            data = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise ValueError(f"experiment config {path} is not valid JSON: {exc}") from exc
        except RecursionError:
            raise ValueError(
                f"experiment config {path} nests its JSON too deeply (thousands of levels); an "
                "experiment config is an object of a few levels"
            ) from None
        if not isinstance(data, dict):
            raise ValueError(f"experiment config {path} must hold a JSON object")
        bad = sorted(set(data) - set(CONFIG_KEYS))
        if bad:
            raise ValueError(f"experiment config {path}: unknown keys {bad}; valid keys: {list(CONFIG_KEYS)}")
        for key in ("scenes", "methods"):
            if key not in data:
                raise ValueError(f"experiment config {path}: missing {key!r}")
        base = path.parent
        if not isinstance(data["scenes"], list) or not all(isinstance(s, str) for s in data["scenes"]):
            raise ValueError(
                f"experiment config {path}: 'scenes' must be a list of dataset folders, got {data['scenes']!r}"
            )
        data["scenes"] = [str((base / s).resolve()) for s in data["scenes"]]
        if "output" in data:
            data["output"] = str((base / data["output"]).resolve())
        return cls(**data)

    def active_config(self, method: str, seed: int, **extra: Any) -> ActiveConfig:
        """The ActiveConfig of one run (``M@D``: method ``M`` with the selection's probes restricted to ``D``)."""
        base, direction = split_method(method)
        overrides = {**self.active, **extra, "method": base, "seed": seed}
        if direction is not None:
            physics = overrides.get("physics") or {}
            physics = physics.to_dict() if hasattr(physics, "to_dict") else dict(physics)
            overrides["physics"] = {**physics, "directions": [direction]}
        return ActiveConfig.from_preset(self.preset, **overrides)

    def check_scene_views(self, scene: str, views: int) -> None:
        """Refuse, before any job, a view count of this config that exceeds the ``views`` candidate (train) views
        of ``scene``: the budget, the initial ids and ``reference_views``.

        Raises:
            ValueError: naming the config key, the scene and its view count.
        """
        active = self.active_config(self.methods[0], self.seeds[0])
        counts = [("active.budget", active.budget), ("reference_views", self.reference_views)]
        if active.initial_ids is not None:
            counts.append(("active.initial_ids (largest index + 1)", max(active.initial_ids) + 1))
        for key, n in counts:
            if n is not None and n > views:
                raise ValueError(
                    f"experiment config {key!r} is {n:,}, but the scene {scene} has only {views} "
                    f"candidate (train) views; lower {key.split(' ')[0]!r} to at most {views}"
                )

    def eval_config(self) -> EvalConfig:
        return EvalConfig.from_dict(self.eval)


def check_preset(preset: Any, what: str = "experiment config") -> None:
    """ValueError naming the ``'preset'`` key of the ``what`` config and the presets, unless ``preset`` is one."""
    if not isinstance(preset, str) or preset not in PRESETS:
        raise ValueError(f"{what}: 'preset' must be one of {', '.join(map(repr, PRESETS))}, got {preset!r}")


@contextmanager
def config_keys(keys: dict[str, str], what: str = "experiment config") -> Iterator[None]:
    """Re-raise a ValueError of a nested config with its ``Class.field`` names as the ``what`` config's keys
    (``ActiveConfig.budget`` -> ``'active.budget'``): the user wrote the keys, not the classes. The training
    iterations of an active run are its ``total_iterations`` (the TrainConfig's are derived from it). Unknown keys
    are named by where they stand (``unknown ActiveConfig keys`` -> ``unknown keys in 'active'``)."""
    try:
        yield
    except ValueError as exc:
        message = str(exc)
        if "ActiveConfig" in keys:
            message = re.sub(r"\bTrainConfig\.iterations\b", "ActiveConfig.total_iterations", message)
        unknown = re.compile(rf"\bunknown ({'|'.join(keys)}) keys\b")
        message = unknown.sub(lambda m: f"unknown keys in '{keys[m.group(1)].rstrip('.')}'", message)
        pattern = re.compile(rf"\b({'|'.join(keys)})\.(\w+)")
        message = pattern.sub(lambda m: f"'{keys[m.group(1)]}{m.group(2)}'", message)
        if message == str(exc):
            raise
        raise ValueError(f"{what}: {message}") from None


def check_method(method: str) -> str:
    """``method`` unchanged when it names a registered planner (``M`` or ``M@D``, :data:`nbv.plan.PLANNERS`).

    Raises:
        ValueError: naming the method, the registered planners and, for a near miss, the closest name.
    """
    if not isinstance(method, str) or not method:
        raise ValueError(f"experiment config: 'methods' entries must be planner names, got {method!r}")
    base = method.partition("@")[0]
    if base not in PLANNERS:
        close = difflib.get_close_matches(base, list(PLANNERS), n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise ValueError(
            f"experiment config: method {method!r} is not a planner{hint}; the methods are "
            f"{', '.join(sorted(PLANNERS))}, each optionally with @ and a probe direction "
            f"({', '.join(DIRECTIONS)})"
        )
    split_method(method)  # the direction, and whether the method's pick runs the probes
    return method


def split_method(method: str) -> tuple[str, str | None]:
    """``"fisher+fluid@-x"`` -> ("fisher+fluid", "-x"); a plain method -> (method, None).

    Raises:
        ValueError: an unknown direction, or a direction on a method whose pick does not use the physics.
    """
    if "@" not in method:
        return method, None
    base, _, direction = method.partition("@")
    if direction not in DIRECTIONS:
        raise ValueError(
            f"experiment method {method!r}: unknown probe direction {direction!r}; use one of {', '.join(DIRECTIONS)}"
        )
    if base not in PLANNERS or not uses_physics(base):
        raise ValueError(
            f"experiment method {method!r}: a single-direction variant needs a method whose pick uses "
            "the physics (fisher+fluid, variance+fluid, random+fluid, a +shuffled control, "
            "fisher+fluid-occ, fisher+excess, fisher+perprobe, fisher+balanced(-occ) or physics; "
            "the +area controls run no probe)"
        )
    return base, direction


def method_folder(method: str) -> str:
    """Run folder name of a method: ``fisher+fluid`` -> ``fisher_fluid``,
    ``fisher+fluid@-x`` -> ``fisher_fluid_at-x``, ``fisher+fluid@+x`` -> ``fisher_fluid_at+x``
    (the direction keeps its sign, so the +x and -x folders read as such)."""
    base, sep, direction = method.partition("@")
    return base.replace("+", "_") + (f"_at{direction}" if sep else "")


def scene_names(scenes: Sequence[str]) -> list[str]:
    """Folder names of the scenes (experiment and oracle), made unique with a counter where two share one: the
    first keeps its plain name, so adding a scene never renames an earlier one's folder."""
    names, seen = [], Counter()
    for s in scenes:
        base = Path(s).name or "scene"
        seen[base] += 1
        names.append(base if seen[base] == 1 else f"{base}-{seen[base]}")
    return names


def reference_label(views: int) -> str:
    return f"reference-{views}views"
