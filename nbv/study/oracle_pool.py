"""Pool the states of several oracle studies into one summary (``fluidgs study oracle-pool``).

A study grows in pieces: more seeds on another machine, a second run with a cheaper rule set, the held-out shapes.
Each piece is a results folder of ``fluidgs study oracle`` (its ``oracle-config.json`` and ``states/``). Pooling
reads the finished states of every folder and summarises them together (:func:`nbv.study.oracle_summary.summarise`),
under three rules:

- the folders must agree on everything that changes a state's content except the rule list (the loop's settings,
  the horizon, the probe settings, the planner, K): states reached or measured differently are refused, naming the
  folders and the key;
- only the rules that every state scored are summarised; the others are listed as dropped, never filled in;
- a (scene, seed, state) found in more than one folder is taken from the first folder that holds it, and counted.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fluidsim.files import check_input_file, read_json
from nbv.study.oracle_config import MAX_BOOTSTRAP, OracleConfig

MAX_STATE_BYTES = 64 << 20  # a state file is a few hundred KB (its rules' scores per candidate)

# The config keys that do not change a state's content (nbv.study.oracle.STUDY_ONLY_KEYS), and the rule list, which
# changes only which scores a state holds: pooled folders may differ in these and nothing else.
POOL_FREE_KEYS = ("scenes", "seeds", "states", "output", "bootstrap", "rules")


def _numbers(values: Any, count: int) -> bool:
    """``values`` is a list of ``count`` numbers (None stands for a NaN that JSON cannot hold)."""
    return isinstance(values, list) and len(values) == count and all(_number(v) for v in values)


def _number(v: Any) -> bool:
    return v is None or (isinstance(v, (int, float)) and not isinstance(v, bool))


def state_problem(state: Any) -> str | None:
    """What keeps ``state`` (a state file's JSON) from being a finished state of `fluidgs study oracle`, in words, or
    None: the summary reads its scene, seed and state, and per candidate the rules' scores and the oracle's gains."""
    if not isinstance(state, dict):
        return f"holds a JSON {type(state).__name__}, not a state object"
    kinds = {"config": dict, "scene": str, "seed": int, "n_selected": int, "candidates": list, "shortlist": list}
    kinds |= {"scores": dict, "oracle": dict}
    words = {dict: "object", str: "string", int: "integer", list: "list"}
    wrong = [k for k, kind in kinds.items() if not isinstance(state.get(k), kind) or isinstance(state[k], bool)]
    if wrong:
        return f"has no {wrong[0]!r} {words[kinds[wrong[0]]]}"
    count = len(state["candidates"])
    lists = {f"scores.{k}": v for k, v in state["scores"].items()}
    lists |= {f"oracle.{k}": v for k, v in state["oracle"].items() if isinstance(v, list)}
    bad = [key for key, values in lists.items() if not _numbers(values, count)]
    if bad:
        return f"has a {bad[0]!r} that is not {count} numbers, one per candidate"
    if not all(_number(v) for v in state["oracle"].values() if not isinstance(v, list)):
        return "has an 'oracle' value that is not a number"
    if not all(isinstance(i, int) and 0 <= i < count for i in state["shortlist"]):
        return f"has a 'shortlist' that is not candidate positions below {count}"
    return None


@dataclass
class Pool:
    """The pooled study: a config whose rules every state scored, the states, and what pooling left out."""

    config: OracleConfig
    states: list[dict]
    dropped_rules: list[str]  # labels scored in some states but not all
    duplicates: list[str]  # "scene seed S state N (folder)" taken from an earlier folder instead
    stale: list[str]  # state files of an earlier config of their folder (that study would redo them)
    sources: list[dict]  # per folder: its path and how many states it gave


def _read_folder(folder: Path) -> tuple[dict, list[dict]]:
    """(the config dict, the finished states) of one results folder of ``fluidgs study oracle``."""
    meta = folder / "oracle-config.json"
    if not meta.is_file():
        raise ValueError(f"{folder} is not an oracle study folder (no oracle-config.json); give the 'output' folder")
    config = read_json(meta, "the study file", "it must be the oracle-config.json that `fluidgs study oracle` writes")
    if not isinstance(config, dict) or not isinstance(config.get("config"), dict):
        raise ValueError(f"{meta} is not an oracle-config.json written by `fluidgs study oracle` (no 'config' object)")
    config = config["config"]
    states = []
    for path in sorted((folder / "states").rglob("state*.json")):
        check_input_file(path, "the state file", "delete it (a FIFO or a link is never a state) and resume that study")
        state = read_json(path, "the state file", "delete it and resume that study", MAX_STATE_BYTES)
        problem = state_problem(state)
        if problem is not None:
            raise ValueError(f"the state file {path} {problem}; delete it and resume that study")
        states.append(state)
    return config, states


def pool_studies(folders: list[str | Path], bootstrap: int | None = None) -> Pool:
    """The states of ``folders`` (results folders of ``fluidgs study oracle``), checked and pooled.

    Raises:
        ValueError: a folder that is not a study, a study that differs from the first in a key other than
            :data:`POOL_FREE_KEYS`, or no rule or no state in common.
    """
    if not folders:
        raise ValueError("give at least one oracle study folder")
    if bootstrap is not None and not 1 <= bootstrap <= MAX_BOOTSTRAP:
        raise ValueError(f"--bootstrap must be from 1 to {MAX_BOOTSTRAP:,} resamples, got {bootstrap:,}")
    first_cfg: dict | None = None
    first_folder = None
    states: list[dict] = []
    seen: dict[tuple, str] = {}
    duplicates, stale, sources = [], [], []
    for folder in map(Path, folders):
        cfg, found = _read_folder(folder)
        if first_cfg is None:
            first_cfg, first_folder = cfg, folder
        else:
            for key in sorted(set(cfg) | set(first_cfg)):
                if key not in POOL_FREE_KEYS and cfg.get(key) != first_cfg.get(key):
                    raise ValueError(
                        f"{folder} and {first_folder} differ in {key!r} ({cfg.get(key)!r} against "
                        f"{first_cfg.get(key)!r}): their states were reached or measured differently; pool only "
                        "studies that differ in scenes, seeds, states and rules"
                    )
        given = 0
        for st in found:
            key = (st["scene"], st["seed"], st["n_selected"])
            if st.get("config", {}).get("rules") != cfg.get("rules"):
                stale.append(f"{key[0]} seed {key[1]} state {key[2]} ({folder})")
                continue
            if key in seen:
                duplicates.append(f"{key[0]} seed {key[1]} state {key[2]} ({folder}; kept {seen[key]})")
                continue
            seen[key] = str(folder)
            states.append(st)
            given += 1
        sources.append({"folder": str(folder), "states": given})
    if not states:
        raise ValueError(f"no finished states in {', '.join(map(str, folders))}")
    common = set.intersection(*(set(st["scores"]) for st in states))
    everywhere = set.union(*(set(st["scores"]) for st in states))
    # the listed rules of the pooled config: the base names of the common labels (in the first study's order)
    order = [label.partition(":")[0] for label in states[0]["scores"]]
    rules = list(dict.fromkeys(name for name in order if any(lb.partition(":")[0] == name for lb in common)))
    if not rules:
        raise ValueError(f"the studies share no rule: {sorted(everywhere)}")
    over: dict[str, Any] = {k: v for k, v in first_cfg.items() if k not in ("scenes", "seeds", "states", "rules")}
    config = OracleConfig(
        **{
            **over,
            "scenes": list(dict.fromkeys(st["dataset"] for st in states)),
            "seeds": sorted({st["seed"] for st in states}),
            "states": sorted({st["n_selected"] for st in states}),
            "rules": rules,
            **({"bootstrap": bootstrap} if bootstrap is not None else {}),
        }
    )
    missing = [label for label in config.scored_rules() if label not in common]
    if missing:  # a rule whose control some state lacks: drop it too
        keep = [r for r in config.rules if not any(m.partition(":")[0] == r for m in missing)]
        if not keep:
            raise ValueError(f"the studies share no rule: {sorted(everywhere)}")
        config = OracleConfig(**{**config.to_dict(), "rules": keep})
    return Pool(config, states, sorted(everywhere - set(config.scored_rules())), duplicates, stale, sources)
