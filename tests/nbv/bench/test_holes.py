"""The hole check (:mod:`nbv.bench.holes`): the hole's geometry against hand computations and brute force, and the
mechanism measured on the real person capture, shown on a synthetic capture-like set.

The capture-like set is a hollow sphere of thin surface Gaussians (normal sigma 10x below the spacing) with, 5 cm
under the surface, larger flat Gaussians whose tails overlap (the person capture has such sub-surface Gaussians, of
sigma 4-13 cm, under its 1-1.5 cm surface elements). Removing the centres in a cylinder leaves those tails over the
disc: a render along the axis still sees opacity >= tau there, so the solid stays closed and D_g cannot move (the
same solid gives the same fluid). A see-through hole, which also removes every Gaussian whose footprint crosses the
disc, opens the solid, and the head-on probe's D_g at the rim rises.
"""

import dataclasses
import math

import numpy as np
import pytest
import torch

from nbv.bench.holes import (
    Hole,
    axis_opacity,
    covering,
    cut_cylinder,
    disc_offsets,
    head_on_probe,
    lattice_keys,
    open_fraction,
    ray_peaks,
    rim_ratios,
    simulate_with_hole,
)
from nbv.physics import PhysicsConfig, simulate_gaussians
from nbv.physics.scene_frame import gaussian_arrays_in_sim, inverse_covariances_in_sim
from nbv.physics.solidify import (
    SceneTransform,
    SolidifyConfig,
    SolidLattice,
    gaussians_to_solid,
)
from recon.gaussians import GaussianSet, concat

from helpers.shells import flat_gaussians
from helpers.spheres import fibonacci_sphere

RADIUS = 0.6  # sphere, m (scale 1: scene units are simulation metres, +y up)
SPACING = 0.1  # lattice spacing of the probes below (r = 0.05 m)
HOLE = Hole((RADIUS, 0.0, 0.0), (1.0, 0.0, 0.0), radius=0.2, depth=0.1, band=0.1)
TAU = 0.3
SURFACE_SIGMA = 0.04  # in-plane sigma of the surface Gaussians, m: their reach 3 sigma exceeds the spacing
TAIL_SIGMA, TAIL_DEPTH, TAIL_GAP = (0.12, 0.05), 0.05, 1.0  # the sub-surface Gaussians: sigma (plane, normal), m
CFG = PhysicsConfig(particle_radius=0.05, steps=75, dt=0.004, scale=1.0, empty_reference=False, directions=("-x",))


def capture_like(with_tails: bool = True) -> GaussianSet:
    """The hollow sphere's surface (sigma 4 cm in the plane, 1 cm along the normal, o = 0.9), plus, 5 cm under it,
    flat Gaussians of sigma 12 cm in the plane and 5 cm along the normal (o = 0.9), one sigma apart."""
    d = fibonacci_sphere(int(4 * math.pi * RADIUS**2 / (1.2 * SURFACE_SIGMA) ** 2))
    surface = flat_gaussians(RADIUS * d, d, SURFACE_SIGMA, SPACING / 10.0, 0.9)
    if not with_tails:
        return surface
    e = fibonacci_sphere(int(4 * math.pi * RADIUS**2 / (TAIL_GAP * TAIL_SIGMA[0]) ** 2))
    return concat([surface, flat_gaussians((RADIUS - TAIL_DEPTH) * e, e, *TAIL_SIGMA, 0.9)])


def arrays(g: GaussianSet):
    tr = SceneTransform("+y", 1.0)
    means, _, opacities, _ = gaussian_arrays_in_sim(g, tr)
    return means, inverse_covariances_in_sim(g, tr), opacities


def holed(g: GaussianSet, see_through: float | None = None) -> tuple[GaussianSet, np.ndarray]:
    means, inv, opacities = arrays(g)
    removed = HOLE.removed(means)
    if see_through is not None:
        removed |= covering(HOLE, means, inv, opacities, see_through)
    kept = np.nonzero(~removed)[0]
    return g.subset(torch.from_numpy(kept)), kept


def solid_keys(g: GaussianSet) -> set:
    s = gaussians_to_solid(g, SolidifyConfig(spacing=SPACING), SceneTransform("+y", 1.0))
    return {tuple(k) for k in np.round(s.points / SPACING).astype(int).tolist()}


