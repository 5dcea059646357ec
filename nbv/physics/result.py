"""The result of a probe run (:class:`PhysicsResult`) and its HDF5 file RESULT.h5 (:func:`save_result`,
:func:`load_result`, :func:`check_result_matches`)."""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import torch

from fluidsim import SimulationDiverged
from fluidsim.files import check_input_file
from nbv import scores
from nbv.io import atomic_h5
from nbv.physics.config import PhysicsConfig
from nbv.physics.forces import ProbeForces, result_forces
from nbv.physics.leaks import read_probe_leaks, write_probe_leaks
from nbv.physics.replicas import ReplicaRuns, read_replicas, write_replicas
from nbv.physics.scene_frame import SceneTransform, gaussian_arrays_in_sim
from nbv.physics.trajectory import read_trajectory, write_trajectory
from recon.inflate import check_hdf5_sizes


@dataclass
class PhysicsResult:
    """Everything one probe run on a Gaussian set produced (see :func:`save_result` for the HDF5 layout).

    Attributes:
        directions: the probes, in run order (P of them).
        per_probe: [P, G] float64 D_g^(IC), 1/s.
        per_probe_counts: [P, G] int64 (particle, step) samples per Gaussian.
        per_probe_distinct: [P, G] int64 |P_g| per probe, or None when not tracked.
        divergence: [G] D_g = max over the probes, 1/s.
        divergence_mean: [G] mean over the probes, 1/s.
        dbar, dbar_mean: D-bar of the max- and mean-combined D_g, m^4/s.
        dbar_empty, dbar_empty_mean: the same for the empty scene (None when not computed).
        empty_per_probe: [P, G] D_g^(IC) of the empty scene, or None.
        solid: [M, 3] solid particles, sim metres.
        transform: the scene -> simulation transform.
        means: [G, 3] Gaussian centres, sim metres. covariances: [G, 3, 3] sim metres^2.
        reach: [G] n r_g, sim metres.
        stats: per direction, the structured step statistics (fluidsim.output.stats_table).
        domains: per direction, (domain_min, domain_max) in sim metres.
        timings: seconds: solidify, simulation (steps only), aggregation, empty_reference, total.
        config: the PhysicsConfig. source: where the Gaussians came from.
        source_frame: JSON record of the frame the Gaussian file was read in and the transform applied to its
            values (:class:`recon.formats.SourceFrame`; "" when not recorded).
        kept: [G] bool, the Gaussians inside ``config.crop`` (None without a crop; the others have D_g = 0).
        warnings: per direction, what makes that probe's D_g suspect (no fluid reached any Gaussian, most fluid
            left the domain); empty lists when all is well.
        gaussians_sha256: :func:`gaussians_sha256` of the Gaussians simulated ("" in files written before it).
        status: "complete", or "diverged" (then ``directions`` are the probes completed before ``failure``).
        failure: None, or {"probe", "step", "reason"} of the probe that diverged.
        leaks: per direction, the probe's final fluid state and leak measure (:class:`nbv.physics.leaks.ProbeLeaks`);
            empty in files written before it.
        trajectories: per recorded direction, its fluid every k steps (:class:`nbv.physics.trajectory.ProbeTrajectory`;
            only with ``record``); :func:`load_result` reads them only when asked (``trajectories=True``).
        replicas: with ``config.replicas`` > 1, what each replica gave (:class:`nbv.physics.replicas.ReplicaRuns`);
            the fields above are then the replicas combined (:mod:`nbv.physics.replicas`). None: one run.
    """

    directions: tuple[str, ...]
    per_probe: np.ndarray
    per_probe_counts: np.ndarray
    per_probe_distinct: np.ndarray | None
    divergence: np.ndarray
    divergence_mean: np.ndarray
    dbar: float
    dbar_mean: float
    dbar_empty: float | None
    dbar_empty_mean: float | None
    empty_per_probe: np.ndarray | None
    solid: np.ndarray
    transform: Any
    means: np.ndarray
    covariances: np.ndarray
    reach: np.ndarray
    stats: dict[str, np.ndarray]
    domains: dict[str, tuple[np.ndarray, np.ndarray]]
    timings: dict[str, float]
    config: PhysicsConfig
    source: str = ""
    source_frame: str = ""
    kept: np.ndarray | None = None
    warnings: dict[str, list[str]] = field(default_factory=dict)
    gaussians_sha256: str = ""
    status: str = "complete"
    failure: dict[str, Any] | None = None
    leaks: dict[str, Any] = field(default_factory=dict)
    trajectories: dict[str, Any] = field(default_factory=dict)
    replicas: ReplicaRuns | None = None

    @property
    def num_gaussians(self) -> int:
        return int(self.divergence.shape[0])

    @property
    def reached(self) -> np.ndarray:
        """[G] bool, the Gaussians some probe's fluid reached (a (particle, step) sample within n r_g). The others
        have D_g = 0 because no fluid came near them, not because the flow is calm there: show them apart."""
        return np.asarray(self.per_probe_counts).sum(0) > 0

    @property
    def forces(self) -> dict[str, ProbeForces]:
        """Per probe, the force of its fluid on the solid (:class:`nbv.physics.forces.ProbeForces`: the series per
        step, N, simulation frame; the time mean over the second half; the impulse; drag, lift, side and their
        coefficients). Probes whose statistics predate the forces are left out."""
        return result_forces(self)

    def distinct_counts(self) -> np.ndarray:
        """[G] |P_g| summed over the probes (each probe has its own fluid particles); needs track_distinct."""
        if self.per_probe_distinct is None:
            raise ValueError("this result has no distinct particle counts; simulate with track_distinct=True")
        return self.per_probe_distinct.sum(0)


