"""Experiments: methods x scenes x seeds of active runs plus evaluation, and the paper's tables (Sec. 4, Tab. 1-4).

Config (JSON; paths relative to the file)::

    {
      "scenes": ["data/ahmed64"],                 # datasets (Blender or COLMAP folders)
      "methods": ["random", "fisher", "fisher+fluid", "fisher+fluid@-x"],
      "seeds": [0, 1, 2],
      "preset": "cpu-small",                      # ActiveConfig preset ("paper" or "cpu-small")
      "output": "out/experiment",                 # results folder
      "reference_views": 20,                      # many-view reference: a run on this many views (null: none)
      "active": {"budget": 10, "mode": "continue", "train": {...}, "physics": {...}},   # ActiveConfig overrides
      "eval": {"critical_views": 20}              # EvalConfig overrides
    }

A method ``M@D`` (``M`` a physics-driven method: ``fisher+fluid``, ``variance+fluid``, ``random+fluid``, a
``+shuffled`` control or ``physics``; ``D`` one of -x, +x, -z, +z, -y) runs ``M`` with the selection's physics
driven by the single probe ``D``: the paper's per-direction ablation (Tab. 6), where NBV selection uses one initial
condition. Evaluation always uses all five probes.

Jobs: one ``active`` run + ``eval`` per (scene, method, seed) in ``OUTPUT/runs/<scene>/<method>/seed<k>``, and per
(scene, seed) the many-view reference in ``OUTPUT/runs/<scene>/reference-<N>views/seed<k>``: the first N candidate
views as initial views with budget N, so no selection happens and it trains ``total_iterations`` on N views.
A job whose eval.json matches its config is skipped, and an interrupted run resumes (:mod:`nbv.active`), so the
whole experiment is resumable.

Tables (``OUTPUT/tables/*.md`` and ``*.csv``, all in ``tables.md``; mean +- sample std over scenes x seeds, n runs):

- ``visual``: PSNR, SSIM, LPIPS, Chamfer per method (and the many-view reference);
- ``physics``: D-bar, critical-view PSNR and D-bar per method, with the *empty scene* (the empty-scene D-bar of the
  method runs) and the *many-view* reference rows;
- ``ablation_random``: the selection ablation, random vs visual shortlist, with and without the physics pick
  (random, random+fluid, fisher, fisher+fluid, variance, variance+fluid and the +area / +shuffled controls: those
  that ran);
- ``paired`` (when a fused method and its planner or a control ran): per (scene, seed) pair, each ``<visual>+fluid``
  against ``<visual>``, ``<visual>+area`` and ``<visual>+shuffled``, and ``<visual>+area`` against ``<visual>``: wins,
  mean and median difference, exact sign-test and Wilcoxon p-values per metric, and which differences clear
  p < 0.05 (:mod:`nbv.paired`);
- ``ablation_direction``: D-bar of every probe direction's own D_g^(IC) per method (how each initial condition
  sees the result);
- ``ablation_selection_direction`` (when ``M@D`` methods ran): PSNR, SSIM, D-bar and critical D-bar of the runs whose
  selection was driven by one direction, beside the visual planner alone and the five-direction fused method (the
  paper's per-direction ablation).

Plots (matplotlib bar charts with +-std whiskers, :func:`viz.plots.bar_chart`): ``OUTPUT/plots/psnr.png``,
``dbar.png``, ``dbar_direction.png``.
"""

from __future__ import annotations

import csv
import difflib
import io
import json
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from fluidsim.directions import DIRECTIONS
from recon.datasets import dataset_format

from .active import ActiveConfig, config_differences, run_active
from .evaluate import EvalConfig, evaluate_run
from .io import json_safe, write_json_atomic, write_text_atomic
from .paired import paired_table
from .planners import PLANNERS, uses_physics

log = logging.getLogger(__name__)

CONFIG_KEYS = ("scenes", "methods", "seeds", "preset", "output", "reference_views", "active", "eval")
ABLATION_ORDER = ("random", "random+fluid", "random+area", "random+shuffled", "fisher", "fisher+fluid", "fisher+area",
                  "fisher+shuffled", "variance", "variance+fluid", "variance+area", "variance+shuffled")