# ---- geometry -------------------------------------------------------------------------------------------------
def test_hole_and_rim_masks_by_hand():
    h = Hole((1.0, 0.0, 0.0), (2.0, 0.0, 0.0), radius=0.1, depth=0.05, band=0.1)
    assert h.normal == (1.0, 0.0, 0.0)
    pts = np.array(
        [
            [1.0, 0.05, 0.0],  # t 0, r 0.05: in the hole
            [1.04, 0.0, 0.099],  # t 0.04, r 0.099: in the hole
            [1.06, 0.0, 0.0],  # t 0.06: outside the slab
            [1.0, 0.1, 0.0],  # r = R: the rim's first radius
            [0.96, 0.0, -0.19],  # r 0.19: rim
            [1.0, 0.2, 0.0],
        ]
    )  # r = R + band: outside the rim
    assert h.removed(pts).tolist() == [True, True, False, False, False, False]
    assert h.rim(pts).tolist() == [False, False, False, True, True, False]
    t, r = h.coordinates(pts)
    np.testing.assert_allclose(t, [0.0, 0.04, 0.06, 0.0, -0.04, 0.0], atol=1e-12)
    np.testing.assert_allclose(r, [0.05, 0.099, 0.0, 0.1, 0.19, 0.2], atol=1e-12)
    tunnel = Hole((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), radius=0.1, depth=math.inf)
    assert tunnel.removed(np.array([[0.0, 0.05, -50.0], [0.0, 0.2, 0.0]])).tolist() == [True, False]


@pytest.mark.parametrize(
    "kwargs, word",
    [
        ({"radius": 0.0}, "radius"),
        ({"band": float("nan")}, "band"),
        ({"depth": -1.0}, "depth"),
        ({"normal": (0.0, 0.0, 0.0)}, "normal"),
        ({"point": (0.0, 1.0)}, "point"),
    ],
)
def test_hole_validation_names_the_field(kwargs, word):
    base = {"point": (0.0, 0.0, 0.0), "normal": (1.0, 0.0, 0.0)}
    with pytest.raises(ValueError, match=word):
        Hole(**{**base, **kwargs})


def test_ray_peaks_equal_dense_sampling_of_the_ray():
    rng = np.random.default_rng(3)
    g = GaussianSet(
        torch.tensor(rng.uniform(-0.3, 0.3, (40, 3))),
        torch.tensor(rng.normal(size=(40, 4))),
        torch.tensor(rng.uniform(np.log(0.01), np.log(0.2), (40, 3))),
        torch.tensor(rng.normal(size=40)),
        torch.zeros(40, 1, 3, dtype=torch.float64),
    )
    means, inv, opacities = arrays(g)
    h = Hole((0.05, -0.02, 0.1), (0.3, 1.0, -0.5), radius=0.1, depth=0.2)
    a = np.cross(np.asarray(h.normal), (0.0, 1.0, 0.0))
    a /= np.linalg.norm(a)
    b = np.cross(np.asarray(h.normal), a)
    offset = (0.03, -0.04)
    s = np.linspace(-0.2, 0.2, 40001)
    x = np.asarray(h.point) + offset[0] * a + offset[1] * b + s[:, None] * np.asarray(h.normal)
    dense = np.empty(len(means))
    for k in range(len(means)):
        d = x - means[k]
        dense[k] = opacities[k] * np.exp(-0.5 * np.einsum("si,ij,sj->s", d, inv[k], d)).max()
    exact = ray_peaks(h, means, inv, opacities, offset)
    assert np.all(exact >= dense - 1e-12)  # the exact peak is never below a sample
    np.testing.assert_allclose(exact, dense, rtol=1e-4, atol=1e-9)
    combined, single = axis_opacity(h, means, inv, opacities, offset)
    assert combined == pytest.approx(1.0 - np.prod(1.0 - exact), rel=1e-12)
    assert single == pytest.approx(exact.max())


def test_disc_offsets_cover_the_disc():
    offsets = disc_offsets(HOLE, 0.01)
    assert (np.hypot(*offsets.T) < HOLE.radius + 1e-12).all()
    assert len(offsets) == pytest.approx(math.pi * HOLE.radius**2 / 0.01**2, rel=0.02)


def test_rim_ratios_by_hand():
    intact = np.array([[1.0, 2.0, 3.0, 4.0], [4.0, 0.0, 1.0, 1.0]])
    holed_rows = np.array([[9.0, 6.0, 8.0], [1.0, 2.0, 0.0]])  # the rows of intact Gaussians 0, 2, 3
    rim = np.array([False, True, True, True])  # Gaussian 1 was removed; the rim left is 2, 3
    out = rim_ratios(intact, holed_rows, np.array([0, 2, 3]), rim)
    assert out["probe 0"] == pytest.approx(((6 + 8) / 2) / ((3 + 4) / 2))
    assert out["probe 1"] == pytest.approx(((2 + 0) / 2) / ((1 + 1) / 2))
    assert out["max"] == pytest.approx(((6 + 8) / 2) / ((3 + 4) / 2))
    with pytest.raises(ValueError, match="do not match"):
        rim_ratios(intact, holed_rows[:, :2], np.array([0, 2, 3]), rim)


