"""The oracle: what every view-scoring rule is worth against the view that actually helps.

A *state* of the active loop (:mod:`nbv.active`) is the set of views selected so far and the model trained on them:
the biased initial views plus the picks of a planner (FisherRF by default, any registered planner), reached by the
loop itself (:meth:`nbv.active.ActiveRun.reach`: its training, its planners and their contexts) before its selection
round with that many views. At a state the study

1. trains a copy of the model once per remaining candidate, for M iterations (``horizon``) with that candidate added
   to the selected views, and once without (:func:`copy_gains`). Every copy starts from the same trainer state
   (parameters, Adam moments, iteration, RNG), so they share the seed and the schedule. The candidate's **oracle
   gain** is the difference in mean test PSNR (dB) with and without it (the image target, :func:`image_target`); the
   SSIM gain is recorded too;
2. scores every remaining candidate with every rule of :data:`nbv.study.oracle_config.RULES` (the physics rules once
   per probe setting, through the probe run and the per-Gaussian values the planners use:
   :func:`nbv.active.probes.probe_run`, :func:`nbv.plan.fused.per_gaussian_values`);
3. with a mesh, computes the per-Gaussian calibration (:mod:`nbv.study.calibration`).

Each state is written to ``OUTPUT/states/<scene>/seed<k>/state<n>.json`` (atomically), so an interrupted study
resumes: a state whose file holds the same config is not recomputed, and its selected views spare the planner's picks
of the larger states.

The summary (``OUTPUT/oracle.json`` and ``OUTPUT/oracle.md``), per rule:

- the mean Spearman between its scores and the oracle gains over the states, with a 95 % bootstrap interval that
  resamples the (scene, seed) pairs (the states of one run are not independent);
- the regret of its pick inside FisherRF's greedy top-K (K = max(B - n, 2), or ``top_k``): the best gain of the
  shortlist minus the gain of the rule's pick there (dB);
- for a physics rule, the paired difference of its Spearman against its coverage control, with the same interval and
  the sign-test and Wilcoxon p-values over the states (:mod:`nbv.study.paired`).
"""

from __future__ import annotations

import copy
import json
import logging
import math
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch
from tqdm import tqdm

from fluidsim.files import read_json
from nbv.active import ActiveRun, planner_seed
from nbv.active.probes import ProbeRun, probe_run
from nbv.io import json_safe, write_json_atomic, write_text_atomic
from nbv.physics import PhysicsConfig
from nbv.physics.thin import thin_or_open, thin_or_open_gaussians
from nbv.plan import PlanningContext, fused_k
from nbv.plan.fisher import FisherPlanner
from nbv.plan.fisher_info import FisherConfig, view_fisher
from nbv.plan.fused import balanced_scores, per_gaussian_values
from nbv.plan.fvs import farthest_view_distances
from nbv.plan.physics import physics_view_scores
from nbv.plan.rules import VALUES
from nbv.plan.variance import VariancePlanner
from nbv.plan.variance_model import VarianceConfig
from nbv.ranking import spearman
from nbv.study import calibration as cal
from nbv.study.experiment_config import scene_names
from nbv.study.oracle_config import RULES, OracleConfig, Rule, rule_of
from nbv.study.oracle_pool import state_problem
from nbv.study.oracle_summary import format_summary, summarise
from recon.datasets import load_dataset
from recon.gaussians import GaussianSet
from recon.mesh_render import load_mesh
from recon.train import Trainer, evaluate, view_to

log = logging.getLogger(__name__)

CALIBRATION_SAMPLES = 2000  # mesh samples of the missing geometry
MISSING_OPACITY = 0.05  # Gaussians below it cover nothing (the authors' solid threshold)


# ---- planning ----------------------------------------------------------------------------------------
def state_path(output: str | Path, scene: str, seed: int, n: int) -> Path:
    return Path(output) / "states" / scene / f"seed{seed}" / f"state{n}.json"


