"""Random Gaussian sets inside every splat format's range, and the comparisons the reader tests make on what a
format gives back (within its quantisation step, quaternions up to sign) or refuses."""

from __future__ import annotations

import pytest
import torch

from recon import formats
from recon.gaussians import SH_C0, GaussianSet


def random_splats(n: int, degree: int, seed: int = 0, min_w: float = 0.0) -> GaussianSet:
    """``n`` random Gaussians of SH degree ``degree`` inside every format's range (colours in [0.02, 0.98],
    |SH rest| < 0.9); ``min_w`` > 0 keeps the quaternions' w at least that far from 0 (version-2 .spz derives w)."""
    gen = torch.Generator().manual_seed(seed)
    quats = torch.randn(n, 4, generator=gen)
    quats = quats / quats.norm(dim=1, keepdim=True)
    if min_w > 0:
        quats[:, 0] = quats[:, 0].abs().clamp_min(min_w)
        quats = quats / quats.norm(dim=1, keepdim=True)
    k = (degree + 1) ** 2
    rgb = 0.02 + 0.96 * torch.rand(n, 3, generator=gen)
    sh = torch.cat([((rgb - 0.5) / SH_C0)[:, None], 1.8 * torch.rand(n, k - 1, 3, generator=gen) - 0.9], 1)
    return GaussianSet(
        means=4 * torch.rand(n, 3, generator=gen) - 2,
        quats=quats,
        log_scales=7 * torch.rand(n, 3, generator=gen) - 6,
        opacity_logits=10 * torch.rand(n, generator=gen) - 5,
        sh=sh,
    )


def sign_aligned(q: torch.Tensor, ref: torch.Tensor) -> torch.Tensor:
    """``q`` [N, 4] normalised and sign-aligned with ``ref`` (q and -q are the same rotation)."""
    q = q / q.norm(dim=1, keepdim=True)
    ref = ref / ref.norm(dim=1, keepdim=True)
    return torch.where((q * ref).sum(1, keepdim=True) < 0, -q, q)


def assert_within(got: torch.Tensor, want: torch.Tensor, tol, what: str) -> None:
    """Every |got - want| at most ``tol`` (a number or a tensor broadcasting to them), up to 1e-5."""
    excess = ((got - want).abs() - tol).max().item()
    assert excess <= 1e-5, f"{what}: error exceeds the quantisation by {excess}"


def refused_load(path, *fragments: str) -> str:
    """The message of the ``ValueError`` with which :func:`recon.formats.load_gaussians` refuses ``path``; asserts
    that it names the path and holds every one of ``fragments``."""
    with pytest.raises(ValueError) as info:
        formats.load_gaussians(path)
    message = str(info.value)
    assert str(path) in message, message
    for fragment in fragments:
        assert fragment in message, message
    return message
