"""The method's own claim, as a test: a planted defect must show in D_g, D-bar and the view ranking.

A closed cube shell of Gaussians (side 1 scene unit, 2 m after auto scaling) against the same shell with a
hole punched in its +x face (a disc of radius 0.25, a quarter of the face removed). The four horizontal
probes run at coarse settings (r = 0.08 m, 75 steps of 4 ms). Eight cameras look at the cube from around
it, camera 0 straight at the hole.

What we measured with the filled solid (cut edges + fill, :mod:`nbv.physics.solidify`): the intact cube is a filled
body (3367 solid points), the holed one a thick shell (2591) whose opening runs from the outside into the
cavity (no solid point on the hole's axis), and 13 fluid particles of the -x probe end inside the cavity.
D_g at the hole rim rises (x1.12), D-bar rises (x2.09), but the fluid that
enters through the hole raises D_g most on the *inner* side of the opposite wall, so the cameras on the
hole's axis (front and back) gain the most and the back cameras outrank the front one. The paper's claim
"the camera looking at the defect ranks near the top" therefore does not hold with the paper's frustum-only
visibility. With ``occlusion=True`` (a depth test against the rendered surface, not in the paper) only the
Gaussians a camera actually sees count, and the four cameras on the hole's axis take the top four places;
that is what the ranking test asserts.

The coverage control (S(T) with D_g = 1, no physics) ranks the hole camera last: the hole removes what that camera
sees. The physics is what lifts it (to 4th of 8 with the depth test); see
``test_coverage_alone_does_not_find_the_hole``.
"""

import math

import numpy as np
import pytest
import torch

from nbv.physics import PhysicsConfig, simulate_gaussians
from nbv.scores import rank, unoccluded, view_scores
from recon.camera import Camera
from recon.gaussians import GaussianSet
from recon.render import render

N_SIDE = 13
HOLE = 0.25  # hole radius, scene units
CFG = PhysicsConfig(
    particle_radius=0.08, steps=75, dt=0.004, scale=2.0, empty_reference=False, directions=("-x", "+x", "-z", "+z")
)


def cube_shell(n: int = N_SIDE) -> tuple[np.ndarray, np.ndarray]:
    """Points on the six faces of [-0.5, 0.5]^3 (n x n per face, shared edges once) and a +x-face mask."""
    t = np.linspace(-0.5, 0.5, n)
    a, b = (m.ravel() for m in np.meshgrid(t, t, indexing="ij"))
    faces = []
    for axis in range(3):
        for sign in (-0.5, 0.5):
            p = np.zeros((len(a), 3))
            p[:, axis] = sign
            others = [k for k in range(3) if k != axis]
            p[:, others[0]], p[:, others[1]] = a, b
            faces.append(p)
    pts = np.unique(np.round(np.concatenate(faces), 9), axis=0)
    return pts, np.isclose(pts[:, 0], 0.5)


def gaussians(points: np.ndarray) -> GaussianSet:
    spacing = 1.0 / (N_SIDE - 1)
    return GaussianSet.from_points(torch.tensor(points, dtype=torch.float32), scale=0.7 * spacing, opacity=0.9)


@pytest.fixture(scope="module")
def runs():
    pts, front = cube_shell()
    r = np.linalg.norm(pts[:, 1:], axis=1)
    hole = front & (r < HOLE)
    keep = ~hole
    intact, holed = gaussians(pts), gaussians(pts[keep])
    res_i = simulate_gaussians(intact, CFG, progress=False)
    res_h = simulate_gaussians(holed, CFG, progress=False)
    rim = front & (r >= HOLE) & (r < HOLE + 2.0 / (N_SIDE - 1))  # two Gaussian spacings around the hole
    cams = [
        Camera.look_at(
            (2.5 * math.cos(a), 0.2, 2.5 * math.sin(a)), (0, 0, 0), (0, 1, 0), 64, 64, math.radians(45), name=f"c{k}"
        )
        for k, a in enumerate(np.arange(8) * 2 * math.pi / 8)
    ]
    return dict(intact=intact, holed=holed, res_i=res_i, res_h=res_h, keep=keep, rim=rim, cams=cams)


def _scores(g: GaussianSet, d: np.ndarray, cams, occlusion: bool) -> torch.Tensor:
    outs = [render(g, c, 1.0) for c in cams]
    vis = None
    if occlusion:
        vis = torch.stack(
            [unoccluded(g.means, 3 * g.max_radii().double(), c, o) for c, o in zip(cams, outs, strict=True)]
        )
    return view_scores(torch.from_numpy(d), outs, visible=vis)


def test_the_hole_is_open_to_the_fluid(runs):
    """The opening is in the solid (not closed at the lattice spacing) and the fluid goes through it.

    Measured at this alignment and at six shifts of the cube against the lattice (0.125-0.75 spacing): the hole's
    axis carries 7-8 solid points in the filled intact cube and none in the holed one, and 8-19 fluid particles of
    the -x probe end inside the cavity (none for the intact cube)."""
    spacing = 2.0 * CFG.particle_radius
    for name, expect_open in (("res_i", False), ("res_h", True)):
        res = runs[name]
        solid = res.solid  # sim metres: the scene scaled by 2, axes unchanged (up +y)
        on_axis = (np.abs(solid[:, 1:]) < 0.5 * spacing).all(axis=1) & (solid[:, 0] > 0.0)
        inside = (np.abs(res.leaks["-x"].x_final) < 0.6).all(axis=1).sum()  # the cavity is |x|, |y|, |z| < 0.7 m
        if expect_open:
            assert not on_axis.any() and inside >= 5
        else:
            assert on_axis.sum() >= 5 and inside == 0