# what re-ranks the shortlist of a fused method <visual>+<pick> (the ablation table's "physics pick" column)
PICKS = {"fluid": "yes", "area": "no: coverage sum w_g (D_g = 1)", "shuffled": "D_g shuffled across the Gaussians",
         "fluid-occ": "yes, depth-tested visibility", "area-occ": "no: coverage of the unhidden Gaussians",
         "excess": "D_g minus the empty-scene D_g", "perprobe": "D_g normalised per probe",
         "balanced": "z(coverage) + z(S / coverage)", "balanced-occ": "z(coverage) + z(S / coverage), depth-tested"}


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
        if len(set(self.methods)) != len(self.methods) or len(set(self.seeds)) != len(self.seeds):
            raise ValueError("experiment config: 'methods' and 'seeds' must not repeat entries")
        if any(isinstance(s, bool) or not isinstance(s, int) or s < 0 for s in self.seeds):
            raise ValueError(f"experiment config: 'seeds' must be integers >= 0, got {list(self.seeds)}")
        if self.reference_views is not None and (isinstance(self.reference_views, bool)
                                                 or not isinstance(self.reference_views, int)
                                                 or self.reference_views < 1):
            raise ValueError(f"experiment config: 'reference_views' must be null or an integer >= 1 "
                             f"(the paper: >= 20), got {self.reference_views!r}")
        for name in ("active", "eval"):
            if not isinstance(getattr(self, name), dict):
                raise ValueError(f"experiment config: {name!r} must be an object of overrides")
        for method in self.methods:  # validates the names, the overrides and the preset before any job starts
            check_method(method)
            self.active_config(method, self.seeds[0])
        self.eval_config()

    @classmethod
    def load(cls, path: str | Path) -> ExperimentConfig:
        """Read a JSON config; relative scene and output paths are taken relative to the file."""
        path = Path(path)
        if not path.is_file():
            raise ValueError(f"experiment config {path} does not exist")
        try:
            data = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise ValueError(f"experiment config {path} is not valid JSON: {exc}") from exc
        if not isinstance(data, dict):
            raise ValueError(f"experiment config {path} must hold a JSON object")
        bad = sorted(set(data) - set(CONFIG_KEYS))
        if bad:
            raise ValueError(f"experiment config {path}: unknown keys {bad}; valid keys: {list(CONFIG_KEYS)}")
        for key in ("scenes", "methods"):
            if key not in data:
                raise ValueError(f"experiment config {path}: missing {key!r}")
        base = path.parent
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

    def eval_config(self) -> EvalConfig:
        return EvalConfig.from_dict(self.eval)


