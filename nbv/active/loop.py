"""The active-reconstruction loop (paper Sec. 3.5 and 4.1; protocol of FisherRF / ActiveNeRF).

Training starts from a few *biased* initial views (two by default) and adds one view per selection until
the view budget B (10) is reached:

1. before selection number s (``n_selected`` views so far) the Gaussians are trained
   ``n_selected x iterations_per_view`` iterations (the paper: n_selected x 100) on the selected views;
2. the planner (:mod:`nbv.plan`) sees the current Gaussians, the selected views and the remaining
   candidate *cameras* (never their images) and picks one; fused methods (``fisher+fluid``...) shortlist the
   visual top-K, K = max(B - n_selected, 2), run the five fluid probes once (:func:`nbv.physics.simulate_gaussians`)
   and take the candidate with the largest S(T) (Eq. 4-5); the controls ``fisher+area`` (coverage, no probes) and
   ``fisher+shuffled`` (D_g permuted), and the same on ``variance`` and ``random``, keep that shortlist and K;
3. after the budget is reached training continues to ``total_iterations`` (30k in the paper).

Two modes (``ActiveConfig.mode``):

- ``continue`` (the paper's setup): one :class:`recon.train.Trainer` keeps optimising the same Gaussians across
  rounds, with the schedule of a ``total_iterations`` run (learning-rate decay, densification, SH degree
  follow the global iteration count). Cheap, but what is learnt from the first views shapes what follows
  (path dependence).
- ``reset``: after every selection the Gaussians are re-initialised from the *initial* Gaussians and retrained
  from scratch on all selected views, each round with a complete schedule compressed to
  ``n_selected x iterations_per_view`` iterations, and the final model is a fresh ``total_iterations`` run on the
  B selected views. The final model then depends on *which* views were selected only, not on the order;
  it costs about B / 2 times more training.

Biased initial views: the candidate whose direction from the candidates' common look-at point is closest to an
anchor direction (``initial_direction``, or a unit vector drawn from ``seed``), then its nearest neighbours by
camera-centre distance, so that the initial views cover one side of the object only. ``initial_ids`` overrides.

Planners are rebuilt for every selection with the seed ``seed * 1000 + round`` (:func:`planner_seed`), so no
planner state crosses rounds and a resumed run makes the same choices as an uninterrupted one.

Run folder (every file is written atomically, through :mod:`nbv.io`)::

    RUN/config.json     {"dataset": absolute path, "active": ActiveConfig.to_dict()}
    RUN/rounds.json     {"rounds": [one record per selection, with its "timing" split], "final": {...} once finished,
                        with the run's "timing" (:mod:`nbv.active.timing`)}
    RUN/checkpoint.pt   completed rounds, selected ids, Trainer.state_dict (continue mode, and during the final
                        training in both modes), torch RNG, phase
    RUN/gaussians.ply   the final Gaussians (3DGS .ply)

The final training (to ``total_iterations``) is checkpointed every ``final_checkpoint_every`` iterations, so an
interruption there loses at most that many iterations. Re-running on an existing RUN with the same config
resumes after the last complete round (or the last final-training checkpoint); a different config is
an error naming the differing keys (``overwrite=True`` starts again).
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import torch
from tqdm import tqdm

from fluidsim.files import remove_stale_temps
from nbv import scores
from nbv.active.config import CHECKPOINT_VERSION, ActiveConfig
from nbv.active.probes import probe_run
from nbv.active.run_dir import _state_to, load_checkpoint, prepare_run_dir
from nbv.active.timing import round_timing, run_timing
from nbv.coverage import coverage_line, ranking_agreement, view_parts
from nbv.io import write_atomic, write_json_atomic
from nbv.physics.scene_frame import describe_auto_up
from nbv.physics.thin import thin_or_open_gaussians
from nbv.plan import PLANNERS, Planner, PlanningContext, ProbeFields, Selection, make_planner, reads_empty_scene
from recon.datasets import load_dataset
from recon.formats.ply import save_gaussians
from recon.frames import up_from_cameras
from recon.gaussians import GaussianSet
from recon.train import Trainer, initial_gaussians, look_at_point, scene_extent, view_to

log = logging.getLogger(__name__)


# ---- initial views and seeds -------------------------------------------------------------------------
def anchor_direction(seed: int) -> torch.Tensor:
    """[3] float64 unit vector drawn from ``seed`` (normalised Gaussian sample)."""
    gen = torch.Generator().manual_seed(int(seed))
    v = torch.randn(3, generator=gen, dtype=torch.float64)
    return v / v.norm()


def biased_initial_views(
    cameras: Sequence, count: int, seed: int = 0, direction: Sequence[float] | None = None
) -> list[int]:
    """Biased initial views: the camera closest to an anchor direction, then its nearest neighbours.

    Args:
        cameras: the C candidate cameras (``recon.camera.Camera``).
        count: number of views (1 <= count <= C).
        seed: draws the anchor direction when ``direction`` is None.
        direction: (x, y, z) anchor direction from the cameras' common look-at point.
    Returns:
        ``count`` distinct indices: first the camera with the largest cosine between its direction from the look-at
        point and the anchor, then the others by increasing camera-centre distance to it (ties: lower index).
    """
    if not 1 <= count <= len(cameras):
        raise ValueError(f"initial views: need 1 <= count <= {len(cameras)} candidates, got {count}")
    centres = torch.stack([c.center for c in cameras]).to(torch.float64)
    target = look_at_point(cameras)
    d = (
        anchor_direction(seed)
        if direction is None
        else torch.tensor([float(v) for v in direction], dtype=torch.float64)
    )
    d = d / d.norm()
    dirs = centres - target
    cos = (dirs @ d) / dirs.norm(dim=-1).clamp_min(1e-12)
    first = int(torch.argsort(-cos, stable=True)[0])
    dist = (centres - centres[first]).norm(dim=-1)
    order = torch.argsort(dist, stable=True).tolist()
    return [first] + [i for i in order if i != first][: count - 1]


def planner_seed(seed: int, round_index: int) -> int:
    """The planner seed of one selection round (planners are rebuilt each round; see the module docstring)."""
    return int(seed) * 1000 + int(round_index)


# ---- the loop ----------------------------------------------------------------------------------------


def pick_parts(context: PlanningContext, pick: int, fields: ProbeFields | None) -> dict:
    """Coverage beside a pick: every candidate's coverage A(T) = sum of w_g over the Gaussians it counts (with the
    round's visibility), and, when the round ran probes, its physics part S / A with D_g the max over the probes
    and the agreement of the S and A rankings (:func:`nbv.coverage.ranking_agreement`).

    Returns:
        {"occlusion", "coverage": {candidate id: A}, "pick_coverage_rank"; with probes also "physics_mean":
        {id: S / A or None}, "pick_physics_rank" and "agreement"}.
    """
    ids = [str(i) for i in context.candidate_ids]
    g = context.gaussians.detach()
    buffer = scores.DepthBuffer() if context.occlusion else None
    ones = torch.ones(g.num, dtype=torch.float64)
    d = ones if fields is None else torch.as_tensor(fields.per_probe, dtype=torch.float64).amax(0).cpu()
    scored = scores.projected_view_scores(d, g, list(context.candidates), depth_buffer=buffer)
    parts = view_parts(scored.scores.numpy(), scored.coverage.numpy())
    out: dict[str, Any] = {
        "occlusion": bool(context.occlusion),
        "coverage": {i: p["coverage"] for i, p in zip(ids, parts, strict=True)},
        "pick_coverage_rank": parts[pick]["coverage_rank"],
    }
    if fields is not None:
        out["physics_mean"] = {i: p["physics_mean"] for i, p in zip(ids, parts, strict=True)}
        out["pick_physics_rank"] = parts[pick]["physics_rank"]
        out["agreement"] = ranking_agreement(scored.scores.numpy(), scored.coverage.numpy())
    return out


def parts_summary(parts: dict) -> str:
    """One log phrase on a pick's parts: its coverage rank, and with probes its physics rank and the coverage line."""
    n = len(parts["coverage"])
    text = f"coverage rank {parts['pick_coverage_rank']} of {n}"
    if "agreement" in parts:
        text += f", physics-part rank {parts['pick_physics_rank']}; {coverage_line(parts['agreement'])}"
    return text


