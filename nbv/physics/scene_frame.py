"""The scene frame -> the simulation frame: up direction, scale, robust object box and crop.

No paper equation is implemented here. The paper simulates in a Y-up frame of about [-1.5, 1.5]^3 m
and rotates Z-up Blender scenes by -90 deg about x; real captures come in any frame (COLMAP
reconstructions are usually y-down), so the up direction is a free vector here:

- ``up`` is the scene direction that becomes simulation +y. An axis (``"+x"``, ``"-y"``, ``"z"``, ...)
  or a 3-vector. The rotation is the smallest one taking ``up`` to +y (Rodrigues' formula about
  ``up x y``); for ``up`` = -y, where that axis vanishes, it is the half turn about x, (x, y, z) ->
  (x, -y, -z). For ``up`` = +z it is the -90 deg turn about x of the paper, (x, y, z) -> (x, z, -y).
- ``scale`` is metres per scene unit: simulation point = scale * R * scene point (no translation; the
  probes' domains are fitted around the solid wherever it lies).
- The *robust object box* is the per-axis opacity-weighted 0.5 % - 99.5 % quantile range of the
  centres of the Gaussians whose opacity reaches tau (all Gaussians when fewer than two do). One far
  floater then moves it by nothing, where the raw bounding box would grow to reach it.
- A *crop* keeps the Gaussians whose centres lie in an axis-aligned scene box: given by its corners,
  or ``"auto"``: the robust box grown by ``margin`` times its extent on every side.
- :class:`SimGaussians` is the Gaussians in simulation metres (means, covariances, opacities, largest radii),
  converted once per run and handed to every step that needs them.

Example:
    >>> SceneTransform("-y", 2.0).to_sim(np.array([[0.0, 1.0, 0.0]]))
    array([[ 0., -2.,  0.]])
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from recon.gaussians import GaussianSet

AXES = {"x": 0, "y": 1, "z": 2}
# Opacity-weighted quantiles of the robust object box.
ROBUST_QUANTILES = (0.005, 0.995)
# --crop auto: the robust box grown by this fraction of its extent on every side.
CROP_MARGIN = 0.1
_AXIS_SPEC = re.compile(r"^([+-]?)([xyz])$")


def parse_up(spec: str | Sequence[float] | np.ndarray, option: str = "--up") -> np.ndarray:
    """An up direction -> a unit 3-vector in scene coordinates.

    Args:
        spec: ``"x"``, ``"+x"``, ``"-x"`` (and y, z), a comma list ``"0,-1,0"``, or a sequence of 3 numbers.
        option: the option's name, for error messages.
    Returns:
        [3] float64, unit length.
    Raises:
        ValueError: neither an axis nor a finite non-zero 3-vector (the message names ``option`` and the fix).
    """
    fix = f"use {option} +x, -x, +y, -y, +z, -z or a non-zero vector such as {option}=0,-1,0"
    if isinstance(spec, str):
        text = spec.strip().lower()
        m = _AXIS_SPEC.match(text)
        if m:
            v = np.zeros(3)
            v[AXES[m.group(2)]] = -1.0 if m.group(1) == "-" else 1.0
            return v
        parts = [p for p in re.split(r"[,\s]+", text.strip("[]()")) if p]
        try:
            values = [float(p) for p in parts]
        except ValueError:
            raise ValueError(f"{option} {spec!r} is neither an axis nor a 3-vector; {fix}") from None
    else:
        try:
            values = [float(v) for v in np.asarray(spec, dtype=np.float64).reshape(-1)]
        except (TypeError, ValueError):
            raise ValueError(f"{option} {spec!r} is neither an axis nor a 3-vector; {fix}") from None
    v = np.asarray(values, dtype=np.float64)
    if v.shape != (3,) or not np.isfinite(v).all():
        raise ValueError(f"{option} {spec!r} must have 3 finite components; {fix}")
    largest = float(np.abs(v).max())
    if not largest > 0:
        raise ValueError(f"{option} {spec!r} is the zero vector, which has no direction; {fix}")
    v = v / largest  # first to [-1, 1], so that the norm neither overflows (1e200) nor underflows (1e-200)
    return v / np.linalg.norm(v)


def up_label(up: np.ndarray) -> str:
    """``"+y"``-style name of an axis-aligned unit vector, else the vector as ``"0.1,0.99,0"``."""
    u = np.asarray(up, dtype=np.float64)
    for name, axis in AXES.items():
        for sign, label in ((1.0, "+"), (-1.0, "-")):
            e = np.zeros(3)
            e[axis] = sign
            if np.allclose(u, e, atol=1e-12):
                return label + name
    return ",".join(f"{c:.6g}" for c in u)


def nearest_axis(up: np.ndarray) -> tuple[str, float]:
    """(``"+y"``-style name, angle in degrees) of the coordinate axis closest to the unit vector ``up``."""
    u = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    k = int(np.argmax(np.abs(u)))
    name = ("+" if u[k] > 0 else "-") + "xyz"[k]
    return name, float(np.degrees(np.arccos(min(1.0, abs(u[k])))))


def describe_auto_up(up: np.ndarray) -> str:
    """The log line of ``--up auto``: the vector, and the nearest axis with its angle (to pass it explicitly)."""
    name, angle = nearest_axis(up)
    return (
        f"--up auto: the cameras' mean up vector is {up_label(up)}, {angle:.1f} deg from {name} "
        f"(pass --up {name} to use the axis itself)"
    )


def rotation_to_y_up(up: np.ndarray) -> np.ndarray:
    """[3, 3] the smallest rotation R with R up = +y (the half turn about x when up = -y).

    Args:
        up: [3] unit vector, scene coordinates.
    """
    u = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    y = np.array([0.0, 1.0, 0.0])
    axis = np.cross(u, y)
    s, c = float(np.linalg.norm(axis)), float(u @ y)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    k = axis / s
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + s * kx + (1.0 - c) * (kx @ kx)


@dataclass(frozen=True, init=False)
class SceneTransform:
    """Scene units and axes -> simulation metres, Y-up: x_sim = scale * R x_scene.

    Attributes:
        up: the scene's up direction as a unit 3-tuple (it becomes simulation +y).
        scale: metres per scene unit (> 0).

    Args:
        up: anything :func:`parse_up` takes (``"y"``, ``"-y"``, ``"z"``, a 3-vector); default +y.
        scale: metres per scene unit.

    Example:
        >>> SceneTransform("z", 2.0).to_sim(np.array([[0.0, 0.0, 1.0]]))
        array([[0., 2., 0.]])
    """

    up: tuple[float, float, float]
    scale: float

    def __init__(self, up: str | Sequence[float] = "+y", scale: float = 1.0) -> None:
        u = parse_up(up, "SceneTransform.up")
        if isinstance(scale, bool) or not (isinstance(scale, (int, float)) and math.isfinite(scale) and scale > 0):
            raise ValueError(f"SceneTransform.scale must be a finite number > 0 (metres per scene unit), got {scale!r}")
        object.__setattr__(self, "up", tuple(float(c) for c in u))
        object.__setattr__(self, "scale", float(scale))

    @property
    def up_label(self) -> str:
        """``"+y"``, ``"-y"``, ``"+z"``, ... or the vector's components."""
        return up_label(np.asarray(self.up))

    @property
    def rotation(self) -> np.ndarray:
        """[3, 3] rotation from scene axes to simulation axes."""
        return rotation_to_y_up(np.asarray(self.up))

    @property
    def matrix(self) -> np.ndarray:
        """[4, 4] the homogeneous scene -> simulation transform (scale * R, no translation)."""
        m = np.eye(4)
        m[:3, :3] = self.scale * self.rotation
        return m

    def to_sim(self, points: np.ndarray) -> np.ndarray:
        """Scene points [N, 3] -> simulation metres [N, 3] (float64)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return self.scale * (p @ self.rotation.T)

    def to_scene(self, points: np.ndarray) -> np.ndarray:
        """Simulation metres [N, 3] -> scene points [N, 3] (the inverse of :meth:`to_sim`)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return (p @ self.rotation) / self.scale

    def covariances_to_sim(self, covs: np.ndarray) -> np.ndarray:
        """Scene covariances [N, 3, 3] -> simulation covariances scale^2 R Sigma R^T [N, 3, 3] (m^2)."""
        c = np.asarray(covs, dtype=np.float64).reshape(-1, 3, 3)
        m = self.rotation
        return (self.scale**2) * (m @ c @ m.T)

    def to_dict(self) -> dict:
        """JSON-able: up (vector and label), scale, and the 4x4 matrix."""
        return {
            "up": list(self.up),
            "up_label": self.up_label,
            "scale_m_per_unit": self.scale,
            "scene_to_sim": self.matrix.tolist(),
        }