def test_divergence_rises_at_the_defect(runs):
    """The rim's mean D_g (the same Gaussians, matched by index) rises when the hole opens.

    The numbers behind the threshold: runs are deterministic (two runs gave bit-identical D_g and D-bar), and a hole
    that the solid closes gives exactly x1.000 (the same solid gives the same fluid: an 11 cm hole in the real person
    capture at r = 0.05 m leaves its 181 solid points unchanged and its rim at x1.000). Here the rim reads x1.122
    (0.288 -> 0.323, all of it from the -x probe: the other three do not reach the +x face in 75 steps). The size of
    the rise is set by how the lattice falls on the cube: shifting the cube by 0.125-0.75 spacing gives x1.55-x3.56
    (the intact rim collects 9-225 samples per Gaussian depending on how far the first fluid layer stands off the
    solid, and none at all for a sixth shift), and eight points that the cut-edge test adds in the hole's mouth (edges
    cut by the product of the Gaussians' peaks, 0.39, where their combined opacity stays at 0.28 < tau) take it from
    x1.41 to x1.12 at this alignment, the lowest measured. So the test asserts the rise, x1.05, above the closed-hole
    value 1 and below every measured value; D-bar (``test_geometry_divergence_rises``) carries the size of the effect.
    """
    d_i, d_h = runs["res_i"].divergence, runs["res_h"].divergence
    rim, keep = runs["rim"], runs["keep"]
    assert rim.sum() >= 20
    rim_intact, rim_holed = d_i[rim].mean(), d_h[rim[keep]].mean()
    assert rim_intact > 0  # the intact front face is upstream of the -x probe: it is not a zero baseline
    assert rim_holed > 1.05 * rim_intact


def test_geometry_divergence_rises(runs):
    # measured x2.09 here, x2.4-x5.0 at the six lattice shifts of test_divergence_rises_at_the_defect
    assert runs["res_h"].dbar > 1.5 * runs["res_i"].dbar
    # the rise is not an artefact of removing low-D Gaussians: the Gaussians both sets share read higher too
    assert runs["res_h"].divergence.mean() > 1.5 * runs["res_i"].divergence[runs["keep"]].mean()


def test_defect_axis_cameras_gain_most(runs):
    """Without occlusion every camera sees every Gaussian; with the depth test, the cameras on the hole's
    axis (0: facing the hole, 3-5: facing the opposite wall, where the inflow lands) gain, the side ones
    (1, 2, 6, 7) barely change."""
    cams = runs["cams"]
    s_i = _scores(runs["intact"], runs["res_i"].divergence, cams, occlusion=True)
    s_h = _scores(runs["holed"], runs["res_h"].divergence, cams, occlusion=True)
    gain = (s_h / s_i).tolist()
    axis, side = [0, 3, 4, 5], [1, 2, 6, 7]
    assert min(gain[k] for k in axis) > 1.5 * max(gain[k] for k in side)
    assert set(rank(s_h)[:4].tolist()) == set(axis)


def test_coverage_alone_does_not_find_the_hole(runs):
    """The coverage control (issue 19): rank the views by A(T) = sum_{g visible} w_g, i.e. S(T) with D_g = 1.

    Measured on this scene (holed cube): coverage ranks the camera facing the hole *last* of the eight, with and
    without the depth test, because the hole removed Gaussians from exactly that view (A = 26.5 vs 26.6-27.0
    without occlusion; 10.8 vs 11.4-13.2 with it). So coverage alone does not pick the hole camera, and the
    physics margin is what moves it: with the depth test, S(T) lifts camera 0 from 8th (coverage) to 4th, inside
    the four cameras on the hole's axis, and S(T) / A(T) (the area-weighted mean D_g a view sees) ranks it 4th too.
    Between the intact and the holed cube, camera 0's coverage falls (x0.95) while its S(T) rises (x3.2).
    Under the paper's frustum-only visibility the physics does not rescue it: S(T) also ranks camera 0 last, since
    every camera counts the inner wall that the inflow hits (the module docstring).
    """
    cams, g_i, g_h = runs["cams"], runs["intact"], runs["holed"]
    d_i, d_h = runs["res_i"].divergence, runs["res_h"].divergence
    last = len(cams) - 1

    def position(scores: torch.Tensor, cam: int) -> int:
        return rank(scores).tolist().index(cam)

    for occlusion in (False, True):
        area = _scores(g_h, np.ones(g_h.num), cams, occlusion)
        assert position(area, 0) == last  # coverage ranks the hole camera last
    area_i = _scores(g_i, np.ones(g_i.num), cams, occlusion=True)
    area_h = _scores(g_h, np.ones(g_h.num), cams, occlusion=True)
    s_i = _scores(g_i, d_i, cams, occlusion=True)
    s_h = _scores(g_h, d_h, cams, occlusion=True)
    assert position(s_h, 0) <= 3 < position(area_h, 0)  # the physics margin: top 4 with D_g, last with ones
    assert position(s_h / area_h, 0) <= 3
    assert area_h[0] < area_i[0] and s_h[0] > 2.0 * s_i[0]
    # the negative result under the paper's visibility: S(T) ranks the hole camera last as well
    assert position(_scores(g_h, d_h, cams, occlusion=False), 0) == last
