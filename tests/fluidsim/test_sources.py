"""Tests for fluidsim.sources: boundary particles from walls, point clouds, meshes and spheres.

Lattice counts are checked against hand-computed values, and the filled mesh is checked against
a brute-force numpy twin (lattice ∩ box, minus points within 0.5 * spacing of the surface sample).
"""

import logging
import math

import numpy as np
import open3d as o3d
import pytest

from fluidsim.sources import (
    INSET,
    load_mesh,
    load_points,
    mesh_particles,
    points_inside_mesh,
    sphere_particles,
    wall_particles,
)


def brute_nearest(sources: np.ndarray, queries: np.ndarray, exclude_self: bool = False) -> np.ndarray:
    """O(N·M) distance from each query to its nearest source point, in chunks of 256 queries."""
    out = np.empty(len(queries))
    for start in range(0, len(queries), 256):
        chunk = queries[start : start + 256]
        d2 = ((chunk[:, None, :] - sources[None, :, :]) ** 2).sum(axis=2)
        if exclude_self:
            rows = np.arange(len(chunk))
            d2[rows, start + rows] = np.inf
        out[start : start + 256] = np.sqrt(d2.min(axis=1))
    return out


def self_nearest(points: np.ndarray) -> np.ndarray:
    """O(N²) nearest-neighbour distance of each point to the others."""
    return brute_nearest(points, points, exclude_self=True)


def uniform_surface_points(mesh: o3d.geometry.TriangleMesh, count: int, seed: int) -> np.ndarray:
    """Area-weighted uniform random points on the mesh surface."""
    corners = np.asarray(mesh.vertices)[np.asarray(mesh.triangles)]
    areas = np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    rng = np.random.default_rng(seed)
    tri = rng.choice(len(areas), size=count, p=areas / areas.sum())
    u, v = rng.random((2, count))
    flip = u + v > 1.0
    u[flip], v[flip] = 1.0 - u[flip], 1.0 - v[flip]
    c = corners[tri]
    return c[:, 0] + u[:, None] * (c[:, 1] - c[:, 0]) + v[:, None] * (c[:, 2] - c[:, 0])


def surface_distance(mesh: o3d.geometry.TriangleMesh, points: np.ndarray) -> np.ndarray:
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    return scene.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()


def write_mesh(mesh: o3d.geometry.TriangleMesh, path) -> None:
    mesh = o3d.geometry.TriangleMesh(mesh)
    if str(path).endswith(".stl"):
        mesh.compute_triangle_normals()  # the STL writer needs them; the OBJ writer warns on them
    assert o3d.io.write_triangle_mesh(str(path), mesh)


def box_mesh(size) -> o3d.geometry.TriangleMesh:
    return o3d.geometry.TriangleMesh.create_box(*size)


# ---------------------------------------------------------------------------------------------
# wall_particles


def wall_count(lo, hi, spacing, layers):
    n = [math.ceil(round((h - l) / spacing, 6)) for l, h in zip(lo, hi, strict=True)]
    return math.prod(k + 2 * layers for k in n) - math.prod(n)


@pytest.mark.parametrize(
    ("lo", "hi", "spacing", "layers", "expected"),
    [
        ((0, 0, 0), (1, 1, 1), 0.1, 2, 14**3 - 10**3),
        ((0, 0, 0), (1.0, 0.5, 0.3), 0.1, 2, 14 * 9 * 7 - 10 * 5 * 3),
        ((-1, 0, 2), (0.05, 0.33, 2.71), 0.1, 1, 13 * 6 * 10 - 11 * 4 * 8),  # extents not multiples
        ((0, 0, 0), (0.4, 0.4, 0.4), 0.1, 3, 10**3 - 4**3),
    ],
)
def test_wall_count_matches_hand_computed_lattice(lo, hi, spacing, layers, expected):
    walls = wall_particles(lo, hi, spacing, layers)
    assert walls.shape == (expected, 3)
    assert walls.dtype == np.float64
    assert expected == wall_count(lo, hi, spacing, layers)
    assert len(np.unique(walls, axis=0)) == len(walls)