def check_scenes(config: OracleConfig) -> dict[str, dict]:
    """Load every scene once (before any training) and check it against the config.

    Returns:
        scene path -> {"candidates": train views, "test": test views, "mesh": mesh path or None}.
    Raises:
        ValueError: a scene that does not load, has no test views, or too few candidates for the largest state,
            naming the config key and the fix.
    """
    out = {}
    acfg, largest = config.active_config(config.seeds[0]), max(config.states)
    for scene in config.scenes:
        try:
            ds = load_dataset(scene, resolution=acfg.resolution)
        except ValueError as exc:
            raise ValueError(f"oracle config 'scenes': {exc}") from exc
        if not ds.test:
            raise ValueError(
                f"oracle config 'scenes': {scene} has no test views; the oracle gain is a test PSNR, so "
                "render the dataset with test views (fluidgs render-dataset --test N) or drop the scene"
            )
        if largest >= len(ds.train):
            raise ValueError(
                f"oracle config 'states': a state of {largest} views leaves no candidate of the "
                f"{len(ds.train)} in {scene}; use states below {len(ds.train)}"
            )
        if acfg.budget > len(ds.train):
            raise ValueError(
                f"oracle config 'active': budget {acfg.budget} exceeds the {len(ds.train)} candidates of "
                f"{scene}; lower active.budget"
            )
        out[scene] = {
            "candidates": len(ds.train),
            "test": len(ds.test),
            "mesh": None if ds.mesh_path is None else str(ds.mesh_path),
        }
    return out


STUDY_ONLY_KEYS = ("scenes", "seeds", "states", "output", "bootstrap")  # keys that do not change a state's content


def state_key(config: OracleConfig) -> dict:
    """What a state file must match to be reused: the config without the keys that only choose or summarise states
    (so adding a seed or a state to a finished study reuses its states)."""
    return {k: v for k, v in json_safe(config.to_dict()).items() if k not in STUDY_ONLY_KEYS}


def plan_jobs(config: OracleConfig) -> list[dict]:
    """One picklable job per (scene, seed, state)."""
    cfg, path = json_safe(config.to_dict()), partial(state_path, config.output)
    return [
        {"scene": name, "dataset": scene, "seed": seed, "n": n, "config": cfg, "path": str(path(name, seed, n))}
        for scene, name in zip(config.scenes, scene_names(config.scenes), strict=True)
        for seed in config.seeds
        for n in sorted(config.states)
    ]


def _stored(path: Path, config: dict) -> dict | None:
    """The state file at ``path`` when it holds a finished state of ``config`` (:func:`state_key`)."""
    if not path.is_file():
        return None
    try:
        data = read_json(path, "the state file", "it is computed again")
    except ValueError:  # not a finished state (cut short, garbage, nested too deeply): the state is computed again
        return None
    key = {k: v for k, v in config.items() if k not in STUDY_ONLY_KEYS}
    return data if state_problem(data) is None and data.get("config") == key else None


@contextmanager
def _timed(seconds: dict[str, float], name: str) -> Iterator[None]:
    """Note the wall time of the ``with`` body in ``seconds[name]``."""
    t0 = time.perf_counter()
    yield
    seconds[name] = time.perf_counter() - t0


# ---- probes and rules --------------------------------------------------------------------------------
class SettingRun(NamedTuple):
    """One probe setting at a state: its probe run (:func:`nbv.active.probes.probe_run`; None where the setting's
    rules read the solid only) and [N] bool where the solid is thin or open (:func:`nbv.physics.thin.thin_or_open`;
    every Gaussian when they form no solid)."""

    probes: ProbeRun | None
    thin: torch.Tensor


def setting_run(gaussians: GaussianSet, physics: PhysicsConfig, probes: bool, source: str) -> SettingRun:
    """The probes of one setting on ``gaussians`` and the thin-or-open mask of their solid; with ``probes`` False
    the solid alone (:func:`nbv.physics.thin.thin_or_open_gaussians`, as the ``+thin-area`` planners read it)."""
    if not probes:
        return SettingRun(None, thin_or_open_gaussians(gaussians, physics))
    run = probe_run(gaussians, physics, source)
    res = run.result
    if res is None:
        return SettingRun(run, torch.ones(gaussians.num, dtype=torch.bool))
    thin = thin_or_open(res.solid, 2.0 * physics.particle_radius, res.means, res.reach)
    return SettingRun(run, torch.from_numpy(thin))


def setting_context(context: PlanningContext, run: SettingRun) -> PlanningContext:
    """``context`` reading one setting's run: its D_g, its per-probe fields and its thin-or-open mask."""
    probes = run.probes
    return replace(
        context,
        physics=None if probes is None else lambda gaussians: probes.divergence,
        probe_fields=None if probes is None else lambda gaussians: probes.fields,
        solid_mask=lambda gaussians: run.thin,
    )


