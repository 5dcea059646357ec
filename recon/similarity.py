"""Moving Gaussians by a similarity transform ``x' = s R x + t`` (used to undo a trainer's normalisation).

For a Gaussian with mean mu, covariance Sigma = R_g S^2 R_g^T and SH colour c(d):

- mean: ``mu' = s R mu + t``;
- covariance: ``Sigma' = s^2 R Sigma R^T``, so the rotation becomes ``R R_g`` (the quaternion product q_R q_g) and the
  log-scales grow by ``ln s``;
- colour: the colour seen along d' = R d must equal the old colour along d, so each SH band l is mixed by the
  (2l+1) x (2l+1) matrix M_l with ``Y_l(R^T d') = Y_l(d') M_l`` (the real Wigner matrix of the basis of
  :mod:`recon.sh`), computed here by least squares on a fixed set of directions; it is exact since every band
  is closed under rotation.

Example:
    >>> m = np.diag([2.0, 2.0, 2.0, 1.0])
    >>> g = GaussianSet.from_points(torch.zeros(1, 3))
    >>> float(transform_gaussians(g, m).log_scales[0, 0] - g.log_scales[0, 0])  # doctest: +ELLIPSIS
    0.693...
"""

from __future__ import annotations

import numpy as np
import torch

from .gaussians import GaussianSet
from .sh import sh_basis


def split_similarity(matrix: np.ndarray, what: str = "transform") -> tuple[float, np.ndarray, np.ndarray]:
    """(s, R, t) of a 4x4 (or 3x4) similarity ``[[s R, t], [0, 1]]``.

    Raises:
        ValueError: not a rotation times a positive scale (shear, mirror, non-uniform scale or not finite).
    """
    m = np.asarray(matrix, np.float64)
    if m.shape not in ((4, 4), (3, 4)) or not np.isfinite(m).all():
        raise ValueError(f"{what} must be a finite 3x4 or 4x4 matrix, got shape {m.shape}")
    a = m[:3, :3]
    s = float(np.cbrt(np.linalg.det(a)))
    if not s > 0:
        raise ValueError(f"{what} is not a similarity (its 3x3 part has determinant {s**3:.3g}: mirrored or singular)")
    r = a / s
    if not np.allclose(r @ r.T, np.eye(3), atol=1e-5):
        raise ValueError(f"{what} is not a similarity (its 3x3 part is not a rotation times one scale)")
    return s, r, m[:3, 3].copy()


def invert_similarity(matrix: np.ndarray) -> np.ndarray:
    """The 4x4 inverse of a similarity: ``x = R^T (x' - t) / s``."""
    s, r, t = split_similarity(matrix)
    out = np.eye(4)
    out[:3, :3] = r.T / s
    out[:3, 3] = -(r.T @ t) / s
    return out


def rotation_to_quaternion(r: np.ndarray) -> np.ndarray:
    """(w, x, y, z) unit quaternion of a 3x3 rotation matrix (Shepperd's method, w >= 0)."""
    r = np.asarray(r, np.float64)
    trace = np.trace(r)
    candidates = [trace, r[0, 0], r[1, 1], r[2, 2]]
    k = int(np.argmax(candidates))
    if k == 0:
        w = 0.5 * np.sqrt(1.0 + trace)
        q = [w, (r[2, 1] - r[1, 2]) / (4 * w), (r[0, 2] - r[2, 0]) / (4 * w), (r[1, 0] - r[0, 1]) / (4 * w)]
    else:
        i = k - 1
        j, l = (i + 1) % 3, (i + 2) % 3
        v = 0.5 * np.sqrt(1.0 + r[i, i] - r[j, j] - r[l, l])
        q = [0.0] * 4
        q[0] = (r[l, j] - r[j, l]) / (4 * v)
        q[1 + i] = v
        q[1 + j] = (r[j, i] + r[i, j]) / (4 * v)
        q[1 + l] = (r[l, i] + r[i, l]) / (4 * v)
    q = np.array(q)
    return q * (1.0 if q[0] >= 0 else -1.0) / np.linalg.norm(q)


def quaternion_multiply(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """The Hamilton product a b of (w, x, y, z) quaternions (broadcast over leading dimensions)."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        -1,
    )


def sh_rotation(r: np.ndarray, degree: int) -> torch.Tensor:
    """[K, K] float64 matrix M (K = (degree + 1)^2) with ``sh_basis(d R)`` = ``sh_basis(d) M`` for unit row
    directions d, i.e. Y(R^T d) = Y(d) M; block diagonal by band."""
    gen = torch.Generator().manual_seed(0)
    dirs = torch.nn.functional.normalize(torch.randn(256, 3, generator=gen, dtype=torch.float64), dim=1)
    basis = sh_basis(dirs, degree)
    turned = sh_basis(dirs @ torch.as_tensor(r, dtype=torch.float64), degree)
    return torch.linalg.lstsq(basis, turned).solution


def transform_gaussians(gaussians: GaussianSet, matrix: np.ndarray) -> GaussianSet:
    """The Gaussians moved by the similarity ``matrix`` (4x4 or 3x4, ``x' = s R x + t``); module docstring.

    Args:
        gaussians: the set (any device; computed in float64, returned in its dtype).
        matrix: the similarity.
    Returns:
        A new GaussianSet: means ``s R mu + t``, quaternions ``q_R q``, log-scales ``+ ln s``, SH mixed per band.
    """
    s, r, t = split_similarity(matrix)
    g = gaussians.detach()
    dtype, device = g.dtype, g.device
    g64 = g.to(device="cpu", dtype=torch.float64)
    rot = torch.as_tensor(r, dtype=torch.float64)
    means = s * g64.means @ rot.T + torch.as_tensor(t, dtype=torch.float64)
    q_r = torch.as_tensor(rotation_to_quaternion(r), dtype=torch.float64)
    quats = quaternion_multiply(q_r.expand_as(g64.quats), g64.quats)
    m = sh_rotation(r, g64.sh_degree)
    sh = torch.einsum("jk,nkc->njc", m, g64.sh)
    out = GaussianSet(
        means=means,
        quats=quats,
        log_scales=g64.log_scales + float(np.log(s)),
        opacity_logits=g64.opacity_logits.clone(),
        sh=sh,
    )
    return out.to(device=device, dtype=dtype)
