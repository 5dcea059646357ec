"""View-dependent colour from real spherical harmonics (Kerbl et al. 2023, "3D Gaussian Splatting", Sec. 4).

A Gaussian stores K = (degree + 1)^2 SH coefficients per colour channel; its colour seen along the unit
direction d (from the camera centre to the Gaussian mean) is

    c(d) = max(sum_k sh_k Y_k(d) + 0.5, 0),

with the real SH basis Y_k of degree 0 to 3 and the constants and sign conventions of the reference
3DGS code (``computeColorFromSH`` in diff-gaussian-rasterization, itself from PlenOctrees). The basis is
orthonormal on the unit sphere, which the tests check by quadrature.
"""

from __future__ import annotations

import torch

from .gaussians import SH_C0, sh_degree_of

SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
SH_C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)


def sh_basis(dirs: torch.Tensor, degree: int) -> torch.Tensor:
    """The real SH basis Y_k(d) of the 3DGS reference, k = 0 .. (degree + 1)^2 - 1.

    Args:
        dirs: [N, 3] unit directions.
        degree: 0 to 3.
    Returns:
        [N, (degree + 1)^2] basis values.
    """
    x, y, z = dirs.unbind(-1)
    basis = [torch.full_like(x, SH_C0)]
    if degree >= 1:
        basis += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        basis += [
            SH_C2[0] * x * y,
            SH_C2[1] * y * z,
            SH_C2[2] * (2.0 * zz - xx - yy),
            SH_C2[3] * x * z,
            SH_C2[4] * (xx - yy),
        ]
    if degree >= 3:
        basis += [
            SH_C3[0] * y * (3.0 * xx - yy),
            SH_C3[1] * x * y * z,
            SH_C3[2] * y * (4.0 * zz - xx - yy),
            SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
            SH_C3[4] * x * (4.0 * zz - xx - yy),
            SH_C3[5] * z * (xx - yy),
            SH_C3[6] * x * (xx - 3.0 * yy),
        ]
    return torch.stack(basis, -1)


def eval_sh(sh: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    """Evaluate SH coefficients along unit directions (no +0.5 offset, no clamp).

    Args:
        sh: [N, K, 3] coefficients, K = (degree + 1)^2 for a degree in 0..3; sh[:, 0] is the DC term.
        dirs: [N, 3] unit directions (camera centre -> Gaussian mean in 3DGS).
    Returns:
        [N, 3] sum_k sh[:, k] * Y_k(dirs).

    Example:
        >>> eval_sh(torch.ones(1, 1, 3), torch.tensor([[0.0, 0.0, 1.0]]))
        tensor([[0.2821, 0.2821, 0.2821]])
    """
    if sh.dim() != 3 or sh.shape[2] != 3:
        raise ValueError(f"sh must have shape (N, K, 3), got {tuple(sh.shape)}")
    if dirs.shape != (sh.shape[0], 3):
        raise ValueError(
            f"dirs must have shape ({sh.shape[0]}, 3) to match sh {tuple(sh.shape)}, got {tuple(dirs.shape)}"
        )
    degree = sh_degree_of(sh.shape[1])
    basis = sh_basis(dirs, degree)
    return (basis[:, :, None] * sh).sum(1)  # broadcasting beats a batched matmul for tiny K


def sh_to_color(sh: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    """RGB colour of the 3DGS reference: max(eval_sh(sh, dirs) + 0.5, 0), [N, 3]."""
    return torch.clamp_min(eval_sh(sh, dirs) + 0.5, 0.0)
