"""Tests for recon/sh.py: degree 1 against the direct formula, orthonormality of the degree-3 basis by
quadrature, the +0.5 offset and clamp of the colour, and shape errors."""

import math

import pytest
import torch

from recon.gaussians import SH_C0
from recon.sh import SH_C1, eval_sh, sh_basis, sh_to_color


def _fibonacci_sphere(n: int) -> torch.Tensor:
    """n nearly uniform unit directions (equal-area Fibonacci lattice), float64."""
    k = torch.arange(n, dtype=torch.float64) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = math.pi * (1.0 + math.sqrt(5.0)) * k
    r = torch.sqrt(1.0 - z * z)
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], -1)


def test_degree1_matches_direct_formula():
    gen = torch.Generator().manual_seed(0)
    sh = torch.randn(50, 4, 3, generator=gen, dtype=torch.float64)
    dirs = torch.nn.functional.normalize(torch.randn(50, 3, generator=gen, dtype=torch.float64), dim=-1)
    x, y, z = (dirs[:, i : i + 1] for i in range(3))
    expected = SH_C0 * sh[:, 0] - SH_C1 * y * sh[:, 1] + SH_C1 * z * sh[:, 2] - SH_C1 * x * sh[:, 3]
    torch.testing.assert_close(eval_sh(sh, dirs), expected, rtol=0, atol=1e-12)


def test_degree3_basis_is_orthonormal_on_the_sphere():
    dirs = _fibonacci_sphere(200_000)
    basis = sh_basis(dirs, 3)  # [n, 16]
    gram = 4.0 * math.pi * basis.T @ basis / dirs.shape[0]
    torch.testing.assert_close(gram, torch.eye(16, dtype=torch.float64), rtol=0, atol=2e-3)


def test_lower_degrees_are_prefixes_of_degree3():
    dirs = _fibonacci_sphere(100)
    full = sh_basis(dirs, 3)
    for degree in (0, 1, 2):
        torch.testing.assert_close(sh_basis(dirs, degree), full[:, : (degree + 1) ** 2])


def test_colour_offset_and_clamp():
    dirs = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    sh = torch.zeros(2, 1, 3)
    sh[0, 0] = torch.tensor([1.0, 0.0, -1.0]) / SH_C0  # DC contributions +1, 0, -1
    sh[1, 0] = -10.0
    color = sh_to_color(sh, dirs)
    torch.testing.assert_close(color[0], torch.tensor([1.5, 0.5, 0.0]))
    assert (color[1] == 0).all()


def test_shape_errors_name_the_shapes():
    with pytest.raises(ValueError, match=r"\(N, K, 3\)"):
        eval_sh(torch.zeros(3, 4), torch.zeros(3, 3))
    with pytest.raises(ValueError, match="dirs must have shape"):
        eval_sh(torch.zeros(3, 4, 3), torch.zeros(2, 3))
    with pytest.raises(ValueError, match="coefficients"):
        eval_sh(torch.zeros(3, 5, 3), torch.zeros(3, 3))