def score_rules(
    config: OracleConfig, context: PlanningContext, physics: dict[str, PhysicsConfig], seed: int, shortlist_k: int
) -> tuple[dict[str, list[float]], list[int], dict[str, Any]]:
    """Every rule's score of every candidate of ``context``.

    Args:
        config: the study (its rules and probe settings).
        context: the state (Gaussians, selected views, all remaining candidates).
        physics: probe setting name -> PhysicsConfig (up direction resolved).
        seed: the planner seed of this round.
        shortlist_k: K of FisherRF's greedy shortlist.
    Returns:
        (rule label -> [C] scores, FisherRF's greedy shortlist (positions), extras: the per-setting runs
        (:class:`SettingRun`), seconds per rule family).
    """
    g, cams = context.gaussians, context.candidates
    count = len(cams)
    scores: dict[str, list[float]] = {}
    seconds: dict[str, float] = {}
    wanted = set(config.scored_rules())

    def summed(at: PlanningContext, rule: Rule, who: str) -> list[float]:
        """S(T) of the rule's per-Gaussian values at ``at``, with the rule's visibility."""
        v = per_gaussian_values(rule.values, at, seed, who)
        return physics_view_scores(g, cams, v, occlusion=rule.depth_test)

    with _timed(seconds, "fisher"):
        shortlist, fisher = FisherPlanner(FisherConfig(seed=seed)).rank(context, min(shortlist_k, count))
    scores["fisher"] = list(fisher)
    if "variance" in wanted:
        with _timed(seconds, "variance"):
            scores["variance"] = list(VariancePlanner(VarianceConfig(seed=seed)).rank(context, count)[1])
    if "fvs" in wanted:
        scores["fvs"] = farthest_view_distances(cams, [v.camera for v in context.train_views])
    if "random" in wanted:
        scores["random"] = np.random.default_rng([seed, 7]).random(count).tolist()
    with _timed(seconds, "coverage"):
        ones = per_gaussian_values("area", context, seed)
        coverage = {occ: physics_view_scores(g, cams, ones, occlusion=occ) for occ in (False, True)}
        for name, rule in RULES.items():  # the per-Gaussian rules without probes: the coverages, the transparencies
            if name in wanted and rule.per_gaussian and not rule.physics:
                scores[name] = coverage[rule.depth_test] if rule.values == "area" else summed(context, rule, name)
    runs = {}
    for setting, pcfg in physics.items():
        labels = [label for label in config.physics_rules() if label.endswith(f":{setting}")]
        if not labels:
            continue
        with _timed(seconds, f"probes:{setting}"):
            probes = any(VALUES[rule_of(label).values].probes for label in labels)
            runs[setting] = run = setting_run(g, pcfg, probes, f"probe setting {setting}")
        with _timed(seconds, f"scores:{setting}"):
            at = setting_context(context, run)
            cache: dict[tuple[str, bool], list[float]] = {}
            for label in labels:
                rule = rule_of(label)
                key = (rule.values, rule.depth_test)
                if key not in cache:
                    cache[key] = summed(at, rule, label)
                s, a = cache[key], coverage[rule.depth_test]
                if rule.combine == "balanced":
                    s = balanced_scores(a, s)
                elif rule.combine == "ratio":
                    s = [si / ai if ai > 0 else 0.0 for si, ai in zip(s, a, strict=True)]
                scores[label] = list(s)
    return scores, list(shortlist), {"runs": runs, "seconds": seconds}


