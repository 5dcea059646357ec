"""The thin-or-open mask of the oracle study (nbv.physics.thin) on solids whose thickness is known."""

import math

import numpy as np
import pytest
import torch

from nbv.physics import PhysicsConfig
from nbv.physics.thin import lattice_volume, thin_or_open, thin_or_open_gaussians
from recon.gaussians import GaussianSet

S = 0.1  # lattice spacing, m


def box(lo, hi, offset=0.03):
    """Lattice points of spacing S inside [lo, hi] (voxel indices, inclusive), shifted by ``offset``."""
    axes = [np.arange(a, b + 1) for a, b in zip(lo, hi, strict=True)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3) * S + offset


def test_a_slab_two_spacings_thin_beside_a_thick_block():
    block = box((0, 0, 0), (9, 9, 9))  # 10 spacings thick
    sheet = box((20, 0, 0), (21, 9, 9))  # 2 spacings thick: the opening of depth 2 removes it
    solid = np.concatenate([block, sheet])
    means = (
        np.array(
            [
                [0.5, 0.5, -0.05],  # on the block's face, just outside it
                [0.5, 0.5, 0.45],  # inside the block
                [2.05, 0.5, 0.5],  # on the sheet
                [5.0, 5.0, 5.0],  # far from every solid point: open
            ]
        )
        + 0.03
    )
    reach = np.full(4, 0.06)
    np.testing.assert_array_equal(thin_or_open(solid, S, means, reach), [False, False, True, True])
    # a thicker opening probe also removes the block's corners, never its middle; depth 0 keeps every solid point
    assert not thin_or_open(solid, S, means, reach, depth=4)[1]
    np.testing.assert_array_equal(thin_or_open(solid, S, means, reach, depth=0), [False, False, False, True])
    # reach counts: a Gaussian 0.4 m off the block is open with a small reach, next to it with a large one
    off = np.array([[0.5, 0.5, -0.4]]) + 0.03
    assert thin_or_open(solid, S, off, np.array([0.1]))[0]
    assert not thin_or_open(solid, S, off, np.array([0.35]))[0]


def test_no_solid_is_all_open_and_off_lattice_points_are_refused():
    assert thin_or_open(np.zeros((0, 3)), S, np.zeros((3, 3)), np.ones(3)).all()
    vol, idx = lattice_volume(box((0, 0, 0), (2, 3, 4)), S)
    assert vol.shape == (5, 6, 7) and vol.sum() == 3 * 4 * 5 and (idx.min(axis=0) == 1).all()
    with pytest.raises(ValueError, match="lattice of spacing"):
        lattice_volume(np.array([[0.0, 0, 0], [0.05, 0, 0]]), S)


def test_the_gaussians_of_a_filled_shell_are_thick_and_far_floaters_open():
    # 600 surface Gaussians on a sphere (filled by the solidification: thick) and four small floaters well outside
    n = 600
    i = np.arange(n) + 0.5
    phi, th = np.arccos(1 - 2 * i / n), math.pi * (1 + 5**0.5) * i
    shell = 0.5 * np.stack([np.cos(th) * np.sin(phi), np.sin(th) * np.sin(phi), np.cos(phi)], -1)
    floaters = np.array([[1.5, 0, 0], [-1.5, 0, 0], [0, 0, 1.5], [0, 0, -1.5]])
    g = GaussianSet.from_points(torch.tensor(np.concatenate([shell, floaters]), dtype=torch.float32), scale=0.06)
    cfg = PhysicsConfig(particle_radius=0.05, crop=(-0.7, -0.7, -0.7, 0.7, 0.7, 0.7))
    mask = thin_or_open_gaussians(g, cfg).numpy()
    assert mask.shape == (n + 4,) and mask.dtype == bool
    assert not mask[:n].any()  # every shell Gaussian touches the thick filled ball
    assert not mask[n:].any()  # cropped out: not simulated, so not marked
    uncropped = thin_or_open_gaussians(g, PhysicsConfig(particle_radius=0.05)).numpy()
    assert uncropped[n:].all() and not uncropped[:n].any()  # the floaters make no solid near them: open
