"""The probes' layout (fluidsim.probes): the solid's box snapped to a grid, so that nearby solids share one setup.

The solids below are sampled on the lattice of spacing 0.1 m at offset 0 (points at multiples of 0.1 m), so their
boxes' sides lie at odd multiples of 0.05 m, and the snap grid's lines at 0.05 + 0.4 k m: ..., -0.75, -0.35, 0.05,
0.45, 0.85, 1.25."""

import numpy as np
import pytest

from fluidsim.probes import (
    DIRECTIONS,
    PHASE_STEPS,
    SNAP_TOLERANCE,
    ProbeConfig,
    lattice_phase,
    probe_setups,
    snapped_box,
)
from fluidsim.scene import lattice_in_box

SPACING = 0.1
SNAP = 4  # spacings: a grid of 0.4 m
CELL = SNAP * SPACING


def solid_in(lo, hi, n: int = 400, seed: int = 0) -> np.ndarray:
    """Random points whose box (grown by half a spacing, as a solid's is) is exactly [lo, hi]."""
    lo, hi = np.asarray(lo, np.float64) + 0.5 * SPACING, np.asarray(hi, np.float64) - 0.5 * SPACING
    pts = np.random.default_rng(seed).uniform(lo, hi, (n, 3))
    pts[0], pts[1] = lo, hi
    return pts


def test_snapped_box_is_the_smallest_grid_box_around_the_box():
    rng = np.random.default_rng(1)
    for _ in range(200):
        lo = rng.uniform(-3, 3, 3)
        hi = lo + rng.uniform(0.01, 2, 3)
        slo, shi = snapped_box(lo, hi, CELL)
        # on the grid (multiples of the cell) ...
        np.testing.assert_allclose(slo / CELL, np.round(slo / CELL), atol=1e-9)
        np.testing.assert_allclose(shi / CELL, np.round(shi / CELL), atol=1e-9)
        # ... around the box, less than one cell away from it
        assert np.all(slo <= lo + SNAP_TOLERANCE * CELL) and np.all(shi >= hi - SNAP_TOLERANCE * CELL)
        assert np.all(lo - slo < CELL) and np.all(shi - hi < CELL)
    # a side on a grid line, up to float noise, stays there: the noise never moves it by a whole cell
    for noise in (-1e-12, 0.0, 1e-12):
        slo, shi = snapped_box(np.full(3, -2 * CELL + noise), np.full(3, 3 * CELL + noise), CELL)
        assert slo.tolist() == [-2 * CELL] * 3 and shi.tolist() == [3 * CELL] * 3
        # the grid moved by a phase: the same box on the moved grid
        slo, shi = snapped_box(np.full(3, -2 * CELL + 0.03 + noise), np.full(3, 0.5 + noise), CELL, 0.03)
        np.testing.assert_allclose(slo, -2 * CELL + 0.03, rtol=0, atol=1e-12)
        np.testing.assert_allclose(shi, 2 * CELL + 0.03, rtol=0, atol=1e-12)


def test_the_lattice_phase_ignores_float_noise():
    for offset in (0.0, 1 / 3, 0.5, 0.75):  # where the solid's lattice sits, spacings
        phases = set()
        for i in range(-40, 40, 7):
            for noise in (-1e-12, 0.0, 1e-12):  # one lattice point computed from two origins
                phases.add(tuple(lattice_phase(np.full(3, (i + offset - 0.5) * SPACING + noise), SPACING)))
        assert len(phases) == 1
        np.testing.assert_allclose(phases.pop(), ((offset - 0.5) % 1.0) * SPACING, rtol=0, atol=1e-6 * SPACING)


def test_solids_within_one_grid_cell_share_every_setup():
    probe = ProbeConfig(snap=SNAP)
    # two solids whose boxes differ by up to 0.2 m (two spacings), all their sides in the same grid cells
    a = probe_setups(solid_in([-0.65, -0.25, 0.15], [0.75, 0.35, 1.15]), probe, SPACING)
    b = probe_setups(solid_in([-0.45, -0.15, 0.35], [0.55, 0.15, 1.25], seed=3), probe, SPACING)
    assert list(a) == list(DIRECTIONS)
    assert a == b  # the same floats: the same empty scene and the same cache key
    # unsnapped, the same two solids get different setups
    off = ProbeConfig(snap=0)
    assert probe_setups(solid_in([-0.65, -0.25, 0.15], [0.75, 0.35, 1.15]), off, SPACING) != probe_setups(
        solid_in([-0.45, -0.15, 0.35], [0.55, 0.15, 1.25], seed=3), off, SPACING
    )