class ProbeDiverged(SimulationDiverged):
    """A probe diverged. ``probe`` and ``step`` say where; ``result`` holds the probes completed before it
    (``status`` "diverged", ``failure`` set), for saving: nothing computed is lost."""

    def __init__(self, probe: str, step: int, reason: str, result: PhysicsResult):
        super().__init__(step, reason)
        self.probe, self.result = probe, result
        done = ", ".join(result.directions) or "none"
        self.args = (f"probe {probe} diverged at step {step}: {reason} (probes completed: {done})",)


def gaussians_sha256(gaussians) -> str:
    """SHA-256 (hex) of what the probes depend on: the float32 bytes of means, quats, log_scales and
    opacity_logits, in that order (colours are left out, so a re-coloured copy has the same digest)."""
    h = hashlib.sha256()
    for t in (gaussians.means, gaussians.quats, gaussians.log_scales, gaussians.opacity_logits):
        h.update(np.ascontiguousarray(t.detach().cpu().numpy(), np.float32).tobytes())
    return h.hexdigest()


def _t(a: np.ndarray):
    return torch.from_numpy(np.asarray(a, np.float64))


# how a diverged run's failure is stored: attribute diverged_<key>, read back with the type
_FAILURE_KEYS = (("probe", str), ("step", int), ("reason", str))


