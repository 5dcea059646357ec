"""The run the `simulate` and `score` input tests start from: the 300-Gaussian test sphere, four ring cameras and
its -x result after 20 coarse steps."""

from __future__ import annotations

from pathlib import Path

from apps import cli
from recon.formats.ply import save_gaussians

from helpers.cameras import ring_cameras, write_transforms
from helpers.spheres import sphere_gaussians

FAST = ["--particle-radius", "0.08", "--steps", "5", "--dt", "0.004", "--no-empty-reference", "--threads", "2"]


def ring_transforms(path: Path, w: int = 48, h: int = 40) -> Path:
    """A transforms.json at ``path`` of four ring cameras, ``w`` x ``h`` pixels."""
    return write_transforms(path, ring_cameras(4), w, h)


def simulate_sphere(root: Path) -> dict:
    """The sphere's PLY, its cameras and its -x RESULT.h5 (simulate, 20 coarse steps), all in ``root``, as a dict
    with keys root, ply, cameras and h5."""
    ply = save_gaussians(sphere_gaussians(), root / "mine.ply")
    cams = ring_transforms(root / "transforms.json")
    h5 = root / "r.h5"
    assert cli.main(["simulate", str(ply), "-o", str(h5), "--directions=-x", *FAST, "--steps", "20"]) == 0
    return dict(root=root, ply=ply, cameras=cams, h5=h5)