def test_a_solid_crossing_a_grid_line_gets_another_setup():
    probe = ProbeConfig(snap=SNAP)
    inside = probe_setups(solid_in([-0.65, -0.25, 0.15], [0.85, 0.35, 1.15]), probe, SPACING)
    # one spacing more on +x takes that side past the grid line at 0.85 m
    across = probe_setups(solid_in([-0.65, -0.25, 0.15], [0.95, 0.35, 1.15]), probe, SPACING)
    for d in DIRECTIONS:
        assert inside[d] != across[d]
        # the -x probe's slab sits on the +x side, past the snapped box (1.25 m, not 0.85 m) by the gap
        if d == "-x":
            assert inside[d].fluid_min[0] == pytest.approx(0.85 + 2 * SPACING)
            assert across[d].fluid_min[0] == pytest.approx(1.25 + 2 * SPACING)


def test_the_slab_stays_on_the_solids_lattice():
    """On a lattice shifted by a fraction of a spacing (a replica), the snapped box's sides move by whole spacings, so
    along the flow the slab's particles sit on the solid's lattice, as unsnapped: the replicas keep their shifted
    slabs."""
    probe = ProbeConfig(snap=SNAP)
    for offset in ([0.0, 0.0, 0.0], [1 / 2, 1 / 3, 1 / 5], [1 / 4, 2 / 3, 2 / 5]):
        shift = np.asarray(offset) * SPACING
        pts = solid_in([-0.65, -0.25, 0.15], [0.75, 0.35, 1.15]) + shift
        setups = probe_setups(pts, probe, SPACING)
        for d in DIRECTIONS:
            axis = "xyz".index(d[1])
            fluid = lattice_in_box(setups[d].fluid_min, setups[d].fluid_max, SPACING)
            cells = fluid[:, axis] / SPACING - offset[axis]
            np.testing.assert_allclose(cells, np.round(cells), atol=1e-6)


@pytest.mark.parametrize("seed", range(5))
def test_the_snapped_layout_contains_the_unsnapped_one_and_costs_a_bounded_growth(seed):
    """The snapped domain contains the unsnapped one; each side grows by at most what the box's growth (< 1 cell per
    side, < 2 cells in extent) adds through the layout's fractions of the extent: 2.3 cells upstream (box, thickness
    0.5 x extent, padding 0.15 x extent), 1.6 across the flow (box, margin and padding 0.15 x extent each), 1.3
    downstream (box and padding)."""
    rng = np.random.default_rng(seed)
    lo = rng.uniform(-2, 2, 3)
    pts = solid_in(lo, lo + rng.uniform(0.3, 2.5, 3), seed=seed)
    raw = probe_setups(pts, ProbeConfig(snap=0), SPACING)
    snapped = probe_setups(pts, ProbeConfig(snap=SNAP), SPACING)
    tol = SNAP_TOLERANCE * CELL + SPACING / PHASE_STEPS  # how far a side may move inward (snapped_box)
    for d in DIRECTIONS:
        r, s = raw[d], snapped[d]
        assert s.velocity == r.velocity
        grow_lo = np.subtract(r.domain_min, s.domain_min)
        grow_hi = np.subtract(s.domain_max, r.domain_max)
        assert np.all(grow_lo >= -tol) and np.all(grow_hi >= -tol), d  # contains the unsnapped domain
        axis = "xyz".index(d[1])
        upstream_hi = d[0] == "-"  # a flow toward -axis comes from the +axis side
        bound_lo, bound_hi = np.full(3, 1.6 * CELL), np.full(3, 1.6 * CELL)
        bound_lo[axis], bound_hi[axis] = (1.3 * CELL, 2.3 * CELL) if upstream_hi else (2.3 * CELL, 1.3 * CELL)
        assert np.all(grow_lo <= bound_lo + tol) and np.all(grow_hi <= bound_hi + tol), d
        # the slab still keeps the gap to the solid and spans it across the flow
        side = 1 if upstream_hi else 0
        face = (s.fluid_min if upstream_hi else s.fluid_max)[axis]
        solid_side = pts[:, axis].max() + 0.5 * SPACING if side else pts[:, axis].min() - 0.5 * SPACING
        assert (face - solid_side) * (1 if upstream_hi else -1) >= 2 * SPACING - tol
        across = [a for a in range(3) if a != axis]
        assert np.all(np.asarray(s.fluid_min)[across] <= pts.min(0)[across])
        assert np.all(np.asarray(s.fluid_max)[across] >= pts.max(0)[across])


def test_snap_must_be_a_whole_number_of_spacings():
    for bad in (-1, 2.5, True, "4"):
        with pytest.raises(ValueError, match="snap"):
            ProbeConfig(snap=bad)
    assert ProbeConfig().snap == 0  # off unless asked for: docs/performance.md measures what it costs
