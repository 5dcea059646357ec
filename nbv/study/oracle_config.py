"""The oracle study's configuration (:class:`OracleConfig`) and its rules as data (:data:`RULES`).

Config (JSON; scene and output paths relative to the file)::

    {
      "scenes": ["data/torus", "data/ahmed"],     # datasets with test views (render-dataset folders keep the mesh)
      "seeds": [0, 1],                            # run seeds: initial views, training, planner
      "states": [2, 4],                           # views selected at each measured state
      "planner": "fisher",                        # the planner whose picks reach the states
      "rules": ["fisher", "coverage", "fluid-occ", ...],   # default: every rule of RULES
      "probes": {"s150": {"steps": 150}, "s750": {"steps": 750}},   # probe settings (PhysicsConfig overrides)
      "horizon": 100,                             # M: iterations each copy trains with its candidate added
      "top_k": null,                              # FisherRF shortlist of the regret (null: the loop's K)
      "preset": "cpu-small",                      # ActiveConfig preset of the states
      "active": {"iterations_per_view": 100},     # ActiveConfig overrides
      "calibration": true,                        # per-Gaussian calibration against the dataset's mesh
      "bootstrap": 2000,                          # bootstrap resamples of the intervals
      "output": "out/oracle"
    }

A rule scores every remaining candidate. The physics rules run once per probe setting and are reported as
``RULE:SETTING`` (``fluid-occ:s750``); each has a coverage control with the same visibility (``coverage`` or
``coverage-occ``), computed whether listed or not.
"""

from __future__ import annotations

import difflib
import logging
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from fluidsim.files import read_json
from nbv.active import ActiveConfig
from nbv.active.config import MAX_SEED, MAX_VIEWS
from nbv.physics import PhysicsConfig
from nbv.plan import PLANNERS
from nbv.plan.rules import VALUES
from nbv.study.experiment_config import MAX_JOBS, check_preset, config_keys
from recon.train_config import MAX_ITERATIONS

log = logging.getLogger(__name__)

# Bootstrap resamples of an interval: 2000 is the default; each resample re-ranks every state, so a mistyped count is
# refused before the study runs rather than after its states.
MAX_BOOTSTRAP = 1_000_000

# The rules that score the candidates themselves; every other rule sums per-Gaussian values v_g over a view
# (S(T) = sum_g w_g(T) v_g) and names them as the fused planners do (nbv.plan.rules.VALUES).
VIEW_SCORES = ("fisher", "variance", "fvs", "random")
# Rule names of the values vocabulary the study once used, still read with a note: old name -> rule.
OLD_RULE_NAMES = {
    old + occ: new + occ
    for old, new in (("divergence", "fluid"), ("ones", "coverage"), ("thinmask", "thin-area"))
    for occ in ("", "-occ")
}
COMBINES = ("sum", "balanced", "ratio")


@dataclass(frozen=True)
class Rule:
    """One way to score a candidate view.

    Attributes:
        name: the rule's name in configs and tables.
        values: what it scores: a visual planner's per-candidate score ("fisher", "variance"), the farthest-view
            distance ("fvs"), uniform noise ("random") (:data:`VIEW_SCORES`), or S(T) = sum_g w_g(T) v_g of the
            per-Gaussian values v_g named in :data:`nbv.plan.rules.VALUES`, the fused planners' names: "area" (the
            coverage A(T)), "transparency" (1 - opacity), "fluid" (D_g), "shuffled", "excess", "perprobe", "thin"
            (D_g where the solid is thin or open: :mod:`nbv.physics.thin`) and "thin-area" (1 there: the thin
            rules' own coverage control, which needs the probes' solid but not their fluid).
        depth_test: S(T) counts only the Gaussians the coarse depth test finds unhidden.
        combine: "sum" (S(T)), "balanced" (z(A) + z(S/A) over the candidates) or "ratio" (the physics part
            P(T) = S/A).
        description: one line for the tables.
    """

    name: str
    values: str
    depth_test: bool = False
    combine: str = "sum"
    description: str = ""

    def __post_init__(self) -> None:
        values = VIEW_SCORES + tuple(VALUES)
        if self.values not in values or self.combine not in COMBINES:
            raise ValueError(f"Rule {self.name!r}: values must be one of {values} and combine one of {COMBINES}")

    @property
    def per_gaussian(self) -> bool:
        """Whether the rule sums per-Gaussian values (:data:`nbv.plan.rules.VALUES`) over each view."""
        return self.values in VALUES

    @property
    def physics(self) -> bool:
        """Whether the rule needs a probe setting's run (its fluid, or its solid alone)."""
        return self.per_gaussian and (VALUES[self.values].probes or VALUES[self.values].solid)

    @property
    def control(self) -> str | None:
        """The coverage rule with the same visibility (physics rules only)."""
        if not self.physics:
            return None
        return "coverage-occ" if self.depth_test else "coverage"

    @property
    def own_control(self) -> str | None:
        """A second control, for the rules that weight D_g by a mask: the coverage of the masked Gaussians alone
        (``thin`` -> ``thin-area``, with the same visibility and probe setting), so that what D_g adds is measured
        apart from what the mask adds."""
        if self.values != "thin":
            return None
        return "thin-area-occ" if self.depth_test else "thin-area"