@pytest.mark.parametrize(("hi", "layers"), [((1.0, 0.5, 0.3), 2), ((0.05, 0.33, 0.71), 3)])
def test_walls_outside_box_within_layers_and_not_clumped(hi, layers):
    lo, hi, spacing = np.zeros(3), np.asarray(hi), 0.1
    walls = wall_particles(lo, hi, spacing, layers)
    # Per-axis (Chebyshev) distance outside the box: the k-th layer sits at (k + 0.5) * spacing.
    outside = np.maximum(lo - walls, walls - hi).max(axis=1)
    assert np.all(outside > 0.0)
    np.testing.assert_allclose(outside.min(), 0.5 * spacing)
    np.testing.assert_allclose(outside.max(), (layers - 0.5) * spacing)
    nearest = self_nearest(walls)
    assert nearest.min() > 0.5 * spacing - 1e-12
    assert nearest.max() <= spacing + 1e-12


def test_walls_are_closed_at_faces_edges_and_corners():
    lo, hi, spacing = np.array([0.0, 0.0, 0.0]), np.array([0.6, 0.45, 0.3]), 0.1
    walls = wall_particles(lo, hi, spacing, layers=2)
    # Probe points on a fine grid over the whole box surface, pulled just inside.
    axes = [np.linspace(lo[a], hi[a], 13) for a in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    on_surface = np.any(np.isclose(grid, lo) | np.isclose(grid, hi), axis=1)
    probes = np.clip(grid[on_surface], lo + 1e-6, hi - 1e-6)
    assert np.any(np.all(np.isclose(probes, lo, atol=1e-5), axis=1))  # a corner is probed
    assert brute_nearest(walls, probes).max() < 1.5 * spacing


def test_walls_symmetric_about_box_centre():
    lo, hi = np.array([-0.2, 0.1, 0.0]), np.array([0.43, 0.37, 0.25])
    walls = wall_particles(lo, hi, 0.1, layers=2)
    mirrored = (lo + hi) - walls
    key = np.lexsort(np.round(walls, 9).T)
    key_m = np.lexsort(np.round(mirrored, 9).T)
    np.testing.assert_allclose(walls[key], mirrored[key_m], atol=1e-12)


def test_walls_on_regular_lattice_when_extent_fits():
    lo, spacing, layers = np.array([0.2, -0.3, 1.0]), 0.1, 2
    hi = lo + spacing * np.array([6, 4, 3])
    walls = wall_particles(lo, hi, spacing, layers)
    ijk = (walls - lo) / spacing - 0.5
    np.testing.assert_allclose(ijk, np.round(ijk), atol=1e-9)
    ijk = np.round(ijk).astype(int)
    full = np.stack(np.meshgrid(*[np.arange(-layers, n + layers) for n in (6, 4, 3)], indexing="ij"), -1)
    full = full.reshape(-1, 3)
    expected = full[np.any((full < 0) | (full >= [6, 4, 3]), axis=1)]
    assert set(map(tuple, ijk)) == set(map(tuple, expected))


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"domain_min": [0, 0, 1], "domain_max": [1, 1, 1]}, "domain_max"),
        ({"domain_min": [0, 0, np.nan], "domain_max": [1, 1, 1]}, "domain_min"),
        ({"domain_min": [0, 0], "domain_max": [1, 1, 1]}, "domain_min"),
        ({"spacing": 0.0}, "spacing"),
        ({"spacing": np.inf}, "spacing"),
        ({"layers": 0}, "layers"),
        ({"layers": 1.5}, "layers"),
    ],
)
def test_wall_validation_names_bad_argument(kwargs, name):
    args = {"domain_min": [0, 0, 0], "domain_max": [1, 1, 1], "spacing": 0.1, "layers": 2} | kwargs
    with pytest.raises(ValueError, match=name):
        wall_particles(**args)


# ---------------------------------------------------------------------------------------------
# sphere_particles


def test_sphere_count_matches_volume():
    points = sphere_particles([0.0, 0.0, 0.0], radius=1.0, spacing=0.1)
    expected = 4.0 / 3.0 * math.pi / 0.1**3
    assert abs(len(points) - expected) / expected < 0.03
    assert np.linalg.norm(points, axis=1).max() <= 1.0 + 1e-9
    assert len(np.unique(points, axis=0)) == len(points)