# ---- the Gaussians in the simulation frame --------------------------------------------------------------
def _numpy64(t) -> np.ndarray:
    return t.detach().to("cpu").double().numpy()


def _rotations_in_sim(gaussians: GaussianSet, transform: SceneTransform) -> np.ndarray:
    """[N, 3, 3] principal axes in simulation axes, computed in float64 (orthogonal to rounding)."""
    from recon.gaussians import quaternion_to_rotation  # noqa: PLC0415 - torch; the config and --help need none

    rot = quaternion_to_rotation(gaussians.quats.detach().to("cpu").double()).numpy()
    return transform.rotation @ rot


def gaussian_arrays_in_sim(
    gaussians: GaussianSet, transform: SceneTransform
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The Gaussians' geometry in simulation metres.

    Args:
        gaussians: N Gaussians in scene units.
        transform: scene -> simulation.
    Returns:
        means [N, 3] m, covariances [N, 3, 3] m^2, opacities [N], largest principal radii r_g [N] m,
        all float64.
    """
    means = transform.to_sim(_numpy64(gaussians.means))
    rot = _rotations_in_sim(gaussians, transform)
    scales = transform.scale * np.exp(_numpy64(gaussians.log_scales))
    m = rot * scales[:, None, :]
    covs = m @ np.swapaxes(m, -1, -2)
    return means, covs, _numpy64(gaussians.opacities), scales.max(axis=1)


def inverse_covariances_in_sim(gaussians: GaussianSet, transform: SceneTransform) -> np.ndarray:
    """[N, 3, 3] Sigma^-1 = R diag(1 / s^2) R^T in simulation units (no matrix inversion: thin Gaussians stay exact)."""
    rot = _rotations_in_sim(gaussians, transform)
    inv_scales = 1.0 / (transform.scale * np.exp(_numpy64(gaussians.log_scales)))
    m = rot * inv_scales[:, None, :]
    return m @ np.swapaxes(m, -1, -2)


@dataclass(frozen=True)
class SimGaussians:
    """The Gaussians in simulation metres: computed once per run (:meth:`of`) and handed down to the memory check,
    the solidification, the accumulator and the result, instead of being converted again by each.

    Attributes:
        gaussians: the ``recon.gaussians.GaussianSet`` they come from (scene units; checked).
        transform: scene -> simulation.
        means: [N, 3] m. covariances: [N, 3, 3] m^2. opacities: [N]. radii: [N] m, the largest principal
            standard deviation r_g. All float64.
    """

    gaussians: GaussianSet
    transform: SceneTransform
    means: np.ndarray
    covariances: np.ndarray
    opacities: np.ndarray
    radii: np.ndarray

    @classmethod
    def of(cls, gaussians: GaussianSet, transform: SceneTransform) -> SimGaussians:
        """Check ``gaussians`` (NaN/Inf, zero quaternions) and convert them to the simulation frame once."""
        gaussians.check("gaussians")
        means, covs, opacities, radii = gaussian_arrays_in_sim(gaussians, transform)
        return cls(gaussians, transform, means, covs, opacities, radii)

    def __len__(self) -> int:
        return len(self.means)

    @property
    def num(self) -> int:
        """N, as ``GaussianSet.num``."""
        return len(self.means)

    def inverse_covariances(self) -> np.ndarray:
        """[N, 3, 3] Sigma^-1 in simulation units (computed on demand: the run keeps only Sigma)."""
        return inverse_covariances_in_sim(self.gaussians, self.transform)


def as_sim(gaussians: GaussianSet | SimGaussians, transform: SceneTransform) -> SimGaussians:
    """``gaussians`` in the simulation frame: a :class:`SimGaussians` is used as it is (it must carry
    ``transform``), a ``GaussianSet`` is checked and converted."""
    if isinstance(gaussians, SimGaussians):
        if gaussians.transform != transform:
            raise ValueError(f"the Gaussians were converted with {gaussians.transform}, not {transform}")
        return gaussians
    return SimGaussians.of(gaussians, transform)


def weighted_quantiles(values: np.ndarray, weights: np.ndarray, quantiles: Sequence[float]) -> np.ndarray:
    """Weighted quantiles of ``values`` [N] (piecewise-linear in the cumulative weight, midpoint rule).

    With equal weights this is ``np.quantile(values, q, method="hazen")``: sample k (sorted) sits at
    cumulative weight (k + 1/2) / N.

    Args:
        values: [N]. weights: [N] >= 0, not all zero. quantiles: in [0, 1].
    Returns:
        [len(quantiles)] float64.
    """
    v = np.asarray(values, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    order = np.argsort(v, kind="stable")
    v, w = v[order], w[order]
    total = w.sum()
    if not total > 0:
        raise ValueError("weighted_quantiles: the weights sum to zero")
    cdf = (np.cumsum(w) - 0.5 * w) / total
    return np.interp(np.asarray(quantiles, dtype=np.float64), cdf, v)


def robust_box(
    means: np.ndarray, opacities: np.ndarray, tau: float, quantiles: tuple[float, float] = ROBUST_QUANTILES
) -> tuple[np.ndarray, np.ndarray]:
    """The robust object box: per-axis opacity-weighted quantiles of the centres with opacity >= tau.

    Args:
        means: [N, 3] centres (any frame; the box is in the same frame). opacities: [N] in [0, 1].
        tau: the solid threshold; Gaussians under it do not count (all count when fewer than two reach it).
        quantiles: (low, high) in [0, 1].
    Returns:
        (lo [3], hi [3]) float64.
    """
    m = np.asarray(means, dtype=np.float64).reshape(-1, 3)
    o = np.asarray(opacities, dtype=np.float64).reshape(-1)
    if len(m) == 0:
        raise ValueError("robust_box: there are no Gaussians")
    keep = o >= tau
    if keep.sum() < 2:
        keep = np.ones(len(m), dtype=bool)
    w = np.maximum(o[keep], 1e-12)
    box = np.stack([weighted_quantiles(m[keep, a], w, quantiles) for a in range(3)], axis=1)
    return box[0], box[1]


def parse_crop(spec: str | Sequence[float] | None) -> str | tuple[float, ...] | None:
    """``--crop`` -> None, ``"auto"`` or (xmin, ymin, zmin, xmax, ymax, zmax) in scene units.

    Raises:
        ValueError: not ``auto`` nor 6 finite numbers with min < max on every axis.
    """
    if spec is None:
        return None
    fix = "use --crop auto or --crop xmin,ymin,zmin,xmax,ymax,zmax (scene units)"
    if isinstance(spec, str):
        if spec.strip().lower() == "auto":
            return "auto"
        try:
            values = [float(p) for p in re.split(r"[,\s]+", spec.strip()) if p]
        except ValueError:
            raise ValueError(f"--crop {spec!r} is not a list of numbers; {fix}") from None
    else:
        values = [float(v) for v in spec]
    if len(values) != 6 or not all(math.isfinite(v) for v in values):
        raise ValueError(f"--crop {spec!r} must be 6 finite numbers; {fix}")
    lo, hi = values[:3], values[3:]
    if not all(a < b for a, b in zip(lo, hi, strict=True)):
        raise ValueError(f"--crop {spec!r}: every min must be below its max (xmin < xmax, ...); {fix}")
    return tuple(values)


def crop_box(
    crop: str | Sequence[float], means: np.ndarray, opacities: np.ndarray, tau: float, margin: float = CROP_MARGIN
) -> tuple[np.ndarray, np.ndarray]:
    """(lo [3], hi [3]) scene units of a crop: the given corners, or the robust box grown by ``margin``."""
    if isinstance(crop, str):
        if crop != "auto":
            raise ValueError(f"crop must be 'auto' or 6 numbers, got {crop!r}")
        lo, hi = robust_box(means, opacities, tau)
        pad = margin * (hi - lo)
        return lo - pad, hi + pad
    c = np.asarray(crop, dtype=np.float64).reshape(6)
    return c[:3], c[3:]


def inside_box(means: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """[N] bool: centres inside the closed box [lo, hi]."""
    m = np.asarray(means, dtype=np.float64).reshape(-1, 3)
    return np.all((m >= lo) & (m <= hi), axis=1)