# ---- the mechanism on a capture-like set ------------------------------------------------------------------------
def test_a_hollow_surface_opens_where_its_centres_are_removed():
    g = capture_like(with_tails=False)
    hg, kept = holed(g)
    means, inv, opacities = arrays(hg)
    assert open_fraction(HOLE, means, inv, opacities, TAU)[0] > 0.4  # the edge tails cover the rest (0.56)
    intact, holed_solid = solid_keys(g), solid_keys(hg)
    # the filled ball becomes a shell open to the fluid: most of its interior leaves the solid
    assert len(intact - holed_solid) > 0.5 * len(intact)


def test_covering_tails_keep_a_centre_hole_closed_and_a_see_through_hole_opens():
    """What the person capture shows: the centres' hole leaves the neighbours' tails over the disc (combined opacity
    >= tau on every ray, and even a single Gaussian reaching tau on most), so the solid is unchanged; the see-through
    hole opens it."""
    g = capture_like()
    hg, _ = holed(g)
    means, inv, opacities = arrays(hg)
    combined_open, single_open = open_fraction(HOLE, means, inv, opacities, TAU)
    assert combined_open == 0.0 and single_open < 0.25  # the person capture: 0 % and 13 % (0 % for a tunnel)
    assert solid_keys(hg) == solid_keys(g)
    sg, _ = holed(g, see_through=0.02)
    means, inv, opacities = arrays(sg)
    assert open_fraction(HOLE, means, inv, opacities, TAU)[0] == 1.0
    assert len(solid_keys(g) - solid_keys(sg)) > 0.2 * len(solid_keys(g))


@pytest.fixture(scope="module")
def probes():
    g = capture_like()
    means = arrays(g)[0]
    out = {"intact": simulate_gaussians(g, CFG, progress=False)}
    for name, eps in (("centres", None), ("see_through", 0.02)):
        hg, kept = holed(g, eps)
        mask = np.zeros(g.num, dtype=bool)
        mask[kept] = True
        out[name] = (simulate_gaussians(hg, CFG, progress=False), kept, HOLE.rim(means, mask))
    return out


def test_rim_divergence_needs_the_hole_to_open(probes):
    """A hole the solid closes gives the same fluid, so the rim's D_g is exactly unchanged (x1.000); the see-through
    hole lets the head-on (-x) probe into the sphere and its rim D_g rises (measured x28: the fluid that flows past the
    rim into the hole reaches every rim Gaussian, where it reached 20 % of them on the closed surface)."""
    intact = probes["intact"]
    res, kept, rim = probes["centres"]
    np.testing.assert_array_equal(res.solid, intact.solid)
    assert rim_ratios(intact.per_probe, res.per_probe, kept, rim)["probe 0"] == pytest.approx(1.0, abs=1e-12)
    res, kept, rim = probes["see_through"]
    assert len(res.solid) < 0.7 * len(intact.solid)
    assert rim_ratios(intact.per_probe, res.per_probe, kept, rim)["probe 0"] > 1.2


def test_head_on_probe_and_lattice_keys():
    """The head-on probe's flow is the most anti-parallel to the normal; lattice keys round to the nearest site."""
    dirs = ("-x", "+x", "-z", "+z", "-y")
    assert head_on_probe(dirs, (1.0, 0.0, 0.0)) == "-x"  # fluid flows along -x onto a +x-facing hole
    assert head_on_probe(dirs, (0.0, 0.0, -1.0)) == "+z"
    assert head_on_probe(dirs, (0.0, 1.0, 0.0)) == "-y"
    assert head_on_probe(dirs, (0.6, 0.0, 0.8)) == "-z"
    pts = np.array([[0.0, 0.0, 0.0], [0.049, -0.051, 0.1], [0.051, 0.0, 0.0], [0.0, 0.0, 0.004]])
    assert lattice_keys(pts, 0.1) == {(0, 0, 0), (0, -1, 1), (1, 0, 0)}