@dataclass
class Reached:
    """A state of a run (:meth:`ActiveRun.reach`): the model trained before the pick of round ``round``.

    Attributes:
        trainer: trained as the loop trains before that pick (its ``state_dict`` is the state's model).
        selected: the ``n_selected`` views selected so far (ids of the train split).
        round: the round whose pick is next (0-based; :func:`planner_seed` of the run's seed and it seeds it).
        context: that round's planning context, as the loop builds it (the probes, their fields and the solid's
            mask of the selection physics, run when read).
        record: what the context's callables noted (probe and mask times).
    """

    trainer: Trainer
    selected: list[int]
    round: int
    context: PlanningContext
    record: dict


@dataclass
class RunState:
    """Progress of a run (what checkpoint.pt holds besides the trainer)."""

    selected: list[int]
    rounds: list[dict]
    phase: str = "rounds"  # "rounds" while selecting, "final" while training to the end, "done" once written


def load_active_dataset(dataset_path: str | Path, config: ActiveConfig):
    """The dataset at the run's resolution, checked against the config (before any training).

    Raises:
        ValueError: too few train (candidate) views for the budget, or an initial id out of range.
    """
    ds = load_dataset(dataset_path, resolution=config.resolution)
    n = len(ds.train)
    if n < config.budget:
        raise ValueError(
            f"{dataset_path}: {n} candidate (train) views but the budget is {config.budget}; "
            "lower --budget or render more train views"
        )
    if config.initial_ids is not None and max(config.initial_ids) >= n:
        raise ValueError(
            f"--initial-views {list(config.initial_ids)} out of range: the train split has {n} views (0..{n - 1})"
        )
    return ds