# ---- HDF5 ------------------------------------------------------------------------------------------
def save_result(path: str | Path, result: PhysicsResult) -> Path:
    """Write a result to HDF5 atomically (a temporary file in the same folder, then rename).

    Layout::

        /gaussians/D            (G,) D_g, max over the probes, 1/s
        /gaussians/D_mean       (G,) mean over the probes, 1/s
        /gaussians/means        (G, 3) centres, sim metres
        /gaussians/covariances  (G, 3, 3) sim metres^2
        /gaussians/reach        (G,) n r_g, sim metres
        /gaussians/reached      (G,) bool, some probe's fluid reached the Gaussian (D_g = 0 otherwise: unmeasured)
        /probes/<dir>/D         (G,) D_g^(IC), 1/s
        /probes/<dir>/counts    (G,) (particle, step) samples
        /probes/<dir>/distinct  (G,) |P_g| (only with track_distinct)
        /probes/<dir>/D_empty   (G,) the empty-scene D_g^(IC) (only with the empty reference)
        /probes/<dir>/stats     one row per step (fluidsim StepStats fields, the forces on the solid and the walls
                                among them)
        /probes/<dir>/force     (S, 3) the force of the fluid on the solid per step, N, simulation frame (Y up)
                                attributes: mean (3,) N, the time mean over the second half of the run; impulse (3,)
                                N s; drag, lift, side (N, of the mean; NaN where undefined); C_d, C_l, C_s (NaN without
                                an inflow speed); area (m^2, projected normal to the flow); speed (m/s)
                                attributes: domain_min, domain_max (sim metres), warnings (JSON list of text)
        /probes/<dir>/leaked    (K,) int32 ids of the fluid particles inside the filled solid at the end (leaks.py:
                                the nearest lattice point and its 6 neighbours are solid; contact is not a leak)
                                attributes: final (K), max (the most inside after any step), max_step (0-based)
        /probes/<dir>/leaked_per_step  (S,) int32 particles inside after each step
        /probes/<dir>/x_final   (F, 3) float32 final fluid positions, sim metres, ordered by id (gzip)
        /probes/<dir>/ids_final (F,) int32 their ids (index in the probe's initial fluid set)
        /probes/<dir>/trajectory  only for the probes recorded (``record``): x (T, F, 3), D (T, F), speed (T, F),
                                steps (T,) every k steps (:mod:`nbv.physics.trajectory`; NaN: retired)
        /solid/x                (M, 3) solid particles, sim metres
        attributes: config (PhysicsConfig JSON), directions, dbar, dbar_mean, dbar_empty, dbar_empty_mean
                    (m^4/s; NaN when not computed), up (the scene's up vector, 3 floats), up_label ("-y", ...),
                    scale (m per scene unit), scene_to_sim (4x4: x_sim = M [x_scene, 1]), source (the Gaussian
                    file's absolute path), source_relative (the same relative to RESULT.h5's folder), timings (JSON)
        /gaussians/kept         (G,) bool, the Gaussians inside the crop (only with a crop)
        attributes too: gaussians_sha256 (:func:`gaussians_sha256`), status ("complete" or "diverged": then
                    /probes holds the probes completed before it, and diverged_probe, diverged_step,
                    diverged_reason say which probe diverged at which step and why)
        /replicas               only with config.replicas > 1 (:func:`nbv.physics.replicas.write_replicas`):
                                offsets (N, 3) spacings, D (N, P, G) each replica's D_g^(IC), distinct (N, P, G),
                                reached (N, G); attributes solid_points, seconds, spearman_gaussians_mean, _min,
                                _pairs (the per-Gaussian Spearman of D_g between replicas). The datasets above
                                are then the replicas combined.

    Returns:
        the path written.
    """
    p = Path(path)
    with atomic_h5(p) as f:
        g = f.create_group("gaussians")
        g["D"], g["D_mean"], g["means"] = result.divergence, result.divergence_mean, result.means
        g["covariances"], g["reach"], g["reached"] = result.covariances, result.reach, result.reached
        for i, d in enumerate(result.directions):
            _write_probe(f.create_group(f"probes/{d}"), result, i)
        f.create_dataset("solid/x", data=result.solid, compression="gzip", compression_opts=1)
        _write_run_attributes(f, result, p)
        if result.replicas is not None:
            write_replicas(f, result.replicas)
    return p


def _write_probe(pg, result: PhysicsResult, i: int) -> None:
    """/probes/<dir> of probe ``i`` (:func:`save_result`)."""
    d = result.directions[i]
    pg["D"], pg["counts"] = result.per_probe[i], result.per_probe_counts[i]
    if result.per_probe_distinct is not None:
        pg["distinct"] = result.per_probe_distinct[i]
    if result.empty_per_probe is not None:
        pg["D_empty"] = result.empty_per_probe[i]
    pg["stats"] = result.stats[d]
    # the early stop (nbv.physics.early_stop): the steps this probe (and its empty scene) ran
    pg.attrs["steps_run"] = len(result.stats[d])
    pg.attrs["stopped_early"] = len(result.stats[d]) < result.config.steps
    if d in result.forces:
        write_probe_force(pg, result.forces[d])
    if d in result.domains:
        pg.attrs["domain_min"], pg.attrs["domain_max"] = result.domains[d]
    pg.attrs["warnings"] = json.dumps(list(result.warnings.get(d, [])))
    if d in result.leaks:
        write_probe_leaks(pg, result.leaks[d])
    if d in result.trajectories:
        write_trajectory(pg, result.trajectories[d])