def test_cut_cylinder_equals_brute_force_and_keeps_occupancy():
    spacing, lo = 0.05, np.array([-0.3, -0.2, -0.25])
    shape = (13, 9, 11)
    occupancy = np.zeros(shape, bool)
    occupancy[1:12, 1:8, 2:10] = True
    occupancy[6, 4, 5] = False  # a pocket: never re-filled by the cut
    ijk = np.argwhere(occupancy)
    solid = SolidLattice(
        points=lo + spacing * ijk,
        lattice_min=lo,
        lattice_shape=shape,
        occupancy=occupancy,
        spacing=spacing,
        counts={"opacity": len(ijk), "total": len(ijk)},
    )
    hole = Hole((0.05, 0.0, 0.0), (1.0, 0.3, -0.2), radius=0.11, depth=0.08)
    cut = cut_cylinder(solid, hole)
    n = np.asarray(hole.normal)
    inside = set()
    for p in solid.points:  # the cylinder's definition, one point at a time
        d = p - np.asarray(hole.point)
        t = float(d @ n)
        if abs(t) < hole.depth and np.linalg.norm(d - t * n) < hole.radius:
            inside.add(tuple(np.round(p, 9)))
    assert len(inside) > 10
    assert {tuple(np.round(p, 9)) for p in cut.points} == {tuple(np.round(p, 9)) for p in solid.points} - inside
    assert np.array_equal(lo + spacing * np.argwhere(cut.occupancy), cut.points)  # occupancy follows the points
    assert cut.counts["ideal_cut"] == len(inside) and cut.counts["total"] == len(solid.points) - len(inside)
    assert not cut.occupancy[6, 4, 5] and solid.occupancy.sum() == len(ijk)  # the input is not modified


def test_simulate_with_hole_runs_the_probes_against_the_cut_solid():
    gaussians = capture_like()
    cfg = dataclasses.replace(CFG, steps=5)
    res = simulate_with_hole(gaussians, cfg, HOLE)
    plain = gaussians_to_solid(
        gaussians, SolidifyConfig(spacing=SPACING, opacity_threshold=TAU), SceneTransform("+y", 1.0)
    )
    cut = lattice_keys(cut_cylinder(plain, HOLE).points, SPACING)
    assert len(cut) < len(plain.points)
    assert lattice_keys(res.solid, SPACING) == cut


# ---- the benchmark command ------------------------------------------------------------------------------------
def test_bench_hole_command_prints_and_writes_the_figures(tmp_path, capsys):
    import json

    from apps import cli
    from recon.formats.ply import save_gaussians

    ply = save_gaussians(capture_like(), tmp_path / "sphere.ply")
    out = tmp_path / "hole.json"
    hole = ["bench", "hole", str(ply), "--scale", "1", "--point", "0.6,0,0", "--radius", "0.2"]
    probe = ["--depth", "0.1", "--band", "0.1", "--particle-radius", "0.05", "--steps", "20", "--directions=-x"]
    assert cli.main([*hole, *probe, "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "solid 1357 -> 1357 (0 removed, 0 added)" in text and "-x*" in text and "x1.000" in text
    doc = json.loads(out.read_text())
    assert doc["shifts"][0]["solid_removed"] == 0 and doc["shifts"][0]["head_on"] == "-x"
    assert doc["shifts"][0]["probes"]["-x"]["ratio"] == pytest.approx(1.0, abs=1e-12)
    see_through = ["--see-through", "0.02", "--particle-radius", "0.05", "--solid-only", "--shifts", "0,0.5"]
    assert cli.main([*hole, *see_through]) == 0
    text = capsys.readouterr().out
    assert text.count("open to a render: 100 % of the disc") == 2
    # --ideal: the same covered hole, its cylinder cut out of the holed solid (the centres-only hole removed none)
    ideal = ["--depth", "0.1", "--particle-radius", "0.05", "--solid-only", "--ideal", "--json", str(out)]
    assert cli.main([*hole, *ideal]) == 0
    assert "ideal hole, " in capsys.readouterr().out
    doc = json.loads(out.read_text())
    shift = doc["shifts"][0]
    assert doc["hole"]["ideal"] and shift["ideal"] and shift["solid_added"] == 0
    assert shift["solid_holed"] == shift["solid_intact"] - shift["solid_removed"] and shift["solid_removed"] >= 8


def test_bench_hole_refuses_bad_options(tmp_path):
    from apps import cli
    from recon.formats.ply import save_gaussians

    ply = save_gaussians(capture_like(with_tails=False), tmp_path / "sphere.ply")
    base = ["bench", "hole", str(ply), "--scale", "1", "--point", "0.6,0,0", "--solid-only"]
    assert cli.main([*base, "--see-through", "1.5"]) == 2
    assert cli.main([*base, "--radius", "-1"]) == 2
    assert cli.main([*base[:5], "--side", "+z", "--height", "5", "--solid-only"]) == 2  # no surface at y = 5 m
