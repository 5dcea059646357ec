"""An active run's folder: its config check on resume (:func:`prepare_run_dir`) and its checkpoint, read safely
(:func:`load_checkpoint`: tensors and plain types only)."""

from __future__ import annotations

import pickle
import re
from pathlib import Path
from typing import Any

import torch

from fluidsim.files import read_json
from nbv.active.config import RUN_FILES
from nbv.io import json_safe, write_json_atomic


def config_differences(old: dict, new: dict, prefix: str = "") -> list[str]:
    """Dotted keys whose values differ between two nested dicts (missing keys count)."""
    out = []
    for key in sorted(set(old) | set(new)):
        a, b = old.get(key, "<missing>"), new.get(key, "<missing>")
        if isinstance(a, dict) and isinstance(b, dict):
            out.extend(config_differences(a, b, f"{prefix}{key}."))
        elif json_safe(a) != json_safe(b):
            out.append(f"{prefix}{key}")
    return out


def prepare_run_dir(run_dir: Path, run_config: dict, overwrite: bool) -> bool:
    """Create RUN/ or check it; returns True when an existing run with the same config can be resumed.

    Raises:
        ValueError: RUN/ holds another config (the message names the differing keys) and ``overwrite`` is False,
            or RUN is a file.
    """
    if run_dir.exists() and not run_dir.is_dir():
        raise ValueError(f"{run_dir} is a file; -o must be a run folder")
    cfg_path = run_dir / "config.json"
    _check_run_files(run_dir, cfg_path)
    if cfg_path.exists() and not overwrite:
        old = read_json(cfg_path, "the run's config", "pass --overwrite to start again")
        diff = config_differences(old, json_safe(run_config))
        if diff:
            raise ValueError(
                f"{run_dir} holds a run with another config (differing keys: {', '.join(diff)}); "
                "use another -o folder, the same options, or --overwrite to start again"
            )
        return (run_dir / "checkpoint.pt").is_file()
    if overwrite:
        for name in RUN_FILES:
            (run_dir / name).unlink(missing_ok=True)
    run_dir.mkdir(parents=True, exist_ok=True)
    write_json_atomic(cfg_path, run_config)
    return False


def _check_run_files(run_dir: Path, cfg_path: Path) -> None:
    """Refuse, with or without --overwrite, a folder whose files of a run's names are someone else's: a config.json
    that is JSON but not a run's config (an object with 'active' and 'dataset'), or a gaussians.ply, rounds.json,
    ... beside no config.json (a run writes its config.json first). The run would replace or delete them."""
    fix = "choose another -o folder (--overwrite discards only a run of `fluidgs active`)"
    if cfg_path.exists():
        try:
            old = read_json(cfg_path, "the run's config", "")
        except ValueError:
            return  # unreadable: the resume check names it, and --overwrite may discard a damaged run
        if not isinstance(old, dict) or not isinstance(old.get("active"), dict) or "dataset" not in old:
            raise ValueError(f"{cfg_path} is not the config.json of a `fluidgs active` run; {fix}")
    elif run_dir.is_dir():
        found = [name for name in RUN_FILES if (run_dir / name).exists()]
        if found:
            raise ValueError(f"-o {run_dir} holds {', '.join(found)} but no run's config.json; {fix}")


CHECKPOINT_KEYS = frozenset({"version", "config", "selected", "rounds", "phase", "trainer", "torch_rng"})


def read_run_config(run_dir: str | Path) -> dict:
    """The config.json of a finished active run in ``run_dir``: an object with the ``active`` config (an object)
    and the ``dataset`` path; ValueError naming the file and the fix otherwise."""
    path = Path(run_dir) / "config.json"
    fix = "run `fluidgs active DATASET -o RUN` again to write it"
    data = read_json(path, "the run's config", fix)
    if (
        not isinstance(data, dict)
        or not isinstance(data.get("active"), dict)
        or not isinstance(data.get("dataset"), str)
    ):
        raise ValueError(f"the run's config {path} has no 'active' object and 'dataset' path; {fix}")
    return data


def load_checkpoint(path: str | Path) -> dict:
    """A run folder's ``checkpoint.pt``, read with ``torch.load(weights_only=True)``: tensors and plain types
    (dict, list, tuple, str, numbers, None) only, so a planted file cannot run code while it loads.

    Raises:
        ValueError: naming the file and the fix, when it is not a checkpoint of this version made of tensors and
            plain types (a pickle that asks for any other object is refused before anything of it runs).
    """
    path = Path(path)
    fix = "delete it, or pass --overwrite to start the run again"
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        found = re.search(r"(?:unsupported GLOBAL|Unsupported global:?) ?(?:GLOBAL )?([\w.]+)", str(exc))
        if found:
            raise ValueError(
                f"{path} is refused: loading it would call {found.group(1)}, and a checkpoint holds "
                f"tensors and plain types only (a planted file could run code); {fix}"
            ) from None
        raise ValueError(
            f"{path} is not a readable checkpoint (not a torch.save file of tensors and plain types); {fix}"
        ) from None
    except (RuntimeError, EOFError, OSError, AttributeError, ValueError) as exc:
        raise ValueError(
            f"{path} is not a readable checkpoint ({type(exc).__name__}: {str(exc)[:200]}); {fix}"
        ) from None
    if not isinstance(ckpt, dict) or not CHECKPOINT_KEYS <= set(ckpt):
        keys = sorted(ckpt) if isinstance(ckpt, dict) else type(ckpt).__name__
        raise ValueError(f"{path} is not a checkpoint of `fluidgs active` (holds {keys}); {fix}")
    return ckpt


def _state_to(state: Any, device: str) -> Any:
    """A checkpoint's nested dict with float tensors on ``device`` (RNG states stay on the CPU)."""
    if isinstance(state, dict):
        return {k: v if k == "generator" else _state_to(v, device) for k, v in state.items()}
    if isinstance(state, list):
        return [_state_to(v, device) for v in state]
    if isinstance(state, torch.Tensor) and state.is_floating_point():
        return state.to(device)
    return state