def _write_run_attributes(f, result: PhysicsResult, p: Path) -> None:
    """The file's attributes (and /gaussians/kept, written among them) (:func:`save_result`)."""
    f.attrs["config"] = json.dumps(result.config.to_dict())
    f.attrs["directions"] = json.dumps(list(result.directions))
    for key in ("dbar", "dbar_mean", "dbar_empty", "dbar_empty_mean"):
        v = getattr(result, key)
        f.attrs[key] = float("nan") if v is None else float(v)
    f.attrs["up"], f.attrs["up_label"] = np.asarray(result.transform.up), result.transform.up_label
    f.attrs["scale"], f.attrs["scene_to_sim"] = float(result.transform.scale), result.transform.matrix
    if result.kept is not None:
        f["gaussians"]["kept"] = np.asarray(result.kept, bool)
    f.attrs["source"], f.attrs["source_relative"] = _source_paths(result.source, p)
    f.attrs["source_frame"] = str(result.source_frame)
    f.attrs["timings"] = json.dumps(result.timings)
    f.attrs["gaussians_sha256"], f.attrs["status"] = result.gaussians_sha256, result.status
    if result.failure is not None:
        for key, _ in _FAILURE_KEYS:
            f.attrs[f"diverged_{key}"] = result.failure[key]


def write_probe_force(group, pf: ProbeForces) -> None:
    """The /probes/<dir>/force dataset and its attributes (:func:`save_result`)."""
    ds = group.create_dataset("force", data=pf.series)
    ds.attrs["mean"], ds.attrs["impulse"] = pf.mean, pf.impulse
    ds.attrs["area"], ds.attrs["speed"] = pf.area, pf.speed
    for key, v in pf.parts().items():
        ds.attrs[key] = float("nan") if v is None else v
    coefficients = pf.coefficients() if pf.area > 0 else None
    for key, name in (("drag", "C_d"), ("lift", "C_l"), ("side", "C_s")):
        v = None if coefficients is None else coefficients[key]
        ds.attrs[name] = float("nan") if v is None else v


def _source_paths(source: str, result_path: Path) -> tuple[str, str]:
    """(source, source_relative) of RESULT.h5: an existing Gaussian file as its absolute path and as a path relative
    to RESULT.h5's folder (so ``fluidgs view`` finds it from any working folder, and after both files move together);
    anything else as given, with no relative form."""
    if not source or not Path(source).exists():
        return str(source), ""
    absolute = Path(source).resolve()
    try:
        relative = os.path.relpath(absolute, result_path.resolve().parent)
    except ValueError:  # another drive (Windows)
        relative = ""
    return str(absolute), relative


def load_result(path: str | Path, trajectories: bool = False) -> PhysicsResult:
    """Read a result written by :func:`save_result` (``trajectories``: also the recorded probe trajectories, which
    can be large; by default ``PhysicsResult.trajectories`` is left empty).

    Raises:
        ValueError: naming the file when it is not such a result.
    """
    p = Path(path)
    check_input_file(p, "result file", "run `fluidgs simulate` to create it")
    try:
        with h5py.File(p, "r") as f:
            if "gaussians/D" not in f or "config" not in f.attrs:
                raise ValueError(f"{p} is not a `fluidgs simulate` result (no /gaussians/D); re-run `fluidgs simulate`")
            check_hdf5_sizes(f, str(p), skip=() if trajectories else ("trajectory",))  # before any is read
            return _read_result(f, trajectories)
    except (OSError, KeyError) as exc:
        raise ValueError(f"cannot read the result file {p}: {exc}; re-run `fluidgs simulate`") from exc


