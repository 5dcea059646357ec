"""Replicas of a probe run: the same probes with the solid lattice and the fluid slab shifted by a fraction of a
spacing, D_g averaged over them, and how far they agree.

No paper equation is new here; the replicas average the estimate of Eq. 2 over where the lattice happens to lie.
The solid is sampled on a lattice of spacing s = 2 r (:mod:`nbv.physics.solidify`), and each probe's slab is laid
out around the solid's box (:mod:`fluidsim.probes`), so the lattice position decides which points are solid and
which fluid particles pass within n r_g of a Gaussian. The same capture read from two file formats (centres within
1e-4 of each other, one solid point apart) moved the quick setting's view scores by a median 9 %: part of a single
run's D_g is the lattice position, not the geometry.

- **Shifts.** Replica k lays the lattice at ``lattice_offset`` = (phi_2(k), phi_3(k), phi_5(k)) spacings, the
  Halton point k (phi_b the radical inverse in base b): replica 0 is the unshifted run, replica 1 moves the lattice
  by (1/2, 1/3, 1/5) s, replica 2 by (1/4, 2/3, 2/5) s, ... A low-discrepancy sequence covers the cell evenly for
  any N, and the first N points are the same whatever N, so N replicas extend N - 1. The slabs move with the solid.
- **Combination** (:func:`nbv.physics.result.combine_replicas`; the replicas run in
  :func:`nbv.physics.run.simulate_replicas`). Intensive quantities are averaged over the replicas, extensive ones
  add up:

  - D_g^(IC) of each probe and of the empty scene: the mean over the replicas (0 where a replica's fluid did not
    reach g, as in one run). D_g = max over the probes of those means (Eq. 3) and D_mean their mean, so every
    relation of one run holds (D = max_IC D^(IC)); D-bar and the empty D-bar are those of the combined D_g;
  - the (particle, step) sample counts and the distinct-particle counts |P_g|: the sum over the replicas (each
    replica has its own fluid, as each probe has: ``PhysicsResult.distinct_counts`` sums the probes). A Gaussian
    counts as reached when any replica reached it;
  - the solid, the step statistics, the domains, the leak measures and the recorded trajectories: replica 0's
    (only replica 0 records); warnings: every replica's, those of replica k > 0 labelled with k; timings: summed
    over the replicas, ``total`` the whole run.

- **Agreement.** Per pair of replicas, the Spearman correlation of D_g over the Gaussians both reached (as
  :mod:`nbv.study.convergence` compares settings), summarised by its mean and minimum over the pairs; the callers
  that rank views (``fluidgs score``, ``fluidgs critical``) add the Spearman correlation between the replicas' view
  rankings S(T) and between their physics parts S/A (:func:`replica_agreement`). The two differ: the coverage
  A(T) is the same in every replica, so S(T) agrees more than the physics does whenever coverage carries the
  ranking; S/A says how reproducible the physics' own say is.

Example:
    >>> replica_offsets(3).tolist()
    [[0.0, 0.0, 0.0], [0.5, 0.3333333333333333, 0.2], [0.25, 0.6666666666666666, 0.4]]
"""

from __future__ import annotations

import itertools
import json
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

log = logging.getLogger(__name__)

HALTON_BASES = (2, 3, 5)  # one base per axis (x, y, z) of the lattice offsets


def radical_inverse(k: int, base: int) -> float:
    """phi_b(k): the digits of k in ``base`` mirrored about the point (phi_2(6) = 0.011 in binary = 0.375)."""
    if k < 0 or base < 2:
        raise ValueError(f"radical_inverse needs k >= 0 and base >= 2, got k = {k}, base = {base}")
    value, unit = 0.0, 1.0
    while k:
        unit /= base
        k, digit = divmod(k, base)
        value += digit * unit
    return value


def replica_offsets(count: int) -> np.ndarray:
    """[count, 3] float64 lattice offsets of replicas 0 .. count - 1, in spacings (each in [0, 1); row 0 is 0)."""
    if isinstance(count, bool) or not isinstance(count, int) or count < 1:
        raise ValueError(f"the number of replicas must be an integer >= 1, got {count!r}")
    return np.array([[radical_inverse(k, b) for b in HALTON_BASES] for k in range(count)], np.float64)


