"""Where a probe run's time goes, and what a shorter run would change (``fluidgs bench probes``).

No paper equation is implemented here. :func:`trace_probes` runs the probes of a Gaussian set (and, optionally, the
empty scene's) as :func:`nbv.physics.simulate_gaussians` does (the same frame, solid, plan, solvers and accumulator),
with the solver's stages timed, and records per probe:

- the fluid particles, the steps, the mean solver iterations, and the seconds of each solver stage (the
  neighbourhood pass, the two solves, D_i, the forces, ...) and of the per-Gaussian aggregation;
- the running D_g^(IC) every ``every`` steps (the means a probe stopped there would give: the accumulation is a
  running mean whose integer sums do not depend on when they are read), so that any stop rule can be judged from one
  uncut run (:func:`judge_rule`);
- the share of the slab's particles that ever came within reach of a Gaussian (:func:`reach_mask`: a cell of half a
  spacing counts as within reach when its centre lies within a Gaussian's reach plus the cell's half diagonal, so the
  share is an upper bound), checked every ``reach_every`` steps.

:func:`judge_rule` applies a :class:`nbv.physics.early_stop.StopRule` to the recorded means (the empty-scene probe
stops where its solid probe did) and compares the stopped answer with the uncut one: the view ranking (Spearman of
S(T) over orbit cameras, depth-tested), the per-Gaussian D_g (Spearman) and D-bar / D-bar_empty (relative move).

The report of the command is made here too, as lines and JSON rows: :func:`profile_report` (per probe and stage),
:func:`judge_cuts` and :func:`cut_report` (the stop rules and fixed lengths), :func:`save_traces` and
:func:`against_line` (a run's answer saved, and compared with a saved one).

:func:`rounding_floor` runs the uncut probes again with the time step nudged by a millionth of itself: the same
physics with other float roundings. The answer moves under that by more than the fixed criteria above allow (measured
on the bundled asset and a real capture, docs/performance.md), so a cut that is not bit-identical is judged against
this floor as well (:class:`RoundingFloor`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from fluidsim.probes import build_probe_solver, probe_setups
from fluidsim.simulation import run as run_solver
from nbv import scores
from nbv.bench import timed
from nbv.physics.aggregate import GaussianAccumulator, GaussianLists
from nbv.physics.early_stop import StopRule, relative_change
from nbv.physics.plan import ProbePlan, RunFrame
from nbv.ranking import spearman
from nbv.view_scoring import project_scores

# A cut is kept when, on every capture, the stopped run agrees with the uncut one at least this well.
VIEW_SPEARMAN_MIN = 0.97
DG_SPEARMAN_MIN = 0.9
RATIO_MOVE_MAX = 0.05
# A rounding replica runs the uncut probes again with dt nudged by this fraction of itself (a few float32 ulps): the
# same physics, other roundings. How far that moves the answer is the floor under any cut that is not bit-identical.
ROUNDING_NUDGE = 1e-6
# The solver stages timed apart, in the order of the profile's columns (the rest of the step is one more column).
STAGES = ("neighbors", "divergence_solve", "density_solve", "divergence_estimate", "forces")


@dataclass
class ProbeTrace:
    """One probe's run: sizes, times and the running means (see the module docstring)."""

    direction: str
    empty: bool
    fluid: int
    steps: int = 0
    density_iterations: float = 0.0
    divergence_iterations: float = 0.0
    stage_s: dict[str, float] = field(default_factory=dict)
    aggregation_s: float = 0.0
    wall_s: float = 0.0  # the probe's whole time, less the recording of this trace
    checkpoints: list[int] = field(default_factory=list)  # steps run at each recorded mean
    means: list[np.ndarray] = field(default_factory=list)  # [G] float32 running D_g^(IC) at each checkpoint
    reached: float = float("nan")  # share of the slab's particles ever within reach of a Gaussian
    reached_by: list[tuple[int, float]] = field(default_factory=list)  # (steps run, share reached so far)
    touched: list[int] = field(default_factory=list)  # Gaussians with a sample at each checkpoint

    def means_at(self, steps_run: int) -> np.ndarray:
        """The running means after ``steps_run`` steps (a checkpoint)."""
        return self.means[self.checkpoints.index(steps_run)].astype(np.float64)