def _read_result(f, trajectories: bool) -> PhysicsResult:
    """The result in an open RESULT.h5 (:func:`load_result`)."""
    dirs = tuple(json.loads(f.attrs["directions"]))
    probes = [f[f"probes/{d}"] for d in dirs]
    g = f["gaussians/D"].shape[0]
    by_direction = list(zip(dirs, probes, strict=True))
    return PhysicsResult(
        directions=dirs,
        per_probe=_stack_probes(probes, "D", g, np.float64),
        per_probe_counts=_stack_probes(probes, "counts", g, np.int64),
        per_probe_distinct=_stack_probes_if_all(probes, "distinct"),
        divergence=f["gaussians/D"][()],
        divergence_mean=f["gaussians/D_mean"][()],
        dbar=float(f.attrs["dbar"]),
        dbar_mean=float(f.attrs["dbar_mean"]),
        dbar_empty=_optional_float(f.attrs, "dbar_empty"),
        dbar_empty_mean=_optional_float(f.attrs, "dbar_empty_mean"),
        empty_per_probe=_stack_probes_if_all(probes, "D_empty"),
        solid=f["solid/x"][()],
        transform=SceneTransform(
            tuple(f.attrs["up"]) if "up" in f.attrs else str(f.attrs["up_axis"]), float(f.attrs["scale"])
        ),
        kept=f["gaussians/kept"][()] if "gaussians/kept" in f else None,
        means=f["gaussians/means"][()],
        covariances=f["gaussians/covariances"][()],
        reach=f["gaussians/reach"][()],
        stats={d: pg["stats"][()] for d, pg in by_direction},
        domains={
            d: (np.asarray(pg.attrs["domain_min"]), np.asarray(pg.attrs["domain_max"]))
            for d, pg in by_direction
            if "domain_min" in pg.attrs
        },
        timings=json.loads(f.attrs["timings"]),
        config=PhysicsConfig.from_dict(json.loads(f.attrs["config"])),
        source=str(f.attrs["source"]),
        source_frame=str(f.attrs.get("source_frame", "")),
        warnings={
            d: list(json.loads(pg.attrs["warnings"])) if "warnings" in pg.attrs else [] for d, pg in by_direction
        },
        gaussians_sha256=str(f.attrs.get("gaussians_sha256", "")),
        status=str(f.attrs.get("status", "complete")),
        failure=_read_failure(f.attrs),
        leaks={d: read_probe_leaks(pg) for d, pg in by_direction if "leaked" in pg},
        trajectories={d: read_trajectory(pg) for d, pg in by_direction if trajectories and "trajectory" in pg},
        replicas=read_replicas(f),
    )


def _stack_probes(probes: list, key: str, g: int, dtype) -> np.ndarray:
    """(P, G) of each probe's ``key`` dataset, read straight into its row; (0, G) of ``dtype`` without probes.

    Raises:
        ValueError: the probes' datasets differ in shape (a damaged file).
    """
    if not probes:
        return np.zeros((0, g), dtype)
    first = probes[0][key]
    out = np.empty((len(probes), *first.shape), first.dtype)
    for row, dataset in zip(out, (pg[key] for pg in probes), strict=True):
        if dataset.shape != first.shape:
            raise ValueError(
                f"{dataset.file.filename}: the probes' '{key}' datasets have the shapes {first.shape} and "
                f"{dataset.shape} (a damaged result); re-run `fluidgs simulate`"
            )
        if row.size:
            dataset.read_direct(row)
    return out


def _stack_probes_if_all(probes: list, key: str) -> np.ndarray | None:
    """(P, G) of each probe's optional ``key`` dataset; None unless every probe has it (or there is no probe)."""
    return _stack_probes(probes, key, 0, np.float64) if probes and all(key in pg for pg in probes) else None


def _optional_float(attrs, key: str) -> float | None:
    """An attribute written as NaN when not computed."""
    v = float(attrs[key])
    return None if math.isnan(v) else v


def _read_failure(attrs) -> dict | None:
    """Which probe diverged at which step and why; None for a complete run."""
    if "diverged_probe" not in attrs:
        return None
    return {key: kind(attrs[f"diverged_{key}"]) for key, kind in _FAILURE_KEYS}


def check_result_matches(result: PhysicsResult, gaussians, path: str | Path) -> None:
    """Raise ValueError when a stored result was not computed, completely, for ``gaussians``.

    Args:
        result: a loaded result.
        gaussians: the ``GaussianSet`` the result is used with (an int: only the count is compared).
        path: the result file, for the message.

    The count must match and the run must be complete. Then :func:`gaussians_sha256` must match the stored
    digest; in files written before the digest, the Gaussians' centres mapped by the stored transform must
    match the stored centres (to 1e-5 of the object's size).
    """
    num = gaussians if isinstance(gaussians, int) else gaussians.num
    if result.num_gaussians != num:
        raise ValueError(
            f"{path} holds D_g for {result.num_gaussians} Gaussians but the .ply has {num}; "
            "pass the result of this .ply or drop --result to simulate again"
        )
    if result.status != "complete":
        f = result.failure or {}
        raise ValueError(
            f"{path} is the result of a run that diverged (probe {f.get('probe')} at step "
            f"{f.get('step')}: {f.get('reason')}); "
            + (f"it has only the probes {', '.join(result.directions)}" if result.directions else "no probe completed")
            + "; re-run `fluidgs simulate` with a smaller --dt"
        )
    if isinstance(gaussians, int):
        return
    if result.gaussians_sha256:
        digest = gaussians_sha256(gaussians)
        if digest == result.gaussians_sha256:
            return
        differs = (
            f"different positions, shapes or opacities: content hash {result.gaussians_sha256[:12]}... vs "
            f"{digest[:12]}... of this file"
        )
    else:
        means = np.asarray(gaussian_arrays_in_sim(gaussians, result.transform)[0], np.float64)
        stored = np.asarray(result.means, np.float64)
        size = float(np.ptp(stored, axis=0).max()) if len(stored) else 0.0
        gap = float(np.abs(means - stored).max()) if len(stored) else 0.0
        if gap <= 1e-5 * max(size, 1e-12):
            return
        differs = f"centres up to {gap:.3g} m away from the stored ones"
    raise ValueError(
        f"{path} was computed for other Gaussians (same count, {num}, but {differs}); pass the result of these "
        "Gaussians or drop --result to simulate again"
    )