# ---- the oracle --------------------------------------------------------------------------------------
def copy_gains(
    new_trainer: Callable[[], Trainer],
    state: dict,
    train_views: list,
    candidate_views: list,
    horizon: int,
    measure: Callable[[Trainer], dict[str, float]],
    progress: Callable[[], None] | None = None,
) -> dict[str, Any]:
    """Train one copy per candidate (and one without) for ``horizon`` iterations from ``state``; measure each.

    A candidate's gain in a metric is the copy's value with it minus the value without.

    Args:
        new_trainer: builds a Trainer of the run's config (its state is replaced by ``state``).
        state: :meth:`recon.train.Trainer.state_dict` of the state's model.
        train_views: the selected views. candidate_views: the C remaining views (their images are used here only).
        horizon: M iterations per copy.
        measure: a trained copy -> {metric: value} (a target: :func:`image_target`).
        progress: called after each copy.
    Returns:
        per metric m: ``m_base`` (the copy without a candidate), ``m`` [C] and ``gain_m`` [C].
    """

    def run(views: list) -> dict[str, float]:
        trainer = new_trainer()
        trainer.load_state_dict(copy.deepcopy(state))
        trainer.train(views, horizon)
        metrics = measure(trainer)
        if progress is not None:
            progress()
        return metrics

    base = run(list(train_views))
    per = [run(list(train_views) + [view]) for view in candidate_views]
    out: dict[str, Any] = {f"{m}_base": base[m] for m in base}
    out.update({m: [p[m] for p in per] for m in base})
    out.update({f"gain_{m}": [p[m] - base[m] for p in per] for m in base})
    return out


def object_target(mesh_path: Path, physics: PhysicsConfig):
    """The dataset's object as a functional target (:class:`nbv.functional.FunctionalTarget`, its flows cached)."""
    from nbv.functional import FlowCache, FunctionalTarget  # noqa: PLC0415
    from nbv.functional.solids import reference_source  # noqa: PLC0415

    return FunctionalTarget(
        reference_source(Path(mesh_path), physics, None, None), physics, FlowCache.from_environment()
    )


def image_target(test_views: list, background: Sequence[float]) -> Callable[[Trainer], dict[str, float]]:
    """The image target of a copy: its mean test PSNR (dB) and SSIM over the held-out views."""

    def measure(trainer: Trainer) -> dict[str, float]:
        metrics = evaluate(trainer.gaussians, test_views, background, backend=trainer.backend)
        return {"psnr": metrics["psnr"], "ssim": metrics["ssim"]}

    return measure


def functional_target(target) -> Callable[[Trainer], dict[str, float]]:
    """The functional target of a copy: its functional error against the object (``target``, a
    :class:`nbv.functional.FunctionalTarget`: the headline, the relative error of the time-mean force), and that
    error's noise floor (the same for every copy: the object against itself on a shifted lattice)."""

    def measure(trainer: Trainer) -> dict[str, float]:
        try:
            c = target.error(trainer.gaussians.detach().to("cpu"))
        except ValueError as exc:  # no solid, or none overlapping the object: the copy behaves like nothing
            log.warning("functional target: %s", exc)
            return {"functional_error": math.nan, "functional_floor": math.nan}
        return {"functional_error": c.error, "functional_floor": c.floor}

    return measure


def both_targets(*targets: Callable[[Trainer], dict[str, float]]) -> Callable[[Trainer], dict[str, float]]:
    """One measure from several targets (their metrics merged)."""

    def measure(trainer: Trainer) -> dict[str, float]:
        out: dict[str, float] = {}
        for t in targets:
            out.update(t(trainer))
        return out

    return measure


def functional_gains(oracle: dict[str, Any]) -> None:
    """The functional gain of each candidate, in place: the copy without it minus the copy with it
    (``gain_functional``, positive where the candidate lowers the functional error)."""
    if "functional_error" in oracle:
        oracle["gain_functional"] = [-g for g in oracle.pop("gain_functional_error")]
        oracle.pop("gain_functional_floor", None)


def oracle_gains(
    new_trainer: Callable[[], Trainer],
    state: dict,
    train_views: list,
    candidate_views: list,
    test_views: list,
    background: Sequence[float],
    horizon: int,
    progress: Callable[[], None] | None = None,
) -> dict[str, Any]:
    """The oracle gains of the image target (:func:`copy_gains` measured by :func:`image_target`).

    Returns:
        {"psnr_base", "ssim_base", "psnr": [C], "ssim": [C], "gain_psnr": [C] dB, "gain_ssim": [C]}.
    """
    target = image_target(test_views, background)
    return copy_gains(new_trainer, state, train_views, candidate_views, horizon, target, progress)


def fisher_diagonal(gaussians: GaussianSet, cameras: list, background: torch.Tensor) -> torch.Tensor:
    """[N] the Fisher information of each Gaussian over the selected views (the trace of its diagonal block)."""
    h = torch.zeros(gaussians.num, dtype=torch.float64)
    for cam in cameras:
        h += view_fisher(gaussians, cam, background).to(torch.float64).sum(dim=1).cpu()
    return h


