"""3D Gaussians as a dataclass of plain tensors (Kerbl et al. 2023, "3D Gaussian Splatting", Sec. 4).

A Gaussian g has a mean mu_g, a covariance Sigma_g = R S S^T R^T (Eq. 6 of Kerbl et al.), an opacity
o_g = sigmoid(opacity_logit) and view-dependent colour from real spherical harmonics of degree 0 to 3.
Scales are stored as logarithms and quaternions in (w, x, y, z) order, as the reference trainer does.
There is no optimiser inside: training code owns its own state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import torch

# The largest centre coordinate and |log-scale| a Gaussian may have. Beyond them the float32 arithmetic of every
# consumer breaks (a squared distance overflows above 1.8e19, exp(2 x 44) overflows, exp(-2 x 44) is subnormal),
# and no capture comes near: 1e15 scene units is 7,000 AU in metres, exp(30) = 1e13 times the unit; a trained
# capture spans log-scales of about -12 to 0.
MAX_COORDINATE = 1.0e15
MAX_ABS_LOG_SCALE = 30.0

SH_C0 = 0.28209479177387814  # Y_0^0, the constant real spherical harmonic


def sh_coefficient_count(degree: int) -> int:
    """K = (degree + 1)^2 SH coefficients per colour channel."""
    if degree not in (0, 1, 2, 3):
        raise ValueError(f"SH degree must be 0, 1, 2 or 3, got {degree}")
    return (degree + 1) ** 2


def sh_degree_of(count: int) -> int:
    """The SH degree whose coefficient count is ``count`` (1, 4, 9 or 16)."""
    degree = int(round(math.sqrt(count))) - 1
    if degree not in (0, 1, 2, 3) or (degree + 1) ** 2 != count:
        raise ValueError(f"{count} SH coefficients per channel is not (d+1)^2 for a degree d in 0..3")
    return degree


def rgb_to_sh0(rgb: torch.Tensor) -> torch.Tensor:
    """DC coefficient whose colour (with the +0.5 offset of 3DGS) is ``rgb`` in [0, 1]."""
    return (rgb - 0.5) / SH_C0


def sh0_to_rgb(sh0: torch.Tensor) -> torch.Tensor:
    """Colour of a DC coefficient (inverse of :func:`rgb_to_sh0`)."""
    return sh0 * SH_C0 + 0.5


def quaternion_to_rotation(quats: torch.Tensor) -> torch.Tensor:
    """Rotation matrices of (w, x, y, z) quaternions, normalised first.

    Args:
        quats: [N, 4].
    Returns:
        [N, 3, 3].
    """
    q = quats / quats.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - w * z),
            2 * (x * z + w * y),
            2 * (x * y + w * z),
            1 - 2 * (x * x + z * z),
            2 * (y * z - w * x),
            2 * (x * z - w * y),
            2 * (y * z + w * x),
            1 - 2 * (x * x + y * y),
        ],
        -1,
    ).reshape(*q.shape[:-1], 3, 3)


@dataclass
class GaussianSet:
    """N anisotropic 3D Gaussians.

    Attributes:
        means: [N, 3] centres, scene units.
        quats: [N, 4] rotations as (w, x, y, z) quaternions (need not be normalised; never zero).
        log_scales: [N, 3] natural logarithms of the standard deviations along the principal axes.
        opacity_logits: [N] logits of the opacities (opacity = sigmoid(logit)).
        sh: [N, K, 3] real SH coefficients, K = (degree + 1)^2, channel last; sh[:, 0] is the DC term.

    Example:
        >>> g = GaussianSet.from_points(torch.zeros(1, 3), scale=0.1)
        >>> g.num, g.sh_degree
        (1, 0)
    """

    means: torch.Tensor
    quats: torch.Tensor
    log_scales: torch.Tensor
    opacity_logits: torch.Tensor
    sh: torch.Tensor

    def __post_init__(self) -> None:
        m = self.means
        if not isinstance(m, torch.Tensor) or m.dim() != 2 or m.shape[1] != 3:
            got = tuple(m.shape) if isinstance(m, torch.Tensor) else type(m).__name__
            raise ValueError(f"GaussianSet.means must have shape (N, 3) (one centre per Gaussian), got {got}")
        n = m.shape[0]
        expected = {"means": (n, 3), "quats": (n, 4), "log_scales": (n, 3), "opacity_logits": (n,)}
        for name, shape in expected.items():
            t = getattr(self, name)
            if not isinstance(t, torch.Tensor) or tuple(t.shape) != shape:
                got = tuple(t.shape) if isinstance(t, torch.Tensor) else type(t).__name__
                raise ValueError(f"GaussianSet.{name} must have shape {shape} (N = {n}), got {got}")
        if (
            not isinstance(self.sh, torch.Tensor)
            or self.sh.dim() != 3
            or self.sh.shape[0] != n
            or self.sh.shape[2] != 3
        ):
            got = tuple(self.sh.shape) if isinstance(self.sh, torch.Tensor) else type(self.sh).__name__
            raise ValueError(f"GaussianSet.sh must have shape ({n}, K, 3), got {got}")
        try:
            sh_degree_of(self.sh.shape[1])
        except ValueError as exc:
            raise ValueError(f"GaussianSet.sh: {exc}") from None
        devices = {t.device for t in self.tensors()}
        if len(devices) != 1:
            raise ValueError(f"GaussianSet tensors live on several devices: {sorted(map(str, devices))}")

    # ---- construction -------------------------------------------------------------------------
    @classmethod
    def from_points(
        cls,
        points: torch.Tensor,
        colors: torch.Tensor | None = None,
        scale: float | torch.Tensor = 0.01,
        opacity: float = 0.1,
        sh_degree: int = 0,
    ) -> GaussianSet:
        """Isotropic Gaussians at ``points`` [N, 3] with ``colors`` [N, 3] in [0, 1] (grey when None).

        ``scale`` is the standard deviation (a float or an [N] tensor), ``opacity`` in (0, 1).
        """
        points = torch.as_tensor(points)
        if points.dim() != 2 or points.shape[1] != 3:
            raise ValueError(f"points must have shape (N, 3), got {tuple(points.shape)}")
        if not 0.0 < opacity < 1.0:
            raise ValueError(f"opacity must be in (0, 1), got {opacity}")
        n, dtype, device = points.shape[0], points.dtype if points.is_floating_point() else torch.float32, points.device
        points = points.to(dtype)
        scale_t = (
            torch.as_tensor(scale, dtype=dtype, device=device).expand(n)
            if not isinstance(scale, torch.Tensor)
            else scale.to(dtype=dtype, device=device).reshape(n)
        )
        if (scale_t <= 0).any() or not torch.isfinite(scale_t).all():
            raise ValueError("scale must be finite and > 0")
        quats = torch.zeros(n, 4, dtype=dtype, device=device)
        quats[:, 0] = 1.0
        sh = torch.zeros(n, sh_coefficient_count(sh_degree), 3, dtype=dtype, device=device)
        rgb = (
            torch.full((n, 3), 0.5, dtype=dtype, device=device)
            if colors is None
            else torch.as_tensor(colors, dtype=dtype, device=device).reshape(n, 3)
        )
        sh[:, 0] = rgb_to_sh0(rgb)
        logit = math.log(opacity / (1.0 - opacity))
        return cls(
            points.clone(),
            quats,
            torch.log(scale_t)[:, None].repeat(1, 3).contiguous(),
            torch.full((n,), logit, dtype=dtype, device=device),
            sh,
        )

    # ---- derived quantities -------------------------------------------------------------------
    @property
    def num(self) -> int:
        """N, the number of Gaussians."""
        return int(self.means.shape[0])

    @property
    def sh_degree(self) -> int:
        """Degree of the stored SH coefficients (0 to 3)."""
        return sh_degree_of(self.sh.shape[1])

    @property
    def device(self) -> torch.device:
        return self.means.device

    @property
    def dtype(self) -> torch.dtype:
        return self.means.dtype

    @property
    def scales(self) -> torch.Tensor:
        """[N, 3] standard deviations along the principal axes."""
        return torch.exp(self.log_scales)

    @property
    def opacities(self) -> torch.Tensor:
        """[N] opacities in (0, 1)."""
        return torch.sigmoid(self.opacity_logits)

    def rotations(self) -> torch.Tensor:
        """[N, 3, 3] rotation matrices R (columns are the principal axes)."""
        return quaternion_to_rotation(self.quats)

    def covariances(self) -> torch.Tensor:
        """[N, 3, 3] Sigma = R S S^T R^T (Kerbl et al. Eq. 6)."""
        m = self.rotations() * self.scales[:, None, :]
        return m @ m.transpose(-1, -2)

    def max_radii(self) -> torch.Tensor:
        """[N] largest principal standard deviation r_g (the radius the scorer uses)."""
        return self.scales.max(dim=-1).values

    # ---- plumbing ------------------------------------------------------------------------------
    def tensors(self) -> tuple[torch.Tensor, ...]:
        """The five tensors, in field order."""
        return tuple(getattr(self, f.name) for f in fields(self))

    def map(self, fn) -> GaussianSet:
        """A new set with ``fn`` applied to every tensor (e.g. ``lambda t: t.detach()``)."""
        return GaussianSet(*(fn(t) for t in self.tensors()))

    def to(self, device=None, dtype: torch.dtype | None = None) -> GaussianSet:
        return self.map(lambda t: t.to(device=device, dtype=dtype))

    def detach(self) -> GaussianSet:
        return self.map(lambda t: t.detach())

    def clone(self) -> GaussianSet:
        return self.map(lambda t: t.detach().clone())

    def subset(self, index: torch.Tensor) -> GaussianSet:
        """The Gaussians selected by a boolean mask [N] or an index tensor."""
        return self.map(lambda t: t[index])

    def with_sh_degree(self, degree: int) -> GaussianSet:
        """The same Gaussians with SH coefficients truncated or zero-padded to ``degree``."""
        k = sh_coefficient_count(degree)
        sh = self.sh[:, :k]
        if sh.shape[1] < k:
            pad = torch.zeros(self.num, k - sh.shape[1], 3, dtype=self.dtype, device=self.device)
            sh = torch.cat([sh, pad], 1)
        return GaussianSet(self.means, self.quats, self.log_scales, self.opacity_logits, sh.contiguous())

    def check(self, source: str = "GaussianSet") -> GaussianSet:
        """Raise ``ValueError`` naming ``source`` when the set is empty, non-finite or has a zero quaternion.

        Returns ``self`` so that loaders can write ``return GaussianSet(...).check(path)``.
        """
        if self.num == 0:
            raise ValueError(f"{source}: the Gaussian set is empty (0 Gaussians); train or load a non-empty set")
        for f in fields(self):
            t = getattr(self, f.name)
            bad = ~torch.isfinite(t)
            if bad.any():
                rows = torch.nonzero(bad.reshape(self.num, -1).any(-1)).flatten()
                raise ValueError(
                    f"{source}: {len(rows)} Gaussians have NaN or Inf in {f.name} "
                    f"(first rows {rows[:5].tolist()}); remove or repair them"
                )
        self._check_magnitudes(source)
        zero = self.quats.norm(dim=-1) == 0
        if zero.any():
            rows = torch.nonzero(zero).flatten()
            raise ValueError(
                f"{source}: {len(rows)} Gaussians have a zero rotation quaternion "
                f"(first rows {rows[:5].tolist()}); set them to (1, 0, 0, 0)"
            )
        return self

    def _check_magnitudes(self, source: str) -> None:
        """Refuse centres beyond ``MAX_COORDINATE`` and log-scales beyond ``MAX_ABS_LOG_SCALE``, naming the rows."""
        for name, values, bound, what in (
            ("means", self.means, MAX_COORDINATE, "a centre coordinate beyond +-1e15 scene units"),
            (
                "log_scales",
                self.log_scales,
                MAX_ABS_LOG_SCALE,
                "a log-scale beyond +-30 (a size of exp(30) = 1e13 or exp(-30) = 1e-13 scene units)",
            ),
        ):
            bad = values.abs().amax(-1) > bound
            if bad.any():
                rows = torch.nonzero(bad).flatten()
                first = int(rows[0])
                raise ValueError(
                    f"{source}: {len(rows)} Gaussians have {what} (first rows {rows[:5].tolist()}; Gaussian {first} "
                    f"has {name} ({', '.join(f'{v:.3g}' for v in values[first].tolist())})): a corrupt or "
                    "unconverted file; delete or repair those Gaussians"
                )


def concat(sets: list[GaussianSet]) -> GaussianSet:
    """One set holding all Gaussians of ``sets`` (SH degrees must agree)."""
    if not sets:
        raise ValueError("concat needs at least one GaussianSet")
    degrees = {s.sh_degree for s in sets}
    if len(degrees) != 1:
        raise ValueError(f"cannot concatenate Gaussian sets of SH degrees {sorted(degrees)}; use with_sh_degree")
    return GaussianSet(*(torch.cat(ts, 0) for ts in zip(*(s.tensors() for s in sets), strict=True)))
