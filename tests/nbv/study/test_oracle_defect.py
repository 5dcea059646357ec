"""The planted defect as an oracle case: a state whose best view is known (:mod:`nbv.study.oracle`).

The true object is a closed cube shell of Gaussians (as in ``test_defect.py``, side 1, 13 x 13 per face), each face
its own colour so that a hole shows in the images: through it a camera sees the inside of the opposite wall. The
reconstruction of the state lacks a disc of radius 0.25 in the +x face (the planted defect). One view is selected,
camera 4 (looking at the -x face, opposite the hole); the seven others are the candidates, camera 0 straight at the
hole. The oracle trains a copy per candidate for M = 30 iterations late in a 200-iteration schedule (iteration 150 on,
where the learning rates have decayed: a model trained from its first iteration falls in PSNR with any view added)
and tests on twelve cameras of a higher ring.

Measured (1 thread): camera 0 gains +0.83 dB, the only clear gain (next: camera 5, +0.10 dB; the others -0.4 to
-3.3 dB). The rules' rank of camera 0 among the seven:

| rule | rank of the hole camera |
| --- | --- |
| fisher | 1 |
| fvs | 1 (it is the farthest from camera 4) |
| coverage (frustum) | 5 |
| coverage-occ | 7 (last: the hole removed what it sees) |
| fluid (frustum S(T)) | 7 |
| fluid-occ (depth-tested S(T)) | 3 |

So on this case the visual and geometric baselines find the defect, the depth-tested physics lifts the hole camera
from last (its coverage control) to third, and the frustum physics ranks it last: the result of ``test_defect.py``,
now against the view that actually helps.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from nbv.active.probes import probe_run
from nbv.physics import PhysicsConfig
from nbv.plan import PlanningContext
from nbv.plan.fisher import FisherPlanner
from nbv.plan.fvs import farthest_view_distances
from nbv.plan.physics import physics_view_scores
from nbv.study.oracle import oracle_gains
from recon.camera import Camera
from recon.datasets import View
from recon.gaussians import GaussianSet
from recon.render import render
from recon.train import Trainer, scene_extent
from recon.train_config import TrainConfig

N_SIDE, HOLE = 13, 0.25
PROBES = PhysicsConfig(
    particle_radius=0.08, steps=75, dt=0.004, scale=2.0, empty_reference=False, directions=("-x", "+x", "-z", "+z")
)
FACE_COLOURS = {
    (0, 1): (0.9, 0.2, 0.2),
    (0, 0): (0.2, 0.2, 0.9),
    (1, 1): (0.2, 0.8, 0.2),
    (1, 0): (0.8, 0.8, 0.2),
    (2, 1): (0.2, 0.8, 0.8),
    (2, 0): (0.8, 0.2, 0.8),
}
SELECTED, CANDIDATES, HOLE_CAMERA = [4], [0, 1, 2, 3, 5, 6, 7], 0


def coloured_cube() -> tuple[np.ndarray, np.ndarray]:
    """Points on the faces of [-0.5, 0.5]^3 (shared edges once) and their face colours."""
    t = np.linspace(-0.5, 0.5, N_SIDE)
    a, b = (m.ravel() for m in np.meshgrid(t, t, indexing="ij"))
    points, colours = [], []
    for axis in range(3):
        for side, sign in enumerate((-0.5, 0.5)):
            p = np.zeros((len(a), 3))
            p[:, axis] = sign
            others = [k for k in range(3) if k != axis]
            p[:, others[0]], p[:, others[1]] = a, b
            points.append(p)
            colours.append(np.tile(FACE_COLOURS[(axis, side)], (len(a), 1)))
    pts, cols = np.concatenate(points), np.concatenate(colours)
    _, first = np.unique(np.round(pts, 9), axis=0, return_index=True)
    keep = np.sort(first)
    return pts[keep], cols[keep]


def _gaussians(points: np.ndarray, colours: np.ndarray) -> GaussianSet:
    return GaussianSet.from_points(
        torch.tensor(points, dtype=torch.float32),
        torch.tensor(colours, dtype=torch.float32),
        scale=0.7 / (N_SIDE - 1),
        opacity=0.9,
    )


def _ring(count: int, height: float, offset: float, prefix: str) -> list[Camera]:
    angles = (np.arange(count) + offset) * 2 * math.pi / count
    eyes = [(2.5 * math.cos(x), height, 2.5 * math.sin(x)) for x in angles]
    return [
        Camera.look_at(e, (0, 0, 0), (0, 1, 0), 48, 48, math.radians(45), name=f"{prefix}{k}")
        for k, e in enumerate(eyes)
    ]


def _rank(scores, position: int) -> int:
    order = sorted(range(len(scores)), key=lambda i: (-scores[i], i))
    return order.index(position) + 1


@pytest.fixture(scope="module")
def case():
    pts, cols = coloured_cube()
    r = np.linalg.norm(pts[:, 1:], axis=1)
    hole = np.isclose(pts[:, 0], 0.5) & (r < HOLE)
    truth, holed = _gaussians(pts, cols), _gaussians(pts[~hole], cols[~hole])
    cams, tests = _ring(8, 0.2, 0.0, "c"), _ring(12, 0.9, 0.5, "t")
    bg = torch.ones(3)
    with torch.no_grad():
        views = [View(c, render(truth, c, bg, backend="torch").image.clamp(0, 1), None, c.name) for c in cams]
        test_views = [View(c, render(truth, c, bg, backend="torch").image.clamp(0, 1), None, c.name) for c in tests]
    cfg = TrainConfig.for_iterations(200, sh_degree=0, densify_from_iter=0, opacity_reset_interval=10**6)

    def new_trainer() -> Trainer:
        return Trainer(holed, cfg, extent=scene_extent(cams), backend="torch")

    state = new_trainer().state_dict()
    state["iteration"] = 150  # late in the schedule: decayed learning rates
    oracle = oracle_gains(
        new_trainer,
        state,
        [views[i] for i in SELECTED],
        [views[i] for i in CANDIDATES],
        test_views,
        (1.0, 1.0, 1.0),
        30,
    )
    ctx = PlanningContext(
        gaussians=holed,
        train_views=[views[i] for i in SELECTED],
        candidates=[cams[i] for i in CANDIDATES],
        candidate_ids=CANDIDATES,
        n_selected=1,
        budget=4,
        background=bg,
    )
    divergence = probe_run(holed, PROBES, "the holed cube").divergence
    ones = torch.ones(holed.num, dtype=torch.float64)
    scores = {
        "fisher": FisherPlanner().rank(ctx, 1)[1],
        "fvs": farthest_view_distances(ctx.candidates, [cams[i] for i in SELECTED]),
    }
    for occ, suffix in ((False, ""), (True, "-occ")):
        scores["coverage" + suffix] = physics_view_scores(holed, ctx.candidates, ones, occlusion=occ)
        scores["fluid" + suffix] = physics_view_scores(holed, ctx.candidates, divergence, occlusion=occ)
    return oracle, scores


def test_the_oracle_finds_the_hole_camera(case):
    oracle, _ = case
    gains = oracle["gain_psnr"]
    best = CANDIDATES.index(HOLE_CAMERA)
    assert _rank(gains, best) == 1
    assert gains[best] > 0.3  # measured +0.83 dB
    assert gains[best] - sorted(gains)[-2] > 0.3  # and clear of the next (+0.10 dB)


def test_each_rules_rank_of_the_hole_camera(case):
    _, scores = case
    pos = CANDIDATES.index(HOLE_CAMERA)
    ranks = {name: _rank(s, pos) for name, s in scores.items()}
    assert ranks["fisher"] == 1 and ranks["fvs"] == 1
    assert ranks["coverage-occ"] == len(CANDIDATES)  # coverage ranks the hole camera last
    assert ranks["fluid-occ"] <= 3 < ranks["coverage-occ"]  # the depth-tested physics lifts it
    assert ranks["fluid"] == len(CANDIDATES)  # the frustum physics does not
    assert ranks["coverage"] >= 4
