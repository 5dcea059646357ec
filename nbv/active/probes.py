"""The probe run for a planner: the probes of one physics setting on the current Gaussians
(:func:`nbv.physics.simulate_gaussians`, paper Sec. 3.2-3.3) as a planner reads them, D_g and the per-probe fields
(:class:`nbv.plan.ProbeFields`), with the fallback for Gaussians that form no solid.

The active loop runs it for the fused planners' picks, and the oracle study (:mod:`nbv.study.oracle`) once per probe
setting at a state; both go through :func:`probe_run`, so both fall back alike.
"""

from __future__ import annotations

import logging
from typing import NamedTuple

import torch

from nbv.physics import PhysicsConfig, PhysicsResult, simulate_gaussians
from nbv.physics.solidify import is_empty_solid
from nbv.plan import ProbeFields
from recon.gaussians import GaussianSet

log = logging.getLogger(__name__)


class ProbeRun(NamedTuple):
    """One probe run for a planner.

    Attributes:
        divergence: [N] float64 D_g (1/s); zeros when the Gaussians form no solid.
        fields: the per-probe D_g (and the empty scene's, when run); one probe "none" of zeros without a solid.
        result: the run's :class:`nbv.physics.PhysicsResult`, or None when the Gaussians form no solid.
        error: why there is no result (the solidification's message), else None.
    """

    divergence: torch.Tensor
    fields: ProbeFields
    result: PhysicsResult | None
    error: str | None = None


def probe_run(gaussians: GaussianSet, physics: PhysicsConfig, source: str, progress: bool = False) -> ProbeRun:
    """The probes of ``physics`` on ``gaussians``, as the planners read them.

    A barely trained reconstruction can be too transparent to form any solid: then there is no divergence anywhere,
    D_g = 0 (logged as a warning naming ``source``), and a fused pick falls back to the visual ranking (all S(T) = 0).

    Args:
        gaussians: the current Gaussians (scene units).
        physics: the probe setting, its up direction resolved.
        source: names the run in the log and the progress bars ("round 3", "probe setting s750").
        progress: tqdm bars of the probes.
    Returns:
        :class:`ProbeRun`.
    Raises:
        ValueError: bad Gaussians or settings other than an empty solid (from :func:`nbv.physics.simulate_gaussians`).
    """
    try:
        res = simulate_gaussians(gaussians, physics, progress=progress, source=source)
    except ValueError as exc:
        if not is_empty_solid(exc):
            raise
        log.warning("%s: %s; D_g = 0", source, exc)
        zeros = torch.zeros(gaussians.num, dtype=torch.float64)
        fields = ProbeFields(("none",), zeros.reshape(1, -1), zeros.reshape(1, -1))
        return ProbeRun(zeros, fields, None, str(exc))
    fields = ProbeFields(
        tuple(res.directions),
        torch.from_numpy(res.per_probe),
        None if res.empty_per_probe is None else torch.from_numpy(res.empty_per_probe),
    )
    return ProbeRun(torch.from_numpy(res.divergence).to(torch.float64), fields, res)