def reach_mask(centers: np.ndarray, reach: np.ndarray, lo, hi, cell: float) -> np.ndarray:
    """[nx, ny, nz] bool over the box (lo, hi) in cells of ``cell`` m: True where the cell's centre lies within a
    Gaussian's reach plus the cell's half diagonal (a superset of the cells a particle within reach can sit in)."""
    lo = np.asarray(lo, np.float64)
    shape = np.maximum(np.ceil((np.asarray(hi, np.float64) - lo) / cell).astype(int), 1)
    mask = np.zeros(shape, bool)
    grow = cell * math.sqrt(3.0) / 2.0
    centers = np.asarray(centers, np.float64)
    radius = np.asarray(reach, np.float64) + grow
    span = np.ceil(radius / cell).astype(int)
    base = np.floor((centers - lo) / cell).astype(int)
    for k in np.unique(span):
        sel = np.nonzero(span == k)[0]
        for chunk in np.array_split(sel, max(1, len(sel) // 65536)):
            b, c, r = base[chunk], centers[chunk], radius[chunk]
            for dx in range(-k, k + 1):
                for dy in range(-k, k + 1):
                    for dz in range(-k, k + 1):
                        idx = b + np.array([dx, dy, dz])
                        centre = lo + (idx + 0.5) * cell
                        ok = (np.linalg.norm(centre - c, axis=1) <= r) & (idx >= 0).all(1) & (idx < shape).all(1)
                        if ok.any():
                            i = idx[ok]
                            mask[i[:, 0], i[:, 1], i[:, 2]] = True
    return mask


def trace_probes(
    frame: RunFrame,
    plan: ProbePlan,
    solid_points: np.ndarray,
    *,
    every: int = 25,
    reach_every: int = 5,
    empty: bool = True,
    progress: bool = True,
) -> tuple[list[ProbeTrace], dict[str, float]]:
    """Run the probes of ``plan`` (and the empty scene's, with ``empty``) for ``frame.config.steps`` steps each,
    recording a :class:`ProbeTrace` per probe.

    Returns:
        (the traces, solid probes first; {"lists": s, "mask": s} the set-up times).
    """
    config = frame.config
    scfg, probe = config.solver_config(), config.probe_config()
    centers, reach = frame.means, frame.reach
    lo, hi = plan.bounds
    cell = 0.5 * scfg.spacing
    lists, lists_s, _ = timed(GaussianLists, centers, reach, lo, hi)
    mask, mask_s, _ = timed(reach_mask, centers, reach, lo, hi, cell)
    runs = [(d, False) for d in config.directions] + ([(d, True) for d in config.directions] if empty else [])
    counts = plan.fluid_counts(config.directions)
    bar = tqdm(
        total=sum(counts[d] for d, _ in runs) * config.steps,
        desc="probes",
        bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}<{remaining}",
        disable=not progress,
        leave=False,
    )
    traces = []
    for d, is_empty in runs:
        setup = plan.setups[d]
        bar.set_description_str(f"{'empty ' if is_empty else ''}{d}", refresh=False)
        solver = build_probe_solver(np.zeros((0, 3)) if is_empty else solid_points, setup, scfg, probe)
        trace = ProbeTrace(d, is_empty, int(solver.fluid.capacity))
        solver.stage_times = {}
        acc = GaussianAccumulator(lists, setup.domain_min, setup.domain_max, max_fluid=solver.fluid.capacity)
        ever = np.zeros(solver.fluid.capacity, bool)
        side = np.asarray(mask.shape)
        extra = [0.0]  # seconds spent recording the trace, left out of the probe's time

        def on_step(s, st, acc=acc, trace=trace, ever=ever, side=side, extra=extra):
            trace.aggregation_s += timed(acc.add_from_solver, s)[1]
            n = st.step + 1
            t = time.perf_counter()
            if n % reach_every == 0 or n == 1:
                x, ids = s.fluid.numpy("x"), s.fluid.numpy("ids")
                c = np.floor((x - lo) / cell).astype(int)
                ok = (c >= 0).all(1) & (c < side).all(1)
                hit = np.zeros(len(x), bool)
                hit[ok] = mask[c[ok, 0], c[ok, 1], c[ok, 2]]
                ever[ids[hit]] = True
            if n % every == 0:
                m = acc.means()
                trace.checkpoints.append(n)
                trace.means.append(m.astype(np.float32))
                trace.touched.append(int(np.count_nonzero(acc.counts)))
                trace.reached_by.append((n, float(ever.mean())))
            extra[0] += time.perf_counter() - t
            bar.update(trace.fluid)

        t0 = time.perf_counter()
        history = run_solver(solver, config.steps, on_step=on_step)
        trace.aggregation_s += timed(acc.flush)[1]
        trace.wall_s = time.perf_counter() - t0 - extra[0]
        trace.steps = len(history)
        trace.density_iterations = float(np.mean([h.density_iterations for h in history]))
        trace.divergence_iterations = float(np.mean([h.divergence_iterations for h in history]))
        trace.stage_s = dict(solver.stage_times)
        trace.reached = float(ever.mean())
        traces.append(trace)
        del solver, acc
    bar.close()
    return traces, {"lists": lists_s, "mask": mask_s}


def converged_step(trace: ProbeTrace, tolerance: float) -> int:
    """The first checkpoint from which the running means stay within ``tolerance`` (relative L1,
    :func:`nbv.physics.early_stop.relative_change`) of the final ones: when D_g^(IC) stopped changing."""
    final = trace.means[-1].astype(np.float64)
    step = trace.checkpoints[-1]
    for n, m in zip(reversed(trace.checkpoints), reversed(trace.means), strict=True):
        if relative_change(final, m.astype(np.float64)) > tolerance:
            break
        step = n
    return step


def rule_stop(trace: ProbeTrace, rule: StopRule) -> int:
    """The steps a probe would run under ``rule`` (its checks at the recorded checkpoints; the full run when no
    check passes). The checkpoints must include every multiple of ``rule.window``."""
    if not rule.enabled:
        return trace.checkpoints[-1]
    for n in trace.checkpoints:
        if not rule.checks_at(n) or n - rule.window not in trace.checkpoints:
            continue
        if relative_change(trace.means_at(n - rule.window), trace.means_at(n)) <= rule.tolerance:
            return n
    return trace.checkpoints[-1]


@dataclass(frozen=True)
class Judged:
    """A stop rule's answer against the uncut run's, on one capture."""

    stops: dict[str, int]
    step_share: float  # fluid particle-steps run, of the uncut run's (solid and empty probes)
    view_spearman: float
    dg_spearman: float
    ratio_move: float  # |ratio_cut / ratio_uncut - 1| of D-bar / D-bar_empty (NaN without the empty scene)

    @property
    def kept(self) -> bool:
        ratio_ok = math.isnan(self.ratio_move) or self.ratio_move <= RATIO_MOVE_MAX
        return self.view_spearman >= VIEW_SPEARMAN_MIN and self.dg_spearman >= DG_SPEARMAN_MIN and ratio_ok


def answer(traces: list[ProbeTrace], stops: dict[str, int], covariances: np.ndarray):
    """(D_g = max over the probes, D-bar / D-bar_empty or NaN) with each probe (and its empty scene) stopped at
    ``stops[direction]`` steps."""
    solid = [t for t in traces if not t.empty]
    empties = [t for t in traces if t.empty]
    d_g = np.max([t.means_at(stops[t.direction]) for t in solid], axis=0)
    dbar = scores.geometry_divergence(torch.from_numpy(covariances), torch.from_numpy(d_g))
    if not empties:
        return d_g, float("nan")
    d_e = np.max([t.means_at(stops[t.direction]) for t in empties], axis=0)
    dbar_e = scores.geometry_divergence(torch.from_numpy(covariances), torch.from_numpy(d_e))
    return d_g, dbar / dbar_e if dbar_e > 0 else float("nan")


def full_stops(traces: Sequence[ProbeTrace]) -> dict[str, int]:
    """{direction: the steps it ran}: every probe uncut."""
    return {t.direction: t.checkpoints[-1] for t in traces}


def judge_stops(traces: list[ProbeTrace], stops: dict[str, int], covariances: np.ndarray, view_scores) -> Judged:
    """Compare the answer with the probes stopped at ``stops`` against the uncut one (``view_scores(values [G]) ->
    [C]`` scores the candidate views)."""
    full = full_stops(traces)
    d_cut, r_cut = answer(traces, stops, covariances)
    d_full, r_full = answer(traces, full, covariances)
    run = sum(t.fluid * stops[t.direction] for t in traces)
    whole = sum(t.fluid * full[t.direction] for t in traces)
    return Judged(
        stops=dict(stops),
        view_spearman=spearman(view_scores(d_cut), view_scores(d_full)),
        dg_spearman=spearman(d_cut, d_full),
        ratio_move=ratio_move(r_cut, r_full),
        step_share=run / whole,
    )


def ratio_move(ratio: float, reference: float) -> float:
    """|ratio / reference - 1|, NaN without a reference (no empty scene)."""
    return abs(ratio / reference - 1.0) if reference and not math.isnan(reference) else float("nan")


def rounding_dt(dt: float, k: int) -> float:
    """Rounding replica k's (1, 2, 3, ...) time step: dt (1 + n), dt (1 - n), dt (1 + 2 n), ... with n
    :data:`ROUNDING_NUDGE`."""
    if k < 1:
        raise ValueError(f"a rounding replica is numbered from 1, got {k}")
    m = (k + 1) // 2
    return dt * (1.0 + (m if k % 2 else -m) * ROUNDING_NUDGE)


@dataclass(frozen=True)
class RoundingFloor:
    """How far rounding alone moves the uncut answer: each rounding replica's agreement with the uncut run (the same
    physics with dt nudged by :data:`ROUNDING_NUDGE`, so other float roundings from the first step on).

    A cut that is not bit-identical changes the roundings too, so it cannot be expected to agree with the uncut run
    better than these; :meth:`holds` asks whether it agrees at least as well as the worst replica."""

    views: tuple[float, ...]
    dg: tuple[float, ...]
    ratio: tuple[float, ...]  # relative moves of D-bar / D-bar_empty (NaN without the empty scene)

    @classmethod
    def of(cls, uncut: tuple[np.ndarray, float, np.ndarray], replicas) -> RoundingFloor:
        """From the uncut (D_g, ratio, view scores) and each replica's."""
        d_g, ratio, views = uncut
        return cls(
            tuple(spearman(v, views) for _, _, v in replicas),
            tuple(spearman(d, d_g) for d, _, _ in replicas),
            tuple(ratio_move(r, ratio) for _, r, _ in replicas),
        )

    def holds(self, view_spearman: float, dg_spearman: float, move: float) -> bool:
        """Whether an answer that agrees with the uncut one this well is within the floor."""
        ratio_ok = math.isnan(move) or not all(map(math.isfinite, self.ratio)) or move <= max(self.ratio)
        return view_spearman >= min(self.views) and dg_spearman >= min(self.dg) and ratio_ok

    def line(self) -> str:
        """One line: the replicas and the range of each figure."""

        def span(values, fmt):
            return f"{fmt(min(values))}-{fmt(max(values))}" if len(values) > 1 else fmt(values[0])

        ratio = "n/a" if not all(map(math.isfinite, self.ratio)) else span(self.ratio, lambda v: f"{100 * v:.2g} %")
        return (
            f"rounding floor ({len(self.views)} uncut runs with dt nudged by {ROUNDING_NUDGE:g} of itself, against the "
            f"uncut run): views {span(self.views, lambda v: f'{v:.3f}')}, D_g {span(self.dg, lambda v: f'{v:.3f}')}, "
            f"ratio moved {ratio}"
        )


def rounding_floor(
    frame: RunFrame,
    plan: ProbePlan,
    solid_points: np.ndarray,
    uncut: tuple[np.ndarray, float, np.ndarray],
    replicas: int,
    view_scores,
    *,
    every: int = 25,
    empty: bool = True,
) -> RoundingFloor | None:
    """Run the uncut probes ``replicas`` more times at :func:`rounding_dt` and measure their agreement with ``uncut``
    (D_g, ratio, view scores): :class:`RoundingFloor` (None for no replicas: nothing is run)."""
    if replicas == 0:
        return None
    answers = []
    for k in range(1, replicas + 1):
        nudged = replace(frame, config=replace(frame.config, dt=rounding_dt(frame.config.dt, k)))
        traces, _ = trace_probes(nudged, plan, solid_points, every=every, empty=empty)
        d_g, ratio = answer(traces, full_stops(traces), frame.covariances)
        answers.append((d_g, ratio, view_scores(d_g)))
    return RoundingFloor.of(uncut, answers)


def judge_rule(traces: list[ProbeTrace], rule: StopRule, covariances: np.ndarray, view_scores) -> Judged:
    """:func:`judge_stops` with each probe stopped by ``rule`` (its empty scene at the same step)."""
    stops = {t.direction: rule_stop(t, rule) for t in traces if not t.empty}
    return judge_stops(traces, stops, covariances, view_scores)


# ---- the probe set-up of a run, and its report ------------------------------------------------------------------
def trimmed_plan(plan: ProbePlan, solid_points: np.ndarray, config, margin: float) -> ProbePlan:
    """``plan`` with its slabs spanning ``margin`` times the solid's largest extent (plus a spacing) past the solid
    across the flow, instead of the probes' default (``ProbeConfig.margin``)."""
    extent = float(np.ptp(solid_points, axis=0).max() + 2 * config.particle_radius)
    probe = replace(config.probe_config(), margin=margin * extent)
    return replace(plan, setups=probe_setups(solid_points, probe, plan.spacing, config.directions))


def view_scorer(gaussians, cameras, kept: np.ndarray | None) -> Callable[[np.ndarray], np.ndarray]:
    """``view_scores(values [G']) -> [C]``: S(T) of ``cameras`` from the projection with the coarse depth test, the
    values of the kept Gaussians (``kept`` [G] bool, None: all) scattered over the whole set (0 elsewhere)."""

    def view_scores(values: np.ndarray) -> np.ndarray:
        full = values if kept is None else np.zeros(len(kept))
        if kept is not None:
            full[kept] = values
        return project_scores(gaussians, cameras, full, occlusion=True).scores.numpy()

    return view_scores


def profile_report(traces: Sequence[ProbeTrace]) -> tuple[list[str], list[dict]]:
    """(lines, rows): a table with one line per probe (fluid, steps, iterations, seconds per stage, convergence,
    reach) and a line of the stages' shares of all probes; the rows are the JSON's, one per probe."""
    lines = ["probe       fluid steps  it d/v   nbhd  divS  densS  D_i  force  rest  aggr  total  D_g 1%/5%  reached"]
    rows = []
    for t in traces:
        st = t.stage_s
        rest = sum(st.values()) - sum(st.get(k, 0.0) for k in STAGES)
        name = ("empty " if t.empty else "") + t.direction
        c1, c5 = converged_step(t, 0.01), converged_step(t, 0.05)
        lines.append(
            f"{name:<9} {t.fluid:>7} {t.steps:>5} {t.density_iterations:4.2f}/{t.divergence_iterations:4.2f} "
            + " ".join(f"{st.get(k, 0.0):5.1f}" for k in STAGES)
            + f" {rest:5.1f} {t.aggregation_s:5.1f} {t.wall_s:6.1f}  {c1:>4}/{c5:<4}  {100 * t.reached:5.1f} %"
        )
        rows.append(
            {
                "probe": name,
                "fluid": t.fluid,
                "steps": t.steps,
                "density_iterations": t.density_iterations,
                "divergence_iterations": t.divergence_iterations,
                "stage_s": st,
                "aggregation_s": t.aggregation_s,
                "wall_s": t.wall_s,
                "converged_1pct": c1,
                "converged_5pct": c5,
                "reached": t.reached,
                "reached_by": t.reached_by,
                "touched": t.touched,
            }
        )
    total = sum(t.wall_s for t in traces)
    agg = sum(t.aggregation_s for t in traces)
    stage_tot = {k: sum(t.stage_s.get(k, 0.0) for t in traces) for k in STAGES}
    lines.append(
        f"all probes {total:.1f} s: "
        + ", ".join(f"{k} {100 * v / total:.0f} %" for k, v in stage_tot.items())
        + f", aggregation {100 * agg / total:.0f} %"
    )
    return lines, rows


def judge_cuts(
    traces: list[ProbeTrace],
    rules: Sequence[StopRule],
    fixed: Sequence[int],
    covariances: np.ndarray,
    view_scores,
) -> list[tuple[str, Judged]]:
    """(name, :class:`Judged`) of each stop rule ("rule tol T") and each fixed run length ("fixed N"), against the
    uncut run."""
    cuts = [(f"rule tol {rule.tolerance:g}", judge_rule(traces, rule, covariances, view_scores)) for rule in rules]
    for n in fixed:
        stops = {t.direction: n for t in traces if not t.empty}
        cuts.append((f"fixed {n}", judge_stops(traces, stops, covariances, view_scores)))
    return cuts


def cut_report(
    cuts: Sequence[tuple[str, Judged]], cameras: int, floor: RoundingFloor | None = None
) -> tuple[list[str], list[dict]]:
    """(lines, rows) of :func:`judge_cuts`' answer judged on ``cameras`` orbit cameras: the criteria, then one line
    (and one JSON row) per cut; with ``floor``, its line and a column saying whether each cut is within it."""
    lines = [
        f"judged against the uncut run on {cameras} orbit cameras (depth test); kept when views >= "
        f"{VIEW_SPEARMAN_MIN:g}, D_g >= {DG_SPEARMAN_MIN:g}, ratio move <= {100 * RATIO_MOVE_MAX:g} %",
    ]
    if floor is not None:
        lines.append(floor.line() + "; 'floor': the cut agrees at least as well as the worst of them")
    lines.append(
        "cut                      stops (per probe)               steps run  views  D_g    ratio   kept"
        + ("  floor" if floor is not None else "")
    )
    rows = []
    for name, j in cuts:
        stops = " ".join(f"{d}:{s}" for d, s in j.stops.items())
        within = None if floor is None else floor.holds(j.view_spearman, j.dg_spearman, j.ratio_move)
        lines.append(
            f"{name:<18} {stops:<38} {100 * j.step_share:5.1f} %  {j.view_spearman:.3f}  {j.dg_spearman:.3f}  "
            f"{100 * j.ratio_move:5.2f} %  {'yes' if j.kept else 'no ':<3}"
            + ("" if within is None else f"  {'yes' if within else 'no'}")
        )
        rows.append({"cut": name, **asdict(j), "kept": j.kept, "within_rounding_floor": within})
    return lines, rows


def npz_path(path: Path) -> Path:
    """The file :func:`save_traces` writes for ``path``: ``path`` itself, with ``.npz`` appended unless it ends so
    (as numpy's ``savez`` does)."""
    return Path(path) if str(path).endswith(".npz") else Path(f"{path}.npz")


def save_traces(
    path: Path,
    traces,
    covariances: np.ndarray,
    d_g: np.ndarray,
    ratio: float,
    views: np.ndarray,
    floor: RoundingFloor | None = None,
) -> Path:
    """Write a run's answer (covariances, D_g, D-bar / D-bar_empty, view scores), every probe's running means and
    checkpoints, and its rounding floor when measured, to :func:`npz_path` of ``path``; returns that path."""
    out = npz_path(path)
    extra = {} if floor is None else {"floor_views": floor.views, "floor_dg": floor.dg, "floor_ratio": floor.ratio}
    np.savez(
        out,
        covariances=covariances,
        d_g=d_g,
        ratio=ratio,
        views=views,
        **extra,
        **{f"{'empty' if t.empty else 'solid'}{t.direction}": np.stack(t.means) for t in traces},
        **{f"steps{'empty' if t.empty else 'solid'}{t.direction}": np.asarray(t.checkpoints) for t in traces},
    )
    return out


def against_line(path: Path, d_g: np.ndarray, ratio: float, views: np.ndarray) -> str:
    """How this run's answer agrees with the one :func:`save_traces` wrote to ``path``: the views' and D_g's
    Spearman, and D-bar / D-bar_empty against the saved one; with that run's rounding floor saved, whether this
    agreement is within it."""
    other = np.load(path)
    view_s, dg_s = spearman(views, other["views"]), spearman(d_g, other["d_g"])
    move = ratio_move(ratio, float(other["ratio"]))
    line = (
        f"against {path.name}: views Spearman {view_s:.3f}, D_g Spearman {dg_s:.3f}, D-bar / D-bar_empty {ratio:.4g} "
        f"against {float(other['ratio']):.4g} (moved {100 * move:.2f} %)"
    )
    if "floor_views" not in other:
        return line
    floor = RoundingFloor(*(tuple(float(v) for v in other[k]) for k in ("floor_views", "floor_dg", "floor_ratio")))
    return f"{line}; within its {floor.line()}: {'yes' if floor.holds(view_s, dg_s, move) else 'no'}"