def _physics_rules() -> list[Rule]:
    out = []
    for values, label in (
        ("fluid", "S(T) of D_g"),
        ("shuffled", "S(T) of D_g permuted across the Gaussians"),
        ("excess", "S(T) of the excess over the empty scene"),
        ("perprobe", "S(T) of D_g with every probe normalised"),
        ("thin", "S(T) of D_g where the solid is thin or open"),
        ("thin-area", "the coverage of the Gaussians where the solid is thin or open (the thin rules' control)"),
    ):
        for occ in (False, True):
            suffix, vis = ("-occ", "depth-tested") if occ else ("", "frustum")
            out.append(Rule(values + suffix, values, occ, "sum", f"{label}, {vis}"))
    for occ in (False, True):
        suffix, vis = ("-occ", "depth-tested") if occ else ("", "frustum")
        out.append(Rule("balanced" + suffix, "fluid", occ, "balanced", f"z(A) + z(S/A), {vis}"))
        out.append(Rule("ratio" + suffix, "fluid", occ, "ratio", f"the physics part P(T) = S/A, {vis}"))
    return out


RULES: dict[str, Rule] = {
    r.name: r
    for r in [
        Rule("fisher", "fisher", description="FisherRF: sum H_c / (H_train + lambda)"),
        Rule("variance", "variance", description="ActiveNeRF variance reduction"),
        Rule("fvs", "fvs", description="farthest view sampling: distance to the nearest selected camera"),
        Rule("random", "random", description="uniform noise (a rule that knows nothing)"),
        Rule("coverage", "area", False, description="coverage A(T) = sum w_g, frustum"),
        Rule("coverage-occ", "area", True, description="coverage A(T) of the unhidden Gaussians"),
        Rule("transparent", "transparency", False, description="S(T) of 1 - opacity (no probes), frustum"),
        Rule("transparent-occ", "transparency", True, description="S(T) of 1 - opacity (no probes), depth-tested"),
        *_physics_rules(),
    ]
}


def rule_of(label: str) -> Rule:
    """The rule of a reported label (``fluid-occ:s750`` -> ``RULES["fluid-occ"]``)."""
    return RULES[label.partition(":")[0]]


def _renamed(rules: Sequence) -> Sequence:
    """``rules`` with the old names (:data:`OLD_RULE_NAMES`) read as the rules they name, with a note in the log."""
    old = [r for r in rules if isinstance(r, str) and r in OLD_RULE_NAMES]
    if not old:
        return rules
    new = [OLD_RULE_NAMES[r] for r in old]
    log.warning("oracle config: 'rules' %s are old names, read as %s; write the new names", old, new)
    return [OLD_RULE_NAMES.get(r, r) if isinstance(r, str) else r for r in rules]


def _is_int(v: Any, low: int) -> bool:
    return not isinstance(v, bool) and isinstance(v, int) and v >= low


