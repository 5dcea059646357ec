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
``dbar.png``, ``dbar_direction.png``."""

from __future__ import annotations

import json
import logging
import os
import time
from pathlib import Path
from typing import Any

from tqdm import tqdm

from fluidsim.files import remove_stale_temps
from nbv.active import ActiveConfig, config_differences, run_active
from nbv.io import json_safe, write_json_atomic
from nbv.study.cost import MEASURED, Costs, Estimate, Scene, cpu_slowdown, estimate, job_seconds, minutes
from nbv.study.evaluate import EvalConfig, eval_physics_config, evaluate_run
from nbv.study.experiment_config import (
    CONFIG_KEYS,
    ExperimentConfig,
    method_folder,
    reference_label,
    scene_names,
)
from nbv.study.tables import write_tables
from recon.colmap import find_colmap_sparse, read_colmap_model
from recon.datasets import count_train_views, dataset_format, load_cameras

log = logging.getLogger(__name__)


class JobFailed(RuntimeError):
    """An experiment job raised: the message names the job, its error and how to resume; ``__cause__`` is the job's
    own exception (`fluidgs experiment` exits with that cause's code, in one line)."""


def plan_jobs(config: ExperimentConfig) -> list[dict]:
    """One job dict (picklable) per (scene, method, seed), plus the many-view references."""
    out = Path(config.output)
    eval_cfg = config.eval_config().to_dict()
    jobs = []
    for scene, name in zip(config.scenes, scene_names(config.scenes), strict=True):
        for seed in config.seeds:
            runs = [("method", m, method_folder(m), config.active_config(m, seed)) for m in config.methods]
            if config.reference_views is not None:
                n = config.reference_views
                ref = config.active_config("random", seed, budget=n, initial_ids=tuple(range(n)))
                runs.append(("reference", reference_label(n), reference_label(n), ref))
            jobs += [
                {
                    "kind": kind,
                    "scene": name,
                    "dataset": scene,
                    "method": method,
                    "seed": seed,
                    "run_dir": str(out / "runs" / name / folder / f"seed{seed}"),
                    "active": active.to_dict(),
                    "eval": eval_cfg,
                }
                for kind, method, folder, active in runs
            ]
    return jobs


def job_done(job: dict) -> bool:
    """Whether a job's evaluation is already on disk (a resumed experiment skips it: it costs about nothing)."""
    run_dir = Path(job["run_dir"])
    return (run_dir / "eval.json").is_file() and (run_dir / "gaussians.ply").is_file()


def scene_facts(dataset: str, resolution: int | None) -> Scene | None:
    """A dataset's candidate views and the pixels of one train image at ``resolution`` (its width, the aspect
    kept), read from its cameras without loading an image; None when they cannot be read that way."""
    views = count_train_views(dataset)
    if views is None:
        return None
    try:
        if dataset_format(dataset) == "blender":
            cam = load_cameras(Path(dataset) / "transforms_train.json")[0]
            width, height = cam.width, cam.height
        else:
            width, height = next(iter(read_colmap_model(find_colmap_sparse(Path(dataset))).cameras.values()))[:2]
    except (ValueError, OSError, StopIteration):
        return None
    if resolution is not None:
        width, height = resolution, max(1, round(height * resolution / width))
    return Scene(views=views, pixels=width * height)


def job_estimate(job: dict, scene: Scene, costs: Costs = MEASURED) -> dict[str, float]:
    """One job's seconds per part on one thread from its own config (:func:`nbv.study.cost.job_seconds`)."""
    active = ActiveConfig.from_dict(job["active"])
    probes = eval_physics_config(active.physics, EvalConfig.from_dict(job["eval"]), active.physics.up)
    return job_seconds(active, probes, scene, costs)


def time_estimate(
    jobs: list[dict],
    workers: int = 1,
    threads: int = 1,
    cores: int | None = None,
    slowdown: float | None = None,
    costs: Costs = MEASURED,
) -> tuple[str, Estimate | None]:
    """One line, before the experiment starts, and its :class:`Estimate`: the jobs left and about how long they
    take from their own protocol (:mod:`nbv.study.cost`), with what the figure assumes; None when a scene's
    views or image size cannot be read. ``cores`` defaults to this machine's and ``slowdown`` to
    :func:`nbv.study.cost.cpu_slowdown` measured now."""
    todo = [j for j in jobs if not job_done(j)]
    done = len(jobs) - len(todo)
    resumed = f" ({done} already done)" if done else ""
    if not todo:
        return f"estimate: all {len(jobs)} jobs are done{resumed}; only the tables are written", None
    left = f"{len(todo)} job{'s' if len(todo) != 1 else ''} to run{resumed}"
    scenes: dict[tuple[str, int | None], Scene | None] = {}
    per_job = []
    for job in todo:
        key = (job["dataset"], job["active"]["resolution"])
        if key not in scenes:
            scenes[key] = scene_facts(*key)
        if scenes[key] is None:
            return (
                f"estimate: {left}; the views or image size of {key[0]} cannot be read "
                "from its cameras, so no time estimate",
                None,
            )
        per_job.append(job_estimate(job, scenes[key], costs))
    cores = cores or os.cpu_count() or 1
    slowdown = cpu_slowdown() if slowdown is None else slowdown
    est = estimate(per_job, workers, threads, cores, slowdown, costs)
    parts = ", ".join(f"{p} {minutes(s)}" for p, s in est.seconds.items() if s >= 0.5)
    sizes = sorted({(s.views, s.pixels) for s in scenes.values() if s is not None})
    active = ActiveConfig.from_dict(todo[0]["active"])
    evaluation = eval_physics_config(active.physics, EvalConfig.from_dict(todo[0]["eval"]), active.physics.up)
    return (
        f"estimate: {left}: about {minutes(est.wall_s)} ({parts} on one thread, shared by "
        f"{est.parallel} thread{'s' if est.parallel != 1 else ''}: {workers} worker{'s' if workers != 1 else ''} x "
        f"{threads}, {cores} cores, x {slowdown:.1f}: a thread gets 1/{slowdown:.1f} of a core now). Assumes "
        f"{', '.join(f'{v} views of {p:,} px' for v, p in sizes)}, {active.total_iterations} iterations, budget "
        f"{active.budget}, probes r = {active.physics.particle_radius:g} m x {active.physics.steps} steps, eval "
        f"{len(evaluation.directions)} probe{'s' if len(evaluation.directions) != 1 else ''} x "
        f"{evaluation.steps} steps at r = {evaluation.particle_radius:g} m, at "
        "the costs measured on the 2-core CPU (docs/performance.md)",
        est,
    )


def actual_line(estimate: Estimate | None, seconds: float, jobs: int) -> str:
    """The line at the end: the wall time of the jobs that ran against their estimate."""
    if estimate is None or not jobs:
        return f"took {minutes(seconds)} for {jobs} job{'s' if jobs != 1 else ''} (no estimate)"
    ratio = seconds / estimate.wall_s if estimate.wall_s > 0 else float("inf")
    return (
        f"took {minutes(seconds)} for {jobs} job{'s' if jobs != 1 else ''}, estimated {minutes(estimate.wall_s)} "
        f"(actual / estimate = {ratio:.2f})"
    )


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
    return {
        "kind": job["kind"],
        "scene": job["scene"],
        "method": job["method"],
        "seed": job["seed"],
        "run_dir": str(run_dir),
        "selected": rounds.get("selected"),
        **result["summary"],
    }


def check_scenes(config: ExperimentConfig) -> None:
    """Every scene is a dataset with enough candidate views for the config's counts, checked before the first job
    (a mistyped scene or a too large ``reference_views`` fails now, not after the other scenes' jobs).

    Raises:
        ValueError: naming the scene or the config key and the fix.
    """
    for scene in config.scenes:
        try:
            dataset_format(scene)
        except ValueError as exc:
            raise ValueError(f"experiment config 'scenes': {exc}") from exc
    for scene in config.scenes:
        views = count_train_views(scene)
        if views == 0:
            raise ValueError(
                f"experiment config 'scenes': {scene} has no train (candidate) views; add train views to it or "
                "drop the scene"
            )
        if views is not None:
            config.check_scene_views(scene, views)


def collect_rows(results, out: Path, bar) -> list[dict]:
    """The result rows of ``results`` (the executor's (job, row) pairs) as they come; a failed job raises
    :class:`JobFailed` naming it."""
    rows = []
    while True:
        try:
            job, row = next(results)
        except StopIteration:
            return rows
        except Exception as exc:
            failed = getattr(exc, "job", None)
            where = (
                f"{failed['scene']} {failed['method']} seed {failed['seed']} ({failed['run_dir']})"
                if failed
                else "a job"
            )
            raise JobFailed(
                f"experiment job {where} failed: {type(exc).__name__}: {exc}. Finished jobs are kept "
                f"under {out}; fix the cause and run the same command again to resume"
            ) from exc
        rows.append(row)
        bar.update(1)
        log.info(
            "done: %s %s seed %d (PSNR %s, D-bar %s)",
            job["scene"],
            job["method"],
            job["seed"],
            row.get("psnr"),
            row.get("dbar"),
        )


def run_experiment(config: ExperimentConfig, executor, progress: bool = True, threads: int = 1) -> dict[str, Any]:
    """Run every job through ``executor`` (``nbv.study.executors``), then write results.json, the tables and plots.

    Logs the time estimate before the first job (``threads``: CPU threads per worker) and the actual time beside
    it after the last.

    Returns:
        {"rows": per-job result rows, "tables": {name: Markdown}, "files": written paths}.
    """
    check_scenes(config)
    jobs = plan_jobs(config)  # every job's ActiveConfig is validated here, before the output folder exists
    out = Path(config.output)
    left = sum(not job_done(j) for j in jobs)
    line, est = time_estimate(jobs, getattr(executor, "workers", 1), threads)
    log.info("%s", line)
    started = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out / "experiment.json", {"config": {k: getattr(config, k) for k in CONFIG_KEYS}})
    remove_stale_temps(out)
    with tqdm(total=len(jobs), desc="jobs", unit="job", disable=not progress) as bar:
        results = executor.map(run_job, jobs)
        try:
            rows = collect_rows(results, out, bar)
        finally:  # a signal here too stops the executor's workers (the generator's clean-up)
            close = getattr(results, "close", None)
            if close is not None:
                close()
    log.info("%s", actual_line(est, time.perf_counter() - started, left))
    order = {(j["scene"], j["method"], j["seed"]): i for i, j in enumerate(jobs)}
    rows.sort(key=lambda r: order[(r["scene"], r["method"], r["seed"])])
    write_json_atomic(out / "results.json", {"rows": rows})
    return write_tables(rows, config, out)