# ---- replicas ------------------------------------------------------------------------------------------------
def _dbar(covariances: np.ndarray, divergence: np.ndarray, kept: np.ndarray | None) -> float:
    """D-bar of ``divergence`` [G] over the simulated Gaussians (the kept ones with a crop, as one run reports)."""
    if kept is not None:
        covariances, divergence = covariances[kept], divergence[kept]
    return scores.geometry_divergence(_t(covariances), _t(divergence))


def combine_replicas(
    results: Sequence[PhysicsResult], offsets: np.ndarray, started: float | None = None
) -> PhysicsResult:
    """One PhysicsResult from the complete results of the replicas (:mod:`nbv.physics.replicas`: intensive quantities
    averaged, extensive ones summed, the rest replica 0's). One result is returned unchanged.

    Args:
        results: N complete results of the same Gaussians and probes, replica 0 first.
        offsets: [N, 3] their lattice offsets, spacings.
        started: the run's start (``time.perf_counter()``), for ``timings["total"]``; None: the sum of theirs.
    """
    if len(results) != len(offsets) or not results:
        raise ValueError(f"combine_replicas: {len(results)} results for {len(offsets)} offsets")
    first = results[0]
    if len(results) == 1:
        return first
    if any(r.directions != first.directions or r.num_gaussians != first.num_gaussians for r in results):
        raise ValueError("combine_replicas: the replicas ran different probes or Gaussians")
    per = np.stack([r.per_probe for r in results])  # [N, P, G]
    per_probe = per.mean(0)
    counts = np.sum([r.per_probe_counts for r in results], axis=0)
    distinct = None if first.per_probe_distinct is None else np.stack([r.per_probe_distinct for r in results])
    empty = None if first.empty_per_probe is None else np.mean([r.empty_per_probe for r in results], axis=0)
    d_max, d_mean = per_probe.max(0), per_probe.mean(0)
    covs, kept = first.covariances, first.kept
    timings = {key: float(sum(r.timings.get(key, 0.0) for r in results)) for key in first.timings}
    timings["total"] = time.perf_counter() - started if started is not None else timings.get("total", 0.0)
    warnings = {
        d: list(first.warnings.get(d, []))
        + [f"replica {k}: {w}" for k, r in enumerate(results[1:], 1) for w in r.warnings.get(d, [])]
        for d in first.directions
    }
    runs = ReplicaRuns(
        offsets=np.asarray(offsets, np.float64).copy(),
        per_probe=per,
        per_probe_distinct=distinct,
        reached=np.stack([r.per_probe_counts.sum(0) > 0 for r in results]),
        solid_points=np.array([len(r.solid) for r in results], np.int64),
        seconds=np.array([r.timings.get("total", 0.0) for r in results], np.float64),
    )
    return replace(
        first,
        per_probe=per_probe,
        per_probe_counts=counts,
        per_probe_distinct=None if distinct is None else distinct.sum(0),
        divergence=d_max,
        divergence_mean=d_mean,
        dbar=_dbar(covs, d_max, kept),
        dbar_mean=_dbar(covs, d_mean, kept),
        empty_per_probe=empty,
        dbar_empty=None if empty is None else _dbar(covs, empty.max(0), kept),
        dbar_empty_mean=None if empty is None else _dbar(covs, empty.mean(0), kept),
        timings=timings,
        warnings=warnings,
        replicas=runs,
    )