@dataclass(frozen=True)
class ReplicaRuns:
    """What each replica of a probe run gave, beside the combined result (``PhysicsResult.replicas``).

    Attributes:
        offsets: [N, 3] float64 lattice offset of each replica, in spacings (row 0: the unshifted run).
        per_probe: [N, P, G] float64 D_g^(IC) of each replica, 1/s.
        per_probe_distinct: [N, P, G] int64 |P_g| of each replica, or None when not tracked.
        reached: [N, G] bool, the Gaussians some probe's fluid reached in each replica.
        solid_points: [N] int64 solid particles of each replica.
        seconds: [N] float64 each replica's run time, s.
    """

    offsets: np.ndarray
    per_probe: np.ndarray
    per_probe_distinct: np.ndarray | None
    reached: np.ndarray
    solid_points: np.ndarray
    seconds: np.ndarray

    @property
    def count(self) -> int:
        return int(self.offsets.shape[0])

    def metric_values(self, metric: str, directions: Sequence[str]) -> np.ndarray:
        """[N, G] each replica's per-Gaussian metric: "max" or "mean" over the probes, or one probe's D_g
        (``directions``: the probes of ``per_probe``, in order); as :func:`nbv.view_scoring.metric_values`."""
        if metric == "max":
            return self.per_probe.max(1)
        if metric == "mean":
            return self.per_probe.mean(1)
        if metric not in directions:
            raise ValueError(
                f"--metric {metric}: the replicas have no probe {metric} (they have {','.join(directions)})"
            )
        return self.per_probe[:, list(directions).index(metric)]

    def distinct_counts(self) -> np.ndarray:
        """[N, G] |P_g| of each replica, summed over its probes; needs track_distinct."""
        if self.per_probe_distinct is None:
            raise ValueError("these replicas have no distinct particle counts; simulate with track_distinct=True")
        return self.per_probe_distinct.sum(1)

    def summary(self) -> dict:
        """JSON-able: count, offsets (spacings), solid_points, seconds, and the per-Gaussian Spearman of D_g between
        the replicas (spearman_gaussians_mean, spearman_gaussians_min)."""
        agreement = self.gaussian_agreement()
        return {
            "count": self.count,
            "offsets": np.round(self.offsets, 6).tolist(),
            "solid_points": self.solid_points.tolist(),
            "seconds": np.round(self.seconds, 3).tolist(),
            "spearman_gaussians_mean": agreement["mean"],
            "spearman_gaussians_min": agreement["min"],
        }

    def gaussian_agreement(self) -> dict:
        """The per-Gaussian Spearman correlation of D_g (max over the probes) between every pair of replicas, over
        the Gaussians both reached: {"pairs": [[i, j, rho], ...], "mean", "min"} (None where undefined)."""
        d = self.per_probe.max(1)
        return _pairs_summary(pairwise_spearman(d, self.reached))


def replicas_gaussian_line(runs: ReplicaRuns) -> str:
    """The printed line on how far the replicas' D_g agree (the per-Gaussian Spearman, pairwise)."""
    agreement = runs.gaussian_agreement()
    if agreement["mean"] is None:
        return f"replicas: {runs.count} shifted lattices; their D_g cannot be compared (fewer than 3 Gaussians reached)"
    return (
        f"replicas: {runs.count} shifted lattices, D_g averaged over them; their D_g agree at Spearman "
        f"{agreement['mean']:.2f} per Gaussian (pairwise mean; min {agreement['min']:.2f})"
    )


def pairwise_spearman(rows: np.ndarray, masks: np.ndarray | None = None) -> list[tuple[int, int, float]]:
    """(i, j, Spearman of rows i and j) for every pair i < j of ``rows`` [N, K]; with ``masks`` [N, K] bool, over the
    entries both rows keep (NaN for fewer than 3 of them or a constant side)."""
    from nbv.ranking import spearman  # noqa: PLC0415 - nbv.study reads results: a cycle at import time

    x = np.asarray(rows, np.float64)
    out = []
    for i, j in itertools.combinations(range(x.shape[0]), 2):
        keep = np.ones(x.shape[1], bool) if masks is None else np.asarray(masks[i], bool) & np.asarray(masks[j], bool)
        rho = spearman(x[i][keep], x[j][keep]) if keep.sum() >= 3 else math.nan
        out.append((i, j, rho))
    return out


def _finite_or_none(value: float) -> float | None:
    return None if not math.isfinite(value) else round(float(value), 4)


def _pairs_summary(pairs: list[tuple[int, int, float]]) -> dict:
    values = np.array([rho for _, _, rho in pairs], np.float64)
    finite = values[np.isfinite(values)]
    return {
        "pairs": [[i, j, _finite_or_none(rho)] for i, j, rho in pairs],
        "mean": _finite_or_none(float(finite.mean())) if finite.size else None,
        "min": _finite_or_none(float(finite.min())) if finite.size else None,
    }