def dataset_up(spec: str | tuple[float, float, float] | None, dataset) -> str | tuple[float, float, float]:
    """The probes' up direction for ``dataset`` (a ``recon.datasets.Dataset``).

    Args:
        spec: None (the dataset's ``up_axis``), "auto" (:func:`recon.frames.up_from_cameras` of the training
            cameras, logged) or an explicit direction.
    Returns:
        An up spec for :class:`nbv.physics.PhysicsConfig` ("+y", "-y", or a 3-tuple).
    """
    if spec is None:
        return "+" + dataset.up_axis
    if spec != "auto":
        return spec

    up = up_from_cameras([v.camera for v in dataset.train])
    log.info("%s (training cameras)", describe_auto_up(up))
    return tuple(float(c) for c in up)


class ActiveRun:
    """One active-reconstruction run in a folder: :meth:`run` executes or resumes it; :meth:`reach` replays its
    rounds in memory up to a state (the oracle study measures there).

    Args:
        dataset_path: Blender or COLMAP dataset (its train split is the candidate set).
        run_dir: output folder (see the module docstring); None for a run that only reaches states (:meth:`reach`) and
            writes nothing.
        config: the run's settings.
        physics_fn: per-Gaussian D_g [N] of a Gaussian set; default: the five probes of ``config.physics``
            (needs an initialised Taichi runtime). Tests pass a cheap stand-in.
        on_round: called with each round record after its checkpoint is written.
        final_checkpoint_every: iterations between checkpoints of the final training (>= 1; default 1000).
        on_final_checkpoint: called with the trainer's iteration after each final-training checkpoint.
        device: torch device of the Gaussians and images.
        overwrite: discard an existing run in ``run_dir``.
        progress: tqdm bars.
    """

    def __init__(
        self,
        dataset_path: str | Path,
        run_dir: str | Path | None,
        config: ActiveConfig,
        *,
        physics_fn: Callable[[GaussianSet], torch.Tensor] | None = None,
        on_round: Callable[[dict], None] | None = None,
        device: str = "cpu",
        overwrite: bool = False,
        progress: bool = True,
        final_checkpoint_every: int = 1000,
        on_final_checkpoint: Callable[[int], None] | None = None,
    ) -> None:
        if (
            isinstance(final_checkpoint_every, bool)
            or not isinstance(final_checkpoint_every, int)
            or final_checkpoint_every < 1
        ):
            raise ValueError(f"final_checkpoint_every must be an integer >= 1, got {final_checkpoint_every!r}")
        self.final_checkpoint_every = final_checkpoint_every
        self.on_final_checkpoint = on_final_checkpoint

        if config.method not in PLANNERS:
            raise ValueError(f"unknown method {config.method!r}; use one of {sorted(PLANNERS)}")
        self.config = config
        self.run_dir = None if run_dir is None else Path(run_dir)
        self.dataset_path = Path(dataset_path)
        self.device = device
        self.on_round = on_round
        self.progress = progress
        self.dataset = load_active_dataset(dataset_path, config)
        self.physics_config = replace(config.physics, up=dataset_up(config.up, self.dataset))
        if self.physics_config.empty_reference and not reads_empty_scene(config.method):
            # the pick never reads the empty scene, and the rounds record no D-bar of it: running it would double
            # every round's probe time for nothing
            log.info("%s does not read the empty-scene probes: the rounds run without them", config.method)
            self.physics_config = replace(self.physics_config, empty_reference=False)
        self.physics_fn = physics_fn
        run_config = {"dataset": str(self.dataset_path.resolve()), "active": config.to_dict()}
        self.resumable = self.run_dir is not None and prepare_run_dir(self.run_dir, run_config, overwrite)
        self.views = [view_to(v, device) for v in self.dataset.train]
        self.cameras = [v.camera for v in self.dataset.train]
        self.extent = scene_extent(self.cameras)
        self.background = torch.tensor(self.dataset.background, dtype=torch.float32, device=device)
        init_cfg = config.train_config(config.total_iterations)
        self.initial = initial_gaussians(init_cfg, self.cameras, self.dataset.points, self.dataset.point_colors).to(
            device
        )
        self._write_seconds = 0.0  # this session's rounds.json and checkpoint writes (the run's "other" part)

    # ---- pieces --------------------------------------------------------------------------------
    def initial_ids(self) -> list[int]:
        c = self.config
        if c.initial_ids is not None:
            return list(c.initial_ids)
        return biased_initial_views(self.cameras, c.initial_count, c.seed, c.initial_direction)

    def new_trainer(self, iterations: int) -> Trainer:
        return Trainer(
            self.initial,
            self.config.train_config(iterations),
            extent=self.extent,
            data_background=self.dataset.background,
            backend=self.config.backend,
        )

    def _physics(self, record: dict, fields: dict) -> Callable[[GaussianSet], torch.Tensor]:
        """The context's physics callable; it notes D-bar, per-probe D-bar and the time in ``record``, and puts
        the run's :class:`nbv.plan.ProbeFields` in ``fields["fields"]``."""

        def run(gaussians: GaussianSet) -> torch.Tensor:
            t0 = time.perf_counter()
            if self.physics_fn is not None:
                d = torch.as_tensor(self.physics_fn(gaussians)).to(torch.float64).cpu()
                record["physics"] = {"seconds": time.perf_counter() - t0, "source": "custom"}
                fields["fields"] = ProbeFields(("custom",), d.reshape(1, -1))
                return d

            probes = probe_run(gaussians, self.physics_config, f"round {record['round']}", self.progress)
            fields["fields"] = probes.fields
            res = probes.result
            if res is None:
                record["physics"] = {"seconds": time.perf_counter() - t0, "error": probes.error}
                return probes.divergence
            covs = torch.from_numpy(res.covariances)
            record["physics"] = {
                "seconds": time.perf_counter() - t0,
                "dbar": res.dbar,
                "solid_particles": int(len(res.solid)),
                **({} if res.replicas is None else {"replicas": res.replicas.summary()}),
                "dbar_per_direction": {
                    d: scores.geometry_divergence(covs, torch.from_numpy(res.per_probe[i]))
                    for i, d in enumerate(res.directions)
                },
            }
            return probes.divergence

        return run

    def _solid_mask(self, record: dict) -> Callable[[GaussianSet], torch.Tensor]:
        """The context's ``solid_mask`` (the ``+thin-area`` planners): the thin-or-open Gaussians under the selection
        physics, from the solid alone; it notes the time and the share in ``record``."""

        def get(gaussians: GaussianSet) -> torch.Tensor:
            t0 = time.perf_counter()
            mask = thin_or_open_gaussians(gaussians, self.physics_config)
            record["solid_mask"] = {"seconds": time.perf_counter() - t0, "share": float(mask.double().mean())}
            return mask

        return get

    @staticmethod
    def _probe_fields(physics: Callable[[GaussianSet], torch.Tensor], fields: dict):
        """The context's ``probe_fields``: the per-probe D_g of ``physics``'s run (it runs the probes if needed)."""

        def get(gaussians: GaussianSet):
            if "fields" not in fields:
                physics(gaussians)
            return fields["fields"]

        return get

    def _train_round(self, trainer: Trainer | None, selected: list[int], r: int, n: int) -> tuple[Trainer, dict]:
        """Step 1 of round ``r``: train ``n x iterations_per_view`` iterations on the ``n`` selected views (a fresh
        trainer in reset mode). Returns the trainer and the training record."""
        iters = n * self.config.iterations_per_view
        if self.config.mode == "reset":
            trainer = self.new_trainer(max(iters, 1))
        return trainer, self._train(trainer, [self.views[i] for i in selected], iters, f"round {r + 1} train")

    def _context(self, trainer: Trainer, selected: list[int], r: int, n: int, record: dict, fields: dict):
        """Step 2 of round ``r``: what the planner sees (the probes, their fields and the solid's mask run only when
        the planner asks for them, noting their times in ``record``; the fields go to ``fields["fields"]``)."""
        remaining = [i for i in range(len(self.views)) if i not in set(selected)]
        physics = self._physics(record, fields)
        return PlanningContext(
            gaussians=trainer.gaussians,
            train_views=[self.views[i] for i in selected],
            candidates=[self.cameras[i] for i in remaining],
            candidate_ids=remaining,
            n_selected=n,
            budget=self.config.budget,
            background=self.background,
            physics=physics,
            round=r,
            occlusion=self.config.occlusion,
            probe_fields=self._probe_fields(physics, fields),
            sh_degree=trainer.active_sh_degree,
            solid_mask=self._solid_mask(record),
        )

    def _planner(self, r: int) -> Planner:
        c = self.config
        return make_planner(c.method, **{**dict(c.planner), "seed": planner_seed(c.seed, r)})

    def reach(self, n_selected: int, picks: Sequence[int] = ()) -> Reached:
        """Replay the rounds in memory (no file is written) up to the state of ``n_selected`` views: the rounds
        before it train and pick as :meth:`run` does, the state's round trains and stops before its pick.

        Args:
            n_selected: the state, a round's ``n_selected`` (``config.rounds()``).
            picks: known picks of this run (the selected ids in order, initial views first): where they reach, the
                planner is not asked, its pick is taken from them (the training is replayed all the same).
        Returns:
            :class:`Reached`.
        """
        c = self.config
        if n_selected not in c.rounds():
            raise ValueError(f"reach: {n_selected} selected views is not a round of this run (rounds {c.rounds()})")
        selected = self.initial_ids()
        trainer = self.new_trainer(c.total_iterations) if c.mode == "continue" else None
        for r, n in enumerate(c.rounds()):
            trainer, _ = self._train_round(trainer, selected, r, n)
            record: dict[str, Any] = {"round": r, "n_selected": n}
            context = self._context(trainer, selected, r, n, record, {})
            if n == n_selected:
                return Reached(trainer, selected, r, context, record)
            known = len(picks) > n
            selected.append(int(picks[n]) if known else context.candidate_ids[self._planner(r).select(context).pick])
        raise AssertionError("unreachable: n_selected is a round")

    def _train(
        self,
        trainer: Trainer,
        views: list,
        iterations: int,
        label: str,
        chunk: int = 0,
        after_chunk: Callable[[], None] | None = None,
    ) -> dict:
        """Train ``iterations`` iterations on ``views`` (in chunks of ``chunk``, calling ``after_chunk`` after
        each); returns the training record."""
        summary: dict[str, Any] = {"iterations": 0, "seconds": 0.0}
        if iterations <= 0:
            return summary
        with tqdm(total=iterations, desc=label, unit="it", disable=not self.progress, leave=False) as bar:
            while summary["iterations"] < iterations:
                n = min(chunk or iterations, iterations - summary["iterations"])
                out = trainer.train(views, n, callback=lambda st: bar.update(1))
                summary["iterations"] += n
                summary["seconds"] += out.wall_time_s
                summary["final_loss"] = out.losses[-1]
                summary["final_psnr"] = out.psnrs[-1]
                summary["num_gaussians"] = out.num_gaussians[-1]
                if after_chunk is not None:
                    after_chunk()
        return summary

    def _train_final(self, state: RunState, trainer: Trainer, views: list) -> dict:
        """Train to ``total_iterations`` in chunks, with a checkpoint (trainer included) after each chunk."""
        start = trainer.iteration

        def checkpoint() -> None:
            self._save_checkpoint(state, trainer)
            if self.on_final_checkpoint is not None:
                self.on_final_checkpoint(trainer.iteration)

        remaining = self.config.total_iterations - start
        summary = self._train(trainer, views, remaining, "final train", self.final_checkpoint_every, checkpoint)
        summary["resumed_from_iteration"] = start
        return summary

    def _save_checkpoint(self, state: RunState, trainer: Trainer | None) -> None:
        payload = {
            "version": CHECKPOINT_VERSION,
            "config": self.config.to_dict(),
            "selected": list(state.selected),
            "rounds": len(state.rounds),
            "phase": state.phase,
            "trainer": None if trainer is None else trainer.state_dict(),
            "torch_rng": torch.get_rng_state(),
        }
        write_atomic(self.run_dir / "checkpoint.pt", lambda tmp: torch.save(payload, tmp))

    def _write_rounds(self, state: RunState, final: dict | None = None) -> None:
        data = {
            "method": self.config.method,
            "mode": self.config.mode,
            "budget": self.config.budget,
            "initial_ids": state.selected[: self.config.initial_count],
            "selected": list(state.selected),
            "selected_names": [self.views[i].name for i in state.selected],
            "rounds": state.rounds,
        }
        if final is not None:
            data["final"] = final
        write_json_atomic(self.run_dir / "rounds.json", data)

    def _load(self) -> tuple[RunState, Trainer | None]:
        ckpt = load_checkpoint(self.run_dir / "checkpoint.pt")
        if ckpt.get("version") != CHECKPOINT_VERSION:
            raise ValueError(
                f"{self.run_dir / 'checkpoint.pt'} has checkpoint version {ckpt.get('version')}, "
                f"expected {CHECKPOINT_VERSION}; pass --overwrite to start again"
            )
        rounds_path = self.run_dir / "rounds.json"
        rounds = json.loads(rounds_path.read_text())["rounds"][: ckpt["rounds"]] if rounds_path.is_file() else []
        if len(rounds) != ckpt["rounds"]:
            raise ValueError(
                f"{rounds_path} has {len(rounds)} rounds but the checkpoint {ckpt['rounds']}; "
                "pass --overwrite to start again"
            )
        torch.set_rng_state(ckpt["torch_rng"])
        trainer = None
        if ckpt["trainer"] is not None:
            trainer = self.new_trainer(self.config.total_iterations)
            trainer.load_state_dict(_state_to(ckpt["trainer"], self.device))
        return RunState(list(ckpt["selected"]), rounds, ckpt["phase"]), trainer

    # ---- driver --------------------------------------------------------------------------------
    def run(self) -> dict:
        """Run (or resume) the loop; returns the rounds.json content."""
        if self.run_dir is None:
            raise ValueError("ActiveRun.run needs a run folder (run_dir); a run without one can only reach states")
        t_start = time.perf_counter()
        stale = remove_stale_temps(self.run_dir)  # left by a run killed at once (SIGKILL): this run owns the folder
        if stale:
            log.info(
                "%s: removed %d temporary file(s) of an earlier run killed while writing", self.run_dir, len(stale)
            )
        state, trainer = self._start()
        if state.phase == "done":
            return json.loads((self.run_dir / "rounds.json").read_text())
        for r, n in enumerate(self.config.rounds()):
            if r >= len(state.rounds):
                trainer = self._run_round(state, trainer, r, n)
        return self._finish(state, trainer, t_start)

    def _start(self) -> tuple[RunState, Trainer | None]:
        """The state to go on from: the checkpoint's when resuming, else the initial views (rounds.json written)."""
        c = self.config
        if self.resumable:
            state, trainer = self._load()
            log.info("%s: resuming after %d of %d selections", self.run_dir, len(state.rounds), len(c.rounds()))
            return state, trainer
        state = RunState(self.initial_ids(), [])
        trainer = self.new_trainer(c.total_iterations) if c.mode == "continue" else None
        self._write_rounds(state)
        return state, trainer

    def _run_round(self, state: RunState, trainer: Trainer | None, r: int, n: int) -> Trainer | None:
        """Round ``r`` (``n`` views selected): train, plan, pick; the round's record, rounds.json and checkpoint
        written. Returns the trainer the next round goes on with."""
        c = self.config
        t0, cpu0 = time.perf_counter(), time.process_time()
        trainer, training = self._train_round(trainer, state.selected, r, n)
        training_seconds = time.perf_counter() - t0
        record: dict[str, Any] = {"round": r, "n_selected": n, "training": training}
        fields: dict = {}
        context = self._context(trainer, state.selected, r, n, record, fields)
        remaining = context.candidate_ids
        t_plan = time.perf_counter()
        sel = self._planner(r).select(context)
        if not 0 <= sel.pick < len(remaining):
            raise ValueError(f"planner {c.method!r} picked position {sel.pick} of {len(remaining)} candidates")
        pick = remaining[sel.pick]
        record.update(self._selection_record(remaining, sel, pick, t_plan))
        t_parts = time.perf_counter()
        record["parts"] = pick_parts(context, sel.pick, fields.get("fields"))
        end = time.perf_counter()
        record["round_seconds"] = end - t0
        record["cpu_seconds"] = time.process_time() - cpu0
        record["timing"] = round_timing(
            round_seconds=record["round_seconds"],
            training=training_seconds,
            selection=record["selection_seconds"],
            visual=float(sel.seconds.get("visual", 0.0)),
            probes=float(record.get("physics", {}).get("seconds", 0.0))
            + float(record.get("solid_mask", {}).get("seconds", 0.0)),
            parts=end - t_parts,
        )
        state.selected.append(pick)
        state.rounds.append(record)
        # rounds.json first: a crash between the two files leaves a checkpoint that is one round behind, and
        # _load trims rounds.json to the checkpoint.
        self._write_rounds(state)
        self._save_checkpoint(state, trainer if c.mode == "continue" else None)
        self._write_seconds += time.perf_counter() - end
        log.info(
            "round %d/%d: picked %s (%d) from %d candidates in %.1f s; %s",
            r + 1,
            len(c.rounds()),
            self.views[pick].name,
            pick,
            len(remaining),
            record["round_seconds"],
            parts_summary(record["parts"]),
        )
        if self.on_round is not None:
            self.on_round(record)
        return trainer

    def _selection_record(self, remaining: list[int], sel: Selection, pick: int, t_plan: float) -> dict[str, Any]:
        """What a round records of its selection: the candidates, the shortlist, every score and the pick."""
        return {
            "candidates": remaining,
            "candidate_names": [self.views[i].name for i in remaining],
            "shortlist": [remaining[p] for p in sel.shortlist],
            "k": sel.k,
            "scores": {
                name: {str(remaining[p]): float(v) for p, v in enumerate(vals)} for name, vals in sel.scores.items()
            },
            "pick": pick,
            "pick_name": self.views[pick].name,
            "planner_seconds": dict(sel.seconds),
            "selection_seconds": time.perf_counter() - t_plan,
        }

    def _finish(self, state: RunState, trainer: Trainer | None, t_start: float) -> dict:
        c = self.config
        t_final = time.perf_counter()
        views = [self.views[i] for i in state.selected]
        if trainer is None or (c.mode == "reset" and state.phase != "final"):
            trainer = self.new_trainer(c.total_iterations)
        state.phase = "final"
        training = self._train_final(state, trainer, views)
        gaussians = trainer.gaussians
        save_gaussians(gaussians, self.run_dir / "gaussians.ply")
        state.phase = "done"
        final_seconds = time.perf_counter() - t_final
        final = {
            "training": training,
            "iterations": trainer.iteration,
            "num_gaussians": gaussians.num,
            "seconds_this_session": time.perf_counter() - t_start,
            "timing": run_timing(
                state.rounds, training["seconds"], max(final_seconds - training["seconds"], 0.0) + self._write_seconds
            ),
        }
        self._write_rounds(state, final)
        self._save_checkpoint(state, None)
        return json.loads((self.run_dir / "rounds.json").read_text())


def run_active(dataset_path: str | Path, run_dir: str | Path, config: ActiveConfig, **kwargs: Any) -> dict:
    """Run or resume an active-reconstruction run (see :class:`ActiveRun` for the keyword arguments).

    Returns:
        The rounds.json content (per-round records and the final summary).
    """
    return ActiveRun(dataset_path, run_dir, config, **kwargs).run()