def test_sphere_benchmark_size():
    points = sphere_particles([0.0, 0.0, 0.0], radius=1.0, spacing=0.05)
    assert abs(len(points) - 4.0 / 3.0 * math.pi * 20**3) / (4.0 / 3.0 * math.pi * 20**3) < 0.01


def test_sphere_shell_and_lattice():
    center, radius, spacing = np.array([0.3, -1.0, 2.0]), 0.45, 0.05
    solid = sphere_particles(center, radius, spacing, fill=True)
    shell = sphere_particles(center, radius, spacing, fill=False)
    r_solid = np.linalg.norm(solid - center, axis=1)
    r_shell = np.linalg.norm(shell - center, axis=1)
    assert np.all(r_shell > radius - spacing) and np.all(r_shell <= radius + 1e-9)
    assert len(shell) == np.count_nonzero(r_solid > radius - spacing)
    ijk = (solid - center) / spacing
    np.testing.assert_allclose(ijk, np.round(ijk), atol=1e-9)
    assert np.any(np.all(np.isclose(solid, center), axis=1))  # the centre is a lattice point


def test_sphere_validation():
    with pytest.raises(ValueError, match="radius"):
        sphere_particles([0, 0, 0], radius=-1.0, spacing=0.1)
    with pytest.raises(ValueError, match="center"):
        sphere_particles([0, 0], radius=1.0, spacing=0.1)


# ---------------------------------------------------------------------------------------------
# load_points


def test_load_points_round_trips_npy_and_ply(tmp_path):
    points = np.random.default_rng(1).normal(size=(50, 3))
    np.save(tmp_path / "pts.npy", points.astype(np.float32))
    np.testing.assert_allclose(load_points(tmp_path / "pts.npy"), points.astype(np.float32))
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    assert o3d.io.write_point_cloud(str(tmp_path / "pts.ply"), cloud)
    loaded = load_points(str(tmp_path / "pts.ply"))
    assert loaded.dtype == np.float64
    np.testing.assert_allclose(loaded, points, rtol=1e-6, atol=1e-6)


def test_load_points_accepts_mesh_ply(tmp_path):
    mesh = box_mesh((1.0, 2.0, 3.0))
    write_mesh(mesh, tmp_path / "box.ply")
    loaded = load_points(tmp_path / "box.ply")
    np.testing.assert_allclose(np.sort(loaded, axis=0), np.sort(np.asarray(mesh.vertices), axis=0))


@pytest.mark.parametrize(
    ("name", "content", "error", "match"),
    [
        ("missing.npy", None, FileNotFoundError, "not found"),
        ("flat.npy", np.zeros((4, 2)), ValueError, r"\(4, 2\).*\(N, 3\)"),
        ("nan.npy", np.array([[0.0, 0.0, 0.0], [np.nan, 1.0, 2.0]]), ValueError, "NaN"),
        ("empty.npy", np.zeros((0, 3)), ValueError, "no points"),
        ("pts.txt", "0 0 0\n", ValueError, "extension"),
        ("garbage.ply", "not a ply file\n", ValueError, "no points"),
    ],
)
def test_load_points_errors_name_the_file(tmp_path, name, content, error, match):
    path = tmp_path / name
    if isinstance(content, np.ndarray):
        np.save(path, content)
    elif isinstance(content, str):
        path.write_text(content)
    with pytest.raises(error, match=match) as info:
        load_points(path)
    assert name in str(info.value)


# ---------------------------------------------------------------------------------------------
# load_mesh / mesh_particles / points_inside_mesh


@pytest.mark.parametrize("suffix", [".obj", ".stl", ".ply"])
def test_load_mesh_formats_merge_vertices(tmp_path, suffix):
    write_mesh(box_mesh((1.0, 0.5, 0.25)), tmp_path / f"box{suffix}")
    mesh = load_mesh(tmp_path / f"box{suffix}")
    assert len(mesh.triangles) == 12
    assert len(mesh.vertices) == 8  # STL's 36 corners merged
    np.testing.assert_allclose(mesh.get_max_bound(), [1.0, 0.5, 0.25], rtol=1e-6)