def replica_agreement(
    replicas: ReplicaRuns, view_scores: np.ndarray, candidates: Sequence[int], coverage: np.ndarray | None = None
) -> dict:
    """How far the replicas agree, for a ranking's JSON (``agreement["replicas"]`` of scores.json, critical.json).

    Args:
        replicas: the run's :class:`ReplicaRuns`.
        view_scores: [N, C] each replica's view scores (S(T) or C(T) from its own per-Gaussian metric).
        candidates: the C candidates' camera indices (for the top view of each replica).
        coverage: [C] the coverage A(T) of the candidates (the same for every replica), or None.
    Returns:
        {"count", "offsets" (spacings), "spearman_views_mean", "spearman_views_min" (the view rankings, pairwise),
        "spearman_physics_mean", "spearman_physics_min" (the physics parts S/A, pairwise over the views with
        A > 0; only with ``coverage``), "spearman_gaussians_mean", "spearman_gaussians_min" (D_g, pairwise over
        the Gaussians both reached), "top_views" (each replica's best candidate)}; a Spearman is None where
        undefined (fewer than 3 views).
    """
    s = np.asarray(view_scores, np.float64)
    if s.shape[0] != replicas.count or s.shape[1] != len(candidates):
        raise ValueError(
            f"replica_agreement: view scores of shape {s.shape} for {replicas.count} replicas and "
            f"{len(candidates)} candidates; give one row per replica and one column per candidate"
        )
    views = _pairs_summary(pairwise_spearman(s))
    gaussians = replicas.gaussian_agreement()
    out = {
        "count": replicas.count,
        "offsets": np.round(replicas.offsets, 6).tolist(),
        "spearman_views_mean": views["mean"],
        "spearman_views_min": views["min"],
    }
    if coverage is not None:
        a = np.asarray(coverage, np.float64).reshape(-1)
        if a.shape[0] != s.shape[1]:
            raise ValueError(f"replica_agreement: coverage of {a.shape[0]} views for {s.shape[1]} candidates")
        seen = np.broadcast_to(a > 0, s.shape)
        physics = _pairs_summary(pairwise_spearman(np.divide(s, a, out=np.zeros_like(s), where=a > 0), seen))
        out["spearman_physics_mean"], out["spearman_physics_min"] = physics["mean"], physics["min"]
    return {
        **out,
        "spearman_gaussians_mean": gaussians["mean"],
        "spearman_gaussians_min": gaussians["min"],
        "top_views": [int(candidates[int(np.argmax(row))]) for row in s],
    }


# ---- the run ------------------------------------------------------------------------------------------------------
# ---- HDF5 ---------------------------------------------------------------------------------------------------------
def write_replicas(f, runs: ReplicaRuns) -> None:
    """The group /replicas of RESULT.h5 (``f`` an open h5py file): offsets (N, 3) spacings, D (N, P, G) each
    replica's D_g^(IC), distinct (N, P, G) (with track_distinct), reached (N, G); attributes solid_points,
    seconds, and the per-Gaussian Spearman between replicas (spearman_gaussians_mean, _min, _pairs as JSON)."""
    g = f.create_group("replicas")
    g["offsets"] = runs.offsets
    g.create_dataset("D", data=runs.per_probe, compression="gzip", compression_opts=1)
    if runs.per_probe_distinct is not None:
        g.create_dataset("distinct", data=runs.per_probe_distinct, compression="gzip", compression_opts=1)
    g.create_dataset("reached", data=runs.reached, compression="gzip", compression_opts=1)
    g.attrs["solid_points"], g.attrs["seconds"] = runs.solid_points, runs.seconds
    agreement = runs.gaussian_agreement()
    for key in ("mean", "min"):
        g.attrs[f"spearman_gaussians_{key}"] = float("nan") if agreement[key] is None else agreement[key]
    g.attrs["spearman_gaussians_pairs"] = json.dumps(agreement["pairs"])


def read_replicas(f) -> ReplicaRuns | None:
    """The /replicas group of an open RESULT.h5, or None (a run of one replica)."""
    if "replicas" not in f:
        return None
    g = f["replicas"]
    return ReplicaRuns(
        offsets=g["offsets"][()],
        per_probe=g["D"][()],
        per_probe_distinct=g["distinct"][()] if "distinct" in g else None,
        reached=g["reached"][()].astype(bool),
        solid_points=np.asarray(g.attrs["solid_points"], np.int64),
        seconds=np.asarray(g.attrs["seconds"], np.float64),
    )