def calibrate(
    gaussians: GaussianSet,
    mesh_path: str,
    train_cameras: list,
    candidate_cameras: list,
    background: torch.Tensor,
    signals_physics: dict[str, torch.Tensor],
    scores: dict[str, list[float]],
    gains: list[float],
    seed: int,
) -> dict[str, Any]:
    """The per-Gaussian calibration of one state (module :mod:`nbv.study.calibration`).

    Every signal is oriented as an uncertainty (larger = more likely wrong): D_g and its variants as they are,
    1 - opacity, the largest scale, and minus the Fisher information. Reported per signal: the Spearman of the
    oriented signal with the Gaussian's distance to the mesh (positive: it points at wrong geometry) and the AUSE.
    """
    vertices, triangles = load_mesh(mesh_path)
    g = gaussians.detach().to("cpu")
    dist = cal.surface_distance(g.means.double().numpy(), vertices, triangles)
    signals = {
        "opacity": 1.0 - g.opacities.double(),
        "largest scale": g.max_radii().double(),
        "fisher diagonal": -fisher_diagonal(g, train_cameras, background),
    }
    signals.update(signals_physics)
    out: dict[str, Any] = {
        "gaussians": g.num,
        "mean_distance": float(dist.mean()),
        "median_distance": float(np.median(dist)),
        "signals": {},
    }
    for name, u in signals.items():
        u = u.numpy() if isinstance(u, torch.Tensor) else np.asarray(u)
        out["signals"][name] = {
            "spearman": spearman(u, dist),
            "ause": cal.ause(u, dist),
            "reached": float((u > 0).mean()) if name.startswith("D_g") else None,
        }
    samples = cal.sample_surface(vertices, triangles, CALIBRATION_SAMPLES, seed)
    missing = cal.missing_samples(samples, g, 2.0, MISSING_OPACITY)
    seen = cal.visible_samples(samples, candidate_cameras, vertices, triangles)
    per_view = (seen & missing[None]).sum(axis=1).astype(float)
    out["missing"] = {"samples": CALIBRATION_SAMPLES, "missing": int(missing.sum()), "per_view": per_view.tolist()}
    out["rules_vs_missing"] = {label: spearman(s, per_view) for label, s in scores.items()}
    out["gain_vs_missing"] = spearman(gains, per_view)
    return out


# ---- one state ---------------------------------------------------------------------------------------
def calibration_signals(runs: dict[str, SettingRun], context: PlanningContext, seed: int) -> dict[str, torch.Tensor]:
    """The per-Gaussian physics signals of the calibration, per probe setting that ran the probes: D_g, each probe
    normalised, the excess over the empty scene (when run) and D_g where the solid is thin or open."""
    signals = {}
    for setting, run in runs.items():
        if run.probes is None:
            continue
        at = setting_context(context, run)
        names = {"D_g": "fluid", "perprobe": "perprobe", "excess": "excess", "thin": "thin"}
        if run.probes.fields.empty_per_probe is None:
            del names["excess"]
        signals.update({f"{k}:{setting}": per_gaussian_values(v, at, seed) for k, v in names.items()})
    return signals