def test_load_mesh_errors_name_the_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothere.obj"):
        load_mesh(tmp_path / "nothere.obj")
    (tmp_path / "mesh.off").write_text("OFF\n")
    with pytest.raises(ValueError, match=r"mesh\.off.*extension"):
        load_mesh(tmp_path / "mesh.off")
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.eye(3)))
    o3d.io.write_point_cloud(str(tmp_path / "cloud.ply"), cloud)
    with pytest.raises(ValueError, match=r"cloud\.ply.*no triangles"):
        load_mesh(tmp_path / "cloud.ply")
    (tmp_path / "nan.obj").write_text("v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(ValueError, match=r"nan\.obj.*NaN"):
        load_mesh(tmp_path / "nan.obj")


@pytest.mark.parametrize(
    ("suffix", "mesh"),
    [
        (".obj", box_mesh((1.0, 0.6, 0.4))),
        (".stl", o3d.geometry.TriangleMesh.create_sphere(0.5, resolution=20)),
        (".ply", o3d.geometry.TriangleMesh.create_sphere(0.5, resolution=20)),
    ],
)
def test_mesh_surface_sample_on_surface_and_evenly_spaced(tmp_path, suffix, mesh):
    spacing = 0.05
    path = tmp_path / f"solid{suffix}"
    write_mesh(mesh, path)
    points = mesh_particles(path, spacing, fill=False)
    assert points.dtype == np.float64
    expected = mesh.get_surface_area() / (spacing**2 * math.sqrt(3.0) / 2.0)
    assert abs(len(points) - expected) <= 1.0
    assert surface_distance(mesh, points).max() < 0.5 * spacing
    assert surface_distance(mesh, points).max() < 1e-4 * spacing
    nearest = self_nearest(points)
    assert 0.6 * spacing <= np.median(nearest) <= 1.2 * spacing
    assert nearest.min() >= 0.5 * spacing  # no clumping
    # No big holes: any point of the surface is near a particle.
    probes = uniform_surface_points(mesh, 2000, seed=3)
    assert brute_nearest(points, probes).max() < 1.2 * spacing  # documented: about 1.1 * spacing


def test_mesh_particles_deterministic_and_accepts_mesh_object():
    mesh = o3d.geometry.TriangleMesh.create_sphere(0.3, resolution=12)
    a = mesh_particles(mesh, 0.05, fill=False)
    b = mesh_particles(o3d.geometry.TriangleMesh(mesh), 0.05, fill=False)
    np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="spacing"):
        mesh_particles(mesh, 0.0, fill=False)


def test_filled_box_matches_brute_force_twin(tmp_path):
    """A closed box: the surface sample moved inward by INSET spacings along its face's normal, those that come
    closer than 0.8 of that to another face dropped (the edges' fins), then lattice inside the box, at least INSET
    spacings deep and 0.5 spacing from the moved surface."""
    size, spacing = np.array([1.03, 0.61, 0.47]), 0.1
    write_mesh(box_mesh(size), tmp_path / "box.obj")
    surface = mesh_particles(tmp_path / "box.obj", spacing, fill=False)
    filled = mesh_particles(tmp_path / "box.obj", spacing, fill=True)

    depth = INSET * spacing
    face_gap = np.concatenate([surface, size - surface], axis=1)  # distance to each of the six faces
    face = face_gap.argmin(1)
    inward = np.zeros_like(surface)
    inward[np.arange(len(surface)), face % 3] = np.where(face < 3, 1.0, -1.0)
    moved = surface + depth * inward

    def depth_inside(p):
        return np.minimum(p, size - p).min(1)

    expected_surface = moved[depth_inside(moved) >= 0.8 * depth - 1e-6]
    assert len(surface) > len(expected_surface) > 0.7 * len(surface)  # the fins are a minority
    np.testing.assert_allclose(filled[: len(expected_surface)], expected_surface, atol=1e-6)
    interior = filled[len(expected_surface) :]

    counts = np.ceil(size / spacing - 1e-6).astype(int)
    axes = [size[a] / 2 + (np.arange(counts[a]) - (counts[a] - 1) / 2) * spacing for a in range(3)]
    lattice = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    inside = np.all((lattice > 0) & (lattice < size), axis=1) & (depth_inside(lattice) >= depth)
    expected = lattice[inside & (brute_nearest(expected_surface, lattice) >= 0.5 * spacing)]
    assert len(expected) > 0.3 * np.prod(counts)
    key = np.lexsort(np.round(interior, 9).T)
    key_e = np.lexsort(np.round(expected, 9).T)
    np.testing.assert_allclose(interior[key], expected[key_e], atol=1e-6)  # OBJ stores ~7 digits