def check_method(method: str) -> str:
    """``method`` unchanged when it names a registered planner (``M`` or ``M@D``, :data:`nbv.planners.PLANNERS`).

    Raises:
        ValueError: naming the method, the registered planners and, for a near miss, the closest name.
    """
    if not isinstance(method, str) or not method:
        raise ValueError(f"experiment config: 'methods' entries must be planner names, got {method!r}")
    base = method.partition("@")[0]
    if base not in PLANNERS:
        close = difflib.get_close_matches(base, list(PLANNERS), n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise ValueError(f"experiment config: method {method!r} is not a planner{hint}; the methods are "
                         f"{', '.join(sorted(PLANNERS))}, each optionally with @ and a probe direction "
                         f"({', '.join(DIRECTIONS)})")
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
        raise ValueError(f"experiment method {method!r}: unknown probe direction {direction!r}; use one of "
                         f"{', '.join(DIRECTIONS)}")
    if base not in PLANNERS or not uses_physics(base):
        raise ValueError(f"experiment method {method!r}: a single-direction variant needs a method whose pick uses "
                         "the physics (fisher+fluid, variance+fluid, random+fluid, a +shuffled control, "
                         "fisher+fluid-occ, fisher+excess, fisher+perprobe, fisher+balanced(-occ) or physics; "
                         "the +area controls run no probe)")
    return base, direction


def method_folder(method: str) -> str:
    """Run folder name of a method: ``fisher+fluid`` -> ``fisher_fluid``,
    ``fisher+fluid@-x`` -> ``fisher_fluid_at-x``, ``fisher+fluid@+x`` -> ``fisher_fluid_at+x``
    (the direction keeps its sign, so the +x and -x folders read as such)."""
    base, sep, direction = method.partition("@")
    return base.replace("+", "_") + (f"_at{direction}" if sep else "")


def scene_names(scenes: Sequence[str]) -> list[str]:
    """Folder names of the scenes, made unique with an index suffix."""
    names = [Path(s).name or "scene" for s in scenes]
    return [n if names.count(n) == 1 else f"{n}-{i}" for i, n in enumerate(names)]


def reference_label(views: int) -> str:
    return f"reference-{views}views"


def plan_jobs(config: ExperimentConfig) -> list[dict]:
    """One job dict (picklable) per (scene, method, seed), plus the many-view references."""
    out = Path(config.output)
    eval_cfg = config.eval_config().to_dict()
    jobs = []
    for scene, name in zip(config.scenes, scene_names(config.scenes), strict=True):
        for seed in config.seeds:
            for method in config.methods:
                jobs.append({"kind": "method", "scene": name, "dataset": scene, "method": method, "seed": seed,
                             "run_dir": str(out / "runs" / name / method_folder(method) / f"seed{seed}"),
                             "active": config.active_config(method, seed).to_dict(), "eval": eval_cfg})
            if config.reference_views is not None:
                n = config.reference_views
                ref = config.active_config("random", seed, budget=n, initial_ids=tuple(range(n)))
                label = reference_label(n)
                jobs.append({"kind": "reference", "scene": name, "dataset": scene, "method": label, "seed": seed,
                             "run_dir": str(out / "runs" / name / label / f"seed{seed}"), "active": ref.to_dict(),
                             "eval": eval_cfg})
    return jobs


def run_job(job: dict) -> dict:
    """Run (or resume) one job's active run and evaluation; returns its result row.

    Needs an initialised Taichi runtime in this process (the executor's initializer). A job whose eval.json
    exists with the same evaluation config and a finished run is not recomputed.
    """
    run_dir = Path(job["run_dir"])
    eval_path = run_dir / "eval.json"
    eval_cfg = EvalConfig.from_dict(job["eval"])
    rounds = run_active(job["dataset"], run_dir, ActiveConfig.from_dict(job["active"]), progress=False)
    result = None
    if eval_path.is_file() and (run_dir / "gaussians.ply").stat().st_mtime <= eval_path.stat().st_mtime:
        stored = json.loads(eval_path.read_text())
        if not config_differences(stored.get("config", {}), json_safe(eval_cfg.to_dict())):
            result = stored
            log.info("%s: already evaluated", run_dir)
    if result is None:
        result = evaluate_run(run_dir, eval_cfg, progress=False)
    return {"kind": job["kind"], "scene": job["scene"], "method": job["method"], "seed": job["seed"],
            "run_dir": str(run_dir), "selected": rounds.get("selected"), **result["summary"]}


def run_experiment(config: ExperimentConfig, executor, progress: bool = True) -> dict[str, Any]:
    """Run every job through ``executor`` (``nbv.executors``), then write results.json, the tables and plots.

    Returns:
        {"rows": per-job result rows, "tables": {name: Markdown}, "files": written paths}.
    """
    for scene in config.scenes:  # a mistyped scene fails now, not after the other scenes' jobs
        try:
            dataset_format(scene)
        except ValueError as exc:
            raise ValueError(f"experiment config 'scenes': {exc}") from exc
    out = Path(config.output)
    out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out / "experiment.json", {"config": {k: getattr(config, k) for k in CONFIG_KEYS}})
    jobs = plan_jobs(config)
    rows = []
    with tqdm(total=len(jobs), desc="jobs", unit="job", disable=not progress) as bar:
        results = executor.map(run_job, jobs)
        while True:
            try:
                job, row = next(results)
            except StopIteration:
                break
            except Exception as exc:
                failed = getattr(exc, "job", None)
                where = f"{failed['scene']} {failed['method']} seed {failed['seed']} ({failed['run_dir']})" if failed \
                    else "a job"
                raise RuntimeError(f"experiment job {where} failed: {exc}. Finished jobs are kept under {out}; "
                                   f"fix the cause and run the same command again to resume") from exc
            rows.append(row)
            bar.update(1)
            log.info("done: %s %s seed %d (PSNR %s, D-bar %s)", job["scene"], job["method"], job["seed"],
                     row.get("psnr"), row.get("dbar"))
    order = {(j["scene"], j["method"], j["seed"]): i for i, j in enumerate(jobs)}
    rows.sort(key=lambda r: order[(r["scene"], r["method"], r["seed"])])
    write_json_atomic(out / "results.json", {"rows": rows})
    return write_tables(rows, config, out)


