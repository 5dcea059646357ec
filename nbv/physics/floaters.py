"""Which Gaussians can make solid, and so size the solid lattice; which one alone widens it (a floater).

The solid test of :mod:`nbv.physics.solidify` (paper Sec. 3.2) makes a lattice point x solid when the combined opacity
1 - prod_g (1 - o_g exp(-d_g(x)^2 / 2)) reaches tau, each Gaussian counted inside its sigma box only. Two
consequences bound where solid can be, and so the lattice (and the probes' domain) the Gaussians need:

- A Gaussian with o_g < tau cannot make a point solid alone: a point it helps make solid is also in the box of
  another Gaussian. Its box is therefore clipped to the box spanned by the other Gaussians' (clipped) boxes, which
  loses no solid point; repeated until nothing changes, this removes isolated faint floaters however large they
  are (one faint Gaussian of log-scale 10 in a 17,952-Gaussian capture asked for 10^12 GiB).
- Gaussians with o_g < tau / 10 do not size the lattice at all: it takes log(1 - tau) / log(1 - tau / 10) (11.7
  at tau = 0.3) of them at their peak on one point to reach tau, which mist away from the object does not do.
  This is the one approximation; the memory estimate of :mod:`nbv.physics` used the same rule.

A Gaussian that still widens the lattice (opaque and huge, or far away) is named by :func:`dominant_gaussian`,
so that the error can say which one to delete or crop away.
"""

from __future__ import annotations

import numpy as np

# Gaussians fainter than this fraction of tau do not size the lattice.
FAINT_FRACTION = 0.1
# A Gaussian whose removal shrinks the lattice at least this many times is named in the size errors.
DOMINANT_FACTOR = 4.0
_MAX_ROUNDS = 8


def others_box(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """[N, 3] min of ``lo`` and max of ``hi`` over every box but each one's own (needs N >= 2)."""
    n = len(lo)
    rows = np.arange(n)[:, None]
    lo2 = np.partition(lo, 1, axis=0)[:2]  # [2, 3]: smallest and second smallest per axis
    hi2 = -np.partition(-hi, 1, axis=0)[:2]
    others_lo = np.where(rows == lo.argmin(0)[None, :], lo2[1], lo2[0])
    others_hi = np.where(rows == hi.argmax(0)[None, :], hi2[1], hi2[0])
    return others_lo, others_hi


def solid_capable_boxes(
    box_lo: np.ndarray, box_hi: np.ndarray, opacities: np.ndarray, tau: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The Gaussians' sigma boxes reduced to where they can take part in making solid (module docstring).

    Args:
        box_lo, box_hi: [N, 3] corners of each Gaussian's sigma box, m.
        opacities: [N] o_g in [0, 1].
        tau: the solid threshold.
    Returns:
        lo, hi [N, 3] (faint boxes clipped), keep [N] bool: the Gaussians that size the lattice (all of them when
        none could make solid, so that the solid is reported empty rather than the lattice being undefined).
    """
    o = np.asarray(opacities, np.float64)
    lo, hi = np.array(box_lo, np.float64), np.array(box_hi, np.float64)
    keep = o >= FAINT_FRACTION * tau
    faint = o < tau
    for _ in range(_MAX_ROUNDS):
        idx = np.nonzero(keep)[0]
        clip = idx[faint[idx]]
        if len(idx) < 2 or not len(clip):
            break
        others_lo, others_hi = others_box(lo[idx], hi[idx])
        at = faint[idx]
        new_lo, new_hi = np.maximum(lo[clip], others_lo[at]), np.minimum(hi[clip], others_hi[at])
        if np.array_equal(new_lo, lo[clip]) and np.array_equal(new_hi, hi[clip]):
            break
        lo[clip], hi[clip] = new_lo, new_hi
        keep[clip[(new_lo > new_hi).any(1)]] = False  # wholly outside the others: it makes no solid
    if not keep.any():
        return np.array(box_lo, np.float64), np.array(box_hi, np.float64), np.ones(len(o), bool)
    return lo, hi, keep


def lattice_extent(lo: np.ndarray, hi: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(3,) min and max corners of the kept boxes, m."""
    return lo[keep].min(0), hi[keep].max(0)


def dominant_gaussian(lo: np.ndarray, hi: np.ndarray, keep: np.ndarray, spacing: float) -> tuple[int, float] | None:
    """The Gaussian whose removal shrinks the lattice most, if at least :data:`DOMINANT_FACTOR`-fold.

    Args:
        lo, hi, keep: from :func:`solid_capable_boxes`. spacing: lattice spacing, m.
    Returns:
        (index into the Gaussians, lattice points with it / without it), or None.
    """
    idx = np.nonzero(keep)[0]
    if len(idx) < 2:
        return None
    klo, khi = lo[idx], hi[idx]
    others_lo, others_hi = others_box(klo, khi)
    # only a Gaussian on the box's border can shrink it: the argmin / argmax of some axis
    cand = np.unique(np.concatenate([klo.argmin(0), khi.argmax(0)]))

    def points(a, b):
        return np.prod(np.maximum(b - a, 0.0) / spacing + 1.0, axis=-1)

    full = points(klo.min(0), khi.max(0))
    factors = full / points(others_lo[cand], others_hi[cand])
    best = int(np.argmax(factors))
    return (int(idx[cand[best]]), float(factors[best])) if factors[best] >= DOMINANT_FACTOR else None


def dominant_note(
    lo: np.ndarray,
    hi: np.ndarray,
    keep: np.ndarray,
    spacing: float,
    means: np.ndarray,
    covs: np.ndarray,
    opacities: np.ndarray,
    transform,
) -> str:
    """``"; Gaussian 12 (centre ..., ...) alone widens it 1e9-fold: ..."`` for a size error, or "" when none does.

    Args:
        lo, hi, keep: from :func:`solid_capable_boxes`. spacing: m. means [N, 3] m, covs [N, 3, 3] m^2 and
        opacities [N] in simulation units; transform: the ``SceneTransform`` to report the scene-unit centre
        and standard deviations.
    """
    found = dominant_gaussian(lo, hi, keep, spacing)
    if found is None:
        return ""
    i, factor = found
    centre = transform.to_scene(means[i : i + 1])[0]
    sigmas = np.sqrt(np.maximum(np.linalg.eigvalsh(covs[i]), 0.0)) / transform.scale
    others = keep.copy()
    others[i] = False
    olo, ohi = lattice_extent(lo, hi, others)
    if np.all((means[i] >= olo) & (means[i] <= ohi)):  # a crop keeps Gaussians by their centre: it would keep this one
        fix = "delete that Gaussian from the file (its centre lies among the others, so a --crop box keeps it)"
    else:
        fix = (
            "delete that floater, or crop the Gaussians to the object (--crop auto, or --crop "
            "xmin,ymin,zmin,xmax,ymax,zmax in scene units)"
        )
    return (
        f"; Gaussian {i} (centre {_fmt(centre)}, standard deviations {_fmt(sigmas)} in scene units, opacity "
        f"{float(opacities[i]):.3g}) alone widens it {factor:.3g}-fold: {fix}"
    )


def _fmt(v: np.ndarray) -> str:
    return "(" + ", ".join(f"{float(x):.4g}" for x in v) + ")"