def run_state(job: dict, progress: Callable[[], None] | None = None) -> dict:
    """Reach one state, measure its oracle gains, score the rules, calibrate; write and return the state record.

    Needs an initialised Taichi runtime when a rule or the reaching planner runs the probes.
    """
    path = Path(job["path"])
    stored = _stored(path, job["config"])
    if stored is not None:
        log.info("%s: already measured", path)
        return stored
    config = OracleConfig(**job["config"])  # its lists become tuples there
    seed, target = int(job["seed"]), int(job["n"])
    seconds: dict[str, float] = {}
    with _timed(seconds, "reach"):
        active = ActiveRun(job["dataset"], None, config.active_config(seed), progress=False)
        reached = active.reach(target, _known_picks(job, config))
    ds, views, context, selected = active.dataset, active.views, reached.context, reached.selected
    remaining = context.candidate_ids
    k = config.top_k if config.top_k is not None else fused_k(active.config.budget, target)
    ps = planner_seed(seed, reached.round)
    with _timed(seconds, "rules"):
        scores, shortlist, extra = score_rules(config, context, config.probe_configs(active.physics_config.up), ps, k)
    with _timed(seconds, "oracle"):
        oracle = copy_gains(
            partial(active.new_trainer, active.config.total_iterations),
            reached.trainer.state_dict(),
            [views[i] for i in selected],
            [views[i] for i in remaining],
            config.horizon,
            state_measure(config, active),
            progress,
        )
        functional_gains(oracle)
    seconds.update(extra["seconds"])
    record: dict[str, Any] = {
        "config": state_key(config),
        "scene": job["scene"],
        "dataset": job["dataset"],
        "seed": seed,
        "n_selected": target,
        "selected": selected,
        "candidates": remaining,
        "candidate_names": [views[i].name for i in remaining],
        "num_gaussians": context.gaussians.num,
        "shortlist": shortlist,
        "k": k,
        "oracle": oracle,
        "scores": scores,
        "thin_share": {name: float(run.thin.double().mean()) for name, run in extra["runs"].items()},
    }
    if config.calibration and ds.mesh_path is not None:
        with _timed(seconds, "calibration"):
            record["calibration"] = calibrate(
                context.gaussians,
                str(ds.mesh_path),
                [v.camera for v in context.train_views],
                context.candidates,
                active.background,
                calibration_signals(extra["runs"], context, ps),
                scores,
                oracle["gain_psnr"],
                seed,
            )
    record["seconds"] = seconds
    path.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(path, json_safe(record))
    return record


def state_measure(config: OracleConfig, active: ActiveRun) -> Callable[[Trainer], dict[str, float]]:
    """What a copy of the model is worth: its test images, and with a functional target in the config and a mesh in
    the dataset, also how it behaves in the fluid."""
    ds = active.dataset
    measure = image_target([view_to(v, active.device) for v in ds.test], ds.background)
    functional = config.functional_config(active.physics_config.up)
    if functional is not None and ds.mesh_path is not None:
        measure = both_targets(measure, functional_target(object_target(ds.mesh_path, functional)))
    return measure


def _known_picks(job: dict, config: OracleConfig) -> list[int]:
    """The longest selected-view list of a finished state of the same (scene, seed) at or below this one."""
    best: list[int] = []
    for n in config.states:
        if n <= int(job["n"]):
            stored = _stored(state_path(config.output, job["scene"], job["seed"], n), job["config"])
            if stored is not None and len(stored["selected"]) > len(best):
                best = list(stored["selected"])
    return best


def _state_task(job: dict) -> dict:
    rec = run_state(job)
    return {"scene": rec["scene"], "seed": rec["seed"], "n": rec["n_selected"], "seconds": rec["seconds"]}


def run_oracle(config: OracleConfig, executor, progress: bool = True) -> dict[str, Any]:
    """Check the scenes, run every missing state through ``executor`` (:mod:`nbv.study.executors`), summarise.

    Returns:
        {"summary": :func:`summarise`, "markdown": the tables, "files": written paths}.
    """
    scenes = check_scenes(config)
    out = Path(config.output)
    out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out / "oracle-config.json", {"config": json_safe(config.to_dict()), "scenes": scenes})
    jobs = plan_jobs(config)
    todo = [j for j in jobs if _stored(Path(j["path"]), j["config"]) is None]
    with tqdm(total=len(jobs), initial=len(jobs) - len(todo), desc="states", unit="state", disable=not progress) as bar:
        try:
            for job, row in executor.map(_state_task, todo):
                bar.update(1)
                log.info(
                    "done: %s seed %d state %d (%.0f s oracle)",
                    job["scene"],
                    job["seed"],
                    job["n"],
                    row["seconds"]["oracle"],
                )
        except Exception as exc:
            failed = getattr(exc, "job", None)
            where = f"{failed['scene']} seed {failed['seed']} state {failed['n']}" if failed else "a state"
            raise RuntimeError(
                f"oracle {where} failed: {exc}. Finished states are kept under {out / 'states'}; "
                "fix the cause and run the same command again to resume"
            ) from exc
    states = [json.loads(Path(j["path"]).read_text()) for j in jobs]
    summary = summarise(config, states)
    markdown = format_summary(summary)
    write_json_atomic(out / "oracle.json", json_safe(summary))
    write_text_atomic(out / "oracle.md", markdown)
    return {"summary": summary, "markdown": markdown, "files": [str(out / "oracle.json"), str(out / "oracle.md")]}