# ---- tables ------------------------------------------------------------------------------------------
def mean_std(values: Sequence[Any]) -> tuple[float | None, float | None, int]:
    """(mean, sample std (0 for one value), n) over the finite numbers of ``values``; (None, None, 0) if none."""
    xs = [float(v) for v in values if isinstance(v, (int, float)) and math.isfinite(float(v))]
    if not xs:
        return None, None, 0
    arr = np.asarray(xs)
    return float(arr.mean()), float(arr.std(ddof=1)) if len(xs) > 1 else 0.0, len(xs)


def _cell(values: Sequence[Any]) -> str:
    m, s, n = mean_std(values)
    if m is None:
        return "n/a"
    big = abs(m) >= 1e4 or (m != 0 and abs(m) < 1e-2)
    return f"{m:.3e} ± {s:.1e}" if big else f"{m:.4f} ± {s:.4f}"


def _table(title: str, header: list[str], body: list[list[str]]) -> tuple[str, str]:
    md = [f"### {title}", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    md += ["| " + " | ".join(r) + " |" for r in body]
    buf = io.StringIO()
    writer = csv.writer(buf)
    writer.writerow(header)
    writer.writerows(body)
    return "\n".join(md) + "\n", buf.getvalue()


def _by_method(rows: list[dict], kind: str | None = "method") -> dict[str, list[dict]]:
    groups: dict[str, list[dict]] = {}
    for r in rows:
        if kind is None or r["kind"] == kind:
            groups.setdefault(r["method"], []).append(r)
    return groups


def build_tables(rows: list[dict]) -> dict[str, tuple[str, str]]:
    """The four tables as {name: (Markdown, CSV)} from the job rows (see the module docstring)."""
    methods, refs = _by_method(rows), _by_method(rows, "reference")

    def n_col(rs: list[dict]) -> str:
        return str(len(rs))

    tables = {}
    vis_cols = ["method", "n", "PSNR (dB)", "SSIM", "LPIPS", "Chamfer (scene units)"]
    body = [[m, n_col(rs), _cell([r["psnr"] for r in rs]), _cell([r["ssim"] for r in rs]),
             _cell([r["lpips"] for r in rs]), _cell([r["chamfer"] for r in rs])]
            for m, rs in {**methods, **refs}.items()]
    tables["visual"] = _table("Visual metrics (test views)", vis_cols, body)

    phys_cols = ["method", "n", "D-bar (m^4/s)", "critical PSNR (dB)", "critical D-bar (m^4/s)"]
    body = [[m, n_col(rs), _cell([r["dbar"] for r in rs]), _cell([r["critical_psnr"] for r in rs]),
             _cell([r["critical_dbar"] for r in rs])] for m, rs in methods.items()]
    all_runs = [r for rs in methods.values() for r in rs]
    body.append(["empty scene (reference)", n_col(all_runs), _cell([r["dbar_empty"] for r in all_runs]), "", ""])
    for m, rs in refs.items():
        body.append([f"many-view: {m}", n_col(rs), _cell([r["dbar"] for r in rs]),
                     _cell([r["critical_psnr"] for r in rs]), _cell([r["critical_dbar"] for r in rs])])
    tables["physics"] = _table("Geometry divergence D-bar (lower is better) with the references", phys_cols, body)

    abl_cols = ["method", "shortlist", "physics pick", "n", "PSNR (dB)", "D-bar (m^4/s)", "critical D-bar (m^4/s)"]
    body = []
    for m in [m for m in ABLATION_ORDER if m in methods] + [m for m in methods
                                                            if m not in ABLATION_ORDER and "@" not in m]:
        rs = methods[m]
        visual, _, pick = m.partition("+")
        fused = pick in PICKS
        shortlist = ("random K" if visual == "random" else f"{visual} top-K") if fused else \
            ("all (random pick)" if m == "random" else "all")
        physics_pick = PICKS[pick] if fused else ("yes" if m == "physics" else "no")
        body.append([m, shortlist, physics_pick, n_col(rs),
                     _cell([r["psnr"] for r in rs]), _cell([r["dbar"] for r in rs]),
                     _cell([r["critical_dbar"] for r in rs])])
    tables["ablation_random"] = _table("Selection ablation: random vs visual shortlist, with / without physics",
                                       abl_cols, body)
    paired = paired_table(rows)
    if paired is not None:
        header, body, summary = paired
        md, text = _table("Paired: each physics pick against its planner and its controls (same scene and seed)",
                          header, body)
        tables["paired"] = (md + "\n" + "\n".join(summary) + "\n", text)

    dirs = [d for d in DIRECTIONS if any((r.get("dbar_per_direction") or {}).get(d) is not None for r in rows)]
    dir_cols = ["method", "n"] + [f"D-bar {d} (m^4/s)" for d in dirs] + ["D-bar max (m^4/s)"]
    body = [[m, n_col(rs)] + [_cell([(r.get("dbar_per_direction") or {}).get(d) for r in rs]) for d in dirs]
            + [_cell([r["dbar"] for r in rs])] for m, rs in {**methods, **refs}.items()]
    tables["ablation_direction"] = _table("Per-direction ablation: D-bar of each probe's own D_g", dir_cols, body)

    single = {m: rs for m, rs in methods.items() if "@" in m}
    if single:
        bases = list(dict.fromkeys(split_method(m)[0] for m in single))
        names = []
        for base in bases:
            visual = base.split("+")[0]
            names += [m for m in (visual, base) if m in methods]
            names += sorted((m for m in single if split_method(m)[0] == base),
                            key=lambda m: DIRECTIONS.index(split_method(m)[1]))
        cols = ["method", "selection physics", "n", "PSNR (dB)", "SSIM", "D-bar (m^4/s)", "critical D-bar (m^4/s)"]
        body = []
        for m in dict.fromkeys(names):
            base, direction = split_method(m)
            driven = direction or ("all five probes" if base.endswith("+fluid") or base == "physics" else "none")
            rs = methods[m]
            body.append([m, driven, n_col(rs), _cell([r["psnr"] for r in rs]), _cell([r["ssim"] for r in rs]),
                         _cell([r["dbar"] for r in rs]), _cell([r["critical_dbar"] for r in rs])])
        tables["ablation_selection_direction"] = _table(
            "Per-direction ablation of the selection: physics from one probe direction", cols, body)
    return tables


def write_tables(rows: list[dict], config: ExperimentConfig, out: Path) -> dict[str, Any]:
    """Write OUTPUT/tables/{name}.md|.csv, OUTPUT/tables.md and the plots."""
    from viz.plots import DBAR_LABEL, bar_chart  # noqa: PLC0415 - matplotlib (~0.6 s), only for the plots

    tables = build_tables(rows)
    tdir, pdir = out / "tables", out / "plots"
    tdir.mkdir(exist_ok=True)
    pdir.mkdir(exist_ok=True)
    files = []
    for name, (md, text) in tables.items():
        files.append(write_text_atomic(tdir / f"{name}.md", md))
        files.append(write_text_atomic(tdir / f"{name}.csv", text))
    head = (f"# Experiment\n\nscenes: {', '.join(scene_names(config.scenes))}; methods: {', '.join(config.methods)}; "
            f"seeds: {list(config.seeds)}; preset: {config.preset}. Cells: mean ± sample std over scenes x seeds "
            "(n runs).\n\n")
    combined = head + "\n".join(md for md, _ in tables.values())
    files.append(write_text_atomic(out / "tables.md", combined))
    groups = {**_by_method(rows), **_by_method(rows, "reference")}
    labels = list(groups)
    for key, title, ylabel in (("psnr", "test PSNR", "PSNR (dB)"),
                               ("dbar", "geometry divergence D-bar", DBAR_LABEL)):
        stats = [mean_std([r[key] for r in groups[m]]) for m in labels]
        files.append(bar_chart(pdir / f"{key}.png", labels, [s[0] for s in stats], [s[1] for s in stats],
                               title=title, ylabel=ylabel))
    dir_labels, dir_means, dir_stds = [], [], []
    for m in labels:
        for d in DIRECTIONS:
            vals = [(r.get("dbar_per_direction") or {}).get(d) for r in groups[m]]
            mean, std, n = mean_std(vals)
            if n:
                dir_labels.append(f"{m[:8]} {d}")
                dir_means.append(mean)
                dir_stds.append(std)
    if dir_labels:
        files.append(bar_chart(pdir / "dbar_direction.png", dir_labels, dir_means, dir_stds,
                               title="D-bar per probe direction", ylabel=DBAR_LABEL, xlabel="method and probe",
                               width=max(720, 60 * len(dir_labels))))
    return {"rows": rows, "tables": {k: md for k, (md, _) in tables.items()}, "files": [str(f) for f in files]}
