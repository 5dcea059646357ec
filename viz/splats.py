"""The Gaussians as the viewer draws them: RESULT.h5's means and covariances (simulation metres) with the colours
and opacities of the Gaussian file they came from.

A Gaussian's own colour is that of its SH DC term (:func:`recon.gaussians.sh0_to_rgb`, the view-independent part);
its opacity is sigmoid(logit). The file must be the one RESULT.h5 was computed from: the same count, and its
centres mapped by RESULT.h5's ``scene_to_sim`` must be RESULT.h5's centres (a re-coloured copy, such as
``RESULT_divergence.ply``, matches too: colours are not compared).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fluidsim.files import check_input_file

from .data import ViewData

log = logging.getLogger(__name__)

# centres may differ by this fraction of the object's size (float32 files, float64 results)
MEANS_RELATIVE_TOLERANCE = 1e-5
# without a Gaussian file the splats are drawn at this opacity
DEFAULT_OPACITY = 0.8


@dataclass(frozen=True)
class SplatLooks:
    """Colours and opacities of the Gaussians.

    Attributes:
        rgb: [G, 3] float32 own colours in [0, 1], or None (no Gaussian file: only D_g colours can be shown).
        opacity: [G] float32 in [0, 1].
        source: the file they came from ("" when none).
    """

    rgb: np.ndarray | None
    opacity: np.ndarray
    source: str


def check_gaussians_match(means_scene: np.ndarray, data: ViewData, where: str) -> None:
    """Raise ValueError when Gaussians (their centres [G, 3], scene units) are not those of ``data``.

    The count must match, and the centres mapped by ``data.scene_to_sim`` must be ``data.means`` to
    :data:`MEANS_RELATIVE_TOLERANCE` of the object's size.
    """
    m = np.asarray(means_scene, np.float64).reshape(-1, 3)
    redo = (
        f"pass the Gaussian file RESULT.h5 was computed from (its source: {data.source or 'not recorded'}), or "
        f"re-run `fluidgs simulate {where} -o {data.path}`"
    )
    if len(m) != data.num_gaussians:
        raise ValueError(
            f"--gaussians {where} has {len(m):,} Gaussians but {data.path} holds D_g for {data.num_gaussians:,}; {redo}"
        )
    sim = m @ data.scene_to_sim[:3, :3].T + data.scene_to_sim[:3, 3]
    stored = np.asarray(data.means, np.float64)
    size = float(np.ptp(stored, axis=0).max()) if len(stored) else 0.0
    gap = float(np.abs(sim - stored).max()) if len(stored) else 0.0
    if not gap <= MEANS_RELATIVE_TOLERANCE * max(size, 1e-12):
        worst = int(np.abs(sim - stored).max(axis=1).argmax())
        raise ValueError(
            f"--gaussians {where}: the same count ({len(m):,}) but other centres than {data.path}: "
            f"Gaussian {worst} lies {gap:.3g} m from the stored one after the stored scene_to_sim "
            f"transform; {redo}"
        )


def resolve_gaussians(path: str | Path | None, data: ViewData) -> Path | None:
    """The Gaussian file to colour the splats with: ``path``, else RESULT.h5's ``source`` when that file exists (its
    absolute path, else its path relative to RESULT.h5's folder, for files moved together, else beside RESULT.h5),
    else None."""
    if path is not None:
        return Path(path)
    if not data.source:
        return None
    relative = [data.path.parent / data.source_relative] if data.source_relative else []
    for candidate in (Path(data.source), *relative, data.path.parent / Path(data.source).name):
        if candidate.is_file():
            log.info("Gaussians: %s (the source recorded in %s)", candidate, data.path.name)
            return candidate
    return None


def splat_looks(path: str | Path | None, data: ViewData) -> SplatLooks:
    """The Gaussians' own colours and opacities from ``path`` (see :func:`resolve_gaussians`), checked against
    ``data``; without a file, no colours and :data:`DEFAULT_OPACITY`.

    Raises:
        ValueError: the file is missing or unreadable (the message lists the supported formats), or its Gaussians
            are not those of RESULT.h5 (:func:`check_gaussians_match`).
    """
    file = resolve_gaussians(path, data)
    if file is None:
        log.warning(
            "no --gaussians (and RESULT.h5's source %r is not there): the splats are drawn from RESULT.h5's "
            "centres and covariances at opacity %.1f, coloured by D_g only; pass --gaussians G.ply for their "
            "own colours and opacities",
            data.source,
            DEFAULT_OPACITY,
        )
        return SplatLooks(rgb=None, opacity=np.full(data.num_gaussians, DEFAULT_OPACITY, np.float32), source="")
    from recon.formats import SUPPORTED, load_gaussians  # noqa: PLC0415 - torch, only when a splat file is read
    from recon.gaussians import sh0_to_rgb  # noqa: PLC0415 - torch, as above

    check_input_file(file, "--gaussians", f"pass the Gaussian file of {data.path} ({SUPPORTED})", folder_ok=True)
    g = load_gaussians(file)
    check_gaussians_match(g.means.detach().cpu().numpy(), data, str(file))
    rgb = sh0_to_rgb(g.sh[:, 0].detach().cpu()).clamp(0.0, 1.0).numpy().astype(np.float32)
    opacity = g.opacities.detach().cpu().numpy().astype(np.float32)
    return SplatLooks(rgb=rgb, opacity=opacity, source=str(file))