def test_filled_sphere_inset_count_and_no_clumping():
    radius, spacing = 0.6, 0.08
    mesh = o3d.geometry.TriangleMesh.create_sphere(radius, resolution=30)
    filled = mesh_particles(mesh, spacing, fill=True)
    r = np.linalg.norm(filled, axis=1)
    # every particle at least INSET spacings inside (the mesh's chords lie up to 0.6 mm inside the sphere)
    assert r.max() <= radius - INSET * spacing + 1e-3
    inner = radius - INSET * spacing
    volume_count = 4.0 / 3.0 * math.pi * inner**3 / spacing**3
    area_count = 4.0 * math.pi * inner**2 / spacing**2
    assert volume_count + 0.4 * area_count <= len(filled) <= volume_count + 1.3 * area_count
    assert self_nearest(filled).min() >= 0.5 * spacing - 1e-6
    # No holes inside: every point of the inset ball is within a lattice half-diagonal of a particle.
    probes = sphere_particles([0.0, 0.0, 0.0], inner * 0.98, spacing * 0.73)
    assert brute_nearest(filled, probes).max() <= math.sqrt(3.0) / 2.0 * spacing + 1e-6


def test_thin_closed_part_is_inset_by_half_its_thickness():
    """A plate thinner than two insets: its two faces' samples meet in its mid-plane and never cross."""
    spacing, t = 0.05, 0.03
    filled = mesh_particles(box_mesh((0.6, t, 0.5)), spacing, fill=True)
    assert len(filled) > 0.6 * 0.5 / spacing**2  # the plate is still there
    np.testing.assert_allclose(filled[:, 1], t / 2, atol=1e-4)


def test_points_inside_unit_cube(tmp_path):
    cube = box_mesh((1.0, 1.0, 1.0))
    rng = np.random.default_rng(7)
    points = rng.uniform(-0.5, 1.5, size=(2000, 3))
    margin = np.minimum(points, 1.0 - points).min(axis=1)
    points = points[np.abs(margin) > 0.01]  # clearly inside or outside
    expected = margin[np.abs(margin) > 0.01] > 0
    assert 100 < expected.sum() < len(expected) - 100
    np.testing.assert_array_equal(points_inside_mesh(cube, points), expected)
    write_mesh(cube, tmp_path / "cube.stl")
    np.testing.assert_array_equal(points_inside_mesh(tmp_path / "cube.stl", points), expected)
    assert points_inside_mesh(cube, np.zeros((0, 3))).shape == (0,)
    with pytest.raises(ValueError, match=r"\(5, 2\)"):
        points_inside_mesh(cube, np.zeros((5, 2)))


def test_open_mesh_warns_closed_mesh_does_not(tmp_path, caplog):
    write_mesh(box_mesh((1.0, 1.0, 1.0)), tmp_path / "closed.stl")
    with caplog.at_level(logging.WARNING, logger="fluidsim.sources"):
        mesh_particles(tmp_path / "closed.stl", 0.2, fill=True)
    assert not caplog.records
    open_box = box_mesh((1.0, 1.0, 1.0))
    open_box.remove_triangles_by_index([0])
    with caplog.at_level(logging.WARNING, logger="fluidsim.sources"):
        mesh_particles(open_box, 0.2, fill=True)
    assert any("not closed" in r.getMessage() for r in caplog.records)