@dataclass(frozen=True)
class OracleConfig:
    """An oracle study; the module docstring shows the JSON form and what each key means.

    Attributes:
        states: each at least the initial views and below the number of candidates.
        probes: overrides on the preset's selection physics.
        functional: the functional target's probe settings (PhysicsConfig overrides on the selection physics, e.g.
            {"particle_radius": 0.05, "steps": 300, "directions": ["-x"]}), or None (default): no functional target.
            With it, each copy is also measured by its functional error against the dataset's mesh
            (:mod:`nbv.functional`, one probe run per copy and direction) and each candidate gets a functional gain,
            the copy without it minus the copy with it (positive: the candidate makes the model behave more like the
            object).
    """

    scenes: tuple[str, ...]
    seeds: tuple[int, ...] = (0,)
    states: tuple[int, ...] = (2,)
    planner: str = "fisher"
    rules: tuple[str, ...] = tuple(RULES)
    probes: dict = field(default_factory=lambda: {"default": {}})
    horizon: int = 100
    top_k: int | None = None
    preset: str = "cpu-small"
    active: dict = field(default_factory=dict)
    calibration: bool = True
    bootstrap: int = 2000
    output: str = "out/oracle"
    functional: dict | None = None

    def __post_init__(self) -> None:
        for name in ("scenes", "seeds", "states", "rules"):
            v = getattr(self, name)
            if isinstance(v, (str, bytes)) or not isinstance(v, Sequence) or len(v) == 0:
                raise ValueError(f"oracle config: {name!r} must be a non-empty list, got {v!r}")
            if name == "rules":
                v = _renamed(v)
            if len(set(v)) != len(v):
                raise ValueError(f"oracle config: {name!r} must not repeat entries, got {list(v)}")
            object.__setattr__(self, name, tuple(v))
        if not all(_is_int(s, 0) and s <= MAX_SEED for s in self.seeds):
            raise ValueError(
                f"oracle config: 'seeds' must be integers from 0 to {MAX_SEED}, got {list(self.seeds)[:5]}"
            )
        if not all(_is_int(n, 0) and n < MAX_VIEWS for n in self.states):  # before the budget is made from them
            raise ValueError(
                f"oracle config: 'states' must be view counts, integers from 0 to {MAX_VIEWS - 1:,}, got "
                f"{list(self.states)[:5]}"
            )
        check_preset(self.preset, "oracle config")
        settings = len(self.probes) if isinstance(self.probes, dict) and self.probes else 1
        states = len(self.scenes) * len(self.seeds) * len(self.states) * settings
        if states > MAX_JOBS:  # as the experiment's: checked before any work, not after days of it
            raise ValueError(
                f"oracle config: {len(self.scenes)} 'scenes' x {len(self.seeds)} 'seeds' x {len(self.states)} "
                f"'states' x {settings} 'probes' settings make {states:,} oracle states, more than the {MAX_JOBS:,} "
                "a study may plan; list fewer seeds or states (or split the study into several configs)"
            )
        self._check_rules_and_numbers()
        self._check_overrides()
        keys = {"ActiveConfig": "active.", "TrainConfig": "active.train.", "PhysicsConfig": "active.physics."}
        with config_keys(keys, "oracle config"):
            base = self.active_config(self.seeds[0])  # validates the preset and the overrides
        for name in self.probes:
            self.probe_config(name)
        low = base.initial_count
        for n in self.states:
            if n < low:
                raise ValueError(
                    f"oracle config: 'states' entry {n!r} must be an integer >= the {low} initial "
                    "views; lower it or set active.initial_count"
                )

    def _check_rules_and_numbers(self) -> None:
        """The rules and the reaching planner are registered; horizon, top_k, bootstrap and calibration in range."""
        for rule in self.rules:
            if rule not in RULES:
                close = difflib.get_close_matches(str(rule), list(RULES), n=1)
                hint = f" (did you mean {close[0]!r}?)" if close else ""
                raise ValueError(
                    f"oracle config: 'rules' has the unknown rule {rule!r}{hint}; the rules are {', '.join(RULES)}"
                )
        if self.planner not in PLANNERS:
            raise ValueError(
                f"oracle config: 'planner' {self.planner!r} is not a planner; choose one of "
                f"{', '.join(sorted(PLANNERS))}"
            )
        if not _is_int(self.horizon, 1) or self.horizon > MAX_ITERATIONS:
            raise ValueError(
                f"oracle config: 'horizon' (M, iterations per oracle copy) must be an integer from 1 to "
                f"{MAX_ITERATIONS:,}, got {self.horizon!r}; the study's default is 100"
            )
        if self.top_k is not None and not _is_int(self.top_k, 1):
            raise ValueError(
                f"oracle config: 'top_k' must be null (the loop's K) or an integer >= 1, got {self.top_k!r}"
            )
        if not _is_int(self.bootstrap, 100) or self.bootstrap > MAX_BOOTSTRAP:
            raise ValueError(
                f"oracle config: 'bootstrap' must be an integer from 100 to {MAX_BOOTSTRAP:,}, got {self.bootstrap!r}"
            )
        if not isinstance(self.calibration, bool):
            raise ValueError(f"oracle config: 'calibration' must be true or false, got {self.calibration!r}")

    def _check_overrides(self) -> None:
        """'active', 'probes' and 'functional' are objects of overrides (checked against their configs after)."""
        if not isinstance(self.active, dict):
            raise ValueError("oracle config: 'active' must be an object of ActiveConfig overrides")
        if not isinstance(self.probes, dict) or not self.probes:
            raise ValueError(
                "oracle config: 'probes' must be a non-empty object: setting name -> PhysicsConfig "
                'overrides, e.g. {"s750": {"steps": 750}}'
            )
        for name, over in self.probes.items():
            if not isinstance(name, str) or not name or ":" in name or not isinstance(over, dict):
                raise ValueError(
                    f"oracle config: 'probes' entry {name!r} must be a name without ':' mapped to an "
                    "object of PhysicsConfig overrides"
                )
        if self.functional is not None:
            if not isinstance(self.functional, dict):
                raise ValueError(
                    "oracle config: 'functional' must be null or an object of PhysicsConfig overrides for the "
                    'functional target, e.g. {"particle_radius": 0.05, "steps": 300, "directions": ["-x"]}'
                )
            self.functional_config()

    @classmethod
    def load(cls, path: str | Path) -> OracleConfig:
        """Read a JSON config; relative scene and output paths are taken relative to the file."""
        path = Path(path)
        data = read_json(path, "oracle config", f"an oracle config is a JSON object with the keys {list(CONFIG_KEYS)}")
        if not isinstance(data, dict):
            raise ValueError(f"oracle config {path} must hold a JSON object")
        bad = sorted(set(data) - set(CONFIG_KEYS))
        if bad:
            raise ValueError(f"oracle config {path}: unknown keys {bad}; valid keys: {list(CONFIG_KEYS)}")
        if "scenes" not in data:
            raise ValueError(f"oracle config {path}: missing 'scenes' (the dataset folders)")
        base = path.parent
        if isinstance(data["scenes"], list):
            data["scenes"] = [str((base / s).resolve()) for s in data["scenes"]]
        if "output" in data:
            data["output"] = str((base / data["output"]).resolve())
        return cls(**data)

    def active_config(self, seed: int) -> ActiveConfig:
        """The ActiveConfig that reaches the states: the planner, the preset and the overrides, this seed.

        Its budget is at least the largest state + 1, so that every state is a selection round of the loop.
        """
        over = {**self.active, "method": self.planner, "seed": seed}
        cfg = ActiveConfig.from_preset(self.preset, **over)
        need = max(self.states) + 1
        if cfg.budget < need:
            cfg = ActiveConfig.from_preset(self.preset, **{**over, "budget": need})
        return cfg

    def _physics(self, over: dict, up: str | tuple[float, float, float] | None, key: str) -> PhysicsConfig:
        """The selection physics with the overrides ``over`` (and the up direction ``up`` when given); an error names
        the config ``key``."""
        base = self.active_config(self.seeds[0]).physics.to_dict()
        try:
            return PhysicsConfig.from_dict({**base, **over, **({} if up is None else {"up": up})})
        except (TypeError, ValueError) as exc:
            raise ValueError(f"oracle config: {key}: {exc}") from exc

    def probe_config(self, name: str, up: str | tuple[float, float, float] | None = None) -> PhysicsConfig:
        """The PhysicsConfig of probe setting ``name``: the selection physics with the setting's overrides (and the
        empty scene when an ``excess`` rule is asked for)."""
        over = dict(self.probes[name])
        if any(RULES[r].values == "excess" for r in self.rules):
            over["empty_reference"] = True
        return self._physics(over, up, f"'probes' setting {name!r}")

    def functional_config(self, up: str | tuple[float, float, float] | None = None) -> PhysicsConfig | None:
        """The functional target's PhysicsConfig (the selection physics with ``functional``'s overrides, no empty
        scene; default direction -x, head-on), or None without a functional target."""
        if self.functional is None:
            return None
        over = {"directions": ["-x"], **self.functional, "empty_reference": False, "track_distinct": False}
        return self._physics(over, up, "'functional'")

    def probe_configs(self, up: str | tuple[float, float, float]) -> dict[str, PhysicsConfig]:
        """Every probe setting's PhysicsConfig (:meth:`probe_config`) with the up direction ``up``."""
        return {name: self.probe_config(name, up) for name in self.probes}

    def physics_rules(self) -> list[str]:
        """The reported labels of the physics rules, ``RULE:SETTING``, and their coverage controls."""
        names = [r for r in self.rules if RULES[r].physics]
        for r in list(names):
            own = RULES[r].own_control
            if own is not None and own not in names:
                names.append(own)
        return [f"{r}:{p}" for r in names for p in self.probes]

    def scored_rules(self) -> list[str]:
        """Every rule computed at a state: the listed ones, the physics ones per probe setting, their controls."""
        names = [r for r in self.rules if not RULES[r].physics]
        for r in self.rules:
            control = RULES[r].control
            if control is not None and control not in names:
                names.append(control)
        return names + self.physics_rules()

    def to_dict(self) -> dict[str, Any]:
        """JSON-able; ``functional`` is left out when None, so the states of a study without it keep their key."""
        d = {k: list(v) if isinstance(v, tuple) else v for k, v in ((k, getattr(self, k)) for k in CONFIG_KEYS)}
        if d["functional"] is None:
            del d["functional"]
        return d


CONFIG_KEYS = tuple(f.name for f in fields(OracleConfig))  # the JSON keys, in the order to_dict writes them
