"""Function-critical views (paper Sec. 3.4): C(T) = sum_g w_g |P_g| per candidate view, ranked, and the top-k subset.

|P_g| is the number of distinct fluid particles that came within reach of Gaussian g during a probe
(``PhysicsResult.distinct_counts``), and w_g the weight of Eq. 5 from the projection alone
(:func:`nbv.scores.projected_view_scores`), so no view is rendered. The library side of `fluidgs critical`:
:func:`rank_critical_views`, :func:`subset_warning` and the JSON of :func:`critical_record`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from nbv.scores import DepthBuffer, critical_subset, projected_view_scores
from nbv.view_scoring import ranked_rows, replicas_view_agreement, rows_agreement
from recon.device import torch_device


@dataclass(frozen=True)
class CriticalViews:
    """The ranking of the candidate views by C(T).

    Attributes:
        scored: the projected scores (``scores`` [C], ``seen`` per Gaussian),
            :func:`nbv.scores.projected_view_scores`.
        subset: positions (into the candidates) of the top views by C(T), best first.
        rows: one dict per candidate, best first (:func:`nbv.view_scoring.ranked_rows`, value ``critical_score``).
        agreement: how far coverage decides the ranking (and the replicas' agreement when the run has replicas).
    """

    scored: object
    subset: list[int]
    rows: list[dict]
    agreement: dict


def rank_critical_views(
    distinct: np.ndarray, gaussians, cams, idx: list[int], result, subset: int, occlusion: bool, device: str = "cpu"
) -> CriticalViews:
    """Rank the candidate cameras ``cams`` (candidate numbers ``idx``) by C(T) = sum_g w_g |P_g|.

    Args:
        distinct: [G] |P_g|, distinct fluid particles per Gaussian.
        gaussians: the Gaussian set the counts belong to. cams: the candidate cameras.
        idx: [C] the candidates' numbers among all cameras. result: the PhysicsResult (its replicas, if any).
        subset: size k of the critical subset. occlusion: the depth test (False: the paper's frustum culling).
        device: "cpu" or "cuda".
    Returns:
        :class:`CriticalViews`.
    """
    scored = projected_view_scores(
        torch.from_numpy(distinct).to(torch.float64),
        gaussians.to(torch_device(device)),
        cams,
        depth_buffer=DepthBuffer() if occlusion else None,
    )
    chosen = critical_subset(scored.scores, subset).tolist()
    rows = ranked_rows(scored, cams, idx, value="critical_score")
    agreement = rows_agreement(rows, "critical_score")
    if result.replicas is not None:  # each replica's own ranking by its |P_g|, against the others
        agreement["replicas"] = replicas_view_agreement(
            result.replicas, result.replicas.distinct_counts(), gaussians, cams, idx, occlusion=occlusion, device=device
        )
    return CriticalViews(scored, chosen, rows, agreement)


def subset_warning(subset: int, candidates: int) -> str | None:
    """The warning for a critical subset of ``subset`` views out of ``candidates``: None below half of them."""
    if 2 * subset < candidates:
        return None
    return (
        f"the critical subset holds {subset} of the {candidates} candidate views (half or more), so it selects "
        f"little; pass a smaller --subset (e.g. {max(1, candidates // 4)}) or more candidates"
    )


def critical_record(
    views: CriticalViews,
    distinct: np.ndarray,
    idx: list[int],
    result,
    cameras: str | Path,
    gaussians: str | Path,
    occlusion: bool,
    source: str | Path | None,
    warning: str | None,
) -> dict:
    """The JSON of `fluidgs critical`: C(T) per camera, the critical subset (candidate numbers) and its warning,
    the distinct-particle totals, D-bar, the agreement and the result's config (``source``: the --result read)."""
    return {
        "cameras": str(cameras),
        "gaussians": str(gaussians),
        "directions": list(result.directions),
        "occlusion": occlusion,
        "dbar_m4_s": result.dbar,
        "dbar_empty_m4_s": result.dbar_empty,
        "distinct_particles": {
            "total_over_gaussians": int(distinct.sum()),
            "gaussians_reached": int((distinct > 0).sum()),
            "max": int(np.max(distinct)),
        },
        "agreement": views.agreement,
        "views": views.rows,
        "critical_subset": [idx[k] for k in views.subset],
        "subset_warning": warning,
        "result": None if source is None else str(source),
        "config": result.config.to_dict(),
    }
